"""The two worker processes of the one-run A/B scripts here (``ab_update.py``, ``ab_lods.py``): one
importing git ``rev``'s ``optim`` and ``pmetric`` (from ``git archive``), one this tree's, fed the same
requests in an alternating order so that both see the same machine load."""
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path


def old_and_new(root: Path, rev: str, worker: str, args: list, calls: list) -> dict:
    """``{"old": [...], "new": [...]}``: the JSON line each worker answered per call. ``worker``: the
    worker's source (run with ``python -c``, ``args`` after it; it prints ``ready`` once set up, then one
    JSON line per request line read from stdin); ``calls``: ``(request line, "old" or "new" first)``."""
    def start(src: Path):
        env = dict(os.environ, PYTHONPATH=str(src))
        return subprocess.Popen([sys.executable, "-c", worker, *map(str, args)], cwd=src, env=env,
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)

    with tempfile.TemporaryDirectory() as tmp:
        archive = subprocess.check_output(["git", "-C", str(root), "archive", rev, "optim", "pmetric"])
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        workers = {"old": start(Path(tmp)), "new": start(root)}
        for w in workers.values():
            assert w.stdout.readline().strip() == "ready"
        res = {k: [] for k in workers}
        for line, first in calls:
            for k in ((first, "new") if first == "old" else (first, "old")):
                workers[k].stdin.write(f"{line}\n")
                workers[k].stdin.flush()
                res[k].append(json.loads(workers[k].stdout.readline()))
        for w in workers.values():
            w.stdin.close()
            w.wait()
    return res

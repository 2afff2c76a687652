"""Shared parts of the A/B scripts here: another commit's ``optim`` package loaded beside the working
tree's, and the bench_optim meshes."""
import importlib.util
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

import optim  # noqa: E402

# (label, make() -> (vertices, faces)): bench_optim's 1M torus and 1.3M sphere
BENCH_MESHES = (("bumpy_torus(1000, 500)", lambda: optim.bumpy_torus(1000, 500, seed=0)),
                ("bumpy_sphere(8)", lambda: optim.bumpy_sphere(8, seed=0)[:2]))


def optim_at(rev: str):
    """The ``optim/`` package of git ``rev``, imported as the package ``optim_old`` (its modules import
    each other relatively)."""
    tmp = Path(tempfile.mkdtemp())
    subprocess.run(f"git archive {rev} optim | tar -x -C {tmp}", shell=True, cwd=ROOT, check=True)
    (tmp / "optim").rename(tmp / "optim_old")
    spec = importlib.util.spec_from_file_location("optim_old", tmp / "optim_old" / "__init__.py",
                                                  submodule_search_locations=[str(tmp / "optim_old")])
    old = importlib.util.module_from_spec(spec)
    sys.modules["optim_old"] = old
    spec.loader.exec_module(old)
    return old

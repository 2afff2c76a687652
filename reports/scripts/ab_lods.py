"""One-run A/B of :func:`optim.direction_keys` (the loop every ``plod lods`` level runs: a framed view and
its keys per direction) at a git revision against this tree: two worker processes, each importing its own
``optim`` and ``pmetric`` (the revision's from ``git archive``), building the same tree and timing the
same calls in turn (order alternated per round), so both see the same machine load. Checks that both give
identical keys.

    .venv/bin/python reports/scripts/ab_lods.py [REV] [--mesh horse.ply] [--directions 64] [--rounds 6] [--sizes 2,8] [--chain]

REV defaults to ca461ef (before the framing sphere and the default display were made once, not per view).
Each call: the hybrid tree of ``../shared/data/meshes/MESH`` (or a procedural ``sphere:SUBDIV``), relit
with the default light, object sizes cycling through ``--sizes`` (deg), no gaze, ``--directions`` directions.
``--chain``: each call is a whole :func:`optim.lod_chain` at budgets 25 / 5 / 2 % of the input over
``--directions`` directions (``plod lods --budgets 25%,5%,2%``), checked for identical sizes and cuts.
Prints wall ms per direction (or per chain; median over calls) of each and the paired ratio.
"""
import argparse
import os
import sys
from pathlib import Path

import numpy as np

from _workers import old_and_new  # (this folder: the scripts run as files)

ROOT = Path(__file__).resolve().parents[2]

WORKER = r"""
import hashlib, json, sys, time
import numpy as np
import optim
mesh, n, chain = sys.argv[1], int(sys.argv[2]), sys.argv[3] == "1"
if mesh.startswith("sphere:"):
    v, f, c = optim.bumpy_sphere(int(mesh.split(":")[1]), seed=0)[:2] + (None,)
else:
    v, f, c = optim.load_mesh(mesh)
tree = optim.build_tree(v, f, c, method="hybrid")
light = optim.Lighting()
optim.direction_keys(tree, 2.0, 4, lighting=light)
print("ready", flush=True)
for line in sys.stdin:
    size = float(line)
    t0 = time.perf_counter()
    if chain:  # plod lods --budgets 25%,5%,2%: the levels' sizes and cuts
        T = tree.n_triangles
        lv = optim.lod_chain(tree, budgets=[T // 4, T // 20, T // 50], directions=n, lighting=light)
        k = np.concatenate([[l.object_deg for l in lv], np.concatenate([l.cut.unfolded for l in lv])])
        wall = time.perf_counter() - t0
    else:
        k = optim.direction_keys(tree, size, n, lighting=light)
        wall = (time.perf_counter() - t0) / n
    print(json.dumps({"wall": wall, "hash": hashlib.sha256(np.asarray(k).tobytes()).hexdigest()}), flush=True)
"""


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("rev", nargs="?", default="ca461ef")
    ap.add_argument("--mesh", default="horse.ply")
    ap.add_argument("--directions", type=int, default=64)
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--sizes", default="2,8", help="object sizes (deg) the calls cycle through")
    ap.add_argument("--chain", action="store_true", help="time whole lod_chain calls (budgets 25 / 5 / 2 %%)")
    a = ap.parse_args()
    mesh = a.mesh if a.mesh.startswith("sphere:") else str(ROOT.parent / "shared" / "data" / "meshes" / a.mesh)
    sizes = [float(x) for x in a.sizes.split(",")]
    calls = [(sizes[r % len(sizes)], "old" if r % 4 < 2 else "new") for r in range(a.rounds)]
    res = old_and_new(ROOT, a.rev, WORKER, [mesh, a.directions, "1" if a.chain else "0"], calls)
    same = all(o["hash"] == n["hash"] for o, n in zip(res["old"], res["new"]))
    wall = {k: np.array([x["wall"] for x in v]) * 1e3 for k, v in res.items()}
    load = os.getloadavg()
    what = ("lod_chain (budgets 25 / 5 / 2 %)" if a.chain else
            f"direction_keys ({' / '.join(a.sizes.split(','))} deg)")
    print(f"git {a.rev} (old) against this tree (new): {what} on {a.mesh} (hybrid tree, relit), {a.directions} "
          f"directions x {a.rounds} calls, alternated; load average {load[0]:.1f} / {load[1]:.1f} at the end; "
          f"identical {'levels' if a.chain else 'keys'}: {same}")
    unit = "ms per chain" if a.chain else "ms per direction"
    for k in ("old", "new"):
        print(f"  {k}: {np.median(wall[k]):.2f} {unit} median (min {wall[k].min():.2f})")
    print(f"  ratio old / new: median {np.median(wall['old']) / np.median(wall['new']):.2f}x, paired median "
          f"{np.median(wall['old'] / wall['new']):.2f}x")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())

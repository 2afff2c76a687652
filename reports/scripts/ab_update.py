"""One-run A/B of the per-view update (score + budget cut + extract, bench_optim's loop) at a git revision
against this tree: two worker processes, each importing its own ``optim`` and ``pmetric`` (the revision's
from ``git archive``), building the same tree and timing the same views in turn (order alternated per
round), so both see the same machine load. Checks that both give identical keys and meshes.

    .venv/bin/python reports/scripts/ab_update.py [REV] [--mesh torus|sphere|turbine] [--rounds 4] [--moving]

REV defaults to 56f8ac8 (before the asynchronous chunk programs and the other update changes). Meshes: the
bench's 1,000,000-triangle bumpy torus, 1,310,720-triangle bumpy sphere or the shared 796k turbine blade;
8 views around the object as in ``experiments.bench_optim`` (relit, perceptual keys, default model, 10 %
budget); ``--moving``: each view carries the previous frame of a 60 deg/s orbit at 60 Hz. Prints wall and
process CPU ms per update (median over views and rounds) of each and the paired ratio.
"""
import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from _workers import old_and_new  # (this folder: the scripts run as files)

ROOT = Path(__file__).resolve().parents[2]

WORKER = r"""
import hashlib, json, sys, time
import numpy as np
import optim
which, moving = sys.argv[1], sys.argv[2] == "1"
if which == "torus":
    v, f = optim.bumpy_torus(1000, 500)[:2]
elif which == "sphere":
    v, f = optim.bumpy_sphere(8)[:2]
else:
    v, f = optim.load_mesh(which)[:2]
tree = optim.build_tree(v, f, method="meshopt")
def at(az, **kw):
    return optim.View.framing(v, 30.0, direction=(np.sin(az), 0.25, np.cos(az)), lighting=optim.Lighting(), **kw)
views = []
for i in range(8):
    az = 2 * np.pi * i / 8
    views.append(at(az, previous=at(az - np.radians(1.0)), dt_s=1 / 60) if moving else at(az))
T = tree.n_triangles
def update(view):
    keys = optim.score(tree, view)
    cut = optim.budget_cut(tree, keys, T // 10, monotone="trust")
    return keys, optim.extract(tree, cut)
for view in views[:2]:
    update(view)
print("ready", flush=True)
for line in sys.stdin:
    i = int(line)
    c0, t0 = time.process_time(), time.perf_counter()
    keys, (vv, ff, cc) = update(views[i])
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    h = hashlib.sha256(keys.tobytes() + vv.tobytes() + ff.tobytes()).hexdigest()
    print(json.dumps({"wall": wall, "cpu": cpu, "hash": h, "triangles": int(len(ff))}), flush=True)
"""


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("rev", nargs="?", default="56f8ac8")
    ap.add_argument("--mesh", default="torus")
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--moving", action="store_true")
    a = ap.parse_args()
    mesh = a.mesh
    if mesh == "turbine":
        mesh = str(ROOT.parent / "shared" / "data" / "meshes" / "turbineblade-subdiv-796k.ply")
    calls = [(i, "old" if (r + i) % 2 == 0 else "new") for r in range(a.rounds) for i in range(8)]
    res = old_and_new(ROOT, a.rev, WORKER, [mesh, "1" if a.moving else "0"], calls)
    same = all(o["hash"] == n["hash"] for o, n in zip(res["old"], res["new"]))
    wall = {k: np.array([x["wall"] for x in v]) * 1e3 for k, v in res.items()}
    cpu = {k: np.array([x["cpu"] for x in v]) * 1e3 for k, v in res.items()}
    load = os.getloadavg()
    print(f"git {a.rev} (old) against this tree (new): {a.mesh}{' moving' if a.moving else ''}, 8 views x "
          f"{a.rounds} rounds, alternated; load average {load[0]:.1f} / {load[1]:.1f} at the end; "
          f"identical keys and meshes: {same}")
    for k in ("old", "new"):
        print(f"  {k}: update {np.median(wall[k]):.1f} ms median (min {wall[k].min():.1f}), "
              f"CPU {np.median(cpu[k]):.1f} ms")
    print(f"  ratio old / new: wall median {np.median(wall['old']) / np.median(wall['new']):.2f}x, paired median "
          f"{np.median(wall['old'] / wall['new']):.2f}x, min {wall['old'].min() / wall['new'].min():.2f}x; "
          f"CPU median {np.median(cpu['old']) / np.median(cpu['new']):.2f}x")
    return 0 if same else 1


if __name__ == "__main__":
    t0 = time.perf_counter()
    sys.exit(main())

"""One-run A/B of table mode's two gather paths in ``optim.score`` (static views, perceptual keys): numpy
gathers (``_table_keys_host``) against the XLA programs with their gathers, on the same tree and views,
alternated view by view (after one warm-up call of each), checking that both give the same keys:

    .venv/bin/python reports/scripts/ab_score_gathers.py [--mesh torus|sphere|both] [--views 8] [--repeat 3]

The bench_optim views (8 around the object, framed at 30 deg, relit); per view the least of ``--repeat``
calls of each path. Prints the backend, the core count, the median score ms of each path and their ratio,
and which path ``optim._score._host_gathers`` picks here.
"""
import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
import jax  # noqa: E402

import optim  # noqa: E402
import optim._score as S  # noqa: E402
from experiments.bench_optim import _views  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--mesh", choices=("torus", "sphere", "both"), default="both")
ap.add_argument("--views", type=int, default=8)
ap.add_argument("--repeat", type=int, default=3)
a = ap.parse_args()
meshes = {"torus": lambda: optim.bumpy_torus(1000, 500, seed=0), "sphere": lambda: optim.bumpy_sphere(8, seed=0)[:2]}
names = list(meshes) if a.mesh == "both" else [a.mesh]
print(f"backend {jax.default_backend()}, {os.cpu_count()} cores; _host_gathers() -> {S._host_gathers()}")
for name in names:
    v, f = meshes[name]()
    tree = optim.build_tree(v, f)
    views = _views(tree.vertices, a.views, optim.Lighting())
    for host in (True, False):  # warm-up: the tree's scoring context, the key table, compilation
        S._host_gathers = (lambda h: (lambda: h))(host)
        optim.score(tree, views[0])
    times = {True: [], False: []}
    same = 0
    for view in views:
        keys = {}
        best = {True: np.inf, False: np.inf}
        for _ in range(a.repeat):
            for host in (True, False):
                S._host_gathers = (lambda h: (lambda: h))(host)
                t0 = time.perf_counter()
                keys[host] = optim.score(tree, view)
                best[host] = min(best[host], time.perf_counter() - t0)
        same += bool(np.array_equal(keys[True], keys[False]))
        for host in (True, False):
            times[host].append(best[host] * 1e3)
    h, x = statistics.median(times[True]), statistics.median(times[False])
    print(f"{name} ({f.shape[0]:,} triangles): score ms median numpy gathers {h:.1f}, XLA gathers {x:.1f}, "
          f"ratio {h / x:.2f}x; identical keys in {same}/{len(views)} views")

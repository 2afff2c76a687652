"""A/B of ``optim.visible_budget_cut`` against the ``optim`` package of another commit, in one run (machines
are noisy):

    .venv/bin/python reports/scripts/ab_visible_cut.py [REV]   (default REV: HEAD)

The other commit's ``optim/`` is loaded as ``optim_old``. The bench_optim meshes (1M torus, 1.3M
sphere), its 8 relit views, budget 10 % of the input; per view the least of 3 calls of each version,
alternating, on the same keys; prints the median times and ratio (old / new) and checks that both return
identical meshes.
"""
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import numpy as np  # noqa: E402

from _ab import BENCH_MESHES, optim, optim_at  # noqa: E402
from experiments.bench_optim import _views  # noqa: E402

rev = sys.argv[1] if len(sys.argv) > 1 else "HEAD"
old = optim_at(rev)

for name, make in BENCH_MESHES:
    v, f = make()
    tree, tree_old = optim.build_tree(v, f), old.build_tree(v, f)
    budget = tree.n_triangles // 10
    t_old, t_new = [], []
    for view in _views(tree.vertices, 8, optim.Lighting()):
        keys = optim.score(tree, view)
        bo = bn = float("inf")
        for _ in range(3):
            t0 = time.perf_counter()
            ro = old.visible_budget_cut(tree_old, keys, budget, view, monotone="trust")
            t1 = time.perf_counter()
            rn = optim.visible_budget_cut(tree, keys, budget, view, monotone="trust")
            t2 = time.perf_counter()
            bo, bn = min(bo, t1 - t0), min(bn, t2 - t1)
        assert ro.cut_budget == rn.cut_budget and all(
            (a is None and b is None) or np.array_equal(a, b) for a, b in zip(ro.mesh, rn.mesh)), name
        t_old.append(bo * 1e3)
        t_new.append(bn * 1e3)
    mo, mn = statistics.median(t_old), statistics.median(t_new)
    ratio = statistics.median(o / n for o, n in zip(t_old, t_new))
    print(f"{name}: {rev} {mo:.1f} ms, working tree {mn:.1f} ms, median ratio {ratio:.2f}x (identical meshes in 8/8 views)")

"""A/B of ``optim.extract`` against the version of another commit, in one run (machines are noisy):

    .venv/bin/python reports/scripts/ab_extract.py [REV]   (default REV: HEAD~1)

The other commit's ``optim/`` is loaded as ``optim_old``. The bench_optim meshes (1M torus, 1.3M
sphere), its 8 relit views, budget cuts of 10 % and 20 % of the input triangles; per cut the least of 5
calls of each version, alternating; prints the median ratio (old / new) and checks that both return
identical arrays.
"""
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import numpy as np  # noqa: E402

from _ab import BENCH_MESHES, optim, optim_at  # noqa: E402
from experiments.bench_optim import _views  # noqa: E402

rev = sys.argv[1] if len(sys.argv) > 1 else "HEAD~1"
old = optim_at(rev)

for name, make in BENCH_MESHES:
    v, f = make()
    tree = optim.build_tree(v, f)
    for frac in (0.1, 0.2):
        t_old, t_new = [], []
        for view in _views(tree.vertices, 8, optim.Lighting()):
            cut = optim.budget_cut(tree, optim.score(tree, view), int(frac * tree.n_triangles), monotone="trust")
            unf = cut.unfolded
            a, b = old.extract(tree, unf), optim.extract(tree, unf)
            assert all((x is None and y is None) or np.array_equal(x, y) for x, y in zip(a, b))
            bo = bn = float("inf")
            for _ in range(5):
                t0 = time.perf_counter()
                old.extract(tree, unf)
                t1 = time.perf_counter()
                optim.extract(tree, unf)
                t2 = time.perf_counter()
                bo, bn = min(bo, t1 - t0), min(bn, t2 - t1)
            t_old.append(bo * 1e3)
            t_new.append(bn * 1e3)
        r = statistics.median([o / n for o, n in zip(t_old, t_new)])
        print(f"{name}, budget {frac:.0%}: extract {rev} {statistics.median(t_old):.1f} ms, now "
              f"{statistics.median(t_new):.1f} ms, ratio {r:.2f}x (identical arrays in 8/8 views)")

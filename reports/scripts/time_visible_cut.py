"""Cost of ``optim.visible_budget_cut`` against the plain budget cut + extract on the bench_optim meshes:

    .venv/bin/python reports/scripts/time_visible_cut.py

The 1M-triangle torus and the 1.3M sphere, the 8 bench_optim views (relit), budget 10 % of the input; per
view the least of 3 calls of each; prints medians (ms), the budget cuts tried and the drawn / whole-cut
triangles. Moving camera: the bench_optim moving views (a 60 deg/s orbit at 60 Hz), each searched with the
previous frame's ``cut_budget`` as ``hint`` (that frame's own search untimed).
"""
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
import optim  # noqa: E402
from experiments.bench_optim import _views  # noqa: E402

for name, make in (("bumpy_torus(1000, 500)", lambda: optim.bumpy_torus(1000, 500, seed=0)),
                   ("bumpy_sphere(8)", lambda: optim.bumpy_sphere(8, seed=0)[:2])):
    v, f = make()
    tree = optim.build_tree(v, f)
    budget = tree.n_triangles // 10
    plain, vis, evals, ratio = [], [], [], []
    for view in _views(tree.vertices, 8, optim.Lighting()):
        keys = optim.score(tree, view)
        bp = bv = float("inf")
        for _ in range(3):
            t0 = time.perf_counter()
            optim.extract(tree, optim.budget_cut(tree, keys, budget, monotone="trust"))
            t1 = time.perf_counter()
            r = optim.visible_budget_cut(tree, keys, budget, view, monotone="trust")
            t2 = time.perf_counter()
            bp, bv = min(bp, t1 - t0), min(bv, t2 - t1)
        plain.append(bp * 1e3)
        vis.append(bv * 1e3)
        evals.append(r.evaluations)
        ratio.append(r.cut.triangles / r.triangles)
    warm, wevals = [], []
    for view in _views(tree.vertices, 8, optim.Lighting(), moving=True):
        hint = optim.visible_budget_cut(tree, optim.score(tree, view.previous), budget, view.previous,
                                        monotone="trust").cut_budget
        keys = optim.score(tree, view)
        bw = float("inf")
        for _ in range(3):
            t0 = time.perf_counter()
            r = optim.visible_budget_cut(tree, keys, budget, view, monotone="trust", hint=hint)
            bw = min(bw, time.perf_counter() - t0)
        warm.append(bw * 1e3)
        wevals.append(r.evaluations)
    p_ms, v_ms, w_ms = statistics.median(plain), statistics.median(vis), statistics.median(warm)
    print(f"{name}: visible_budget_cut / (cut + extract) {v_ms / p_ms:.1f}x static, {w_ms / p_ms:.1f}x moving with hint")
    print(f"{name}: cut + extract {statistics.median(plain):.1f} ms, visible_budget_cut {statistics.median(vis):.1f} ms "
          f"({statistics.median(evals):g} budget cuts, whole cut / drawn triangles {statistics.median(ratio):.2f}); "
          f"moving camera with the previous frame's hint {statistics.median(warm):.1f} ms "
          f"({statistics.median(wevals):g} budget cuts)")

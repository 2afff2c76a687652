"""The cost of the normals a cut carries: ``optim.extract(tree, cut, normals)`` for None / "region" / "faces"
on a bench_optim mesh (the 1.3M bumpy sphere), budget 10 %, 8 views around it with lights (alternating the
three, best of 3 each per view; medians over views; ratios in this one run).

    .venv/bin/python reports/scripts/time_normals.py [SUBDIV]
"""
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import numpy as np  # noqa: E402

import optim  # noqa: E402


def main():
    sub = int(sys.argv[1]) if len(sys.argv) > 1 else 8
    v, f = optim.bumpy_sphere(sub)[:2]
    tree = optim.build_tree(v, f)
    t0 = time.perf_counter()
    optim.region_normals(tree)
    build = time.perf_counter() - t0
    out = {None: [], "region": [], "faces": []}
    for k in range(8):
        az = 2 * np.pi * k / 8
        view = optim.View.framing(v, direction=(np.sin(az), 0.3, np.cos(az)), lighting=optim.Lighting())
        cut = optim.budget_cut(tree, optim.score(tree, view), tree.n_triangles // 10, monotone="trust")
        best = {h: np.inf for h in out}
        for _ in range(3):
            for h in out:
                t0 = time.perf_counter()
                optim.extract(tree, cut, h)
                best[h] = min(best[h], time.perf_counter() - t0)
        for h in out:
            out[h].append(best[h] * 1e3)
    med = {h: statistics.median(x) for h, x in out.items()}
    print(f"{tree.n_triangles:,} triangles, cut {cut.triangles:,}; region_normals once per tree {build * 1e3:.0f} ms")
    for h, m in med.items():
        print(f"  extract normals={h!s:7s} {m:6.2f} ms  (+{m - med[None]:.2f} ms, {m / med[None]:.2f}x)")


if __name__ == "__main__":
    main()

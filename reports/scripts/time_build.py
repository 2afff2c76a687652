"""Tree build time by method on one mesh, in one run (alternating, best of 2 each): the hybrid tree's cost
against the meshopt and qem trees.

    .venv/bin/python reports/scripts/time_build.py [SUBDIV]     # bumpy_sphere(SUBDIV), default 7 (327,680 triangles)
"""
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import optim  # noqa: E402


def main():
    sub = int(sys.argv[1]) if len(sys.argv) > 1 else 7
    v, f = optim.bumpy_sphere(sub)[:2]
    best = {}
    for _ in range(2):
        for m in ("meshopt", "hybrid", "qem"):
            t0 = time.perf_counter()
            optim.build_tree(v, f, method=m)
            best[m] = min(best.get(m, 1e9), time.perf_counter() - t0)
    print(f"bumpy_sphere({sub}): {len(f):,} triangles")
    for m, s in best.items():
        print(f"  {m:8s} {s:6.2f} s  ({s / best['meshopt']:.2f}x meshopt)")


if __name__ == "__main__":
    main()

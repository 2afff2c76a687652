"""Which flight frames are the slowest to refine with all criteria, and why: the refinement of the 1025 x 1025
fractal for every ``--step``-th frame from 3 (each frame's least of 3 runs), listed slowest first with the
frame's triangles and its yaw rate (deg/s, the flight's sinusoidal sweep plus the orbit), one core:

    OMP_NUM_THREADS=1 taskset -c 1 .venv/bin/python reports/terrain/scripts/worst_frames.py [--step 10] [--top 8]
"""
import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from _flight import table1_flight  # noqa: E402
from optim._terrain import TerrainCriteria, refine_terrain  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--step", type=int, default=10)
ap.add_argument("--top", type=int, default=8)
a = ap.parse_args()
hf, cams, xi, dt, fl = table1_flight()
crit = TerrainCriteria(xi=xi)
refine_terrain(hf, cams[3], crit, (cams[2], cams[1], cams[0]), dt_s=dt)  # warm-up: compiles H'(v, e)


def yaw_rate(k):  # deg/s of the heading: the orbit's 2 pi turns / duration plus the sweep's derivative
    t = k / fl["fps"]
    orbit = 360.0 * fl["orbit_turns"] / fl["duration_s"]
    sweep = fl["yaw_amp_deg"] * 2 * math.pi / fl["yaw_period_s"] * math.cos(2 * math.pi * t / fl["yaw_period_s"])
    return orbit + sweep


rows = []
for k in range(3, len(cams), a.step):
    best, lod = 1e9, None
    for _ in range(3):
        t0 = time.perf_counter()
        lod = refine_terrain(hf, cams[k], crit, (cams[k - 1], cams[k - 2], cams[k - 3]), dt_s=dt)
        best = min(best, time.perf_counter() - t0)
    rows.append((1e3 * best, k, lod.triangles, yaw_rate(k)))
ms = np.array([r[0] for r in rows])
tri = np.array([r[2] for r in rows])
print(f"{len(rows)} frames: median {np.median(ms):.1f} ms, {np.median(tri):,.0f} triangles; "
      f"ms per million triangles out: median {np.median(ms / tri * 1e6):.1f}; "
      f"correlation of ms and triangles {np.corrcoef(ms, tri)[0, 1]:.2f}")
print("| frame | ms | triangles | yaw rate (deg/s) |")
print("| ---: | ---: | ---: | ---: |")
for m, k, n, w in sorted(rows, reverse=True)[:a.top]:
    print(f"| {k} | {m:.1f} | {n:,} | {w:+.1f} |")

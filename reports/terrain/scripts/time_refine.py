"""The ms columns of Table 1 for the 1025 x 1025 fractal without the rest of the experiment: the refinement
alone over the flight's every ``--step``-th frame from 3, timed as experiments.terrain.run_flight times it
(one warm-up call, then wall clock per refine_terrain call), with the process CPU time of each call too,
one core:

    OMP_NUM_THREADS=1 taskset -c 1 .venv/bin/python reports/terrain/scripts/time_refine.py [--step 10] [--repeat 1]

With ``--repeat k`` each frame is refined k times in a row and its least time kept (less of the noise of a
shared machine in the figures; the triangles are the same each time).
"""
import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from _flight import table1_flight  # noqa: E402
from experiments.terrain import SEED_TABLE  # noqa: E402
from optim._terrain import TerrainCriteria, refine_terrain  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--step", type=int, default=10)
ap.add_argument("--repeat", type=int, default=1)
a = ap.parse_args()
hf, cams, xi, dt, _ = table1_flight()
frames = list(range(3, len(cams), a.step))
print(f"{len(frames)} frames, least of {a.repeat} per frame")
print("| size | periphery | velocity | cull | mean triangles / frame | ms / frame median | worst | CPU ms median | worst |")
print("| --- | --- | --- | --- | ---: | ---: | ---: | ---: | ---: |")
for (s, p, v, c), _ in SEED_TABLE:
    crit = TerrainCriteria(size=bool(s), periphery=bool(p), velocity=bool(v), cull=bool(c), xi=xi)
    refine_terrain(hf, cams[3], crit, (cams[2], cams[1], cams[0]), dt_s=dt)  # warm-up: compiles H'(v, e)
    tris, wall, cpu = [], [], []
    for k in frames:
        prev = (cams[k - 1], cams[k - 2], cams[k - 3])
        w = u = np.inf
        for _ in range(a.repeat):
            c0, t0 = time.process_time(), time.perf_counter()
            lod = refine_terrain(hf, cams[k], crit, prev, dt_s=dt)
            w, u = min(w, time.perf_counter() - t0), min(u, time.process_time() - c0)
        tris.append(lod.triangles)
        wall.append(w)
        cpu.append(u)
    wall, cpu = 1e3 * np.array(wall), 1e3 * np.array(cpu)
    yn = lambda b: "yes" if b else "no"  # noqa: E731
    print(f"| {yn(s)} | {yn(p)} | {yn(v)} | {yn(c)} | {np.mean(tris):,.0f} | {np.median(wall):.1f} | {wall.max():.1f} | "
          f"{np.median(cpu):.1f} | {cpu.max():.1f} |", flush=True)

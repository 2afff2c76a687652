"""The ms columns of Table 1 for the 1025 x 1025 fractal without the rest of the experiment: the refinement
alone over the flight's every ``--step``-th frame, timed as experiments.terrain.run_flight times it (wall clock
per refine_terrain call after one warm-up call), plus the process CPU time per frame, one core:

    OMP_NUM_THREADS=1 taskset -c 1 .venv/bin/python reports/terrain/scripts/time_refine.py [--step 10]
"""
import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from experiments.terrain import FLIGHT, SEED_TABLE, flight_cameras, load_config, repo_path, run_flight  # noqa: E402
from optim._terrain import Heightfield, TerrainCriteria, fractal_heightfield  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--step", type=int, default=10)
a = ap.parse_args()
hf = Heightfield(fractal_heightfield(1025, seed=0, relief=600.0), 10.0)
fl = load_config(repo_path("configs/terrain_flight.toml"), FLIGHT)
cams = flight_cameras(hf, fl)
xi = 1280 / (2.0 * fl["fov_deg"][0])
print("| size | periphery | velocity | cull | mean triangles / frame | ms / frame median | worst | CPU ms / frame |")
print("| --- | --- | --- | --- | ---: | ---: | ---: | ---: |")
for (s, p, v, c), _ in SEED_TABLE:
    crit = TerrainCriteria(size=bool(s), periphery=bool(p), velocity=bool(v), cull=bool(c), xi=xi)
    c0 = time.process_time()
    tris, secs = run_flight(hf, cams, crit, fl["fps"], a.step)
    cpu = (time.process_time() - c0) / (len(secs) + 1)  # run_flight refines one warm-up frame too
    yn = lambda b: "yes" if b else "no"  # noqa: E731
    print(f"| {yn(s)} | {yn(p)} | {yn(v)} | {yn(c)} | {tris.mean():,.0f} | {1e3 * np.median(secs):.1f} | "
          f"{1e3 * secs.max():.1f} | {1e3 * cpu:.1f} |", flush=True)

"""One-run A/B of the per-frame refinement of the 1025 x 1025 fractal: refine_terrain at a git revision against
this tree, the same flight frames alternated (every ``--step``-th frame from 3, as the table's ms columns), one
core, checking that both give the same split sets, drawn leaves, fans and triangles:

    OMP_NUM_THREADS=1 taskset -c 1 .venv/bin/python reports/terrain/scripts/ab_refine.py [REV] [--step 10]

REV defaults to 56f8ac8 (before the float32 bound pass of the size test); 3de5b5b is before the per-level
rewrite. Prints, per criteria, wall-clock ms per frame (median, worst) of each, their ratios and the process
CPU time of each over all frames.
"""
import argparse
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
import optim._terrain as T  # noqa: E402
from experiments.terrain import FLIGHT, flight_cameras, load_config, named_criteria, repo_path  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("rev", nargs="?", default="56f8ac8")
ap.add_argument("--step", type=int, default=10)
a = ap.parse_args()
old = types.ModuleType("old_terrain")
sys.modules["old_terrain"] = old
old.__package__ = "optim"  # its relative imports (optim._terrain_bounds) resolve in this tree
exec(subprocess.check_output(["git", "-C", str(ROOT), "show", f"{a.rev}:optim/_terrain.py"]).decode(), old.__dict__)
old.TerrainCamera = T.TerrainCamera  # refine_terrain checks its cameras' class: the flight's are this tree's
hf = T.Heightfield(T.fractal_heightfield(1025, seed=0, relief=600.0), 10.0)
fl = load_config(repo_path("configs/terrain_flight.toml"), FLIGHT)
cams = flight_cameras(hf, fl)
frames = list(range(3, len(cams), a.step))
xi = 1280 / 400
crits = dict(named_criteria(xi))
crits["size + velocity + cull"] = T.TerrainCriteria(periphery=False, xi=xi)
print(f"git {a.rev} (old) against this tree (new), {len(frames)} flight frames, fractal 1025")
for name in ("cull", "size + cull", "size + periphery + cull", "size + velocity + cull", "all"):
    crit = crits[name]
    wall = {"old": [], "new": []}
    cpu = {"old": 0.0, "new": 0.0}
    for mod in (old, T):
        mod.refine_terrain(hf, cams[3], crit, (cams[2], cams[1], cams[0]))  # warm-up: compiles H'(v, e)
    same = 0
    for k in frames:
        prev = (cams[k - 1], cams[k - 2], cams[k - 3])
        out = {}
        for mod, key in ((old, "old"), (T, "new")):
            c0, t0 = time.process_time(), time.perf_counter()
            out[key] = mod.refine_terrain(hf, cams[k], crit, prev)
            wall[key].append(time.perf_counter() - t0)
            cpu[key] += time.process_time() - c0
        same += out["old"].triangles == out["new"].triangles and all(
            np.array_equal(x, y) for f in ("split", "drawn", "fans")
            for x, y in zip(getattr(out["old"], f), getattr(out["new"], f)))
    o, n = np.array(wall["old"]), np.array(wall["new"])
    print(f"{name}: old {1e3 * np.median(o):.1f} / {1e3 * o.max():.1f} ms, new {1e3 * np.median(n):.1f} / "
          f"{1e3 * n.max():.1f} ms (median / worst); ratio median {np.median(o) / np.median(n):.2f}x, worst "
          f"{o.max() / n.max():.2f}x, per-frame median {np.median(o / n):.2f}x; CPU {cpu['old']:.2f} s vs "
          f"{cpu['new']:.2f} s ({cpu['old'] / cpu['new']:.2f}x); identical split sets, leaves and triangles in "
          f"{same}/{len(frames)} frames", flush=True)

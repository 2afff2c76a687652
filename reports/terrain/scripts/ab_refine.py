"""One-run A/B of the per-frame refinement: refine_terrain at git 3de5b5b (before the 2026-12-03 rewrite) against
this tree, the same flight frames alternated, one core: `OMP_NUM_THREADS=1 taskset -c 1 .venv/bin/python reports/terrain/scripts/ab_refine.py`."""
import time, sys, subprocess, types, numpy as np
ROOT = __import__("pathlib").Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
import optim._terrain as T
from experiments.terrain import flight_cameras, FLIGHT, named_criteria, load_config, repo_path
old = types.ModuleType("old_terrain"); sys.modules["old_terrain"] = old
exec(subprocess.check_output(["git", "-C", str(ROOT), "show", "3de5b5b:optim/_terrain.py"]).decode(), old.__dict__)
hf = T.Heightfield(T.fractal_heightfield(1025, seed=0, relief=600.0), 10.0)
fl = load_config(repo_path("configs/terrain_flight.toml"), FLIGHT)
cams = flight_cameras(hf, fl)
frames = list(range(3, len(cams), 30))
for name in ("cull", "size + cull", "all"):
    crit = named_criteria(1280 / 400)[name]
    t = {"old": [], "new": []}
    for mod, key in ((old, "old"), (T, "new")):
        mod.refine_terrain(hf, cams[3], crit, (cams[2], cams[1], cams[0]))
    for k in frames:
        prev = (cams[k - 1], cams[k - 2], cams[k - 3])
        for mod, key in ((old, "old"), (T, "new")):
            t0 = time.perf_counter(); r = mod.refine_terrain(hf, cams[k], crit, prev); t[key].append(time.perf_counter() - t0)
    o, n = np.median(t["old"]), np.median(t["new"])
    print(f"{name}: {len(frames)} flight frames, median old {1e3*o:.1f} ms, new {1e3*n:.1f} ms, ratio {o/n:.2f}x; worst ratio {max(t['old'])/max(t['new']):.2f}x")

"""What ``TerrainCriteria(split_view_edge=True)`` costs: mean triangles per frame (and refinement ms) on the
Table 1 flight (configs/terrain_table1.toml, every frame_step-th frame) with and without it, for the
criteria rows the report judges; and on the random scenes of monotone.py, the ratio with all criteria on.

    OMP_NUM_THREADS=1 .venv/bin/python reports/terrain/scripts/edge_cost.py [--scenes 300]
"""
import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from dataclasses import replace  # noqa: E402

from experiments._runinfo import load_config, repo_path  # noqa: E402
from experiments.terrain import (DEFAULTS, FLIGHT, check_flight, flight_cameras, load_terrains,  # noqa: E402
                                 named_criteria, run_flight)
from monotone import NAMES, scene  # noqa: E402
from optim._terrain import TerrainCriteria, refine_terrain  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", type=int, default=300)
    a = ap.parse_args()
    cfg = load_config(str(ROOT / "configs/terrain_table1.toml"), DEFAULTS)
    fl = check_flight(load_config(repo_path(cfg["flight"]), FLIGHT), cfg["flight"])
    xi = float(cfg["resolution"][0]) / (2.0 * fl["fov_deg"][0])
    print("| terrain | criteria | triangles / frame | with split_view_edge | ratio | ms median | with |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: |")
    for name, hf in load_terrains(cfg):
        cams = flight_cameras(hf, fl)
        for label, crit in named_criteria(xi).items():
            t0, s0 = run_flight(hf, cams, crit, fl["fps"], cfg["frame_step"])
            t1, s1 = run_flight(hf, cams, replace(crit, split_view_edge=True), fl["fps"], cfg["frame_step"])
            print(f"| {name} | {label} | {t0.mean():,.0f} | {t1.mean():,.0f} | {t1.mean() / t0.mean():.3f} | "
                  f"{1e3 * np.median(s0):.1f} | {1e3 * np.median(s1):.1f} |", flush=True)
    rng = np.random.default_rng(0)
    r = []
    for _ in range(a.scenes):
        hf, cam, prev, x = scene(rng)
        on = {k: True for k in NAMES}
        base = refine_terrain(hf, cam, TerrainCriteria(xi=x, **on), prev).triangles
        r.append(refine_terrain(hf, cam, TerrainCriteria(xi=x, split_view_edge=True, **on), prev).triangles / max(base, 1))
    r = np.array(r)
    print(f"\nmonotone.py's {a.scenes} random scenes, all criteria: triangles with / without split_view_edge: median "
          f"{np.median(r):.3f}, 90th percentile {np.percentile(r, 90):.2f}, largest {r.max():.0f} "
          f"(scenes where the default draws almost nothing inside a view whose edge crosses the terrain)")


if __name__ == "__main__":
    main()

"""Issue 10: today's imperceptible cut (with the neighbours' vertex normals scored) against the cut without
them (``neighbour_normals.cone_only_tree``) on the motion judge's orbits (``configs/accuracy_motion.toml``:
30 deg/s, frames judged as stills at 960 x 540): JOD and drawn triangles per frame.

    OMP_NUM_THREADS=1 PYOPENGL_PLATFORM=egl .venv/bin/python reports/accuracy/scripts/nb_orbit.py OUT.jsonl [meshes] [gazes] [every]
"""
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import optim  # noqa: E402
from neighbour_normals import cone_only_tree  # noqa: E402
from ring_imperceptible import judge_row  # noqa: E402
from experiments.accuracy import _Mesh, load_meshes  # noqa: E402
from experiments.accuracy_motion import DEFAULTS, orbit_views  # noqa: E402
from experiments.experiment import view_directions  # noqa: E402


def main():
    out = open(sys.argv[1], "a")
    names = sys.argv[2].split(",") if len(sys.argv) > 2 and sys.argv[2] else ["cow"]
    gazes = [float(g) for g in sys.argv[3].split(",")] if len(sys.argv) > 3 else [0.0]
    every = int(sys.argv[4]) if len(sys.argv) > 4 else 3
    cfg = dict(DEFAULTS)
    light = optim.Lighting()
    for name, v, f, c in load_meshes(dict(cfg, views=1)):
        if name not in names:
            continue
        mesh = _Mesh(name, v, f, c)
        trees = {"cone_only": cone_only_tree(v, f, c, light), "today": mesh.tree["relit"]}
        start = view_directions(1, int(cfg["seed"]), name)[0]
        for g in gazes:
            views, _ = orbit_views(v, start, g, int(cfg["frames"]), float(cfg["fps"]), float(cfg["orbit_deg_s"]), cfg)
            for k in range(0, len(views), every):
                judge_row(out, dict(mesh=name, gaze=g, frame=k), trees, mesh, views[k], cfg, light)


if __name__ == "__main__":
    main()

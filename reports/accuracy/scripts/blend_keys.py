"""Issue 10 experiment: do budget cuts gain from an order between the perceptual and the geometric keys?

Geometric keys (the projected fold error, pixels) are the rival that binds the relit gain target most
often (35 of 54 cells of reports/accuracy_facecull_hybrid). A budget cut only needs an order, so this
blends the two: ``blend{a}`` ranks folds by k_perc^a * k_geom^(1 - a) (a = 1: today's perceptual keys,
a = 0: geometric keys; both are monotone up the tree, so the product is too; a culled fold stays 0).
Budget keys only, on the relit default of plod simplify (the hybrid tree, region normals, face culling),
on the held-out cells (meshes the tests and the sweep do not use). JOD of each variant's cut at the drawn
count of today's perceptual cut.

    OMP_NUM_THREADS=1 PYOPENGL_PLATFORM=egl .venv/bin/python reports/accuracy/scripts/blend_keys.py OUT.jsonl [meshes] [a,...]
"""
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import optim  # noqa: E402
import experiments.accuracy as A  # noqa: E402
import pooled_priority as PP  # noqa: E402
from experiments.accuracy import DEFAULTS, _Mesh, plod_mesh  # noqa: E402
from experiments.experiment import procedural_mesh  # noqa: E402


def hybrid_mesh(name):
    """The held-out mesh with the hybrid tree (plod simplify's default with --light)."""
    v, f, c = procedural_mesh(name) if ":" in name else optim.load_mesh(ROOT.parent / "shared/data/meshes" / name)
    return _Mesh(name, v, f, c, method="hybrid")


def blend(kp, kg, a):
    """k_perc^a k_geom^(1 - a), 0 where either is 0, inf where either is inf."""
    kp, kg = np.asarray(kp, np.float64), np.asarray(kg, np.float64)
    with np.errstate(all="ignore"):
        k = kp ** a * kg ** (1.0 - a)
    k = np.where((kp == 0) | (kg == 0), 0.0, k)
    return np.where(np.isinf(kp) | np.isinf(kg), np.inf, k).astype(np.float32)


def main():
    PP.held_out_mesh = hybrid_mesh
    out = open(sys.argv[1], "a")
    names = sys.argv[2].split(",") if len(sys.argv) > 2 and sys.argv[2] else PP.HELD_OUT
    alphas = [float(x) for x in sys.argv[3].split(",")] if len(sys.argv) > 3 else [0.5, 0.75]
    cfg = dict(DEFAULTS, face_cull=True, normals="region", method="hybrid", size=list(PP.SIZE))
    A.DEFAULTS["normals"] = "region"
    for name, mesh, view, g, J in PP.held_out_cells(names, cfg):
        tree = mesh.tree["relit"]
        kp, kg = optim.score(tree, view), optim.score(tree, view, None, "geometric")
        variants = {f"blend{a:g}": blend(kp, kg, a) for a in alphas}
        PP.budget_rows(out, tree, view, cfg, J,
                       {v: (lambda t, k=k: plod_mesh(tree, k, view, cfg, t)[0]) for v, k in variants.items()},
                       mesh=name, gaze=g)


if __name__ == "__main__":
    main()

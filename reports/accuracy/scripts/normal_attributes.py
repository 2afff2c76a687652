"""Issue 10 experiment: meshoptimizer's levels with the vertex normals as attributes
(``simplifyWithAttributes``, weight ``w`` per normal component, beside the colours' weight 1) in the meshopt
and hybrid trees, against the same trees without. Held-out meshes and views of tree_choice.py (two random
views, gaze at the centre, relit with region normals, no culling, 960x540); each tree's perceptual cut at
the first tree's count.

    OMP_NUM_THREADS=1 PYOPENGL_PLATFORM=egl .venv/bin/python reports/accuracy/scripts/normal_attributes.py OUT.jsonl [meshes] [weights]
"""
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402

import optim  # noqa: E402
import optim._meshopt_tree as MT  # noqa: E402
from optim._tree import _vertex_normals  # noqa: E402
from pooled_priority import HELD_OUT, SIZE, held_out_mesh  # noqa: E402
from tree_choice import tree_rows  # noqa: E402
from experiments.accuracy import DEFAULTS  # noqa: E402

_ORIG = MT.meshopt_parents


def with_normals(w):
    """meshopt_parents with the unit vertex normals times ``w`` appended to the attributes."""
    def parents(v, f, colors=None, **kw):
        n = _vertex_normals(np.asarray(v, np.float64), np.asarray(f, np.int64))
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        attr = w * n if colors is None else np.hstack([colors, w * n])
        return _ORIG(v, f, attr, **kw)
    return parents


def build(mesh, method, w):
    MT.meshopt_parents = _ORIG if w is None else with_normals(w)
    try:
        return optim.build_tree(mesh.v, mesh.f, mesh.c, method=method)
    finally:
        MT.meshopt_parents = _ORIG


def main():
    out = open(sys.argv[1], "a")
    names = sys.argv[2].split(",") if len(sys.argv) > 2 and sys.argv[2] else HELD_OUT
    weights = [float(x) for x in sys.argv[3].split(",")] if len(sys.argv) > 3 else [0.5]
    cfg = dict(DEFAULTS, size=list(SIZE), normals="region")
    for name in names:
        mesh = held_out_mesh(name)
        trees = {"meshopt": mesh.tree["relit"]}
        for w in weights:
            trees[f"meshopt_n{w:g}"] = build(mesh, "meshopt", w)
        trees["hybrid"] = build(mesh, "hybrid", None)
        for w in weights:
            trees[f"hybrid_n{w:g}"] = build(mesh, "hybrid", w)
        tree_rows(out, name, mesh, trees, cfg, lambda tn, tree, cut, m, b: {})


if __name__ == "__main__":
    main()

"""Issue 10 experiment: relit fold contrast from the normal *detail* a fold loses, for budget keys only.

Today a fold's relit contrast covers the whole normal cone of its region, so a smooth curved region
(whose shading a coarse mesh with interpolated normals reproduces) counts as much as a bumpy one, and the
perceptual order spends a budget much as size keys do. Here a node's tilt is the RMS residual of its
vertex normals about the best affine field ``n ~ A p + b`` over its supported vertices (what linear
interpolation over coarser triangles cannot show), inflated by ``W / (W - 4)`` for the fit's degrees of
freedom (nodes of at most 4 vertices keep today's contrast), times a scale, capped by the cone. Moments
summed up the tree (O(N)). Not a bound: the imperceptible cut keeps today's columns.

    OMP_NUM_THREADS=1 .venv/bin/python reports/accuracy/scripts/detail_contrast.py OUT.jsonl [meshes] [scales]
"""
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402

import optim  # noqa: E402
from optim._mesh import face_normals  # noqa: E402
from deviation_contrast import tilt_columns  # noqa: E402
from optim._relight import _tree_nodes, light_key, normal_cones, relit_columns  # noqa: E402
from optim._tree import _vertex_normals  # noqa: E402
from pooled_priority import HELD_OUT, SIZE, budget_rows, held_out_cells  # noqa: E402
from experiments.accuracy import DEFAULTS, plod_mesh  # noqa: E402


def detail_rms(tree):
    """(N,) RMS residual (rad, about) of unit vertex normals about each node's affine normal field, and
    the node's vertex count."""
    v = np.asarray(tree.vertices, np.float64)
    v = (v - v.mean(0)) / max(np.abs(v - v.mean(0)).max(), 1e-300)
    f = np.asarray(tree.faces, np.int64)
    vn = _vertex_normals(v, f, face_normals(v, f))
    vn = vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)
    mom = np.concatenate([np.ones((len(v), 1)), v, vn, (v[:, :, None] * v[:, None, :]).reshape(-1, 9),
                          (v[:, :, None] * vn[:, None, :]).reshape(-1, 9), (vn * vn).sum(1, keepdims=True)], 1)
    m = tree.levels.reduce_up(_tree_nodes(tree, mom), np.add)
    w = np.maximum(m[:, 0], 1e-300)
    mp, mn = m[:, 1:4] / w[:, None], m[:, 4:7] / w[:, None]
    cpp = m[:, 7:16].reshape(-1, 3, 3) / w[:, None, None] - mp[:, :, None] * mp[:, None, :]
    cpn = m[:, 16:25].reshape(-1, 3, 3) / w[:, None, None] - mp[:, :, None] * mn[:, None, :]
    var = m[:, 25] / w - (mn * mn).sum(1)
    tr = np.trace(cpp, axis1=1, axis2=2)
    reg = cpp + (1e-9 * tr + 1e-18)[:, None, None] * np.eye(3)
    x = np.linalg.solve(reg, cpn)  # (N, 3, 3): A^T
    expl = np.einsum("nij,nij->n", cpn, x)
    res = np.maximum(var - expl, 0.0)
    return np.sqrt(res), m[:, 0]


def detail_columns(tree, light, scale):
    base = relit_columns(tree, light)
    axis, half = normal_cones(tree)
    rms, count = detail_rms(tree)
    infl = count / np.maximum(count - 4, 1)
    tilt = np.where(count > 4, np.minimum(scale * np.nan_to_num(rms) * np.sqrt(infl), half), half).astype(float)
    return tilt_columns(tree, light, base, axis, tilt)


def main():
    out = open(sys.argv[1], "a")
    names = sys.argv[2].split(",") if len(sys.argv) > 2 and sys.argv[2] else HELD_OUT
    scales = tuple(float(x) for x in sys.argv[3].split(",")) if len(sys.argv) > 3 else (1.0, 2.0, 4.0)
    cfg = dict(DEFAULTS, face_cull=True, size=list(SIZE))
    light = optim.Lighting()
    trees = {}
    for name, mesh, view, g, J in held_out_cells(names, cfg):
        if name not in trees:
            trees = {name: {}}
            for s in scales:
                t = optim.build_tree(mesh.v, mesh.f, mesh.c)
                t._derived[f"relight.columns.{light_key(light)}"] = detail_columns(t, light, s)
                trees[name][f"detail{s:g}"] = t
        budget_rows(out, mesh.tree["relit"], view, cfg, J,
                    {kn: (lambda n, tr=tr: plod_mesh(tr, optim.score(tr, view), view, cfg, n)[0])
                     for kn, tr in trees[name].items()}, mesh=name, gaze=g)

if __name__ == "__main__":
    main()

"""Issue 10 experiment: choose the tree per mesh by a view-independent surface error, and see whether the
judge agrees. For each held-out mesh, the meshopt (default) and qem trees; their perceptual cuts on two
random views (gaze at the centre, relit with region normals, no culling; budgets 3 / 8 / 20 %) are judged
beside meshoptimizer and fast-simplification at the default tree's count. The candidate criterion, per tree
and budget: the error of its view-independent geometric-key cut, the mean over input vertices of the
squared distance to the cut's surface plus the mean of (1 - cos) between each input vertex normal and the
normal of the nearest cut face (libigl's point-mesh distance), both at the budget.

    OMP_NUM_THREADS=1 PYOPENGL_PLATFORM=egl .venv/bin/python reports/accuracy/scripts/tree_choice.py OUT.jsonl [meshes]
"""
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402

import optim  # noqa: E402
from optim._tree import _vertex_normals  # noqa: E402
from pooled_priority import HELD_OUT, SIZE, emit, held_out_mesh, judge_fn  # noqa: E402
from experiments.accuracy import DEFAULTS, _view  # noqa: E402
from experiments.experiment import view_directions  # noqa: E402


def surface_error(v, f, vn, cut_mesh):
    import igl

    cv, cf = np.asarray(cut_mesh[0], np.float64), np.asarray(cut_mesh[1], np.int64)
    d2, idx, _ = igl.point_mesh_squared_distance(v, cv, cf)
    fn = np.cross(cv[cf[:, 1]] - cv[cf[:, 0]], cv[cf[:, 2]] - cv[cf[:, 0]])
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
    diag = np.linalg.norm(v.max(0) - v.min(0))
    return float(d2.mean() / diag ** 2), float((1 - np.einsum("ij,ij->i", vn, fn[idx])).mean())


def main():
    out = open(sys.argv[1], "a")
    names = sys.argv[2].split(",") if len(sys.argv) > 2 and sys.argv[2] else HELD_OUT
    cfg = dict(DEFAULTS, size=list(SIZE), normals="region")
    for name in names:
        mesh = held_out_mesh(name)
        v, f = np.asarray(mesh.v, np.float64), np.asarray(mesh.f, np.int64)
        vn = _vertex_normals(v, f)
        vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)
        trees = {"meshopt": mesh.tree["relit"], "qem": optim.build_tree(mesh.v, mesh.f, mesh.c, method="qem")}
        crit = {}
        for tn, tree in trees.items():
            frame = optim.View.framing(v)
            gk = optim.score(tree, frame, None, "geometric")
            for b in (0.03, 0.08, 0.2):
                cut = optim.budget_cut(tree, gk, int(b * tree.n_triangles), monotone="trust")
                crit[tn, b] = surface_error(v, f, vn, optim.extract(tree, cut))
        tree_rows(out, name, mesh, trees, cfg, lambda tn, tree, cut, m, b: {
            tn + "_tris": len(m[1]), tn + "_d2": crit[tn, b][0], tn + "_ncos": crit[tn, b][1]})


def tree_rows(out, name, mesh, trees, cfg, extra):
    """Emit one row per view (two random views, gaze at the centre, relit) and budget (3, 8, 20 %): each
    tree's perceptual cut carrying region normals, judged, the first tree's drawn count for the others and
    the peers; ``extra(tree name, tree, cut, mesh, budget)`` -> more fields of the row."""
    for vi, d in enumerate(view_directions(2, 55, name)):
        view = _view(mesh, d, 0.0, "relit", cfg, True)
        J = judge_fn(mesh, view, "relit")
        for b in (0.03, 0.08, 0.2):
            t0 = time.perf_counter()
            row = dict(mesh=name, view=vi, budget=b)
            target = None
            for tn, tree in trees.items():
                n = max(int(b * tree.n_triangles), 1) if target is None else target
                cut = optim.budget_cut(tree, optim.score(tree, view), n, monotone="trust")
                m = optim.extract(tree, cut, "region")
                target = target or len(m[1])
                row[tn] = J(m)
                row.update(extra(tn, tree, cut, m, b))
            for peer in ("meshoptimizer", "fast_simplification"):
                row[peer] = J(mesh.peer(peer, "relit", target))
            row["s"] = round(time.perf_counter() - t0, 1)
            emit(out, row)


if __name__ == "__main__":
    main()

"""Issue 10 experiment: region normals weighted by what the view sees. A cut vertex's carried normal is the
area-weighted mean normal of its node's input surface (``optim.region_normals``); a node across a silhouette
then averages its front and back faces and is shaded as if seen edge-on. Here each input vertex's
area-weighted normal is also weighted by max(0, cos) of its angle to the eye (projected area, no occlusion)
before the sum; a node with nothing facing the eye keeps its region normal. Same cells as tree_choice.py
(held-out meshes, two random views, gaze at the centre, relit, no culling, budgets 3 / 8 / 20 %), the
hybrid tree (the relit default): its perceptual cut with region normals, with view-weighted normals, and
the peers at that count.

    OMP_NUM_THREADS=1 PYOPENGL_PLATFORM=egl .venv/bin/python reports/accuracy/scripts/view_normals.py OUT.jsonl [meshes]
"""
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402

import optim  # noqa: E402
from optim._cut import _extract_parts, _unfolded_mask  # noqa: E402
from optim._mesh import face_normals  # noqa: E402
from optim._normals import region_normals  # noqa: E402
from optim._tree import _vertex_normals  # noqa: E402
from pooled_priority import HELD_OUT, SIZE, emit, held_out_mesh, judge_fn  # noqa: E402
from experiments.accuracy import DEFAULTS, _view  # noqa: E402
from experiments.experiment import view_directions  # noqa: E402


def view_weighted(tree, eye):
    """(N, 3) unit normals per node: sum over its leaves of max(0, cos(normal, to eye)) x area-weighted
    normal; the region normal where that sum is under 1e-3 of the region's."""
    v = np.asarray(tree.local_vertices, np.float64)
    f = np.asarray(tree.faces)
    lv = np.asarray(tree.leaf_vertex)
    vn = _vertex_normals(v, f, face_normals(v, f))[lv]
    p = v[lv]
    d = np.asarray(eye, np.float64) - np.asarray(tree.origin, np.float64) - p
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    ln = np.linalg.norm(vn, axis=1)
    cos = np.einsum("ij,ij->i", vn, d) / np.maximum(ln, 1e-300)
    w = vn * np.maximum(cos, 0.0)[:, None]
    lo, hi = np.asarray(tree.leaf_lo, np.intp), np.asarray(tree.leaf_hi, np.intp)
    pre = np.zeros((len(w) + 1, 3))
    np.cumsum(w, axis=0, out=pre[1:])
    tot = np.zeros(len(w) + 1)
    np.cumsum(ln, out=tot[1:])
    s = pre[hi] - pre[lo]
    length = np.linalg.norm(s, axis=1)
    ok = length > 1e-3 * (tot[hi] - tot[lo])
    out = region_normals(tree).astype(np.float64)
    out[ok] = s[ok] / length[ok, None]
    return out


def main():
    out = open(sys.argv[1], "a")
    names = sys.argv[2].split(",") if len(sys.argv) > 2 and sys.argv[2] else HELD_OUT
    cfg = dict(DEFAULTS, size=list(SIZE), normals="region")
    for name in names:
        mesh = held_out_mesh(name)
        tree = optim.build_tree(mesh.v, mesh.f, mesh.c, method="hybrid")
        for vi, d in enumerate(view_directions(2, 55, name)):
            view = _view(mesh, d, 0.0, "relit", cfg, True)
            J = judge_fn(mesh, view, "relit")
            vw = view_weighted(tree, view.eye)
            for b in (0.03, 0.08, 0.2):
                t0 = time.perf_counter()
                cut = optim.budget_cut(tree, optim.score(tree, view), max(int(b * tree.n_triangles), 1),
                                       monotone="trust")
                m = optim.extract(tree, cut, "region")
                nodes = _extract_parts(tree, _unfolded_mask(tree, cut), False)[4]
                row = dict(mesh=name, view=vi, budget=b, tris=len(m[1]), region=J(m),
                           view_weighted=J((m[0], m[1], m[2], vw[np.asarray(nodes)])))
                for peer in ("meshoptimizer", "fast_simplification"):
                    row[peer] = J(mesh.peer(peer, "relit", len(m[1])))
                row["s"] = round(time.perf_counter() - t0, 1)
                emit(out, row)


if __name__ == "__main__":
    main()

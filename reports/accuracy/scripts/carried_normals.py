"""Issue 10 experiment: a cut that carries its region's normals, instead of normals recomputed from its faces.

A renderer shades a simplified mesh from the vertex normals it carries. Today a cut's output has none, so
a renderer (and the judge) recomputes them from the coarse faces, and the relit image of a fold shows the
facets of its proxy's triangles. Here each output vertex carries the unit area-weighted normal of the
input surface its node stands for (its supported vertices' area-weighted normals summed: the region's
mean normal, a prefix sum over the depth-first leaf order). meshoptimizer keeps input vertices, so its
result can carry their input normals as an engine would (`mo_carry`); fast-simplification moves its
vertices and gets recomputed normals.

    OMP_NUM_THREADS=1 PYOPENGL_PLATFORM=egl .venv/bin/python reports/accuracy/scripts/carried_normals.py OUT.jsonl [meshes] [cull:0|1]
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
from optim._facecull import drop_back_faces  # noqa: E402
from optim._mesh import face_normals  # noqa: E402
from optim._tree import _vertex_normals  # noqa: E402
from pooled_priority import HELD_OUT, SIZE, emit, held_out_cells  # noqa: E402
from experiments.accuracy import DEFAULTS, PEERS  # noqa: E402
from experiments.peers import compact, meshopt_simplify  # noqa: E402


def _unit(n):
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def region_normal_sums(tree):
    """(V + 1, 3) prefix sums, over depth-first leaf positions, of the input's area-weighted vertex normals."""
    v = np.asarray(tree.vertices, np.float64)
    f = np.asarray(tree.faces, np.int64)
    vn = _vertex_normals(v, f, face_normals(v, f))
    out = np.zeros((len(v) + 1, 3))
    np.cumsum(vn[np.asarray(tree.leaf_vertex)], axis=0, out=out[1:])
    return out


def carried(tree, unf, sums):
    """``(vertices, faces, colors, normals)``: the cut ``unf``'s mesh with each vertex carrying its region's
    mean normal."""
    v, f, c, keep = _extract_parts(tree, unf)[:4]
    src = np.empty(len(v), np.int64)  # an input vertex each output vertex stands for
    src[f.ravel()] = np.asarray(tree.faces)[keep].ravel()
    pos = np.empty(len(tree.vertices), np.int64)
    pos[np.asarray(tree.leaf_vertex)] = np.arange(len(tree.vertices))
    parent = np.asarray(tree.parent)
    folded = ~unf
    bnd = np.flatnonzero(folded & np.concatenate([[True], unf[parent[1:]]]))
    lo = np.asarray(tree.leaf_lo)[bnd]
    order = np.argsort(lo)
    node = bnd[order][np.searchsorted(lo[order], pos[src], "right") - 1]
    n = sums[np.asarray(tree.leaf_hi)[node]] - sums[np.asarray(tree.leaf_lo)[node]]
    return v, f, c, _unit(n)


def plod_variants(tree, keys, view, cull, target, sums):
    """(today's mesh, carried mesh) of the budget cut of ``keys`` to ``target`` (drawn triangles with
    ``cull``)."""
    if cull:
        vc = optim.visible_budget_cut(tree, keys, target, view, monotone="trust")
        unf, today = _unfolded_mask(tree, vc.cut), vc.mesh
    else:
        cut = optim.budget_cut(tree, keys, target, monotone="trust")
        unf = _unfolded_mask(tree, cut)
        today = optim.extract(tree, cut)
    v, f, c, n = carried(tree, unf, sums)
    if cull:
        keepf = drop_back_faces((v, f, c), view)[1]
        f = keepf
    return today, (v, f, c, n)


def main():
    out = open(sys.argv[1], "a")
    names = sys.argv[2].split(",") if len(sys.argv) > 2 and sys.argv[2] else HELD_OUT
    cull = bool(int(sys.argv[3])) if len(sys.argv) > 3 else False
    cfg = dict(DEFAULTS, face_cull=cull, size=list(SIZE))
    sums_of = {}
    for name, mesh, view, g, J in held_out_cells(names, cfg):
        tree = mesh.tree["relit"]
        if name not in sums_of:
            sums_of = {name: region_normal_sums(tree)}
            vn = _unit(_vertex_normals(np.asarray(mesh.v, np.float64), np.asarray(mesh.f, np.int64)))
        sums = sums_of[name]
        for b in (0.03, 0.08, 0.2):
            t0 = time.perf_counter()
            pk = optim.score(tree, view)
            today, car = plod_variants(tree, pk, view, cull, max(int(b * tree.n_triangles), 1), sums)
            target = len(today[1])
            row = dict(mesh=name, gaze=g, cull=cull, budget=b, tris=target, perceptual=J(today),
                       perc_carry=J(car), carry_tris=len(car[1]))
            for metric in ("size", "geometric"):
                k = optim.score(tree, view, None, metric)
                t, c = plod_variants(tree, k, view, cull, target, sums)
                row[metric], row[metric + "_carry"] = J(t), J(c)
            for peer in PEERS:
                row[peer] = J(mesh.peer(peer, "relit", target))
            mf = meshopt_simplify(mesh.v, mesh.f, target, mesh.c)
            used = np.unique(mf.ravel())
            row["mo_carry"] = J((*compact(mesh.v, mf, mesh.c), vn[used]))
            row["s"] = round(time.perf_counter() - t0, 1)
            emit(out, row)


if __name__ == "__main__":
    main()

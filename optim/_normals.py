"""The vertex normals a cut's mesh carries for a renderer that relights it.

A renderer shades a mesh from its vertex normals, interpolated per pixel. Two choices for a cut:

* ``"faces"``: the unit area-weighted normals of the cut's own faces, what a renderer computes for a mesh
  that carries none. A fold's proxy triangles then show their facets, and every vertex around a fold
  changes its normal with the faces the fold changes (the neighbours' term of the relit contrast).
* ``"region"``: each vertex carries the unit area-weighted mean normal of the input surface its node
  stands for (the sum of its supported vertices' area-weighted normals; a leaf carries the input vertex's
  own normal, exactly what the input mesh is shaded with). The mean of unit vectors inside a cone lies
  inside the cone, so a carried normal stays in the node's normal cone (the relit contrast's bound,
  :mod:`optim._relight`), and vertices around a fold keep theirs. In the spirit of appearance-preserving
  simplification [Coh98], without a texture: one normal per vertex.

Measured under the judge in reports/accuracy/what_we_tried.md ("Cuts that carry their region's normals").
Hand-written: a prefix sum over the tree's depth-first leaf order; no library here knows the tree.
"""

from __future__ import annotations

import numpy as np

from pmetric import PlodError

__all__ = ["NORMALS", "region_normals", "cut_normals"]

NORMALS = ("region", "faces")

# A region whose area-weighted normals cancel to under this share of their total length (a thin sheet
# seen from both sides, a closed surface's root) has no mean direction: its vertex takes the faces' normal.
_CANCEL = 1e-3


def check_normals(normals, who: str):
    """``normals`` itself if it is None or one of :data:`NORMALS`; PlodError naming ``who`` otherwise."""
    if normals is not None and (not isinstance(normals, str) or normals not in NORMALS):
        raise PlodError(f"{who}: normals must be None, 'region' or 'faces', got {normals!r}")
    return normals


def region_normals(tree) -> np.ndarray:
    """(N, 3) float32 unit normal of each node's region: the area-weighted vertex normals of the input
    vertices it supports, summed and normalised (for a leaf, its input vertex's unit normal); rows of 0
    where they cancel (their sum under 1e-3 of their total length). Cached on the tree."""
    return tree.derived("normals.region", lambda: _build_region_normals(tree))


def _build_region_normals(tree) -> np.ndarray:
    from ._mesh import face_normals
    from ._tree import _vertex_normals

    v = np.asarray(tree.local_vertices, np.float64)
    f = np.asarray(tree.faces)
    vn = _vertex_normals(v, f, face_normals(v, f))[np.asarray(tree.leaf_vertex)]  # depth-first order
    lo, hi = np.asarray(tree.leaf_lo, np.intp), np.asarray(tree.leaf_hi, np.intp)
    pre = np.zeros((len(vn) + 1, 3))
    np.cumsum(vn, axis=0, out=pre[1:])
    total = np.zeros(len(vn) + 1)
    np.cumsum(np.sqrt(np.einsum("ij,ij->i", vn, vn)), out=total[1:])
    s = pre[hi] - pre[lo]
    length = np.sqrt(np.einsum("ij,ij->i", s, s))
    ok = length > _CANCEL * (total[hi] - total[lo])
    out = np.zeros_like(s)
    np.divide(s, length[:, None], out=out, where=ok[:, None])
    return out.astype(np.float32)


def face_vertex_normals(vertices, faces, fn=None) -> np.ndarray:
    """(V, 3) float64 unit area-weighted vertex normals of a mesh from its own faces (``fn``: the faces'
    unnormalised normals (T, 3), when already made). Where a vertex's face normals cancel (a sheet drawn
    from both sides: a coarse cut of a closed surface may keep a triangle in both windings) the vertex
    takes the unit normal of its largest face instead of the zero vector the sum gives; 0 only for a
    vertex on no face of nonzero area."""
    from ._mesh import face_normals
    from ._normal_cube import _unit
    from ._tree import _vertex_normals

    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces)
    if fn is None:
        fn = face_normals(v, f)
    out = _unit(_vertex_normals(v, f, fn))
    zero = ~out.any(axis=1)
    if zero.any() and len(f):
        area = np.einsum("ij,ij->i", fn, fn)
        touch = np.flatnonzero(zero[f].any(axis=1) & (area > 0))  # the few faces at such vertices
        if touch.size:
            order = touch[np.argsort(area[touch], kind="stable")]  # ascending: the largest face written last
            best = np.full(len(v), -1)
            for t in order:  # ascending area: each such vertex ends with its largest face
                for c in f[t]:
                    if zero[c]:
                        best[c] = t
            have = np.flatnonzero(best >= 0)
            out[have] = _unit(fn[best[have]])
    return out


def cut_normals(tree, vertices, faces, nodes, normals: str, rows=None) -> np.ndarray:
    """(V', 3) float64 unit vertex normals of a cut's mesh ``(vertices, faces)`` whose vertex ``i`` is
    drawn for node ``nodes[i]``: ``"region"`` (:func:`region_normals`, the faces' normal where the region
    has none) or ``"faces"`` (area-weighted over ``faces``; 0 for a vertex no face uses). ``rows``: the
    nodes' rows of :func:`region_normals` when already gathered."""
    if normals is None or check_normals(normals, "cut_normals") is None:
        raise PlodError(f"cut_normals: normals must be 'region' or 'faces', got {normals!r}")
    v = np.asarray(vertices, np.float64)
    if normals == "faces":
        return face_vertex_normals(v, faces)
    from ._cut import _take_rows

    if rows is None:  # a caller's nodes (extract passes the rows it gathered): checked
        nodes = np.asarray(nodes)
        if nodes.shape != (len(v),) or not np.issubdtype(nodes.dtype, np.integer) or \
                (nodes.size and (nodes.min() < 0 or nodes.max() >= tree.n_nodes)):
            raise PlodError(f"cut_normals: nodes must be ({len(v)},) node indices in [0, {tree.n_nodes}), one per vertex")
        rows = _take_rows(region_normals(tree), nodes)  # float32 records: one gather
    out = rows.astype(np.float64)
    none = ~rows.view(np.uint32).any(axis=1)  # a zero row: its 3 words are 0 (-0.0 cannot arise from the division)
    if none.any():
        out[none] = face_vertex_normals(v, faces)[none]
    return out

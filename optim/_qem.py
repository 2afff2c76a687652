"""Quadric-error vertex hierarchy ([GH97] edge collapses; [LHNW00 §6.3]).

Stages:

1. ``collapse``: fast-simplification (Fast-Quadric-Mesh-Simplification) decimates the mesh towards
   zero triangles and reports its collapse sequence: row ``[i0, i1]`` merges vertex ``i1`` into ``i0``.
   Its order is set by an absolute threshold schedule (iteration i collapses edges of error below
   ``1e-9 (i + 3)^agg``, squared object units, for at most 100 iterations), so it depends on the mesh's
   units; ``diagonal`` scales a copy of the mesh to that bounding-box diagonal first (the order is then
   the same in any units; reports/accuracy/hierarchy.md measures it).
2. ``binary tree``: collapse k creates node ``V + k`` whose children are the current nodes of ``i0``
   and ``i1`` (vectorised: the current node of a vertex is its latest collapse as ``i0``).
3. ``top``: what cannot be collapsed (separate components, stuck vertices) is joined by a tight octree
   over the remaining roots' centroids (``optim._octree``).
4. ``proxies``: node quadrics are sums of the vertices' area-weighted plane quadrics; a node's proxy
   minimises its quadric, regularised towards the centroid (``quadric_optimal``, ``proxy="optimal"``),
   or is the supported input vertex of least quadric error (``quadric_vertex``, ``proxy="vertex"``:
   what an edge-collapse simplifier that keeps input vertices, such as meshoptimizer's, would place).

Quadric units: object units squared times area (a sum of area-weighted squared plane distances).
"""

from __future__ import annotations

import numpy as np

__all__ = ["qem_parents", "vertex_quadrics", "quadric_optimal", "quadric_error", "quadric_vertex", "PROXIES"]

#: proxy placements of :func:`optim.build_tree` (``proxy=``)
PROXIES = ("optimal", "vertex")


def _plane_quadrics(n: np.ndarray, d: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(K, 10) quadrics ``w (n.x + d)^2`` of planes with unit normals n (K, 3), offsets d (K,), weights w (K,)."""
    return np.stack(
        [n[:, 0] * n[:, 0], n[:, 0] * n[:, 1], n[:, 0] * n[:, 2], n[:, 1] * n[:, 1], n[:, 1] * n[:, 2],
         n[:, 2] * n[:, 2], n[:, 0] * d, n[:, 1] * d, n[:, 2] * d, d * d], axis=1
    ) * w[:, None]


def vertex_quadrics(v: np.ndarray, f: np.ndarray, fn: np.ndarray | None = None, *, weights: str = "area",
                    boundary_weight: float = 0.0) -> np.ndarray:
    """Plane quadrics (V, 10): A (3x3 symmetric: a11 a12 a13 a22 a23 a33), b (3), c.

    Q(x) = x^T A x + 2 b.x + c = sum over incident triangles of w * (n.x + d)^2, with ``w`` the
    triangle's area (``weights="area"``, the default) or 1 (``"uniform"``, as fast-simplification).
    ``boundary_weight`` > 0 adds, for every boundary edge (an edge of one triangle), the quadric of the
    plane through the edge perpendicular to its triangle, weighted ``boundary_weight * |edge|^2``, to
    both endpoints ([GH97]: it keeps open borders in place; area units, as the area weights).
    """
    from ._mesh import corner_sum, face_normals

    if fn is None:
        fn = face_normals(v, f)
    dbl = np.linalg.norm(fn, axis=1)
    n = np.divide(fn, dbl[:, None], out=np.zeros_like(fn), where=dbl[:, None] > 0)
    if weights not in ("area", "uniform"):
        from pmetric import PlodError

        raise PlodError(f"vertex_quadrics: weights must be 'area' or 'uniform', got {weights!r}")
    w = 0.5 * dbl if weights == "area" else np.ones(f.shape[0])
    d = -np.einsum("ij,ij->i", n, v.take(f[:, 0], axis=0))
    out = corner_sum(f, _plane_quadrics(n, d, w), v.shape[0])
    if boundary_weight > 0:
        tri, a, b = _boundary_edges(f)
        if tri.size:
            e = v[b] - v[a]
            m = np.cross(e, n[tri])
            mn = np.linalg.norm(m, axis=1)
            m = np.divide(m, mn[:, None], out=np.zeros_like(m), where=mn[:, None] > 0)
            qb = _plane_quadrics(m, -np.einsum("ij,ij->i", m, v[a]), boundary_weight * np.einsum("ij,ij->i", e, e))
            for k in range(10):
                out[:, k] += np.bincount(np.concatenate([a, b]), weights=np.tile(qb[:, k], 2), minlength=v.shape[0])
    return out


def _boundary_edges(f: np.ndarray):
    """Boundary edges (used by exactly one triangle): ``(triangle, corner a, corner b)`` (E,) each."""
    a = f.ravel()
    b = f[:, [1, 2, 0]].ravel()
    lo, hi = np.minimum(a, b).astype(np.int64), np.maximum(a, b).astype(np.int64)
    code = lo * (int(f.max()) + 1 if f.size else 1) + hi
    _, inv, cnt = np.unique(code, return_inverse=True, return_counts=True)
    one = np.flatnonzero(cnt[inv] == 1)
    return one // 3, a[one], b[one]


def quadric_optimal(q: np.ndarray, centroid: np.ndarray, reg: float = 1e-3) -> np.ndarray:
    """Points (N, 3) minimising ``Q(x) + lam |x - centroid|^2`` with ``lam = reg * trace(A) / 3``.

    The small regulariser makes flat and ridge regions (singular A) well posed: there the minimiser
    is the centroid projected onto the planes. Falls back to the centroid where A vanishes.
    """
    tr = q[:, 0] + q[:, 3] + q[:, 5]
    lam = reg * tr / 3.0
    # symmetric 3x3 system (A + lam I) x = lam m - b, solved by the adjugate (vectorised Cramer)
    a11, a12, a13 = q[:, 0] + lam, q[:, 1], q[:, 2]
    a22, a23, a33 = q[:, 3] + lam, q[:, 4], q[:, 5] + lam
    r = lam[:, None] * centroid - q[:, 6:9]
    c11 = a22 * a33 - a23 * a23
    c12 = a13 * a23 - a12 * a33
    c13 = a12 * a23 - a13 * a22
    c22 = a11 * a33 - a13 * a13
    c23 = a12 * a13 - a11 * a23
    c33 = a11 * a22 - a12 * a12
    det = a11 * c11 + a12 * c12 + a13 * c13
    ok = (tr > 0) & (np.abs(det) > 1e-12 * np.maximum(tr / 3.0, 1e-300) ** 3)
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    out = centroid.copy()
    x = np.stack([c11 * r[:, 0] + c12 * r[:, 1] + c13 * r[:, 2],
                  c12 * r[:, 0] + c22 * r[:, 1] + c23 * r[:, 2],
                  c13 * r[:, 0] + c23 * r[:, 1] + c33 * r[:, 2]], axis=1) * inv[:, None]
    out[ok] = x[ok]
    bad = ~np.all(np.isfinite(out), axis=1)
    out[bad] = centroid[bad]
    return out


def quadric_error(q: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Q(x) (K,) of quadrics q (K, 10) at points x (K, 3)."""
    x0, x1, x2 = x[:, 0], x[:, 1], x[:, 2]
    return (q[:, 0] * x0 * x0 + q[:, 3] * x1 * x1 + q[:, 5] * x2 * x2
            + 2.0 * (q[:, 1] * x0 * x1 + q[:, 2] * x0 * x2 + q[:, 4] * x1 * x2)
            + 2.0 * (q[:, 6] * x0 + q[:, 7] * x1 + q[:, 8] * x2) + q[:, 9])


def quadric_vertex(q: np.ndarray, points: np.ndarray, lo: np.ndarray, size: np.ndarray) -> np.ndarray:
    """For K nodes, the index into ``points`` of the candidate of least quadric error.

    Node k has quadric ``q[k]`` (10,) and candidates ``points[lo[k] : lo[k] + size[k]]`` (each
    ``size[k] >= 1``; ranges of one call should not overlap, as the supports of one tree level do not,
    to keep the work O(len(points))). Errors are evaluated about the candidates' mean
    (``Q(m + y) = y^T A y + 2 (A m + b).y + Q(m)``, dropping the constant ``Q(m)``), which keeps the
    comparison exact to rounding of the small terms where plain ``Q(x)`` would cancel; ties go to the
    first candidate. Returns (K,) intp.
    """
    size = size.astype(np.intp, copy=False)
    off = np.concatenate([[0], np.cumsum(size)[:-1]]).astype(np.intp)
    idx = np.repeat(lo.astype(np.intp) - off, size) + np.arange(int(size.sum()), dtype=np.intp)
    pts = points.take(idx, axis=0)
    mean = np.add.reduceat(pts, off, axis=0) / size[:, None]
    y = pts - np.repeat(mean, size, axis=0)
    A = q[:, :6]
    g = np.stack([A[:, 0] * mean[:, 0] + A[:, 1] * mean[:, 1] + A[:, 2] * mean[:, 2],
                  A[:, 1] * mean[:, 0] + A[:, 3] * mean[:, 1] + A[:, 4] * mean[:, 2],
                  A[:, 2] * mean[:, 0] + A[:, 4] * mean[:, 1] + A[:, 5] * mean[:, 2]], axis=1) + q[:, 6:9]
    qs = np.concatenate([A, g, np.zeros((q.shape[0], 1))], axis=1)  # the shifted quadric, without Q(m)
    err = quadric_error(np.repeat(qs, size, axis=0), y)
    best = np.minimum.reduceat(err, off)
    pos = np.where(err <= np.repeat(best, size), np.arange(err.size), err.size)
    return idx.take(np.minimum.reduceat(pos, off))


def qem_parents(v: np.ndarray, f: np.ndarray, aggressiveness: float = 7.0, diagonal: float | None = None) -> np.ndarray:
    """Binary edge-collapse hierarchy over the vertices, topped by a tight octree.

    Args:
        v: (V, 3) float64 vertices; f: (T, 3) int32 faces (validated).
        aggressiveness: fast-simplification's ``agg`` (higher = faster, rougher ordering).
        diagonal: None (the mesh as given) or the bounding-box diagonal, in the units of
            fast-simplification's error thresholds, that the collapse order is computed at.

    Returns:
        parent (V + M,) int64: leaves 0..V-1 are the vertices, one root (-1).
    """
    V = v.shape[0]
    col = qem_collapses(v, f, aggressiveness, diagonal)
    C = col.shape[0]
    parent, _ = _binary_nodes(col, V)
    roots = np.flatnonzero(parent < 0)
    if roots.size == 1:
        return parent
    # top: tight octree over the remaining roots (centroids of their supported vertices)
    from ._octree import octree_parents

    leaf_root = _root_of(parent, V)
    cnt = np.bincount(leaf_root, minlength=V + C)[roots].astype(np.float64)
    cen = np.stack([np.bincount(leaf_root, weights=v[:, a], minlength=V + C)[roots] for a in range(3)], 1)
    cen /= cnt[:, None]
    top, _ = octree_parents(cen)
    R = roots.size
    M = top.size - R
    out = np.concatenate([parent, np.full(M, -1, dtype=np.int64)])
    # top nodes 0..R-1 are the roots; R.. are new internal nodes at V + C + (j - R)
    remap = np.concatenate([roots, V + C + np.arange(M)])
    has = top >= 0
    out[remap[has]] = remap[top[has]]
    return out


def qem_collapses(v: np.ndarray, f: np.ndarray, aggressiveness: float = 7.0, diagonal: float | None = None) -> np.ndarray:
    """fast-simplification's full collapse sequence ``(C, 2)`` int64: collapse ``k`` merges vertex
    ``[k, 1]`` into ``[k, 0]`` (input numbering), in order; the mesh scaled to ``diagonal`` first as in
    :func:`qem_parents`."""
    import fast_simplification

    V = v.shape[0]
    vs = np.asarray(v, dtype=np.float64)
    if diagonal is not None and V:
        lo = vs.min(0)
        ext = float(np.linalg.norm(vs.max(0) - lo))
        vs = (vs - lo) * (float(diagonal) / ext) if ext > 0 else vs
    _, _, col = fast_simplification.simplify(
        np.ascontiguousarray(vs, dtype=np.float64), np.ascontiguousarray(f, dtype=np.int32),
        target_count=0, agg=float(aggressiveness), return_collapses=True,
    )
    col = np.asarray(col, dtype=np.int64).reshape(-1, 2)
    if len(col) and (col.min() < 0 or col.max() >= V or np.bincount(col[:, 1], minlength=V).max() > 1):
        raise RuntimeError("fast_simplification returned an inconsistent collapse sequence")
    return col


def qem_prefix(v: np.ndarray, f: np.ndarray, keep: float, aggressiveness: float = 7.0,
               diagonal: float | None = None):
    """The bottom of a hybrid hierarchy: fast-simplification's collapses, in order, while the collapsed
    mesh keeps more than ``keep`` of the input's triangles. Returns ``(parent (V + C',) int64`` (leaves
    0..V-1, then one binary node per collapse, -1 where the node is still a root), ``cur (V,)`` the
    current node of every vertex, ``faces (T', 3)`` the input faces mapped to their surviving vertices
    without the degenerate ones (input numbering), ``removed (V,) bool)``."""
    V, T = v.shape[0], f.shape[0]
    col = qem_collapses(v, f, aggressiveness, diagonal)
    f64 = np.asarray(f, np.int64)

    def mapped(c):
        r = np.arange(V)
        r[col[:c, 1]] = col[:c, 0]
        # compose: a survivor of an early collapse may be removed later (pointer jumping to a fixpoint)
        while True:
            nr = r[r]
            if np.array_equal(nr, r):
                break
            r = nr
        g = r[f64]
        ok = (g[:, 0] != g[:, 1]) & (g[:, 1] != g[:, 2]) & (g[:, 0] != g[:, 2])
        return g[ok]

    goal = keep * T
    lo, hi = 0, len(col)
    faces = None  # mapped(lo), once found
    while lo < hi:  # binary search: the largest C' whose mesh still has more than goal triangles (counts fall with C')
        mid = (lo + hi + 1) // 2
        g = mapped(mid)
        if len(g) > goal:
            lo, faces = mid, g
        else:
            hi = mid - 1
    C = lo
    parent, cur = _binary_nodes(col[:C], V)
    removed = np.zeros(V, bool)
    removed[col[:C, 1]] = True
    return parent, cur, (mapped(C) if faces is None else faces), removed


def _binary_nodes(col: np.ndarray, V: int):
    """``(parent (V + C,) int64, cur (V,) int64)``: one binary node ``V + k`` per collapse ``k`` of ``col``
    (its children: the current nodes of the two vertices), -1 where a node is still a root; ``cur``: the
    latest node of each vertex (its leaf if it never took part)."""
    C = col.shape[0]
    i0, i1 = col[:, 0], col[:, 1]
    k = np.arange(C)
    # previous collapse with the same i0 (its node is child 0 of collapse k), else the leaf i0
    o = np.lexsort((k, i0))
    same = np.zeros(C, dtype=bool)
    same[1:] = i0[o][1:] == i0[o][:-1]
    prev = np.full(C, -1, dtype=np.int64)
    prev[o[same]] = o[np.flatnonzero(same) - 1]
    child0 = np.where(prev >= 0, V + prev, i0)
    # latest collapse where a vertex was i0 (its final node), for i1: all such collapses precede k
    last = np.full(V, -1, dtype=np.int64)
    last[i0[o]] = o  # o is sorted by (i0, k): the last write per i0 is the latest k
    l1 = last[i1]
    if np.any(l1 >= k):
        raise RuntimeError("fast_simplification collapsed a vertex after it was removed")
    child1 = np.where(l1 >= 0, V + l1, i1)
    parent = np.full(V + C, -1, dtype=np.int64)
    parent[child0] = V + k
    parent[child1] = V + k
    cur = np.where(last >= 0, V + last, np.arange(V))
    return parent, cur


def _root_of(parent: np.ndarray, V: int) -> np.ndarray:
    """Root of each leaf 0..V-1 (pointer jumping)."""
    p = parent.copy()
    r = np.arange(parent.size)
    # jump: r <- parent(r) while it exists
    act = np.flatnonzero(p >= 0)
    while act.size:
        p[act] = np.where(p[p[act]] >= 0, p[p[act]], p[act])
        done = p[p[act]] < 0
        act = act[~done]
    root = np.where(parent >= 0, p, r)
    return root[:V]

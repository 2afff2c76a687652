"""Quadric-error vertex hierarchy ([GH97] edge collapses; [LHNW00 §6.3]).

Stages:

1. ``collapse``: fast-simplification (Fast-Quadric-Mesh-Simplification) decimates the mesh towards
   zero triangles and reports its collapse sequence: row ``[i0, i1]`` merges vertex ``i1`` into ``i0``.
2. ``binary tree``: collapse k creates node ``V + k`` whose children are the current nodes of ``i0``
   and ``i1`` (vectorised: the current node of a vertex is its latest collapse as ``i0``).
3. ``top``: what cannot be collapsed (separate components, stuck vertices) is joined by a tight octree
   over the remaining roots' centroids (``optim._octree``).
4. ``proxies``: node quadrics are sums of the vertices' area-weighted plane quadrics; a node's proxy
   minimises its quadric, regularised towards the centroid (``quadric_optimal``).

Quadric units: object units squared times area (a sum of area-weighted squared plane distances).
"""

from __future__ import annotations

import numpy as np

__all__ = ["qem_parents", "vertex_quadrics", "quadric_optimal"]


def vertex_quadrics(v: np.ndarray, f: np.ndarray, fn: np.ndarray | None = None) -> np.ndarray:
    """Area-weighted plane quadrics (V, 10): A (3x3 symmetric: a11 a12 a13 a22 a23 a33), b (3), c.

    Q(x) = x^T A x + 2 b.x + c = sum over incident triangles of area * (n.x + d)^2.
    """
    from ._mesh import corner_sum, face_normals

    if fn is None:
        fn = face_normals(v, f)
    dbl = np.linalg.norm(fn, axis=1)
    n = np.divide(fn, dbl[:, None], out=np.zeros_like(fn), where=dbl[:, None] > 0)
    area = 0.5 * dbl
    d = -np.einsum("ij,ij->i", n, v.take(f[:, 0], axis=0))
    q = np.stack(
        [n[:, 0] * n[:, 0], n[:, 0] * n[:, 1], n[:, 0] * n[:, 2], n[:, 1] * n[:, 1], n[:, 1] * n[:, 2],
         n[:, 2] * n[:, 2], n[:, 0] * d, n[:, 1] * d, n[:, 2] * d, d * d], axis=1
    ) * area[:, None]
    return corner_sum(f, q, v.shape[0])


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


def qem_parents(v: np.ndarray, f: np.ndarray, aggressiveness: float = 7.0) -> np.ndarray:
    """Binary edge-collapse hierarchy over the vertices, topped by a tight octree.

    Args:
        v: (V, 3) float64 vertices; f: (T, 3) int32 faces (validated).
        aggressiveness: fast-simplification's ``agg`` (higher = faster, rougher ordering).

    Returns:
        parent (V + M,) int64: leaves 0..V-1 are the vertices, one root (-1).
    """
    import fast_simplification

    V = v.shape[0]
    _, _, col = fast_simplification.simplify(
        np.ascontiguousarray(v, dtype=np.float64), np.ascontiguousarray(f, dtype=np.int32),
        target_count=0, agg=float(aggressiveness), return_collapses=True,
    )
    col = np.asarray(col, dtype=np.int64).reshape(-1, 2)
    C = col.shape[0]
    i0, i1 = col[:, 0], col[:, 1]
    if C and (col.min() < 0 or col.max() >= V or np.bincount(i1, minlength=V).max() > 1):
        raise RuntimeError("fast_simplification returned an inconsistent collapse sequence")
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

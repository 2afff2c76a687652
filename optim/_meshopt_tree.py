"""Vertex hierarchy from nested meshoptimizer simplifications (``build_tree(method="meshopt")``).

meshoptimizer's ``simplify`` is the best view-independent simplifier plod is compared with, and it keeps
input vertices, so a chain of its results is a hierarchy over them. Hand-written here: only what
meshoptimizer does not report, its collapse map (which kept vertex each removed vertex merged into),
recovered from the two index buffers it does return (the C library has no remap output, see ``_collapse_map``).

Stages (:func:`meshopt_parents`):

1. ``levels``: level 0 is the input; level k+1 is meshoptimizer's ``simplify`` of level k's index buffer
   to ``ratio`` of its triangles (``target_error`` 1, so the count decides; ``simplifyWithAttributes``
   on the vertex colours when the mesh has them). Every level's vertices are a subset of the previous
   level's. Nested calls judge as well as one call to the same count (FovVideoVDP, ratios 0.5 to
   0.85); ``ratio`` 0.8 keeps each call to few of its internal passes (a vertex moved in one pass can
   move again in the next), which makes the collapse map recoverable almost exactly.
2. ``collapse map``: meshoptimizer collapses each removed vertex along an edge into a neighbour, possibly
   again in a later internal pass, and its output is exactly the image of the input triangles under the
   composed map with degenerate triangles dropped. So the target of a removed vertex is the target of
   one of its level-k neighbours; among those, each removed vertex takes the one under which most of its
   triangles map onto an output triangle or vanish (a few rounds of local search, ties to the nearest
   candidate). What no candidate reaches goes to the nearest target along level-k edges (multi-source
   Dijkstra, scipy); a component meshoptimizer dropped entirely becomes one node of its own.
3. ``nodes``: every kept vertex that absorbed at least one vertex at a level gets a new node whose
   children are its current node and the current nodes of what it absorbed (no single-child chains);
   a uniform cut at level k reproduces meshoptimizer's level-k triangles up to the recovered map.
4. ``top``: what meshoptimizer cannot reduce further (and the dropped components) is joined by a tight
   octree over the remaining nodes' kept vertices (``optim._octree``), as ``optim._qem`` joins what
   fast-simplification cannot collapse.

Proxies (``optim._build``): ``build_tree(..., proxy="vertex")`` places a node at its kept input vertex
(meshoptimizer's own placement; ``survival`` ranks the vertices so that the vertex of highest rank a
node supports is that vertex), so a uniform cut is meshoptimizer's mesh; the default ``"optimal"`` places
it at the node's quadric optimum, as for ``"qem"``, which FovVideoVDP rates higher on the same hierarchy.
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["MeshoptHierarchy", "meshopt_parents", "meshopt_simplify", "COLOR_WEIGHT"]

#: weight of each colour channel (sRGB in [0, 1]) in meshoptimizer's attribute metric (positions are
#: measured relative to the mesh's extent, so 1 is about an error of the extent); experiments.peers uses 1
COLOR_WEIGHT = 1.0


def _simplify_with_attributes():
    """meshoptimizer's C ``meshopt_simplifyWithAttributes`` with its argument types declared: the Python
    binding (0.2.30a0) declares none for it, so ctypes would pass its sizes as 32-bit ints and could not
    pass its float. The same declaration as ``experiments.peers`` (which optim may not import)."""
    import ctypes

    from meshoptimizer._loader import lib

    fn = lib.meshopt_simplifyWithAttributes
    P = ctypes.POINTER
    f32 = np.ctypeslib.ndpointer(np.float32, flags="C")
    u32 = np.ctypeslib.ndpointer(np.uint32, flags="C")
    fn.argtypes = [u32, u32, ctypes.c_size_t, f32, ctypes.c_size_t, ctypes.c_size_t, f32, ctypes.c_size_t, f32,
                   ctypes.c_size_t, P(ctypes.c_ubyte), ctypes.c_size_t, ctypes.c_float, ctypes.c_uint,
                   P(ctypes.c_float)]
    fn.restype = ctypes.c_size_t
    return fn


def meshopt_simplify(positions: np.ndarray, faces: np.ndarray, target: int, colors: np.ndarray | None = None,
                     color_weight: float = COLOR_WEIGHT) -> np.ndarray:
    """meshoptimizer's simplify of ``faces`` (T, 3) over ``positions`` (V, 3) to about ``target`` triangles
    (error bound 1: the count decides); ``simplifyWithAttributes`` on ``colors`` (V, 3) when given.
    Returns faces (T', 3) int64 into the same vertices."""
    import meshoptimizer

    idx = np.ascontiguousarray(faces, dtype=np.uint32).ravel()
    pos = np.ascontiguousarray(positions, dtype=np.float32)
    dest = np.empty_like(idx)
    if colors is None:
        n = meshoptimizer.simplify(dest, idx, pos, target_index_count=3 * int(target), target_error=1.0)
    else:
        attr = np.ascontiguousarray(colors, dtype=np.float32)
        w = np.full(attr.shape[1], color_weight, np.float32)
        n = _simplify_with_attributes()(dest, idx, idx.size, pos, len(pos), 12, attr, attr.shape[1] * 4, w, w.size,
                                        None, 3 * int(target), 1.0, 0, None)
    return dest[:n].reshape(-1, 3).astype(np.int64)


@dataclasses.dataclass(frozen=True)
class MeshoptHierarchy:
    """What :func:`meshopt_parents` built (old numbering: leaves 0..V-1 are the vertices, then internals).

    ``parent`` (N,) int64, -1 for the root; ``survival`` (V,) int64: rank of each vertex, the highest
    a node supports is its kept vertex (2k: removed at level k; 2k+1: kept vertex of a dropped
    component at level k; 2L+2: in the last level L); ``node_level`` (N,) int64: the level whose mesh
    a node's fold belongs to (0 for leaves, k+1 for nodes made from level k to k+1, L+1 for the octree
    top); ``level_triangles`` (L+1,) triangles of meshoptimizer's level meshes (level 0: the input).
    """

    parent: np.ndarray
    survival: np.ndarray
    node_level: np.ndarray
    level_triangles: np.ndarray


def _edge_table(G: np.ndarray, V: int):
    """Directed edges of ``G`` grouped by first corner (CSR): ``(start (V+1,), second, third)``."""
    a = G.ravel()
    o = np.argsort(a)
    start = np.concatenate([[0], np.cumsum(np.bincount(a, minlength=V))])
    return start, G[:, [1, 2, 0]].ravel()[o], G[:, [2, 0, 1]].ravel()[o]


def _lookup(table, a, b, V):
    """Third corner of the output triangle holding directed edge a->b, -1 where there is none (a scan of
    a's few out-edges: faster than a binary search over all edges on meshes of 10^6 triangles)."""
    start, second, third = table
    lo = start[a]
    cnt = start[a + 1] - lo
    out = np.full(a.shape, -1, np.int64)
    act = np.flatnonzero(cnt > 0)
    j = 0
    while act.size:
        p = lo[act] + j
        hit = second[p] == b[act]
        out[act[hit]] = third[p[hit]]
        j += 1
        act = act[~hit & (cnt[act] > j)]
    return out


def _valid(img: np.ndarray, table, V: int) -> np.ndarray:
    """Per image triangle (K, 3) (-1 = unknown corner): 1 if it is an output triangle or vanishes (two
    equal known corners), -1 if neither, 0 if unknown (weighting a vanishing triangle 0.5 or 0.9 does not
    recover more of the map: measured)."""
    known = img >= 0
    eq = ((img[:, 0] == img[:, 1]) & known[:, 0]) | ((img[:, 1] == img[:, 2]) & known[:, 1]) | (
        (img[:, 2] == img[:, 0]) & known[:, 2])
    full = known.all(1)
    q = np.flatnonzero(full & ~eq)  # only these need the look-up
    hit = np.zeros(img.shape[0], bool)
    hit[q] = _lookup(table, img[q, 0], img[q, 1], V) == img[q, 2]
    return np.where(hit | eq, 1.0, np.where(full, -1.0, 0.0))


def _collapse_map(F: np.ndarray, G: np.ndarray, v: np.ndarray, rounds: int = 8) -> np.ndarray:
    """Recovered collapse map (V,) of one meshoptimizer call from level faces ``F`` to output faces ``G``:
    kept vertices map to themselves, removed ones to a kept vertex, -1 where nothing is found (vertices
    not in ``F`` or a component without kept vertices). See the module docstring (stage 2)."""
    V = v.shape[0]
    r = np.full(V, -1, np.int64)
    keep = np.zeros(V, bool)
    keep[G.ravel()] = True
    kept = np.flatnonzero(keep)
    r[kept] = kept
    isrem = np.zeros(V, bool)
    isrem[F.ravel()] = True
    isrem &= ~keep
    if not isrem.any():
        return r
    table = _edge_table(G, V)
    # neighbour pairs (x removed, y any), unique, and the corners of removed vertices grouped by vertex
    a, b = F.ravel(), F[:, [1, 2, 0]].ravel()
    ex, ey = np.concatenate([a, b]), np.concatenate([b, a])
    m = isrem[ex]
    pc, once = np.unique(ex[m] * V + ey[m], return_counts=True)  # (x, y) once: a border edge
    px_all, py_all = pc // V, pc % V
    border = np.zeros(V, bool)
    border[px_all[once == 1]] = True
    # meshoptimizer moves a border vertex only along its border loop (kCanCollapse: border -> border)
    sel = ~border[px_all] | (once == 1)
    px_all, py_all = px_all[sel], py_all[sel]
    corner = np.flatnonzero(isrem[F.ravel()])
    cx = F.ravel()[corner]
    o = np.argsort(cx, kind="stable")
    cx, cface, cslot = cx[o], corner[o] // 3, corner[o] % 3
    ctri = F[cface]  # (C, 3) the triangle of each corner
    deg = np.bincount(cx, minlength=V)
    cstart = np.cumsum(deg) - deg
    todo = np.zeros(V, bool)
    todo[isrem] = True
    n_bad = F.shape[0] + 1
    for _ in range(rounds):
        sel = todo[px_all]
        px, pt = px_all[sel], r[py_all[sel]]
        ok = pt >= 0
        if not ok.any():
            break
        px, pt = px[ok], pt[ok]  # grouped by x (a repeated candidate scores the same: harmless)
        n = deg[px]
        pair = np.repeat(np.arange(px.size), n)
        off = np.repeat(cstart[px] - np.concatenate([[0], np.cumsum(n)[:-1]]), n) + np.arange(int(n.sum()))
        img = r[ctri[off]]
        img[np.arange(off.size), cslot[off]] = pt[pair]
        score = np.bincount(pair, weights=_valid(img, table, V), minlength=px.size)
        # per x: best score, then the current target, then the nearest candidate (then the first)
        grp = np.flatnonzero(np.concatenate([[True], px[1:] != px[:-1]]))
        gid = np.repeat(np.arange(grp.size), np.diff(np.append(grp, px.size)))
        prio = 2 * score + (r[px] == pt)
        top = prio == np.maximum.reduceat(prio, grp)[gid]
        dist = np.full(px.size, np.inf)
        ti = np.flatnonzero(top)
        d = v[px[ti]] - v[pt[ti]]
        dist[ti] = np.einsum("ij,ij->i", d, d)
        best = top & (dist == np.minimum.reduceat(dist, grp)[gid])
        first = np.minimum.reduceat(np.where(best, np.arange(px.size), px.size), grp)
        bx, bt = px[first], pt[first]
        changed = r[bx] != bt
        r[bx] = bt
        # next round: the removed corners of triangles still not valid, while their number falls
        nn = deg[bx]  # only the triangles of the vertices just evaluated can have changed (and hold every bad one)
        faces = np.unique(cface[np.repeat(cstart[bx] - np.concatenate([[0], np.cumsum(nn)[:-1]]), nn)
                                + np.arange(int(nn.sum()))])
        bad = faces[_valid(r[F[faces]], table, V) <= 0]
        todo[:] = False
        todo[F[bad].ravel()] = True
        todo &= isrem
        if not changed.any() or not todo.any() or bad.size >= n_bad:
            break
        n_bad = bad.size
    return r


def _fill_unreached(F: np.ndarray, r: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vertices of ``F`` without a target take that of the nearest vertex with one along ``F``'s edges
    (multi-source Dijkstra); returns the vertices no target reaches."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import dijkstra

    inF = np.zeros(r.size, bool)
    inF[F.ravel()] = True
    un = np.flatnonzero(inF & (r < 0))
    if un.size == 0:
        return un
    verts = np.flatnonzero(inF)
    loc = np.full(r.size, -1, np.int64)
    loc[verts] = np.arange(verts.size)
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    w = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1) + 1e-30
    n = verts.size
    A = sp.coo_matrix((w, (loc[e[:, 0]], loc[e[:, 1]])), shape=(n, n)).tocsr()
    src = np.flatnonzero(r[verts] >= 0)
    if src.size == 0:
        return un
    _, _, s = dijkstra(A, directed=False, indices=src, min_only=True, return_predecessors=True)
    lu = loc[un]
    hit = s[lu] >= 0
    r[un[hit]] = r[verts[s[lu[hit]]]]
    return un[~hit]


def meshopt_parents(v: np.ndarray, f: np.ndarray, colors: np.ndarray | None = None, *, ratio: float = 0.8,
                    color_weight: float = COLOR_WEIGHT, start=None) -> MeshoptHierarchy:
    """Hierarchy of nested meshoptimizer simplifications over the vertices (module docstring).

    Args:
        v: (V, 3) vertices; f: (T, 3) faces (validated: every vertex used); colors: (V, 3) or None.
        ratio: each level's triangle target as a fraction of the previous level's, in (0, 1).
        color_weight: meshoptimizer's attribute weight of each colour channel.
        start: None, or the bottom of a hybrid hierarchy, :func:`optim._qem.qem_prefix`'s ``(parent,
            cur, faces, removed)``: the levels then start from those faces (over the surviving input
            vertices) and those nodes; the removed vertices rank lowest in ``survival``.
    """
    from scipy.sparse.csgraph import connected_components
    import scipy.sparse as sp

    from pmetric import PlodError

    from ._octree import octree_parents

    if not (isinstance(ratio, (int, float, np.floating)) and 0.0 < float(ratio) < 1.0):
        raise PlodError(f"meshopt_parents: ratio must be a number in (0, 1), got {ratio!r}")

    V = v.shape[0]
    pos = np.ascontiguousarray(v, dtype=np.float32)
    col = None if colors is None else np.ascontiguousarray(colors, dtype=np.float32)
    parent = np.full(max(2 * V - 1, 1), -1, np.int64)
    node_level = np.zeros(parent.size, np.int64)
    survival = np.zeros(V, np.int64)
    cur = np.arange(V, dtype=np.int64)  # current node of every vertex
    nxt = V
    retired = []  # (root, kept vertex) of dropped components
    F = np.asarray(f, dtype=np.int64)
    level_tris = [F.shape[0]]
    k = 0
    if start is not None:  # a hybrid: qem collapses below, their nodes at level 1
        p0, cur0, F0, removed = start
        parent[:p0.size] = p0
        node_level[V:p0.size] = 1
        cur, nxt, F, k = np.array(cur0, np.int64), p0.size, np.asarray(F0, np.int64), 1
        level_tris.append(F.shape[0])
        survival[~removed] = 2
        inF0 = np.zeros(V, bool)
        inF0[F.ravel()] = True
        gone = np.flatnonzero(~removed & ~inF0)  # components the collapses took to no triangle: one node each
        if gone.size:
            retired.append(np.stack([cur[gone], gone], axis=1))
    while F.shape[0] > 1:
        inF = np.zeros(V, bool)  # compact: meshoptimizer's work follows the level's size
        inF[F.ravel()] = True
        used = np.flatnonzero(inF)
        Fl = (np.cumsum(inF) - 1)[F]
        Gl = meshopt_simplify(pos[used], Fl, max(int(ratio * F.shape[0]), 1), None if col is None else col[used],
                              color_weight)
        if Gl.shape[0] == 0 or Gl.shape[0] >= F.shape[0]:
            break
        G = used[Gl]
        vl = v[used]
        rl = _collapse_map(Fl, Gl, vl)  # on the level's own vertex numbering: work follows its size
        lost = used[_fill_unreached(Fl, rl, vl)]
        r = np.full(V, -1, np.int64)
        r[used] = np.where(rl >= 0, used[np.maximum(rl, 0)], -1)
        removed = used[(rl >= 0) & (rl != np.arange(used.size))]
        survival[removed] = 2 * k
        if removed.size:
            absorb, inv = np.unique(r[removed], return_inverse=True)
            ids = nxt + np.arange(absorb.size)
            nxt += absorb.size
            parent[cur[removed]] = ids[inv]
            parent[cur[absorb]] = ids
            node_level[ids] = k + 1
            cur[absorb] = ids
        if lost.size:  # components meshoptimizer dropped: one node each
            survival[lost] = 2 * k
            e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
            loc = np.full(V, -1, np.int64)
            loc[lost] = np.arange(lost.size)
            e = e[(loc[e[:, 0]] >= 0) & (loc[e[:, 1]] >= 0)]
            A = sp.coo_matrix((np.ones(len(e)), (loc[e[:, 0]], loc[e[:, 1]])), shape=(lost.size,) * 2)
            nc, lab = connected_components(A, directed=False)
            size = np.bincount(lab, minlength=nc)
            keep = np.full(nc, V, np.int64)
            np.minimum.at(keep, lab, lost)  # each component's smallest vertex stands for it
            survival[keep] = 2 * k + 1
            multi = size > 1
            ids = np.full(nc, -1, np.int64)
            ids[multi] = nxt + np.arange(int(multi.sum()))
            nxt += int(multi.sum())
            inm = multi[lab]
            parent[cur[lost[inm]]] = ids[lab[inm]]
            node_level[ids[multi]] = k + 1
            cur[keep[multi]] = ids[multi]
            retired.append(np.stack([cur[keep], keep], axis=1))
        F = G
        level_tris.append(F.shape[0])
        k += 1
    last = np.flatnonzero(np.bincount(F.ravel(), minlength=V))
    survival[last] = 2 * k + 2
    ret = np.concatenate(retired) if retired else np.zeros((0, 2), np.int64)
    roots = np.concatenate([cur[last], ret[:, 0]])
    if roots.size > 1:
        top, _ = octree_parents(v[np.concatenate([last, ret[:, 1]])])
        R = roots.size
        M = top.size - R
        remap = np.concatenate([roots, nxt + np.arange(M)])
        has = top >= 0
        parent[remap[has]] = remap[top[has]]
        node_level[nxt:nxt + M] = k + 1
        nxt += M
    return MeshoptHierarchy(parent=parent[:nxt].copy(), survival=survival, node_level=node_level[:nxt].copy(),
                            level_triangles=np.asarray(level_tris, np.int64))

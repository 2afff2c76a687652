"""The builder of the vertex tree, :func:`build_tree` [LHNW00 §2; LH01 §5].

Named stages of :func:`build_tree` (:data:`BUILD_STAGES`, the order its ``progress`` callback reports):

* ``validate``: the bad-input policy of :func:`optim.validate_mesh` (degenerate, duplicate triangles
  and unreferenced vertices dropped and counted in ``tree.mesh_report``).
* ``cluster``: a hierarchy over the input vertices, as a parent array (leaves = vertices):
  ``"octree"`` (tight octree, ``optim._octree``), ``"qem"`` (quadric edge collapses,
  ``optim._qem``; the better hierarchy [LHNW00 §6.3] asks for) or ``"meshopt"`` (nested meshoptimizer
  simplifications, ``optim._meshopt_tree``).
* ``renumber``: top-down breadth-first numbering (root 0, ``parent[i] < i``, contiguous children).
* ``aggregate``: bottom-up per node: vertex count, bounding box, colour and normal sums, luminance
  range, normal masks (OR), smallest vertex index; then proxies (octree: centroid; qem:
  quadric-optimal point), proxy colour and luminance, bounding spheres and geometric errors (exact
  over the supported vertices), fold contrast ``fold_delta`` [LH01 §5.2].
* ``subtris``: each triangle's owner is the deepest of the three pairwise lowest common ancestors
  of its corners' leaves: exactly the node whose fold removes it (CSR ``subtri_start``/``subtris``).

Units: positions, ``center``, ``radius``, ``geom_error`` in object units; ``lum*`` and
``fold_delta`` are relative linear luminance in [0, 1] ([LHNW00]: "intensity ... luminance output by a
standard computer monitor, normalized to the range [0, 1]").
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

from pmetric import PlodError

from ._levels import Levels, level_runs
from ._mesh import face_normals, validated_mesh_and_normals
from ._normal_cube import _unit, normal_cells
from ._qem import PROXIES
from ._tree import METHODS, VertexTree, Lighting, _srgb_luminance, _vertex_normals, local_origin

__all__ = ["build_tree", "BUILD_STAGES"]


# ----------------------------------------------------------------------------------------------
# build


def _list_rank(parent: np.ndarray) -> np.ndarray:
    """Synchronous pointer jumping (Wyllie): depth of each node = number of ancestors."""
    d = (parent >= 0).astype(np.int64)
    p = parent.copy()
    while True:
        act = np.flatnonzero(p >= 0)
        if act.size == 0:
            return d
        pa = p[act]
        dn = d[pa]
        pn = p[pa]
        d[act] += dn
        p[act] = pn


def _bfs_order(parent: np.ndarray, depth: np.ndarray, root: int):
    """Top-down numbering: sort by depth, then by the new index of the parent, then by old index.

    Returns ``(order, new_of_old)``: ``order[new] = old``.
    """
    n = parent.shape[0]
    by_depth = np.argsort(depth, kind="stable")
    counts = np.bincount(depth)
    starts = np.concatenate([[0], np.cumsum(counts)])
    new_of_old = np.empty(n, dtype=np.int64)
    order = np.empty(n, dtype=np.int64)
    order[0] = root
    new_of_old[root] = 0
    for d in range(1, counts.size):
        olds = by_depth[starts[d]:starts[d + 1]]
        keys = new_of_old[parent[olds]]
        o = olds[np.argsort(keys, kind="stable")]
        order[starts[d]:starts[d + 1]] = o
        new_of_old[o] = np.arange(starts[d], starts[d + 1])
    return order, new_of_old


class _LCA:
    """Lowest common ancestors of leaf pairs by binary lifting on depth-first leaf ranges.

    Node x is an ancestor of leaf position p iff ``leaf_lo[x] <= p < leaf_hi[x]``; climbing from
    one leaf by powers of two while the ancestor does not hold the other leaf takes log2(depth)
    vectorised steps whatever the tree's shape (edge-collapse trees can be deep).
    """

    def __init__(self, parent, depth, leaf_lo, leaf_hi):
        self.lo, self.hi = leaf_lo, leaf_hi
        up = [np.where(parent >= 0, parent, 0)]
        while (1 << len(up)) <= int(depth.max()):
            up.append(up[-1].take(up[-1]))
        self.up = up

    def __call__(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        lo, hi = self.lo, self.hi
        pb = lo.take(b)
        x = a.astype(np.int64, copy=True)
        for u in reversed(self.up):
            y = u.take(x)
            outside = (lo.take(y) > pb) | (hi.take(y) <= pb)
            x = np.where(outside, y, x)
        inside = (lo.take(x) <= pb) & (pb < hi.take(x))
        return np.where(inside, x, self.up[0].take(x))


#: the stages of :func:`build_tree`, in the order the ``progress`` callback reports them
BUILD_STAGES = ("validate", "cluster", "renumber", "aggregate", "subtris")


def build_tree(vertices, faces, colors=None, method: str = "meshopt", lighting=None, *,
               progress: Callable[[str, int, int], None] | None = None,
               qem_aggressiveness: float = 7.0, qem_diagonal: float | None = 100.0,
               proxy: str = "optimal") -> VertexTree:
    """Build the vertex tree of a triangle mesh [LHNW00 §2; LH01 §5].

    Args:
        vertices: (V, 3) positions, object units. faces: (T, 3) vertex indices.
        colors: optional (V, 3) sRGB vertex colours in [0, 1]: vertex intensity is their relative
            luminance; without colours the mesh is pre-lit with ``lighting`` (:class:`Lighting`).
        method: ``"meshopt"`` (default: nested meshoptimizer simplifications to 80 % of the previous
            level, with the colours when given; its uniform cuts are meshoptimizer's meshes, see
            ``optim._meshopt_tree``; judged 0.18 JOD better than ``"qem"`` at equal triangle counts,
            reports/accuracy), ``"qem"`` (quadric edge-collapse hierarchy via fast-simplification,
            topped by a tight octree over what it cannot collapse), ``"hybrid"`` (qem's collapses while
            the mesh keeps more than :data:`HYBRID_KEEP` of its triangles, meshoptimizer's nested levels
            on what is left: qem's finer levels and meshoptimizer's coarse ones, which the judge rates
            best at those budgets once cuts carry their region normals, reports/accuracy/what_we_tried.md)
            or ``"octree"`` (VDSlib's tight octree).
        lighting: :class:`Lighting`, dict or None (default light); used only without colours.
        progress: optional callback ``progress(stage, done, total)``, called before each stage of
            :data:`BUILD_STAGES` with ``done`` the number of stages finished and ``total`` their
            number, and once more as ``("done", total, total)``; ``done`` never decreases. The
            library prints nothing itself (``experiments._progress.rich_progress`` draws a bar).
        qem_aggressiveness: fast-simplification's ``agg`` for the collapse order (``method="qem"``).
        qem_diagonal: a positive bounding-box diagonal (default 100) to scale a copy of the mesh to
            for the qem collapse order only (fast-simplification's error thresholds are absolute, so
            its order depends on the units: with the default the hierarchy is unit-independent and
            measured better, reports/accuracy/hierarchy.md), or None (the mesh in its own units).
            Positions, quadrics and errors stay in object units.
        proxy: placement of internal nodes: ``"optimal"`` (qem: the point minimising the node's
            area-weighted quadric, regularised towards the centroid; octree: the centroid) or
            ``"vertex"`` (the supported input vertex of least node quadric error, as edge collapses
            that keep input vertices place it; reports/accuracy/hierarchy.md compares them; meshopt:
            the vertex meshoptimizer kept, so a uniform cut is exactly its mesh). meshopt's
            ``"optimal"`` is qem's (the quadric optimum), which FovVideoVDP rates higher.

    Returns:
        :class:`VertexTree` over the *validated* mesh (see :func:`optim.validate_mesh`;
        ``tree.mesh_report`` lists what was dropped).
    """
    if not isinstance(method, str) or method not in METHODS:
        raise PlodError(f"build_tree: method must be one of {METHODS}, got {method!r}")
    agg = qem_aggressiveness
    if (not isinstance(agg, (int, float, np.integer, np.floating)) or isinstance(agg, (bool, np.bool_))
            or not np.isfinite(agg) or agg <= 0):
        raise PlodError(f"build_tree: qem_aggressiveness must be a finite number > 0 (fast-simplification's agg), "
                        f"got {agg!r}")
    if qem_diagonal is not None:
        ok = isinstance(qem_diagonal, (int, float, np.integer, np.floating)) and not isinstance(qem_diagonal, bool)
        if not ok or not np.isfinite(qem_diagonal) or qem_diagonal <= 0:
            raise PlodError(f"build_tree: qem_diagonal must be None or a finite number > 0, got {qem_diagonal!r}")
    if not isinstance(proxy, str) or proxy not in PROXIES:
        raise PlodError(f"build_tree: proxy must be one of {PROXIES}, got {proxy!r}")
    if progress is not None and not callable(progress):
        raise PlodError(f"build_tree: progress must be None or a callable (stage, done, total), got {progress!r}")
    light = Lighting.coerce(lighting)
    total = len(BUILD_STAGES)

    def step(stage):
        if progress is not None:
            progress(stage, BUILD_STAGES.index(stage) if stage in BUILD_STAGES else total, total)

    step("validate")
    mesh, fn = validated_mesh_and_normals(vertices, faces, colors, count_nonmanifold=False)
    v_in, f, c = mesh.vertices, mesh.faces, mesh.colors
    origin = local_origin(v_in)  # 0 unless the mesh is far from 0 for its size: then all work is relative
    if origin.any():
        v = v_in - origin  # exact (see local_origin)
        fn = face_normals(v, f)  # the face normals of the relative positions, as for a mesh near 0
    else:
        v = v_in
    step("cluster")
    vn = _vertex_normals(v, f, fn)
    parent_old, quadrics, survival = _cluster(v, f, fn, method, qem_aggressiveness, qem_diagonal, c)
    if proxy == "vertex" and quadrics is None:
        from ._qem import vertex_quadrics

        quadrics = vertex_quadrics(v, f, fn)
    tree = _assemble(v, f, c, vn, fn, parent_old, quadrics, light if c is None else None, step, proxy=proxy,
                     survival=survival, method=method, mesh_report=dataclasses.asdict(mesh.report), origin=origin)
    if origin.any():
        tree = dataclasses.replace(tree, vertices=v_in)  # the input's vertices; node arrays stay relative
    step("done")
    return tree


#: ``method="hybrid"``: qem collapses while the mesh keeps more than this share of its triangles, then
#: meshoptimizer's nested levels on what is left
HYBRID_KEEP = 0.2


def _cluster(v, f, fn, method, qem_aggressiveness, qem_diagonal=None, c=None):
    """The ``cluster`` stage: (parent array over V leaves + internal nodes, vertex quadrics or None, vertex
    survival ranks or None: with ranks, ``proxy="vertex"`` places a node at its supported vertex of highest
    rank, the vertex the simplifier kept)."""
    if method == "octree":
        from ._octree import octree_parents

        return octree_parents(v)[0], None, None
    if method in ("meshopt", "hybrid"):
        from ._meshopt_tree import meshopt_parents
        from ._qem import qem_prefix, vertex_quadrics

        start = None if method == "meshopt" else qem_prefix(v, f, HYBRID_KEEP, qem_aggressiveness, qem_diagonal)
        h = meshopt_parents(v, f, c, start=start)
        return h.parent, vertex_quadrics(v, f, fn), h.survival
    from ._qem import qem_parents, vertex_quadrics

    return (qem_parents(v, f, aggressiveness=qem_aggressiveness, diagonal=qem_diagonal), vertex_quadrics(v, f, fn),
            None)


def _renumber(parent_old: np.ndarray, V: int):
    """The ``renumber`` stage: (parent, depth, vertex_node) in top-down breadth-first numbering."""
    n = parent_old.shape[0]
    roots = np.flatnonzero(parent_old < 0)
    if roots.size != 1:
        raise ValueError(f"internal error: hierarchy has {roots.size} roots")
    depth_old = _list_rank(parent_old)
    order, new_of_old = _bfs_order(parent_old, depth_old, int(roots[0]))
    parent = np.full(n, -1, dtype=np.int64)
    parent[1:] = new_of_old[parent_old[order[1:]]]
    return parent, depth_old[order], new_of_old[:V]


def _aggregate(lv: Levels, v, f, c, vn, fn, vertex_node, quadrics, light) -> dict:
    """The ``aggregate`` stage: bottom-up sums, bounds, luminance range, normal masks, proxies."""
    V, N = v.shape[0], len(lv.parent)
    leaf = np.ones(N, bool)
    leaf[lv.parent[1:]] = False
    lum_v = _srgb_luminance(c) if c is not None else light.intensity(_unit(vn))
    ssum = np.zeros((N, 10 if c is not None else 7))  # count, pos(3), normal(3)[, color(3)]
    ssum[vertex_node] = np.hstack([np.ones((V, 1)), v, vn] + ([c] if c is not None else []))
    lv.reduce_up(ssum, np.add)
    smin = np.zeros((N, 5))  # bbox min(3), lum min, min vertex
    smax = np.zeros((N, 4))  # bbox max(3), lum max
    smin[vertex_node] = np.hstack([v, lum_v[:, None], np.arange(V)[:, None]])
    smax[vertex_node] = np.hstack([v, lum_v[:, None]])
    lv.reduce_up(smin, np.minimum)
    lv.reduce_up(smax, np.maximum)
    count = ssum[:, 0]
    centroid = ssum[:, 1:4] / count[:, None]
    if quadrics is not None:
        from ._qem import quadric_optimal

        qn = np.zeros((N, quadrics.shape[1]))
        qn[vertex_node] = quadrics
        pos = quadric_optimal(lv.reduce_up(qn, np.add), centroid)
    else:
        pos = centroid
    pos[vertex_node] = v  # leaves: exactly the input vertex
    color = None
    if c is not None:
        color = (ssum[:, 7:10] / count[:, None]).astype(np.float32)
        color[vertex_node] = c
        lum = _srgb_luminance(color)
    else:
        lum = light.intensity(_unit(ssum[:, 4:7]))
    lum[vertex_node] = lum_v
    lum_min = np.minimum(smin[:, 3], lum).astype(np.float32)
    lum_max = np.maximum(smax[:, 3], lum).astype(np.float32)
    fold_delta = np.maximum(lum_max - lum, lum - lum_min).astype(np.float32)
    fold_delta[leaf] = 0.0
    return dict(leaf=leaf, pos=pos, color=color, lum=lum, lum_min=lum_min, lum_max=lum_max,
                fold_delta=fold_delta, center=0.5 * (smin[:, 0:3] + smax[:, 0:3]),
                min_vertex=smin[:, 4].astype(np.int32), mask=_normal_masks(lv, f, fn, vertex_node))


def _normal_masks(lv: Levels, f, fn, vertex_node) -> np.ndarray:
    """(N, 6) uint64 normal masks: triangle normal cells OR-ed into the corner leaves, then up the tree."""
    cell = normal_cells(fn)
    mask = np.zeros((len(lv.parent), 6), dtype=np.uint64)
    bits = np.left_shift(np.uint64(1), (cell % 64).astype(np.uint64))
    flat = mask.reshape(-1)
    for k in range(3):
        np.bitwise_or.at(flat, vertex_node[f[:, k]] * 6 + cell // 64, bits)
    return lv.reduce_up(mask, np.bitwise_or)


def _leaf_ranges(lv: Levels, leaf, vertex_node):
    """Depth-first leaf ranges (top-down): (leaf_lo, leaf count, leaf_vertex)."""
    V = vertex_node.shape[0]
    nleaf = lv.reduce_up(leaf.astype(np.int64), np.add)
    leaf_lo = np.zeros(len(nleaf), dtype=np.int64)
    for a, b, seg, pids in lv.groups[1:]:
        cs = np.cumsum(nleaf[a:b])
        seg_id = np.repeat(np.arange(seg.size), np.diff(np.append(seg, b - a)))
        base = np.concatenate([[0], cs])[seg]  # cumsum before each segment start
        excl = np.concatenate([[0], cs[:-1]]) - base[seg_id]
        leaf_lo[a:b] = leaf_lo[pids][seg_id] + excl
    leaf_vertex = np.empty(V, dtype=np.int64)
    leaf_vertex[leaf_lo[vertex_node]] = np.arange(V)
    return leaf_lo, nleaf, leaf_vertex


def _bounds(lv: Levels, v, leaf, vertex_node, center, pos, leaf_lo, nleaf, leaf_vertex):
    """Exact bounding radius and geometric error over the supported vertices, rounded up to float32."""
    N = len(leaf)
    center = center.astype(np.float32).astype(np.float64)  # measure from the stored (float32) centre
    pos = pos.astype(np.float32).astype(np.float64)
    radius = np.zeros(N)
    geom = np.zeros(N)
    vd = v.take(leaf_vertex, axis=0)  # vertices in depth-first order
    for nodes, idx, off in level_runs(lv.start, leaf_lo, nleaf, ~leaf):
        pts = vd.take(idx, axis=0)
        sz = nleaf.take(nodes)
        dc = pts - np.repeat(center.take(nodes, axis=0), sz, axis=0)
        dp = pts - np.repeat(pos.take(nodes, axis=0), sz, axis=0)
        radius[nodes] = np.maximum.reduceat(np.einsum("ij,ij->i", dc, dc), off)
        geom[nodes] = np.maximum.reduceat(np.einsum("ij,ij->i", dp, dp), off)
    radius = np.sqrt(radius)
    geom = np.sqrt(geom)
    radius[vertex_node] = np.sqrt(((v - center[vertex_node]) ** 2).sum(1))  # float32 rounding of a leaf centre
    # round up so that the float32 sphere still holds every supported vertex
    radius = np.where(radius > 0, np.nextafter(radius.astype(np.float32), np.float32(np.inf)), 0.0)
    geom = np.where(geom > 0, np.nextafter(geom.astype(np.float32), np.float32(np.inf)), 0.0)
    return center, pos, radius, geom


def _subtris(parent, depth, f, vertex_node, leaf_lo, leaf_hi):
    """The ``subtris`` stage: each triangle's owner is the deepest pairwise LCA of its corners' leaves.

    Two of the three pairwise LCAs coincide (the triple's LCA); the third is deeper or equal. If
    LCA(0,1) != LCA(0,2) the deeper of the two is the answer; else LCA(1,2) decides."""
    N = len(parent)
    lf = vertex_node.take(f)
    lca = _LCA(parent, depth, leaf_lo, leaf_hi)
    l01 = lca(lf[:, 0], lf[:, 1])
    l02 = lca(lf[:, 0], lf[:, 2])
    tri_node = np.where(depth.take(l01) >= depth.take(l02), l01, l02)
    same = np.flatnonzero(l01 == l02)
    tri_node[same] = lca(lf[same, 1], lf[same, 2])
    subtris = np.argsort(tri_node, kind="stable")
    num_subtris = np.bincount(tri_node, minlength=N)
    return tri_node, subtris, num_subtris, np.concatenate([[0], np.cumsum(num_subtris)])


def _vertex_proxies(lv: Levels, v, leaf, vertex_node, quadrics, leaf_lo, nleaf, leaf_vertex) -> np.ndarray:
    """``proxy="vertex"``: each internal node's supported input vertex of least node quadric error (level by
    level, as :func:`_bounds`: the supports of one level are disjoint); leaves keep their vertex."""
    from ._qem import quadric_vertex

    qn = np.zeros((len(leaf), quadrics.shape[1]))
    qn[vertex_node] = quadrics
    lv.reduce_up(qn, np.add)
    vd = v.take(leaf_vertex, axis=0)  # vertices in depth-first order
    pos = np.empty((len(leaf), 3))
    pos[vertex_node] = v
    for d in range(len(lv.start) - 1):
        s, e = lv.start[d], lv.start[d + 1]
        nodes = np.arange(s, e)[~leaf[s:e]]
        if nodes.size:
            pos[nodes] = vd.take(quadric_vertex(qn.take(nodes, axis=0), vd, leaf_lo.take(nodes), nleaf.take(nodes)),
                                 axis=0)
    return pos


def _survivor_proxies(lv: Levels, v, vertex_node, survival) -> np.ndarray:
    """Proxies at each node's supported vertex of highest ``survival`` rank (ties: the smallest index):
    ``method="meshopt", proxy="vertex"`` places a node at the input vertex meshoptimizer kept
    (``optim._meshopt_tree``)."""
    V = v.shape[0]
    code = np.zeros(len(lv.parent), np.int64)
    code[vertex_node] = np.asarray(survival, np.int64) * V + (V - 1 - np.arange(V))
    lv.reduce_up(code, np.maximum)
    return v.take(V - 1 - code % V, axis=0)


def _assemble(v, f, c, vn, fn, parent_old, quadrics, light, step=lambda stage: None, proxy: str = "optimal",
              survival=None, **meta) -> VertexTree:
    """Stages ``renumber`` to ``subtris`` of :func:`build_tree` for a hierarchy given as a parent array
    over V leaves + internals; ``meta`` (``method``, ``mesh_report``) goes to the tree."""
    step("renumber")
    parent, depth, vertex_node = _renumber(parent_old, v.shape[0])
    child_count = np.bincount(parent[1:], minlength=parent.shape[0])
    child_start = np.searchsorted(parent, np.arange(parent.shape[0]), side="left")
    lv = Levels.from_depth(parent, depth)
    step("aggregate")
    agg = _aggregate(lv, v, f, c, vn, fn, vertex_node, quadrics, light)
    leaf_lo, nleaf, leaf_vertex = _leaf_ranges(lv, agg["leaf"], vertex_node)
    leaf_hi = leaf_lo + nleaf
    if proxy == "vertex" and survival is not None:
        agg["pos"] = _survivor_proxies(lv, v, vertex_node, survival)
    elif proxy == "vertex":
        agg["pos"] = _vertex_proxies(lv, v, agg["leaf"], vertex_node, quadrics, leaf_lo, nleaf, leaf_vertex)
    center, pos, radius, geom = _bounds(lv, v, agg["leaf"], vertex_node, agg["center"], agg["pos"],
                                        leaf_lo, nleaf, leaf_vertex)
    step("subtris")
    tri_node, subtris, num_subtris, subtri_start = _subtris(parent, depth, f, vertex_node, leaf_lo, leaf_hi)

    i32 = lambda x: np.ascontiguousarray(x, dtype=np.int32)  # noqa: E731
    f32 = lambda x: np.ascontiguousarray(x, dtype=np.float32)  # noqa: E731
    N = parent.shape[0]
    mask = np.ascontiguousarray(agg["mask"], dtype="<u8").view(np.uint8).reshape(N, 48)
    return VertexTree(
        vertices=v, faces=i32(f), colors=c, parent=i32(parent), child_start=i32(child_start),
        child_count=i32(child_count), depth=i32(depth), vertex_node=i32(vertex_node), position=f32(pos),
        color=agg["color"], center=f32(center), radius=f32(radius), lum=f32(agg["lum"]), lum_min=agg["lum_min"],
        lum_max=agg["lum_max"], fold_delta=agg["fold_delta"], geom_error=f32(geom), normal_mask=mask,
        subtri_start=i32(subtri_start), subtris=i32(subtris), tri_node=i32(tri_node), num_subtris=i32(num_subtris),
        leaf_lo=i32(leaf_lo), leaf_hi=i32(leaf_hi), leaf_vertex=i32(leaf_vertex), min_vertex=agg["min_vertex"],
        lighting=light, **meta,
    )

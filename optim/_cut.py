"""Cuts through the vertex tree: triangle-budget and threshold selection, and mesh extraction.

Stages: ``check keys`` (monotone: parent >= child [LH01 fn 2]) -> ``select`` (budget: the
greedy order of VDSlib's triangle-budget mode [LH01 §5.3]; threshold: every fold that is
perceptible) -> ``extract`` (representatives and surviving triangles).

A cut is a boolean ``unfolded`` (N,) closed under ancestors. Only internal nodes are ever unfolded
(a leaf has nothing to unfold). Triangles of a cut = ``num_subtris[unfolded].sum()``.

Greedy budget mode (VDSlib; :func:`budget_cut_heap` is the plain heap reference): start with the root
folded; repeatedly take the *boundary* node (folded, parent unfolded) with the greatest key - ties:
lower node index first - and unfold it if its subtris fit in the budget; stop at the first that does
not fit. With monotone keys every node's parent precedes it in the order (key desc, index asc), so
the greedy sequence is that sorted order and the cut is its longest prefix whose triangle sum fits.
:func:`budget_cut` finds that prefix by a weighted radix selection on 32-bit key codes (two 16-bit passes,
O(N)), sorting only the few candidates at the boundary: the identical cut, without a full sort.
"""

from __future__ import annotations

import dataclasses
import heapq

import numpy as np

from pmetric import PlodError

from ._levels import expand_ranges
from ._parallel import beside

__all__ = ["Cut", "budget_cut", "budget_cut_heap", "min_nonempty_budget", "threshold_cut", "imperceptible_cut",
           "repair_monotone", "extract"]

_MONOTONE = ("check", "repair", "trust")


@dataclasses.dataclass(frozen=True)
class Cut:
    """A cut through a vertex tree.

    Attributes:
        unfolded: (N,) bool, closed under ancestors.
        triangles: triangles of the simplified mesh.
        distance: the largest key among folded internal nodes whose parent is unfolded (the boundary):
            for perceptual keys, the viewing-distance multiple beyond which the cut is imperceptible
            [LH01 §5.3]; 0.0 when every internal node is unfolded.
        stop_reason: ``"budget"`` (the next fold did not fit), ``"imperceptible"`` (every remaining
            fold has key <= threshold) or ``"all_unfolded"``.
    """

    unfolded: np.ndarray
    triangles: int
    distance: float
    stop_reason: str

    @property
    def n_unfolded(self) -> int:
        return int(np.count_nonzero(self.unfolded))


def _prepare_keys(tree, keys, monotone: str, who: str):
    """Check keys; returns ``(k (N,), ki (M,))``: all keys and those of the internal nodes.

    float32 keys stay float32 (the selection then works on 32-bit codes); anything else becomes
    float64. Only internal nodes' keys matter (leaves are never unfolded) and only they are checked.
    """
    if not isinstance(monotone, str) or monotone not in _MONOTONE:
        raise PlodError(f"{who}: monotone must be one of {_MONOTONE}, got {monotone!r}")
    _check_tree(tree, who)
    k = np.asarray(keys)
    N = tree.n_nodes
    if k.shape != (N,):
        raise PlodError(f"{who}: keys must have shape ({N},) (one per tree node), got {k.shape}")
    if not np.issubdtype(k.dtype, np.floating) and not np.issubdtype(k.dtype, np.integer):
        raise PlodError(f"{who}: keys must be real numbers, got dtype {k.dtype}")
    if k.dtype != np.float32:
        k = k.astype(np.float64, copy=False)
    internal = tree.internal
    ki = k.take(internal)
    if monotone == "trust" or internal.size < 2:
        if np.isnan(ki).any():
            raise PlodError(f"{who}: keys contain NaN (node {int(internal[np.flatnonzero(np.isnan(ki))[0]])})")
        return k, ki
    ok = ki.take(_internal_parent_pos(tree)) >= ki[1:]  # False for a violation or a NaN
    if ok.all():
        return k, ki
    if np.isnan(ki).any():
        raise PlodError(f"{who}: keys contain NaN (node {int(internal[np.flatnonzero(np.isnan(ki))[0]])})")
    if monotone == "repair":
        k = repair_monotone(tree, k)
        return k, k.take(internal)
    bad = ~ok
    i = int(internal[1:][np.flatnonzero(bad)[0]])
    raise PlodError(
        f"{who}: keys are not monotone (parent >= child) at {int(bad.sum())} internal nodes, e.g. node "
        f"{i} key {k[i]:g} > parent {int(tree.parent[i])} key {k[tree.parent[i]]:g}; pass "
        f"monotone='repair' to propagate the maximum upward [LH01 fn 2]"
    )


def _check_tree(tree, who: str):
    if not hasattr(tree, "n_nodes") or not hasattr(tree, "internal"):
        raise PlodError(f"{who}: tree must be an optim.VertexTree, got {type(tree).__name__}")


def _internal_parent_pos(tree) -> np.ndarray:
    """(M - 1,) position in ``tree.internal`` of the parent of each non-root internal node (cached)."""
    def build():
        internal = tree.internal
        pos = np.full(tree.n_nodes, -1, dtype=np.int64)
        pos[internal] = np.arange(internal.size)
        return pos.take(tree.parent.take(internal[1:])).astype(np.int32)

    return tree.derived("cut.internal_parent_pos", build)


def repair_monotone(tree, keys) -> np.ndarray:
    """Monotone envelope: each node's key becomes the maximum over its subtree [LH01 fn 2].

    Returns a new float64 (N,) array; parent >= child holds afterwards.
    """
    _check_tree(tree, "repair_monotone")
    try:
        k = np.array(keys, dtype=np.float64)
    except (TypeError, ValueError):
        raise PlodError("repair_monotone: keys must be real numbers, one per tree node") from None
    if k.shape != (tree.n_nodes,):
        raise PlodError(f"repair_monotone: keys must have shape ({tree.n_nodes},) (one per tree node), got {k.shape}")
    if np.isnan(k).any():  # a NaN would spread to every ancestor
        raise PlodError(f"repair_monotone: keys contain NaN (node {int(np.flatnonzero(np.isnan(k))[0])})")
    return tree.levels.reduce_up(k, np.maximum, include_self=True)


def _desc_rank_bits(k: np.ndarray) -> np.ndarray:
    """Unsigned codes whose ascending order is the descending order of the float keys.

    float32 -> uint32, float64 -> uint64 (IEEE bit trick; -0.0 is first turned into 0.0 so that the
    two zeros tie, as they do for the heap's float comparison).
    """
    if k.dtype == np.float32:
        u, s, top = np.uint32, np.int32, 31
    else:
        u, s, top = np.uint64, np.int64, 63
    k = k + k.dtype.type(0)  # -0.0 -> 0.0
    b = k.view(u)
    neg = (k.view(s) >> top).view(u)  # all ones for negative keys
    return b ^ ~(neg | u(1 << top))


def budget_cut(tree, keys, budget: int, *, monotone: str = "check") -> Cut:
    """VDSlib's greedy triangle-budget cut [LH01 §5.3], computed by selection.

    Args:
        tree: :class:`optim.VertexTree`.
        keys: (N,) fold priorities, larger = keep unfolded first (perceptual keys: imperceptible
            viewing-distance multiples); -inf is allowed (culled). Only internal nodes' keys are
            used; they must be monotone (parent >= child). float32 keys are used as they are.
        budget: largest number of triangles, an integer >= 0 (bool, NaN and fractions are
            rejected). A budget below :func:`min_nonempty_budget` gives the coarsest cut, the empty
            one (0 triangles): check that first when the result must be a mesh.
        monotone: ``"check"`` (default: PlodError on violation), ``"repair"`` (use the monotone
            envelope, :func:`repair_monotone`) or ``"trust"`` (no check: the caller promises monotone
            keys; with non-monotone keys the result is the sorted prefix, which differs from the heap
            greedy and need not be closed under ancestors, i.e. is not a cut).

    Returns:
        :class:`Cut`, identical to :func:`budget_cut_heap` for monotone keys.
    """
    budget = _check_budget(budget)
    k, ki = _prepare_keys(tree, keys, monotone, "budget_cut")
    internal = tree.internal
    M = internal.size
    unfolded = np.zeros(tree.n_nodes, dtype=bool)
    if M == 0:
        return Cut(unfolded, 0, 0.0, "all_unfolded")
    w = _internal_subtris(tree)
    total = int(tree.n_triangles)
    if total <= budget:
        unfolded[internal] = True
        return Cut(unfolded, total, 0.0, "all_unfolded")
    # weighted radix selection on 32-bit codes, 16 bits per pass from the top: find the item (order:
    # key desc, index asc) at which the running triangle sum first exceeds the budget. float64 keys
    # are rounded to float32 for the passes (rounding is monotone, so a strictly smaller 32-bit code
    # means a strictly larger key); the final candidates are ordered by their exact keys.
    code = _desc_rank_bits(ki if ki.dtype == np.float32 else ki.astype(np.float32))
    cand = None  # None = all items
    base = 0.0
    for shift in (16, 0):
        cc = code if cand is None else code.take(cand)
        wc = w if cand is None else w.take(cand)
        b = ((cc >> np.uint32(shift)) & np.uint32(0xFFFF)).astype(np.intp)
        cum = np.cumsum(np.bincount(b, weights=wc, minlength=65536))
        j = int(np.searchsorted(cum, budget - base, side="right"))  # first bucket whose running sum > budget
        if j > 0:
            base += float(cum[j - 1])
        sel = np.flatnonzero(b == j)
        cand = sel if cand is None else cand.take(sel)
        if cand.size <= 4096:
            break
    # exact order among the candidates (cand is ascending in index already)
    cs = cand[np.lexsort((cand, _desc_rank_bits(ki.take(cand))))]
    run = base + np.cumsum(w.take(cs), dtype=np.float64)
    m = int(np.searchsorted(run, budget, side="right"))  # cs[m] is the first that does not fit
    stop = int(cs[m])
    unfolded = k > ki[stop]  # everything with a greater key than the stop's ...
    unfolded &= _is_internal(tree)
    unfolded[internal.take(cs[:m])] = True  # ... and the candidates before it (its ties of lower index)
    tri = int(run[m - 1]) if m > 0 else int(base)
    return Cut(unfolded, tri, float(ki[stop]), "budget")


def _is_internal(tree) -> np.ndarray:
    return tree.derived("cut.is_internal", lambda: tree.child_count > 0)


def _internal_subtris(tree) -> np.ndarray:
    return tree.derived("cut.internal_subtris", lambda: tree.num_subtris[tree.internal].astype(np.float64))


def _check_budget(budget) -> int:
    """A budget as a Python int: integers (Python or NumPy) and integral finite floats >= 0.

    bool (an int subclass: ``True`` would be 1), NaN, infinities, fractions, strings and negative
    numbers raise :class:`PlodError`."""
    if isinstance(budget, (bool, np.bool_)):
        raise PlodError(f"budget must be an integer number of triangles, got the bool {budget!r}")
    if isinstance(budget, (int, np.integer)):
        b = int(budget)
    elif isinstance(budget, (float, np.floating)):
        if not np.isfinite(budget) or float(budget) != np.floor(budget):
            raise PlodError(f"budget must be an integer number of triangles, got {budget!r}")
        b = int(budget)
    else:
        raise PlodError(f"budget must be an integer number of triangles, got {type(budget).__name__} {budget!r}")
    if b < 0:
        raise PlodError(f"budget must be a non-negative integer number of triangles, got {budget!r}")
    return b


def min_nonempty_budget(tree, keys, *, monotone: str = "check") -> int:
    """The smallest budget for which :func:`budget_cut` with these keys gives at least one triangle.

    With nothing unfolded a cut has ``0`` triangles (unfolding the root alone may add none either),
    and the greedy stops at the first fold that does not fit, so a budget below the subtris of the
    first fold (in greedy order) that adds triangles gives the empty cut, whose extracted mesh is
    empty (``save_mesh`` refuses to write it). Returns 0 for a tree without triangles.
    """
    k, ki = _prepare_keys(tree, keys, monotone, "min_nonempty_budget")
    w = _internal_subtris(tree)
    pos = np.flatnonzero(w > 0)
    if pos.size == 0:
        return 0
    kp = ki.take(pos)
    first = pos[np.flatnonzero(kp == kp.max())[0]]  # greatest key, lowest index (pos is ascending)
    return int(w[first])


def budget_cut_heap(tree, keys, budget: int, *, monotone: str = "check") -> Cut:
    """Reference greedy triangle-budget cut with ``heapq`` (VDSlib's budget mode [LH01 §5.3]).

    Pops the boundary node with the greatest key (ties: lower index first), unfolds it while its
    subtris fit, stops at the first that does not. O(n log n) in Python: for tests and benchmarks.
    """
    budget = _check_budget(budget)
    k, _ = _prepare_keys(tree, keys, monotone, "budget_cut_heap")
    N = tree.n_nodes
    unfolded = np.zeros(N, dtype=bool)
    cc, cst, ns = tree.child_count, tree.child_start, tree.num_subtris
    heap = [(-float(k[0]), 0)] if cc[0] > 0 else []
    tri = 0
    while heap:
        nk, n = heap[0]
        if tri + int(ns[n]) > budget:
            return Cut(unfolded, tri, -nk, "budget")
        heapq.heappop(heap)
        unfolded[n] = True
        tri += int(ns[n])
        for c in range(int(cst[n]), int(cst[n]) + int(cc[n])):
            if cc[c] > 0:
                heapq.heappush(heap, (-float(k[c]), c))
    return Cut(unfolded, tri, 0.0, "all_unfolded")


def threshold_cut(tree, keys, threshold: float = 1.0, *, monotone: str = "check") -> Cut:
    """Unfold every internal node whose key exceeds ``threshold`` (with its ancestors: top-down).

    For perceptual keys and threshold 1 this is the imperceptible simplification of
    [LH01 §5.1]: every remaining fold is invisible from the current viewpoint.
    """
    try:
        thr = float(threshold)
    except (TypeError, ValueError):
        raise PlodError(f"threshold_cut: threshold must be a number, got {threshold!r}") from None
    if np.isnan(thr):
        raise PlodError("threshold_cut: threshold is NaN")
    k, ki = _prepare_keys(tree, keys, monotone, "threshold_cut")
    internal = tree.internal
    unfolded = np.zeros(tree.n_nodes, dtype=bool)
    if internal.size == 0:
        return Cut(unfolded, 0, 0.0, "all_unfolded")
    take = ki > thr
    if monotone == "trust":  # close under ancestors explicitly
        unfolded[internal[take]] = True
        tree.levels.spread_down(unfolded, np.logical_and)
        take = unfolded[internal]
    else:
        unfolded[internal[take]] = True
    tri = int(tree.num_subtris[internal[take]].sum())
    if take.all():
        return Cut(unfolded, tri, 0.0, "all_unfolded")
    par_unf = np.ones(internal.size, dtype=bool)
    par_unf[internal != 0] = unfolded[tree.parent[internal[internal != 0]]]
    bnd = ~take & par_unf
    return Cut(unfolded, tri, float(ki[bnd].max()), "imperceptible")


def extract(tree, cut, normals: str | None = None):
    """The simplified mesh of a cut.

    Each input vertex is replaced by its representative, the highest folded node above it (its
    proxy position and colour; leaves give back the input vertex exactly); the triangles kept are
    those whose owner node is unfolded. Vertices come in the order of the smallest input vertex each
    represents, triangles in input order, so unfolding everything returns the input mesh exactly.

    Args:
        tree: :class:`optim.VertexTree`; cut: a :class:`Cut` or an (N,) bool ``unfolded`` array (its
            leaves' entries are ignored: a leaf has nothing to unfold). An array not closed under
            ancestors is not a cut; it is accepted with the same rule (each vertex takes the highest
            folded node above it), but its mesh may fold over itself (:func:`optim.cut_flips`).
        normals: None, or the vertex normals the mesh carries for a renderer that relights it
            (:mod:`optim._normals`): ``"region"``, each vertex the mean normal of the input surface its
            node stands for [Coh98]; ``"faces"``, recomputed from the cut's faces (what a renderer does
            for a mesh without normals).

    Returns:
        ``(vertices (V', 3) float64, faces (T', 3) int32, colors (V', 3) float32 or None)``, and with
        ``normals`` a fourth element, ``(V', 3) float64`` unit vertex normals.

    Where the process may use two or more cores, independent parts (the kept triangles and the boundary;
    half of the corners; the vertex positions and the faces) run at once on a side thread
    (:mod:`optim._parallel`), with the same result.
    """
    from ._normals import check_normals, cut_normals

    check_normals(normals, "extract")
    v, f, c, _, nodes, rows = _extract_parts(tree, _unfolded_mask(tree, cut), normals == "region")
    if normals is None:
        return v, f, c
    return v, f, c, cut_normals(tree, v, f, nodes, normals, rows)


def _extract_parts(tree, unf, region: bool = False):
    """:func:`extract` of a checked (N,) bool ``unfolded``, the input triangle of each output face and the
    node of each output vertex: ``(vertices, faces, colors, keep (T',) intp ascending, nodes (V',), rows)``,
    ``faces[i]`` being input triangle ``keep[i]`` with its corners replaced by their representatives
    (shared with :mod:`optim._flips`); ``rows``: with ``region``, the nodes' rows of
    :func:`optim.region_normals` (float32), else None."""
    parts = _boundary_corners(tree, unf)
    if parts is None:  # not closed under ancestors
        return _reference_parts(tree, unf) + (None,)
    return _mesh_from_boundary(tree, *parts, region=region)


def _mesh_from_boundary(tree, bnd, fb, keep, rep=None, region: bool = False):
    """Second stage of :func:`extract`: the mesh ``(vertices, faces, colors, keep, nodes, rows)`` of
    :func:`_boundary_corners`'s arrays (the boundary nodes, ordered by their name, the smallest input
    vertex each represents: the used ones, in the same order, are the output vertices). ``rep``:
    :func:`_representatives` of ``bnd`` when already made; ``region``: also the nodes' region normal rows
    (gathered on this thread while the side thread makes the positions), else ``rows`` is None."""
    nb = bnd.size
    used = np.zeros(nb, dtype=bool)
    used[fb.ravel()] = True
    srt = np.flatnonzero(used)  # used ids, by name
    nodes = bnd.take(srt)
    drawn = beside(_drawn_vertices, tree, nodes, None if rep is None else _take_rows(rep, srt))  # side thread
    newidx = np.empty(nb, dtype=np.int32)  # read only at used boundary ids
    newidx[srt] = np.arange(srt.size, dtype=np.int32)
    faces = newidx.take(fb)
    rows = None
    if region:
        from ._normals import region_normals

        rows = _take_rows(region_normals(tree), nodes)
    verts, colors = drawn.result()
    return verts, faces, colors, keep, nodes, rows


def _drawn_vertices(tree, nodes, verts=None):
    """Positions (:func:`_representatives`, unless given as ``verts``) and colours (or None) of the nodes
    a cut draws; leaves keep the input vertex and colour exactly."""
    if verts is None:
        verts = _representatives(tree, nodes)
    colors = None
    if tree.color is not None:
        colors = tree.color.take(nodes, axis=0)
        if tree.colors is not None:
            leaf = np.flatnonzero(tree.child_count.take(nodes) == 0)  # leaves keep the input colour exactly
            colors[leaf] = tree.colors.take(tree.min_vertex.take(nodes.take(leaf)), axis=0)
    return verts, colors


def _boundary_corners(tree, unf):
    """First stage of :func:`extract`: ``(bnd, fb, keep)``, the highest folded nodes ``bnd`` (nb,) ordered
    by name (the smallest input vertex each represents), the boundary id of each corner of the kept
    triangles ``fb`` (T', 3) int32 and those triangles ``keep`` (T',) ascending; None when ``unf`` is not
    closed under ancestors (the boundary nodes' leaf ranges do not tile 0..V-1).

    Work proportional to the cut, plus a few O(V) fills: the kept triangles are the subtris of the
    unfolded nodes (contiguous per node); the highest folded nodes (folded, parent unfolded) are the
    folded children of unfolded nodes. Their depth-first leaf ranges tile 0..V-1, so a running maximum
    of the range starts maps every leaf position to the start of its range, and that start to its node.
    Ordering the nodes by name here, not by leaf position, makes the output's vertex order free."""
    corner_lp, sub_start, subtris = _extract_index_fast(tree)
    U = np.flatnonzero(unf)
    # the kept triangles on the side thread (optim._parallel), the boundary on this one
    kept = beside(_kept_triangles, U, sub_start, subtris, tree.num_subtris, tree.n_triangles)
    tiling = _boundary_tiling(tree, unf, U)
    keep = kept.result()
    if tiling is None:
        return None
    bnd, start, node_at = tiling
    return bnd, _corner_ids(corner_lp, keep, start, node_at), keep


def _kept_triangles(U, sub_start, subtris, num_subtris, T) -> np.ndarray:
    """The triangles (ascending intp) whose owner is one of the unfolded nodes ``U``: their subtris."""
    if not U.size:
        return np.zeros(0, dtype=np.intp)
    return _ascending(subtris.take(expand_ranges(sub_start.take(U), num_subtris.take(U))), T)


def _boundary_tiling(tree, unf, U):
    """The boundary nodes of :func:`_boundary_corners` ordered by name, with the (V,) int32 maps of a
    leaf position to the start of the range holding it (``start``) and of a range start to its boundary
    id (``node_at``, read only at starts); None when their ranges do not tile 0..V-1."""
    V = tree.n_vertices
    if U.size:
        bnd = expand_ranges(tree.child_start.take(U), tree.child_count.take(U))
        bnd = bnd[~unf.take(bnd)]
    else:
        bnd = np.zeros(1, dtype=np.intp)
    nb = bnd.size
    order = _order_of_distinct(tree.min_vertex.take(bnd), V)  # by name
    if order.size != nb:  # two boundary nodes with one name: nested, not closed
        return None
    bnd = bnd.take(order)
    lo, hi = tree.leaf_lo.take(bnd), tree.leaf_hi.take(bnd)
    if int((hi - lo).sum()) != V:
        return None
    start = np.zeros(V, dtype=np.int32)  # start of the range holding each leaf position
    start[lo] = lo
    np.maximum.accumulate(start, out=start)
    node_at = np.empty(V, dtype=np.int32)  # boundary id at each range start (read only there)
    ids = np.arange(nb, dtype=np.int32)
    node_at[lo] = ids
    # a tiling: distinct starts (no id overwritten), none inside another range (the last leaf of each
    # range maps back to its own start), lengths summing to V (then the disjoint ranges cover 0..V-1)
    if not (np.array_equal(node_at.take(lo), ids) and np.array_equal(start.take(hi - 1), lo)):
        return None
    return bnd, start, node_at


def _corner_ids(corner_lp, keep, start, node_at) -> np.ndarray:
    """(T', 3) int32 boundary id of each corner of the kept triangles; the first half of the rows on the
    side thread (optim._parallel)."""
    fb = np.empty((keep.size, 3), dtype=np.int32)

    def rows(a, b):
        np.take(node_at, start.take(_take_rows(corner_lp, keep[a:b])), out=fb[a:b])

    h = keep.size // 2
    first = beside(rows, 0, h)
    rows(h, keep.size)
    first.result()
    return fb


def _representatives(tree, nodes) -> np.ndarray:
    """(k, 3) positions of the nodes a cut draws (input vertices for leaves, proxies otherwise), in the
    input vertices' dtype."""
    verts = _take_rows(tree.position, nodes).astype(tree.vertices.dtype)
    if tree.origin.any():  # proxies are stored relative to the tree's origin
        verts += tree.origin
    leaf = np.flatnonzero(tree.child_count.take(nodes) == 0)  # leaves give back the input vertex exactly
    verts[leaf] = tree.vertices.take(tree.min_vertex.take(nodes.take(leaf)), axis=0)
    return verts


def _ascending(idx: np.ndarray, n: int) -> np.ndarray:
    """Distinct integers ``idx`` in [0, n) in ascending order: a sort when they are few (under n / 64),
    else a (n,) mask and its nonzero positions (O(n); measured on 2 cores: 100k kept of 1M triangles, 2.3
    ms sorting the subtris of the unfolded nodes against 1.0 ms by mask)."""
    if idx.size * 64 < n:
        return np.sort(idx)
    mask = np.zeros(n, dtype=bool)
    mask[idx] = True
    return np.flatnonzero(mask)


def _order_of_distinct(vals: np.ndarray, n: int) -> np.ndarray:
    """(k,) intp or int32: the permutation sorting the integers ``vals`` (k,) in [0, n) ascending, when they are
    distinct (repeated values: fewer than k positions, one per value; argsort keeps them all)."""
    if vals.size * 64 < n:
        return np.argsort(vals, kind="stable")
    seen = np.zeros(n, dtype=bool)
    seen[vals] = True
    slot = np.empty(n, dtype=np.int32)  # read only where seen
    slot[vals] = np.arange(vals.size, dtype=np.int32)
    return slot[seen]  # shorter than vals when they repeat


def _take_rows(a: np.ndarray, idx) -> np.ndarray:
    """``a.take(idx, axis=0)`` for a C-contiguous (n, k) array, as one gather of k-element records
    (numpy's take along axis 0 copies row by row, about 1.3x slower)."""
    rec = np.ascontiguousarray(a).view(np.dtype((np.void, a.dtype.itemsize * a.shape[1]))).reshape(-1)
    return rec.take(idx).view(a.dtype).reshape(-1, a.shape[1])


def _unfolded_mask(tree, cut, who: str = "extract") -> np.ndarray:
    """The (N,) bool ``unfolded`` array of a :class:`Cut` or of the array itself (checked). A leaf has
    nothing to unfold, so an array's entries for leaves are ignored (an all-True array is the whole mesh;
    before, each leaf marked unfolded lost its vertex and the mesh collapsed to one point)."""
    _check_tree(tree, who)
    if isinstance(cut, Cut):
        unf = np.asarray(cut.unfolded)
    else:
        try:
            unf = np.asarray(cut)
        except (TypeError, ValueError):
            unf = np.zeros(0)
    N = tree.n_nodes
    if unf.shape != (N,) or unf.dtype != np.bool_:
        raise PlodError(f"{who}: unfolded must be a bool array of shape ({N},), got {unf.dtype} {unf.shape}")
    if not isinstance(cut, Cut):  # a Cut of this module never marks a leaf
        internal = _is_internal(tree)
        if np.any(unf > internal):
            unf = unf & internal
    return unf


def _extract_index_fast(tree):
    """Per-tree arrays of :func:`extract` (cached on the tree): the depth-first leaf position of each
    triangle corner (T, 3) int32, ``subtri_start`` (N+1,) and ``subtris`` (T,) as intp-free int32."""
    def build():
        lp = tree.leaf_lo.take(tree.vertex_node).astype(np.int32)
        return lp.take(tree.faces), np.asarray(tree.subtri_start), np.asarray(tree.subtris)

    return tree.derived("cut.extract_index_fast", build)


def _extract_reference(tree, cut):
    """Reference form of :func:`extract` (every node, vertex and triangle, O(N + V + T) per call);
    the tests check that :func:`extract` returns the identical arrays."""
    return _reference_parts(tree, _unfolded_mask(tree, cut))[:3]


def _reference_parts(tree, unf):
    """:func:`_extract_reference` plus ``keep`` and ``nodes``, as :func:`_extract_parts` returns them."""
    V = tree.n_vertices
    # highest folded nodes (folded, parent unfolded): each leaf lies under exactly one; their
    # depth-first leaf ranges tile 0..V-1, so a forward fill maps every leaf position to its node
    parent, tri_node, vdfs = _extract_index(tree)
    pu = unf.take(parent)
    pu[0] = True
    bnd = np.flatnonzero(pu & ~unf)
    lo = tree.leaf_lo.take(bnd)
    fill = np.zeros(V, dtype=np.intp)
    fill[lo] = lo
    np.maximum.accumulate(fill, out=fill)
    canon = np.zeros(V, dtype=np.intp)
    canon[lo] = tree.min_vertex.take(bnd)  # a cluster is named by its smallest input vertex
    node_at = np.zeros(V, dtype=np.intp)
    node_at[lo] = bnd
    repv = canon.take(fill).take(vdfs)  # (V,) canonical vertex of each input vertex
    keep = np.flatnonzero(unf.take(tri_node))
    fr = repv.take(tree.faces.take(keep, axis=0))  # (T', 3) canonical vertex ids
    used = np.zeros(V, dtype=bool)
    used[fr.ravel()] = True
    out_v = np.flatnonzero(used)
    newidx = np.cumsum(used, dtype=np.int32) - 1
    faces = newidx.take(fr)
    nodes = node_at.take(fill.take(vdfs.take(out_v)))
    verts = tree.vertices.take(out_v, axis=0)  # right for leaves (a leaf's canonical vertex is its own)
    inner = np.flatnonzero(tree.child_count.take(nodes))
    verts[inner] = tree.position.take(nodes.take(inner), axis=0) + tree.origin
    colors = None
    if tree.color is not None:
        colors = tree.colors.take(out_v, axis=0) if tree.colors is not None else tree.color.take(nodes, axis=0)
        colors[inner] = tree.color.take(nodes.take(inner), axis=0)
    return verts, faces, colors, keep, nodes


def _extract_index(tree):
    """``parent`` (N,), ``tri_node`` (T,) and the depth-first leaf position of each vertex (V,) intp,
    which :func:`extract` needs every view (cached on the tree: 8 bytes per vertex)."""
    return tree.derived("cut.extract_index", lambda: (tree.parent, tree.tri_node,
                                                       tree.leaf_lo.take(tree.vertex_node).astype(np.intp)))


def imperceptible_cut(tree, view, model=None, *, exact: bool = False) -> Cut:
    """Fold every node whose fold is imperceptible from ``view``, top down [LHNW00 §4; LH01 §5.1]:
    :func:`threshold_cut` at key 1 of the perceptual keys of :func:`optim.score`, ``stop_reason``
    ``"imperceptible"`` (or ``"all_unfolded"`` when no fold is imperceptible)."""
    from ._score import score

    return threshold_cut(tree, score(tree, view, model, "perceptual", exact=exact), 1.0, monotone="trust")

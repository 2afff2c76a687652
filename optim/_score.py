"""Per-view scoring of every fold of a vertex tree (stage 3 of optim), and the imperceptible cut.

``score(tree, view, model, metric)`` returns one key per node, larger = more important to keep the node
unfolded, made monotone (a parent's key is at least its children's, Luebke & Hallen 2001 [seed 004],
footnote 2). Units of the keys:

* ``"perceptual"``: the imperceptible distance of the fold (seed 004 section 5.3), a multiple of the
  current viewing distance: ``k <= 1`` means the fold cannot be seen from here.
* ``"size"``: projected bounding-sphere diameter, pixels (VDSlib's default criterion).
* ``"geometric"``: projected object-space fold error (``tree.geom_error``, largest distance from a
  supported vertex to the proxy), pixels, at the nearest point of the node's bounding sphere.

Stages 1-6 are jitted XLA programs over all internal nodes (flat arrays; leaves have nothing to fold
and get 0), per view. They run as three programs (``_facing_kernel``, ``_key_terms``,
``_table_lookup``) rather than one: fused together, XLA:CPU recomputes shared per-node arithmetic
inside scalar gather loops and measured about 1.5-2x slower.

1. ``_facing_flags`` / ``_terms``: sphere-frustum test and wholly-back-facing test (normal masks
   against a per-direction table, made conservative for perspective by the node's angular radius);
   culled nodes and their whole subtrees are folded (key 0).
2. ``_extent``: angular size of the bounding sphere -> ``theta`` (deg of the viewer's visual field;
   the fold's lowest frequency is ``1 / (2 theta)`` cycles/deg, seed 004 section 3.1).
3. ``_eccentricity``: angle (deg) between the node's image and the nearest gaze point minus half of
   ``theta`` minus the gaze uncertainty, clamped at 0 (Luebke et al. 2000 [seed 001] section 4.4);
   skipped (0) when the view has no gaze.
4. ``_velocity``: retinal velocity (deg/s) of the node's image from the previous view; skipped (0)
   when the view has no previous view.
5. ``_contrast``: Michelson contrast of display luminances (cd/m2): the fold's own luminance change
   ``fold_delta`` above the node's darkest value for front-facing nodes; for silhouette nodes (normal
   mask overlapping both the possibly-front-facing and the possibly-back-facing cells, seed 001
   section 4.3) the node's luminance range against the scene's brightest and darkest values,
   background included (seed 001 section 4.2, seed 004 section 5.2).
6. key: ``model.imperceptible_distance(c, theta, e, v)`` (``exact=True`` or with motion), else a
   per-model table ``theta * K(c, e / theta)`` read on the conservative side; or the pixel keys.
7. ``monotone``: maximum propagated from the deepest level up, and culling propagated down (two
   O(N) numpy passes over the breadth-first levels, ``np.maximum.reduceat`` per level).

Table mode (perceptual keys without motion, the default) runs one XLA program per chunk
(``_split_terms``: table-word positions, key-table indices for the front-facing and silhouette
contrasts, theta, frustum cull) and does both table gathers in numpy (``_fast_table_keys``): XLA:CPU
fuses index arithmetic into gather loops as scalar code. Chunks are padded to a multiple of 1024 nodes
(odd lengths ran ~6x slower per node). The max propagation uses one gather per child slot.

Per-tree device arrays (breadth-first order, compacted normal masks) are built once:
:func:`scoring_context` caches them on the tree. Speed (2-core CPU, 796k-triangle mesh, 398k internal
nodes): about 20-30 ms per view; see ``reports/bench_optim.md``.
"""

from __future__ import annotations

import functools
import math
import weakref
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["score", "imperceptible_cut", "node_terms", "scoring_context", "ScoringContext", "NodeTerms",
           "METRICS"]

METRICS = ("perceptual", "size", "geometric")

#: projected sizes are capped at this many image heights (a node around the eye covers everything)
_SIZE_CAP_IMAGES = 16.0
#: extra angular margins (deg) of the silhouette table, chosen per node by its angular radius
_MARGINS_DEG = (0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 90.0)
#: direction bins per cube-face side for the per-node view direction
_DIR_BINS = 16
#: internal nodes per chunk of the per-view programs (1 MiB float32 columns)
_CHUNK = 262144
#: child-group sizes up to this use fixed-arity gathers in the max propagation (else reduceat)
_MAX_ARITY = 8
#: chunk lengths are padded to a multiple of this many nodes (vectorised XLA loops)
_PAD = 1024


# =============================================================================== stage 0: normal cube
def _cube_face_uv(d: np.ndarray):
    """Unit-ish vectors (..., 3) -> (face 0..5 = +x,-x,+y,-y,+z,-z, u, v in [-1, 1])."""
    ad = np.abs(d)
    axis = np.argmax(ad, axis=-1)
    comp = np.take_along_axis(d, axis[..., None], -1)[..., 0]
    face = 2 * axis + (comp < 0)
    others = np.array([[1, 2], [0, 2], [0, 1]])[axis]
    m = np.maximum(np.abs(comp), 1e-30)
    u = np.take_along_axis(d, others[..., :1], -1)[..., 0] / m
    v = np.take_along_axis(d, others[..., 1:], -1)[..., 0] / m
    return face, u, v


def _fallback_cell(normals: np.ndarray) -> np.ndarray:
    """Normal-cube cell (0..383) of unit normals (..., 3): 6 faces x 8 x 8 cells (seed 001 section 4.3)."""
    face, u, v = _cube_face_uv(np.asarray(normals, np.float64))
    i = np.clip(np.floor((u + 1) * 4), 0, 7).astype(np.int64)
    j = np.clip(np.floor((v + 1) * 4), 0, 7).astype(np.int64)
    return face * 64 + j * 8 + i


@functools.lru_cache(maxsize=1)
def _cell_layout():
    """(cell function normals -> cell index 0..383, bit function cell -> (byte, bit value)).

    Uses the tree builder's normal-cube layout when ``optim._tree`` exposes one, so the masks this
    module builds agree bit for bit with ``tree.normal_mask``; else the layout of :func:`_fallback_cell`
    with bit ``cell % 8`` (LSB first) of byte ``cell // 8``.
    """
    try:
        from . import _tree  # noqa: F401

        cell_fn = getattr(_tree, "normal_cells", None)
        bit_fn = None  # _tree documents the same bit order: byte cell // 8, bit cell % 8
    except ImportError:
        cell_fn = bit_fn = None
    if cell_fn is None:
        cell_fn = _fallback_cell
    if bit_fn is None:
        def bit_fn(cell):
            cell = np.asarray(cell)
            return cell // 8, (1 << (cell % 8)).astype(np.uint8)
    return cell_fn, bit_fn


def _sample_sphere(per_side: int) -> np.ndarray:
    """Unit vectors sampling the sphere through a (6, per_side, per_side) cube-face grid, edges included."""
    t = np.linspace(-1.0, 1.0, per_side)
    u, v = np.meshgrid(t, t, indexing="ij")
    u, v, one = u.ravel(), v.ravel(), np.ones(u.size)
    faces = [np.stack(x, -1) for x in ((one, u, v), (-one, u, v), (u, one, v), (u, -one, v), (u, v, one), (u, v, -one))]
    d = np.concatenate(faces)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def _cones(dirs: np.ndarray, labels: np.ndarray, n: int, pad_deg: float):
    """Axis (n, 3) and angular radius (n,) deg (+ pad) of the direction samples in each label."""
    sums = np.zeros((n, 3))
    np.add.at(sums, labels, dirs)
    axes = sums / np.maximum(np.linalg.norm(sums, axis=-1, keepdims=True), 1e-30)
    ang = np.degrees(np.arccos(np.clip(np.sum(dirs * axes[labels], -1), -1, 1)))
    rad = np.zeros(n)
    np.maximum.at(rad, labels, ang)
    return axes, rad + pad_deg


def _dir_bin_np(d: np.ndarray) -> np.ndarray:
    face, u, v = _cube_face_uv(d)
    q = _DIR_BINS
    i = np.clip(np.floor((u + 1) * (q / 2)), 0, q - 1).astype(np.int64)
    j = np.clip(np.floor((v + 1) * (q / 2)), 0, q - 1).astype(np.int64)
    return face * q * q + j * q + i


@functools.lru_cache(maxsize=4)
def _silhouette_table_cached(layout_key) -> np.ndarray:
    cell_fn, bit_fn = _cell_layout()
    samples = _sample_sphere(97)
    spacing = 2.0 / 96 * 57.3  # deg between neighbouring samples at a face centre (upper bound)
    cell_axes, cell_rad = _cones(samples, np.asarray(cell_fn(samples)), 384, spacing)
    nb = 6 * _DIR_BINS * _DIR_BINS
    bin_axes, bin_rad = _cones(samples, _dir_bin_np(samples), nb, spacing)
    ang = np.degrees(np.arccos(np.clip(bin_axes @ cell_axes.T, -1, 1)))  # (nb, 384)
    slack = cell_rad[None, :] + bin_rad[:, None]
    byte, bit = bit_fn(np.arange(384))
    table = np.zeros((len(_MARGINS_DEG), nb, 2, 48), np.uint8)
    for li, m in enumerate(_MARGINS_DEG):
        front = ang - slack - m < 90.0  # some normal of the cell may face some point's eye direction
        back = ang + slack + m > 90.0
        for k, sel in enumerate((front, back)):
            rows, cells = np.nonzero(sel)
            np.bitwise_or.at(table[li, :, k], (rows, byte[cells]), bit[cells])
    return table.reshape(len(_MARGINS_DEG) * nb, 2, 48).view("<u4").reshape(-1, 24)


def silhouette_table() -> np.ndarray:
    """(len(margins) * 6 * 16 * 16, 24) uint32: per (margin, view-direction bin) the possibly-front-facing
    (words 0..11) and possibly-back-facing (words 12..23) normal-cube cells, as packed 48-byte masks
    (Zhang & Hoff's normal masks as used by seed 001 section 4.3, made conservative for perspective)."""
    cell_fn, bit_fn = _cell_layout()
    return _silhouette_table_cached((id(cell_fn), id(bit_fn)))


# =============================================================================== stage 1: per-tree context
class _Chunk(eqx.Module):
    """Device arrays of up to ``_CHUNK`` internal nodes (breadth-first order): flat float32 columns
    ``cx, cy, cz`` bounding-sphere centre and ``radius`` (object units), ``lum_min``, ``lum_max``,
    ``fold_delta`` (relative luminance), ``geom_error`` (object units); normal masks (48 bytes = 12
    uint32 words) as ``word_idx``, ``word_val`` (C, 2): the (up to) two nonzero words of each mask,
    ``wide`` (W,) positions of masks with more nonzero words and ``wide_mask`` (W, 12) their full
    masks; ``nonempty`` (C,) bool."""

    cx: jax.Array
    cy: jax.Array
    cz: jax.Array
    radius: jax.Array
    lum_min: jax.Array
    lum_max: jax.Array
    fold_delta: jax.Array
    geom_error: jax.Array
    word_idx: jax.Array
    word_val: jax.Array
    wide: jax.Array
    wide_mask: jax.Array
    nonempty: jax.Array


class ScoringContext:
    """Per-tree data of :func:`score`, built once by :func:`scoring_context` (cached on the tree).

    Only the M internal nodes are kept (a leaf has nothing to fold: its key is 0), in breadth-first
    order with children grouped by parent, split into ``chunks`` (:class:`_Chunk`) of ``_CHUNK``
    nodes: on arrays of more than about 2 MB XLA:CPU's per-element cost measured several times
    higher, so each per-view program runs once per chunk. ``passes`` holds the numpy index arrays of
    the two tree passes (culling down, maximum up); ``m`` is M; ``scene_lum`` the darkest and
    brightest relative luminance of the model.
    """

    def __init__(self, chunks, passes, m, scene_lum):
        self.chunks, self.passes, self.m, self.scene_lum = tuple(chunks), passes, m, scene_lum


class _TreePasses:
    """numpy index arrays for the hierarchical passes over the M internal nodes (breadth-first order).

    ``parent`` (M,) position of the parent (-1 for the root); ``levels`` start of each depth level;
    ``groups[k]`` for level k >= 1: (positions of the level-(k-1) parents that have internal children,
    start offsets of their child groups within the level); ``node`` (M,) tree index; ``n_nodes`` N.
    Hashed by identity (it is a static field of the jitted context)."""

    def __init__(self, parent, levels, node, n_nodes):
        self.parent, self.levels, self.node, self.n_nodes = parent, levels, node, n_nodes
        self.groups = [None]
        for k in range(1, len(levels) - 1):
            a, b = levels[k], levels[k + 1]
            p = parent[a:b]
            start = np.flatnonzero(np.r_[True, p[1:] != p[:-1]]) if b > a else np.zeros(0, np.int64)
            self.groups.append((p[start], start))
        self.sorted_nodes = bool(np.all(np.diff(node) > 0))
        # fixed-arity form of the same groups (``monotone``): per level, the parents' positions and
        # (A, P) child positions, short groups padded with their first child (max is idempotent).
        # ``np.maximum.reduceat`` pays a per-group overhead that dominates on binary trees.
        self.slots = [None]
        for k in range(1, len(levels) - 1):
            pids, starts = self.groups[k]
            if not len(pids):
                self.slots.append(None)
                continue
            a, b = levels[k], levels[k + 1]
            cnt = np.diff(np.r_[starts, b - a])
            arity = int(cnt.max())
            if arity > _MAX_ARITY:
                self.slots.append(None)  # reduceat for this level
                continue
            pos = a + starts
            sl = np.stack([pos + np.minimum(j, cnt - 1) for j in range(arity)]).astype(np.intp)
            self.slots.append((pids.astype(np.intp), sl))

    def propagate_culled(self, culled: np.ndarray) -> np.ndarray:
        """A culled node culls its whole subtree (top down, one gather per level)."""
        c = np.array(culled, dtype=bool)
        lv, par = self.levels, self.parent
        for k in range(1, len(lv) - 1):
            a, b = lv[k], lv[k + 1]
            c[a:b] |= c[par[a:b]]
        return c

    def monotone(self, key: np.ndarray) -> np.ndarray:
        """key[parent] = max(key[parent], max key[children]), deepest level first (seed 004 footnote 2).

        In place; identical to :meth:`monotone_reduceat` (max is exact), with one gather per child slot."""
        lv = self.levels
        for k in range(len(lv) - 2, 0, -1):
            sl = self.slots[k]
            if sl is None:
                pids, starts = self.groups[k]
                if len(pids):
                    sub = key[lv[k]:lv[k + 1]]
                    key[pids] = np.maximum(key[pids], np.maximum.reduceat(sub, starts))
                continue
            pids, child = sl
            m = key.take(pids)
            for row in child:
                np.maximum(m, key.take(row), out=m)
            key[pids] = m
        return key

    def monotone_reduceat(self, key: np.ndarray) -> np.ndarray:
        """Reference form of :meth:`monotone`: ``np.maximum.reduceat`` over each level's child groups."""
        lv = self.levels
        for k in range(len(lv) - 2, 0, -1):
            pids, starts = self.groups[k]
            if len(pids):
                sub = key[lv[k]:lv[k + 1]]
                key[pids] = np.maximum(key[pids], np.maximum.reduceat(sub, starts))
        return key

    def to_tree(self, vals: np.ndarray, fill=0) -> np.ndarray:
        """Internal-node values (M,) -> tree order (N,), ``fill`` at the leaves."""
        out = np.full(self.n_nodes, fill, dtype=vals.dtype)
        out[self.node] = vals
        return out


_FIELDS = ("parent", "child_start", "child_count", "center", "radius", "lum_min", "lum_max",
           "fold_delta", "geom_error", "normal_mask")
_CONTEXTS: dict = {}


def _check_tree(tree) -> int:
    missing = [f for f in _FIELDS if getattr(tree, f, None) is None]
    if missing:
        raise ValueError(f"score: the tree lacks the field(s) {', '.join(missing)} (expected an optim.VertexTree)")
    n = len(np.asarray(tree.parent))
    if n == 0:
        raise ValueError("score: the tree has no nodes")
    for f in _FIELDS:
        a = np.asarray(getattr(tree, f))
        want = {"center": (n, 3), "normal_mask": (n, 48)}.get(f, (n,))
        if a.shape != want:
            raise ValueError(f"score: tree.{f} has shape {a.shape}, expected {want}")
    return n


def _level_order(parent, child_start, child_count):
    """Breadth-first order of the nodes: (order (N,) tree indices, depth (N,) of each entry)."""
    n = len(parent)
    roots = np.flatnonzero(parent < 0)
    if len(roots) != 1 or roots[0] != 0:
        raise ValueError(f"score: the tree must have exactly one root, node 0 (found roots {roots[:5].tolist()})")
    order, depth = [np.array([0], np.int64)], [np.zeros(1, np.int64)]
    total = 1
    while True:
        cur = order[-1]
        cnt = child_count[cur].astype(np.int64)
        if cnt.sum() == 0:
            break
        starts = np.repeat(child_start[cur].astype(np.int64), cnt)
        nxt = starts + np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        order.append(nxt)
        depth.append(np.full(len(nxt), len(depth)))
        total += len(nxt)
        if total > n:
            raise ValueError("score: the tree's child ranges are inconsistent (a node is reached twice)")
    if total != n:
        raise ValueError(f"score: only {total} of {n} nodes are reachable from the root through child ranges")
    order = np.concatenate(order)
    if not np.array_equal(parent[order[1:]] >= 0, np.ones(n - 1, bool)):
        raise ValueError("score: the tree's parent and child arrays disagree")
    return order, np.concatenate(depth)


def _compact_masks(mask: np.ndarray) -> dict:
    """Normal masks (M, 12) uint32 -> up to 2 nonzero (word index, word) pairs per node, plus the
    positions (and full masks) of the nodes that use more than 2 words."""
    nz = mask != 0
    wide = np.flatnonzero(nz.sum(1) > 2)
    order = np.argsort(~nz, axis=1, kind="stable")[:, :2]  # first two nonzero words (or zero words)
    val = np.take_along_axis(mask, order, 1)
    val[wide] = 0
    return dict(word_idx=jnp.asarray(order.astype(np.int32)), word_val=jnp.asarray(val),
                wide=jnp.asarray(wide.astype(np.int32)), wide_mask=jnp.asarray(mask[wide]))


def scoring_context(tree) -> ScoringContext:
    """Build (once; cached on the tree) the device arrays :func:`score` needs for ``tree``."""
    cached = getattr(tree, "_plod_scoring_context", None)
    if cached is None:
        hit = _CONTEXTS.get(id(tree))
        if hit is not None and hit[0]() is tree:
            cached = hit[1]
    if cached is not None:
        return cached
    n = _check_tree(tree)
    parent = np.asarray(tree.parent, np.int64)
    count = np.asarray(tree.child_count)
    order, depth = _level_order(parent, np.asarray(tree.child_start), count)
    keep = count[order] > 0
    node = order[keep] if keep.any() else np.zeros(1, np.int64)  # a lone vertex: nothing to fold
    depth_int = depth[keep] if keep.any() else np.zeros(1, np.int64)
    m = len(node)
    pos = np.full(n, -1, np.int64)
    pos[node] = np.arange(m)
    par = np.where(parent[node] >= 0, pos[np.maximum(parent[node], 0)], -1)
    if (par[1:] < 0).any():
        raise ValueError("score: an internal node's parent is not an internal node")
    levels = tuple(int(x) for x in np.searchsorted(depth_int, np.arange(int(depth_int.max()) + 2)))
    passes = _TreePasses(par, levels, node, n)
    center = np.asarray(tree.center, np.float32)[node]
    mask = np.ascontiguousarray(np.asarray(tree.normal_mask, np.uint8)[node]).view("<u4")
    lum_min, lum_max = np.asarray(tree.lum_min, np.float32), np.asarray(tree.lum_max, np.float32)
    cols = dict(cx=center[:, 0], cy=center[:, 1], cz=center[:, 2], radius=np.asarray(tree.radius)[node],
                lum_min=lum_min[node], lum_max=lum_max[node], fold_delta=np.asarray(tree.fold_delta)[node],
                geom_error=np.asarray(tree.geom_error)[node])
    chunks, sizes = [], []
    for a in range(0, m, _CHUNK):
        sl = slice(a, min(a + _CHUNK, m))
        size = sl.stop - a
        # pad to a multiple of _PAD with zero nodes (empty masks): on a length that is not a multiple
        # of the vector width XLA:CPU emitted scalar loops, measured ~6x slower per node
        pad = -size % _PAD
        padf = lambda v: np.concatenate([v, np.zeros((pad,) + v.shape[1:], v.dtype)]) if pad else v  # noqa: E731
        mk = padf(mask[sl])
        chunks.append(_Chunk(**{k: jnp.asarray(np.ascontiguousarray(padf(v[sl]), np.float32)) for k, v in cols.items()},
                             **_compact_masks(mk), nonempty=jnp.asarray((mk != 0).any(1))))
        sizes.append(size)
    ctx = ScoringContext(chunks, passes, m, (float(np.clip(lum_min.min(), 0, 1)), float(np.clip(lum_max.max(), 0, 1))))
    ctx.sizes = tuple(sizes)
    try:
        object.__setattr__(tree, "_plod_scoring_context", ctx)
    except (AttributeError, TypeError):
        _CONTEXTS[id(tree)] = (weakref.ref(tree), ctx)
    return ctx


# =============================================================================== stage 2: view parameters
class _ViewParams(NamedTuple):
    eye: jax.Array  # (3,)
    rot: jax.Array  # (3, 3) world -> camera
    scal: jax.Array  # (10,) focal_px, tan_x, tan_y, near, size_cap, deg_per_px, kx, ky, gaze_err, 1/dt
    gaze: jax.Array  # (G, 2) pixel offsets from the image centre (y down)
    lum: jax.Array  # (4,) black cd/m2, peak - black cd/m2, scene min, scene max (relative)
    prev_eye: jax.Array
    prev_rot: jax.Array
    prev_focal: jax.Array


def _view_params(view, ctx: ScoringContext) -> _ViewParams:
    from ._view import View

    if not isinstance(view, View):
        raise ValueError(f"score: view must be an optim.View, got {type(view).__name__}")
    w, h = view.width, view.height
    tan_y = math.tan(math.radians(view.fov_deg) / 2)
    px, py = view.pixel_pitch_m
    d = view.distance_m
    gaze = view.gaze_px if view.gaze_px is not None else np.array([[w / 2, h / 2]])
    gaze = gaze - np.array([w / 2, h / 2])
    prev = view.previous
    scal = [view.focal_px, tan_y * w / h, tan_y, view.near, _SIZE_CAP_IMAGES * max(w, h), view.degrees_per_pixel,
            px / d, py / d, view.gaze_error_deg, 1.0 / view.dt_s if prev is not None else 0.0]
    black = float(view.display.black_level)
    peak = float(view.display.peak_luminance)
    lo = min(ctx.scene_lum[0], view.background)
    hi = max(ctx.scene_lum[1], view.background)
    f = jnp.float32
    return _ViewParams(
        eye=jnp.asarray(view.eye, f), rot=jnp.asarray(view.rotation, f), scal=jnp.asarray(scal, f),
        gaze=jnp.asarray(gaze, f), lum=jnp.asarray([black, peak - black, lo, hi], f),
        prev_eye=jnp.asarray((prev or view).eye, f), prev_rot=jnp.asarray((prev or view).rotation, f),
        prev_focal=jnp.asarray((prev or view).focal_px, f),
    )


# =============================================================================== stage 3: the kernel
def _safe_div(a, b):
    ok = b != 0
    return jnp.where(ok, a / jnp.where(ok, b, 1.0), 0.0)


def _atan2_pos(y, x):
    """atan2(y, x) in rad for y >= 0, with mul/add only (max error about 2e-6 rad; XLA's CPU atan2
    is scalar code and ~30x slower). Finite value and gradient at (0, 0)."""
    ax = jnp.abs(x)
    mx = jnp.maximum(ax, y)
    mn = jnp.minimum(ax, y)
    a = _safe_div(mn, mx)
    s = a * a
    r = a * (0.99997726 + s * (-0.33262347 + s * (0.19354346 + s * (-0.11643287 + s * (0.05265332 - 0.0117212 * s)))))
    r = jnp.where(y > ax, 0.5 * np.pi - r, r)
    return jnp.where(x < 0, np.pi - r, r)


def _angle_deg(a, b):
    """Angle (deg) between 3-vectors given as column tuples a = (ax, ay, az), b = (bx, by, bz)."""
    cx = a[1] * b[2] - a[2] * b[1]
    cy = a[2] * b[0] - a[0] * b[2]
    cz = a[0] * b[1] - a[1] * b[0]
    n2 = cx * cx + cy * cy + cz * cz
    pos = n2 > 0
    n = jnp.where(pos, jnp.sqrt(jnp.where(pos, n2, 1.0)), 0.0)
    return jnp.degrees(_atan2_pos(n, a[0] * b[0] + a[1] * b[1] + a[2] * b[2]))


def _dir_bin(dx, dy, dz):
    """View-direction bin (0 .. 6*16*16-1) of vectors (columns); same layout as ``_dir_bin_np``."""
    ax_, ay_, az_ = jnp.abs(dx), jnp.abs(dy), jnp.abs(dz)
    x_major = (ax_ >= ay_) & (ax_ >= az_)
    y_major = ~x_major & (ay_ >= az_)
    axis = jnp.where(x_major, 0, jnp.where(y_major, 1, 2))
    comp = jnp.where(x_major, dx, jnp.where(y_major, dy, dz))
    u_src = jnp.where(x_major, dy, dx)
    v_src = jnp.where(x_major | y_major, dz, dy)
    inv = 1.0 / jnp.maximum(jnp.abs(comp), 1e-30)
    q = _DIR_BINS
    i = jnp.clip(jnp.floor((u_src * inv + 1) * (q / 2)), 0, q - 1).astype(jnp.int32)
    j = jnp.clip(jnp.floor((v_src * inv + 1) * (q / 2)), 0, q - 1).astype(jnp.int32)
    face = 2 * axis + (comp < 0).astype(jnp.int32)
    return face * q * q + j * q + i


class _Terms(NamedTuple):
    culled: jax.Array
    backfacing: jax.Array
    silhouette: jax.Array
    size_px: jax.Array
    theta: jax.Array
    ecc: jax.Array
    vel: jax.Array
    contrast: jax.Array
    err_px: jax.Array


def _project(cx, cy, cz, eye, rot):
    dx, dy, dz = cx - eye[0], cy - eye[1], cz - eye[2]
    x = rot[0, 0] * dx + rot[0, 1] * dy + rot[0, 2] * dz
    y = rot[1, 0] * dx + rot[1, 1] * dy + rot[1, 2] * dz
    depth = -(rot[2, 0] * dx + rot[2, 1] * dy + rot[2, 2] * dz)
    return (dx, dy, dz), x, y, depth


def _facing_rows(ctx: _Chunk, vp: _ViewParams):
    """Row of the silhouette table (margin level, view-direction bin) of every node (M,) int32."""
    r = ctx.radius
    (dx, dy, dz), _, _, _ = _project(ctx.cx, ctx.cy, ctx.cz, vp.eye, vp.rot)
    dist = jnp.sqrt(dx * dx + dy * dy + dz * dz)
    s = jnp.clip(_safe_div(r, dist), 0.0, 1.0)
    margins = np.sin(np.radians(_MARGINS_DEG[:-1])).astype(np.float32)
    level = sum((s > float(mk)).astype(jnp.int32) for mk in margins)
    level = jnp.where(dist <= r, len(_MARGINS_DEG) - 1, level)
    return level * (6 * _DIR_BINS * _DIR_BINS) + _dir_bin(-dx, -dy, -dz)


def _facing_flags(ctx: _Chunk, vp: _ViewParams, table):
    """(possibly front facing, possibly back facing) (M,) bool: the node's normal mask against the
    table row of its view direction and angular-radius margin (seed 001 section 4.3).

    ``table`` is (rows * 12, 2) uint32: for each row and mask word, the front and back words side by
    side, so one gather fetches both. Most masks use at most 2 of their 12 words (``word_idx``); the
    few wider ones gather whole rows. 'clip' mode avoids XLA's slow checked gather."""
    row = _facing_rows(ctx, vp)
    got = jnp.take(table, row[:, None] * 12 + ctx.word_idx, axis=0, mode="clip")  # (M, 2 words, front/back)
    hit = jnp.any((got & ctx.word_val[:, :, None]) != 0, axis=1)  # (M, 2)
    if ctx.wide.shape[0]:
        rows = table.reshape(-1, 12, 2)
        tab = jnp.take(rows, jnp.take(row, ctx.wide, mode="clip"), axis=0, mode="clip")  # (W, 12, 2)
        wide_hit = jnp.any((tab & ctx.wide_mask[:, :, None]) != 0, axis=1)
        hit = hit.at[ctx.wide].set(wide_hit, indices_are_sorted=True, unique_indices=True)
    return hit[:, 0], hit[:, 1]


@eqx.filter_jit
def _facing_kernel(ctx, vp, table):
    """``_facing_flags`` as its own XLA program: fused into the per-node terms, XLA:CPU duplicates the
    direction-bin arithmetic into several gather loops (measured ~2x slower on 10^6 nodes)."""
    return _facing_flags(ctx, vp, table)


def _terms(ctx: _Chunk, vp: _ViewParams, table, has_gaze: bool, has_motion: bool, need: str,
           facing=None) -> _Terms:
    focal, tan_x, tan_y, near, size_cap, dpp, kx, ky, gaze_err, inv_dt = (vp.scal[i] for i in range(10))
    r = ctx.radius
    (dx, dy, dz), x, y, depth = _project(ctx.cx, ctx.cy, ctx.cz, vp.eye, vp.rot)
    dist = jnp.sqrt(dx * dx + dy * dy + dz * dz)
    inside = dist <= r  # the eye is inside the bounding sphere

    # --- stage 1: cull: sphere wholly outside a side plane of the frustum or before the near plane
    ix, iy = jax.lax.rsqrt(1 + tan_x * tan_x), jax.lax.rsqrt(1 + tan_y * tan_y)
    outside = ((depth + r < near)
               | ((x - tan_x * depth) * ix > r) | ((-x - tan_x * depth) * ix > r)
               | ((y - tan_y * depth) * iy > r) | ((-y - tan_y * depth) * iy > r))
    s = jnp.clip(_safe_div(r, dist), 0.0, 1.0)  # sin of the angular radius
    #     wholly back facing / silhouette: normal mask against the per-direction table (``_facing``)
    if facing is None:
        facing = _facing_flags(ctx, vp, table)
    front, back = facing
    backfacing = ctx.nonempty & ~front
    silhouette = front & back
    culled = (outside & ~inside) | backfacing

    # --- stage 2: extent. projected diameter 2 f tan(asin s) = 2 f s / sqrt(1 - s^2), guarded at s -> 1
    one_m = jnp.maximum(1.0 - s * s, 1e-12)
    size_px = jnp.where(inside, size_cap, jnp.minimum(2.0 * focal * s * jax.lax.rsqrt(one_m), size_cap))
    theta = size_px * dpp  # deg of the viewer's visual field

    zero = jnp.zeros_like(r)
    front_pt = depth > near
    inv_depth = jnp.where(front_pt, 1.0 / jnp.where(front_pt, depth, 1.0), 0.0)
    u = focal * x * inv_depth  # px from the image centre, x right
    v = -focal * y * inv_depth  # y down
    eye_vec = (u * kx, v * ky, jnp.ones_like(u))  # direction from the viewer's eye to the image point

    # --- stage 3: eccentricity (deg), minimum over the gaze points
    if has_gaze and need == "perceptual":
        g = vp.gaze
        ang = None
        for k in range(g.shape[0]):
            a_k = _angle_deg(eye_vec, (g[k, 0] * kx, g[k, 1] * ky, 1.0))
            ang = a_k if ang is None else jnp.minimum(ang, a_k)
        ecc = jnp.maximum(ang - 0.5 * theta - gaze_err, 0.0)
        ecc = jnp.where(front_pt & ~inside, ecc, 0.0)
    else:
        ecc = zero

    # --- stage 4: retinal velocity (deg/s) of the node's image between the previous view and this one
    if has_motion and need == "perceptual":
        _, px_, py_, pdepth = _project(ctx.cx, ctx.cy, ctx.cz, vp.prev_eye, vp.prev_rot)
        pfront = pdepth > near
        pinv = jnp.where(pfront, 1.0 / jnp.where(pfront, pdepth, 1.0), 0.0)
        prev_vec = (vp.prev_focal * px_ * pinv * kx, -vp.prev_focal * py_ * pinv * ky, jnp.ones_like(u))
        vel = jnp.where(front_pt & pfront, _angle_deg(eye_vec, prev_vec) * inv_dt, 0.0)
    else:
        vel = zero

    # --- stage 5: contrast (Michelson of display luminances, cd/m2)
    if need == "perceptual":
        black, span, scene_lo, scene_hi = vp.lum[0], vp.lum[1], vp.lum[2], vp.lum[3]
        cd = lambda rel: black + span * jnp.clip(rel, 0.0, 1.0)  # noqa: E731
        mich = lambda a, b: _safe_div(jnp.abs(a - b), a + b)  # noqa: E731
        lo = cd(ctx.lum_min)
        c_own = mich(cd(ctx.lum_min + ctx.fold_delta), lo)
        c_sil = jnp.maximum(mich(cd(ctx.lum_max), cd(scene_lo)), mich(cd(scene_hi), lo))
        contrast = jnp.where(silhouette, jnp.maximum(c_sil, c_own), c_own)
    else:
        contrast = zero

    # --- geometric error in pixels at the nearest point of the bounding sphere
    if need == "geometric":
        near_d = jnp.maximum(dist - r, near)
        err_px = jnp.where(inside, size_cap, jnp.minimum(focal * ctx.geom_error / near_d, size_cap))
    else:
        err_px = zero
    return _Terms(culled, backfacing, silhouette, size_px, theta, ecc, vel, contrast, err_px)


# ------------------------------------------------------------------ perceptual key through a contrast table
#: contrast grid: log10 c from -4 to 0; eccentricity-to-size ratio grid: 0, then log10 from -2 to 4.
#: 256 x 96 float32 = 96 KiB, small enough to stay in cache during the per-node gather
_TAB_C = (-4.0, 0.0, 256)
_TAB_R = (-2.0, 4.0, 96)


def _perceptual_table(model) -> jax.Array:
    """K[j, i] = model.imperceptible_distance(c_j, 1 deg, r_i deg, 0), made conservative: non-decreasing
    in c and, over each r cell, the larger of its two ends. Flat (Nc * Nr,) float32."""
    lc0, lc1, nc = _TAB_C
    lr0, lr1, nr = _TAB_R
    c = np.logspace(lc0, lc1, nc)
    rr = np.concatenate([[0.0], np.logspace(lr0, lr1, nr - 1)])
    cg, rg = np.meshgrid(c, rr, indexing="ij")
    k = np.asarray(jax.jit(lambda m, a, b: m.imperceptible_distance(a, jnp.ones_like(a), b, 0.0))(
        model, jnp.asarray(cg, jnp.float32), jnp.asarray(rg, jnp.float32)), np.float64)
    k = np.where(np.isfinite(k), k, 1e30)
    k = np.maximum.accumulate(k, axis=0)  # non-decreasing in contrast
    k[:, :-1] = np.maximum(k[:, :-1], k[:, 1:])  # cell [r_i, r_i+1): upper end of a monotone pair
    return jnp.asarray(k.astype(np.float32).ravel())


_TABLES: dict = {}
_KTAB_HOST: dict = {}


def _ktab_host(ktab) -> np.ndarray:
    h = _KTAB_HOST.get(id(ktab))
    if h is None or h[0] is not ktab:
        if len(_KTAB_HOST) > 16:
            _KTAB_HOST.clear()
        h = _KTAB_HOST[id(ktab)] = (ktab, np.asarray(ktab))
    return h[1]


def _model_table(model):
    leaves = jax.tree_util.tree_leaves(model)
    key = (type(model).__qualname__, str(jax.tree_util.tree_structure(model)),
           tuple(np.asarray(x).tobytes() for x in leaves))
    tab = _TABLES.get(key)
    if tab is None:
        if len(_TABLES) > 16:
            _TABLES.clear()
        tab = _TABLES[key] = _perceptual_table(model)
    return tab


def _table_index_impl(c, theta, ecc):
    """Flat index into the key table of (c rounded up, ecc / theta rounded down), -1 where the key is
    0 (no contrast or no extent). Computed apart from the gather (``_table_lookup``): fused into it,
    XLA:CPU computes the indices with scalar code (log10 per element), several times slower."""
    lc0, lc1, nc = _TAB_C
    lr0, lr1, nr = _TAB_R
    pos_c = c > 0
    lc = jnp.log10(jnp.where(pos_c, jnp.maximum(c, 10.0 ** lc0), 1.0))
    j = jnp.clip(jnp.ceil((lc - lc0) * ((nc - 1) / (lc1 - lc0)) - 1e-4), 0, nc - 1).astype(jnp.int32)
    ratio = _safe_div(ecc, theta)
    small = ratio < 10.0 ** lr0
    lr = jnp.log10(jnp.where(small, 1.0, ratio))
    i = jnp.where(small, 0, 1 + jnp.clip(jnp.floor((lr - lr0) * ((nr - 2) / (lr1 - lr0))), 0, nr - 2)).astype(jnp.int32)
    return jnp.where(pos_c & (theta > 0), j * nr + i, -1)


@jax.jit
def _table_lookup(ktab, idx, theta):
    """theta * K(c rounded up, ecc / theta rounded down): an upper bound of the exact key within the
    table's resolution (3.7 % in contrast, 15.7 % in the eccentricity-to-size ratio; ratios below 0.01
    use 0, above 1e4 use 1e4). ``idx`` from ``_table_index_impl``; 0 where it is -1."""
    return jnp.where(idx >= 0, theta * jnp.take(ktab, idx, mode="clip"), 0.0).astype(jnp.float32)


@eqx.filter_jit
def _key_terms(ctx, vp, facing, metric, has_gaze, has_motion, table_mode=False):
    """Stages 1-5: (cull flag, the metric's input terms) of every internal node. Only what stage 6
    needs leaves the program (per-node arrays of 10^6 nodes no longer fit in cache): with
    ``table_mode`` the key-table index and theta, else (contrast, theta[, ecc][, vel]) or the pixel key."""
    t = _terms(ctx, vp, None, has_gaze, has_motion, metric, facing)
    if metric == "perceptual":
        if table_mode:
            return t.culled, (_table_index_impl(t.contrast, t.theta, t.ecc), t.theta)
        return t.culled, (t.contrast, t.theta, t.ecc if has_gaze else None, t.vel if has_motion else None)
    return t.culled, (t.size_px if metric == "size" else t.err_px,)


@eqx.filter_jit
def _key_from_terms(model, ktab, terms, metric, has_gaze, has_motion):
    """Stage 6 without the key table (``exact=True``, motion, pixel metrics): raw key (M,) float32 >= 0.
    A separate XLA program: fused with stages 1-5, XLA:CPU
    recomputes shared intermediates and runs ~1.5x slower."""
    if metric == "perceptual":
        contrast, theta, ecc, vel = terms
        key = model.imperceptible_distance(contrast, theta, ecc if has_gaze else 0.0, vel if has_motion else 0.0)
        key = jnp.where(jnp.isnan(key), 1e30, jnp.minimum(key, 1e30))
    else:
        key = terms[0]
    return jnp.maximum(key, 0.0).astype(jnp.float32)


@eqx.filter_jit
def _split_terms(ctx, vp, has_gaze):
    """Fast path of the table-mode perceptual key, stages 1-5 in one XLA program without gathers:
    the silhouette-table word positions (M, 2) int32 of each node, the key-table index for the
    front-facing contrast and for the silhouette contrast, theta, and the frustum cull flag. The two
    facing cases are ``_terms`` itself with the facing flags fixed (shared arithmetic is computed
    once), so the values equal those of ``_key_terms``. The gathers run in numpy
    (``_fast_table_keys``): XLA:CPU fuses the index arithmetic into its gather loops as scalar code
    (measured ~8x slower than numpy's take on the same indices)."""
    widx = _facing_rows(ctx, vp)[:, None] * 12 + ctx.word_idx
    yes = jnp.ones(ctx.radius.shape, bool)
    t_own = _terms(ctx, vp, None, has_gaze, False, "perceptual", (yes, ~yes))
    t_sil = _terms(ctx, vp, None, has_gaze, False, "perceptual", (yes, yes))
    return (widx, _table_index_impl(t_own.contrast, t_own.theta, t_own.ecc),
            _table_index_impl(t_sil.contrast, t_sil.theta, t_sil.ecc), t_own.theta, t_own.culled)


class _HostMasks(NamedTuple):
    """numpy copies of a chunk's compacted normal masks for the fast path: ``val`` (C, 2) uint64 (the
    word repeated in both halves), ``wide`` (W,) positions, ``wide_val`` (W, 12) uint64, ``nonempty``."""

    val: np.ndarray
    wide: np.ndarray
    wide_val: np.ndarray
    nonempty: np.ndarray


def _host_masks(ctx) -> list:
    """Per chunk :class:`_HostMasks`, cached on the context (not on the chunk: an attribute added
    to the eqx.Module changed its jit cache key and recompiled the programs)."""
    hms = getattr(ctx, "host_masks", None)
    if hms is None:
        dbl = lambda w: (lambda u: u | (u << np.uint64(32)))(np.asarray(w).astype(np.uint64))  # noqa: E731
        hms = ctx.host_masks = [_HostMasks(dbl(ch.word_val), np.asarray(ch.wide).astype(np.intp),
                                           dbl(ch.wide_mask), np.asarray(ch.nonempty)) for ch in ctx.chunks]
    return hms


def _table_host():
    """The silhouette table as numpy (rows * 12,) uint64: front word in the low, back word in the high half."""
    return np.ascontiguousarray(np.asarray(_table_device())).view(np.uint64).ravel()


def _fast_table_keys(ctx, vp, ktab_host, has_gaze):
    """Raw key (M,) float32 and cull flag (M,) bool, table mode: identical to ``_key_kernel``'s."""
    table = _table_host_cached()
    outs = [_split_terms(ch, vp, has_gaze) for ch in ctx.chunks]  # dispatch all chunks first
    key = np.empty(ctx.m, np.float32)
    culled = np.empty(ctx.m, bool)
    a = 0
    for hm, n, out in zip(_host_masks(ctx), ctx.sizes, outs):
        widx, i_own, i_sil, theta, outside = (np.asarray(x)[:n] for x in out)
        m = table.take(widx)
        m &= hm.val[:n]
        m = m[:, 0] | m[:, 1]
        if hm.wide.size:  # (wide masks are never padding)
            rows = (widx[hm.wide, 0] // 12) * 12
            mw = table.take(rows[:, None] + np.arange(12)) & hm.wide_val
            m[hm.wide] = np.bitwise_or.reduce(mw, axis=1)
        front = (m & np.uint64(0xFFFFFFFF)) != 0
        sil = front & ((m >> np.uint64(32)) != 0)
        b = a + n
        np.logical_or(outside, hm.nonempty[:n] & ~front, out=culled[a:b])
        idx = np.where(sil, i_sil, i_own)
        k = theta * ktab_host.take(idx, mode="clip")
        k[idx < 0] = 0.0
        key[a:b] = k
        a = b
    return key, culled


@functools.lru_cache(maxsize=1)
def _table_host_cached_impl(_key):
    return _table_host()


def _table_host_cached():
    cell_fn, bit_fn = _cell_layout()
    return _table_host_cached_impl((id(cell_fn), id(bit_fn)))


def _key_kernel(ctx, vp, table, model, ktab, metric, has_gaze, has_motion, fast=True):
    """Raw key (M,) float32 and cull flag (M,) of every internal node (stages 1-6), chunk by chunk
    (all chunks are dispatched before any result is read). ``fast``: table mode through
    ``_fast_table_keys`` (same values)."""
    table_mode = metric == "perceptual" and ktab is not None and not has_motion
    if table_mode and fast:
        return _fast_table_keys(ctx, vp, _ktab_host(ktab), has_gaze)
    outs = []
    for ch in ctx.chunks:
        culled, terms = _key_terms(ch, vp, _facing_kernel(ch, vp, table), metric, has_gaze, has_motion, table_mode)
        if table_mode:
            key = _table_lookup(ktab, terms[0], terms[1])
        else:
            key = _key_from_terms(model, ktab, terms, metric, has_gaze, has_motion)
        outs.append((key, culled))
    sz = ctx.sizes
    return (np.concatenate([np.asarray(k)[:n] for (k, _), n in zip(outs, sz)]),
            np.concatenate([np.asarray(c)[:n] for (_, c), n in zip(outs, sz)]))


@eqx.filter_jit
def _terms_jit(ctx, vp, facing, has_gaze, has_motion):
    return _terms(ctx, vp, None, has_gaze, has_motion, "perceptual", facing)


def _terms_kernel(ctx, vp, table, has_gaze, has_motion):
    parts = [_terms_jit(ch, vp, _facing_kernel(ch, vp, table), has_gaze, has_motion) for ch in ctx.chunks]
    return _Terms(*(np.concatenate([np.asarray(getattr(p, f))[:n] for p, n in zip(parts, ctx.sizes)])
                    for f in _Terms._fields))


# =============================================================================== public API
class NodeTerms(NamedTuple):
    """Per-node terms of one view, tree order, numpy (N,) (leaves: all False / 0): ``culled`` (outside
    the frustum, wholly back facing, or below such a node), ``backfacing``, ``silhouette`` (bool);
    ``size_px`` projected bounding-sphere diameter (pixels); ``theta`` its visual angle (deg);
    ``eccentricity`` (deg); ``velocity`` retinal velocity (deg/s); ``contrast`` Michelson contrast of
    the fold."""

    culled: np.ndarray
    backfacing: np.ndarray
    silhouette: np.ndarray
    size_px: np.ndarray
    theta: np.ndarray
    eccentricity: np.ndarray
    velocity: np.ndarray
    contrast: np.ndarray


def default_model():
    """The perceptual model used when none is given: Kelly's abstract CSF (seed 001) with its defaults
    (peak sensitivity 200 at 4 cycles/deg)."""
    import pmetric

    return pmetric.KellyAbstract()


def node_terms(tree, view) -> NodeTerms:
    """Cull flags, silhouette flags, angular size, eccentricity, velocity and contrast of every node
    for ``view`` (the inputs of the perceptual key; see the module docstring for units)."""
    ctx = scoring_context(tree)
    vp = _view_params(view, ctx)
    t = _terms_kernel(ctx, vp, _table_device(), view.gaze_px is not None, view.previous is not None)
    tp = ctx.passes
    culled = tp.propagate_culled(t.culled)
    return NodeTerms(*(tp.to_tree(a, False if a.dtype == bool else 0.0)
                       for a in (culled, t.backfacing, t.silhouette, t.size_px, t.theta, t.ecc, t.vel, t.contrast)))


def score(tree, view, model=None, metric: str = "perceptual", *, exact: bool = False) -> np.ndarray:
    """Keys (N,) float32, one per node of ``tree`` for ``view``: larger = more important to keep unfolded.

    ``metric="perceptual"``: ``model.imperceptible_distance`` of the fold (multiples of the current
    viewing distance; <= 1 = imperceptible now; seed 004 section 5.3); ``model`` is a
    :class:`pmetric.CSFModel` (default: :func:`default_model`). Without motion the key is read from a
    per-model table (``k(c, theta, e) = theta K(c, e / theta)`` holds for every model by the definition
    of the distance key) rounded to the conservative side; ``exact=True`` calls the model per node.
    ``"size"``: projected bounding-sphere diameter (pixels). ``"geometric"``: projected fold error
    (pixels). Leaves, culled nodes (outside the frustum, wholly back facing) and their subtrees get 0.
    Keys are monotone: ``key[parent] >= key[child]`` (seed 004 footnote 2).
    """
    if metric not in METRICS:
        raise ValueError(f"score: metric must be one of {METRICS}, got {metric!r}")
    ctx = scoring_context(tree)
    vp = _view_params(view, ctx)
    ktab = None
    if metric == "perceptual":
        import pmetric

        model = default_model() if model is None else model
        if not isinstance(model, pmetric.CSFModel):
            raise ValueError(f"score: model must be a pmetric.CSFModel, got {type(model).__name__}")
        if not exact and view.previous is None:
            ktab = _model_table(model)
    else:
        model = None
    raw, culled = _key_kernel(ctx, vp, _table_device(), model, ktab, metric, view.gaze_px is not None,
                              view.previous is not None)
    # stage 7 and the subtree culling: two O(M) passes over the levels in numpy (XLA:CPU runs these
    # level-by-level scatters and prefix scans several times slower than numpy's reduceat)
    tp = ctx.passes
    key = np.array(raw)
    key[tp.propagate_culled(np.asarray(culled))] = 0.0
    return tp.to_tree(tp.monotone(key), 0.0)


@functools.lru_cache(maxsize=1)
def _table_device_cached(_key):
    t = silhouette_table()  # (rows, 24): front words 0..11, back words 12..23
    return jnp.asarray(np.ascontiguousarray(np.stack([t[:, :12], t[:, 12:]], axis=-1).reshape(-1, 2)))


def _table_device():
    cell_fn, bit_fn = _cell_layout()
    return _table_device_cached((id(cell_fn), id(bit_fn)))


def imperceptible_cut(tree, view, model=None, *, exact: bool = False):
    """Fold every node whose fold is imperceptible from ``view``, top down (seed 001 section 4; seed
    004 section 5.1): ``optim.threshold_cut`` at key 1 of the perceptual keys, ``stop_reason``
    ``"imperceptible"`` (or ``"all_unfolded"`` when no fold is imperceptible). Returns an ``optim.Cut``."""
    from ._cut import threshold_cut

    keys = score(tree, view, model, "perceptual", exact=exact)
    return threshold_cut(tree, keys, 1.0, monotone="trust")

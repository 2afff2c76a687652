"""The per-tree scoring context: what :func:`optim.score` needs of a tree, built once per tree.

Only the M internal nodes are kept (a leaf has nothing to fold: its key is 0), in breadth-first order
with children grouped by parent, as flat float32 columns split into chunks (:class:`_Chunk`) of
``_CHUNK`` nodes: on arrays of more than about 2 MB XLA:CPU's per-element cost is several times
higher, so each per-view program runs once per chunk. Chunks are padded to a multiple of ``_PAD``
nodes: on a length that is not a multiple of the vector width XLA:CPU emits scalar loops.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from pmetric import PlodError

from ._levels import Levels
from ._tree import VertexTree

__all__ = ["CONTEXT_NAMES", "ScoringContext", "load_context", "save_context", "scoring_context"]

#: internal nodes per chunk of the per-view programs (1 MiB float32 columns)
_CHUNK = 262144
#: child slots gathered per level in the max propagation; children beyond them go to reduceat (Levels._slots)
_MAX_ARITY = 8
#: chunk lengths are padded to a multiple of this many nodes (vectorised XLA loops)
_PAD = 1024

_FIELDS = ("parent", "child_start", "child_count", "center", "radius", "lum_min", "lum_max",
           "fold_delta", "geom_error", "normal_mask")


class _Chunk(eqx.Module):
    """Device arrays of up to ``_CHUNK`` internal nodes (breadth-first order): flat float32 columns
    ``cx, cy, cz`` bounding-sphere centre and ``radius`` (object units), ``cull_radius`` the radius of
    the frustum test (object units, :func:`optim._relight.cull_columns`), ``ax, ay, az`` the normal
    cone's axis and ``cone_cos``, ``cone_sin`` its half-angle's cosine and sine (the half-angle capped
    at 90 deg) over the faces the fold touches, ``lum_min``, ``lum_max``,
    ``fold_delta`` (relative luminance), ``geom_error`` and ``slab`` (the half-width of the slab holding
    the fold, :func:`optim._relight.slab_half_width`; object units); normal masks (48 bytes = 12
    uint32 words) as ``word_idx``, ``word_val`` (C, 2): the (up to) two nonzero words of each mask,
    ``wide`` (W,) positions of masks with more nonzero words and ``wide_mask`` (W, 12) their full
    masks; ``nonempty`` (C,) bool."""

    cx: jax.Array
    cy: jax.Array
    cz: jax.Array
    radius: jax.Array
    cull_radius: jax.Array
    ax: jax.Array
    ay: jax.Array
    az: jax.Array
    cone_cos: jax.Array
    cone_sin: jax.Array
    lum_min: jax.Array
    lum_max: jax.Array
    fold_delta: jax.Array
    geom_error: jax.Array
    slab: jax.Array
    word_idx: jax.Array
    word_val: jax.Array
    wide: jax.Array
    wide_mask: jax.Array
    nonempty: jax.Array


class _HostMasks(NamedTuple):
    """numpy copies of a chunk's compacted normal masks for the numpy classify step: ``val`` (C, 2)
    uint64 (the word repeated in both halves), ``wide`` (W,) positions, ``wide_val`` (W, 12) uint64,
    ``nonempty``. Kept on the context, not on the chunk: a field added to the eqx.Module would change
    its jit cache key and recompile the programs."""

    val: np.ndarray
    wide: np.ndarray
    wide_val: np.ndarray
    nonempty: np.ndarray


@dataclasses.dataclass(frozen=True, eq=False)
class ScoringContext:
    """Per-tree data of :func:`optim.score`, built once by :func:`scoring_context` (cached on the tree).

    ``chunks`` (:class:`_Chunk`, device) and ``host_masks`` (:class:`_HostMasks`, numpy) per chunk,
    ``sizes`` the number of real (unpadded) nodes in each; ``levels`` (:class:`optim._levels.Levels`)
    the level structure of the M internal nodes for the two tree passes (culling down, maximum up);
    ``node`` (M,) tree index of each; ``n_nodes`` N; ``scene_lum`` the darkest and brightest relative
    luminance of the model; ``origin`` (3,) float64 the origin of the node coordinates (the tree's
    :attr:`optim.VertexTree.origin`, 0 for other tree-like objects): views are moved into its frame.
    """

    chunks: tuple
    host_masks: tuple
    sizes: tuple
    levels: Levels
    node: np.ndarray
    n_nodes: int
    scene_lum: tuple
    origin: np.ndarray

    @property
    def m(self) -> int:
        """Number of internal nodes M."""
        return len(self.node)

    def to_tree(self, vals: np.ndarray, fill=0) -> np.ndarray:
        """Internal-node values (M,) -> tree order (N,), ``fill`` at the leaves."""
        out = np.full(self.n_nodes, fill, dtype=vals.dtype)
        out[self.node] = vals
        return out


def _check_tree(tree) -> int:
    missing = [f for f in _FIELDS if getattr(tree, f, None) is None]
    if missing:
        raise PlodError(f"score: the tree lacks the field(s) {', '.join(missing)} (expected an optim.VertexTree)")
    n = len(np.asarray(tree.parent))
    if n == 0:
        raise PlodError("score: the tree has no nodes")
    for f in _FIELDS:
        a = np.asarray(getattr(tree, f))
        want = {"center": (n, 3), "normal_mask": (n, 48)}.get(f, (n,))
        if a.shape != want:
            raise PlodError(f"score: tree.{f} has shape {a.shape}, expected {want}")
    return n


def _level_order(parent, child_start, child_count):
    """Breadth-first order of the nodes: (order (N,) tree indices, depth (N,) of each entry)."""
    n = len(parent)
    roots = np.flatnonzero(parent < 0)
    if len(roots) != 1 or roots[0] != 0:
        raise PlodError(f"score: the tree must have exactly one root, node 0 (found roots {roots[:5].tolist()})")
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
            raise PlodError("score: the tree's child ranges are inconsistent (a node is reached twice)")
    if total != n:
        raise PlodError(f"score: only {total} of {n} nodes are reachable from the root through child ranges")
    order = np.concatenate(order)
    if not np.array_equal(parent[order[1:]] >= 0, np.ones(n - 1, bool)):
        raise PlodError("score: the tree's parent and child arrays disagree")
    return order, np.concatenate(depth)


def _internal_levels(tree, n: int):
    """(tree index (M,) of the internal nodes in breadth-first order, their :class:`Levels`)."""
    parent = np.asarray(tree.parent, np.int64)
    count = np.asarray(tree.child_count)
    order, depth = _level_order(parent, np.asarray(tree.child_start), count)
    keep = count[order] > 0
    node = order[keep] if keep.any() else np.zeros(1, np.int64)  # a lone vertex: nothing to fold
    depth_int = depth[keep] if keep.any() else np.zeros(1, np.int64)
    pos = np.full(n, -1, np.int64)
    pos[node] = np.arange(len(node))
    par = np.where(parent[node] >= 0, pos[np.maximum(parent[node], 0)], -1)
    if (par[1:] < 0).any():
        raise PlodError("score: an internal node's parent is not an internal node")
    return node, Levels.from_depth(par, depth_int, max_arity=_MAX_ARITY)


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


def _host_masks(ch: _Chunk) -> _HostMasks:
    dbl = lambda w: (lambda u: u | (u << np.uint64(32)))(np.asarray(w).astype(np.uint64))  # noqa: E731
    return _HostMasks(dbl(ch.word_val), np.asarray(ch.wide).astype(np.intp), dbl(ch.wide_mask),
                      np.asarray(ch.nonempty))


def _chunks(cols: dict, mask: np.ndarray, m: int):
    """(chunks, sizes): the columns and masks of the M internal nodes cut into padded chunks."""
    chunks, sizes = [], []
    for a in range(0, m, _CHUNK):
        sl = slice(a, min(a + _CHUNK, m))
        size = sl.stop - a
        pad = -size % _PAD  # zero nodes (empty masks) up to a multiple of _PAD
        padf = lambda v: np.concatenate([v, np.zeros((pad,) + v.shape[1:], v.dtype)]) if pad else v  # noqa: E731
        mk = padf(mask[sl])
        chunks.append(_Chunk(**{k: jnp.asarray(np.ascontiguousarray(padf(v[sl]), np.float32)) for k, v in cols.items()},
                             **_compact_masks(mk), nonempty=jnp.asarray((mk != 0).any(1))))
        sizes.append(size)
    return tuple(chunks), tuple(sizes)


def _scene_lum(lum_min, lum_max) -> tuple:
    return (float(np.clip(np.min(lum_min), 0, 1)), float(np.clip(np.max(lum_max), 0, 1)))


def _build(tree, relit: bool = False) -> ScoringContext:
    """The context of ``tree``; for an :class:`optim.VertexTree` its geometry only (luminance columns 0:
    :func:`_with_columns` puts in those of the lighting). ``relit``: a relit view asked for it (the
    neighbours' normals are then made in the cull columns' walk)."""
    n = _check_tree(tree)
    node, levels = _internal_levels(tree, n)
    center = np.asarray(tree.center, np.float32)[node]
    if isinstance(tree, VertexTree):  # what a fold can touch (culled folds are not free)
        from ._relight import cull_columns, normal_cones, slab_half_width

        mask, cull_radius, half = cull_columns(tree, neighbours=relit)
        axis = normal_cones(tree)[0]
        slab = slab_half_width(tree)
        lum = dict.fromkeys(("lum_min", "lum_max", "fold_delta"), np.zeros(n, np.float32))
    else:  # a bare tree-like object: its own masks and spheres; vertex displacement as the slab; no cone
        mask, cull_radius, slab = tree.normal_mask, tree.radius, tree.geom_error
        axis, half = np.zeros((n, 3), np.float32), np.full(n, np.pi, np.float32)
        lum = dict(lum_min=tree.lum_min, lum_max=tree.lum_max, fold_delta=tree.fold_delta)
    mask = np.ascontiguousarray(np.asarray(mask, np.uint8)[node]).view("<u4")
    lum_min, lum_max = np.asarray(lum["lum_min"], np.float32), np.asarray(lum["lum_max"], np.float32)
    cols = dict(cx=center[:, 0], cy=center[:, 1], cz=center[:, 2], radius=np.asarray(tree.radius)[node],
                cull_radius=np.asarray(cull_radius)[node], ax=axis[node, 0], ay=axis[node, 1], az=axis[node, 2],
                cone_cos=np.cos(np.minimum(half[node], np.pi / 2)), cone_sin=np.sin(np.minimum(half[node], np.pi / 2)),
                lum_min=lum_min[node], lum_max=lum_max[node], fold_delta=np.asarray(lum["fold_delta"])[node],
                geom_error=np.asarray(tree.geom_error)[node], slab=np.asarray(slab)[node])
    chunks, sizes = _chunks(cols, mask, len(node))
    scene = _scene_lum(lum_min, lum_max)
    origin = np.asarray(getattr(tree, "origin", np.zeros(3)), np.float64)
    return ScoringContext(chunks, tuple(_host_masks(ch) for ch in chunks), sizes, levels, node, n, scene, origin)


def _with_columns(base: ScoringContext, cols: dict) -> ScoringContext:
    """``base`` with the luminance columns ``cols`` (``lum_min``, ``lum_max``, ``fold_delta`` (N,)
    float32; same shapes: the per-view programs are not recompiled)."""
    cols = {k: np.asarray(cols[k], np.float32) for k in ("lum_min", "lum_max", "fold_delta")}
    chunks, a = [], 0
    for ch, n in zip(base.chunks, base.sizes):
        sl = base.node[a:a + n]
        pad = ch.radius.shape[0] - n
        col = lambda k: jnp.asarray(np.concatenate([cols[k][sl], np.zeros(pad, np.float32)]))  # noqa: E731
        chunks.append(dataclasses.replace(ch, lum_min=col("lum_min"), lum_max=col("lum_max"),
                                          fold_delta=col("fold_delta")))
        a += n
    return dataclasses.replace(base, chunks=tuple(chunks), scene_lum=_scene_lum(cols["lum_min"], cols["lum_max"]))


def scoring_context(tree, lighting=None) -> ScoringContext:
    """The device arrays :func:`optim.score` needs for ``tree``: built once, cached on an
    :class:`optim.VertexTree` (other tree-like objects are rebuilt on every call). ``lighting``
    (an :class:`optim.Lighting`, from ``View.lighting``) swaps in the columns of a renderer relighting
    the mesh with it (:func:`optim._relight.relit_columns`); None uses the tree's pre-lit or colour
    luminance (the seeds' baked case) over the triangles each fold changes
    (:func:`optim._relight.region_columns`)."""
    if not isinstance(tree, VertexTree):
        if lighting is not None:
            raise PlodError("score: relit scoring (View.lighting) needs an optim.VertexTree")
        return _build(tree)
    from ._relight import light_key, region_columns, relit_columns

    base = tree.derived("scoring_context.geometry", lambda: _build(tree, lighting is not None))  # every lighting's
    if lighting is None:  # what the triangles a fold changes show (their corners' colours)
        return tree.derived("scoring_context", lambda: _with_columns(base, region_columns(tree)))
    return tree.derived(f"scoring_context.relit.{light_key(lighting)}",
                        lambda: _with_columns(base, relit_columns(tree, lighting)))


# ----------------------------------------------------------------------------------------------
# the per-tree part of the first view, kept beside a cached tree
#: the derived values of a tree that :func:`save_context` keeps (the costly part of a first view: the
#: walk over the faces the folds leave and the normal cones; seconds to tens of seconds at 10^6 triangles)
CONTEXT_NAMES = ("relight.normal_cones", "relight.cull_columns", "relight.neighbour_normals")


def _context_version() -> str:
    """numpy's version and a hash of the source of the modules that build the :data:`CONTEXT_NAMES`
    values: a stored context is read back only by the code (and numpy) that made it."""
    import hashlib
    import inspect

    from . import _levels, _mesh, _normal_cube, _relight, _tree

    h = hashlib.sha256(np.__version__.encode())
    for m in (_relight, _normal_cube, _levels, _mesh, _tree):
        h.update(inspect.getsource(m).encode())
    return h.hexdigest()


def _digest(arrays) -> str:
    import hashlib

    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.reshape(-1).view(np.uint8))  # the raw bytes (memoryview.cast refuses a 0 in the shape)
    return h.hexdigest()


def save_context(tree: VertexTree, path) -> bool:
    """Write the :data:`CONTEXT_NAMES` values ``tree`` holds (made by a first view) to ``path`` (.npz,
    atomically), with the tree's sizes, :func:`_context_version` and a SHA-256 of the arrays; False
    when the tree holds none of them. A cache of the first view's work: :func:`load_context` puts them
    back into another process's copy of the same tree."""
    import json

    from pmetric import atomic_path

    names = [n for n in CONTEXT_NAMES if tree.has_derived(n)]
    if not names:
        return False
    arrays = {f"{i}.{j}": np.asarray(a) for i, n in enumerate(names) for j, a in enumerate(tree.derived(n, None))}
    meta = {"names": names, "version": _context_version(), "sizes": [tree.n_nodes, tree.n_vertices, tree.n_triangles],
            "digest": _digest(arrays[k] for k in sorted(arrays))}
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, __meta__=np.array(json.dumps(meta)), **arrays)
    return True


def load_context(tree: VertexTree, path) -> bool:
    """Put the values of a :func:`save_context` file into ``tree``'s cache; False (and nothing put)
    when the file is missing, unreadable, made by other code or numpy, for a tree of other sizes, or its
    arrays do not match their digest: the first view then builds them as usual."""
    import json
    import zipfile

    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["__meta__"]))
            if (meta.get("version") != _context_version()
                    or meta.get("sizes") != [tree.n_nodes, tree.n_vertices, tree.n_triangles]):
                return False
            arrays = {k: z[k] for k in z.files if k != "__meta__"}
        if _digest(arrays[k] for k in sorted(arrays)) != meta.get("digest"):
            return False
        values = {}
        for i, n in enumerate(meta["names"]):
            if n not in CONTEXT_NAMES:
                return False
            parts, j = [], 0
            while f"{i}.{j}" in arrays:
                parts.append(arrays[f"{i}.{j}"])
                j += 1
            values[n] = tuple(parts)
    except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile):  # damaged or not ours
        return False
    for n, v in values.items():
        for a in v:
            a.flags.writeable = False
        tree.derived(n, lambda v=v: v)  # kept where the tree already holds its own
    return True

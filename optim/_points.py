"""A bounding-sphere hierarchy over points and its perceptual traversal: QSplat [RL00] driven by the
contrast-sensitivity test of [LH01 §4].

**Hierarchy** (:func:`build_points`). Leaves are the input points (mesh vertices with their normals
and colours, or a point cloud: :func:`points_from_mesh`, :func:`load_points`); each leaf's sphere has
the radius of the distance to its ``leaf_k``-th nearest distinct point position, so neighbouring leaf spheres overlap
and their splats tile the surface [RL00]. The tree is binary, built top down by a median split
of every node along the longest side of its points' bounding box, one vectorized pass per level (no
Python loop over nodes); nodes are numbered breadth first with the children of a parent contiguous
(:class:`optim._levels.Levels`). Every internal node

* holds a sphere containing its children's spheres (hence all its descendants' spheres [LH01 §4]):
  centre the middle of the children's spheres' bounding box, radius the largest ``|c - c_i| + r_i``;
* averages its children's colour (linear RGB, weighted by the number of points, i.e. the mean of its
  points' colours) and normal (the normalised sum of its points' unit normals; where they cancel,
  the normal of its first child, the one with the more points, so that every normal is unit);
* holds a normal cone about that normal whose half-angle is exact over its points' normals (the
  largest angle from the axis to one of them; pi when the normals cancel), and ``sil_half``, that cone
  widened to the cones of every node of its level whose sphere intersects its own ([LH01 §4]:
  "account for contained nodes when computing normal cones"; used for the silhouette test with
  ``widen=True``: on the scanned meshes' noisy normals it makes nearly every node a silhouette, so
  the default tests the node's own cone, QSplat's);
* holds the luminance range its splat can change [LH01 §4, Figure 4]: the relative luminances of the
  points of every node of its level (a node's level: the nodes of its depth and the leaves above it,
  a cut covering every point) whose sphere intersects its own, with its own splat's luminance; its
  ``fold_delta`` is the larger distance of the splat's luminance from that range's ends, so
  :func:`optim._terms.contrast_pair` gives the Michelson contrast of drawing the splat instead of its
  descendants, and the silhouette contrast against the scene's extremes [LHNW00 §4.2].

Luminance is what is displayed: the relative luminance of the points' sRGB colours, or for points
without colours their grey intensity pre-lit by an :class:`optim.Lighting` from their normals
(``Lighting.intensity``, the seeds' baked case, as :func:`optim.vertex_luminance` does for meshes).

**Traversal** (:func:`traverse`, [LH01 §4] TraverseHierarchy): from the root, level by level over the
frontier of visited nodes, skip a node outside the view frustum or wholly back facing (its normal cone
against the directions to its sphere: :func:`optim._terms.cone_facing`) together with its subtree;
draw a splat for a leaf or for a node whose simplification is imperceptible; else descend to its
children. Perceptibility is the seed's test with the project's models and term definitions: the
node's worst-case frequency is ``1 / (2 theta)`` cycles/deg with ``theta`` its sphere's projected
diameter (deg) [LH01 §4, Figure 5], its contrast its own (front facing) or the silhouette contrast
(when its cone may face both ways) [LH01 §4; LHNW00 §4.2], its eccentricity the angle from the
nearest gaze point less half of ``theta`` and the gaze error [LHNW00 §4.4]; the splat is drawn iff
``model.is_perceptible(c, f, e)`` is False (any :class:`pmetric.CSFModel`, default
:func:`pmetric.default_model`; below its peak frequency the peak threshold is used [LH01 §3.1]).
``criterion="size"`` is QSplat's own highest-quality traversal: draw once a splat is under
``min_px`` pixels. The perceptual traversal also stops there (``min_px``, default 1 pixel: the
display shows nothing finer [Red01 Eq 5]; 0 turns that off, the pure test of [LH01 §4]).

The per-node terms of one view are evaluated for all nodes in one XLA program (the term functions of
:mod:`optim._terms`: the same frustum, extent, eccentricity, cone and contrast definitions as the
mesh scoring), then the traversal walks the levels in numpy, touching only the visited nodes.

Units: object units for positions and radii; degrees for angles; pixels for projected sizes;
relative luminance in [0, 1] (display luminance in cd/m2 from the view's :class:`pmetric.Display`).
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from pmetric import PlodError

from ._levels import Levels, expand_ranges, level_runs
from ._mesh import COORD_MAX, DIAGONAL_MIN
from ._normal_cube import _unit, unit_any_length

__all__ = ["PointHierarchy", "Traversal", "PointTerms", "build_points", "points_from_mesh", "load_points",
           "save_points", "point_terms", "traverse", "walk", "splat_discs", "CRITERIA"]

CRITERIA = ("perceptual", "size")
#: the largest ``leaf_k`` of :func:`build_points` (its neighbour query takes P * leaf_k memory)
LEAF_K_MAX = 64
#: node columns are padded to a multiple of this many nodes (vectorised XLA loops; see optim._context)
_PAD = 1024


# ----------------------------------------------------------------------------------------------- input


def _real(a, what: str, name: str) -> np.ndarray:
    """``a`` as a float64 array, PlodError for what is not real numbers (complex included: numpy would
    silently drop the imaginary part)."""
    try:
        raw = np.asarray(a)
        out = None if raw.dtype.kind == "c" else np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError):
        raise PlodError(f"{name}: {what} must be a (P, 3) array of numbers") from None
    if out is None:
        raise PlodError(f"{name}: {what} must be real numbers, got complex values")
    return out


def _check_points(points, normals, colors, name: str = "build_points"):
    """(points (P, 3) float64, unit normals (P, 3) float64, colours (P, 3) float64 sRGB or None)."""
    p = _real(points, "points", name)
    if p.ndim != 2 or p.shape[1] != 3:
        raise PlodError(f"{name}: points must have shape (P, 3), got {p.shape}")
    if len(p) == 0:
        raise PlodError(f"{name}: empty point set (no points)")
    if not np.isfinite(p).all():
        raise PlodError(f"{name}: points contain NaN or infinite coordinates "
                        f"(first at point {int(np.flatnonzero(~np.isfinite(p).all(1))[0])})")
    # the scales the float32 traversal handles, as for meshes (measured: a unit sphere's cloud draws the same
    # splats scaled by 1e-18 .. 1e18; at 1e-20 every leaf, at 1e20 one splat)
    big = float(np.abs(p).max())
    if big > COORD_MAX:
        raise PlodError(f"{name}: coordinates up to {big:g} exceed {COORD_MAX:g}; scale the points (a power of "
                        "two keeps them exact)")
    if len(p) > 1:
        diag = float(np.linalg.norm(p.max(0) - p.min(0)))
        if diag < DIAGONAL_MIN:
            what = "all points coincide (bounding-box diagonal 0)" if diag == 0 else \
                f"bounding-box diagonal {diag:g} is below {DIAGONAL_MIN:g}; scale the points (a power of two keeps them exact)"
            raise PlodError(f"{name}: {what}")
    n = _real(normals, "normals", name)
    if n.shape != p.shape:
        raise PlodError(f"{name}: normals must have shape {p.shape} like the points, got {n.shape}")
    if not np.isfinite(n).all():
        raise PlodError(f"{name}: normals contain NaN or infinite values")
    m = np.abs(n).max(1)
    if (m == 0).any():
        raise PlodError(f"{name}: {int((m == 0).sum())} normal(s) are zero (point {int(np.argmin(m))} "
                        "first); every point needs a direction")
    c = None
    if colors is not None:
        c = _real(colors, "colors", name)
        if c.ndim != 2 or c.shape[0] != len(p) or c.shape[1] not in (3, 4):
            raise PlodError(f"{name}: colors must have shape (P, 3) or (P, 4) with P = {len(p)}, got {c.shape}")
        c = c[:, :3]
        if not np.isfinite(c).all():
            raise PlodError(f"{name}: colors contain NaN or infinite values")
        if np.issubdtype(np.asarray(colors).dtype, np.integer):
            raw = np.asarray(colors)[:, :3]
            if raw.min() < 0 or raw.max() > 255:
                raise PlodError(f"{name}: integer colors must lie in [0, 255] (got {raw.min()}..{raw.max()})")
            c = c / 255.0
        if c.min() < 0 or c.max() > 1:
            raise PlodError(f"{name}: float colors must lie in [0, 1] (got {c.min():g}..{c.max():g})")
    return p, unit_any_length(n), c


def points_from_mesh(vertices, faces, colors=None, *, name: str = "points_from_mesh"):
    """(points, unit normals, colours or None) of a mesh's vertices: the area-weighted vertex normals
    of :func:`optim.vertex_luminance`'s shading; vertices on no face (no normal) are dropped.
    PlodError when no vertex is left (every face degenerate: zero area)."""
    from ._mesh import validate_mesh
    from ._tree import _vertex_normals

    m = validate_mesh(vertices, faces, colors, name=name, count_nonmanifold=False)
    v, f = np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64)
    n = _vertex_normals(v, f)
    ok = np.linalg.norm(n, axis=1) > 0
    if not ok.any():
        raise PlodError(f"{name}: every face is degenerate (zero area), so no vertex has a normal; no points")
    c = None if m.colors is None else np.asarray(m.colors)[ok]
    return v[ok], _unit(n[ok]), c


def load_points(path):
    """(points (P, 3), unit normals (P, 3), sRGB colours (P, 3) in [0, 1] or None) from a file: a
    triangle mesh (its vertices, :func:`points_from_mesh`) or a point-cloud PLY with ``nx, ny, nz``
    normals (and optional ``red, green, blue``), read with trimesh. PlodError for anything else: a path
    that is not a file name, an ASCII PLY whose rows disagree with its header, a mesh of degenerate faces."""
    import trimesh

    if not isinstance(path, (str, os.PathLike)):
        raise PlodError(f"load_points: path must be a file name (str or os.PathLike), got {type(path).__name__}")
    p = Path(path)
    if not p.exists():
        raise PlodError(f"point file {str(p)!r} does not exist")
    if p.is_dir():
        raise PlodError(f"{str(p)!r} is a directory, not a point or mesh file")
    if p.suffix.lower() == ".ply":
        _check_ascii_ply(p)
    try:
        obj = trimesh.load(str(p), process=False)
    except Exception as exc:  # trimesh raises many kinds on unreadable files
        raise PlodError(f"cannot read point file {str(p)!r}: {type(exc).__name__}: {exc}") from None
    if isinstance(obj, trimesh.Scene):
        meshes = [g for g in obj.geometry.values() if isinstance(g, trimesh.Trimesh)]
        if not meshes:
            raise PlodError(f"point file {str(p)!r} holds neither a mesh nor a point cloud")
        obj = trimesh.util.concatenate(meshes)
    if isinstance(obj, trimesh.Trimesh) and len(obj.faces):
        from ._mesh import load_mesh

        v, f, c = load_mesh(p)
        return points_from_mesh(v, f, c, name=f"point file {str(p)!r}")
    if not isinstance(obj, (trimesh.PointCloud, trimesh.Trimesh)):
        raise PlodError(f"point file {str(p)!r} holds a {type(obj).__name__}, not points")
    raw = obj.metadata.get("_ply_raw", {}).get("vertex", {}).get("data") if p.suffix.lower() == ".ply" else None
    if isinstance(raw, np.ndarray) and raw.dtype.names:  # binary PLY: a structured array
        raw = {k: raw[k] for k in raw.dtype.names}
    if not isinstance(raw, dict) or not all(k in raw for k in ("nx", "ny", "nz")):
        raise PlodError(f"point file {str(p)!r}: a point cloud needs per-point normals (PLY properties nx, ny, nz)")
    col = lambda k: np.asarray(raw[k], np.float64).reshape(-1)  # noqa: E731
    normals = np.stack([col("nx"), col("ny"), col("nz")], axis=1)
    colors = None
    if all(k in raw for k in ("red", "green", "blue")):
        rgb = np.stack([col("red"), col("green"), col("blue")], axis=1)
        colors = rgb / 255.0 if np.asarray(raw["red"]).dtype.kind in "ui" else rgb
    return _check_points(np.asarray(obj.vertices, np.float64), normals, colors, name=f"point file {str(p)!r}")


def _check_ascii_ply(p: Path) -> None:
    """PlodError naming ``p`` when an ASCII PLY's data rows disagree with its header (trimesh reads the
    rows it finds: a truncated file lost points silently, several points on one line read as one): the
    number of rows must be the sum of the header's element counts, and each row of an element without
    list properties must hold one number per property. Binary PLYs are left to trimesh (it checks the
    length)."""
    with open(p, "rb") as fh:
        start = fh.read(1 << 16)
    end = start.find(b"end_header")
    if not start.startswith(b"ply") or end < 0 or b"format ascii" not in start[:end]:
        return  # not an ASCII PLY with a header trimesh can read: trimesh's error names it
    elements = []  # (name, count, number of properties, has a list property)
    for line in start[:end].decode("latin-1").splitlines():
        w = line.split()
        if len(w) == 3 and w[0] == "element":
            try:
                elements.append([w[1], int(w[2]), 0, False])
            except ValueError:
                raise PlodError(f"point file {str(p)!r}: bad PLY header line {line.strip()!r}") from None
        elif w and w[0] == "property" and elements:
            elements[-1][2] += 1
            elements[-1][3] |= len(w) > 1 and w[1] == "list"
    data = p.read_bytes()
    body = data[data.find(b"\n", end) + 1:].decode("latin-1").splitlines()
    while body and not body[-1].strip():
        body.pop()
    want = sum(e[1] for e in elements)
    if len(body) != want:
        counts = ", ".join(f"{e[1]} {e[0]}" for e in elements)
        raise PlodError(f"point file {str(p)!r}: its PLY header declares {want} data rows ({counts}) but the file "
                        f"has {len(body)}; the file is truncated or malformed")
    row = 0
    for name, count, n_props, has_list in elements:
        rows = body[row:row + count]
        row += count
        if has_list:
            continue
        sizes = np.fromiter((len(r.split()) for r in rows), np.int64, count)
        bad = np.flatnonzero(sizes != n_props)
        if len(bad):
            raise PlodError(f"point file {str(p)!r}: {name} row {int(bad[0])} has {int(sizes[bad[0]])} values, the "
                            f"header declares {n_props} properties; the file is malformed")
        try:
            np.array(" ".join(rows).split(), dtype=np.float64)
        except ValueError:
            raise PlodError(f"point file {str(p)!r}: a {name} row holds something that is not a number") from None


def save_points(path, points, normals, colors=None, *, protect=()) -> Path:
    """Write a binary point-cloud PLY (``x y z`` float64, so that :func:`load_points` reads the points
    back exactly, far from 0 too; ``nx ny nz`` float32 unit normals; ``red green blue`` uint8 when colours
    are given) atomically. ``protect``: input files never overwritten (one path or several)."""
    import pmetric as pm

    p, n, c = _check_points(points, normals, colors, name="save_points")
    fields = [(k, "<f8") for k in ("x", "y", "z")] + [(k, "<f4") for k in ("nx", "ny", "nz")]
    if c is not None:
        fields += [(k, "u1") for k in ("red", "green", "blue")]
    rec = np.empty(len(p), dtype=fields)
    for i, k in enumerate("xyz"):
        rec[k], rec["n" + k] = p[:, i], n[:, i]
    if c is not None:
        for i, k in enumerate(("red", "green", "blue")):
            rec[k] = np.round(c[:, i] * 255.0)
    ply_type = {"<f8": "double", "<f4": "float", "u1": "uchar"}
    props = "".join(f"property {ply_type[t]} {k}\n" for k, t in fields)
    head = f"ply\nformat binary_little_endian 1.0\nelement vertex {len(p)}\n{props}end_header\n".encode("ascii")
    out = Path(path)
    with pm.atomic_path(out, protect=protect) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(head + rec.tobytes())
    return out


# ----------------------------------------------------------------------------------------------- hierarchy
@dataclasses.dataclass(frozen=True, eq=False)
class PointHierarchy:
    """A bounding-sphere hierarchy over P points, N nodes numbered breadth first (root 0, children of a
    parent contiguous at ``child_start : child_start + child_count``).

    Per node (N,): ``center`` (N, 3) and ``radius`` (object units; a sphere holding every descendant's
    sphere); ``normal`` (N, 3) unit (where its points' normals cancel: its first child's, and
    ``cone_half`` is pi), ``cone_half`` (rad) the cone about it holding every point normal
    below, ``sil_half`` (rad) that cone widened to the cones of the intersecting nodes of its level (the
    silhouette test); ``rgb`` (N, 3) linear RGB of the splat (mean of its points); ``lum`` relative
    luminance of the splat; ``lum_min``, ``lum_max`` the luminance range its splat can change (its
    level's intersecting nodes' points and its own splat); ``fold_delta`` the larger distance of
    ``lum`` from that range's ends (0 for leaves); ``parent``, ``child_start``, ``child_count``,
    ``depth``; ``point`` the input point of a leaf (-1 for internal nodes); ``point_lo``,
    ``point_hi`` the node's points are ``order[point_lo:point_hi]``. ``levels`` the
    :class:`optim._levels.Levels` structure; ``colored``: whether the points had colours."""

    center: np.ndarray
    radius: np.ndarray
    normal: np.ndarray
    cone_half: np.ndarray
    sil_half: np.ndarray
    rgb: np.ndarray
    lum: np.ndarray
    lum_min: np.ndarray
    lum_max: np.ndarray
    fold_delta: np.ndarray
    parent: np.ndarray
    child_start: np.ndarray
    child_count: np.ndarray
    depth: np.ndarray
    point: np.ndarray
    point_lo: np.ndarray
    point_hi: np.ndarray
    order: np.ndarray
    levels: Levels
    colored: bool
    _cache: dict = dataclasses.field(default_factory=dict, repr=False)

    @property
    def n_nodes(self) -> int:
        return len(self.radius)

    @property
    def n_points(self) -> int:
        return len(self.order)

    @property
    def leaves(self) -> np.ndarray:
        """Node indices of the leaves (one per input point)."""
        return np.flatnonzero(self.child_count == 0)

    def srgb(self, nodes=None) -> np.ndarray:
        """(K, 3) float32 sRGB in [0, 1] of the splats of ``nodes`` (K,) node indices in [0, n_nodes)
        (default all nodes)."""
        from pmetric import linear_to_srgb

        rgb = self.rgb if nodes is None else self.rgb[_node_indices(self, nodes, "srgb")]
        return np.array(linear_to_srgb(np.asarray(rgb, np.float32)), np.float32)


def _split_levels(p: np.ndarray):
    """Top-down median split, one vectorized pass per level: (order (P,) the points in depth-first leaf
    order, per level the (lo, hi) point ranges of its nodes in breadth-first order)."""
    order = np.arange(len(p))
    lo, hi = np.array([0]), np.array([len(p)])
    levels = []
    while len(lo):
        levels.append((lo, hi))
        split = hi - lo > 1
        slo, shi = lo[split], hi[split]
        if not len(slo):
            break
        size = shi - slo
        idx = expand_ranges(slo, size)
        off = np.cumsum(size) - size
        pts = p[order[idx]]
        span = np.maximum.reduceat(pts, off, axis=0) - np.minimum.reduceat(pts, off, axis=0)
        axis = np.argmax(span, axis=1)
        seg = np.repeat(np.arange(len(slo)), size)
        # stable sort by (segment, coordinate along the segment's longest axis); segments are ascending
        srt = np.lexsort((pts[np.arange(len(idx)), axis[seg]], seg))
        order[idx] = order[idx][srt]
        mid = slo + (size + 1) // 2
        lo = np.stack([slo, mid], axis=1).ravel()
        hi = np.stack([mid, shi], axis=1).ravel()
    return order, levels


def _level_sets(depth: np.ndarray, is_leaf: np.ndarray):
    """Per depth d, the nodes of a cut covering every point: depth d and the leaves above it."""
    n_levels = int(depth.max()) + 1
    for d in range(n_levels):
        yield d, np.flatnonzero((depth == d) | (is_leaf & (depth < d)))


def _intersecting(center, radius, query, pool):
    """Pairs (q, m) with ``query[q]``'s sphere intersecting the sphere of ``pool[m]`` (``query`` is a
    subset of ``pool``; each query meets itself): (query positions, pool nodes) grouped by query in
    order, group offsets and counts. One dual-tree pass (``cKDTree.query_pairs``) finds the pairs
    within twice the 99th-percentile radius; the few larger spheres are queried one by one."""
    from scipy.spatial import cKDTree

    c, r = center[pool], radius[pool]
    tree = cKDTree(c)
    r_q = float(np.quantile(r, 0.99))
    pairs = [tree.query_pairs(2.0 * r_q, output_type="ndarray").astype(np.intp)]
    big = np.flatnonzero(r > r_q)
    if len(big):
        hits = tree.query_ball_point(c[big], r[big] + float(r.max()), return_sorted=False)
        cnt = np.fromiter((len(x) for x in hits), np.intp, len(hits))
        pairs.append(np.stack([np.repeat(big, cnt), np.concatenate([np.asarray(x, np.intp) for x in hits])], 1))
    pr = np.concatenate(pairs)
    pr = np.concatenate([pr, pr[:, ::-1], np.repeat(np.arange(len(pool)), 2).reshape(-1, 2)])
    pr = pr[np.linalg.norm(c[pr[:, 0]] - c[pr[:, 1]], axis=1) <= (r[pr[:, 0]] + r[pr[:, 1]]) * (1 + 1e-9)]
    pos = np.full(len(radius), -1, np.intp)
    pos[query] = np.arange(len(query))
    qpos = pos[pool[pr[:, 0]]]
    keep = qpos >= 0
    key = np.unique(qpos[keep] * len(pool) + pr[keep, 1])  # sorted by query, duplicates removed
    q, m = key // len(pool), pool[key % len(pool)]
    cnt = np.bincount(q, minlength=len(query))
    return q, m, np.cumsum(cnt) - cnt, cnt


def _angle(a, b):
    """Angle (rad) between unit row vectors a, b (K, 3)."""
    return np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0))


def build_points(points, normals, colors=None, *, lighting=None, leaf_k: int = 4, progress=None) -> PointHierarchy:
    """The bounding-sphere hierarchy over ``points`` (P, 3) with unit-length-or-not ``normals`` (P, 3)
    and optional sRGB ``colors`` (P, 3) in [0, 1] (or 0-255 integers); see the module docstring.

    ``lighting`` (:class:`optim.Lighting` or what ``Lighting.coerce`` takes; default its default)
    pre-lights uncoloured points from their normals (ignored with colours: colours are displayed
    as they are, as in the baked renderer). ``leaf_k`` (1 .. :data:`LEAF_K_MAX`): a leaf's radius is the
    distance to its ``leaf_k``-th nearest distinct position (coincident copies of a point do not count;
    fewer when there are fewer distinct positions; 0 for a single point).
    ``progress(stage, done, total)`` is called per stage. PlodError (one line) for bad input.
    """
    from scipy.spatial import cKDTree

    import pmetric as pm

    from ._tree import Lighting

    p, n_in, c = _check_points(points, normals, colors)
    if not isinstance(leaf_k, (int, np.integer)) or isinstance(leaf_k, bool) or not 1 <= leaf_k <= LEAF_K_MAX:
        raise PlodError(f"build_points: leaf_k must be a positive integer up to {LEAF_K_MAX}, got {leaf_k!r}")
    if progress is not None and not callable(progress):
        raise PlodError(f"build_points: progress must be None or a callable (stage, done, total), got {progress!r}")
    report = progress if progress is not None else (lambda *a: None)
    P = len(p)
    report("split", 0, 4)
    order, levels = _split_levels(p)
    lo = np.concatenate([lv[0] for lv in levels])
    hi = np.concatenate([lv[1] for lv in levels])
    depth = np.concatenate([np.full(len(lv[0]), d) for d, lv in enumerate(levels)])
    N = len(lo)
    is_leaf = hi - lo == 1
    child_count = np.where(is_leaf, 0, 2).astype(np.int64)
    child_start = np.where(is_leaf, 0, 1 + np.cumsum(child_count) - child_count)  # children follow in order
    parent = np.full(N, -1, np.int64)
    internal = np.flatnonzero(~is_leaf)
    parent[child_start[internal]] = internal
    parent[child_start[internal] + 1] = internal
    start = np.searchsorted(depth, np.arange(int(depth[-1]) + 2))
    lv = Levels(parent, start)
    point = np.where(is_leaf, order[lo], -1)
    leaves = np.flatnonzero(is_leaf)

    report("leaves", 1, 4)
    # distinct positions (+ 0.0: -0.0 is 0.0): coincident copies of a point are not its neighbours
    uniq, inv = np.unique(p + 0.0, axis=0, return_inverse=True)
    k = min(int(leaf_k), len(uniq) - 1)
    r_leaf = np.zeros(P)
    if k >= 1:
        dist, _ = cKDTree(uniq).query(uniq, k=k + 1)
        r_leaf = np.asarray(dist)[:, -1][inv.reshape(-1)]
    if c is not None:  # linear light, so that a node's luminance is the mean of its points'
        lin = np.asarray(pm.srgb_to_linear(c.astype(np.float32)), np.float64)
    else:
        lin = np.repeat(Lighting.coerce(lighting).intensity(n_in).astype(np.float64)[:, None], 3, axis=1)

    # sums over each node's contiguous run of points (depth-first order): colour and normal averages
    cs = lambda a: np.concatenate([np.zeros((1,) + a.shape[1:]), np.cumsum(a[order], axis=0)])  # noqa: E731
    count = (hi - lo).astype(np.float64)
    rgb = (cs(lin)[hi] - cs(lin)[lo]) / count[:, None]
    nsum = cs(n_in)[hi] - cs(n_in)[lo]
    normal = _unit(nsum)
    cancel = np.linalg.norm(nsum, axis=1) <= 1e-9 * count  # normals cancel: the cone is every direction
    for i in np.flatnonzero(cancel)[::-1]:  # deepest first: a child's normal is final before its parent's
        normal[i] = normal[child_start[i]]  # the first child has the more points (or as many)
    lum = np.asarray(pm.relative_luminance(rgb), np.float64)

    report("spheres", 2, 4)
    center = np.zeros((N, 3))
    radius = np.zeros(N)
    center[leaves], radius[leaves] = p[point[leaves]], r_leaf[point[leaves]]
    for g in range(len(lv.groups) - 1, 0, -1):  # deepest level first: spheres holding the children's
        a, b, seg, pids = lv.groups[g]
        if not len(pids):
            continue
        cc, rr = center[a:b], radius[a:b]
        box_lo = np.minimum.reduceat(cc - rr[:, None], seg, axis=0)
        box_hi = np.maximum.reduceat(cc + rr[:, None], seg, axis=0)
        center[pids] = 0.5 * (box_lo + box_hi)
        reach = np.linalg.norm(cc - center[parent[a:b]], axis=1) + rr
        radius[pids] = np.maximum.reduceat(reach, seg) * (1 + 1e-7)  # round outward
    # normal cones, exact over each node's points (one pass per level over its points)
    n_sorted = n_in[order]
    cone = np.zeros(N)
    for nodes, idx, off in level_runs(start, lo, hi - lo, ~is_leaf):
        dots = np.einsum("ij,ij->i", np.repeat(normal[nodes], hi[nodes] - lo[nodes], axis=0), n_sorted[idx])
        cone[nodes] = np.arccos(np.clip(np.minimum.reduceat(dots, off), -1.0, 1.0))
    cone[cancel] = np.pi  # normals cancel: any direction
    cone = np.minimum(cone * (1 + 1e-6) + 1e-6 * ~is_leaf, np.pi)

    report("neighbours", 3, 4)
    lmin = lv.reduce_up(np.where(is_leaf, lum, np.inf), np.minimum)
    lmax = lv.reduce_up(np.where(is_leaf, lum, -np.inf), np.maximum)
    lum_min, lum_max, sil = lmin.copy(), lmax.copy(), cone.copy()
    for d, pool in _level_sets(depth, is_leaf):
        query = np.flatnonzero(depth == d)
        q, m, off, cnt = _intersecting(center, radius, query, pool)
        if not len(q):
            continue
        has = cnt > 0
        qs, offs = query[has], off[has]
        lum_min[qs] = np.minimum(lum_min[qs], np.minimum.reduceat(lmin[m], offs))
        lum_max[qs] = np.maximum(lum_max[qs], np.maximum.reduceat(lmax[m], offs))
        wide = np.minimum(_angle(normal[query[q]], normal[m]) + cone[m], np.pi)
        sil[qs] = np.maximum(sil[qs], np.maximum.reduceat(wide, offs))
    lum_min, lum_max = np.minimum(lum_min, lum), np.maximum(lum_max, lum)
    delta = np.maximum(lum_max - lum, lum - lum_min)
    delta[is_leaf] = 0.0
    report("done", 4, 4)
    ro = lambda a: _readonly(np.ascontiguousarray(a))  # noqa: E731
    return PointHierarchy(
        center=ro(center), radius=ro(radius), normal=ro(normal), cone_half=ro(cone), sil_half=ro(sil),
        rgb=ro(rgb), lum=ro(lum), lum_min=ro(lum_min), lum_max=ro(lum_max), fold_delta=ro(delta),
        parent=ro(parent), child_start=ro(child_start), child_count=ro(child_count), depth=ro(depth),
        point=ro(point), point_lo=ro(lo), point_hi=ro(hi), order=ro(order), levels=lv, colored=c is not None)


def _node_indices(h: PointHierarchy, nodes, who: str) -> np.ndarray:
    """``nodes`` as a (K,) intp array of node indices of ``h``; PlodError unless a 1-D integer array
    with every index in [0, n_nodes) (negative indices do not wrap)."""
    raw = np.asarray(nodes)
    if raw.ndim != 1 or not (np.issubdtype(raw.dtype, np.integer) or raw.size == 0):
        raise PlodError(f"{who}: nodes must be a 1-D array of node indices, got {raw.dtype} {raw.shape}")
    if raw.size and (raw.min() < 0 or raw.max() >= h.n_nodes):  # checked before the cast: uint64 would wrap
        raise PlodError(f"{who}: node indices must lie in [0, {h.n_nodes}), got {raw.min()}..{raw.max()}")
    return raw.astype(np.intp)


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


# ----------------------------------------------------------------------------------------------- per view
class _Cols(NamedTuple):
    """Device columns of every node (padded), with the field names the term functions of
    :mod:`optim._terms` read (``cull_radius`` = the sphere: a splat touches nothing outside it)."""

    cx: jnp.ndarray
    cy: jnp.ndarray
    cz: jnp.ndarray
    radius: jnp.ndarray
    cull_radius: jnp.ndarray
    ax: jnp.ndarray
    ay: jnp.ndarray
    az: jnp.ndarray
    cone_cos: jnp.ndarray
    cone_sin: jnp.ndarray
    lum_min: jnp.ndarray
    lum_max: jnp.ndarray
    fold_delta: jnp.ndarray


def _origin(h: PointHierarchy) -> np.ndarray:
    """(3,) float64: the origin of the float32 columns (:func:`optim._tree.local_origin` of the points:
    0 unless the cloud lies far from 0 for its size, as georeferenced scans do)."""
    if "origin" not in h._cache:
        from ._tree import local_origin

        h._cache["origin"] = local_origin(h.center[h.child_count == 0])
    return h._cache["origin"]


def _columns(h: PointHierarchy, widen: bool):
    """(own-cone columns, silhouette-cone columns): the hierarchy as padded float32 device columns;
    the silhouette cone is ``sil_half`` when ``widen``, else the node's own cone."""
    if "cols" not in h._cache:
        pad = -h.n_nodes % _PAD
        f = lambda a: jnp.asarray(np.concatenate([np.asarray(a, np.float32), np.zeros(pad, np.float32)]))  # noqa: E731
        half = lambda a: np.minimum(a, np.pi / 2)  # noqa: E731  (cone_facing takes half-angles up to 90 deg)
        c = np.asarray(h.center, np.float64) - _origin(h)  # float32 relative to the origin (optim.local_origin)
        cols = _Cols(f(c[:, 0]), f(c[:, 1]), f(c[:, 2]), f(h.radius), f(h.radius),
                     f(h.normal[:, 0]), f(h.normal[:, 1]), f(h.normal[:, 2]), f(np.cos(half(h.cone_half))),
                     f(np.sin(half(h.cone_half))), f(h.lum_min), f(h.lum_max), f(h.fold_delta))
        h._cache["cols"] = (cols, cols._replace(cone_cos=f(np.cos(half(h.sil_half))),
                                                cone_sin=f(np.sin(half(h.sil_half)))))
    cols, wide = h._cache["cols"]
    return cols, (wide if widen else cols)


@eqx.filter_jit
def _terms_program(cols, sil_cols, vp, model, has_gaze):
    """Per-node terms of one view (padded arrays): culled, backfacing, silhouette, size_px, theta, ecc,
    contrast, frequency, perceptible."""
    from ._terms import (_geometry, cone_facing, contrast_pair, eccentricity, extent, frustum_culled,
                         select_contrast)

    g = _geometry(cols, vp)
    front, _ = cone_facing(cols, vp, g)
    s_front, s_back = cone_facing(sil_cols, vp, g)
    backfacing = ~front
    culled = frustum_culled(cols, vp, g) | backfacing
    silhouette = s_front & s_back
    size_px, theta = extent(vp, g)
    ecc = eccentricity(vp, g, theta) if has_gaze else jnp.zeros_like(theta)
    c_own, c_sil = contrast_pair(cols, vp)
    contrast = select_contrast(silhouette, c_own, c_sil)
    pos = theta > 0
    freq = jnp.where(pos, 0.5 / jnp.where(pos, theta, 1.0), jnp.inf)  # worst case: period 2 theta [LH01 Fig 5]
    perceptible = pos & model.is_perceptible(contrast, jnp.where(pos, freq, 1.0), ecc)
    return culled, backfacing, silhouette, size_px, theta, ecc, contrast, freq, perceptible


class PointTerms(NamedTuple):
    """Per-node terms of one view (N,) numpy: ``culled`` (outside the frustum or wholly back facing:
    the node and its subtree are skipped), ``backfacing``, ``silhouette`` (its cone may face both
    ways), ``size_px`` projected sphere diameter (pixels), ``theta`` its visual angle (deg),
    ``eccentricity`` (deg), ``contrast`` (Michelson; a silhouette node's: its silhouette contrast),
    ``frequency`` the worst-case frequency ``1 / (2 theta)`` (cycles/deg; inf for a point of no
    extent), ``perceptible``: ``model.is_perceptible(contrast, frequency, eccentricity)`` (below the
    model's peak frequency its peak threshold is used [LH01 §3.1]): drawing the node's splat instead
    of its descendants might be seen."""

    culled: np.ndarray
    backfacing: np.ndarray
    silhouette: np.ndarray
    size_px: np.ndarray
    theta: np.ndarray
    eccentricity: np.ndarray
    contrast: np.ndarray
    frequency: np.ndarray
    perceptible: np.ndarray


def _model(model):
    import pmetric

    if model is None:
        return pmetric.default_model()
    if isinstance(model, str):
        return pmetric.make_model(model)
    if not isinstance(model, pmetric.CSFModel):
        raise PlodError(f"traverse: model must be a pmetric.CSFModel or a model name, got {type(model).__name__}")
    return model


def point_terms(h: PointHierarchy, view, model=None, *, widen: bool = False) -> PointTerms:
    """The terms of every node of ``h`` for ``view`` (an :class:`optim.View`), one XLA program;
    ``model``: a :class:`pmetric.CSFModel` or a registry name (:func:`pmetric.make_model`; default
    :func:`pmetric.default_model`). ``widen``: test silhouettes with the cone widened to the
    intersecting nodes (``sil_half``) instead of the node's own cone (the default: QSplat's cone and
    the seed's "neither entirely back facing nor entirely front facing" test; on scanned surfaces
    with noisy normals the widened cone makes nearly every node a silhouette).

    The test is the seed's ``IsPerceptible(frequency, contrast)`` at the current view, not the
    imperceptible-distance key of :func:`optim.score` (``key <= 1`` also asks that the change stay
    invisible from farther away, where the node moves towards the gaze, so a peripheral node would
    almost never qualify)."""
    from ._terms import view_params
    from ._view import View

    if not isinstance(h, PointHierarchy):
        raise PlodError(f"traverse: expected a PointHierarchy (optim._points.build_points), got {type(h).__name__}")
    if not isinstance(view, View):
        raise PlodError(f"traverse: view must be an optim.View, got {type(view).__name__}")
    m = _model(model)
    vp = view_params(view, (float(np.clip(h.lum_min.min(), 0, 1)), float(np.clip(h.lum_max.max(), 0, 1))),
                     _origin(h))
    cols, sil_cols = _columns(h, bool(widen))
    out = _terms_program(cols, sil_cols, vp, m, view.gaze_px is not None)
    n = h.n_nodes
    return PointTerms(*(np.asarray(x)[:n] for x in out))


class Traversal(NamedTuple):
    """One traversal: ``drawn`` node indices whose splats are drawn, ``skipped`` the culled nodes where
    the walk stopped (their subtrees are not visited), ``visited`` the number of nodes visited;
    ``terms`` the :class:`PointTerms` it used."""

    drawn: np.ndarray
    skipped: np.ndarray
    visited: int
    terms: PointTerms

    @property
    def splats(self) -> int:
        return len(self.drawn)


def _node_flags(h, a, name: str, who: str) -> np.ndarray:
    a = np.asarray(a)
    if a.shape != (h.n_nodes,) or a.dtype != np.bool_:
        raise PlodError(f"{who}: {name} must be a bool array of shape ({h.n_nodes},) (one per node), got {a.dtype} "
                        f"{a.shape}")
    return a


def walk(h: PointHierarchy, culled: np.ndarray, stop: np.ndarray):
    """The traversal of [LH01 §4] over per-node flags, level by level from the root: a ``culled``
    node is skipped with its subtree, a leaf or a ``stop`` node is drawn, any other node is replaced
    by its children. Returns (drawn, skipped, visited)."""
    if not isinstance(h, PointHierarchy):
        raise PlodError(f"walk: h must be a PointHierarchy, got {type(h).__name__}")
    culled, stop = _node_flags(h, culled, "culled", "walk"), _node_flags(h, stop, "stop", "walk")
    frontier = np.zeros(1, np.intp)
    drawn, skipped, visited = [], [], 0
    leaf = h.child_count == 0
    while len(frontier):
        visited += len(frontier)
        c = culled[frontier]
        skipped.append(frontier[c])
        f = frontier[~c]
        s = stop[f] | leaf[f]
        drawn.append(f[s])
        d = f[~s]
        frontier = expand_ranges(h.child_start[d], h.child_count[d])
    return np.concatenate(drawn), np.concatenate(skipped), visited


def traverse(h: PointHierarchy, view, model=None, *, criterion: str = "perceptual", min_px: float = 1.0,
             widen: bool = False, terms: PointTerms | None = None) -> Traversal:
    """The splats to draw for ``view``: QSplat's traversal with the stopping rule ``criterion``:

    * ``"perceptual"`` [LH01 §4]: draw a node whose splat is imperceptible (not ``perceptible``,
      see :func:`point_terms`) or smaller than ``min_px`` pixels (default 1: below the display's pixel;
      0 for the pure perceptual test);
    * ``"size"``: QSplat's highest-quality rendering: draw a node whose splat is under ``min_px``
      pixels (projected sphere diameter).

    Out-of-frustum and back-facing nodes are skipped with their subtrees in both. ``model``,
    ``widen``: as :func:`point_terms`; ``terms``: reuse terms already computed for this view."""
    if not isinstance(h, PointHierarchy):
        raise PlodError(f"traverse: h must be a PointHierarchy (optim.build_points), got {type(h).__name__}")
    if not isinstance(criterion, str) or criterion not in CRITERIA:
        raise PlodError(f"traverse: criterion must be one of {CRITERIA}, got {criterion!r}")
    try:
        px = float(min_px)
    except (TypeError, ValueError):
        raise PlodError(f"traverse: min_px must be a number of pixels >= 0, got {min_px!r}") from None
    if not np.isfinite(px) or px < 0:
        raise PlodError(f"traverse: min_px must be a finite number of pixels >= 0, got {min_px!r}")
    if terms is not None and (not isinstance(terms, PointTerms) or np.shape(terms.culled) != (h.n_nodes,)):
        raise PlodError(f"traverse: terms must be the PointTerms of this hierarchy ({h.n_nodes} nodes), from "
                        "point_terms(h, view)")
    t = terms if terms is not None else point_terms(h, view, model, widen=widen)
    small = t.size_px <= px
    stop = small if criterion == "size" else (small | ~t.perceptible)
    drawn, skipped, visited = walk(h, t.culled, stop)
    return Traversal(drawn, skipped, visited, t)


# ----------------------------------------------------------------------------------------------- splats
def splat_discs(h: PointHierarchy, nodes, *, segments: int = 8, tint=None):
    """A triangle mesh of the splats of ``nodes``: one disc per node, centred on its sphere's centre,
    of its radius, in the plane across its normal, wound counter-clockwise seen from the normal (so a
    renderer culling back faces drops back-facing splats). Returns (vertices (K (S+1), 3) float64,
    faces (K S, 3) int64, sRGB colours (K (S+1), 3) float32); ``tint`` (K, 3) sRGB overrides colours."""
    if not isinstance(h, PointHierarchy):
        raise PlodError(f"splat_discs: h must be a PointHierarchy, got {type(h).__name__}")
    nodes = _node_indices(h, nodes, "splat_discs")
    if not isinstance(segments, (int, np.integer)) or isinstance(segments, bool) or segments < 3:
        raise PlodError(f"splat_discs: segments must be an integer >= 3, got {segments!r}")
    s = int(segments)
    if tint is not None:
        try:
            tint = np.asarray(tint, np.float32)
        except (TypeError, ValueError):
            tint = None
        if tint is None or tint.shape != (len(nodes), 3) or not np.isfinite(tint).all() or tint.min() < 0 \
                or tint.max() > 1:
            raise PlodError(f"splat_discs: tint must be ({len(nodes)}, 3) sRGB colours in [0, 1]")
    nrm = h.normal[nodes]
    helper = np.where(np.abs(nrm[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = _unit(np.cross(nrm, helper))
    w = np.cross(nrm, u)  # (u, w, n) right-handed: counter-clockwise about n
    ang = 2 * np.pi * np.arange(s) / s
    rim = np.cos(ang)[None, :, None] * u[:, None] + np.sin(ang)[None, :, None] * w[:, None]
    rim = rim * h.radius[nodes][:, None, None]
    c = h.center[nodes][:, None]
    v = np.concatenate([c, c + rim], axis=1).reshape(-1, 3)
    base = (np.arange(len(nodes)) * (s + 1))[:, None]
    j = np.arange(s)[None]
    f = np.stack([base + 0 * j, base + 1 + j, base + 1 + (j + 1) % s], axis=-1).reshape(-1, 3)
    col = h.srgb(nodes) if tint is None else tint
    return v, f.astype(np.int64), np.repeat(col, s + 1, axis=0)

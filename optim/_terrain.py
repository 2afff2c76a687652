"""Reddy's perceptually driven terrain quadtree [Red01 §"Perceptually based terrain"], vectorized by level.

A heightfield of ``N x N`` samples (``N = 2^L + 1``) is covered by a quadtree: level ``l`` has
``2^l x 2^l`` squares of ``2^(L-l)`` sample spacings each. Each frame starts from the single root square
and splits, level by level, every square that is

* geometrically refinable: some sample inside it leaves the plane of its two triangles (the nested
  maximum of the vertical error is > ``tol``; a flat or planar region never splits), and
* not culled (``cull``): its bounding box is not wholly outside the field of view, and
* perceptible (``size``): its angular extent ``s`` (deg, largest angle between two of its four corners
  seen from the eye) satisfies ``s >= 1 / (2 H'(v, e))`` with ``H' = min(xi, G(v) M(e))`` cycles/deg
  from :class:`pmetric.ReddyAcuity` [Red01 Eq 4-5]. ``e`` (``periphery``) is the shortest angular
  distance (deg) from the gaze to the square's edges (0 when the gaze falls inside it); ``v``
  (``velocity``) is the retinal velocity (deg/s): the angle a corner travelled between successive
  frames over the time step, averaged over the last frames, smallest over the four corners.

Without ``size`` a refinable visible square always splits (``periphery`` and ``velocity`` act only
through the size test, as in [Red01 Table 1]). The split set is then closed into a *restricted*
quadtree (edge-adjacent leaves differ by at most one level, one bottom-up pass) and each leaf is
triangulated as two triangles, or as a fan around its centre through the midpoints of the edges whose
neighbour is finer: the output has no T-junctions and so no cracks. Culled leaves are not drawn.
Adding a criterion never adds a split; it can add triangles only through a leaf the view's edge crosses
(at most :func:`straddle_triangles`), and none with ``TerrainCriteria(split_view_edge=True)``, which
splits such squares to the finest level (a few percent more triangles on a flight).

Units: heights and spacing in metres (any length unit, consistently), angles in degrees, time in
seconds, velocity deg/s, frequency cycles/deg. Cameras: :class:`TerrainCamera` (world: x = column
spacing, y = height, z = row spacing; right-handed, y up).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from pmetric import PlodError

from ._mesh import real_or_nan
from ._normal_cube import unit_any_length

__all__ = ["Heightfield", "TerrainCamera", "TerrainCriteria", "TerrainLOD", "refine_terrain",
           "terrain_mesh", "full_mesh", "fractal_heightfield", "crop_heightfield"]


_MAX_COORD = 1e12  # m: heights, grid extent and eye coordinates beyond this would overflow the squares


# ----------------------------------------------------------------------------------------------- data
class Heightfield:
    """A square heightfield of ``N = 2^L + 1`` samples per side with its quadtree pyramid.

    ``heights`` (N, N) metres (row 0 at z = 0), ``spacing`` metres between samples. Precomputes per
    level ``l`` (0..L) the nested maximum vertical error (m) of each square against its two triangles
    (diagonal from corner (0, 0) to (1, 1)), and its minimum and maximum height (m) for culling. Keeps
    its own read-only copy of the heights.
    Raises :class:`PlodError` for an empty grid, a grid that is not square ``2^n + 1``, non-finite
    heights, a non-positive spacing, or heights or an extent beyond ``1e12`` m.
    """

    def __init__(self, heights, spacing: float = 1.0):
        try:  # an own copy: the pyramid below must describe the heights the mesh is made from
            raw = np.asarray(heights)
            if raw.dtype.kind == "c":  # numpy would drop the imaginary part
                raise ValueError
            h = np.array(raw, dtype=np.float64)
        except (TypeError, ValueError):
            raise PlodError("terrain: the heights must be real numbers (an (N, N) array)") from None
        if h.size == 0:
            raise PlodError("terrain: the heightfield is empty")
        if h.ndim != 2 or h.shape[0] != h.shape[1]:
            raise PlodError(f"terrain: the heightfield must be a square (N, N) grid, got shape {h.shape}")
        n = h.shape[0]
        L = int(round(math.log2(n - 1))) if n > 1 else -1
        if n < 3 or 2 ** L + 1 != n:
            raise PlodError(f"terrain: the heightfield must be 2^n + 1 samples per side (3, 5, 9, ..., 1025), got {n}")
        bad = ~np.isfinite(h)
        if bad.any():
            r, c = np.argwhere(bad)[0]
            raise PlodError(f"terrain: {int(bad.sum())} non-finite heights (NaN or inf), first at row {r}, column {c}")
        sp = real_or_nan(spacing)
        if not (math.isfinite(sp) and sp > 0):
            raise PlodError(f"terrain: spacing must be a positive number of metres, got {spacing!r}")
        top = float(np.abs(h).max())
        if top > _MAX_COORD or sp * (n - 1) > _MAX_COORD:
            raise PlodError(f"terrain: heights and the grid's extent must stay within {_MAX_COORD:g} m, got heights "
                            f"up to {top:g} m and an extent of {sp * (n - 1):g} m")
        h.flags.writeable = False
        self.heights, self.spacing, self.n, self.levels = h, sp, n, L
        self.err, self.zmin, self.zmax = _pyramid(h, L)

    @property
    def full_triangles(self) -> int:
        """Triangles of the full-resolution mesh: 2 (N - 1)^2."""
        return 2 * (self.n - 1) ** 2

    def points(self, rows, cols):
        """World positions (..., 3) of the samples at integer ``rows``, ``cols``."""
        return np.stack([cols * self.spacing, self.heights[rows, cols], rows * self.spacing], axis=-1)


def _pyramid(h, L):
    """Per level: (nested max error, min height, max height) of each square, each (2^l, 2^l)."""
    n = h.shape[0]
    # a plane's samples differ from its interpolation by a few roundings of the largest height (the
    # weights k / s are inexact): 16 units in the last place of it count as flat, in any length unit
    flat = 16 * np.finfo(np.float64).eps * float(np.abs(h).max())
    own = []
    for l in range(L + 1):
        s = 2 ** (L - l)
        m = 2 ** l
        if s == 1:
            own.append(np.zeros((m, m)))
            continue
        st = h.strides
        blk = np.lib.stride_tricks.as_strided(h, (m, m, s + 1, s + 1), (st[0] * s, st[1] * s, st[0], st[1]))
        h00, h01 = blk[:, :, :1, :1], blk[:, :, :1, -1:]
        h10, h11 = blk[:, :, -1:, :1], blk[:, :, -1:, -1:]
        t = np.arange(s + 1) / s
        r, c = t[:, None], t[None, :]
        lower = h00 + c * (h01 - h00) + r * (h11 - h01)  # c >= r: triangle (0,0) (0,1) (1,1)
        upper = h00 + r * (h10 - h00) + c * (h11 - h10)  # r > c: triangle (0,0) (1,0) (1,1)
        plane = np.where(c >= r, lower, upper)
        e = np.abs(blk - plane).max(axis=(2, 3))
        own.append(np.where(e > flat, e, 0.0))  # rounding of a plane is flat
    err = [None] * (L + 1)
    err[L] = own[L]
    for l in range(L - 1, -1, -1):
        m = 2 ** l
        err[l] = np.maximum(own[l], err[l + 1].reshape(m, 2, m, 2).max(axis=(1, 3)))
    # min / max height of each square (samples on its border included)
    zmin, zmax = [None] * (L + 1), [None] * (L + 1)
    lo = np.minimum(np.minimum(h[:-1, :-1], h[1:, 1:]), np.minimum(h[:-1, 1:], h[1:, :-1]))
    hi = np.maximum(np.maximum(h[:-1, :-1], h[1:, 1:]), np.maximum(h[:-1, 1:], h[1:, :-1]))
    zmin[L], zmax[L] = lo, hi
    for l in range(L - 1, -1, -1):
        m = 2 ** l
        zmin[l] = zmin[l + 1].reshape(m, 2, m, 2).min(axis=(1, 3))
        zmax[l] = zmax[l + 1].reshape(m, 2, m, 2).max(axis=(1, 3))
    del n
    return err, zmin, zmax


def _whole(name: str, x, lo: int) -> int:
    """``x`` as an int >= ``lo`` (an int or NumPy integer, not a bool), or PlodError naming ``name``."""
    if not isinstance(x, (int, np.integer)) or isinstance(x, (bool, np.bool_)) or x < lo:
        raise PlodError(f"terrain: {name} must be an integer >= {lo}, got {x!r}")
    return int(x)


def crop_heightfield(heights, size: int, row: int | None = None, col: int | None = None) -> np.ndarray:
    """The ``size x size`` window of ``heights`` at (row, col) (default: centred). Raises PlodError
    when it does not fit."""
    h = np.asarray(heights)
    size = _whole("crop size", size, 1)
    if h.ndim != 2 or h.shape[0] < size or h.shape[1] < size:
        raise PlodError(f"terrain: cannot crop {size} x {size} from a grid of shape {h.shape}")
    r = (h.shape[0] - size) // 2 if row is None else _whole("crop row", row, 0)
    c = (h.shape[1] - size) // 2 if col is None else _whole("crop column", col, 0)
    if r + size > h.shape[0] or c + size > h.shape[1]:
        raise PlodError(f"terrain: crop at row {r}, column {c} of size {size} leaves the grid {h.shape}")
    return h[r:r + size, c:c + size]


def fractal_heightfield(n: int, *, seed: int = 0, beta: float = 2.2, relief: float = 1.0,
                        dtype=np.float64) -> np.ndarray:
    """Spectral-synthesis fractal terrain (fBm): white noise filtered by ``1 / f^(beta/2)`` amplitude
    (power spectrum ``f^-beta``) and an inverse FFT, ``n x n`` samples, seeded; scaled so its heights
    span ``relief`` (heightfield units, > 0), returned as the floating ``dtype``. ``beta`` 2..3 is
    terrain-like [PS88] (Voss). PlodError for a bad argument or a ``beta`` whose spectrum overflows."""
    n, seed = _whole("fractal_heightfield n", n, 2), _whole("fractal_heightfield seed", seed, 0)
    b, rel = real_or_nan(beta), real_or_nan(relief)
    if not math.isfinite(b):
        raise PlodError(f"terrain: fractal_heightfield beta must be a finite number, got {beta!r}")
    if not (math.isfinite(rel) and rel > 0):
        raise PlodError(f"terrain: fractal_heightfield relief must be a finite number > 0, got {relief!r}")
    try:
        dt = np.dtype(dtype)
    except TypeError:
        dt = None
    if dt is None or not np.issubdtype(dt, np.floating):
        raise PlodError(f"terrain: fractal_heightfield dtype must be a floating type, got {dtype!r}")
    rng = np.random.default_rng(seed)
    m = n - 1 if n > 2 else n  # periodic on (n-1), the last row/column repeats the first
    fx = np.fft.fftfreq(m)[:, None]
    fy = np.fft.rfftfreq(m)[None, :]
    f = np.hypot(fx, fy)
    f[0, 0] = 1.0
    with np.errstate(over="ignore", invalid="ignore"):
        amp = f ** (-b / 2)
        amp[0, 0] = 0.0
        spec = (rng.standard_normal(amp.shape) + 1j * rng.standard_normal(amp.shape)) * amp
        z = np.fft.irfft2(spec, s=(m, m))
        z = np.pad(z, ((0, n - m), (0, n - m)), mode="wrap")
        z -= z.min()
        z *= rel / max(float(z.max()), 1e-300)  # in float64, then the requested type
        out = z.astype(dt)
    if not np.isfinite(out).all():
        raise PlodError(f"terrain: fractal_heightfield with beta={b:g}, relief={rel:g} gives non-finite heights")
    return out


# ----------------------------------------------------------------------------------------------- camera
def _finite_numbers(name: str, x, n: int) -> np.ndarray:
    """``x`` as n float64 finite numbers, or PlodError naming ``name``."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise PlodError(f"terrain: {name} must be {n} numbers, got {x!r}") from None
    if a.shape != (n,) or not np.isfinite(a).all():
        raise PlodError(f"terrain: {name} must be {n} finite numbers, got {a.tolist()}")
    return a


@dataclass(frozen=True)
class TerrainCamera:
    """An eye at ``eye`` (3,) looking along ``forward`` (3,) with ``up`` (3,) (world units, y up).

    ``fov_deg`` (horizontal, vertical) is the angular field of view (deg; may exceed 180 horizontally: the
    test is on azimuth and elevation, not a perspective frustum); ``gaze_deg`` (azimuth, elevation) of
    the gaze from the forward direction (deg; right and up positive).

    Raises :class:`PlodError` for non-finite or wrongly shaped vectors, a zero ``forward`` or ``up``,
    coordinates beyond ``1e12`` m, a field of view outside (0, 360] x (0, 180] deg or a gaze outside
    [-180, 180] x [-90, 90] deg."""

    eye: np.ndarray
    forward: np.ndarray
    up: tuple = (0.0, 1.0, 0.0)
    fov_deg: tuple[float, float] = (200.0, 135.0)
    gaze_deg: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self):
        for name in ("eye", "forward", "up"):
            v = _finite_numbers(f"TerrainCamera.{name}", getattr(self, name), 3)
            if name != "eye" and not np.any(v):
                raise PlodError(f"terrain: TerrainCamera.{name} must be a nonzero vector")
            if name == "eye" and np.abs(v).max() > _MAX_COORD:
                raise PlodError(f"terrain: TerrainCamera.eye must lie within {_MAX_COORD:g} m of 0, got {v.tolist()}")
        fx, fy = _finite_numbers("TerrainCamera.fov_deg", self.fov_deg, 2).tolist()
        if not (0 < fx <= 360 and 0 < fy <= 180):
            raise PlodError(f"terrain: TerrainCamera.fov_deg must be in (0, 360] x (0, 180] deg, got {[fx, fy]}")
        az, el = _finite_numbers("TerrainCamera.gaze_deg", self.gaze_deg, 2).tolist()
        if not (abs(az) <= 180 and abs(el) <= 90):
            raise PlodError(f"terrain: TerrainCamera.gaze_deg must be in [-180, 180] x [-90, 90] deg, got {[az, el]}")

    def rotation(self) -> np.ndarray:
        """(3, 3) world -> camera rows (right, up, back)."""
        f = unit_any_length(self.forward)  # forward and up of any length (1e-300, 1e300)
        r = np.cross(f, unit_any_length(self.up))
        nr = np.linalg.norm(r)
        if not nr >= 1e-12:
            raise PlodError("terrain: camera up is parallel to its forward direction")
        r /= nr
        return np.stack([r, np.cross(r, f), -f])

    def directions(self, p):
        """Unit directions (..., 3) in camera space (x right, y up, -z forward) of world points p."""
        d = (np.asarray(p) - np.asarray(self.eye, float)) @ self.rotation().T
        return d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-300)

    def gaze(self) -> np.ndarray:
        az, el = (math.radians(a) for a in self.gaze_deg)
        return np.array([math.cos(el) * math.sin(az), math.sin(el), -math.cos(el) * math.cos(az)])


@dataclass(frozen=True)
class TerrainCriteria:
    """Which of Reddy's criteria are on [Red01 Table 1], and the display cap.

    ``xi``: the display's highest frequency (cycles/deg) = 1 / (2 pixel angle in deg) [Red01 Eq 5], in
    [1e-6, 1e30] (what the float32 acuity model holds) or None (no cap).
    ``velocity_deg_s``: None measures each square's retinal velocity from the previous cameras; a number
    imposes that uniform velocity (deg/s, Figure 4's axis). ``tol``: vertical error (m) below which a
    square counts as flat. ``split_view_edge``: every square the field of view's edge crosses (its box
    not wholly outside, its sphere not wholly inside) is split, down to the finest level, whatever the
    criteria say (``cull`` included); then adding a criterion never adds triangles. Without it, with
    ``cull``, a leaf left whole by the added criterion on the view's edge is drawn where the finer
    refinement culls all its children (at most :func:`straddle_triangles` more); it costs a few percent
    more triangles (3.5 % on the Table 1 flight)."""

    size: bool = True
    periphery: bool = True
    velocity: bool = True
    cull: bool = True
    xi: float | None = None
    velocity_deg_s: float | None = None
    tol: float = 0.0
    split_view_edge: bool = False

    def __post_init__(self):
        for name in ("size", "periphery", "velocity", "cull", "split_view_edge"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise PlodError(f"terrain: TerrainCriteria.{name} must be True or False, got {getattr(self, name)!r}")
        # xi and the velocity within what the float32 acuity model holds (ReddyAcuity.xi >= 1e-6)
        for name, lo, hi in (("xi", 1e-6, 1e30), ("velocity_deg_s", 0.0, 1e30), ("tol", 0.0, math.inf)):
            x = getattr(self, name)
            if x is None and name != "tol":
                continue
            if not lo <= real_or_nan(x) <= hi or not math.isfinite(real_or_nan(x)):
                raise PlodError(f"terrain: TerrainCriteria.{name} must be a finite number in [{lo:g}, {hi:g}]"
                                f"{' or None' if name != 'tol' else ''}, got {x!r}")


@dataclass
class TerrainLOD:
    """One frame's refinement: ``split[l]`` (2^l, 2^l) bool for l < L (the restricted split set),
    ``drawn[l]`` (K_l, 2) int (row, column) of the drawn leaves at level l, ``fans[l]`` (K_l, 4) bool:
    edge (north, east, south, west) has a finer neighbour, ``triangles`` drawn, ``levels`` L."""

    split: list
    drawn: list
    fans: list
    triangles: int
    levels: int


_ACUITY_CACHE: dict = {}
_ACUITY_JIT = None  # the jitted H'(model, e, v) of every xi (see _acuity_fn)
_MIN_BUCKET, _CHUNK = 64, 1 << 16  # padded lengths 64, 128, ..., 65536; longer inputs go in chunks


def _acuity_fn(xi):
    """``H'(e, v)`` of :class:`pmetric.ReddyAcuity` with display cap ``xi`` (cached per xi): one jitted
    function of (model, e, v) serves every xi (the model is an argument, its constants traced, so a new
    display cap costs no compilation), compiled for every padded length on the process's first call, so no
    frame pays for a compilation."""
    global _ACUITY_JIT
    key = None if xi is None else float(xi)
    fn = _ACUITY_CACHE.get(key)
    if fn is None:
        import functools

        import jax

        import pmetric

        model = pmetric.ReddyAcuity(xi=key)
        if _ACUITY_JIT is None:
            jitted = jax.jit(lambda m, e, v: jax.numpy.exp(m.log_acuity(e, v)))
            b = _MIN_BUCKET
            while b <= _CHUNK:
                jitted(model, np.zeros(b, np.float32), np.zeros(b, np.float32)).block_until_ready()
                b *= 2
            _ACUITY_JIT = jitted
        fn = _ACUITY_CACHE[key] = functools.partial(_ACUITY_JIT, model)
    return fn


def _acuity(xi, e, v):
    """H'(v, e) (cycles/deg) for arrays e, v (deg, deg/s), evaluated in float32 in padded power-of-two
    buckets (at most ``_CHUNK`` long) so the jitted model compiles once per bucket, not once per frame."""
    k = len(e)
    if k == 0:
        return np.zeros(0)
    fn = _acuity_fn(xi)
    out = np.empty(k)
    for s in range(0, k, _CHUNK):
        n = min(k - s, _CHUNK)
        b = 1 << max(_MIN_BUCKET.bit_length() - 1, (n - 1).bit_length())
        ep = np.zeros(b, np.float32)
        vp = np.zeros(b, np.float32)
        ep[:n], vp[:n] = e[s:s + n], v[s:s + n]
        out[s:s + n] = np.asarray(fn(ep, vp))[:n]
    return out


def _culled(hf, cam, R, l, ii, jj, inside=False):
    """True where the square's bounding sphere (about its bounding box) lies wholly outside the field of
    view: beyond the elevation limits, or beyond the azimuth half-planes at +-fov_x/2 (for fov_x >= 180
    the culled back wedge is the intersection of the two outer half-spaces, below 180 their union).

    With ``inside=True`` returns (culled, contained): ``contained`` where the sphere lies wholly inside the
    field of view, so no part of the square's box, nor of any descendant's, can be culled.
    """
    from ._terrain_bounds import cull_squares

    k = len(ii)
    out, ins = np.empty(k, bool), np.empty(k, bool)
    hx, hy = (math.radians(a / 2) for a in cam.fov_deg)
    cull_squares(hf.zmin[l], hf.zmax[l], np.ascontiguousarray(ii), np.ascontiguousarray(jj),
                 float(2 ** (hf.levels - l) * hf.spacing), np.asarray(cam.eye, np.float64),
                 np.ascontiguousarray(R, np.float64), hx, hy, out, ins)
    return (out, ins) if inside else out


def _corner_nodes(l, a, b):
    """The level-l grid nodes at the corners of squares (a, b): (unique node ids on the (2^l + 1)^2 grid
    (U,), (4, K) index into them, corners NW, NE, SE, SW). Shared corners are computed once where the
    squares are dense on the grid; a sparse set lists each square's corners (the same arithmetic per node)."""
    m1 = 2 ** l + 1
    lin = (a * m1 + b)[None, :] + np.array([0, 1, m1 + 1, m1])[:, None]
    if 32 * len(a) < m1 * m1:  # few squares: each corner on its own (a grid-sized mask would cost more)
        return lin.ravel(), np.arange(lin.size).reshape(lin.shape)
    mask = np.zeros(m1 * m1, bool)
    mask[lin.ravel()] = True
    nodes = np.flatnonzero(mask)
    pos = np.cumsum(mask) - 1
    return nodes, pos[lin]


def _perceptible_exact(hf, camera, R, g, criteria, moves, dt_s, l, a, b):
    """(K,) bool: the level-l squares (a, b) pass the size test ``s >= 1 / (2 H'(v, e))``, in float64 (the
    reference arithmetic; :func:`_size_test` sends here only the squares its float32 bounds leave open).

    Work is per unique corner (directions, retinal velocity), then per square: the extent, and e as 0
    where the gaze lies inside the square (tested only where the nearest corner is within the extent, the
    only squares it can lie inside) else the least angle to its four edge arcs; H'(v, e) [Red01 Eq 4-5]
    from the model in one call.
    """
    L = hf.levels
    step = 2 ** (L - l)
    m1 = 2 ** l + 1
    nodes, inv = _corner_nodes(l, a, b)
    return _size_exact(hf, camera, R, g, criteria, moves, dt_s, (nodes // m1) * step, (nodes % m1) * step, inv)


def _size_exact(hf, camera, R, g, criteria, moves, dt_s, r, c, inv):
    """:func:`_perceptible_exact` for squares of any levels given by their corner samples: ``r``, ``c`` (U,)
    int row and column of the grid nodes (samples), ``inv`` (4, K) index of each square's corners NW, NE,
    SE, SW among them. Returns (K,) bool. The geometry (extent, e, v) is compiled, one square at a time
    (``optim._terrain_bounds.exact_terms``), H'(v, e) one call of the model for all of them."""
    from ._terrain_bounds import exact_terms

    measured = criteria.velocity and criteria.velocity_deg_s is None and bool(moves)
    eyes = np.array([e for e, _ in moves], float).reshape(-1, 3)
    turns = np.array([Rp for _, Rp in moves], float).reshape(-1, 3, 3)
    ext, e, v = exact_terms(c * float(hf.spacing), np.ascontiguousarray(hf.heights[r, c], np.float64),
                            r * float(hf.spacing), np.ascontiguousarray(inv), np.asarray(camera.eye, float),
                            np.ascontiguousarray(R, float), np.asarray(g, float), eyes, turns,
                            bool(criteria.periphery), measured, 1.0 / (max(len(moves), 1) * dt_s))
    if criteria.velocity and criteria.velocity_deg_s is not None:
        v = np.full(len(ext), float(criteria.velocity_deg_s))
    return ext >= 1.0 / (2.0 * _acuity(criteria.xi, e, v))


# ------------------------------------------------------------------------- the float32 bound pass
# Error budget of :func:`_strip_bounds` (radians unless stated). Each bound is larger than the worst case
# the arithmetic allows; tests/test_terrain.py checks the measured errors against them.
_EPS_DIR = 4e-6  # |float32 unit direction - exact| (<= 1.5e-6 by the worst case of the roundings)
_EPS_CHORD = 2 * _EPS_DIR + 1e-6  # a chord |d1 - d2| of two such directions, with its own float32 rounding
# (<= 3e-7) and the float64 path's own error on the same angle (arccos near 1: <= sqrt(2 * 6e-16) < 4e-8)
_EPS_COS = _EPS_DIR + 4e-6  # cos(angle to the gaze) from a float32 dot, plus float32 cos / arc rounding
_MU = 1e-3  # relative margin on H': JAX's float32 ReddyAcuity against the exact formula on its float32
# constants (measured <= 3.2e-5, at G near g_min) and the float32 rounding of the per-square arithmetic
_CHORD_MAX = 0.3  # 2 asin(c / 2) <= c + c^3 * _SERIES for chords c <= _CHORD_MAX (<= pi c / 2 for any c)
_SERIES = 1.011 / 24
_SMALL_LEVELS = 4  # levels 0..4 (341 squares) take the size test in one float64 call
_BOUND_MIN = 0  # levels with at least this many candidate squares take the bound pass (tests raise it)
_STRIP_NODES = 1 << 16  # nodes per strip of the bound pass (its float32 temporaries stay in cache)
_CONSTS: dict = {}


def _acuity_consts(xi):
    """ReddyAcuity's constants rounded to float32 as JAX evaluates them, as Python floats (cached):
    (xi, g_max, g_intercept, g_slope / ln 10, g_min, m_scale, m_rate)."""
    key = None if xi is None else float(xi)
    c = _CONSTS.get(key)
    if c is None:
        import pmetric

        m = pmetric.ReddyAcuity(xi=key)
        f = {k: float(np.float32(np.asarray(getattr(m, k)))) for k in
             ("xi", "g_max", "g_intercept", "g_slope", "g_min", "m_scale", "m_rate")}
        c = _CONSTS[key] = (f["xi"], f["g_max"], f["g_intercept"], f["g_slope"] / math.log(10.0), f["g_min"],
                            f["m_scale"], f["m_rate"])
    return c


def _decide(consts, periphery, w_hi, h_s, h_n, g_s, g_n, kmax, far):
    """(yes, no) of the size test from its bounds (float32 arrays of one shape, or scalars for g):
    ``h_s`` the H' a sure split needs (1 / (2 x_lo (1 - mu))), ``h_n`` the H' below which surely no split,
    ``g_s`` / ``g_n`` G at the largest / smallest possible velocity, ``kmax`` the cosine of the angle to
    the nearest corner (its error below ``_EPS_COS``), ``far`` where the gaze is surely outside the square,
    ``w_hi`` the largest possible angle of its longest edge (deg; e >= near - w / 2 there). NaN anywhere
    gives neither."""
    xi, _, _, _, _, ms, mr = consts
    f32 = np.float32
    m0 = f32(min(1.0, ms))  # M(0) = max M
    q_s = h_s / g_s  # M(e) a sure split needs
    q_n = h_n / g_n  # M(e) below which surely no split
    yes = (h_s <= f32(xi)) & (q_s <= m0)
    no = (h_n > f32(xi)) | (q_n > m0)
    if not periphery:  # e = 0: M = M(0)
        return yes, no
    # M(e) >= q iff e <= (sqrt(m_scale / q) - 1) / m_rate (q <= M(0)); compared on cosines, capped at 180 deg
    k = f32(math.pi / 180.0 / mr)
    e_s = np.sqrt(f32(ms) / q_s)
    e_s -= f32(1.0)
    e_s *= k
    np.minimum(e_s, f32(math.pi), out=e_s)
    yes &= (kmax - f32(_EPS_COS)) >= np.cos(e_s)
    e_n = np.sqrt(f32(ms) / q_n)
    e_n -= f32(1.0)
    e_n *= k
    e_n += w_hi * f32(math.pi / 360.0)  # near must exceed E + w/2 for e >= near - w/2 to exceed E
    np.minimum(e_n, f32(math.pi), out=e_n)
    no |= far & ((kmax + f32(_EPS_COS)) < np.cos(e_n))
    return yes, no


def _G(consts, v):
    """G(v) (cycles/deg) of ReddyAcuity on its float32 constants, float32; v deg/s (array or scalar)."""
    _, gmax, gint, gsl, gmin, _, _ = consts
    f32 = np.float32
    lv = np.log(np.maximum(v, f32(1e-30))) if isinstance(v, np.ndarray) else f32(math.log(max(float(v), 1e-30)))
    return np.clip(f32(gint) - f32(gsl) * lv, f32(gmin), f32(gmax))


def _strip_bounds(hf, eye, gw, criteria, motion, dt_s, l, i0, i1, j0, j1, cand):
    """(yes, no), each (i1 - i0, j1 - j0) bool, for the level-l squares of rows i0..i1-1, columns j0..j1-1
    (``cand`` the same shape: the candidates among them): ``yes`` where the size test certainly passes,
    ``no`` where it certainly fails, neither where float32 cannot tell (the float64 path decides those).

    float32 unit directions of the corners give the extent, the cosine of the angle to the gaze ``gw``
    (world axes) and the retinal velocity each with a bounded error (chords, no arc functions: 2 asin(c/2)
    lies between c and its series bound); the test is made at the interval ends with H' from the closed
    form on JAX's float32 constants and a relative margin ``_MU`` (H' is non-increasing in e and v
    [Red01 Eq 4-5]). e lies in [near - w/2, near] with near the angle to the nearest corner and w the
    longest edge (every edge point is within half an edge of a corner), and 0 is possible only where
    near <= s (the gaze inside); the squares that interval leaves open get bounds of e from their edge
    arcs (:func:`_edge_refine`). The measured velocity (``motion``, see :func:`_motion`) is bounded per
    corner from the chords between its directions in successive cameras. The arithmetic is compiled
    (``optim._terrain_bounds``, one float32 rounding per operation as the ``_EPS_*`` budget assumes).
    """
    from ._terrain_bounds import strip_geometry

    consts = _acuity_consts(criteria.xi)
    step = 2 ** (hf.levels - l)
    Y = hf.heights[i0 * step:i1 * step + 1:step, j0 * step:j1 * step + 1:step]
    X, Z = np.arange(j0, j1 + 1) * step * hf.spacing, np.arange(i0, i1 + 1) * step * hf.spacing
    imposed = criteria.velocity and criteria.velocity_deg_s is not None
    measured = criteria.velocity and not imposed and motion is not None
    U, h_s, h_n, x_hi, w, kmax, v_hi, v_lo = strip_geometry(
        Y, X, Z, eye, gw, criteria.periphery, (motion["eyes"], motion["turns"]) if measured else None,
        motion["scale"] if measured else 0.0, (_EPS_CHORD, _SERIES, _CHORD_MAX, _MU))
    if measured:
        g_s, g_n = _G(consts, v_hi), _G(consts, v_lo)
    else:  # v = 0, or imposed: G known
        g_s = g_n = _G(consts, criteria.velocity_deg_s if imposed else 0.0)
    far = None
    if criteria.periphery:
        far = (kmax + np.float32(_EPS_COS)) < np.cos(np.minimum(x_hi * np.float32(math.pi / 180.0),
                                                               np.float32(math.pi)))
    yes, no = _decide(consts, criteria.periphery, w, h_s, h_n, g_s, g_n, kmax, far)
    if criteria.periphery:
        _edge_refine(consts, yes, no, cand, far, U, gw, h_s, h_n, g_s, g_n)
    return yes, no


def _edge_refine(consts, yes, no, cand, far, U, gw, h_s, h_n, g_s, g_n):
    """Decide in place more of the candidates ``cand`` (nr - 1, nc - 1) bool that ``yes`` / ``no`` leave
    open, from bounds of e itself rather than [near - w/2, near] (``far``: where the gaze is surely outside):
    e = 0 where the gaze surely lies inside the square (the float64 path's inside test, with room, where
    that path makes it), else
    the angle from the gaze ``gw`` (world axes) to each edge arc P-Q lies between the angle to its great
    circle asin(|g . n| / |n|), n = P x Q, and that to its nearer end, and is the former where the foot
    of the gaze on the circle falls between P and Q (g.Q - (P.Q)(g.P) > 0 and g.P - (P.Q)(g.Q) > 0), the
    latter where it surely falls outside; e is the least over the four edges. The comparisons with the
    e a sure split allows / below which none can be are made on sines and cosines. float64 arithmetic
    (compiled: ``optim._terrain_bounds.edge_decide``) on the float32 directions ``U`` (three (nr, nc)
    arrays) with their error ``_EPS_DIR``; ``h_s``, ``h_n``,
    ``g_s``, ``g_n`` as in :func:`_decide` (arrays of the squares' shape, or scalars for g)."""
    ri, ci = np.nonzero(cand & ~(yes | no))
    if not len(ri):
        return
    from ._terrain_bounds import edge_decide

    xi, _, _, _, _, ms, mr = consts
    k = len(ri)
    pick = lambda a: np.ascontiguousarray(a[ri, ci], np.float64) if isinstance(a, np.ndarray) else \
        np.full(k, float(a))  # noqa: E731
    y, n = np.empty(k, bool), np.empty(k, bool)
    edge_decide(ri, ci, *U, np.asarray(gw, np.float64), pick(h_s), pick(h_n), pick(g_s), pick(g_n),
                np.ascontiguousarray(far[ri, ci]), float(xi), float(ms), float(mr), _EPS_DIR, y, n)
    yes[ri, ci] = y
    no[ri, ci] = n


def _motion(eye, R, moves, dt_s):
    """What the bound pass needs of the previous cameras (None without them), a dict: ``eyes`` (m, 3) m,
    ``turns`` (m, 3, 3) R_0^T R_j (their directions in the current camera's world axes), ``scale``: deg/s
    per radian of angle sum. ``moves``: [(eye, R)], most recent first."""
    if not moves:
        return None
    return {"eyes": np.array([np.asarray(e, float) for e, _ in moves]),
            "turns": np.array([R.T @ Rj for _, Rj in moves]),
            "scale": 180.0 / math.pi / (len(moves) * dt_s)}


def _size_small(hf, camera, R, g, criteria, moves, dt_s, levels):
    """The size test of every square of levels 0..``levels`` in one float64 call (their per-level fixed
    costs would exceed the work): [(2^l, 2^l) bool] per level, each square's answer as
    :func:`_perceptible_exact` gives it (the same arithmetic per corner)."""
    L = hf.levels
    rows, cols, sizes = [], [], []
    for l in range(levels + 1):
        m, s = 2 ** l, 2 ** (L - l)
        i, j = np.divmod(np.arange(m * m), m)
        rows.append(np.stack([i, i, i + 1, i + 1]) * s)
        cols.append(np.stack([j, j + 1, j + 1, j]) * s)
        sizes.append(m)
    r, c = np.concatenate(rows, 1), np.concatenate(cols, 1)
    k = r.shape[1]
    out = _size_exact(hf, camera, R, g, criteria, moves, dt_s, r.ravel(), c.ravel(), np.arange(4 * k).reshape(4, k))
    maps, s = [], 0
    for m in sizes:
        maps.append(out[s:s + m * m].reshape(m, m))
        s += m * m
    return maps


def _size_test(hf, camera, R, g, criteria, moves, dt_s, l, ok, motion=None):
    """Clear in place the squares of the level-l candidate map ``ok`` (2^l, 2^l) bool that fail the size
    test ``s >= 1 / (2 H'(v, e))``; ``moves``: the previous cameras as (eye (3,), rotation (3, 3)), most
    recent first; ``motion``: :func:`_motion` of them (the frame's, made once; None: made here).

    The answer is :func:`_perceptible_exact`'s (the float64 arithmetic) square for square: levels with at
    least ``_BOUND_MIN`` candidates first take the float32 bound pass (:func:`_strip_bounds`, strips of
    about ``_STRIP_NODES`` nodes over the candidates' columns), which decides every square whose answer
    its error bounds make certain; only the rest (a small fraction) go to the float64 path.
    """
    m = ok.shape[0]
    n = np.count_nonzero(ok)
    if not n:
        return
    if n < _BOUND_MIN:
        t = np.flatnonzero(ok)
        if len(t):
            ok.flat[t] = _perceptible_exact(hf, camera, R, g, criteria, moves, dt_s, l, t >> l, t & (m - 1))
        return
    eye = np.asarray(camera.eye, float)
    if motion is None:
        motion = _motion(eye, R, moves, dt_s)
    gw = R.T @ g
    rows = max(1, _STRIP_NODES // (m + 1))
    used = np.flatnonzero(ok.any(1))
    undecided = []
    with np.errstate(all="ignore"):
        i0 = int(used[0])
        while i0 <= used[-1]:
            i1 = min(i0 + rows, m)
            cols = np.flatnonzero(ok[i0:i1].any(0))
            if len(cols):
                j0, j1 = int(cols[0]), int(cols[-1]) + 1
                cand = ok[i0:i1, j0:j1]  # a view: written below
                yes, no = _strip_bounds(hf, eye, gw, criteria, motion, dt_s, l, i0, i1, j0, j1, cand)
                no |= yes
                np.logical_not(no, out=no)
                no &= cand  # candidates neither bound decides
                cand &= yes
                r, c = np.nonzero(no)
                if len(r):
                    undecided.append((r + i0, c + j0))
            i0 = i1
    if not undecided:
        return
    a = np.concatenate([u[0] for u in undecided])
    b = np.concatenate([u[1] for u in undecided])
    ok[a, b] = _perceptible_exact(hf, camera, R, g, criteria, moves, dt_s, l, a, b)


def refine_terrain(hf: Heightfield, camera: TerrainCamera, criteria: TerrainCriteria = TerrainCriteria(),
                   previous=(), dt_s: float = 1 / 30) -> TerrainLOD:
    """Refine ``hf`` for one frame seen by ``camera`` under ``criteria`` (see the module docstring).

    ``previous``: the cameras of the preceding frames, most recent first (the retinal velocity is the
    mean over consecutive pairs of the angle a corner moved, over ``dt_s`` seconds each); empty means
    velocity 0. Cost: per level, a few passes over dense (2^l, 2^l) one-byte maps (candidates, cull
    state, splits), the cull test on the candidate squares only (their flat indices; done once and reused
    by the leaf pass) and the size test as a float32 bound pass over strips of the level's grid that
    decides all but a small fraction of the squares, the rest in float64 (:func:`_size_test`; the answer is
    the float64 test's square for square). The per-square arithmetic of the cull test, the bound pass,
    the float64 test's geometry and the leaf pass is compiled (``optim._terrain_bounds``, numba; the first
    call of a process compiles or loads it from numba's cache).
    """
    _check_args(hf, camera=camera, criteria=criteria)
    L = hf.levels
    dt = real_or_nan(dt_s)
    if not (0 < dt < math.inf and math.isfinite(180.0 / math.pi / dt)):  # and its velocity scale 1 / dt
        raise PlodError(f"terrain: dt_s must be a finite positive time step in seconds, got {dt_s!r}")
    dt_s = dt
    if isinstance(previous, TerrainCamera) or not isinstance(previous, Iterable) or isinstance(previous, str):
        raise PlodError(f"terrain: previous must be a sequence of TerrainCamera (most recent first), got "
                        f"{type(previous).__name__}")
    previous = tuple(previous)  # once: a generator would be used up by the check below
    for k, c in enumerate(previous):
        if not isinstance(c, TerrainCamera):
            raise PlodError(f"terrain: previous[{k}] must be a TerrainCamera, got {type(c).__name__}")
    R = camera.rotation()
    moves = [(np.asarray(c.eye, float), c.rotation()) for c in previous]
    g = camera.gaze()
    split, culled = [], [None] * (L + 1)
    small_levels = min(L - 1, _SMALL_LEVELS)  # levels whose size test is one batched float64 call
    motion = _motion(np.asarray(camera.eye, float), R, moves, dt_s) if criteria.size else None
    cand = np.ones((1, 1), bool)  # the squares whose parent is split (dense per level); the root
    edge = criteria.split_view_edge
    for l in range(L):
        ok = cand & (hf.err[l] > criteria.tol)
        if criteria.cull or edge:
            # 0 unknown, 1 visible, 2 culled, 3 contained (its box, and every descendant's, in view)
            cmap = np.zeros((1, 1), np.int8) if l == 0 else _inherit(culled[l - 1])
            t = np.flatnonzero((cand if edge else ok) & (cmap != 3))
            c = _cull_states(hf, camera, R, l, cmap, t)
            if criteria.cull:
                ok.flat[t[c]] = False
            culled[l] = cmap
        if criteria.size:
            if l <= small_levels:
                if l == 0:
                    small = _size_small(hf, camera, R, g, criteria, moves, dt_s, small_levels)
                ok &= small[l]
            else:
                _size_test(hf, camera, R, g, criteria, moves, dt_s, l, ok, motion)
        if edge:
            ok |= cand & (culled[l] == 1)  # on the view's edge: split whatever the criteria say
        split.append(ok)
        cand = _up(ok)
    _restrict(split)
    if edge:
        _split_edge_leaves(hf, camera, R, split, culled)
    return _leaves(hf, camera, R, criteria, split, culled)  # (culls only with criteria.cull)


def _cull_states(hf, camera, R, l, cmap, t):
    """The field-of-view test of the level-``l`` squares at flat indices ``t`` written into the level's
    cull map ``cmap`` (2 culled, 3 contained, 1 visible, see :func:`refine_terrain`); returns their
    culled flags (len(t),) bool."""
    if not len(t):
        return np.zeros(0, bool)
    c, inside = _culled(hf, camera, R, l, t >> l, t & (2 ** l - 1), inside=True)
    cmap.flat[t] = np.where(c, 2, np.where(inside, 3, 1))
    return c


def _split_edge_leaves(hf, camera, R, split, culled):
    """``split_view_edge``: split (in place) every leaf above the finest level that the view's edge
    crosses, including those the restriction pass made (their cull state is tested here), and close the
    split set again, until none is left. Every operation only adds splits and each is monotone in the
    split set, so the result stays nested under nested criteria; its leaves are then culled, wholly in
    view, or at the finest level."""
    L = hf.levels
    while True:
        changed = False
        for l in range(L):
            leaf = ~split[l] if l == 0 else _up(split[l - 1]) & ~split[l]
            cmap = culled[l]
            _cull_states(hf, camera, R, l, cmap, np.flatnonzero(leaf & (cmap == 0)))
            on_edge = leaf & (cmap == 1)
            if on_edge.any():
                split[l] |= on_edge  # (their children's states, 0, are tested at the next level)
                changed = True
        if not changed:
            return
        _restrict(split)


def _check_args(hf, **named):
    """PlodError unless ``hf`` is a Heightfield and each of ``named`` (camera, criteria, lod) is of its kind;
    a ``lod`` must be a refinement of a heightfield of ``hf``'s size."""
    kinds = {"hf": Heightfield, "camera": TerrainCamera, "criteria": TerrainCriteria, "lod": TerrainLOD}
    for name, x in {"hf": hf, **named}.items():
        if not isinstance(x, kinds[name]):
            raise PlodError(f"terrain: {name} must be a {kinds[name].__name__}, got {type(x).__name__}")
    lod = named.get("lod")
    if lod is not None and lod.levels != hf.levels:
        raise PlodError(f"terrain: the refinement is of a {2 ** lod.levels + 1}-sample grid, the heightfield has "
                        f"{hf.n} samples per side")


def _inherit(parent_state):
    """The next level's cull map from the level's (0 unknown, 1 visible, 2 culled, 3 contained): 3 under a
    contained parent (its box, and every descendant's, is in view), else 0."""
    out = _up(parent_state == 3).view(np.int8)
    out *= 3
    return out


def _up(M):
    """(2m, 2m) copy of the (m, m) one-byte (bool or int8) level map ``M`` at the next level: each square's value on its four children."""
    m = M.shape[0]
    # each byte doubled as one uint16 (x * 257), then each row written twice: about 50 x faster than
    # numpy's strided copy of a broadcast view (the per-frame cost of a 1025-grid is in these maps)
    r = (np.ascontiguousarray(M).view(np.uint8).astype(np.uint16) * 257).view(np.uint8).reshape(m, 2 * m)
    out = np.empty((m, 2, 2 * m), np.uint8)
    out[:, 0] = r
    out[:, 1] = r
    return out.reshape(2 * m, 2 * m).view(M.dtype)


def _restrict(split):
    """Close the split set in place so that edge-adjacent leaves differ by at most one level."""
    for l in range(len(split) - 1, 0, -1):
        S = split[l]
        D = S.copy()
        D[1:] |= S[:-1]
        D[:-1] |= S[1:]
        D[:, 1:] |= S[:, :-1]
        D[:, :-1] |= S[:, 1:]
        D = D[0::2] | D[1::2]
        split[l - 1] |= D[:, 0::2] | D[:, 1::2]  # any child marked (30 x faster than reshape + any)


def _fan_triangles(fan) -> int:
    """Triangles of leaves with finer-edge flags ``fan`` (K, 4) bool, C-contiguous: two for a leaf without
    a finer edge, a fan of 4 + k for one with k > 0 (each row's four flags read as one uint32)."""
    return 2 * len(fan) + 2 * int(np.count_nonzero(fan.view(np.uint32))) + int(np.count_nonzero(fan))


def _leaves(hf, camera, R, criteria, split, culled):
    """The drawn leaves per level from the restricted split set (dense level maps, one pass per level):
    a leaf is a square whose parent is split and which is not split itself; with ``cull``, leaves whose
    state the refinement left unknown get the cull test here (a contained parent's children are visible)."""
    from ._terrain_bounds import level_leaves

    L = hf.levels
    drawn, fans = [], []
    tri = 0
    hx, hy = (math.radians(a / 2) for a in camera.fov_deg)
    eye, R = np.asarray(camera.eye, np.float64), np.ascontiguousarray(R, np.float64)
    none8, none1 = np.zeros((1, 1), np.int8), np.ones((1, 1), bool)
    for l in range(L + 1):
        known = none8
        if criteria.cull:  # levels < L: the refinement's map; the finest: 3 under a contained parent, else 0
            known = culled[l] if l < L else _inherit(culled[L - 1])
        rc, fan = level_leaves(l, none1 if l == 0 else split[l - 1], split[l] if l < L else none1, l == L,
                               bool(criteria.cull), known, hf.zmin[l], hf.zmax[l],
                               float(2 ** (L - l) * hf.spacing), eye, R, hx, hy)
        tri += _fan_triangles(fan)
        drawn.append(rc)
        fans.append(fan)
    return TerrainLOD(split, drawn, fans, tri, L)


def straddle_triangles(hf: Heightfield, camera: TerrainCamera, lod: TerrainLOD) -> int:
    """Triangles of ``lod``'s drawn leaves whose bounding sphere is not wholly inside ``camera``'s field of
    view (the leaves the view's boundary may cross).

    The bound on monotonicity in the criteria: a refinement under more criteria splits a subset of the
    squares (its split set is nested in the other's), and inside the view a finer refinement of a leaf
    draws at least the leaf's triangles (a leaf keeps its fan or gains finer edges; four children draw
    at least 8, a fan at most 8). Only a straddling leaf can lose: unsplit it is drawn, split its
    children may all be culled. So adding a criterion adds at most this many triangles; with ``cull``
    off, none (``reports/terrain/scripts/monotone.py`` measures how often and how much it adds); with
    ``TerrainCriteria.split_view_edge``, none (the only such leaves left are at the finest level)."""
    _check_args(hf, camera=camera, lod=lod)
    R = camera.rotation()
    tri = 0
    for l, (rc, fan) in enumerate(zip(lod.drawn, lod.fans)):
        if not len(rc):
            continue
        _, contained = _culled(hf, camera, R, l, rc[:, 0], rc[:, 1], inside=True)
        tri += _fan_triangles(fan[~contained])
    return tri


def terrain_mesh(hf: Heightfield, lod: TerrainLOD):
    """The drawn leaves as a triangle mesh: (vertices (V, 3) world, faces (F, 3), grid (V, 2) (row,
    column) sample indices). Faces wind counter-clockwise seen from above (+y)."""
    _check_args(hf, lod=lod)
    L = hf.levels
    faces = []
    for l in range(L + 1):
        rc, fan = lod.drawn[l], lod.fans[l]
        if not len(rc):
            continue
        s = 2 ** (L - l)
        r0, c0 = rc[:, 0] * s, rc[:, 1] * s
        h = s // 2
        # corner / midpoint grid ids going round: NW, N, NE, E, SE, S, SW, W (row grows southwards)
        ring_r = np.stack([r0, r0, r0, r0 + h, r0 + s, r0 + s, r0 + s, r0 + h], -1)
        ring_c = np.stack([c0, c0 + h, c0 + s, c0 + s, c0 + s, c0 + h, c0, c0], -1)
        ring = ring_r * hf.n + ring_c
        centre = (r0 + h) * hf.n + (c0 + h)
        plain = ~fan.any(1)
        # two triangles, diagonal NW-SE as in the error pyramid: (NW, SE, NE) and (NW, SW, SE)
        q = ring[plain]
        faces.append(np.stack([q[:, 0], q[:, 4], q[:, 2]], -1))
        faces.append(np.stack([q[:, 0], q[:, 6], q[:, 4]], -1))
        f = fan[~plain]
        q, cen = ring[~plain], centre[~plain]
        for e in range(4):  # edge e runs ring[2e] -> ring[2e+1] -> ring[2e+2]
            a, mid, b = q[:, 2 * e], q[:, 2 * e + 1], q[:, (2 * e + 2) % 8]
            has = f[:, e]
            faces.append(np.stack([cen[~has], b[~has], a[~has]], -1))
            faces.append(np.stack([cen[has], mid[has], a[has]], -1))
            faces.append(np.stack([cen[has], b[has], mid[has]], -1))
    F = np.concatenate(faces) if faces else np.zeros((0, 3), np.int64)
    ids, inv = np.unique(F, return_inverse=True)
    rows, cols = ids // hf.n, ids % hf.n
    return hf.points(rows, cols), inv.reshape(-1, 3), np.stack([rows, cols], -1)


def full_mesh(hf: Heightfield):
    """The full-resolution mesh (vertices (N^2, 3), faces (2 (N-1)^2, 3)), same diagonal and winding."""
    n = hf.n
    r, c = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    V = hf.points(r.ravel(), c.ravel())
    nw = (r[:-1, :-1] * n + c[:-1, :-1]).ravel()
    ne, sw, se = nw + 1, nw + n, nw + n + 1
    F = np.concatenate([np.stack([nw, se, ne], -1), np.stack([nw, sw, se], -1)])
    return V, F

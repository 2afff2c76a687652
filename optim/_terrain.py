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

Units: heights and spacing in metres (any length unit, consistently), angles in degrees, time in
seconds, velocity deg/s, frequency cycles/deg. Cameras: :class:`TerrainCamera` (world: x = column
spacing, y = height, z = row spacing; right-handed, y up).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pmetric import PlodError

__all__ = ["Heightfield", "TerrainCamera", "TerrainCriteria", "TerrainLOD", "refine_terrain",
           "terrain_mesh", "full_mesh", "fractal_heightfield", "crop_heightfield"]


_MAX_COORD = 1e12  # m: heights, grid extent and eye coordinates beyond this would overflow the squares


# ----------------------------------------------------------------------------------------------- data
class Heightfield:
    """A square heightfield of ``N = 2^L + 1`` samples per side with its quadtree pyramid.

    ``heights`` (N, N) metres (row 0 at z = 0), ``spacing`` metres between samples. Precomputes per
    level ``l`` (0..L) the nested maximum vertical error (m) of each square against its two triangles
    (diagonal from corner (0, 0) to (1, 1)), and its minimum and maximum height (m) for culling.
    Raises :class:`PlodError` for an empty grid, a grid that is not square ``2^n + 1``, non-finite
    heights, a non-positive spacing, or heights or an extent beyond ``1e12`` m.
    """

    def __init__(self, heights, spacing: float = 1.0):
        try:
            h = np.asarray(heights, dtype=np.float64)
        except (TypeError, ValueError):
            raise PlodError("terrain: the heights must be numbers (an (N, N) array)") from None
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
        sp = float(spacing)
        if not (math.isfinite(sp) and sp > 0):
            raise PlodError(f"terrain: spacing must be a positive number of metres, got {spacing!r}")
        top = float(np.abs(h).max())
        if top > _MAX_COORD or sp * (n - 1) > _MAX_COORD:
            raise PlodError(f"terrain: heights and the grid's extent must stay within {_MAX_COORD:g} m, got heights "
                            f"up to {top:g} m and an extent of {sp * (n - 1):g} m")
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
        own.append(np.where(e > 1e-9 * (1.0 + np.abs(h).max()), e, 0.0))  # rounding of a plane is flat
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


def crop_heightfield(heights, size: int, row: int | None = None, col: int | None = None) -> np.ndarray:
    """The ``size x size`` window of ``heights`` at (row, col) (default: centred). Raises PlodError
    when it does not fit."""
    h = np.asarray(heights)
    if h.ndim != 2 or h.shape[0] < size or h.shape[1] < size:
        raise PlodError(f"terrain: cannot crop {size} x {size} from a grid of shape {h.shape}")
    r = (h.shape[0] - size) // 2 if row is None else int(row)
    c = (h.shape[1] - size) // 2 if col is None else int(col)
    if r < 0 or c < 0 or r + size > h.shape[0] or c + size > h.shape[1]:
        raise PlodError(f"terrain: crop at row {r}, column {c} of size {size} leaves the grid {h.shape}")
    return h[r:r + size, c:c + size]


def fractal_heightfield(n: int, *, seed: int = 0, beta: float = 2.2, relief: float = 1.0,
                        dtype=np.float64) -> np.ndarray:
    """Spectral-synthesis fractal terrain (fBm): white noise filtered by ``1 / f^(beta/2)`` amplitude
    (power spectrum ``f^-beta``) and an inverse FFT, ``n x n`` samples, seeded; scaled so its heights
    span ``relief`` (heightfield units). ``beta`` 2..3 is terrain-like [PS88] (Voss)."""
    if n < 2:
        raise PlodError(f"fractal_heightfield: n must be >= 2, got {n}")
    rng = np.random.default_rng(seed)
    m = n - 1 if n > 2 else n  # periodic on (n-1), the last row/column repeats the first
    fx = np.fft.fftfreq(m)[:, None]
    fy = np.fft.rfftfreq(m)[None, :]
    f = np.hypot(fx, fy)
    f[0, 0] = 1.0
    amp = f ** (-beta / 2)
    amp[0, 0] = 0.0
    spec = (rng.standard_normal(amp.shape) + 1j * rng.standard_normal(amp.shape)) * amp
    z = np.fft.irfft2(spec, s=(m, m)).astype(dtype)
    z = np.pad(z, ((0, n - m), (0, n - m)), mode="wrap")
    z -= z.min()
    return z * (relief / max(float(z.max()), 1e-300))


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
        f = np.asarray(self.forward, float)
        f = f / np.linalg.norm(f)
        r = np.cross(f, np.asarray(self.up, float))
        nr = np.linalg.norm(r)
        if nr < 1e-12:
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

    ``xi``: the display's highest frequency (cycles/deg) = 1 / (2 pixel angle in deg) [Red01 Eq 5].
    ``velocity_deg_s``: None measures each square's retinal velocity from the previous cameras; a number
    imposes that uniform velocity (deg/s, Figure 4's axis). ``tol``: vertical error (m) below which a
    square counts as flat."""

    size: bool = True
    periphery: bool = True
    velocity: bool = True
    cull: bool = True
    xi: float | None = None
    velocity_deg_s: float | None = None
    tol: float = 0.0

    def __post_init__(self):
        for name in ("size", "periphery", "velocity", "cull"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise PlodError(f"terrain: TerrainCriteria.{name} must be True or False, got {getattr(self, name)!r}")
        for name, strict in (("xi", True), ("velocity_deg_s", False), ("tol", False)):
            x = getattr(self, name)
            if x is None and name != "tol":
                continue
            ok = isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, bool) and \
                math.isfinite(float(x)) and (float(x) > 0 if strict else float(x) >= 0)
            if not ok:
                raise PlodError(f"terrain: TerrainCriteria.{name} must be a finite number {'>' if strict else '>='} "
                                f"0{' or None' if name != 'tol' else ''}, got {x!r}")


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
_MIN_BUCKET, _CHUNK = 64, 1 << 16  # padded lengths 64, 128, ..., 65536; longer inputs go in chunks


def _acuity_fn(xi):
    """A jitted ``H'(e, v)`` of :class:`pmetric.ReddyAcuity` with display cap ``xi`` (cached), compiled for
    every padded length when first made, so no frame pays for a compilation."""
    key = None if xi is None else float(xi)
    fn = _ACUITY_CACHE.get(key)
    if fn is None:
        import jax

        import pmetric

        model = pmetric.ReddyAcuity(xi=key)
        fn = jax.jit(lambda e, v: jax.numpy.exp(model.log_acuity(e, v)))
        b = _MIN_BUCKET
        while b <= _CHUNK:
            fn(np.zeros(b, np.float32), np.zeros(b, np.float32)).block_until_ready()
            b *= 2
        _ACUITY_CACHE[key] = fn
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


def _cross(a, b):
    """Cross product of (..., 3) arrays (np.cross without its axis shuffling)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], -1)


def _angle(a, b):
    """Angle (deg) between unit vectors (..., 3)."""
    return np.degrees(np.arctan2(np.linalg.norm(_cross(a, b), axis=-1), np.sum(a * b, axis=-1)))


def _arc_distance(g, a, b):
    """Shortest angle (deg) from unit direction g (3,) to the great-circle arcs a-b (K, 3)."""
    n = _cross(a, b)
    nn = np.linalg.norm(n, axis=-1, keepdims=True)
    n = n / np.maximum(nn, 1e-300)
    q = g - (n @ g)[:, None] * n
    qn = np.linalg.norm(q, axis=-1, keepdims=True)
    q = q / np.maximum(qn, 1e-300)
    on_arc = (np.sum(_cross(a, q) * n, -1) >= 0) & (np.sum(_cross(q, b) * n, -1) >= 0) & (nn[:, 0] > 1e-12)
    perp = np.degrees(np.arcsin(np.clip(np.abs(n @ g), 0.0, 1.0)))
    ends = np.minimum(_angle(a, g[None]), _angle(b, g[None]))
    return np.where(on_arc, np.minimum(perp, ends), ends)


def _culled(hf, cam, R, l, ii, jj, inside=False):
    """True where the square's bounding sphere (about its bounding box) lies wholly outside the field of
    view: beyond the elevation limits, or beyond the azimuth half-planes at +-fov_x/2 (for fov_x >= 180
    the culled back wedge is the intersection of the two outer half-spaces, below 180 their union).

    With ``inside=True`` returns (culled, contained): ``contained`` where the sphere lies wholly inside the
    field of view, so no part of the square's box, nor of any descendant's, can be culled.
    """
    s = 2 ** (hf.levels - l) * hf.spacing
    lo, hi = hf.zmin[l][ii, jj], hf.zmax[l][ii, jj]
    c = np.stack([(jj + 0.5) * s, 0.5 * (lo + hi), (ii + 0.5) * s], -1)
    r = np.sqrt(0.5 * s * s + 0.25 * (hi - lo) ** 2)
    d = (c - np.asarray(cam.eye, float)) @ R.T
    dist = np.sqrt(np.einsum("ki,ki->k", d, d))
    far = dist > r
    sin_rho = np.where(far, r / np.maximum(dist, 1e-300), 1.0)
    u = d / np.maximum(dist, 1e-300)[:, None]
    hx, hy = (math.radians(a / 2) for a in cam.fov_deg)
    ca, sa = math.cos(hx), math.sin(hx)
    dp = u[:, 0] * ca + u[:, 2] * sa  # signed distance (over dist) beyond the azimuth +hx half-plane
    dm = -u[:, 0] * ca + u[:, 2] * sa
    wide = hx >= math.pi / 2
    side = ((dp > sin_rho) & (dm > sin_rho)) if wide else ((dp > sin_rho) | (dm > sin_rho))
    el = np.arcsin(np.clip(u[:, 1], -1.0, 1.0))
    rho = np.arcsin(np.clip(sin_rho, 0.0, 1.0))
    out = far & (side | (el - rho > hy) | (el + rho < -hy))
    if not inside:
        return out
    margin = 1e-9
    ins = ((dp < -sin_rho - margin) | (dm < -sin_rho - margin)) if wide else \
        ((dp < -sin_rho - margin) & (dm < -sin_rho - margin))
    return out, far & ins & (el + rho < hy - margin) & (el - rho > -hy + margin)


def _dirs(X, Y, Z, eye, R):
    """Unit camera-space directions (three (U,) arrays) of the world points (X, Y, Z) from ``eye`` under
    rotation R (structure of arrays: each step is one contiguous pass, no (U, 3) strides)."""
    dx, dy, dz = X - eye[0], Y - eye[1], Z - eye[2]
    u = [R[i, 0] * dx + R[i, 1] * dy + R[i, 2] * dz for i in range(3)]
    inv = 1.0 / np.maximum(np.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]), 1e-300)
    for c in u:
        c *= inv
    return u


def _acos_deg(x):
    return np.degrees(np.arccos(np.clip(x, -1.0, 1.0)))


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

    Work is per unique corner (directions, retinal velocity) and the exact eccentricity (distance to the
    edge arcs) is computed only where it can change the answer: H' is non-increasing in e and v
    [Red01 Eq 4-5], and e lies in [max(0, c - s/2), c] with c the angle to the nearest corner and s the
    square's extent (every edge point is within half an edge, <= s/2, of a corner); the gaze can lie inside
    the square only where c <= s, and only those squares get the inside test.
    """
    L = hf.levels
    step = 2 ** (L - l)
    m1 = 2 ** l + 1
    nodes, inv = _corner_nodes(l, a, b)
    return _size_exact(hf, camera, R, g, criteria, moves, dt_s, (nodes // m1) * step, (nodes % m1) * step, inv)


def _size_exact(hf, camera, R, g, criteria, moves, dt_s, r, c, inv):
    """:func:`_perceptible_exact` for squares of any levels given by their corner samples: ``r``, ``c`` (U,)
    int row and column of the grid nodes (samples), ``inv`` (4, K) index of each square's corners NW, NE,
    SE, SW among them. Returns (K,) bool."""
    X, Y, Z = c * hf.spacing, hf.heights[r, c], r * hf.spacing
    U = _dirs(X, Y, Z, np.asarray(camera.eye, float), R)
    C = [u[inv] for u in U]  # (4, K) each: the corners' directions
    nxt = [1, 2, 3, 0]  # corner k + 1 (cheaper than np.roll)
    edge = C[0] * C[0][nxt]  # corners k, k + 1: the four edges
    diag = C[0][:2] * C[0][2:]  # corners 0-2, 1-3: the diagonals
    for Ck in C[1:]:
        edge += Ck * Ck[nxt]
        diag += Ck[:2] * Ck[2:]
    ext = _acos_deg(np.minimum(edge.min(0), diag.min(0)))
    k = inv.shape[1]
    v = np.zeros(k)
    if criteria.velocity:
        if criteria.velocity_deg_s is not None:
            v = np.full(k, float(criteria.velocity_deg_s))
        elif moves:
            prev, acc = U, np.zeros(len(r))
            for eye_p, Rp in moves:
                dp = _dirs(X, Y, Z, eye_p, Rp)
                acc += _acos_deg(prev[0] * dp[0] + prev[1] * dp[1] + prev[2] * dp[2])
                prev = dp
            v = (acc / (len(moves) * dt_s))[inv].min(0)
    if not criteria.periphery:
        return ext >= 1.0 / (2.0 * _acuity(criteria.xi, np.zeros(k), v))
    near = _acos_deg(U[0] * g[0] + U[1] * g[1] + U[2] * g[2])[inv].min(0)  # angle (deg) to the nearest corner: an upper bound of e
    lo = np.maximum(near - 0.5 * ext, 0.0)
    hi = near.copy()

    def edges(sel):  # (4 len(sel), 3) each: the selected squares' edges i (corner i to i + 1), edge by edge
        S = np.stack([Ck[:, sel] for Ck in C], -1)  # (4, len(sel), 3)
        return S.reshape(-1, 3), S[nxt].reshape(-1, 3)

    cand = np.flatnonzero(near <= ext * (1.0 + 1e-9) + 1e-12)
    if len(cand):
        Pc, Qc = edges(cand)
        sides = (_cross(Pc, Qc) @ g).reshape(4, -1).T
        inside = ((sides >= 0).all(1) | (sides <= 0).all(1)) & ((Pc @ g).reshape(4, -1).T > 0).all(1)
        lo[cand[inside]] = 0.0
        hi[cand[inside]] = 0.0
    # H' at both ends of e in one call (each JAX call costs 0.1-0.2 ms, the arithmetic per square nothing)
    h = _acuity(criteria.xi, np.concatenate([hi, lo]), np.concatenate([v, v]))
    sure = ext >= 1.0 / (2.0 * h[:k])  # perceptible even at the largest possible e
    out = sure.copy()
    rest = np.flatnonzero(~sure)
    amb = rest[ext[rest] >= 1.0 / (2.0 * h[k:][rest])]  # maybe, at the smallest e
    if len(amb):
        e = _arc_distance(g, *edges(amb)).reshape(4, -1).min(0)
        out[amb] = ext[amb] >= 1.0 / (2.0 * _acuity(criteria.xi, e, v[amb]))
    return out



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
_VELOCITY_MIN = 0.02  # without periphery: a strip computes its corners' velocities when the motion
# bound leaves more than this fraction of its candidates open
_CONSTS: dict = {}


def _arc_upper_deg(c: np.ndarray) -> np.ndarray:
    """An upper bound (deg, float32) of the arc 2 asin(c / 2) between unit vectors whose chord is ``c``:
    ``c + c^3 * _SERIES`` (rad) for chords up to ``_CHORD_MAX``, ``pi c / 2`` beyond."""
    x = c * c
    x *= np.float32(_SERIES)
    x += np.float32(1.0)
    x *= c
    if c.max() > _CHORD_MAX:
        np.copyto(x, c * np.float32(math.pi / 2), where=c > _CHORD_MAX)
    x *= np.float32(180.0 / math.pi)
    return x


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


def _dirs32(Y, X, Z, eye, R=None):
    """float32 unit directions (three (nr, nc) arrays) of the grid nodes at heights ``Y`` (nr, nc) m,
    columns at x = ``X`` (nc,) m and rows at z = ``Z`` (nr,) m, seen from ``eye``: in world axes
    (``R`` None; then also returns the distances |p - eye| (nr, nc) m, float32) or rotated by ``R``.
    The x and z terms are per column / row (float64, rounded once); every component carries at most a
    few float32 roundings of |p - eye|, so each direction is within ``_EPS_DIR`` of the exact one."""
    f32 = np.float32
    dy = np.empty(Y.shape, f32)
    np.subtract(Y, eye[1], out=dy, casting="same_kind")
    dx, dz = X - eye[0], Z - eye[2]
    if R is None:
        n = dy * dy
        n += (dx * dx).astype(f32)
        n += (dz * dz).astype(f32)[:, None]
        np.sqrt(n, out=n)
        inv = np.divide(f32(1.0), n)  # a node at the eye: inf, then NaN below, so undecided
        dy *= inv
        return [inv * dx.astype(f32), dy, inv * dz.astype(f32)[:, None]], n
    u = []
    for i in range(3):
        c = dy * f32(R[i, 1])
        c += (R[i, 0] * dx).astype(f32)
        c += (R[i, 2] * dz).astype(f32)[:, None]
        u.append(c)
    n = u[0] * u[0]
    t = u[1] * u[1]
    n += t
    np.multiply(u[2], u[2], out=t)
    n += t
    np.sqrt(n, out=n)
    np.divide(f32(1.0), n, out=n)
    for c in u:
        c *= n
    return u


def _chord2(a, b, out, t):
    """Squared chord |a - b|^2 of float32 unit directions (three arrays each), into ``out``."""
    np.subtract(a[0], b[0], out=out)
    out *= out
    for i in (1, 2):
        np.subtract(a[i], b[i], out=t)
        t *= t
        out += t
    return out


def _corner_min(A):
    """(nr - 1, nc - 1) minimum over each square's four corners of the node values A (nr, nc)."""
    m = np.minimum(A[:-1, :-1], A[:-1, 1:])
    np.minimum(m, A[1:, 1:], out=m)
    np.minimum(m, A[1:, :-1], out=m)
    return m


def _corner_max(A):
    """(nr - 1, nc - 1) maximum over each square's four corners of the node values A (nr, nc)."""
    m = np.maximum(A[:-1, :-1], A[:-1, 1:])
    np.maximum(m, A[1:, 1:], out=m)
    np.maximum(m, A[1:, :-1], out=m)
    return m


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
    near <= s (the gaze inside). The measured velocity (``motion``, see :func:`_motion`): with the
    periphery criterion, from the corners' directions in the previous cameras over the whole strip;
    without it, first bounded from the camera motion alone (rotation angles and eye steps), the previous
    cameras' directions then computed only where that leaves more than ``_VELOCITY_MIN`` of the
    candidates open (with the periphery, the squares left open are mostly those whose e interval
    straddles the threshold, which the velocity cannot decide).
    """
    consts = _acuity_consts(criteria.xi)
    f32 = np.float32
    step = 2 ** (hf.levels - l)
    Y = hf.heights[i0 * step:i1 * step + 1:step, j0 * step:j1 * step + 1:step]
    X, Z = np.arange(j0, j1 + 1) * step * hf.spacing, np.arange(i0, i1 + 1) * step * hf.spacing
    U, dist = _dirs32(Y, X, Z, eye)
    nr, nc = Y.shape
    sq = (nr - 1, nc - 1)
    # extent: the largest chord between two of the four corners (four edges shared between squares, two diagonals)
    eh = _chord2([u[:, :-1] for u in U], [u[:, 1:] for u in U], np.empty((nr, nc - 1), f32),
                 np.empty((nr, nc - 1), f32))
    ev = _chord2([u[:-1] for u in U], [u[1:] for u in U], np.empty((nr - 1, nc), f32), np.empty((nr - 1, nc), f32))
    t1, t2 = np.empty(sq, f32), np.empty(sq, f32)
    c = _chord2([u[:-1, :-1] for u in U], [u[1:, 1:] for u in U], np.empty(sq, f32), t1)
    np.maximum(c, _chord2([u[:-1, 1:] for u in U], [u[1:, :-1] for u in U], t1, t2), out=c)
    em = np.maximum(eh[:-1], eh[1:])  # the longest edge: e >= near - (longest edge) / 2 outside the square
    np.maximum(em, ev[:, :-1], out=em)
    np.maximum(em, ev[:, 1:], out=em)
    np.maximum(c, em, out=c)
    np.sqrt(c, out=c)
    deg = f32(180.0 / math.pi)
    h_s = np.maximum(c - f32(_EPS_CHORD), f32(0.0))  # x_lo (rad), then the H' a sure split needs
    h_s *= f32(deg * 2.0 * (1.0 - _MU))
    np.divide(f32(1.0), h_s, out=h_s)  # inf where x_lo = 0
    c += f32(_EPS_CHORD)
    x_hi = _arc_upper_deg(c)
    h_n = np.divide(f32(0.5 / (1.0 + _MU)), x_hi)
    if criteria.periphery:  # the longest edge's angle (deg), bounded above like x_hi
        np.sqrt(em, out=em)
        em += f32(_EPS_CHORD)
        np.minimum(em, c, out=em)
        em = _arc_upper_deg(em)
    kmax = far = None
    if criteria.periphery:
        k = U[0] * f32(gw[0])
        k += U[1] * f32(gw[1])
        k += U[2] * f32(gw[2])
        kmax = _corner_max(k)
        far = (kmax + f32(_EPS_COS)) < np.cos(np.minimum(x_hi * f32(math.pi / 180.0), f32(math.pi)))
    if not criteria.velocity or (criteria.velocity_deg_s is None and motion is None) or \
            criteria.velocity_deg_s is not None:  # v = 0, or imposed: G known
        gv = _G(consts, criteria.velocity_deg_s if criteria.velocity and criteria.velocity_deg_s is not None else 0.0)
        yes, no = _decide(consts, criteria.periphery, em, h_s, h_n, gv, gv, kmax, far)
        if criteria.periphery:
            _edge_refine(consts, yes, no, cand, far, U, gw, h_s, h_n, gv, gv)
        return yes, no
    # measured velocity, first bounded from the camera motion alone (see _motion): per node, each step's
    # angle lies within the rotation's part (<= its angle times the sine to its axis, >= 2 sin(angle/2)
    # times it) plus or minus the parallax; the earlier directions differ from the current one by at most
    # A = asin(D / r) <= D / sqrt(r^2 - D^2) (D the farthest earlier eye, r the distance)
    mo = motion
    if criteria.periphery:  # the corners' velocities over the whole strip (see the docstring)
        lo, hi = _velocity32(Y, X, Z, U, mo)
        g_s, g_n = _G(consts, _corner_min(hi) * f32(mo["scale"])), _G(consts, _corner_min(lo) * f32(mo["scale"]))
        yes, no = _decide(consts, True, em, h_s, h_n, g_s, g_n, kmax, far)
        _edge_refine(consts, yes, no, cand, far, U, gw, h_s, h_n, g_s, g_n)
        return yes, no
    ed = f32(_EPS_DIR)
    r = dist * f32(1.0 - 1e-6)
    A = r * r
    A -= f32(mo["back"] ** 2)
    np.sqrt(np.maximum(A, f32(0.0)), out=A)
    np.divide(f32(mo["back"]), A, out=A)  # inf where the eye may have passed the node
    # sine of the angle to the vertical (the mean rotation axis), bounds from above and below
    ay = np.abs(U[1])
    sn_hi = np.maximum(ay - ed, f32(0.0))
    sn_hi *= sn_hi
    np.subtract(f32(1.0), sn_hi, out=sn_hi)
    np.sqrt(np.maximum(sn_hi, f32(0.0)), out=sn_hi)
    sn_lo = np.minimum(ay + ed, f32(1.0))
    sn_lo *= sn_lo
    np.subtract(f32(1.0), sn_lo, out=sn_lo)
    np.sqrt(np.maximum(sn_lo, f32(0.0)), out=sn_lo)
    # parallax: sum over steps <= X / sqrt(1 - X^2), X = (C s + Rho + Travel A) / (r - D), s the sine of the
    # angle to the mean step direction
    dd = mo["dir"]
    sd = U[0] * f32(dd[0])
    sd += U[1] * f32(dd[1])
    sd += U[2] * f32(dd[2])
    np.abs(sd, out=sd)
    sd -= ed
    np.maximum(sd, f32(0.0), out=sd)
    sd *= sd
    np.subtract(f32(1.0), sd, out=sd)
    np.sqrt(np.maximum(sd, f32(0.0)), out=sd)
    px = sd * f32(mo["along"])
    px += f32(mo["across"])
    px += A * f32(mo["travel"])
    r -= f32(mo["back"])
    px /= r
    np.copyto(px, f32(np.inf), where=r <= f32(mo["travel"]))  # a step may be as long as the distance: unbounded
    par = px * px
    np.subtract(f32(1.0), par, out=par)
    np.sqrt(np.maximum(par, f32(0.0)), out=par)
    np.divide(px, par, out=par)
    th_hi = sn_hi + A
    th_hi *= f32(mo["rot"])
    th_hi += f32(mo["rot_off"])
    th_hi += par
    th_lo = sn_lo - A
    th_lo *= f32(mo["chord"])
    th_lo -= f32(mo["chord_off"])
    th_lo -= par
    np.fmax(th_lo, f32(0.0), out=th_lo)  # NaN (no rotation, node at the eye's path) to 0
    scale = mo["scale"]
    v_hi = _corner_min(th_hi)
    v_hi *= f32(scale * (1.0 + 1e-5))
    v_lo = _corner_min(th_lo)
    v_lo *= f32(scale * (1.0 - 1e-5))
    g_s, g_n = _G(consts, v_hi), _G(consts, v_lo)
    yes, no = _decide(consts, criteria.periphery, em, h_s, h_n, g_s, g_n, kmax, far)
    open_ = cand & ~(yes | no)
    # the squares the corners' velocities may decide: open, with a G interval wider than a few margins
    n_open = np.count_nonzero(open_ & (g_n > g_s * f32(1.0 + 4.0 * _MU)))
    if n_open <= _VELOCITY_MIN * np.count_nonzero(cand):  # few: decided square by square
        if criteria.periphery:
            _edge_refine(consts, yes, no, cand, far, U, gw, h_s, h_n, g_s, g_n)
        return yes, no
    rows, cols = np.flatnonzero(open_.any(1)), np.flatnonzero(open_.any(0))
    # the corners' velocity over the squares still open: per node, the sum over steps of the angle between
    # successive directions (all in the current camera's world axes: R_0^T R_j), from float32 chords
    a0, a1, b0, b1 = int(rows[0]), int(rows[-1]) + 2, int(cols[0]), int(cols[-1]) + 2
    lo, hi = _velocity32(Y[a0:a1, b0:b1], X[b0:b1], Z[a0:a1], [u[a0:a1, b0:b1] for u in U], mo)
    ri, ci = np.nonzero(open_[a0:a1 - 1, b0:b1 - 1])
    gs2 = np.maximum(_G(consts, _corner_min(hi)[ri, ci] * f32(scale)), g_s[ri + a0, ci + b0])
    gn2 = np.minimum(_G(consts, _corner_min(lo)[ri, ci] * f32(scale)), g_n[ri + a0, ci + b0])
    ri += a0
    ci += b0
    y2, n2 = _decide(consts, criteria.periphery, em[ri, ci], h_s[ri, ci], h_n[ri, ci], gs2, gn2,
                     None if kmax is None else kmax[ri, ci], None if far is None else far[ri, ci])
    yes[ri, ci] = y2
    no[ri, ci] = n2
    if criteria.periphery:
        g_s[ri, ci], g_n[ri, ci] = gs2, gn2
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
    e a sure split allows / below which none can be are made on sines and cosines. float64 arithmetic on
    the float32 directions ``U`` (three (nr, nc) arrays) with their error ``_EPS_DIR``; ``h_s``, ``h_n``,
    ``g_s``, ``g_n`` as in :func:`_decide` (arrays of the squares' shape, or scalars for g)."""
    ri, ci = np.nonzero(cand & ~(yes | no))
    if not len(ri):
        return
    xi, _, _, _, _, ms, mr = consts
    ed = _EPS_DIR
    g = np.asarray(gw, float)
    hs, hn = h_s[ri, ci].astype(np.float64), h_n[ri, ci].astype(np.float64)
    q_s = hs / (g_s[ri, ci] if isinstance(g_s, np.ndarray) else g_s)
    q_n = hn / (g_n[ri, ci] if isinstance(g_n, np.ndarray) else g_n)
    m0 = min(1.0, ms)
    # M(e) >= q iff q <= M(0) and e <= E(q) = (sqrt(m_scale / q) - 1) / m_rate (deg); E less / more a
    # little for the float64 path's own rounding of e, in radians, capped at pi
    y_ok = (hs <= xi) & (q_s <= m0)
    n_ok = (hn > xi) | (q_n > m0)
    rad = math.pi / 180.0
    with np.errstate(all="ignore"):
        E_s = np.clip(((np.sqrt(ms / q_s) - 1.0) / mr - 1e-7) * rad, 0.0, math.pi)
        E_n = np.clip(((np.sqrt(ms / q_n) - 1.0) / mr + 1e-7) * rad, 0.0, math.pi)
    cs, ss, cn, sn = np.cos(E_s), np.sin(E_s), np.cos(E_n), np.sin(E_n)
    half_s, half_n = E_s >= math.pi / 2, E_n >= math.pi / 2
    # the corners NW, NE, SE, SW (4, k) per component; edge i runs from corner i to corner i + 1
    nc = U[0].shape[1]
    lin = (ri * nc + ci) + np.array([0, 1, nc + 1, nc])[:, None]  # flat node ids (4, k)
    nxt = [1, 2, 3, 0]  # corner i + 1 (np.roll costs more than the arithmetic here)
    P = [u.ravel()[lin].astype(np.float64) for u in U]
    Q = [p[nxt] for p in P]
    gP = g[0] * P[0] + g[1] * P[1] + g[2] * P[2]  # (4, k): the cosine to the gaze of each corner
    gQ = gP[nxt]
    pq = P[0] * Q[0] + P[1] * Q[1] + P[2] * Q[2]
    n0, n1, n2 = P[1] * Q[2] - P[2] * Q[1], P[2] * Q[0] - P[0] * Q[2], P[0] * Q[1] - P[1] * Q[0]
    nn = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    side = g[0] * n0 + g[1] * n1 + g[2] * n2
    gn = np.abs(side)
    t = 6 * ed
    t1, t2 = gQ - pq * gP, gP - pq * gQ
    on = (t1 > t) & (t2 > t)  # the foot surely on the arc
    off = (t1 < -t) | (t2 < -t)  # surely off it
    cmax = np.maximum(gP, gQ)
    with np.errstate(all="ignore"):
        s_hi = np.where(nn > 2 * ed, (gn + 2 * ed) / (nn - 2 * ed), np.inf)
        s_lo = (gn - 2 * ed) / (nn + 2 * ed)
    # some edge within E_s: its nearer end within it, or the foot on the arc and the circle within it
    within = np.any((cmax - ed >= cs) | (on & (half_s | (s_hi <= ss))), 0)
    # every edge beyond E_n: the ends beyond it and, unless the foot is surely off the arc, the circle too
    beyond = np.all((cmax + ed < cn) & (off | (~half_n & (s_lo > sn))), 0)
    # e = 0 only where the float64 path tests the gaze inside: the nearest corner surely within the
    # extent (the largest cosine to the gaze above the smallest between two corners)
    d02 = P[0][0] * P[0][2] + P[1][0] * P[1][2] + P[2][0] * P[2][2]  # the diagonals' cosines
    d13 = P[0][1] * P[0][3] + P[1][1] * P[1][3] + P[2][1] * P[2][3]
    tested = gP.max(0) - ed > np.minimum(np.minimum(pq.min(0), d02), d13) + 2 * ed
    inside = (np.all(side > 4 * ed, 0) | np.all(side < -4 * ed, 0)) & np.all(gP > 4 * ed, 0) & tested
    outside = far[ri, ci] | (np.any(side > 4 * ed, 0) & np.any(side < -4 * ed, 0)) | np.any(gP < -4 * ed, 0)
    yes[ri, ci] = y_ok & (inside | (outside & within))
    no[ri, ci] = n_ok | (outside & beyond)


def _velocity32(Ys, Xs, Zs, U, mo):
    """Per node (nr, nc) float32 bounds (lo, hi) of the sum over the previous steps of the angle (rad) between
    successive directions, from float32 chords: the grid nodes at heights ``Ys`` (nr, nc), x = ``Xs`` (nc,),
    z = ``Zs`` (nr,) m, ``U`` their current directions (world axes, :func:`_dirs32`), ``mo`` :func:`_motion`."""
    f32 = np.float32
    prev = U
    s1 = np.zeros(Ys.shape, f32)
    s3 = np.zeros(Ys.shape, f32)
    d2, d = np.empty(Ys.shape, f32), np.empty(Ys.shape, f32)
    for eye_p, S in mo["moves"]:
        dp = _dirs32(Ys, Xs, Zs, eye_p, S)
        _chord2(prev, dp, d2, d)
        np.sqrt(d2, out=d)
        s1 += d
        d2 *= d
        s3 += d2
        prev = dp
    n = len(mo["moves"])
    ve = f32(1.02 * n * _EPS_CHORD)
    # per node: the angle sum lies in [s1 + s3 / 24 - ve, s1 + s3 * _SERIES + ve] when every chord is
    # <= _CHORD_MAX (so when s1 is), else in [s1 - n eps, pi / 2 (s1 + n eps)]
    lo = s3 * f32(1.0 / 24.0)
    lo += s1
    lo -= ve
    hi = s3 * f32(_SERIES)
    hi += s1
    hi += ve
    if s1.max() > _CHORD_MAX:
        w = s1 > _CHORD_MAX
        np.copyto(lo, s1 - f32(n * _EPS_CHORD), where=w)
        np.copyto(hi, (s1 + f32(n * _EPS_CHORD)) * f32(math.pi / 2), where=w)
    return lo, hi


def _motion(eye, R, moves, dt_s):
    """What the bound pass needs of the camera motion (None without previous cameras), a dict:

    ``rot`` / ``chord``: the sums over steps of the rotation angles w_j (rad) / of 2 sin(w_j / 2);
    ``rot_off`` / ``chord_off``: the same weighted by |n_j - y| (n_j the axis, y the vertical, either
    sign), plus an allowance for rounding (a node's rotation part is <= w_j |u x n_j| and >= 2 sin(w_j / 2)
    |u x n_j|, and |u x n_j| is within |n_j - y| of |u x y|); ``dir``: the mean step direction (3,),
    ``along`` / ``across``: the sums of the steps' components along it and across it (m), ``travel``: the
    sum of the step lengths (m), ``back``: the farthest an earlier eye lies from the current one (m);
    ``scale``: deg/s per radian of angle sum; ``moves``: [(eye (3,), R_0^T R_j (3, 3))] of the previous
    cameras (directions in the current camera's world axes). ``moves``: [(eye, R)], most recent first."""
    if not moves:
        return None
    cams = [(eye, R)] + list(moves)
    y = np.array([0.0, 1.0, 0.0])
    rot = chord = rot_off = chord_off = 0.0
    steps = []
    for (e0, R0), (e1, R1) in zip(cams, cams[1:]):
        Q = R0.T @ R1  # world-frame rotation between the two cameras' views of one direction
        w = math.acos(max(-1.0, min(1.0, (float(np.trace(Q)) - 1.0) / 2.0)))
        ax = np.array([Q[2, 1] - Q[1, 2], Q[0, 2] - Q[2, 0], Q[1, 0] - Q[0, 1]])
        na = float(np.linalg.norm(ax))
        off = 2.0 if na < 1e-6 else \
            min(float(np.linalg.norm(ax / na - y)), float(np.linalg.norm(ax / na + y))) + 1e-9 / na
        w_hi, w_lo = w + 1e-7, max(w - 1e-7, 0.0)
        rot += w_hi
        rot_off += w_hi * off + 1e-7
        c = 2.0 * math.sin(w_lo / 2.0)
        chord += c
        chord_off += c * off + 1e-7
        steps.append(e0 - e1)
    steps = np.array(steps)
    tot = steps.sum(0)
    nt = float(np.linalg.norm(tot))
    d = tot / nt if nt > 0 else np.array([1.0, 0.0, 0.0])
    along = float(np.abs(steps @ d).sum())
    across = float(np.linalg.norm(steps - np.outer(steps @ d, d), axis=1).sum())
    travel = float(np.linalg.norm(steps, axis=1).sum())
    back = max(float(np.linalg.norm(e - eye)) for e, _ in moves)
    k = 1.0 + 1e-9
    return {"rot": rot, "chord": chord, "rot_off": rot_off + 2e-7 * len(moves),
            "chord_off": chord_off + 2e-7 * len(moves),
            "dir": d, "along": along * k + 1e-9, "across": across * k + 1e-9, "travel": travel * k, "back": back * k,
            "scale": 180.0 / math.pi / (len(moves) * dt_s), "moves": [(e, R.T @ Rj) for e, Rj in moves]}


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
    the float64 test's square for square).
    """
    L = hf.levels
    if not (dt_s > 0):
        raise PlodError(f"terrain: dt_s must be a positive time step in seconds, got {dt_s!r}")
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
    for l in range(L):
        m = 2 ** l
        ok = cand & (hf.err[l] > criteria.tol)
        if criteria.cull:
            # 0 unknown, 1 visible, 2 culled, 3 contained (its box, and every descendant's, in view)
            cmap = np.zeros((1, 1), np.int8) if l == 0 else _inherit(culled[l - 1])
            t = np.flatnonzero(ok & (cmap != 3))
            if len(t):
                c, inside = _culled(hf, camera, R, l, t >> l, t & (m - 1), inside=True)
                cmap.flat[t] = np.where(c, 2, np.where(inside, 3, 1))
                ok.flat[t[c]] = False
            culled[l] = cmap
        if criteria.size:
            if l <= small_levels:
                if l == 0:
                    small = _size_small(hf, camera, R, g, criteria, moves, dt_s, small_levels)
                ok &= small[l]
            else:
                _size_test(hf, camera, R, g, criteria, moves, dt_s, l, ok, motion)
        split.append(ok)
        cand = _up(ok)
    _restrict(split)
    return _leaves(hf, camera, R, criteria, split, culled)


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
    L = hf.levels
    drawn, fans = [], []
    tri = 0
    for l in range(L + 1):
        m = 2 ** l
        leaf = np.ones((1, 1), bool) if l == 0 else _up(split[l - 1])
        if l < L:
            leaf &= ~split[l]
        if criteria.cull:
            if culled[l] is not None:  # levels < L: the refinement's map (3 under every contained parent)
                known = culled[l]
                leaf &= known != 2
                unknown = leaf & (known == 0)
            else:  # the finest level was never tested: visible under a contained parent, else unknown
                unknown = leaf & ~_up(culled[l - 1] == 3)
            t = np.flatnonzero(unknown)
            if len(t):
                leaf.flat[t] = ~_culled(hf, camera, R, l, t >> l, t & (m - 1))
        idx = np.flatnonzero(leaf)
        if l < L:
            # the split map padded by one square: neighbours north, east, south, west by flat offsets
            P = np.zeros((m + 2, m + 2), bool)
            P[1:-1, 1:-1] = split[l]
            P = P.ravel()
            p = idx + 2 * (idx >> l) + (m + 3)
            fan = np.empty((len(idx), 4), bool)
            for e, off in enumerate((-(m + 2), 1, m + 2, -1)):
                np.take(P, p + off, out=fan[:, e])
            tri += _fan_triangles(fan)
        else:  # the finest level has no finer neighbour: two triangles each
            fan = np.zeros((len(idx), 4), bool)
            tri += _fan_triangles(fan)
        rc = np.empty((2, len(idx)), idx.dtype)  # (row, column) as columns of a (K, 2) view
        np.right_shift(idx, l, out=rc[0])
        np.bitwise_and(idx, m - 1, out=rc[1])
        drawn.append(rc.T)
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
    off, none (``reports/terrain/scripts/monotone.py`` measures how often and how much it adds)."""
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

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


# ----------------------------------------------------------------------------------------------- data
class Heightfield:
    """A square heightfield of ``N = 2^L + 1`` samples per side with its quadtree pyramid.

    ``heights`` (N, N) metres (row 0 at z = 0), ``spacing`` metres between samples. Precomputes per
    level ``l`` (0..L) the nested maximum vertical error (m) of each square against its two triangles
    (diagonal from corner (0, 0) to (1, 1)), and its minimum and maximum height (m) for culling.
    Raises :class:`PlodError` for an empty grid, a grid that is not square ``2^n + 1``, non-finite
    heights or a non-positive spacing.
    """

    def __init__(self, heights, spacing: float = 1.0):
        h = np.asarray(heights, dtype=np.float64)
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
@dataclass(frozen=True)
class TerrainCamera:
    """An eye at ``eye`` (3,) looking along ``forward`` (3,) with ``up`` (3,) (world units, y up).

    ``fov_deg`` (horizontal, vertical) is the angular field of view (deg; may exceed 180 horizontally: the
    test is on azimuth and elevation, not a perspective frustum); ``gaze_deg`` (azimuth, elevation) of
    the gaze from the forward direction (deg; right and up positive)."""

    eye: np.ndarray
    forward: np.ndarray
    up: tuple = (0.0, 1.0, 0.0)
    fov_deg: tuple[float, float] = (200.0, 135.0)
    gaze_deg: tuple[float, float] = (0.0, 0.0)

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
    (U,), (4, K) index into them, corners NW, NE, SE, SW). Shared corners are computed once."""
    m1 = 2 ** l + 1
    lin = (a * m1 + b)[None, :] + np.array([0, 1, m1 + 1, m1])[:, None]
    mask = np.zeros(m1 * m1, bool)
    mask[lin.ravel()] = True
    nodes = np.flatnonzero(mask)
    pos = np.cumsum(mask) - 1
    return nodes, pos[lin]


def _perceptible(hf, camera, R, g, criteria, moves, dt_s, l, a, b):
    """(K,) bool: the level-l squares (a, b) pass the size test ``s >= 1 / (2 H'(v, e))``.

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
    r, c = (nodes // m1) * step, (nodes % m1) * step
    X, Y, Z = c * hf.spacing, hf.heights[r, c], r * hf.spacing
    U = _dirs(X, Y, Z, np.asarray(camera.eye, float), R)
    C = [u[inv] for u in U]  # (4, K) each: the corners' directions
    edge = C[0] * np.roll(C[0], -1, 0)  # corners k, k + 1: the four edges
    diag = C[0][:2] * C[0][2:]  # corners 0-2, 1-3: the diagonals
    for Ck in C[1:]:
        edge += Ck * np.roll(Ck, -1, 0)
        diag += Ck[:2] * Ck[2:]
    ext = _acos_deg(np.minimum(edge.min(0), diag.min(0)))
    k = len(a)
    v = np.zeros(k)
    if criteria.velocity:
        if criteria.velocity_deg_s is not None:
            v = np.full(k, float(criteria.velocity_deg_s))
        elif moves:
            prev, acc = U, np.zeros(len(nodes))
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

    def corners(sel):  # (len(sel), 4, 3) directions of the selected squares' corners
        return np.stack([Ck[:, sel] for Ck in C], -1).transpose(1, 0, 2)

    cand = np.flatnonzero(near <= ext * (1.0 + 1e-9) + 1e-12)
    if len(cand):
        Dc = corners(cand)
        sides = np.stack([_cross(Dc[:, i], Dc[:, (i + 1) % 4]) @ g for i in range(4)], -1)
        inside = ((sides >= 0).all(1) | (sides <= 0).all(1)) & ((Dc @ g) > 0).all(1)
        lo[cand[inside]] = 0.0
        hi[cand[inside]] = 0.0
    sure = ext >= 1.0 / (2.0 * _acuity(criteria.xi, hi, v))  # perceptible even at the largest possible e
    out = sure.copy()
    rest = np.flatnonzero(~sure)
    amb = rest[ext[rest] >= 1.0 / (2.0 * _acuity(criteria.xi, lo[rest], v[rest]))]  # maybe, at the smallest e
    if len(amb):
        Da = corners(amb)
        e = np.min(np.stack([_arc_distance(g, Da[:, i], Da[:, (i + 1) % 4]) for i in range(4)], -1), -1)
        out[amb] = ext[amb] >= 1.0 / (2.0 * _acuity(criteria.xi, e, v[amb]))
    return out


def refine_terrain(hf: Heightfield, camera: TerrainCamera, criteria: TerrainCriteria = TerrainCriteria(),
                   previous=(), dt_s: float = 1 / 30) -> TerrainLOD:
    """Refine ``hf`` for one frame seen by ``camera`` under ``criteria`` (see the module docstring).

    ``previous``: the cameras of the preceding frames, most recent first (the retinal velocity is the
    mean over consecutive pairs of the angle a corner moved, over ``dt_s`` seconds each); empty means
    velocity 0. Cost: per level, a few passes over dense (2^l, 2^l) one-byte maps (candidates, cull
    state, splits) and the cull and size tests on the candidate squares only (their flat indices), per
    unique corner where squares share corners, in contiguous float64 component arrays; the cull test of
    each square is done once and reused by the leaf pass.
    """
    L = hf.levels
    if not (dt_s > 0):
        raise PlodError(f"terrain: dt_s must be a positive time step in seconds, got {dt_s!r}")
    R = camera.rotation()
    moves = [(np.asarray(c.eye, float), c.rotation()) for c in previous]
    g = camera.gaze()
    split, culled = [], [None] * (L + 1)
    cand = np.ones((1, 1), bool)  # the squares whose parent is split (dense per level); the root
    for l in range(L):
        m = 2 ** l
        ok = cand & (hf.err[l] > criteria.tol)
        if criteria.cull:
            # 0 unknown, 1 visible, 2 culled, 3 contained (its box, and every descendant's, in view)
            cmap = np.zeros((1, 1), np.int8) if l == 0 else _inherit(culled[l - 1])
            t = np.flatnonzero(ok & (cmap != 3))
            if len(t):
                c, inside = _culled(hf, camera, R, l, t // m, t % m, inside=True)
                cmap.flat[t] = np.where(c, 2, np.where(inside, 3, 1))
                ok.flat[t[c]] = False
            culled[l] = cmap
        if criteria.size:
            t = np.flatnonzero(ok)
            if len(t):
                ok.flat[t] = _perceptible(hf, camera, R, g, criteria, moves, dt_s, l, t // m, t % m)
        split.append(ok)
        cand = _up(ok)
    _restrict(split)
    return _leaves(hf, camera, R, criteria, split, culled)


def _inherit(parent_state):
    """The next level's cull map from the level's (0 unknown, 1 visible, 2 culled, 3 contained): 3 under a
    contained parent (its box, and every descendant's, is in view), else 0."""
    return np.where(_up(parent_state == 3), np.int8(3), np.int8(0))


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


def _finer(S):
    """(4, m, m) bool: the same-level neighbour north, east, south, west of each square exists and is split."""
    F = np.zeros((4,) + S.shape, bool)
    F[0, 1:], F[1, :, :-1], F[2, :-1], F[3, :, 1:] = S[:-1], S[:, 1:], S[1:], S[:, :-1]
    return F


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
            # levels < L: the refinement's map (already 3 under every contained parent); the finest
            # level was never tested: inherited from its parents
            known = culled[l] if culled[l] is not None else _inherit(culled[l - 1])
            leaf &= known != 2
            t = np.flatnonzero(leaf & (known == 0))
            if len(t):
                leaf.flat[t] = ~_culled(hf, camera, R, l, t // m, t % m)
        idx = np.flatnonzero(leaf)
        if l < L:
            fan = _finer(split[l]).reshape(4, -1)[:, idx].T
            k = np.count_nonzero(fan, axis=1)  # a leaf with k > 0 finer edges is a fan of 4 + k triangles
            tri += 2 * len(k) + 2 * int(np.count_nonzero(k)) + int(k.sum())
        else:  # the finest level has no finer neighbour: two triangles each
            fan = np.zeros((len(idx), 4), bool)
            tri += 2 * len(idx)
        drawn.append(np.stack([idx // m, idx % m], -1))
        fans.append(fan)
    return TerrainLOD(split, drawn, fans, tri, L)


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

"""The normal cube [ZH97; LHNW00 §4.3]: cells of normal directions, per-node normal masks, and the
silhouette table the scoring tests the masks against.

Layout: a direction's dominant axis and its sign pick one of 6 cube faces (face = 2 axis + (component
< 0)); the other two components (in axis order) divided by the dominant one give (u, v) in [-1, 1],
cut into ``q x q`` cells: cell = q^2 face + q iv + iu. Normal masks use q = 8 (384 cells = 48 bytes,
bit ``cell`` in byte ``cell // 8`` at bit ``cell % 8``, little-endian); view directions are binned
with q = ``_DIR_BINS`` for the silhouette table.
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np

__all__ = ["normal_cells", "normal_cell_directions", "silhouette_table"]

#: extra angular margins (deg) of the silhouette table, chosen per node by its angular radius
_MARGINS_DEG = (0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 90.0)
#: direction bins per cube-face side for the per-node view direction
_DIR_BINS = 16
#: rows of the silhouette table per margin level
_ROWS_PER_MARGIN = 6 * _DIR_BINS * _DIR_BINS


def _unit(x: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(x, axis=-1, keepdims=True)
    return np.divide(x, n, out=np.zeros_like(x), where=n > 0)


def unit_any_length(x) -> np.ndarray:
    """:func:`_unit` of float64 vectors ``x`` (..., 3) of any length: a row whose largest component lies
    outside (1e-150, 1e150) is first divided by it, so its norm neither under- nor overflows (a 1e200 light
    lit nothing, a 1e-170 normal was "zero"); the other rows keep ``_unit``'s arithmetic bit for bit."""
    x = np.asarray(x, np.float64)
    m = np.abs(x).max(axis=-1, keepdims=True)
    far = (m > 0) & ~((m > 1e-150) & (m < 1e150))
    if far.any():
        x = np.where(far, x / np.where(far, m, 1.0), x)
    if x.ndim == 1:  # one vector: x / |x| with numpy's 1-D norm, as its callers (lights, views) computed it
        n = np.linalg.norm(x)
        return x / n if n > 0 else np.zeros_like(x)
    return _unit(x)


def cube_cells(d: np.ndarray, per_side: int) -> np.ndarray:
    """Cube cell (K,) int64 in ``0 .. 6 per_side^2 - 1`` of each direction (K, 3) (need not be unit;
    zero -> a cell of +x); the layout of the module docstring."""
    n = np.asarray(d, dtype=np.float64)
    x, y, z = n[:, 0], n[:, 1], n[:, 2]
    ax_, ay, az = np.abs(x), np.abs(y), np.abs(z)
    axis = np.where((ax_ >= ay) & (ax_ >= az), 0, np.where(ay >= az, 1, 2))  # first maximum, as argmax
    dom = np.where(axis == 0, x, np.where(axis == 1, y, z))
    face = 2 * axis + (dom < 0)
    den = np.abs(dom)
    den = np.where(den > 0, den, 1.0)
    u = np.where(axis == 0, y, x) / den
    w = np.where(axis == 2, y, z) / den
    q = int(per_side)
    iu = np.clip(np.floor((u + 1.0) * (q / 2)), 0, q - 1).astype(np.int64)
    iv = np.clip(np.floor((w + 1.0) * (q / 2)), 0, q - 1).astype(np.int64)
    return face * q * q + iv * q + iu


def normal_cells(normals: np.ndarray) -> np.ndarray:
    """Normal-cube cell (K,) int64 in 0..383 of each normal (K, 3) (need not be unit; zero -> cell of +x).

    Face = 2 * axis + (component < 0) for the dominant axis; the other two components (in axis order)
    divided by |dominant| give (u, v) in [-1, 1], cut into 8 x 8 cells: cell = 64 face + 8 iv + iu.
    Bit ``cell`` of a mask is byte ``cell // 8``, bit ``cell % 8`` (little-endian).
    """
    return cube_cells(normals, 8)


def normal_cell_directions(corners: bool = False) -> np.ndarray:
    """Unit directions of the 384 normal-cube cells: centres (384, 3), or with ``corners`` (384, 4, 3).

    A cell contains every normal whose direction lies in the cone spanned by its 4 corner directions,
    so a view test that holds for all 4 corners holds for every normal in the cell.
    """
    cell = np.arange(384)
    face, rem = cell // 64, cell % 64
    iv, iu = rem // 8, rem % 8
    axis, neg = face // 2, face % 2
    other = np.array([[1, 2], [0, 2], [0, 1]])[axis]
    if corners:
        du = np.array([0, 1, 1, 0])
        dv = np.array([0, 0, 1, 1])
        u = (iu[:, None] + du) / 4.0 - 1.0
        w = (iv[:, None] + dv) / 4.0 - 1.0
    else:
        u = ((iu + 0.5) / 4.0 - 1.0)[:, None]
        w = ((iv + 0.5) / 4.0 - 1.0)[:, None]
    k = u.shape[1]
    out = np.zeros((384, k, 3))
    r = np.arange(384)[:, None]
    out[r, np.arange(k)[None, :], axis[:, None]] = np.where(neg, -1.0, 1.0)[:, None]
    out[r, np.arange(k)[None, :], other[:, 0][:, None]] = u
    out[r, np.arange(k)[None, :], other[:, 1][:, None]] = w
    out = _unit(out)
    return out if corners else out[:, 0]


def dir_bins(dx, dy, dz):
    """View-direction bin (0 .. 6*16*16-1) of vectors given as jax columns: the layout of
    :func:`cube_cells` with ``_DIR_BINS`` per side (in-kernel float32 form: one reciprocal, then
    multiplies)."""
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


# ----------------------------------------------------------------------------------------------
# silhouette table


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


@functools.lru_cache(maxsize=1)
def silhouette_table() -> np.ndarray:
    """(len(margins) * 6 * 16 * 16, 24) uint32: per (margin, view-direction bin) the possibly-front-facing
    (words 0..11) and possibly-back-facing (words 12..23) normal-cube cells, as packed 48-byte masks
    ([ZH97]'s normal masks as used by [LHNW00 §4.3], made conservative for perspective)."""
    samples = _sample_sphere(97)
    spacing = 2.0 / 96 * 57.3  # deg between neighbouring samples at a face centre (upper bound)
    cell_axes, cell_rad = _cones(samples, normal_cells(samples), 384, spacing)
    nb = _ROWS_PER_MARGIN
    bin_axes, bin_rad = _cones(samples, cube_cells(samples, _DIR_BINS), nb, spacing)
    ang = np.degrees(np.arccos(np.clip(bin_axes @ cell_axes.T, -1, 1)))  # (nb, 384)
    slack = cell_rad[None, :] + bin_rad[:, None]
    cell = np.arange(384)
    byte, bit = cell // 8, (1 << (cell % 8)).astype(np.uint8)
    table = np.zeros((len(_MARGINS_DEG), nb, 2, 48), np.uint8)
    for li, m in enumerate(_MARGINS_DEG):
        front = ang - slack - m < 90.0  # some normal of the cell may face some point's eye direction
        back = ang + slack + m > 90.0
        for k, sel in enumerate((front, back)):
            rows, cells = np.nonzero(sel)
            np.bitwise_or.at(table[li, :, k], (rows, byte[cells]), bit[cells])
    out = table.reshape(len(_MARGINS_DEG) * nb, 2, 48).view("<u4").reshape(-1, 24)
    out.flags.writeable = False
    return out


@functools.lru_cache(maxsize=1)
def table_device():
    """The silhouette table on the device as (rows * 12, 2) uint32: for each row and mask word, the
    front and back words side by side, so one gather fetches both."""
    t = silhouette_table()  # (rows, 24): front words 0..11, back words 12..23
    return jnp.asarray(np.ascontiguousarray(np.stack([t[:, :12], t[:, 12:]], axis=-1).reshape(-1, 2)))


@functools.lru_cache(maxsize=1)
def table_host() -> np.ndarray:
    """The silhouette table as numpy (rows * 12,) uint64: front word in the low, back word in the high half."""
    out = np.ascontiguousarray(np.asarray(table_device())).view(np.uint64).ravel()
    out.flags.writeable = False
    return out

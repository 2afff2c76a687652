"""Display model: screen geometry (pixels -> visual angle) and photometry (RGB -> cd/m2).

Geometry follows [Red01 Eq 5]: the highest frequency a display can show is
``xi = 1 / (2 * degrees_per_pixel)`` cycles/deg. Photometry follows [LH01 §6.1]: RGB values are turned into luminance (cd/m2) either by a transfer function (sRGB, IEC
61966-2-1, or a pure power-law gamma) between a black level and a peak luminance, or by a measured
per-channel lookup table, interpolated linearly, whose channel contributions above black add up.
Contrast is Michelson contrast ``(Lmax - Lmin) / (Lmax + Lmin)``.

Pixel coordinates are continuous, in pixels, with ``(0, 0)`` the top-left corner of the screen and
pixel ``(i, j)`` covering ``[i, i+1) x [j, j+1)`` (its centre is ``(i + 0.5, j + 0.5)``). The eye sits
on the perpendicular through the screen centre ``(W/2, H/2)`` at ``distance`` metres. Angles are exact
(3-D vectors, ``atan2``), not the small-angle approximation.

Default display (``Display.default()``): the seed-004 user study used a screen spanning 46 deg; we model
it as a 24-inch 16:9 1920 x 1080 monitor viewed from 0.6258 m, where it spans 46 deg horizontally,
with peak luminance 200 cd/m2, black level 0.5 cd/m2 and the sRGB transfer function.
"""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._base import check_broadcast, jittable
from ._errors import PlodError

__all__ = ["Display", "michelson", "michelson_range", "relative_luminance", "srgb_to_linear",
           "linear_to_srgb"]

_REC709 = (0.2126, 0.7152, 0.0722)
_TRANSFERS = ("srgb", "gamma", "lut")
_DEFAULTS: dict = {}  # Display.default() per JAX float width (jax_enable_x64)


def _concrete(x) -> np.ndarray | None:
    """numpy view of ``x`` when it is a concrete value (not a tracer), else None."""
    if isinstance(x, jax.core.Tracer):
        return None
    try:
        return np.asarray(x)
    except Exception:  # noqa: BLE001 - anything that is not array-like is left to jnp
        return None


def _check_finite_nonneg(name: str, x, *, positive: bool = False, upper: float | None = None):
    a = _concrete(x)
    if a is None:
        return
    if not np.issubdtype(a.dtype, np.number) and a.dtype != bool:
        raise PlodError(f"{name} must be numeric, got dtype {a.dtype}")
    if np.isnan(a).any():
        raise PlodError(f"{name} contains NaN")
    if np.isinf(a).any():
        raise PlodError(f"{name} contains an infinite value")
    if positive and (a <= 0).any():
        raise PlodError(f"{name} must be > 0, got {a[a <= 0].ravel()[0]!r}")
    if (a < 0).any():
        raise PlodError(f"{name} must be >= 0, got {a[a < 0].ravel()[0]!r}")
    if upper is not None and (a > upper).any():
        raise PlodError(f"{name} must be <= {upper}, got {a[a > upper].ravel()[0]!r}")


def _float(x):
    """Array of the default float dtype (float64 under x64) unless x is already floating."""
    x = jnp.asarray(x)
    if not jnp.issubdtype(x.dtype, jnp.floating) or x.weak_type:
        x = x.astype(jnp.result_type(float))
    return x


# ---------------------------------------------------------------------- photometry helpers
def srgb_to_linear(v):
    """sRGB EOTF (IEC 61966-2-1): encoded value in [0, 1] -> linear value in [0, 1], same shape.

    ``v <= 0.04045 -> v / 12.92``, else ``((v + 0.055) / 1.055) ** 2.4``. Values are clipped to
    [0, 1] (``Display.luminance`` rejects concrete values outside it).
    """
    v = jnp.clip(_float(v), 0.0, 1.0)
    hi = v > 0.04045
    safe = jnp.where(hi, v, 1.0)  # double-where: the pow branch only ever sees its own domain
    return jnp.where(hi, ((safe + 0.055) / 1.055) ** 2.4, v / 12.92)


def linear_to_srgb(u):
    """Inverse sRGB EOTF: linear value in [0, 1] -> encoded value in [0, 1], same shape."""
    u = jnp.clip(_float(u), 0.0, 1.0)
    hi = u > 0.0031308
    safe = jnp.where(hi, u, 1.0)
    return jnp.where(hi, 1.055 * safe ** (1.0 / 2.4) - 0.055, 12.92 * u)


def _gamma_to_linear(v, gamma):
    v = jnp.clip(_float(v), 0.0, 1.0)
    pos = v > 0
    safe = jnp.where(pos, v, 1.0)
    return jnp.where(pos, safe ** gamma, 0.0)


def _linear_to_gamma(u, gamma):
    u = jnp.clip(_float(u), 0.0, 1.0)
    pos = u > 0
    safe = jnp.where(pos, u, 1.0)
    return jnp.where(pos, safe ** (1.0 / gamma), 0.0)


def relative_luminance(rgb_linear):
    """Relative luminance Y of linear RGB (Rec. 709 / sRGB primaries): 0.2126 R + 0.7152 G + 0.0722 B.

    ``rgb_linear``: (..., 3) -> (...). Raises PlodError when the last axis is not 3.
    """
    rgb = _float(rgb_linear)
    if rgb.ndim == 0 or rgb.shape[-1] != 3:
        raise PlodError(f"relative_luminance: expected an (..., 3) RGB array, got shape {rgb.shape}")
    w = jnp.asarray(_REC709, dtype=rgb.dtype)
    return jnp.sum(rgb * w, axis=-1)


def michelson(l1, l2):
    """Michelson contrast ``|l1 - l2| / (l1 + l2)`` of two luminances (cd/m2, >= 0), broadcast.

    Returns 0 where both are 0 (and a finite, zero gradient there: double-where). Concrete negative or
    NaN luminances raise PlodError; under jit they are not checked (negative sums give 0).
    """
    _check_finite_nonneg("michelson: luminance l1", l1)
    _check_finite_nonneg("michelson: luminance l2", l2)
    l1, l2 = _float(l1), _float(l2)
    check_broadcast("michelson", l1=l1.shape, l2=l2.shape)
    den = l1 + l2
    ok = den > 0
    safe = jnp.where(ok, den, 1.0)
    diff = l1 - l2
    # |diff| with a gradient defined as 0 at diff == 0
    adiff = jnp.where(diff >= 0, diff, -diff)
    return jnp.where(ok, adiff / safe, 0.0)


def michelson_range(lum, axis=-1):
    """Michelson contrast ``(max - min) / (max + min)`` of luminances (cd/m2) along ``axis``.

    ``lum``: (..., n) -> (...) (the reduced axis removed). 0 where all values are 0.
    """
    _check_finite_nonneg("michelson_range: luminance", lum)
    lum = _float(lum)
    if lum.ndim == 0:
        raise PlodError("michelson_range: needs at least a 1-D array of luminances")
    return michelson(jnp.max(lum, axis=axis), jnp.min(lum, axis=axis))


def _angle_between(a, b):
    """Angle (rad) between 3-D vectors a, b (..., 3): atan2(|a x b|, a . b), gradient-safe at 0."""
    cr = jnp.cross(a, b)
    n2 = jnp.sum(cr * cr, axis=-1)
    pos = n2 > 0
    n = jnp.where(pos, jnp.sqrt(jnp.where(pos, n2, 1.0)), 0.0)
    return jnp.arctan2(n, jnp.sum(a * b, axis=-1))


class Display(eqx.Module):
    """A flat screen viewed head-on: geometry (m, px) and photometry (cd/m2).

    Array fields (scalars): ``width``, ``height`` (physical size of the image area, m), ``distance``
    (eye to screen centre, m), ``peak_luminance`` (white, cd/m2), ``black_level`` (black, cd/m2),
    ``gamma`` (exponent of the ``"gamma"`` transfer), ``lut_levels`` (K,) and ``lut_luminance`` (K, 3)
    (measured table of the ``"lut"`` transfer, else empty). Static: ``resolution`` (px_x, px_y),
    ``transfer`` (``"srgb"``, ``"gamma"`` or ``"lut"``).

    Construct with ``Display(width=..., height=..., resolution=..., distance=...)``,
    ``Display.from_diagonal(inches, aspect, resolution, distance)``, ``Display.from_lut(...)`` or
    ``Display.default()``. Geometry and photometry methods are jit / grad clean.
    """

    width: jax.Array
    height: jax.Array
    distance: jax.Array
    peak_luminance: jax.Array
    black_level: jax.Array
    gamma: jax.Array
    lut_levels: jax.Array
    lut_luminance: jax.Array
    resolution: tuple[int, int] = eqx.field(static=True)
    transfer: str = eqx.field(static=True)

    param_bounds: ClassVar[dict] = {
        "width": (0.0, None), "height": (0.0, None), "distance": (0.0, None),
        "peak_luminance": (0.0, None), "black_level": (0.0, None), "gamma": (0.0, None),
    }

    def __init__(
        self,
        width,
        height,
        resolution=(1920, 1080),
        distance=0.6,
        *,
        peak_luminance=200.0,
        black_level=0.5,
        transfer: str = "srgb",
        gamma=2.2,
        lut_levels=None,
        lut_luminance=None,
    ):
        if transfer not in _TRANSFERS:
            raise PlodError(f"Display: transfer must be one of {_TRANSFERS}, got {transfer!r}")
        try:
            rx, ry = (int(r) for r in resolution)
        except (TypeError, ValueError):
            raise PlodError(f"Display: resolution must be two integers (px_x, px_y), got {resolution!r}") from None
        if rx <= 0 or ry <= 0 or (rx, ry) != tuple(resolution):
            raise PlodError(f"Display: resolution must be two positive integers, got {resolution!r}")
        for name, val in (("width (m)", width), ("height (m)", height), ("distance (m)", distance),
                          ("peak_luminance (cd/m2)", peak_luminance), ("gamma", gamma)):
            if jnp.ndim(val) != 0:
                raise PlodError(f"Display: {name} must be a scalar, got shape {jnp.shape(val)}")
            _check_finite_nonneg(f"Display: {name}", val, positive=True)
        if jnp.ndim(black_level) != 0:
            raise PlodError(f"Display: black_level must be a scalar, got shape {jnp.shape(black_level)}")
        _check_finite_nonneg("Display: black_level (cd/m2)", black_level)
        pk, bl = _concrete(peak_luminance), _concrete(black_level)
        if pk is not None and bl is not None and not bl < pk:
            raise PlodError(f"Display: black_level {float(bl)} must be below peak_luminance {float(pk)} cd/m2")
        if transfer == "lut":
            if lut_levels is None or lut_luminance is None:
                raise PlodError("Display: transfer='lut' needs lut_levels (K,) and lut_luminance (K, 3)")
            lv, ll = _float(lut_levels), _float(lut_luminance)
            if lv.ndim != 1 or lv.shape[0] < 2 or ll.shape != (lv.shape[0], 3):
                raise PlodError(f"Display: lut_levels must be (K,) with K >= 2 and lut_luminance (K, 3); "
                                 f"got {lv.shape} and {ll.shape}")
            _check_finite_nonneg("Display: lut_levels", lut_levels, upper=1.0)
            _check_finite_nonneg("Display: lut_luminance (cd/m2)", lut_luminance)
            a = _concrete(lut_levels)
            if a is not None and not (np.diff(a) > 0).all():
                raise PlodError("Display: lut_levels must be strictly increasing")
            if a is not None and (a[0] != 0.0 or a[-1] != 1.0):
                raise PlodError(f"Display: lut_levels must span [0, 1] (got {a[0]} .. {a[-1]})")
            b = _concrete(lut_luminance)
            if b is not None and not (np.diff(b, axis=0) >= 0).all():
                raise PlodError("Display: lut_luminance must not decrease with the level in any channel")
        else:
            if lut_levels is not None or lut_luminance is not None:
                raise PlodError(f"Display: lut_levels / lut_luminance only apply to transfer='lut', not {transfer!r}")
            lv, ll = jnp.zeros((0,)), jnp.zeros((0, 3))
        self.width, self.height, self.distance = _float(width), _float(height), _float(distance)
        self.peak_luminance, self.black_level, self.gamma = _float(peak_luminance), _float(black_level), _float(gamma)
        for name, val, given in (("width (m)", self.width, width), ("height (m)", self.height, height),
                                 ("distance (m)", self.distance, distance),
                                 ("peak_luminance (cd/m2)", self.peak_luminance, peak_luminance)):
            a = _concrete(val)  # stored in the default float type: 1e-100 m became 0, 1e300 inf
            if a is not None and not (np.isfinite(a).all() and (a > 0).all()):
                raise PlodError(f"Display: {name} {float(_concrete(given))!r} is outside what {a.dtype} holds "
                                f"(stored as {float(a)!r})")
        self.lut_levels, self.lut_luminance = lv, ll
        self.resolution = (rx, ry)
        self.transfer = transfer

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_diagonal(cls, diagonal_in, aspect=(16, 9), resolution=(1920, 1080), distance=0.6, **kw) -> "Display":
        """Screen of ``diagonal_in`` inches with aspect ratio ``aspect`` (w, h) viewed from ``distance`` m."""
        real = isinstance(diagonal_in, (int, float, np.integer, np.floating)) and not isinstance(diagonal_in, bool)
        if not (real and math.isfinite(diagonal_in) and diagonal_in > 0):
            raise PlodError(f"Display.from_diagonal: diagonal (inches) must be a positive number, got {diagonal_in!r}")
        try:
            aw, ah = (float(a) for a in aspect)
        except (TypeError, ValueError):
            aw = ah = math.nan
        if not (math.isfinite(aw) and math.isfinite(ah) and aw > 0 and ah > 0):
            raise PlodError(f"Display.from_diagonal: aspect must be two positive numbers, got {aspect!r}")
        diag_m = float(diagonal_in) * 0.0254
        hyp = math.hypot(aw, ah)
        return cls(diag_m * aw / hyp, diag_m * ah / hyp, resolution, distance, **kw)

    @classmethod
    def from_lut(cls, width, height, resolution, distance, levels, luminance_rgb) -> "Display":
        """Display calibrated with a photometer [LH01 §6.1].

        ``levels`` (K,): drive levels in [0, 1], increasing, from 0 to 1. ``luminance_rgb`` (K, 3): the
        measured luminance (cd/m2) with one channel at that level and the others at 0. The black level
        is the mean of the level-0 row; ``luminance`` adds each channel's interpolated contribution above
        black to the black level.
        """
        lum = np.asarray(luminance_rgb, dtype=float)
        if lum.ndim != 2 or lum.shape[1] != 3:
            raise PlodError(f"Display.from_lut: luminance_rgb must be (K, 3), got {lum.shape}")
        black = float(lum[0].mean())
        peak = black + float((lum[-1] - black).sum())
        return cls(width, height, resolution, distance, peak_luminance=peak, black_level=black,
                   transfer="lut", lut_levels=levels, lut_luminance=lum)

    @classmethod
    def default(cls) -> "Display":
        """24-inch 16:9 1920x1080 sRGB monitor spanning 46 deg horizontally (the study of [LH01 §6.2]),
        peak 200 cd/m2, black 0.5 cd/m2; viewing distance = (W/2) / tan(23 deg) = 0.6258 m.

        One instance per JAX float width (a ``Display`` is immutable): every :class:`optim.View` without a
        display uses it, and building it anew (its checks) cost about as much as the rest of the view."""
        if cls is not Display:
            return cls._make_default()
        x64 = bool(jax.config.read("jax_enable_x64"))
        d = _DEFAULTS.get(x64)
        if d is None:
            d = _DEFAULTS[x64] = cls._make_default()
        return d

    @classmethod
    def _make_default(cls) -> "Display":
        diag_m = 24 * 0.0254
        w = diag_m * 16 / math.hypot(16, 9)
        return cls.from_diagonal(24, (16, 9), (1920, 1080), (w / 2) / math.tan(math.radians(23.0)))

    # ------------------------------------------------------------------ geometry
    @property
    def pixel_pitch(self):
        """(horizontal, vertical) size of one pixel, m."""
        return self.width / self.resolution[0], self.height / self.resolution[1]

    @property
    def field_of_view(self):
        """(horizontal, vertical) angle the whole screen subtends, deg: 2 atan(W / 2d)."""
        return (jnp.degrees(2 * jnp.arctan(self.width / (2 * self.distance))),
                jnp.degrees(2 * jnp.arctan(self.height / (2 * self.distance))))

    def with_distance(self, distance) -> "Display":
        """The same display viewed from another distance (m)."""
        _check_finite_nonneg("Display.with_distance: distance (m)", distance, positive=True)
        return eqx.tree_at(lambda d: d.distance, self, _float(distance))

    @jittable
    def to_3d(self, xy):
        """Pixel coordinates (..., 2) -> eye-centred 3-D points (..., 3) in m (z = distance)."""
        xy = _float(xy)
        if xy.ndim == 0 or xy.shape[-1] != 2:
            raise PlodError(f"Display: pixel coordinates must have shape (..., 2), got {xy.shape}")
        px, py = self.pixel_pitch
        x = (xy[..., 0] - self.resolution[0] / 2) * px
        y = (xy[..., 1] - self.resolution[1] / 2) * py
        return jnp.stack([x, y, jnp.broadcast_to(self.distance, x.shape).astype(x.dtype)], axis=-1)

    @jittable
    def visual_angle(self, p, q):
        """Visual angle (deg) between screen points ``p`` and ``q`` (pixel coords, (..., 2)), broadcast."""
        a, b = self.to_3d(p), self.to_3d(q)
        check_broadcast("Display.visual_angle", p=a.shape[:-1] + (2,), q=b.shape[:-1] + (2,))
        return jnp.degrees(_angle_between(a, b))

    @jittable
    def eccentricity(self, xy, gaze=None):
        """Eccentricity (deg) of screen points ``xy`` (..., 2) from the ``gaze`` pixel (default: centre)."""
        if gaze is None:
            gaze = jnp.asarray([self.resolution[0] / 2, self.resolution[1] / 2])
        return self.visual_angle(xy, gaze)

    @jittable
    def degrees_per_pixel(self, xy=None):
        """Angle (deg) one pixel subtends horizontally.

        ``xy=None``: a pixel centred on the screen centre, exactly ``2 atan(pitch / 2d)``. With ``xy``
        (..., 2): the pixel centred at ``xy`` (angle between its left and right edges; smaller off-centre).
        """
        if xy is None:
            px, _ = self.pixel_pitch
            return jnp.degrees(2 * jnp.arctan(px / (2 * self.distance)))
        xy = _float(xy)
        if xy.ndim == 0 or xy.shape[-1] != 2:
            raise PlodError(f"Display.degrees_per_pixel: xy must have shape (..., 2), got {xy.shape}")
        half = jnp.asarray([0.5, 0.0], dtype=xy.dtype)
        return self.visual_angle(xy - half, xy + half)

    @jittable
    def max_frequency(self, xy=None):
        """Highest frequency the display can show, xi = 1 / (2 degrees_per_pixel) cycles/deg [Red01 Eq 5]."""
        return 1.0 / (2.0 * self.degrees_per_pixel(xy))

    @property
    def xi(self):
        """``max_frequency()`` at the screen centre, cycles/deg."""
        return self.max_frequency()

    @jittable
    def pixels_per_degree(self, xy=None):
        """1 / degrees_per_pixel, px/deg."""
        return 1.0 / self.degrees_per_pixel(xy)

    # ------------------------------------------------------------------ photometry
    @jittable
    def linearize(self, rgb):
        """Encoded RGB in [0, 1] (..., 3) -> per-channel fraction of the channel's full contribution.

        For ``"srgb"`` the sRGB EOTF, for ``"gamma"`` ``v ** gamma``, for ``"lut"`` the measured table's
        contribution above black divided by that at level 1.
        """
        rgb = self._check_rgb(rgb)
        if self.transfer == "srgb":
            return srgb_to_linear(rgb)
        if self.transfer == "gamma":
            return _gamma_to_linear(rgb, self.gamma)
        contrib = self._lut_contrib(rgb)
        full = self.lut_luminance[-1] - self.black_level
        ok = full > 0
        return jnp.where(ok, contrib / jnp.where(ok, full, 1.0), 0.0)

    def _lut_contrib(self, rgb):
        cols = [jnp.interp(rgb[..., c], self.lut_levels, self.lut_luminance[:, c]) - self.black_level
                for c in range(3)]
        return jnp.maximum(jnp.stack(cols, axis=-1), 0.0)

    def _check_rgb(self, rgb):
        _check_finite_nonneg("Display: RGB value", rgb, upper=1.0)
        rgb = _float(rgb)
        if rgb.ndim == 0 or rgb.shape[-1] != 3:
            raise PlodError(f"Display: RGB values must have shape (..., 3), got {rgb.shape}")
        return rgb

    @jittable
    def luminance(self, rgb):
        """Luminance (cd/m2) of encoded RGB values in [0, 1], shape (..., 3) -> (...).

        ``"srgb"`` / ``"gamma"``: ``black + (peak - black) * relative_luminance(linearize(rgb))``.
        ``"lut"``: ``black + sum_c (LUT_c(rgb_c) - black)`` with LUT_c linearly interpolated
        [LH01 §6.1]. Concrete values outside [0, 1] or NaN raise PlodError; under jit they are clipped.
        """
        rgb = self._check_rgb(rgb)
        if self.transfer == "lut":
            return self.black_level + jnp.sum(self._lut_contrib(rgb), axis=-1)
        return self.black_level + (self.peak_luminance - self.black_level) * relative_luminance(self.linearize(rgb))

    @jittable
    def gray_luminance(self, level):
        """Luminance (cd/m2) of the gray ``(level, level, level)``, ``level`` in [0, 1], shape (...) -> (...)."""
        level = _float(level)
        return self.luminance(jnp.stack([level] * 3, axis=-1))

    @jittable
    def gray_level(self, luminance):
        """Inverse of ``gray_luminance``: the gray level in [0, 1] giving ``luminance`` (cd/m2).

        Luminances outside [black_level, peak] are clipped to that range.
        """
        _check_finite_nonneg("Display.gray_level: luminance (cd/m2)", luminance)
        lum = _float(luminance)
        if self.transfer == "lut":
            # the gray curve is piecewise linear on the table's own levels: invert it exactly
            curve = self.black_level + jnp.sum(jnp.maximum(self.lut_luminance - self.black_level, 0.0), axis=-1)
            return jnp.interp(lum, curve, self.lut_levels)
        u = jnp.clip((lum - self.black_level) / (self.peak_luminance - self.black_level), 0.0, 1.0)
        if self.transfer == "srgb":
            return linear_to_srgb(u)
        return _linear_to_gamma(u, self.gamma)

    @jittable
    def contrast(self, rgb1, rgb2):
        """Michelson contrast between the luminances of two RGB colours (..., 3) -> (...)."""
        return michelson(self.luminance(rgb1), self.luminance(rgb2))

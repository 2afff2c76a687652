"""Manos & Sakrison's foveal CSF [MS74] as printed in [Red01 Eq 1], with an exact inversion.

Units: f cycles/deg, c Michelson contrast (0..1), theta deg.
"""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._base import CSFModel, param
from ._numerics import clenshaw, log_guard, pow_pos

__all__ = ["ManosSakrison"]


_MS_A = 0.0192
_MS_XP = 0.899564265442084  # argmax of (a + x) exp(-x^1.1): solves 1/(a+x) = 1.1 x^0.1
_MS_LOGAMAX = math.log(2.6 * (_MS_A + _MS_XP)) - _MS_XP**1.1  # ln A_max, A_max = 0.98088
_MS_GMAX = math.log(_MS_A + _MS_XP) - _MS_XP**1.1
_MS_SMAX = 60.0  # start polynomial fitted for s = ln(P c) in [0, 60]


def _ms_bisect_root(s):
    """Falling-limb root x(s) of ln(a + x) - x^1.1 - G_max + s = 0 by 200-step float64 bisection (numpy)."""
    lo = np.full_like(s, _MS_XP)
    hi = np.full_like(s, 200.0)
    for _ in range(200):
        m = 0.5 * (lo + hi)
        ok = np.log(_MS_A + m) - m**1.1 - _MS_GMAX + s >= 0
        lo = np.where(ok, m, lo)
        hi = np.where(ok, hi, m)
    return lo


def _ms_start_coeffs(deg: int = 16):
    """Chebyshev coefficients of the falling-limb root x(s) in r = sqrt(s), s = ln(P c) in [0, 60].

    Interpolated at 4 deg Chebyshev nodes; x(s) is analytic in r (sqrt branch at the peak), so degree 16
    reaches the conditioning floor of the root itself (|error| < 7e-8 in x, about 1e-8 near the peak
    where g is flat). Only a starting point: one Newton step (float32) or one Halley step (float64)
    follows, whose error is then at the precision of g."""
    k = np.arange(4 * deg)
    t = np.cos(np.pi * (k + 0.5) / (4 * deg))
    r = (t + 1.0) * (0.5 * math.sqrt(_MS_SMAX))
    cheb = np.polynomial.chebyshev.chebfit(t, _ms_bisect_root(r * r), deg)
    return tuple(float(x) for x in cheb)


_MS_CHEB = _ms_start_coeffs()
_MS_DG_FLOOR = -1e-18  # d g/dx on the falling limb is < 0; kept away from 0 at the peak


@jax.custom_jvp
def _ms_root(s):
    """Falling-limb root x >= x_p of ``ln(a + x) - x^1.1 - G_max + s = 0`` for ``s >= 0`` (elementwise).

    Start: Chebyshev fit in sqrt(s) (clipped to the fitted range s <= 60), then one Newton step in
    float32 or one Halley step in float64 (the start is within 1e-7, so either lands at the precision
    of g). Derivative by the implicit-function theorem: dx/ds = -1 / g'(x) (custom_jvp; the forward
    pass evaluates nothing for it)."""
    r = jnp.sqrt(jnp.minimum(s, _MS_SMAX))
    x = clenshaw(r * (2.0 / math.sqrt(_MS_SMAX)) - 1.0, _MS_CHEB)
    x = jnp.maximum(x, _MS_XP * (1 + 1e-6))
    ax = _MS_A + x
    p01 = jnp.exp(0.1 * jnp.log(x))  # x^0.1
    gx = jnp.log(ax) - x * p01 - _MS_GMAX + s
    dg = jnp.minimum(1.0 / ax - 1.1 * p01, _MS_DG_FLOOR)
    if s.dtype == jnp.float64:  # Halley: cubic convergence from the ~1e-8 start
        d2g = -1.0 / (ax * ax) - 0.11 * p01 / x
        step = gx / (dg - 0.5 * gx * d2g / dg)
    else:
        step = gx / dg
    return jnp.maximum(x - step, _MS_XP)


@_ms_root.defjvp
def _ms_root_jvp(primals, tangents):
    (s,), (ds,) = primals, tangents
    x = _ms_root(s)
    dg = jnp.minimum(1.0 / (_MS_A + x) - 1.1 * jnp.exp(0.1 * jnp.log(x)), _MS_DG_FLOOR)
    return x, -ds / dg


def _ms_log_shape(x):
    """ln[(a + x) exp(-x^1.1)] - ln[(a + x_p) exp(-x_p^1.1)] <= 0 for x = b f >= 0."""
    x = jnp.minimum(x, 1e30)
    return jnp.log(_MS_A + x) - pow_pos(x, 1.1) - _MS_GMAX


class ManosSakrison(CSFModel):
    """Manos & Sakrison's foveal CSF [MS74], [Red01 Eq 1] with the published constant.

    Normalized shape ``A(f) = 2.6 (0.0192 + b f) exp(-(b f)^1.1)`` with ``b = 0.114`` (``printed_constant=True``
    uses the misprint 0.144 of [Red01]); A peaks at 0.9809 at 7.89 cycles/deg. Absolute sensitivity
    ``S(f) = peak_sensitivity * A(f) / A_max``. Default ``peak_sensitivity = 250``: with it contrast 1
    is visible up to 61 cycles/deg, matching the 60 cycles/deg acuity limit G(0) of [Red01 Eq 4].
    No eccentricity or velocity dependence (``e`` and ``v`` are accepted and ignored; wrap it in
    :class:`Eccentric` for an eccentricity term).

    Domain: f in [0, 1e30] cycles/deg (values and gradients finite, f = 0 included); c in [0, 1].
    ``threshold_frequency`` is exact for ``peak_sensitivity * c`` up to e^60.
    """

    peak_sensitivity: jax.Array
    printed_constant: bool = eqx.field(static=True, default=False)

    inputs: ClassVar[tuple[str, ...]] = ("f",)
    param_bounds: ClassVar[dict] = {"peak_sensitivity": (1e-6, None)}

    def __init__(self, peak_sensitivity=250.0, printed_constant: bool = False):
        self.peak_sensitivity = param(peak_sensitivity, "ManosSakrison.peak_sensitivity")
        self.printed_constant = bool(printed_constant)

    @property
    def _b(self) -> float:
        return 0.144 if self.printed_constant else 0.114

    @staticmethod
    def shape(f, printed_constant: bool = False):
        """The normalized shape A(f) of [Red01 Eq 1] (peak 0.9809 at 7.89 cycles/deg); f cycles/deg."""
        b = 0.144 if printed_constant else 0.114
        x = jnp.minimum(jnp.asarray(f, jnp.result_type(f, float)) * b, 1e30)
        return 2.6 * (_MS_A + x) * jnp.exp(-pow_pos(x, 1.1))

    def _log_sensitivity(self, f, e, v):
        """ln S(f) = ln peak_sensitivity + ln A(f)/A_max (e, v ignored)."""
        return jnp.log(self.peak_sensitivity) + _ms_log_shape(self._b * f)

    def _peak_frequency(self, e, v):
        shape = jnp.broadcast_shapes(jnp.shape(e), jnp.shape(v))
        dtype = jnp.result_type(e, v, self.peak_sensitivity, float)
        return jnp.full(shape, _MS_XP / self._b, dtype)

    def _threshold_frequency(self, c, e, v):
        s = log_guard(c) + jnp.log(self.peak_sensitivity)  # ln(c S_peak): visible iff >= 0
        s = jnp.broadcast_to(s, jnp.broadcast_shapes(s.shape, e.shape, v.shape))
        visible = s >= 0
        x = _ms_root(jnp.where(visible, s, 0.0))  # double where: no gradient leaks from invisible c
        return jnp.where(visible, x / self._b, 0.0)

    def _imperceptible_distance(self, c, theta, e, v):
        """Closed in terms of the threshold frequency (no e, v dependence): k = 2 theta f*(c)."""
        return 2.0 * theta * self._threshold_frequency(c, e, v)

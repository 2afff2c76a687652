"""Reddy's visual-acuity model H(v, e) = G(v) M(e), capped at the display's highest frequency xi.

Reference: M. Reddy, "Perceptually Optimized 3D Graphics", IEEE CG&A 21(5), 2001 (seed 000) Eq 4-5,
built on Kelly 1979 (velocity) and Rovamo & Virsu 1979 (eccentricity).

    G(v) = 60                          v <= 0.825 deg/s
           57.69 - 27.78 log10(v)      0.825 < v <= 118.3 deg/s
           0.1                         v > 118.3 deg/s
    M(e) = 1                           e <= 5.79 deg
           7.49 / (0.3 e + 1)^2        e > 5.79 deg
    H'(v, e) = min(xi, G(v) M(e))      cycles/deg

The pieces join continuously, so they are written as ``G = clip(57.69 - 27.78 log10 v, 0.1, 60)`` and
``M = min(1, 7.49 / (0.3 e + 1)^2)`` (equal to the printed piecewise form up to the rounding of the
printed knots). An acuity model ignores contrast (worst case): any nonzero contrast is treated as
contrast 1, so a change is perceptible iff ``c > 0`` and its frequency ``f <= H'(v, e)``.
"""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jax import lax

from ._base import LOG_CT_MAX, CSFModel, check_inputs
from ._csf import _param
from ._inverse import implicit_root, largest_crossing

__all__ = ["ReddyAcuity", "SmoothReddyAcuity"]

_BIG = 1e30  # stands in for xi = None (no display cap): finite so gradients stay finite
_P = 200.0  # p-norm soft minimum: relative error <= 1 - 2^(-1/200) = 0.35 % at a knot


def _softmin_log(la, lb):
    """log of a smooth min(a, b) given log a, log b: -(1/p) log(a^-p + b^-p) (error <= 0.35 %)."""
    return -jnp.logaddexp(-_P * la, -_P * lb) / _P


class ReddyAcuity(CSFModel):
    """Reddy's acuity model as a (step) CSF: visible iff ``c > 0`` and ``f <= H'(v, e)`` (cycles/deg).

    Fields (fittable arrays): ``g_max = 60``, ``g_intercept = 57.69``, ``g_slope = 27.78``,
    ``g_min = 0.1`` (cycles/deg), ``m_scale = 7.49``, ``m_rate = 0.3`` (1/deg) and ``xi``: the display's
    highest frequency ``1 / (2 pixel angle in deg)`` in cycles/deg (``None`` = no display cap).
    ``smooth=True`` (or :class:`SmoothReddyAcuity`) replaces every min/max by a p-norm soft minimum
    (p = 200) and a softplus floor, within 1 % of the exact model everywhere, for gradient fitting.

    :meth:`acuity` is H'; :meth:`sensitivity` is the step ``exp(+-LOG_CT_MAX)`` (about 1e26 below H',
    1e-26 above), so :meth:`threshold_contrast` is ~0 for visible and ~1e26 for invisible frequencies;
    :meth:`peak_frequency` is 0 (sensitivity is flat on [0, H']), :meth:`threshold_frequency` is H' for
    c > 0. :meth:`imperceptible_distance` solves ``k = 2 theta H'(v/k, e/k)`` exactly: log H' is concave
    in log k above the G floor (v/k <= 118.3) and below it, so Newton from the right on each piece (from
    the upper bound ``2 theta min(xi, 60)``) converges monotonically to the largest root.

    Domain: f >= 0, e in [0, 1e4] deg, v in [0, 1e6] deg/s, c in [0, 1].
    """

    g_max: jax.Array
    g_intercept: jax.Array
    g_slope: jax.Array
    g_min: jax.Array
    m_scale: jax.Array
    m_rate: jax.Array
    xi: jax.Array
    smooth: bool = eqx.field(static=True, default=False)

    inputs: ClassVar[tuple[str, ...]] = ("f", "e", "v")
    param_bounds: ClassVar[dict] = {
        "g_max": (1e-3, None),
        "g_intercept": (1e-3, None),
        "g_slope": (1e-6, None),
        "g_min": (1e-6, None),
        "m_scale": (1e-6, None),
        "m_rate": (1e-6, None),
        "xi": (1e-6, None),
    }

    def __init__(
        self,
        xi=None,
        *,
        smooth: bool = False,
        g_max=60.0,
        g_intercept=57.69,
        g_slope=27.78,
        g_min=0.1,
        m_scale=7.49,
        m_rate=0.3,
    ):
        self.xi = _param(_BIG if xi is None else xi, "ReddyAcuity.xi")
        self.g_max = _param(g_max, "ReddyAcuity.g_max")
        self.g_intercept = _param(g_intercept, "ReddyAcuity.g_intercept")
        self.g_slope = _param(g_slope, "ReddyAcuity.g_slope")
        self.g_min = _param(g_min, "ReddyAcuity.g_min")
        self.m_scale = _param(m_scale, "ReddyAcuity.m_scale")
        self.m_rate = _param(m_rate, "ReddyAcuity.m_rate")
        self.smooth = bool(smooth)

    # ------------------------------------------------------------------ the acuity surface
    def _log_g(self, v):
        tiny = jnp.finfo(jnp.result_type(v, self.g_max)).tiny
        lin = self.g_intercept - self.g_slope * jnp.log10(jnp.maximum(v, tiny))
        if not self.smooth:
            return jnp.log(jnp.clip(lin, self.g_min, self.g_max))
        tau = 0.01 * self.g_min  # softplus floor: absolute error <= tau ln 2 = 0.7 % of g_min
        floored = self.g_min + tau * jax.nn.softplus((lin - self.g_min) / tau)
        return _softmin_log(jnp.log(floored), jnp.log(self.g_max))

    def _log_m(self, e):
        lm = jnp.log(self.m_scale) - 2.0 * jnp.log1p(self.m_rate * jnp.minimum(e, 1e30))
        if not self.smooth:
            return jnp.minimum(lm, 0.0)
        return _softmin_log(lm, jnp.zeros_like(lm))

    def log_acuity(self, v, e):
        """ln H'(v, e) (H' in cycles/deg)."""
        lh = self._log_g(jnp.asarray(v)) + self._log_m(jnp.asarray(e))
        lxi = jnp.log(self.xi)
        return _softmin_log(lh, lxi) if self.smooth else jnp.minimum(lh, lxi)

    def acuity(self, v=0.0, e=0.0):
        """H'(v, e) = min(xi, G(v) M(e)) in cycles/deg for velocity v (deg/s), eccentricity e (deg)."""
        v, e = check_inputs("acuity", v=v, e=e)
        return jnp.exp(self.log_acuity(v, e))

    # ------------------------------------------------------------------ CSF interface
    def log_sensitivity(self, f, e=0.0, v=0.0):
        visible = jnp.asarray(f) <= jnp.exp(self.log_acuity(v, e))
        return jnp.where(visible, LOG_CT_MAX, -LOG_CT_MAX)

    def sensitivity(self, f, e=0.0, v=0.0):
        """Step: exp(LOG_CT_MAX) (~1e26) where f <= H'(v, e), exp(-LOG_CT_MAX) above."""
        f, e, v = check_inputs("sensitivity", f=f, e=e, v=v)
        return jnp.exp(self.log_sensitivity(f, e, v))

    def _peak_frequency(self, e, v):
        shape = jnp.broadcast_shapes(jnp.shape(e), jnp.shape(v))
        return jnp.zeros(shape, jnp.result_type(e, v, self.xi, float))

    def is_perceptible(self, c, f, e=0.0, v=0.0):
        """``c > 0`` and ``f <= H'(v, e)`` (any nonzero contrast is treated as contrast 1)."""
        c, f, e, v = check_inputs("is_perceptible", c=c, f=f, e=e, v=v)
        return (c > 0) & (jnp.log(jnp.maximum(f, 1e-30)) <= self.log_acuity(v, e))

    def _threshold_frequency(self, c, e, v):
        return jnp.where(c > 0, jnp.exp(self.log_acuity(v, e)), 0.0)

    def _rho(self, w, theta, e, v):
        """log(2 theta H'(v/k, e/k)) - log k at k = exp(w): perceptible iff >= 0."""
        k = jnp.exp(w)
        return jnp.log(2.0 * theta) + self.log_acuity(v / k, e / k) - w

    def imperceptible_distance(self, c, theta, e=0.0, v=0.0):
        """Largest k with ``k / (2 theta) <= H'(v / k, e / k)`` (0 where c = 0 or theta = 0); theta deg.
        See :meth:`CSFModel.imperceptible_distance` and the class docstring for the method."""
        c, theta, e, v = check_inputs("imperceptible_distance", c=c, theta=theta, e=e, v=v)
        shape = jnp.broadcast_shapes(c.shape, theta.shape, e.shape, v.shape)
        dtype = jnp.result_type(c, theta, e, v, self.xi, float)
        ok_in = (c > 0) & (theta > 0)
        th = jnp.where(theta > 0, theta, 1.0)
        e_b, v_b, th_b = (jnp.broadcast_to(x, shape).astype(dtype) for x in (e, v, th))
        e_, v_, th_ = (lax.stop_gradient(x) for x in (e_b, v_b, th_b))
        rho = lambda w: self._rho(w, th_b, e_b, v_b)  # noqa: E731
        ms = lax.stop_gradient(self)
        rho_sg = lambda w: ms._rho(w, th_, e_, v_)  # noqa: E731
        w_top = jnp.log(2.0 * th_) + jnp.minimum(jnp.log(self.xi), jnp.log(self.g_max))
        w_top = lax.stop_gradient(w_top + 1e-3)
        if self.smooth:
            w, found, _ = largest_crossing(rho_sg, w_top - 40.0, w_top, n_grid=81)
        else:
            # the G floor starts at v/k = v_f (G = g_min): k_f = v / v_f
            log_vf = lax.stop_gradient((self.g_intercept - self.g_min) / self.g_slope * math.log(10.0))
            w_f = jnp.where(v_ > 0, jnp.log(jnp.maximum(v_, 1e-30)) - log_vf, -jnp.inf)

            def newton(w, lo):
                for _ in range(10):
                    r, dr = jax.jvp(rho_sg, (w,), (jnp.ones_like(w),))
                    step = r / jnp.minimum(dr, -1e-6)
                    w = jnp.maximum(w - step, lo)
                return w

            w1 = newton(w_top, w_f)
            found1 = (rho_sg(w1) >= -1e-5) & (w1 > w_f)
            lo2 = jnp.where(jnp.isfinite(w_f), w_top - 60.0, w_top)
            w2 = newton(jnp.minimum(w_top, jnp.where(jnp.isfinite(w_f), w_f, w_top)), lo2)
            found2 = (rho_sg(w2) >= -1e-5) & (w2 > lo2)
            w = jnp.where(found1, w1, w2)
            found = found1 | found2
        ok = found & ok_in
        w = implicit_root(rho, jnp.where(ok, w, 0.0), mask=ok)
        return jnp.where(ok, jnp.exp(w), 0.0).astype(dtype)


class SmoothReddyAcuity(ReddyAcuity):
    """:class:`ReddyAcuity` with ``smooth=True``: differentiable everywhere, within 1 % of H'."""

    def __init__(self, xi=None, **kw):
        kw.setdefault("smooth", True)
        super().__init__(xi, **kw)

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

import functools
import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jax import lax

from ._base import LOG_CT_MAX, CSFModel, check_inputs
from ._csf import _param
from ._inverse import implicit_root, lambertw_m1, largest_crossing

__all__ = ["ReddyAcuity", "SmoothReddyAcuity"]

_BIG = 1e30  # stands in for xi = None (no display cap): finite so gradients stay finite
_P = 200.0  # p-norm soft minimum: relative error <= 1 - 2^(-1/200) = 0.35 % at a knot


_NEWTON_STEPS = 6  # G middle x M outer piece (monotone Newton from an upper bound)


def _dtype(*xs):
    """Floating dtype of the inputs (the fields are cast to it)."""
    return jnp.result_type(*(jnp.asarray(x).dtype for x in xs), float)


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
    def _consts(self, dtype):
        """The fields cast to ``dtype`` (a model built under x64 works on float32 inputs)."""
        return tuple(jnp.asarray(x, dtype) for x in (self.g_max, self.g_intercept, self.g_slope, self.g_min,
                                                     self.m_scale, self.m_rate, self.xi))

    def _log_g(self, v, dtype):
        gmax, ga, gsl, gmin = self._consts(dtype)[:4]
        tiny = jnp.finfo(dtype).tiny
        lin = ga - gsl * jnp.log10(jnp.maximum(v, tiny))
        if not self.smooth:
            return jnp.log(jnp.clip(lin, gmin, gmax))
        tau = 0.01 * gmin  # softplus floor: absolute error <= tau ln 2 = 0.7 % of g_min
        floored = gmin + tau * jax.nn.softplus((lin - gmin) / tau)
        return _softmin_log(jnp.log(floored), jnp.log(gmax))

    def _log_m(self, e, dtype):
        ms, mr = self._consts(dtype)[4:6]
        lm = jnp.log(ms) - 2.0 * jnp.log1p(mr * jnp.minimum(e, 1e30))
        if not self.smooth:
            return jnp.minimum(lm, 0.0)
        return _softmin_log(lm, jnp.zeros_like(lm))

    def _log_gm(self, v, e, dtype):
        return self._log_g(v, dtype) + self._log_m(e, dtype)

    def log_acuity(self, v, e):
        """ln H'(v, e) (H' in cycles/deg); v deg/s, e deg."""
        v, e = jnp.asarray(v), jnp.asarray(e)
        dtype = _dtype(v, e)
        v, e = v.astype(dtype), e.astype(dtype)
        lh = self._log_gm(v, e, dtype)
        lxi = jnp.log(self._consts(dtype)[6])
        return _softmin_log(lh, lxi) if self.smooth else jnp.minimum(lh, lxi)

    def acuity(self, v=0.0, e=0.0):
        """H'(v, e) = min(xi, G(v) M(e)) in cycles/deg for velocity v (deg/s), eccentricity e (deg)."""
        v, e = check_inputs("acuity", v=v, e=e)
        return jnp.exp(self.log_acuity(v, e))

    # ------------------------------------------------------------------ CSF interface
    def log_sensitivity(self, f, e=0.0, v=0.0):
        f = jnp.asarray(f)
        visible = f <= jnp.exp(self.log_acuity(v, e))
        out = jnp.where(visible, LOG_CT_MAX, -LOG_CT_MAX).astype(_dtype(f, e, v))
        return jnp.broadcast_to(out, jnp.broadcast_shapes(f.shape, jnp.shape(e), jnp.shape(v)))

    def sensitivity(self, f, e=0.0, v=0.0):
        """Step: exp(LOG_CT_MAX) (~1e26) where f <= H'(v, e), exp(-LOG_CT_MAX) above."""
        f, e, v = check_inputs("sensitivity", f=f, e=e, v=v)
        return jnp.exp(self.log_sensitivity(f, e, v))

    def _peak_frequency(self, e, v):
        shape = jnp.broadcast_shapes(jnp.shape(e), jnp.shape(v))
        return jnp.zeros(shape, _dtype(e, v))

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

        See :meth:`CSFModel.imperceptible_distance` for the definition. Exact model: direct solve,
        one closed-form (or monotone-Newton) candidate per piece of H' (see ``_exact_distance``).
        Smooth model: the generic largest-crossing scan (81 points over 40 e-folds below
        ``2 theta min(xi, g_max)``, the upper bound of every answer) refined by safeguarded Newton.
        Gradients: implicit-function theorem on ``ln(2 theta H') = ln k``.
        """
        c, theta, e, v = check_inputs("imperceptible_distance", c=c, theta=theta, e=e, v=v)
        shape = jnp.broadcast_shapes(c.shape, theta.shape, e.shape, v.shape)
        dtype = _dtype(c, theta, e, v)
        ok_in = (c > 0) & (theta > 0)
        th = jnp.where(theta > 0, theta, 1.0)
        e_b, v_b, th_b = (jnp.broadcast_to(x, shape).astype(dtype) for x in (e, v, th))
        rho = lambda w: self._rho(w, th_b, e_b, v_b)  # noqa: E731
        if self.smooth:
            e_, v_, th_ = (lax.stop_gradient(x) for x in (e_b, v_b, th_b))
            ms = lax.stop_gradient(self)
            rho_sg = lambda w: ms._rho(w, th_, e_, v_)  # noqa: E731
            lxi, lgmax = jnp.log(self._consts(dtype)[6]), jnp.log(self._consts(dtype)[0])
            w_top = lax.stop_gradient(jnp.log(2.0 * th_) + jnp.minimum(lxi, lgmax) + 1e-3)
            w, found, _ = largest_crossing(rho_sg, w_top - 40.0, w_top, n_grid=81)
        else:
            w, found = self._exact_distance(th_b, e_b, v_b, dtype)
        ok = found & ok_in
        w = implicit_root(rho, jnp.where(ok, w, 0.0), mask=ok)
        return jnp.where(ok, jnp.exp(w), 0.0).astype(dtype)

    def _exact_distance(self, theta, e, v, dtype):
        """ln of the largest k with ``k <= 2 theta H'(v/k, e/k)`` (exact model), under stop_gradient.

        One candidate per piece of ``H' = min(xi, G M)`` (G in {g_max, middle, g_min} x M in {1, outer},
        plus the cap xi): each piece's equation ``k = 2 theta H_piece(v/k, e/k)`` has its largest root in
        closed form (constant G and M = 1: linear; constant G x M outer: a quadratic in k; G middle x
        M = 1: Lambert W_{-1}) or, for G middle x M outer, by Newton from the right on a function of
        ln k that is concave (monotone convergence from an upper bound of the root). A candidate is kept
        where it lies in its piece's region (the knots in ln k are computed once) with the piece
        perceptible there and below the xi cap; every kept candidate is then a perceptible k, and the
        piece holding the true answer yields it, so the answer is the largest kept candidate.
        Returns ``(ln k, found)``.
        """
        sg = lax.stop_gradient
        gmax, ga, gsl, gmin, ms, mr, xi = (sg(x) for x in self._consts(dtype))
        theta, e, v = sg(theta), sg(e), sg(v)
        eps = jnp.finfo(dtype).eps
        tol = 256.0 * eps  # slack of the region tests, in ln k
        big = jnp.asarray(jnp.finfo(dtype).max / 4, dtype)
        T = 2.0 * theta
        lT = jnp.log(T)
        s = gsl / math.log(10.0)  # G middle = A_v + s ln k
        vpos = v > 0
        A_v = ga - gsl * jnp.log10(jnp.where(vpos, v, 1.0))
        w_ghi = jnp.where(vpos, (gmax - A_v) / s, -big)  # G = g_max where ln k >= w_ghi
        w_glo = jnp.where(vpos, (gmin - A_v) / s, -big)  # G = g_min where ln k <= w_glo
        q = mr * e  # M outer = ms k^2 / (q + k)^2
        sq = jnp.sqrt(ms) - 1.0
        epos = (q > 0) & (sq > 0)
        lq = jnp.log(jnp.where(epos, q, 1.0))
        # M outer (<= 1) where ln k <= w_m
        w_m = jnp.where(epos, lq - jnp.log(jnp.where(sq > 0, sq, 1.0)), jnp.where(sq > 0, -big, big))
        w_xi = lT + jnp.log(xi)
        cands = []

        def add(w, ok):
            cands.append(jnp.where(ok & (w <= w_xi + tol), w, -jnp.inf))

        in_gmax = lambda w: w >= w_ghi - tol  # noqa: E731
        in_gmin = lambda w: w <= w_glo + tol  # noqa: E731
        # constant G, M = 1: k = T g
        for g, in_g in ((gmax, in_gmax), (gmin, in_gmin)):
            w = lT + jnp.log(g)
            add(w, in_g(w) & (w >= w_m - tol))
        # constant G, M outer: (q + k)^2 = T g ms k, largest root of k^2 - (B - 2q) k ... (B = T g ms - 2q)
        w_quad = []
        for g, in_g in ((gmax, in_gmax), (gmin, in_gmin)):
            B = T * g * ms - 2.0 * q
            disc = (B - 2.0 * q) * (B + 2.0 * q)
            okq = (disc >= 0) & (B > 0)
            w = jnp.log(jnp.where(okq, 0.5 * (B + jnp.sqrt(jnp.where(okq, disc, 0.0))), 1.0))
            add(w, okq & in_g(w) & (w <= w_m + tol))
            w_quad.append(jnp.where(okq, w, -big))
        # G middle, M = 1: k = T (A_v + s ln k)  ->  k = -T s W_{-1}(-exp(-A_v / s) / (T s))
        lz = -A_v / s - lT - jnp.log(s)  # ln(-z)
        okw = vpos & (lz <= -1.0)
        z = -jnp.exp(jnp.maximum(jnp.where(okw, lz, -1.0), jnp.log(jnp.finfo(dtype).tiny)))
        w5 = jnp.where(okw, lT + jnp.log(s) + jnp.log(-lambertw_m1(z)), -big)
        add(w5, okw & (w5 >= w_glo - tol) & (w5 <= w_ghi + tol) & (w5 >= w_m - tol))
        # G middle, M outer: phi(w) = ln T + ln(A_v + s w) + ln ms + w - 2 ln(q + e^w) = 0, concave in w.
        # In this region phi is below the (G middle, M = 1) and (g_max, M outer) pieces, so their roots
        # bound its largest root from above: Newton from there descends monotonically onto it.
        w = jnp.minimum(jnp.minimum(w_ghi, w_m), jnp.minimum(w5, w_quad[0]))
        ok6 = vpos & epos & (w >= w_glo - tol) & (w > -big)
        w = jnp.where(ok6, w, 0.0)
        lms = jnp.log(ms)

        def phi_dphi(w):
            g_lin = jnp.maximum(A_v + s * w, eps)
            d = w - lq  # ln(k / q)
            phi = lT + jnp.log(g_lin) + lms + w - 2.0 * (lq + jax.nn.softplus(d))
            return phi, s / g_lin + 1.0 - 2.0 * jax.nn.sigmoid(d)

        def newton(_, w):
            phi, dphi = phi_dphi(w)
            return w - jnp.where((phi < 0) & (dphi < 0), phi / jnp.minimum(dphi, -eps), 0.0)

        w = lax.fori_loop(0, _NEWTON_STEPS, newton, w)
        phi, _ = phi_dphi(w)
        in6 = (A_v + s * w > 0) & (w >= w_glo - tol) & (w <= w_ghi + tol) & (w <= w_m + tol)
        add(w, ok6 & in6 & (phi >= -16.0 * tol))
        # the display cap itself: k = T xi where G M is not the binding limit
        kx = jnp.exp(w_xi)
        rho_x = lT + self._log_gm(v / kx, e / kx, dtype) - w_xi
        cands.append(jnp.where(rho_x >= -tol, w_xi, -jnp.inf))
        w_star = functools.reduce(jnp.maximum, cands)
        found = jnp.isfinite(w_star)
        return jnp.where(found, w_star, 0.0), found


class SmoothReddyAcuity(ReddyAcuity):
    """:class:`ReddyAcuity` with ``smooth=True``: differentiable everywhere, within 1 % of H'."""

    def __init__(self, xi=None, **kw):
        kw.setdefault("smooth", True)
        super().__init__(xi, **kw)

"""Reddy's visual-acuity model H(v, e) = G(v) M(e), capped at the display's highest frequency xi.

Reference: [Red01 Eq 4-5], built on [Kel79] (velocity) and [RV79] (eccentricity).

    G(v) = 60                          v <= 0.825 deg/s
           57.69 - 27.78 log10(v)      0.825 < v <= 118.3 deg/s
           0.1                         v > 118.3 deg/s
    M(e) = 1                           e <= 5.79 deg
           7.49 / (0.3 e + 1)^2        e > 5.79 deg
    H'(v, e) = min(xi, G(v) M(e))      cycles/deg   (the method: acuity(e, v), (e, v) order)

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
import numpy as np
from jax import lax

from ._base import LOG_CT_MAX, CSFModel, check_inputs, param
from ._numerics import clenshaw, is_tracer
from ._inverse import implicit_root, implicit_solution, largest_crossing

__all__ = ["ReddyAcuity"]

_BIG = 1e30  # stands in for xi = None (no display cap): finite so gradients stay finite
_P = 200.0  # p-norm soft minimum: relative error <= 1 - 2^(-1/200) = 0.35 % at a knot


def _dtype(*xs):
    """Floating dtype of the inputs (the fields are cast to it; as :meth:`CSFModel._like`, a weakly typed
    input such as a Python scalar does not promote)."""
    return jnp.result_type(*(jnp.asarray(x) for x in xs), float)


def _softmin_log(la, lb):
    """log of a smooth min(a, b) given log a, log b: -(1/p) log(a^-p + b^-p) (error <= 0.35 %)."""
    return -jnp.logaddexp(-_P * la, -_P * lb) / _P


class ReddyAcuity(CSFModel):
    """Reddy's acuity model as a (step) CSF: visible iff ``c > 0`` and ``f <= H'(v, e)`` (cycles/deg).

    Fields (fittable arrays): ``g_max = 60``, ``g_intercept = 57.69``, ``g_slope = 27.78``,
    ``g_min = 0.1`` (cycles/deg), ``m_scale = 7.49``, ``m_rate = 0.3`` (1/deg) and ``xi``: the display's
    highest frequency ``1 / (2 pixel angle in deg)`` in cycles/deg (``None`` = no display cap).
    ``smooth=True`` replaces every min/max by a p-norm soft minimum
    (p = 200) and a softplus floor, within 1 % of the exact model everywhere, for gradient fitting.

    :meth:`acuity` is H' (arguments ``(e, v)``, the order of every method); :meth:`sensitivity` is the step ``exp(+-LOG_CT_MAX)`` (about 1e26 below H',
    1e-26 above), so :meth:`threshold_contrast` is ~0 for visible and ~1e26 for invisible frequencies;
    :meth:`peak_frequency` is 0 (sensitivity is flat on [0, H']), :meth:`threshold_frequency` is H' for
    c > 0. :meth:`imperceptible_distance` solves ``k = 2 theta H'(v/k, e/k)`` exactly: one closed-form
    candidate per piece of H' (the G-middle piece through the Lambert-type root of ``u - ln u = t``), the
    largest valid one is the answer; one fused elementwise pass, no loop for Reddy's constants.

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
        self.xi = param(_BIG if xi is None else xi, "ReddyAcuity.xi")
        self.g_max = param(g_max, "ReddyAcuity.g_max")
        self.g_intercept = param(g_intercept, "ReddyAcuity.g_intercept")
        self.g_slope = param(g_slope, "ReddyAcuity.g_slope")
        self.g_min = param(g_min, "ReddyAcuity.g_min")
        self.m_scale = param(m_scale, "ReddyAcuity.m_scale")
        self.m_rate = param(m_rate, "ReddyAcuity.m_rate")
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

    def _log_gm(self, e, v, dtype):
        return self._log_g(v, dtype) + self._log_m(e, dtype)

    def log_acuity(self, e=0.0, v=0.0):
        """ln H'(v, e) (H' in cycles/deg); e deg, v deg/s (not checked: for gradients and internal use)."""
        e, v = jnp.asarray(e), jnp.asarray(v)
        dtype = _dtype(e, v)
        e, v = e.astype(dtype), v.astype(dtype)
        lh = self._log_gm(e, v, dtype)
        lxi = jnp.log(self._consts(dtype)[6])
        return _softmin_log(lh, lxi) if self.smooth else jnp.minimum(lh, lxi)

    def acuity(self, e=0.0, v=0.0):
        """H'(v, e) = min(xi, G(v) M(e)) in cycles/deg at eccentricity e (deg) and velocity v (deg/s)."""
        e, v = check_inputs("acuity", e=e, v=v)
        return jnp.exp(self._like(e, v).log_acuity(e, v))

    # ------------------------------------------------------------------ CSF interface
    def _log_sensitivity(self, f, e, v):
        """Step: ``LOG_CT_MAX`` where f <= H'(v, e), ``-LOG_CT_MAX`` above."""
        visible = f <= jnp.exp(self.log_acuity(e, v))
        out = jnp.where(visible, LOG_CT_MAX, -LOG_CT_MAX).astype(_dtype(f, e, v))
        return jnp.broadcast_to(out, jnp.broadcast_shapes(f.shape, jnp.shape(e), jnp.shape(v)))

    def _peak_frequency(self, e, v):
        shape = jnp.broadcast_shapes(jnp.shape(e), jnp.shape(v))
        return jnp.zeros(shape, _dtype(e, v))

    def _is_perceptible(self, c, f, e, v):
        """``c > 0`` and ``f <= H'(v, e)`` (any nonzero contrast is treated as contrast 1)."""
        return (c > 0) & (jnp.log(jnp.maximum(f, 1e-30)) <= self.log_acuity(e, v))

    def _threshold_frequency(self, c, e, v):
        return jnp.where(c > 0, jnp.exp(self.log_acuity(e, v)), 0.0)

    def _rho(self, w, theta, e, v):
        """log(2 theta H'(v/k, e/k)) - log k at k = exp(w): perceptible iff >= 0."""
        k = jnp.exp(w)
        return jnp.log(2.0 * theta) + self.log_acuity(e / k, v / k) - w

    def _imperceptible_distance(self, c, theta, e, v):
        """Largest k with ``k / (2 theta) <= H'(v / k, e / k)`` (0 where c = 0 or theta = 0); theta deg.

        ``e`` in deg, ``v`` in deg/s, ``k`` a dimensionless multiple of the viewing distance. See
        :meth:`CSFModel.imperceptible_distance` for the definition; 0 also where no k is perceptible.
        Exact model: direct solve, one closed-form candidate per piece of H' (see ``_exact_distance``),
        elementwise with no loop (traced constants: a ``lax.switch`` on them picks the variant); an
        iterative candidate (``_NEWTON_STEPS`` Newton steps) only for M's outer piece when ``m_scale < 4``.
        Smooth model: the generic largest-crossing scan (81 points over 40 e-folds below
        ``2 theta min(xi, g_max)``, the upper bound of every answer) refined by safeguarded Newton.
        Gradients: implicit-function theorem on ``ln(2 theta H') = ln k`` (exact model:
        :func:`implicit_solution`, so the forward pass is the solve alone).
        """
        shape = jnp.broadcast_shapes(c.shape, theta.shape, e.shape, v.shape)
        dtype = _dtype(c, theta, e, v)
        c_b, th_b, e_b, v_b = (jnp.broadcast_to(x, shape).astype(dtype) for x in (c, theta, e, v))
        if not self.smooth:
            return _exact_k(self._solve_mode(), self, c_b, th_b, e_b, v_b)
        ok_in = (c_b > 0) & (th_b > 0)
        th_b = jnp.where(th_b > 0, th_b, 1.0)
        rho = lambda w: self._rho(w, th_b, e_b, v_b)  # noqa: E731
        e_, v_, th_ = (lax.stop_gradient(x) for x in (e_b, v_b, th_b))
        ms = lax.stop_gradient(self)
        rho_sg = lambda w: ms._rho(w, th_, e_, v_)  # noqa: E731
        lxi, lgmax = jnp.log(self._consts(dtype)[6]), jnp.log(self._consts(dtype)[0])
        w_top = lax.stop_gradient(jnp.log(2.0 * th_) + jnp.minimum(lxi, lgmax) + 1e-3)
        w, found, _ = largest_crossing(rho_sg, w_top - 40.0, w_top, n_grid=81)
        ok = found & ok_in
        w = implicit_root(rho, jnp.where(ok, w, 0.0), mask=ok)
        return jnp.where(ok, jnp.exp(w), 0.0).astype(dtype)

    def _solve_mode(self):
        """``(outer, far)`` for ``_exact_distance`` when the constants are concrete, else None.

        ``outer``: M's outer piece can hold the answer (``m_scale < 4``); ``far``: G's middle piece can
        reach ``u = G / s`` beyond the Chebyshev start of :func:`_u_root` (``g_max / s > 11.4``; Reddy's
        constants: 4.97)."""
        gmax, gsl, ms = self.g_max, self.g_slope, self.m_scale
        if any(is_tracer(x) for x in (gmax, gsl, ms)):
            return None
        far = np.asarray(gmax, float) * math.log(10.0) / np.asarray(gsl, float) > _U_FAR
        return bool(np.any(np.asarray(ms, float) < 4.0)), bool(np.any(far))

    def _exact_distance(self, c, theta, e, v, outer, far):
        """The largest k with ``k <= 2 theta H'(v/k, e/k)`` (exact model; 0 where none, c = 0, theta = 0).

        Inputs: arrays of one shape and floating dtype (theta, e in deg, v in deg/s); no gradient (see
        :func:`_exact_k`). Written for ``y = k / (2 theta)``, the frequency (cycles/deg) of the change at
        distance multiple k: the answer is the largest y with ``y <= H'`` at ``v/k = x / y``,
        ``e/k = (e / 2 theta) / y`` (``x = v / 2 theta``). There ``y = H'`` on one piece of
        ``H' = min(xi, G M)`` [Red01 Eq 4-5], and every piece's equation has its largest root in closed
        form -- G, M constant: ``y = g``; the display cap: ``y = xi``; G's middle piece
        (``G = ga - s ln(v/k)``) with M = 1: ``y = s u`` with ``u - ln u = t`` (the Lambert
        ``-W_{-1}(-e^-t)``, :func:`_u_root`); G constant with M's outer piece ``ms k^2 / (q + k)^2``: a
        quadratic in y. A candidate is kept where it lies in its piece's region (tested in closed form,
        with a slack of 256 ulp in ln k) and below the cap; each kept candidate is a perceptible k and the
        piece holding the answer yields it, so the answer is the largest kept candidate.
        On M's outer piece (k < k_m = q / (sqrt(ms) - 1)) the ratio ``G M / k = G ms k / (q + k)^2`` grows
        with k while ``k < q``; so for ``m_scale >= 4`` (``k_m <= q``; Reddy's 7.49) no answer lies inside
        it (except at the cap) and ``outer=False`` skips its candidates. ``outer=True`` adds them: the two
        quadratics and, for G middle x M outer, Newton from the right on a concave function of ln k from
        an upper bound of its largest root (monotone convergence, ``_NEWTON_STEPS`` steps).
        Without ``outer`` the solve is one elementwise pass with one log (``ln(v / 2 theta)``), a square
        root and, in float64, one exp (see :func:`_u_root`; ``far`` adds its asymptotic start).
        """
        sg = lax.stop_gradient
        dtype = theta.dtype
        gmax, ga, gsl, gmin, ms, mr, xi = (sg(x) for x in self._consts(dtype))
        c, theta, e, v = sg(c), sg(theta), sg(e), sg(v)
        tol = 256.0 * jnp.finfo(dtype).eps  # slack of the region tests, in ln k
        ok_in = (c > 0) & (theta > 0)
        T = 2.0 * jnp.where(theta > 0, theta, 1.0)
        s = gsl / math.log(10.0)  # G middle = ga - s ln(v / k)
        a_hi = (ga - gmax) / s  # ln of the velocity v/k (deg/s) where G leaves g_max (0.825 deg/s)
        a_lo = (ga - gmin) / s  # ... and reaches g_min (118 deg/s)
        sq = jnp.sqrt(ms) - 1.0  # M(e/k) = 1 where q / k <= sq
        xi_hi = xi * (1.0 + tol)
        vpos = v > 0
        x = v / T  # v/k at y = 1 (+inf where it overflows: G = g_min everywhere)
        L = jnp.log(jnp.where(vpos, x, 1.0))  # ln(v/k) at y = 1 (log(0) avoided: slow and -inf)
        r = mr * e / T  # q / k at y = 1 (q = m_rate e)

        def m_one(y):  # M(e/k) = 1 at k = T y
            return r <= sq * y * (1.0 + tol)

        # G = g_max, M = 1 (y = g_max) and G = g_min, M = 1 (y = g_min)
        at_top = ~vpos | (L <= jnp.log(gmax) + a_hi + tol)
        y = jnp.where(at_top & m_one(gmax) & (gmax <= xi_hi), gmax, 0.0)
        at_bot = vpos & (L >= jnp.log(gmin) + a_lo - tol)
        y = jnp.maximum(y, jnp.where(at_bot & m_one(gmin) & (gmin <= xi_hi), gmin, 0.0))
        # G middle, M = 1: y = ga - s ln(v / (T y)), i.e. u - ln u = t with y = s u
        t = ga / s + jnp.log(s) - L
        ok5 = vpos & (t >= 1.0) & (t < jnp.inf)
        y5 = s * _u_root(jnp.where(ok5, t, 1.0), far)
        in5 = (y5 >= gmin - s * tol) & (y5 <= gmax + s * tol) & m_one(y5) & (y5 <= xi_hi)
        y = jnp.maximum(y, jnp.where(ok5 & in5, y5, 0.0))
        # the display cap: y = xi where G M >= xi there
        g_x = jnp.where(vpos, jnp.clip(ga - s * (L - jnp.log(xi)), gmin, gmax), gmax)
        m_x = jnp.minimum(1.0, ms / jnp.square(1.0 + r / xi))
        y = jnp.maximum(y, jnp.where(g_x * m_x >= xi * (1.0 - tol), xi, 0.0))
        if outer:
            y = _outer_candidates(y, jnp.where(vpos, x, 0.0), L, r, vpos, jnp.where(ok5, y5, 0.0),
                                  gmax, ga, gmin, ms, s, a_hi, a_lo, sq, xi_hi, tol)
        k = T * y
        return jnp.where(ok_in & (y > 0) & (k < jnp.inf), k, 0.0)


_NEWTON_STEPS = 10  # G middle x M outer piece (monotone Newton from an upper bound)
_U_P = 4.0  # the Chebyshev start of _u_root covers p = sqrt(2 (t - 1)) in [0, _U_P]


def _u_of_p(p):
    """u >= 1 with ``u - 1 - ln u = p^2 / 2`` (numpy, float64, to convergence): Newton on d = u - 1 from
    above (``d - ln(1 + d)`` is convex and increasing in d > 0, so the iterates decrease onto the root)."""
    p = np.asarray(p, float)
    d = 0.5 * p * p + 2.0 * p + 1.0
    for _ in range(200):
        g = d - np.log1p(d) - 0.5 * p * p
        d = np.maximum(d - g * (1.0 + d) / np.maximum(d, 1e-300), 0.0)
    return 1.0 + d


def _u_cheb(deg: int):
    """Chebyshev coefficients (in ``2 p / _U_P - 1``) of u(p), p in [0, _U_P] (u analytic there: its
    nearest singularities are at p = (1 +- i) sqrt(2 pi)): relative error 4e-9 at degree 10, 1e-13 at 16."""
    j = np.arange(4 * deg)
    xj = np.cos(np.pi * (j + 0.5) / (4 * deg))
    return tuple(float(c) for c in np.polynomial.chebyshev.chebfit(xj, _u_of_p(0.5 * _U_P * (xj + 1.0)), deg))


_U_CHEB32 = _u_cheb(10)
_U_CHEB64 = _u_cheb(16)
_U_FAR = float(_u_of_p(_U_P)) * (1.0 - 1e-3)  # 11.4: u above this needs the asymptotic start


def _u_root(t, far):
    """The root ``u >= 1`` of ``u - ln u = t`` (``t >= 1``), i.e. ``u = -W_{-1}(-exp(-t))``; no gradient.

    Start: a Chebyshev interpolant of u in ``p = sqrt(2 (t - 1))`` on [0, 4] (u <= 11.4; degree 10 in
    float32, 16 in float64, relative error 4e-9 / 1e-13; near the branch point p -> 0, where the
    problem is ill-conditioned, it is as exact as t). Float64 adds one Halley step (cubic convergence,
    one exp) on ``a(u) = u - exp(u - t)`` (the scaled ``u e^-u - e^-t``: no overflow). ``far=True``
    also covers p > 4 with the asymptotic ``t + ln t + ln t / t + ...`` ([Cor96 Eq 4.19])
    and two (float32) / three (float64) Halley steps; otherwise the values there are not the root.
    Elementwise, no loop.
    """
    f64 = jnp.finfo(t.dtype).bits > 32
    p = jnp.sqrt(2.0 * jnp.maximum(t - 1.0, 0.0))
    cheb = _U_CHEB64 if f64 else _U_CHEB32
    u = jnp.maximum(clenshaw(jnp.minimum(p, _U_P) * (2.0 / _U_P) - 1.0, cheb), 1.0)
    steps = 1 if f64 else 0
    if far:
        lt = jnp.log(jnp.maximum(t, 1.0))
        u = jnp.where(p > _U_P, t + lt + lt / t + lt * (lt - 2.0) / (2.0 * t * t), u)
        steps = 3 if f64 else 2
    for _ in range(steps):  # Halley on a(u) = u - e^(u - t): a' = 1 - e^(u-t), a'' = -e^(u-t)
        a = u - jnp.exp(u - t)
        um1 = u - 1.0
        den = 2.0 * um1 * um1 - a * (u - 2.0)
        ok = (p > 1e-3) & (den > 0)
        u = jnp.where(ok, u + 2.0 * a * um1 / jnp.where(ok, den, 1.0), u)
    return u


def _outer_candidates(y, x, L, r, vpos, y5, gmax, ga, gmin, ms, s, a_hi, a_lo, sq, xi_hi, tol):
    """``max(y, candidates on M's outer piece)`` for ``m_scale < 4`` (see ``ReddyAcuity._exact_distance``).

    ``y = k / 2 theta``; ``x = v / 2 theta`` (deg/s), ``L = ln x`` (any finite value where v = 0),
    ``r = m_rate e / 2 theta``, so that ``v/k = x / y`` and ``q/k = r / y``; ``y5`` the root of the
    G-middle x M = 1 piece (0 where it has none). M outer = ``ms y^2 / (r + y)^2``, outer where
    ``r / y > sq``. G constant = g: ``(r + y)^2 = g ms y``, a quadratic. G middle: in z = ln y,
    ``phi(z) = ln(G ms e^z / (r + e^z)^2)`` with ``G = ga - s (L - z)`` is concave; it lies below both
    the (G middle, M = 1) and the (g_max, M outer) pieces, whose roots therefore bound its largest root
    from above: Newton from there descends monotonically onto it (one log and one exp per step).
    """
    dtype = y.dtype
    eps = jnp.finfo(dtype).eps
    tiny = jnp.finfo(dtype).tiny
    v_hi, v_lo = jnp.exp(a_hi), jnp.exp(a_lo)  # v/k (deg/s) at G's knots
    outer_at = lambda yy: r >= sq * yy * (1.0 - tol)  # noqa: E731
    yq = []
    in_top = lambda yy: x <= yy * v_hi * (1.0 + tol)  # noqa: E731  (G = g_max at v/k = x / yy)
    in_bot = lambda yy: x >= yy * v_lo * (1.0 - tol)  # noqa: E731  (G = g_min)
    for g, in_g in ((gmax, in_top), (gmin, in_bot)):
        B = g * ms - 2.0 * r
        disc = (B - 2.0 * r) * (B + 2.0 * r)
        okq = (disc >= 0) & (B > 0)
        yg = jnp.where(okq, 0.5 * (B + jnp.sqrt(jnp.where(okq, disc, 0.0))), 0.0)
        y = jnp.maximum(y, jnp.where(okq & in_g(yg) & outer_at(yg) & (yg <= xi_hi), yg, 0.0))
        yq.append(yg)
    # G middle x M outer, between y_glo and y_ghi (G = g_min below, g_max above) and below y_m
    y_ghi, y_glo = x / v_hi, x / v_lo
    y_m = jnp.where(sq > 0, r / jnp.where(sq > 0, sq, 1.0), jnp.inf)
    y0 = jnp.minimum(jnp.minimum(y_ghi, y_m), jnp.minimum(y5, yq[0]))  # y5, yq[0] = 0 where none
    # its root is <= y0: it matters only where y0 exceeds the best other candidate
    need = vpos & (y0 > y) & (y0 >= y_glo * (1.0 - tol)) & (y0 < jnp.inf) & (r < jnp.inf)

    def solve(y0, Ay, r, y_glo, y_ghi, y_m):
        def phi_dphi(z):
            g_lin = jnp.maximum(Ay + s * z, eps)
            Y = jnp.exp(z)
            rho = Y / (r + Y)  # e^z / (r + e^z)
            phi = jnp.log(jnp.maximum(g_lin * ms / (r + Y) * rho, tiny))
            return phi, s / g_lin + 1.0 - 2.0 * rho, Y

        def newton(_, z):
            phi, dphi, _ = phi_dphi(z)
            return z - jnp.where((phi < 0) & (dphi < 0), phi / jnp.minimum(dphi, -eps), 0.0)

        z = lax.fori_loop(0, _NEWTON_STEPS, newton, jnp.log(y0))
        phi, _, y6 = phi_dphi(z)
        ok = (Ay + s * z > 0) & (y6 >= y_glo * (1.0 - tol)) & (y6 <= y_ghi * (1.0 + tol))
        return y6, ok & (y6 <= y_m * (1.0 + tol)) & (phi >= -16.0 * tol) & (y6 <= xi_hi)

    y6, ok6 = solve(jnp.where(need, y0, 1.0), jnp.where(need, ga - s * L, 1.0), jnp.where(need, r, 0.0),
                    y_glo, y_ghi, y_m)
    return jnp.maximum(y, jnp.where(need & ok6, y6, 0.0))


def _exact_k(mode, model, c, theta, e, v):
    """``model._exact_distance`` (exact ReddyAcuity) with the implicit-function derivative of
    ``rho(ln k; p) = ln(2 theta H'(v/k, e/k)) - ln k = 0`` (:func:`implicit_solution`: the forward pass
    is the solve alone; c carries no derivative).

    ``mode``: ``(outer, far)`` from ``model._solve_mode()``, or None (traced constants): then
    ``lax.switch`` picks at run time among (False, False), (False, True) and (True, True).
    """
    if mode is not None:
        k = model._exact_distance(c, theta, e, v, *mode)
    else:
        dtype = theta.dtype
        gmax, _, gsl, _, ms, _, _ = (lax.stop_gradient(x) for x in model._consts(dtype))
        outer = jnp.any(ms < 4.0)
        far = jnp.any(gmax * math.log(10.0) / gsl > _U_FAR)
        index = jnp.where(outer, 2, jnp.where(far, 1, 0))
        branches = [functools.partial(model._exact_distance, outer=o, far=f)
                    for o, f in ((False, False), (False, True), (True, True))]
        k = lax.switch(index, [lambda ops, fn=fn: fn(*ops) for fn in branches], (c, theta, e, v))
    ok = k > 0
    th = jnp.where(theta > 0, theta, 1.0)
    k = implicit_solution(_rho_k, jnp.where(ok, k, 1.0), ok, model, th, e, v)
    return jnp.where(ok, k, 0.0)


def _rho_k(k, model, theta, e, v):
    """``rho`` at distance multiple ``k`` (for the implicit derivative)."""
    return model._rho(jnp.log(k), theta, e, v)

"""Direct solve of the imperceptible distance for Kelly's (1979) spatio-temporal CSF.

Used by :meth:`pmetric.KellySpatioTemporal.imperceptible_distance` (hook ``_imperceptible_distance``). Notation: a change of contrast
``c`` spanning ``theta`` deg and moving at ``v`` deg/s on the retina, seen from ``k`` times farther
away, has frequency ``f = k / (2 theta)`` cycles/deg and velocity ``u = v / k`` deg/s; its temporal
frequency ``f u = v / (2 theta)`` Hz does not depend on ``k``. With ``K(u) = a0 + a1 |log10(u/3)|^3``,
``A = b v / (2 theta)`` (dimensionless) and ``s = k / v = 1 / u`` (s/deg), the margin
``ln c - ln c_T`` (perceptible iff >= 0; the threshold below the peak frequency is the peak's) is,
for ``k <= 10 v`` (``u >= 0.1``, below which Kelly's fit is clamped):

* on the falling limb (``f >= f_peak(u)``, i.e. ``s >= s_p``, ``s_p = (2 - A) / (2 A)`` for A < 2, else
  every s): ``h(s) = ln K + ln s - 2 A s + C_H``, ``C_H = ln c + 2 ln(A / b) - A``;
* below the peak (``s < s_p``): ``p(t) = ln K + t - 2 ln(e^t + 2) + C_P`` with ``t = ln u``,
  ``C_P = ln c - 2 ln b + 2 ln 2 - 2``: a fixed function of t, whose few local maxima are found once
  per model (``kelly_structure``).

**Concavity.** ``d2h/ds2 = (l1 + l2 - 1) / s^2`` with ``l1, l2`` the first two derivatives of
``ln K`` in ``t = ln u``. They depend only on ``r = a1 / a0``: for Kelly's and Reddy's constants
(r = 1.197) ``max(l1 + l2) = 0.921 < 1``, so ``h`` is strictly concave in s for every input.
(``kelly_structure`` checks it for the model's constants; where it fails the caller uses its scan.)
Newton's method started to the right of the largest root of a concave function never overshoots:
every iterate is an upper bound of the root (a conservative distance), and the iterates decrease
monotonically onto it. An iterate that reaches the lower end of the falling limb, or a point where
``h`` increases, proves there is no root; so does the tangent bound ``h(s) <= h(s_n) + h'(s_n)(s -
s_n)`` over ``[s_lo, s_n]``.

Sources: [Kel79] ([LHNW00 Eq 4]); [Red01 Eq 2] for the refitted constants; [LH01 §5.3] for the
distance key.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
from jax import lax

from ._inverse import bracketed_root, lambertw_m1

__all__ = ["kelly_structure", "kelly_fast", "kelly_slow", "kelly_clamped_root"]

_LN10 = math.log(10.0)
_LN3 = math.log(3.0)
_LN2 = math.log(2.0)
T_MIN = math.log(0.1)  # ln of the lowest velocity of the fit (deg/s); u = v / k >= 0.1 <=> k <= 10 v
NMAX = 4  # local maxima of p(t) kept (Kelly's constants have 2)
_CONCAVE_LIMIT = 0.98  # l1 + l2 must stay below this (1 is the limit; the grid max is within 1e-4)


def lnk(t, a0, a1):
    """``ln K`` and its first two derivatives in ``t = ln u`` (``K = a0 + a1 |log10(u / 3)|^3``)."""
    x = (t - _LN3) * (1.0 / _LN10)
    ax = jnp.abs(x)
    kk = a0 + a1 * ax * ax * ax
    ik = 1.0 / kk
    kx = 3.0 * a1 * x * ax * ik
    l1 = kx * (1.0 / _LN10)
    l2 = (6.0 * a1 * ax * ik - kx * kx) * (1.0 / _LN10**2)
    return jnp.log(kk), l1, l2


def kelly_structure(a0, a1, dtype):
    """Per-model constants of the direct solve (scalars; cost independent of the batch).

    Returns ``(ok, tmax, prev, pmax, pglob)``: ``ok`` is True when ``h`` is concave for every input
    (``max(l1 + l2) < 0.98`` on a fine grid) and ``p`` has at most ``NMAX`` local maxima;
    ``tmax`` (NMAX,) the local maxima of ``p`` on ``[T_MIN, ln 1e7]`` (``+inf`` pads), ``prev`` the
    local minimum before each (``-inf`` if none), ``pmax`` the values of ``p - C_P`` there, ``pglob``
    the largest value of ``p - C_P`` on ``[T_MIN, inf)``.
    """
    a0, a1 = (lax.stop_gradient(jnp.asarray(x, dtype)) for x in (a0, a1))
    r = jnp.maximum(a1 / a0, 0.0)
    s = r ** (1.0 / 3.0) / _LN10
    y = jnp.linspace(0.0, 6.0, 4097, dtype=dtype)  # x = y r^(-1/3); l1 + l2 peaks near y = 0.76
    q = 1.0 + y * y * y
    worst = jnp.max(3.0 * s * y * y / q + s * s * (6.0 * y - 3.0 * y**4) / (q * q))
    t = jnp.linspace(T_MIN, math.log(1e7), 4097, dtype=dtype)

    def dp(t):
        _, l1, _ = lnk(t, a0, a1)
        return l1 + 1.0 - 2.0 / (1.0 + 2.0 * jnp.exp(-t))

    up = dp(t) > 0
    chg_max = up[:-1] & ~up[1:]
    chg_min = ~up[:-1] & up[1:]
    (imax,) = jnp.nonzero(chg_max, size=NMAX, fill_value=-1)
    (imin,) = jnp.nonzero(chg_min, size=NMAX, fill_value=-1)

    def refine(i):  # bisection on the sign change of p' inside grid cell i
        lo, hi = t[jnp.maximum(i, 0)], t[jnp.maximum(i, 0) + 1]
        s_lo = dp(lo) > 0

        def body(_, st):
            lo, hi = st
            mid = 0.5 * (lo + hi)
            same = (dp(mid) > 0) == s_lo
            return jnp.where(same, mid, lo), jnp.where(same, hi, mid)

        lo, hi = lax.fori_loop(0, 48, body, (lo, hi))
        return jnp.where(i >= 0, 0.5 * (lo + hi), jnp.inf)

    tmax, tmin = refine(imax), refine(imin)
    prev = jnp.max(jnp.where(tmin[None, :] < tmax[:, None], tmin[None, :], -jnp.inf), axis=1)

    def p0(t):
        lk, _, _ = lnk(t, a0, a1)
        return lk - t - 2.0 * jnp.log1p(2.0 * jnp.exp(-t))

    fin = jnp.isfinite(tmax)
    pmax = jnp.where(fin, p0(jnp.where(fin, tmax, 0.0)), -jnp.inf)
    pglob = jnp.maximum(jnp.max(pmax), p0(jnp.asarray(T_MIN, dtype)))
    ok = (worst < _CONCAVE_LIMIT) & (jnp.sum(chg_max) <= NMAX) & ~up[-1]
    return ok, tmax, prev, pmax, pglob


def _consts(a0, a1, b, c, th, v):
    vs = jnp.where(v > 0, v, 1.0)
    A = b * vs / (2.0 * th)
    lnc = jnp.log(jnp.maximum(c, 1e-30))
    lnA = jnp.log(A)
    lnb = jnp.log(b)
    ch = lnc + 2.0 * (lnA - lnb) - A
    cp = lnc - 2.0 * lnb + (2.0 * _LN2 - 2.0)
    below = A < 2.0
    s_p = jnp.where(below, (2.0 - A) / (2.0 * A), 0.0)  # falling limb for s >= s_p
    return vs, A, lnA, ch, cp, below, s_p


def _h(s, A, ch, a0, a1):
    """h(s), h'(s) and h''(s) on the falling limb (s = k / v)."""
    t = -jnp.log(s)
    lk, l1, l2 = lnk(t, a0, a1)
    i_s = 1.0 / s
    return lk - t - 2.0 * A * s + ch, (1.0 - l1) * i_s - 2.0 * A, (l1 + l2 - 1.0) * i_s * i_s


def _p(t, cp, a0, a1):
    """p(t), p'(t) below the peak (t = ln u = -ln s)."""
    lk, l1, _ = lnk(t, a0, a1)
    q = 2.0 * jnp.exp(-t)
    return lk - t - 2.0 * jnp.log1p(q) + cp, l1 + 1.0 - 2.0 / (1.0 + q)


def _p_bracket(t_lo, cp, struct, below, a0, a1):
    """Where ``p`` first reaches 0 on ``[t_lo, inf)``: an increasing bracket ``[a, b]`` (in t), and
    whether it exists. ``p``'s supremum there is ``max(p(t_lo), local maxima beyond t_lo)``."""
    _, tmax, prev, pmax, _ = struct
    p_lo, _ = _p(t_lo, cp, a0, a1)
    a = jnp.full_like(t_lo, jnp.inf)
    b = jnp.full_like(t_lo, jnp.inf)
    for j in reversed(range(NMAX)):
        cond = (tmax[j] > t_lo) & (pmax[j] + cp >= 0)
        a = jnp.where(cond, jnp.maximum(prev[j], t_lo), a)
        b = jnp.where(cond, tmax[j], b)
    at_lo = p_lo >= 0
    a = jnp.where(at_lo, t_lo, a)
    b = jnp.where(at_lo, t_lo, b)
    return a, b, below & (at_lo | jnp.isfinite(b))


def _max_l1(a0, a1):
    """``max |l1| = r^(1/3) 2^(2/3) / ln 10`` (``r = a1 / a0``; at ``|y|^3 = 2``, y = r^(1/3) x)."""
    return jnp.maximum(a1 / a0, 0.0) ** (1.0 / 3.0) * (2.0 ** (2.0 / 3.0) / _LN10)


def _s_lo(a0, a1, A, s_p):
    """Lower end of the falling-limb search: the largest root of h is >= its maximum s*, and
    ``s* = (1 - l1(s*)) / (2 A) >= (1 - max l1) / (2 A)``."""
    m1 = _max_l1(a0, a1)
    return jnp.minimum(jnp.maximum(s_p, (1.0 - m1) / (2.0 * A)), 10.0)


# start of the clamped-velocity root: a(D) = 2 + 2 sqrt(D) + D q(sqrt(D)) solves 2 ln a - a + C = 0
# (a >= 2, D = C + 2 ln 2 - 2); q: least-squares fit (numpy.polyfit, weights ~ x^2 / a, 400 Chebyshev
# nodes in sqrt(D) on [0, sqrt(12)]) of the exact root -2 W_{-1}(-e^(-C/2) / 2); relative error <= 1e-5
# for 0 <= D <= 12 (tested), so one Newton step converges. Leading terms 2/3, 1/18 as in the
# branch-point series of W_{-1} [Cor96 Eq 4.22].
_R1_Q = (0.00043165, -0.00676053, 0.05455865, 0.66710294)
_R1_D_MAX = 12.0


def _r1(a0, a1, b, lnc):
    """The clamped-velocity regime ``k >= 10 v`` (u = 0.1 deg/s) in ``y = b k / theta``:
    ``G1(y) = 2 ln y - g1 y + C1`` with ``g1 = (0.1 + 2) / 2``; concave, maximal at ``y* = 2 / g1``
    (the peak frequency) where it equals ``D = C1 + 2 ln(2 / g1) - 2``. Returns ``(g1, C1, D)``."""
    x1 = (T_MIN - _LN3) / _LN10
    k1 = a0 + a1 * abs(x1) ** 3
    g1 = 0.5 * (math.exp(T_MIN) + 2.0)
    c1 = lnc + jnp.log(0.1 * k1) - 2.0 * jnp.log(2.0 * b)
    return g1, c1, c1 + (2.0 * math.log(2.0 / g1) - 2.0)


def kelly_clamped_root(a0, a1, b, c, th):
    """``k0``: the largest perceptible k in the clamped regime (Lambert W, exact; 0 if none). Where
    ``k0 >= 10 v`` it is the answer; :func:`kelly_fast` finds it by Newton, this is its reference."""
    lnc = jnp.log(jnp.maximum(c, 1e-30))
    g1, c1, d = _r1(a0, a1, b, lnc)
    ok = d >= 0
    x = jnp.where(ok, -0.5 * jnp.exp(-0.5 * jnp.where(ok, c1 - 2.0 * math.log(g1), 0.0)), -0.25)
    return jnp.where(ok, -2.0 * lambertw_m1(x) / g1 * th / b, 0.0)


def kelly_fast(a0, a1, b, c, th, v, struct, n_newton: int = 4):
    """Elementwise direct solve for every element (under stop_gradient; ``th > 0``, ``v >= 0``).

    Two independent parts in one elementwise pass, selected at the end:

    * where the change is perceptible at ``k = 10 v`` (or ``v = 0``) the answer is the root of the
      clamped-velocity margin ``G1(y) = 2 ln y - g1 y + C1`` (``y = b k / theta``; Lambert W in closed
      form): a fitted series in ``sqrt(D)`` starts within 1e-5 of it, and in float64 one Newton step
      (from either side of the concave ``G1`` it lands on an upper bound) makes it exact. In float32
      the step is skipped: near the branch point (``D -> 0``) its rounding would cost more than the
      series' 1e-5 (the root is ill-conditioned there in any method);
    * elsewhere: ``n_newton`` monotone Newton steps on ``h`` from an upper bound of the root (at most
      ``s = 10``), with the certificates of the module docstring.

    Returns one array: the largest perceptible ``k`` where found, 0 where nothing is perceptible, NaN
    where this pass cannot settle it (Newton not yet converged to 1e-5 relative without a no-root
    certificate, a possible root below the peak frequency, or ``D > 12``, i.e. ``c >> 1``): the caller
    solves those with :func:`kelly_slow` and :func:`kelly_clamped_root`.
    """
    tiny = jnp.finfo(c.dtype).tiny
    vs, A, lnA, ch, cp, below, s_p = _consts(a0, a1, b, c, th, v)
    s_lo = _s_lo(a0, a1, A, s_p)
    def newton(sv):
        g, dg, _ = _h(sv, A, ch, a0, a1)
        dg = jnp.minimum(dg, -tiny)
        step = jnp.where(g < 0, g / dg, 0.0)
        return jnp.maximum(sv - step, s_lo), g, dg, step

    # start: the root of a linear majorant of h (ln K <= its larger end value on [s_lo, 10], which
    # lies in t = ln(1/s) <= ln(2 A / (1 - max l1)); ln s <= its tangent at 2 / A), an upper bound
    # of the largest root: Newton from there stays monotone
    m1 = _max_l1(a0, a1)
    t_far = jnp.maximum(lnA + jnp.log(2.0 / (1.0 - m1)), T_MIN)
    l_top = jnp.maximum(lnk(jnp.asarray(T_MIN, c.dtype), a0, a1)[0], lnk(t_far, a0, a1)[0])
    lin = l_top + (_LN2 - lnA) - 1.0 + ch
    s0 = jnp.clip(lin / (1.5 * A), s_lo, 10.0)
    s_prev, step0 = s0, jnp.full_like(c, 10.0)
    # an unrolled chain: XLA keeps the whole pass in one fused loop (a fori_loop would write and read
    # every iterate and its per-element constants once per step)
    for _ in range(n_newton - 1):
        s_prev, _, _, step0 = newton(s_prev)
    sv, g, dg, step = newton(s_prev)  # g, dg at s_prev: the certificates use the tangent there
    # no root on the falling limb: h < 0 on (s_prev, 10] (passed by monotone Newton) and, h being
    # concave, below its tangent at s_prev on [s_lo, s_prev]: negative if h rises there or the
    # tangent is negative at s_lo
    none_h = (s_p >= 10.0) | ((g < 0) & ((dg >= 0) | (g - dg * (s_prev - s_lo) < 0)))
    # remaining error: ~step^2 / previous step while Newton converges quadratically (<= step always)
    conv = (g >= 0) | (jnp.minimum(step, step * step / jnp.maximum(step0, tiny)) <= 1e-5 * sv)
    found_h = ~none_h & conv
    undecided = ~none_h & ~conv
    # below the peak (only if the falling limb has no root): p < 0 at t_lo (there p = h(s_p) < 0, or
    # t_lo = T_MIN where the change is not perceptible), so a root needs a later local maximum >= 0
    _, tmax, _, pmax, _ = struct
    s_top = jnp.minimum(jnp.where(below, s_p, 10.0), 10.0)  # t_lo = -ln(s_top)
    has_p = jnp.zeros_like(below)
    for j in range(NMAX):
        has_p = has_p | ((jnp.exp(-tmax[j]) < s_top) & (pmax[j] + cp >= 0))
    rare = undecided | (below & none_h & has_p)
    k_h = jnp.where(rare, jnp.nan, jnp.where(found_h & (v > 0), vs * sv, 0.0))

    # the clamped regime. (Its own chain of expressions: sharing more intermediates with the above
    # makes XLA split the pass into several materialized arrays, which costs more than recomputing.)
    g1, c1, d = _r1(a0, a1, b, jnp.log(jnp.maximum(c, 1e-30)))
    y_star = 2.0 / g1
    y10 = jnp.maximum(10.0 * b * v / th, y_star)
    r1 = (2.0 * jnp.log(y10) - g1 * y10 + c1 >= 0) & (d >= 0)  # perceptible at k = 10 v
    xd = jnp.sqrt(jnp.clip(d, 0.0, None))
    q = _R1_Q[0]
    for coef in _R1_Q[1:]:
        q = q * xd + coef
    y = (2.0 + 2.0 * xd + xd * xd * q) / g1
    if jnp.finfo(c.dtype).bits > 32:
        y = jnp.maximum(y - (2.0 * jnp.log(y) - g1 * y + c1) / jnp.minimum(2.0 / y - g1, -tiny), y_star)
    k_1 = jnp.where(d <= _R1_D_MAX, y * th / b, jnp.nan)
    # one output array (XLA on CPU would otherwise materialize the shared intermediates once per
    # output): k where found, 0 where there is no root, NaN where the slow solver must decide
    return jnp.where(r1, k_1, k_h)


def kelly_slow(a0, a1, b, c, th, v, struct, n_iter: int = 40):
    """Elementwise exact solve with certified brackets (slow: for rare elements and for tests).

    Falling limb: the maximum of the concave ``h`` on ``[s_lo, 10]`` is located by bisection on
    ``h'``; if it is >= 0 the largest root is bracketed between it and 10 and found by safeguarded
    Newton (:func:`pmetric._inverse.bracketed_root`). Otherwise, below the peak: the first increasing stretch of ``p`` that reaches 0 beyond
    ``t_lo`` (from the per-model maxima) brackets the smallest ``t`` (largest k), found likewise.
    Returns ``(k, found)``.
    """
    vs, A, _, ch, cp, below, s_p = _consts(a0, a1, b, c, th, v)
    has_h = s_p < 10.0
    lo = jnp.where(has_h, _s_lo(a0, a1, A, s_p), 1.0)
    hi = jnp.full_like(c, 10.0)

    def gbis(_, st):  # h' decreases (h concave): geometric bisection for h' = 0 on [lo, 10]
        lo, hi = st
        mid = jnp.sqrt(lo * hi)
        _, d, _ = _h(mid, A, ch, a0, a1)
        return jnp.where(d > 0, mid, lo), jnp.where(d > 0, hi, mid)

    s_m, _ = lax.fori_loop(0, n_iter, gbis, (jnp.minimum(lo, hi), hi))
    hm, _, _ = _h(s_m, A, ch, a0, a1)
    found_h = has_h & (hm >= 0)

    # the root in [s_m, 10], h(s_m) >= 0 > h(10): its perceptible end
    lo_h = bracketed_root(lambda x: _h(x, A, ch, a0, a1)[0], s_m, hi, n_iter)
    t_lo = jnp.maximum(-jnp.log(jnp.where(below & (s_p > 0), s_p, 10.0)), T_MIN)
    a, bb, has_p = _p_bracket(t_lo, cp, struct, below, a0, a1)
    has_p = has_p & ~found_h
    a = jnp.where(has_p, a, 0.0)
    bb = jnp.where(has_p, bb, 0.0)

    # p increases on [a, b], p(a) < 0 <= p(b): the smallest t with p >= 0, as a root in x = -t
    hi_p = -bracketed_root(lambda x: _p(-x, cp, a0, a1)[0], -bb, -a, n_iter)
    k = vs * jnp.where(found_h, lo_h, jnp.exp(-hi_p))
    return k, found_h | has_p

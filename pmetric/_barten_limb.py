"""The fast exact solvers of :class:`pmetric.Barten` [Bar99] for concrete constants.

Per-model scalars computed once at trace time in float64 (:func:`_limb`, cached): the exact peak, the
constants of a linear-domain perceptibility test, and the inverse of the falling limb as a piecewise
Chebyshev start in sqrt(ln(c S_peak)) followed by one Newton (float32) or Halley (float64) step on the
exact formula (:func:`_limb_root`).
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from ._base import _F_HI
from ._numerics import LN_FLOOR, clenshaw

# --------------------------------------------------------------------------- fast solvers (concrete constants)
_FIELDS = ("sigma_0", "c_ab", "k", "t", "x_max", "y_max", "n_max", "eta", "p", "phi_0", "u_0")
_Q_HI = _F_HI**2  # the generic solvers' frequency cap 1e4 cycles/deg, as q = u^2
# Start polynomials: (degree, target relative error in u) per dtype; then one Newton (float32) or one
# Halley (float64) step, whose error is of the order of (start error)^2 resp. ^3.
_START_FIT = {"float32": (8, 1e-5), "float64": (12, 1e-7)}
_MAX_PIECES = 8


class _Limb(NamedTuple):
    """Per-model scalars of the fast solvers (Python floats, float64), for the default luminance and area.

    With q = u^2 (u in cycles/deg) Barten's formula is ``ln S(q) = c0 - a q - ln P(q) / 4``,
    ``P = (1 + ra q) (1 + rb q) (w1 + w0 / m)^2``, ``m = 1 - exp(-iu0 q)``:
    ``a = 2 pi^2 sigma^2`` (deg^2), ``ra = 1 / (Nmax^2 (1/X0^2 + 1/Xmax^2))`` and likewise ``rb`` (Y),
    ``iu0 = 1 / u0^2``, ``w1 = N1 / (N1 + Phi0)``, ``w0 = Phi0 / (N1 + Phi0)`` (``N1 = 1 / (eta p E)``) and
    ``c0 = -ln k - (ln 2 - ln T) / 2 - ln(A1 B1) / 4 - ln(N1 + Phi0) / 2``, ``k0 = exp(c0)``
    (A1 = 1/X0^2 + 1/Xmax^2, B1 = 1/Y0^2 + 1/Ymax^2, deg^-2).
    ``u_p`` / ``q_p``: the peak frequency (cycles/deg) and its square; ``ln_s_p = ln S(q_p)``.
    The inverse of the falling limb (None in a peak-only record, see :func:`_limb`):
    ``s_max = ln_s_p - max(ln 1e-30, ln S(1e4^2))`` (``s = ln(c S_peak) >= s_max`` saturates at 1e4
    cycles/deg); the start, u as a Chebyshev series in ``r = sqrt(s)`` on the pieces
    ``breaks[i] <= r < breaks[i + 1]`` (``coeffs[i]``), of maximum relative error ``err`` on a dense
    grid; ``halley``: one Halley (else Newton) step follows.
    """

    a: float
    ra: float
    rb: float
    iu0: float
    w1: float
    w0: float
    c0: float
    k0: float
    u_p: float
    q_p: float
    ln_s_p: float
    s_max: float | None = None
    breaks: tuple | None = None
    coeffs: tuple | None = None
    err: float | None = None
    halley: bool = False


def _limb_terms(consts, luminance, area, stiles_crawford):
    """(a, ra, rb, iu0, w1, w0, c0) of :class:`_Limb` in float64, or None where the fast path does not
    apply (a constant at which the generic formula clamps, e.g. ``k <= 1e-30``)."""
    sigma_0, c_ab, k, t, x_max, y_max, n_max, eta, p, phi_0, u_0 = consts
    if not all(math.isfinite(x) for x in consts):
        return None
    if min(k, t, eta * p, phi_0) <= 1e-30 or min(x_max, y_max, n_max, u_0) <= 0:
        return None
    d = 5.0 - 3.0 * math.tanh(0.4 * math.log10(luminance * area / 1600.0))  # pupil (mm)
    E = math.pi * d**2 / 4.0 * luminance  # retinal illuminance (Td)
    if stiles_crawford:
        E *= 1.0 - (d / 9.7) ** 2 + (d / 12.4) ** 4
    if not E > 0:
        return None
    a = 2.0 * math.pi**2 * (sigma_0**2 + (c_ab * d) ** 2)
    A1 = 1.0 / area + 1.0 / x_max**2
    B1 = 1.0 / area + 1.0 / y_max**2
    nn = 1.0 / n_max**2
    n1 = 1.0 / (eta * p * E)
    c0 = (-math.log(k) - 0.5 * (math.log(2.0) - math.log(t)) - 0.25 * math.log(A1 * B1)
          - 0.5 * math.log(n1 + phi_0))
    return a, nn / A1, nn / B1, 1.0 / u_0**2, n1 / (n1 + phi_0), phi_0 / (n1 + phi_0), c0


def _np_ln_s(q, terms):
    """Unfloored ln S at q = u^2 (numpy float64), from :func:`_limb_terms`."""
    a, ra, rb, iu0, w1, w0, c0 = terms
    m = -np.expm1(-iu0 * q)
    return c0 - a * q - 0.25 * (np.log1p(ra * q) + np.log1p(rb * q)) - 0.5 * np.log(w1 + w0 / m)


def _np_dln_s(q, terms):
    """d ln S / dq (numpy float64)."""
    a, ra, rb, iu0, w1, w0, _ = terms
    ex = np.exp(-iu0 * q)
    m = -np.expm1(-iu0 * q)
    return -a - 0.25 * (ra / (1.0 + ra * q) + rb / (1.0 + rb * q)) + 0.5 * w0 * iu0 * ex / (m * (w1 * m + w0))


def _np_cheb_pieces(r, breaks, coeffs):
    """The piecewise Chebyshev start at r (numpy)."""
    out = np.empty_like(r)
    idx = np.clip(np.searchsorted(np.asarray(breaks[1:-1]), r, side="right"), 0, len(coeffs) - 1)
    for i, cf in enumerate(coeffs):
        sel = idx == i
        lo, hi = breaks[i], breaks[i + 1]
        out[sel] = np.polynomial.chebyshev.chebval((2.0 * r[sel] - (lo + hi)) / (hi - lo), cf)
    return out


@functools.lru_cache(maxsize=256)
def _limb_peak(consts, luminance, area, stiles_crawford):
    """Peak-only :class:`_Limb` for the constants ``consts`` (the ``_FIELDS`` values), or None.

    The peak of ln S over u: the best of a 4097-point log grid over the generic search range [1e-3, 1e3]
    cycles/deg (the same global maximum the generic search finds), refined by 200 bisection steps on
    d ln S / dq (float64, to rounding). None (generic path) where it lies at the end of the range or the
    peak sensitivity is outside (e^-68, e^68) (the 1e-30 floors of c and S would matter)."""
    terms = _limb_terms(consts, luminance, area, stiles_crawford)
    if terms is None:
        return None
    u = np.logspace(-3.0, 3.0, 4097)
    i = int(np.argmax(_np_ln_s(u * u, terms)))
    if not 0 < i < u.size - 1:
        return None
    lo, hi = u[i - 1] ** 2, u[i + 1] ** 2
    if not (_np_dln_s(lo, terms) > 0 > _np_dln_s(hi, terms)):
        return None
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if _np_dln_s(mid, terms) > 0 else (lo, mid)
    q_p = float(0.5 * (lo + hi))
    ln_s_p = float(_np_ln_s(q_p, terms))
    if not -LN_FLOOR - 1.0 > ln_s_p > LN_FLOOR + 1.0:
        return None
    a, ra, rb, iu0, w1, w0, c0 = terms
    return _Limb(a, ra, rb, iu0, w1, w0, c0, math.exp(c0), math.sqrt(q_p), q_p, ln_s_p)


@functools.lru_cache(maxsize=64)
def _limb(consts, luminance, area, stiles_crawford, dtype_name):
    """:class:`_Limb` with the inverse of the falling limb for ``dtype_name``, or None (generic path).

    Built in float64 numpy once per model and dtype (cached; about 0.1 s): the peak (:func:`_limb_peak`);
    a check that ln S falls strictly from the peak to 1e4 cycles/deg or the 1e-30 floor (8192-point
    grid; else None); the exact inverse ``u(r)`` (bisection in ln q from a bracket read off a dense
    table of the forward map); the start pieces, each grown (bisection on its end) as long as its
    degree-``deg`` Chebyshev interpolant stays within the target error (``_START_FIT``), at most
    ``_MAX_PIECES``; finally the start's error on a 4097-point grid (``err``; None if above 1e-3).
    """
    pk = _limb_peak(consts, luminance, area, stiles_crawford)
    if pk is None:
        return None
    terms = pk[:7]
    ln_s = lambda q: _np_ln_s(q, terms)  # noqa: E731
    # strictly falling limb above the peak (down to the 1e-30 floor or 1e4 cycles/deg)
    lq = np.linspace(math.log(pk.q_p), math.log(_Q_HI), 8193)
    ls = ln_s(np.exp(lq))
    ls[0] = pk.ln_s_p
    above = ls[:-1] > LN_FLOOR
    if not (np.all(np.diff(ls)[above] < 0) and np.all(_np_dln_s(np.exp(lq[1:]), terms)[above] < 0)):
        return None
    s_max = pk.ln_s_p - max(LN_FLOOR, float(ls[-1]))
    r_tab = np.sqrt(np.maximum(pk.ln_s_p - ls, 0.0))  # r(ln q), increasing

    def u_of_r(r):  # the exact inverse: ln S(u^2) = ln_s_p - r^2 on the falling limb
        r = np.asarray(r, float)
        target = pk.ln_s_p - r * r
        j = np.clip(np.searchsorted(r_tab, r), 1, lq.size - 1)
        lo, hi = lq[j - 1], lq[j]
        for _ in range(48):
            mid = 0.5 * (lo + hi)
            ok = ln_s(np.exp(mid)) >= target
            lo, hi = np.where(ok, mid, lo), np.where(ok, hi, mid)
        # r = 0: the peak itself (ln S is flat there to rounding over ~sqrt(eps) in u)
        return np.where(r > 0, np.exp(0.25 * (lo + hi)), pk.u_p)

    deg, tol = _START_FIT[dtype_name]
    nodes = np.cos(np.pi * (np.arange(2 * deg + 2) + 0.5) / (2 * deg + 2))
    check = np.cos(np.pi * np.arange(65) / 64)

    def fit(r0, r1):
        cf = np.polynomial.chebyshev.chebfit(nodes, u_of_r(r0 + 0.5 * (nodes + 1.0) * (r1 - r0)), deg)
        rc = r0 + 0.5 * (check + 1.0) * (r1 - r0)
        err = np.max(np.abs(np.polynomial.chebyshev.chebval(check, cf) / u_of_r(rc) - 1.0))
        return cf, err

    R = math.sqrt(s_max)
    breaks, coeffs = [0.0], []
    while breaks[-1] < R and len(coeffs) < _MAX_PIECES:
        r0 = breaks[-1]
        cf, err = fit(r0, R)
        if err <= tol:
            breaks.append(R)
        else:  # the longest piece [r0, r1] within tol (bisection on r1)
            lo, hi = r0, R
            for _ in range(12):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if fit(r0, mid)[1] <= tol else (lo, mid)
            if lo == r0:
                return None
            cf, _ = fit(r0, lo)
            breaks.append(lo)
        coeffs.append(tuple(float(x) for x in cf))
    if breaks[-1] < R:
        return None
    rr = np.linspace(0.0, R, 4097)
    err = float(np.max(np.abs(_np_cheb_pieces(rr, breaks, coeffs) / u_of_r(rr) - 1.0)))
    if not err < 1e-3:
        return None
    # the log argument of the Newton step, (1 + ra q) (1 + rb q) (w1 + w0 / m)^2, at its largest q
    q_end = float(u_of_r(R) ** 2) * (1.0 + 16.0 * err)
    a, ra, rb, iu0, w1, w0, _ = terms
    if not (1.0 + ra * q_end) * (1.0 + rb * q_end) * (w1 + w0 / -math.expm1(-iu0 * q_end)) ** 2 < 1e30:
        return None
    return pk._replace(s_max=s_max, breaks=tuple(breaks), coeffs=tuple(coeffs), err=err,
                       halley=dtype_name == "float64")


def _limb_start(limb: _Limb, r):
    """The piecewise Chebyshev start u(r) (cycles/deg): pieces picked by selects (no gather, fusable)."""
    dtype = r.dtype
    const = lambda x: jnp.asarray(x, dtype)  # noqa: E731
    n = len(limb.coeffs)
    sel = [r >= limb.breaks[i] for i in range(1, n)]

    def pick(vals):
        out = const(vals[0])
        for i in range(1, n):
            out = jnp.where(sel[i - 1], const(vals[i]), out)
        return out

    mids = [0.5 * (limb.breaks[i] + limb.breaks[i + 1]) for i in range(n)]
    scales = [2.0 / (limb.breaks[i + 1] - limb.breaks[i]) for i in range(n)]
    x = (r - pick(mids)) * pick(scales)
    deg = len(limb.coeffs[0])
    return clenshaw(x, [pick([cf[j] for cf in limb.coeffs]) for j in range(deg)])


def _ex_m(limb: _Limb, q):
    """``exp(-q / u0^2)`` and ``m = 1 - exp(-q / u0^2)`` for q >= q_p (expm1 where q_p / u0^2 is small)."""
    x = -limb.iu0 * q
    if limb.q_p * limb.iu0 >= 0.05:  # m >= 0.049: 1 - exp loses at most a factor 20 in relative precision
        ex = jnp.exp(x)
        return ex, 1.0 - ex
    m = -jnp.expm1(x)
    return 1.0 - m, m


def _limb_root(limb: _Limb, logc):
    """u >= u_p (cycles/deg) with ``ln c + ln S(u) = 0`` on the falling limb, given ``logc = ln c``;
    no gradient. Only meaningful where ``0 <= s = ln c + ln_s_p < s_max``.

    Start :func:`_limb_start` at ``r = sqrt(s)``, then one Newton (float32) / Halley (float64) step on
    ``h(q) = ln c + ln S(q)`` (q = u^2; one exp, one log, rational derivatives). The step is limited to
    a few times the start's certified error (near the peak h' -> 0 and the rounding of h would
    otherwise be amplified) and the result kept >= q_p.
    """
    dtype = logc.dtype
    eps = float(jnp.finfo(dtype).eps)
    s = logc + limb.ln_s_p
    r = jnp.sqrt(jnp.clip(s, 0.0, limb.s_max))
    q = jnp.maximum(jnp.square(_limb_start(limb, r)), limb.q_p)
    ex, m = _ex_m(limb, q)
    aq = 1.0 + limb.ra * q
    bq = 1.0 + limb.rb * q
    nm = limb.w1 * m + limb.w0
    ab, mn = aq * bq, m * nm
    i_ab, i_mn = 1.0 / ab, 1.0 / mn
    ns = nm * nm * i_mn  # nm / m = w1 + w0 / m
    h = logc + limb.c0 - limb.a * q - 0.25 * jnp.log(ab * ns * ns)
    g = (0.5 * limb.w0 * limb.iu0) * ex * i_mn
    d1 = jnp.minimum(-limb.a - 0.25 * (limb.ra * bq + limb.rb * aq) * i_ab + g, -1e-30)  # dh/dq < 0
    if limb.halley:
        ia, ib = limb.ra * bq * i_ab, limb.rb * aq * i_ab
        d2 = 0.25 * (ia * ia + ib * ib) - limb.iu0 * g * (1.0 + ex * (nm + limb.w1 * m) * i_mn)
        den = 2.0 * d1 * d1 - h * d2
        step = jnp.where(den > 0, 2.0 * h * d1 / jnp.where(den > 0, den, 1.0), h / d1)
    else:
        step = h / d1
    lim = (8.0 * max(limb.err, 64.0 * eps)) * q
    q = jnp.maximum(q - jnp.clip(step, -lim, lim), limb.q_p)
    return jnp.sqrt(q)

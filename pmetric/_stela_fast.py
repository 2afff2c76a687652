"""Fast exact peak search of the achromatic stelaCSF (Mantiuk, Ashraf & Chapiro 2022) for concrete constants.

Used by :class:`pmetric.StelaCSF` (``is_perceptible``, the distance margin) when the model's constants
are concrete at trace time (not tracers); traced constants use the generic search of ``_stela.py``.

At the default luminance L (cd/m2), area A (deg2) and visual field, with ``u = ln f`` (f in
cycles/deg), ``t = f``, ``omega = f v`` (Hz), e in deg and v in deg/s, the natural log of the
sensitivity (R. K. Mantiuk, M. Ashraf, A. Chapiro, "stelaCSF", ACM TOG 41(4):145, 2022) is::

    F(u) = G(u) + logaddexp(A_s(u), A_t(u)) - kappa t - LN10 drop e,     kappa = LN10 drop_f e
    G(u) = u - ln(alpha + beta t^2) / 2          (alpha = 1/a0 + 1/A, beta = 1/(a0 f0^2): the size term)
    A_s  = C_s + LP_s(u) - omega^beta_s / sigma_s
    A_t  = C_t + LP_t(u) - (omega^beta_t - omega_0^beta_t)^2 / sigma_t
    LP_x = -(u - ln f_max,x)^2 / (LN10 2^bw_x), replaced by ln(1 - a_x) below its kink u_k,x

The truncation of the log-parabolas makes F piecewise smooth, with CONVEX kinks at u_k,t < u_k,s (the
slope jumps up), so a kink is never a maximum: the global maximum over u is the best interior maximum
of the three smooth pieces (u < u_k,t; u_k,t < u < u_k,s; u > u_k,s), each of which has at most one
(checked on the table nodes). Per model, a float64 table over (e, ln v) lists, per node, the one or
two pieces whose maxima can be the global one within half a cell of the node, with their location and
its first derivatives (implicit function theorem). At run time the nearest node gives a first-order
start for each candidate, ONE Newton step (analytic F', F'') polishes it and the quadratic model gives
the value ``F + F'^2 / (2 |F''|)`` (error O(step^3)); the best candidate wins. Elements whose step is
not small (``_STEP_TOL``), whose start leaves its piece, or that lie outside the table, are reported
as unsettled; the caller solves those with the generic search.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jax import lax

_LN10 = math.log(10.0)
_LN_FLOOR = math.log(1e-30)

# table: e in [0, E_HI] deg, ln v in [ln V_LO, ln V_HI] (v in deg/s); v below V_LO uses the V_LO row
E_HI = 120.0
V_LO, V_HI = 1e-5, 3e3
NE, NY = 193, 193
U_LO, U_HI = math.log(1e-6), math.log(1e3)  # search range of the pieces' maxima (ln cycles/deg)
_STEP_TOL = {"float32": 2e-2, "float64": 2e-3}  # largest accepted Newton step (in ln f)


class Consts(NamedTuple):
    """Per-model scalars (float64 Python floats) at the default luminance, area and visual field."""

    cs: float  # ln S_max of the sustained channel at L
    ct: float  # ln S_max of the transient channel at L
    lfs: float  # ln f_max (sustained, at L)
    lft: float  # ln f_max (transient)
    iss: float  # 1 / (LN10 2^bw_s)
    ist: float
    trs: float  # ln(1 - a_s): the truncation level
    trt: float
    uks: float  # kinks (ln cycles/deg)
    ukt: float
    alpha: float
    beta: float
    bs: float  # beta_sust
    isig_s: float  # 1 / sigma_sust
    bt: float
    isig_t: float
    w0b: float  # omega_0^beta_trans
    drop: float
    drop_f: float


def consts_of(vals, luminance, area, vis_field) -> Consts | None:
    """:class:`Consts` from the model's field values (float64) or None where the fast path does not
    apply (non-finite or clamped constants, kinks out of order)."""
    (ps, pf, bws, a_s, pt, tfm, bwt, a_t, sig_t, sig_s, b_s, b_t, om0, ed, edn, edf, edfn, f0, a0) = [
        x if np.ndim(x) else float(x) for x in vals]
    flat = [float(x) for x in np.concatenate([np.ravel(np.asarray(x, np.float64)) for x in vals])]
    if not all(math.isfinite(x) for x in flat):
        return None
    ps, pf, pt = (np.asarray(x, np.float64) for x in (ps, pf, pt))
    L = float(luminance)
    if min(ps[0], pf[0], pt[1], tfm, a0, f0, sig_t, sig_s, om0) <= 1e-30 or not (0 <= a_s < 0.999 and 0 <= a_t < 0.999):
        return None
    x = ps[4] * math.log1p(ps[3] / L)
    if not x > 1e-300:
        return None
    cs = math.log(ps[0]) - ps[2] * math.log1p(ps[1] / L) + math.log(-math.expm1(-x))
    lfs = math.log(pf[0]) - pf[2] * math.log1p(pf[1] / L)
    ct = math.log(pt[1]) + pt[0] * math.log(L)
    lft = math.log(tfm)
    iss, ist = 1.0 / (_LN10 * 2.0**bws), 1.0 / (_LN10 * 2.0**bwt)
    trs, trt = math.log1p(-a_s), math.log1p(-a_t)
    uks = lfs - math.sqrt(-trs / iss)
    ukt = lft - math.sqrt(-trt / ist)
    if not (U_LO < ukt < uks < U_HI):
        return None
    al = min(1.0, abs(float(vis_field) - 180.0) / 90.0)
    drop = al * ed + (1 - al) * edn
    drop_f = al * edf + (1 - al) * edfn
    if drop < 0 or drop_f < 0:
        return None
    out = (cs, ct, lfs, lft, iss, ist, trs, trt, uks, ukt, 1.0 / a0 + 1.0 / float(area), 1.0 / (a0 * f0**2),
           b_s, 1.0 / sig_s, b_t, 1.0 / sig_t, om0**b_t, drop, drop_f)
    return Consts(*(float(x) for x in out))


# --------------------------------------------------------------------------- the piecewise function
def piece_f(xp, k: Consts, u, lv, has_v, kappa, piece, order=2):
    """F, dF/du, d2F/du2 of the smooth function of ``piece`` (0: u < u_kt, 1: middle, 2: u > u_ks) at
    ``u`` (ln cycles/deg), ``lv = ln v`` (used where ``has_v``), ``kappa = LN10 drop_f e``; without the
    constant ``-LN10 drop e``. ``xp``: numpy or jax.numpy. ``piece`` may be an array."""
    t = xp.exp(u)
    bt2 = k.beta * t * t
    den = k.alpha + bt2
    q = bt2 / den
    g0 = u - 0.5 * xp.log(den)
    # log-parabolas, flat below their kinks
    ds, dt = u - k.lfs, u - k.lft
    par_s = piece >= 2
    par_t = piece >= 1
    ls0 = xp.where(par_s, -k.iss * ds * ds, k.trs)
    ls1 = xp.where(par_s, -2.0 * k.iss * ds, 0.0)
    lt0 = xp.where(par_t, -k.ist * dt * dt, k.trt)
    lt1 = xp.where(par_t, -2.0 * k.ist * dt, 0.0)
    # temporal terms (omega = t v)
    lw = u + xp.where(has_v, lv, 0.0)
    ps = xp.where(has_v, xp.exp(k.bs * lw), 0.0)
    pt = xp.where(has_v, xp.exp(k.bt * lw), 0.0)
    rs0 = -k.isig_s * ps
    dpt = pt - k.w0b
    rt0 = -k.isig_t * dpt * dpt
    a_s = k.cs + ls0 + rs0
    a_t = k.ct + lt0 + rt0
    d = a_t - a_s
    ed = xp.exp(-xp.abs(d))
    mx = xp.maximum(a_s, a_t)
    f0 = g0 + mx + xp.log1p(ed) - kappa * t
    if order == 0:
        return f0
    ws = xp.where(d <= 0, 1.0, ed) / (1.0 + ed)  # weight of the sustained channel
    wt = 1.0 - ws
    s1 = ls1 + k.bs * rs0
    t1 = lt1 - 2.0 * k.isig_t * k.bt * pt * dpt
    f1 = (1.0 - q) + ws * s1 + wt * t1 - kappa * t
    s2 = xp.where(par_s, -2.0 * k.iss, 0.0) + k.bs * k.bs * rs0
    t2 = xp.where(par_t, -2.0 * k.ist, 0.0) - 2.0 * k.isig_t * k.bt * k.bt * pt * (2.0 * pt - k.w0b)
    dd = s1 - t1
    f2 = -2.0 * q * (1.0 - q) + ws * s2 + wt * t2 + ws * wt * dd * dd - kappa * t
    return f0, f1, f2


def _np_full(k: Consts, u, lv, has_v, kappa):
    """The true (kinked) F at u (numpy): the piece of u."""
    piece = np.where(u < k.ukt, 0, np.where(u < k.uks, 1, 2))
    return piece_f(np, k, u, lv, has_v, kappa, piece, order=0)


class Table(NamedTuple):
    """Per-node candidates: ``cand[i, j] = (uA, uA_e, uA_y, uB, uB_e, uB_y)`` at e_i, y_j = ln v_j
    (u in ln cycles/deg; derivatives per deg and per unit ln v); ``ok[i, j]`` False where the node
    could not be certified (its elements are left to the generic search)."""

    k: Consts
    cand: np.ndarray  # (NE, NY, 8) float64 (last two: padding; NaN row where not ok)
    max_err: float  # largest ln S shortfall of the candidates vs a dense grid at the nodes


def _piece_roots(k, lv, has_v, kappa, piece, lo, hi, n_iter=52):
    """Root of dF/du of ``piece`` on [lo, hi] by bisection (F' > 0 at lo, < 0 at hi; else NaN)."""
    f_lo = piece_f(np, k, np.full_like(kappa, lo), lv, has_v, kappa, piece)[1]
    f_hi = piece_f(np, k, np.full_like(kappa, hi), lv, has_v, kappa, piece)[1]
    ok = (f_lo > 0) & (f_hi < 0)
    a, b = np.full_like(kappa, lo), np.full_like(kappa, hi)
    for _ in range(n_iter):
        m = 0.5 * (a + b)
        up = piece_f(np, k, m, lv, has_v, kappa, piece)[1] > 0
        a, b = np.where(up, m, a), np.where(up, b, m)
    return np.where(ok, 0.5 * (a + b), np.nan)


@functools.lru_cache(maxsize=16)
def build_table(k: Consts) -> Table | None:
    """The candidate table for ``k`` (float64 numpy, about a second; cached per model)."""
    e = np.linspace(0.0, E_HI, NE)
    y = np.linspace(math.log(V_LO), math.log(V_HI), NY)
    E, Y = np.meshgrid(e, y, indexing="ij")
    kappa = _LN10 * k.drop_f * E
    has_v = np.ones_like(E, bool)
    bounds = [(U_LO, k.ukt), (k.ukt, k.uks), (k.uks, U_HI)]
    us, ms, ues, uys = [], [], [], []
    for p, (lo, hi) in enumerate(bounds):
        r = _piece_roots(k, Y, has_v, kappa, p, lo, hi)
        rs = np.where(np.isnan(r), 0.5 * (lo + hi), r)
        f0, _, f2 = piece_f(np, k, rs, Y, has_v, kappa, p)
        t = np.exp(rs)
        h = 1e-5
        f1p = piece_f(np, k, rs, Y + h, has_v, kappa, p)[1]
        f1m = piece_f(np, k, rs, Y - h, has_v, kappa, p)[1]
        f2s = np.where(f2 < 0, f2, -1.0)
        ues.append(-(-_LN10 * k.drop_f * t) / f2s)
        uys.append(-((f1p - f1m) / (2 * h)) / f2s)
        us.append(r)
        ms.append(np.where(np.isnan(r) | ~(f2 < 0), -np.inf, f0))
    M = np.stack(ms, -1)  # (NE, NY, 3)
    U = np.stack(us, -1)
    order = np.argsort(-M, axis=-1)
    best = order[..., 0]
    # check against a dense grid (true, kinked F): the best candidate is the global maximum
    ug = np.linspace(math.log(1e-4), math.log(50.0), 1201)
    gmax = np.full(E.shape, -np.inf)
    for i0 in range(0, NE, 16):
        sl = slice(i0, i0 + 16)
        vals = _np_full(k, ug[None, None, :], Y[sl, :, None], True, kappa[sl, :, None])
        gmax[sl] = vals.max(-1)
    mbest = np.take_along_axis(M, best[..., None], -1)[..., 0]
    short = gmax - mbest
    ok = np.isfinite(mbest) & (short < 1e-9)
    # second candidate: another piece whose maximum is within tau of the best here, or which wins at a
    # neighbouring node
    tau = 0.05
    second = order[..., 1]
    m2 = np.take_along_axis(M, second[..., None], -1)[..., 0]
    alt = best.copy()
    pad = np.pad(best, 1, mode="edge")
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            nb = pad[1 + di: 1 + di + NE, 1 + dj: 1 + dj + NY]
            alt = np.where(nb != best, nb, alt)
    second = np.where(alt != best, alt, second)
    m2 = np.take_along_axis(M, second[..., None], -1)[..., 0]
    need_b = np.isfinite(m2) & ((alt != best) | (mbest - m2 < tau))
    second = np.where(need_b, second, best)
    cand = np.zeros(E.shape + (8,))
    for slot, idx in ((0, best), (3, second)):
        for j, arr in enumerate((U, np.stack(ues, -1), np.stack(uys, -1))):
            cand[..., slot + j] = np.take_along_axis(arr, idx[..., None], -1)[..., 0]
    bad = ~ok | ~np.isfinite(cand[..., :6]).all(-1)
    cand[bad] = np.nan
    max_err = float(np.max(np.where(ok, short, 0.0)))
    return Table(k, cand, max_err)


def piece_of(k: Consts, u):
    return jnp.where(u < k.ukt, 0, jnp.where(u < k.uks, 1, 2))


def fast_peak(tab: Table, e, v, dtype):
    """``(u_p, lnS_p, settled)``: ln of the peak frequency (cycles/deg) and the peak ln sensitivity (not
    floored) at eccentricity ``e`` (deg) and velocity ``v`` (deg/s), default luminance / area /
    visual field. No gradient. ``settled`` False where the generic search is needed."""
    k = tab.k
    e = e.astype(dtype)
    v = v.astype(dtype)
    has_v = v > 0
    lv = jnp.log(jnp.where(has_v, v, 1.0))
    x = e * ((NE - 1) / E_HI)
    y0 = math.log(V_LO)
    sy = (NY - 1) / (math.log(V_HI) - y0)
    yy = (jnp.maximum(jnp.where(has_v, lv, y0), y0) - y0) * sy
    inside = (x <= NE - 1) & (yy <= NY - 1)
    i = jnp.clip(jnp.round(x), 0, NE - 1).astype(jnp.int32)
    j = jnp.clip(jnp.round(yy), 0, NY - 1).astype(jnp.int32)
    dx = (x - i) * (E_HI / (NE - 1))
    dy = (yy - j) / sy
    idx = i * NY + j
    cols = [jnp.asarray(np.ascontiguousarray(tab.cand[..., q].reshape(-1)), dtype)[idx] for q in range(6)]
    kappa = (_LN10 * k.drop_f) * e
    best_u = best_m = None
    settled = inside
    tol = _STEP_TOL[jnp.dtype(dtype).name]
    n_steps = 1 if jnp.dtype(dtype) == jnp.dtype(jnp.float32) else 2
    for slot in (0, 3):
        u = cols[slot] + cols[slot + 1] * dx + cols[slot + 2] * dy
        piece = piece_of(k, cols[slot])
        good = jnp.isfinite(u)
        u = jnp.where(good, u, 0.0)
        for it in range(n_steps):
            good = good & (piece_of(k, u) == piece)
            f0, f1, f2 = piece_f(jnp, k, u, lv, has_v, kappa, piece)
            step = -f1 / jnp.minimum(f2, -1e-6)
            good = good & (f2 < 0) & (jnp.abs(step) <= (tol if it == 0 else 0.05 * tol))
            u = u + step
            m = f0 + 0.5 * f1 * step
        good = good & (piece_of(k, u) == piece)
        settled = settled & good
        if best_u is None:
            best_u, best_m = u, m
        else:
            better = m > best_m
            best_u, best_m = jnp.where(better, u, best_u), jnp.where(better, m, best_m)
    return best_u, best_m - (_LN10 * k.drop) * e, settled


# --------------------------------------------------------------------------- the distance along a ray
# A change of contrast c spanning theta deg at eccentricity e (deg) and velocity v (deg/s), seen from k
# times farther away, has f = k / (2 theta), e' = e / k = E / f and v' = v / k = V / f with
# E = e / (2 theta), V = v / (2 theta): its temporal frequency omega = f v' = V (Hz) and the
# frequency-dependent drop LN10 drop_f f e' = LN10 drop_f E do not depend on k. With u = ln f, the
# margin ln c + ln S(f, e', v') on the falling limb is (Mantiuk, Ashraf & Chapiro 2022, the model above)
#
#     m(u) = ln c - kappa + G(u) + logaddexp(A_s + LP_s(u), A_t + LP_t(u)) - a e^-u,
#     kappa = LN10 drop_f E,  a = LN10 drop E,  A_s = C_s - V^beta_s / sigma_s,
#     A_t = C_t - (V^beta_t - omega_0^beta_t)^2 / sigma_t,
#
# so on a static grid of u every term but e^(a e^-u) is a per-model constant.
RAY_DU = 0.3  # grid step of the ray scan (ln cycles/deg)
RAY_DU_FINE = 0.05  # the second tier (elements the first cannot certify)
W_DELTA = 0.0  # dP/du below this counts as "P falls along the ray"


class Ray(NamedTuple):
    """Per-model constants of the ray solve (float64 numpy; see :func:`build_ray`)."""

    u: np.ndarray  # (N,) grid of ln f (cycles/deg)
    gs: np.ndarray  # exp(G + LP_s) at the grid points
    gt: np.ndarray
    dc: np.ndarray  # (N-1,) sup over cell j of G' + max(LP_s', LP_t'): m' <= dc + a e^-u_j there
    m2j: np.ndarray  # (N-1,) M2 (du / 2) + kink jumps: m'' <= M2 on cell j but for the convex kinks (see ray_distance)
    eps: np.ndarray  # (N-1,) bump of m above its chord on cell j, without the a e^-u part (see build_ray)
    it: np.ndarray  # (N,) e^-u
    fp_max: float  # above every peak frequency (cycles/deg)
    e_w: float  # P(e', v') can fall along a ray only where e' <= e_w and 0 < v' <= v_w (deg, deg/s)
    v_w: float
    ok: bool  # the monotone-peak certificate holds (else every low-frequency answer is left to the caller)


def _lp(k: Consts, u, which):
    if which == "s":
        return np.where(u >= k.uks, -k.iss * (u - k.lfs) ** 2, k.trs), np.where(u >= k.uks, -2 * k.iss * (u - k.lfs), 0.0)
    return np.where(u >= k.ukt, -k.ist * (u - k.lft) ** 2, k.trt), np.where(u >= k.ukt, -2 * k.ist * (u - k.lft), 0.0)


def _grid_peak(k: Consts, le, y):
    """Global peak (ln f_p, ln S_p, piece) at e' = exp(le), v' = exp(y) (numpy, by bisection per piece)."""
    E = np.exp(le)
    kappa = _LN10 * k.drop_f * E
    has = np.ones_like(E, bool)
    best = None
    for p, (lo, hi) in enumerate([(U_LO, k.ukt), (k.ukt, k.uks), (k.uks, U_HI)]):
        r = _piece_roots(k, y, has, kappa, p, lo, hi, n_iter=44)
        rs = np.where(np.isnan(r), 0.5 * (lo + hi), r)
        f0 = np.where(np.isnan(r), -np.inf, piece_f(np, k, rs, y, has, kappa, p, order=0))
        if best is None:
            best = [rs, f0, np.full(E.shape, p)]
        else:
            b = f0 > best[1]
            best = [np.where(b, rs, best[0]), np.where(b, f0, best[1]), np.where(b, p, best[2])]
    return best[0], best[1] - _LN10 * k.drop * E, best[2]


def _dy_peak(k: Consts, u, y, piece):
    """d ln S / d ln v at frequency e^u (only the temporal terms depend on v; envelope theorem at the peak)."""
    lw = u + y
    ps, pt = np.exp(k.bs * lw), np.exp(k.bt * lw)
    rs0, dpt = -k.isig_s * ps, pt - k.w0b
    ls0 = np.where(piece >= 2, -k.iss * (u - k.lfs) ** 2, k.trs)
    lt0 = np.where(piece >= 1, -k.ist * (u - k.lft) ** 2, k.trt)
    ws = 1.0 / (1.0 + np.exp((k.ct + lt0 - k.isig_t * dpt * dpt) - (k.cs + ls0 + rs0)))
    return ws * k.bs * rs0 + (1.0 - ws) * (-2.0 * k.isig_t * k.bt * pt * dpt)


@functools.lru_cache(maxsize=16)
def _certificate(k: Consts):
    """``(e_w, v_w, ok)`` of :class:`Ray` (see :func:`build_ray`)."""
    le = np.linspace(math.log(1e-4), math.log(120.0), 121)
    y = np.linspace(math.log(1e-5), math.log(1e5), 181)
    LE, Y = np.meshgrid(le, y, indexing="ij")
    u0, p0, pc0 = _grid_peak(k, LE, Y)
    D = np.exp(LE) * _LN10 * (k.drop + k.drop_f * np.exp(u0)) - _dy_peak(k, u0, Y, pc0)
    h = 0.5 * (le[1] - le[0])
    u1, _, _ = _grid_peak(k, LE - h, Y - h)
    bad = D < W_DELTA
    ok = bool(np.all(u1 >= u0 - 1e-6)) and bool(p0[:, -1].max() < -0.1)
    ok = ok and (max(k.cs, k.ct) + 10.0 - _LN10 * k.drop * 120.0 < 0.0 or bool(p0[-1].max() < -0.1))
    ok = ok and not bad[-1].any() and not bad[:, -1].any()
    if bad.any():
        i = np.nonzero(bad)
        e_w = float(np.exp(le[min(i[0].max() + 2, le.size - 1)]))
        v_w = float(np.exp(y[min(i[1].max() + 2, y.size - 1)]))
    else:
        e_w, v_w = 0.0, 0.0
    return e_w, v_w, ok


@functools.lru_cache(maxsize=16)
def build_ray(k: Consts, fp_table_max: float, du: float = RAY_DU) -> Ray:
    """The ray-scan constants and the monotone-peak certificate for ``k`` (numpy, ~0.3 s; cached).

    Certificate: along a ray (k growing) e' and v' shrink. Where the peak ln S, P(e', v'), does not
    fall along the ray and the peak frequency does not jump down, a change perceptible below the peak
    frequency at some k stays perceptible up to where the ray meets the peak frequency, where the
    margin is the falling-limb one: so the answer is the largest falling-limb root. Checked on a
    121 x 181 grid of (ln e', ln v') over [1e-4, 120] deg x [1e-5, 1e5] deg/s: dP/du (closed form by the
    envelope theorem) is negative only inside a small box e' <= e_w, v' <= v_w (the transient channel's
    gain with velocity, about e' < 0.11 deg, v' < 0.36 deg/s for the 2022 constants; the box is
    widened by two grid cells), and the peak frequency never moves down along the ray (finite
    differences over half a cell). Beyond e' = 120 deg or v' = 1e5 deg/s the peak sensitivity is
    below 1 (checked), so nothing is perceptible there at c <= 1."""
    # the static scan range: m <= ln c + Ubar(u) (R <= 0, drop >= 0), so roots (c <= 1) need Ubar >= 0
    ug = np.linspace(math.log(1e-8), math.log(1e6), 28001)
    G = ug - 0.5 * np.log(k.alpha + k.beta * np.exp(2 * ug))
    ub = G + np.logaddexp(k.cs + _lp(k, ug, "s")[0], k.ct + _lp(k, ug, "t")[0])
    sel = ug[ub >= -0.05]
    n = int(math.ceil((sel.max() - sel.min()) / du)) + 3
    u = sel.min() - du + du * np.arange(n)
    t = np.exp(u)
    G = u - 0.5 * np.log(k.alpha + k.beta * t * t)
    lps, dlps = _lp(k, u, "s")
    lpt, dlpt = _lp(k, u, "t")
    gs, gt = np.exp(G + lps), np.exp(G + lpt)

    def cell_dmax(lf, uk, i2):  # sup of LP' over the cell (0 below the kink, decreasing above it)
        a, b = u[:-1], u[1:]
        above = -2 * i2 * (np.maximum(a, uk) - lf)
        return np.where(b <= uk, 0.0, np.where(a < uk, np.maximum(above, 0.0), above))

    q = k.beta * t[:-1] ** 2 / (k.alpha + k.beta * t[:-1] ** 2)
    dc = (1.0 - q) + np.maximum(cell_dmax(k.lfs, k.uks, k.iss), cell_dmax(k.lft, k.ukt, k.ist)) + 1e-9

    # m'' = G'' + w_s LP_s'' + w_t LP_t'' + w_s w_t (LP_s' - LP_t')^2 - a e^-u >= -2 q (1 - q) - max(2 i_s, 2 i_t)
    # - a e^-u (LP'' = 0 below a kink; the kinks are convex and only lower m below its chords): on cell j,
    # m <= chord + (M / 2)(u - u_j)(u_j+1 - u) <= max(m_j, m_j+1) + M du^2 / 8, M = eps0_j / (du^2 / 8) + a e^-u_j
    qq = k.beta * t * t / (k.alpha + k.beta * t * t)
    g2 = np.maximum(2 * qq[:-1] * (1 - qq[:-1]), 2 * qq[1:] * (1 - qq[1:]))
    g2 = np.where((qq[:-1] <= 0.5) & (qq[1:] >= 0.5), 0.5, g2)
    l2 = np.maximum(np.where(u[1:] > k.uks, 2 * k.iss, 0.0), np.where(u[1:] > k.ukt, 2 * k.ist, 0.0))
    eps = (g2 + l2) * (1.01 * du**2 / 8.0) + 1e-9
    # and m'' <= w_s w_t (LP_s' - LP_t')^2 <= (LP_s' - LP_t')^2 / 4 =: M2 between the kinks (piecewise linear
    # difference: extremes at the cell ends or the kinks), where m' jumps up by at most the LP' jumps
    pts = [u[:-1], u[1:]]
    for uk in (k.uks, k.ukt):
        for sgn in (-1e-12, 1e-12):
            pts.append(np.clip(uk + sgn, u[:-1], u[1:]))
    m2 = np.max([0.25 * (_lp(k, x, "s")[1] - _lp(k, x, "t")[1]) ** 2 for x in pts], axis=0) * 1.01 + 1e-9
    jump = np.zeros_like(m2)
    for uk, lf, i2 in ((k.uks, k.lfs, k.iss), (k.ukt, k.lft, k.ist)):
        jump += np.where((u[:-1] <= uk) & (u[1:] > uk), 2 * i2 * (lf - uk), 0.0)
    m2j = m2 * du / 2 + jump * 1.01 + 1e-6

    e_w, v_w, ok = _certificate(k)
    return Ray(u, gs, gt, dc, m2j, eps, 1.0 / t, float(fp_table_max) * 1.01, e_w, v_w, ok)


def ray_margin(k: Consts, u, lnc, A_s, A_t, a, kappa):
    """m(u) and dm/du on the ray (see above); jax, elementwise."""
    t = jnp.exp(u)
    it = jnp.exp(-u)
    bt2 = k.beta * t * t
    den = k.alpha + bt2
    ds, dt = u - k.lfs, u - k.lft
    ps = u >= k.uks
    pt = u >= k.ukt
    x_s = A_s + jnp.where(ps, -k.iss * ds * ds, k.trs)
    x_t = A_t + jnp.where(pt, -k.ist * dt * dt, k.trt)
    d = x_t - x_s
    ed = jnp.exp(-jnp.abs(d))
    m = lnc - kappa + u - 0.5 * jnp.log(den) + jnp.maximum(x_s, x_t) + jnp.log1p(ed) - a * it
    ws = jnp.where(d <= 0, 1.0, ed) / (1.0 + ed)
    dm = k.alpha / den + ws * jnp.where(ps, -2.0 * k.iss * ds, 0.0) + (1.0 - ws) * jnp.where(pt, -2.0 * k.ist * dt, 0.0) + a * it
    return m, dm


_RAY_STEPS = {"float32": 4, "float64": 5}
_RAY_TOL = {"float32": 2e-5, "float64": 1e-10}


def ray_distance(k: Consts, ray: Ray, c, th, e, v, dtype):
    """One fused elementwise pass: the imperceptible distance (see StelaCSF.imperceptible_distance),
    0 where nothing is perceptible, NaN where this pass cannot certify its answer (th > 0 here)."""
    name = jnp.dtype(dtype).name
    E = e / (2.0 * th)
    V = v / (2.0 * th)
    lnc = jnp.log(jnp.clip(c, 1e-30, 1.0))
    kappa = (_LN10 * k.drop_f) * E
    a = (_LN10 * k.drop) * E
    hv = V > 0
    lv = jnp.log(jnp.where(hv, V, 1.0))
    vs = jnp.where(hv, jnp.exp(k.bs * lv), 0.0)
    vt = jnp.where(hv, jnp.exp(k.bt * lv), 0.0)
    A_s = k.cs - k.isig_s * vs
    A_t = k.ct - k.isig_t * (vt - k.w0b) ** 2
    base = lnc - kappa
    X = jnp.maximum(A_s, A_t)
    Ws = jnp.exp(A_s - X)
    Wt = jnp.exp(A_t - X)
    base = base + X
    n = ray.u.size
    du = float(ray.u[1] - ray.u[0])
    unroll = n <= 64  # the first tier: unrolled (Python floats); the fine tier: a fori_loop over arrays
    cst = (lambda x: [float(z) for z in x]) if unroll else (lambda x: jnp.asarray(x, dtype))  # noqa: E731
    U, GS, GT, DC, EPS, IT = (cst(x) for x in (ray.u, ray.gs, ray.gt, ray.dc, ray.eps, ray.it))
    bump = (1.01 * du**2 / 8.0) * a

    def m_at(j):  # m(u_j): one log per grid point
        return base + jnp.log(Ws * GS[j] + Wt * GT[j]) - a * IT[j]

    m_next = m_at(n - 1)
    found = jnp.zeros(c.shape, bool)
    bad = m_next >= 0  # a root above the grid (c > 1 only)
    nd_root = jnp.zeros(c.shape, bool)
    j_root = jnp.zeros(c.shape, jnp.int32)
    n_pend = jnp.zeros(c.shape, jnp.int32)  # cells above the root where m may touch 0: refined below
    j_pend = jnp.zeros(c.shape, jnp.int32)
    m_pa = jnp.zeros(c.shape, dtype)
    m_pb = jnp.zeros(c.shape, dtype)
    u_lo = jnp.zeros(c.shape, dtype)
    m_lo = jnp.zeros(c.shape, dtype)
    m_hi = jnp.zeros(c.shape, dtype)
    def body(j, st):
        found, bad, nd_root, j_root, n_pend, j_pend, m_pa, m_pb, u_lo, m_lo, m_hi, m_next = st
        mj = m_at(j)
        pos = mj >= 0
        # m may reach 0 inside cell j (chord bound) and is not certified decreasing there
        up = jnp.maximum(mj, m_next) + (EPS[j] + bump * IT[j]) >= 0
        dec = DC[j] + a * IT[j] < 0
        new = pos & ~found
        pend = ~found & ~pos & up & ~dec
        # a root cell not certified decreasing: certified after Newton from m' at the root (below)
        nd_root = jnp.where(new, ~dec, nd_root)
        j_root = jnp.where(new, j, j_root)
        first = pend & (n_pend == 0)
        j_pend = jnp.where(first, j, j_pend)
        m_pa = jnp.where(first, mj, m_pa)
        m_pb = jnp.where(first, m_next, m_pb)
        n_pend = n_pend + pend.astype(jnp.int32)
        u_lo = jnp.where(new, U[j], u_lo)
        m_lo = jnp.where(new, mj, m_lo)
        m_hi = jnp.where(new, m_next, m_hi)
        return found | pos, bad, nd_root, j_root, n_pend, j_pend, m_pa, m_pb, u_lo, m_lo, m_hi, mj

    st = (found, bad, nd_root, j_root, n_pend, j_pend, m_pa, m_pb, u_lo, m_lo, m_hi, m_next)
    if unroll:
        for j in range(n - 2, -1, -1):
            st = body(j, st)
    else:
        st = lax.fori_loop(0, n - 1, lambda i, s_: body(n - 2 - i, s_), st)
    found, bad, nd_root, j_root, n_pend, j_pend, m_pa, m_pb, u_lo, m_lo, m_hi, _ = st
    # the (highest) uncertain cell: m at its quarter points, chord bounds on the four quarter cells
    u_p = float(ray.u[0]) + du * j_pend.astype(dtype)
    it_p = jnp.exp(-u_p)
    top = jnp.maximum(m_pa, m_pb)
    for q in (0.25, 0.5, 0.75):
        top = jnp.maximum(top, ray_margin(k, u_p + q * du, lnc, A_s, A_t, a, kappa)[0])
    eps_p = jnp.asarray(EPS, dtype)[j_pend] + bump * it_p
    bad = bad | (n_pend > 1) | ((n_pend == 1) & (top + eps_p / 16.0 >= 0))
    # the root in [u_lo, u_lo + du] (m decreasing there): secant start, safeguarded Newton
    lo, hi = u_lo, u_lo + du
    w = jnp.where(found, jnp.clip(m_lo / jnp.maximum(m_lo - m_hi, 1e-30), 0.0, 1.0), 0.5)
    w = jnp.where(jnp.isfinite(w), w, 0.5)
    x = lo + du * w
    step = jnp.full(c.shape, du, dtype)
    dm = jnp.zeros(c.shape, dtype)
    for _ in range(_RAY_STEPS[name]):
        mm, dm = ray_margin(k, x, lnc, A_s, A_t, a, kappa)
        lo = jnp.where(mm >= 0, x, lo)
        hi = jnp.where(mm >= 0, hi, x)
        nx = x - mm / jnp.minimum(dm, -1e-30)
        nx = jnp.where((nx >= lo) & (nx <= hi), nx, 0.5 * (lo + hi))
        step = nx - x
        x = nx
    conv = jnp.abs(step) <= _RAY_TOL[name]
    # no second root above x in the cell: m(x + s) <= m'(x) s + (jumps) s + M2 s^2 / 2 < 0 for 0 < s <= du
    # (m' taken at the last Newton point, within the tolerance of x: 1e-3 margin)
    bad = bad | (found & nd_root & (dm + jnp.asarray(cst(ray.m2j), dtype)[j_root] + 1e-3 >= 0))
    f_r = jnp.where(found, jnp.exp(x), 0.0)
    # below the peak frequency: certified when the ray meets no point where the peak sensitivity falls
    # along it, between the root and the highest peak frequency
    if ray.ok:
        meets = hv & (jnp.maximum(jnp.maximum(f_r, E / max(ray.e_w, 1e-30)), V / max(ray.v_w, 1e-30)) < ray.fp_max)
        low_ok = ~meets if ray.e_w > 0 else jnp.ones(c.shape, bool)
    else:
        low_ok = f_r >= ray.fp_max
    undecided = bad | (found & ~conv) | ~low_ok | (c > 1.0)
    kk = jnp.where(found, 2.0 * th * f_r, 0.0)
    return jnp.where(undecided, jnp.nan, kk)

"""Fast exact peak search of the achromatic stelaCSF [MAC22] for concrete constants.

Used by :class:`pmetric.StelaCSF` (``is_perceptible``, the distance margin, and the ray solve of
``_stela_ray.py``) when the model's constants
are concrete at trace time (not tracers); traced constants use the generic search of ``_stela.py``.

At the default luminance L (cd/m2), area A (deg2) and visual field, with ``u = ln f`` (f in
cycles/deg), ``t = f``, ``omega = f v`` (Hz), e in deg and v in deg/s, the natural log of the
sensitivity [MAC22] is::

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

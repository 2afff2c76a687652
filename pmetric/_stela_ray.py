"""Direct solve of the imperceptible distance of the achromatic stelaCSF [MAC22] along a ray, for
concrete constants (:func:`ray_distance`; per-model constants :func:`build_ray`). Used by
:meth:`pmetric.StelaCSF.imperceptible_distance`; the peak table it builds on is ``_stela_peak.py``.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jax import lax

from ._stela_peak import U_HI, U_LO, Consts, _piece_roots, piece_f

_LN10 = math.log(10.0)


# --------------------------------------------------------------------------- the distance along a ray
# A change of contrast c spanning theta deg at eccentricity e (deg) and velocity v (deg/s), seen from k
# times farther away, has f = k / (2 theta), e' = e / k = E / f and v' = v / k = V / f with
# E = e / (2 theta), V = v / (2 theta): its temporal frequency omega = f v' = V (Hz) and the
# frequency-dependent drop LN10 drop_f f e' = LN10 drop_f E do not depend on k. With u = ln f, the
# margin ln c + ln S(f, e', v') on the falling limb is ([MAC22], the model above)
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
    0 where nothing is perceptible, NaN where this pass cannot certify its answer (th > 0 here).
    Stages: the per-element constants of the margin (:func:`_ray_terms`), the top-down certified scan
    of the grid (:func:`_ray_scan`), the polish of the root and the certificates (:func:`_ray_root`)."""
    terms = _ray_terms(k, c, th, e, v)
    scan = _ray_scan(ray, terms, c.shape, dtype)
    return _ray_root(k, ray, terms, scan, c, th, dtype)


def _ray_terms(k: Consts, c, th, e, v):
    """The per-element constants of the margin along the ray (see the comment above :class:`Ray`)."""
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
    return dict(E=E, V=V, lnc=lnc, kappa=kappa, a=a, hv=hv, A_s=A_s, A_t=A_t, base=base, Ws=Ws, Wt=Wt)


def _ray_grid(ray: Ray, dtype):
    """``(n, du, unroll, cst)``: the grid size and step, whether the scan is unrolled (the first tier,
    Python floats) or a fori_loop over arrays (the fine tier), and the converter of its constants."""
    n = ray.u.size
    du = float(ray.u[1] - ray.u[0])
    unroll = n <= 64
    cst = (lambda x: [float(z) for z in x]) if unroll else (lambda x: jnp.asarray(x, dtype))  # noqa: E731
    return n, du, unroll, cst


def _ray_scan(ray: Ray, t, shape, dtype):
    """The top-down scan: the highest grid cell with a root, every cell above it certified free of
    roots by the per-cell bounds (or counted as pending). Returns the scan state (a tuple)."""
    n, du, unroll, cst = _ray_grid(ray, dtype)
    U, GS, GT, DC, EPS, IT = (cst(x) for x in (ray.u, ray.gs, ray.gt, ray.dc, ray.eps, ray.it))
    base, Ws, Wt, a = t["base"], t["Ws"], t["Wt"], t["a"]
    bump = (1.01 * du**2 / 8.0) * a

    def m_at(j):  # m(u_j): one log per grid point
        return base + jnp.log(Ws * GS[j] + Wt * GT[j]) - a * IT[j]

    m_next = m_at(n - 1)
    found = jnp.zeros(shape, bool)
    bad = m_next >= 0  # a root above the grid (c > 1 only)
    nd_root = jnp.zeros(shape, bool)
    j_root = jnp.zeros(shape, jnp.int32)
    n_pend = jnp.zeros(shape, jnp.int32)  # cells above the root where m may touch 0: refined below
    j_pend = jnp.zeros(shape, jnp.int32)
    m_pa = jnp.zeros(shape, dtype)
    m_pb = jnp.zeros(shape, dtype)
    u_lo = jnp.zeros(shape, dtype)
    m_lo = jnp.zeros(shape, dtype)
    m_hi = jnp.zeros(shape, dtype)

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
    return st[:-1] + (bump, EPS)


def _ray_root(k: Consts, ray: Ray, t, scan, c, th, dtype):
    """The root in the highest root cell (secant start, safeguarded Newton), the uncertain cell's
    refinement and the certificates below the peak frequency; NaN where any certificate fails."""
    name = jnp.dtype(dtype).name
    n, du, unroll, cst = _ray_grid(ray, dtype)
    found, bad, nd_root, j_root, n_pend, j_pend, m_pa, m_pb, u_lo, m_lo, m_hi, bump, EPS = scan
    lnc, A_s, A_t, a, kappa, hv, E, V = (t[x] for x in ("lnc", "A_s", "A_t", "a", "kappa", "hv", "E", "V"))
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

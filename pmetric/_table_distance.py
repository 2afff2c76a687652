"""The exact imperceptible distance of a :class:`pmetric.CalibratedCSF` [LH01 §5.3, §6.1].

* ``_exact_distance_impl`` -- (f x e) tables (and tables with a velocity axis queried at a concrete
  zero v): exact and elementwise, closed forms below the peak and per bilinear piece of the table, a
  window test from a quadratic, one bracketed root by Halley steps (the method and its proof are in
  its docstring). A concrete table gets a static plan (``_plan``: pieces that cannot matter are
  dropped at trace time); a traced table runs the same tests on every piece in loops
  (``_generic_search``).

The geometry and the static plan are in ``_table_plan.py``; the table-aware scan for tables with a
velocity axis queried at non-zero v is ``pmetric._table._eccentric_distance_impl``.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from ._table_plan import _INF, _p1_pairs, _pieces

_LN10 = math.log(10.0)


_HALLEY = {4: 3, 8: 3}  # Halley steps by itemsize (float32, float64) after the Taylor start (_piece_root)


def _pow10_neg(d, width: float, dtype):
    """10^-d for d in [0, width] (static width): a Taylor polynomial of exp(-ln10 d) accurate to about one
    unit of the last place of ``dtype`` (cheaper than a general exp inside the big fused kernel)."""
    t = _LN10 * max(width, 1e-3)
    eps = float(jnp.finfo(dtype).eps) * 0.25
    deg, term = 1, t
    while term > eps * math.exp(-t) and deg < 40:  # Lagrange remainder t^(deg+1)/(deg+1)! < eps e^-t
        deg += 1
        term = term * t / deg
    acc = (-1.0) ** deg / math.factorial(deg)
    u = _LN10 * d
    for k in range(deg - 1, -1, -1):
        acc = acc * u + (-1.0) ** k / math.factorial(k)
    return acc


def _fmax(a, b):
    """max without NaN propagation (one compare and one blend instead of three instructions on CPU)."""
    return jnp.where(a > b, a, b)


def _fmin(a, b):
    return jnp.where(a < b, a, b)


def _is_inf(x) -> bool:
    return isinstance(x, float) and x == _INF


def _is_zero(x) -> bool:
    return isinstance(x, float) and x == 0.0


def _cut(Qi, bound):
    """Qi - log10(bound): the local x where the path's e' equals a band edge (bound = 0: +inf)."""
    if isinstance(bound, float):
        return Qi - math.log10(bound)
    pos = bound > 0
    return jnp.where(pos, Qi - jnp.log10(jnp.where(pos, bound, 1.0)), jnp.inf)


def _piece_root(A, b, al, be, E0, lo, hi, hlo, hhi, elo, ehi, n_iter):
    """The root of h(x) = A + b e' + x (al + be e'), e' = E0 10^-x, in [lo, hi] where h(lo) <= 0 < h(hi)
    with one sign change (``_exact_distance_impl``); ``elo``, ``ehi``: e' at lo and hi. Start: the root of
    the second-order Taylor model of h at lo (good also when the root is nearly double, i.e. h' small),
    else of the model at hi, else regula falsi; then ``n_iter`` Halley steps (cubic convergence) kept
    inside the shrinking bracket (bisection otherwise). On the test tables of tests/test_table.py 3 steps
    leave at most 2e-15 relative error in k (2 steps: up to 2e-6 on a table with dips)."""
    def taylor(x0, h0, e0, sign):
        g = b + be * x0
        d1 = al + e0 * (be - _LN10 * g)
        d2 = _LN10 * e0 * (_LN10 * g - 2.0 * be)
        disc = d1 * d1 - 2.0 * d2 * h0
        den = d1 + sign * jnp.sqrt(jnp.maximum(disc, 0.0))
        x = x0 - 2.0 * h0 / jnp.where(den != 0, den, 1.0)
        return x, (disc >= 0) & (den != 0) & (x >= lo) & (x <= hi)

    x_lo, ok_lo = taylor(lo, hlo, elo, 1.0)
    x_hi, ok_hi = taylor(hi, hhi, ehi, 1.0)
    dh = hhi - hlo
    rf = jnp.where(dh > 0, lo - hlo * (hi - lo) / jnp.where(dh > 0, dh, 1.0), 0.5 * (lo + hi))
    x = jnp.where(ok_lo, x_lo, jnp.where(ok_hi, x_hi, jnp.where((rf >= lo) & (rf <= hi), rf, 0.5 * (lo + hi))))
    for _ in range(n_iter):
        ep = E0 * jnp.exp(-_LN10 * x)
        g = b + be * x
        h = A + b * ep + x * (al + be * ep)
        d1 = al + ep * (be - _LN10 * g)
        d2 = _LN10 * ep * (_LN10 * g - 2.0 * be)
        neg = h <= 0
        lo = jnp.where(neg, x, lo)
        hi = jnp.where(neg, hi, x)
        xn = x - 2.0 * h * d1 / (2.0 * d1 * d1 - h * d2)  # Halley
        x = jnp.where((xn >= lo) & (xn <= hi), xn, 0.5 * (lo + hi))
    return x


def _generic_search(pieces, pairs, freqs, Ys, qs, Qs, Xu, pXu, shape, dtype):
    """The P1 and P2 searches of ``_exact_distance_impl`` for a TRACED table (no static plan): every pair
    and every G-signed piece, with the same tests, run by two ``fori_loop``s over stacked constants (a
    small loop body: fast to compile; unrolled, the kernel grows past what XLA compiles quickly)."""
    sg = jax.lax.stop_gradient
    f32 = lambda v: jnp.asarray(v, dtype)  # noqa: E731
    ptab = jnp.stack([jnp.stack([f32(p["a"]), f32(p["b"]), f32(p["L"]), f32(p["H"]), f32(p["empty"]),
                                 f32(1.0 / freqs[p["node"]])]) for p in pairs])
    pts = sg(ptab)

    def p1(j, st):
        e1, pid = st
        a, b, L, H, empty, invf = (pts[j, k] for k in range(6))
        u = (Ys - a) / jnp.where(b == 0, 1.0, b)
        hi = jnp.where(b > 0, jnp.minimum(H, u), H)
        lo = jnp.where(b < 0, jnp.maximum(jnp.maximum(L, qs * invf), u), jnp.maximum(L, qs * invf))
        take = (empty < 0.5) & ((b != 0) | (a <= Ys)) & (lo <= hi) & (lo < e1)
        return jnp.where(take, lo, e1), jnp.where(take, j, pid)

    e1, pid = jax.lax.fori_loop(0, len(pairs), p1, (jnp.full(shape, jnp.inf, dtype), jnp.zeros(shape, jnp.int32)))
    F = len(freqs)
    rows = [p for p in pieces if p["half"] != -1]
    tab = jnp.stack([jnp.stack([f32(p[k]) for k in ("a", "b", "al", "be", "xlo", "xhi", "lo", "hi", "sG")]
                               + [f32(math.log10(freqs[p["strip"]])), f32(1.0 / freqs[p["strip"]]),
                                  f32(float(p["strip"] == F - 1))]) for p in rows])
    ts = sg(tab)

    def p2(j, st):
        bkey, zend, blo, bhi, bid = st
        a, b, al, be, xlo, xhi, lo_e, hi_e, sG, z0, invf, top = (ts[j, k] for k in range(12))
        E0, Qi = qs * invf, Qs - z0
        xa = jnp.maximum(xlo, Qi - jnp.log10(hi_e))
        xb = jnp.minimum(xhi, jnp.where(lo_e > 0, Qi - jnp.log10(jnp.where(lo_e > 0, lo_e, 1.0)), jnp.inf))
        xb = jnp.where(top > 0.5, jnp.minimum(xb, Xu), xb)
        ea = jnp.minimum(E0 * jnp.exp(-_LN10 * xlo), hi_e)
        eb = jnp.maximum(E0 * jnp.maximum(jnp.exp(-_LN10 * xhi), jnp.where(top > 0.5, pXu, 0.0)), lo_e)
        ne = xa < xb
        A = a - Ys
        ha = A + b * ea + xa * (al + be * ea)
        hb = A + b * eb + xb * (al + be * eb)
        endp = ne & (hb <= 0)
        zend = jnp.where(endp, jnp.maximum(zend, z0 + xb), zend)
        n0 = -A
        a2 = -_LN10 * al * be
        a1 = _LN10 * (be * n0 - al * b)
        a0 = n0 * (_LN10 * b - be) - al * b
        sd = jnp.sqrt(jnp.maximum(a1 * a1 - 4.0 * a2 * a0, 0.0))
        s_pos = sG > 0
        first = jnp.where(s_pos, a1 <= 0, a1 >= 0)
        num = jnp.where(first, 2.0 * a0, jnp.where(s_pos, -a1 - sd, sd - a1))
        den = jnp.where(first, jnp.where(s_pos, sd - a1, -a1 - sd), 2.0 * a2)
        xr = jnp.clip(num / den, xa, xb)
        er = E0 * jnp.exp(-_LN10 * xr)
        win = A + b * er + xr * (al + be * er) <= 0
        lo = jnp.where(win, xr, xa)
        key = z0 + lo
        better = ne & ~endp & ((ha <= 0) | win) & (key > bkey)
        return (jnp.where(better, key, bkey), zend, jnp.where(better, lo, blo), jnp.where(better, xb, bhi),
                jnp.where(better, j, bid))

    neg_inf = jnp.full(shape, -jnp.inf, dtype)
    zero = jnp.zeros(shape, dtype)
    bkey, zend, blo, bhi, bid = jax.lax.fori_loop(0, len(rows), p2, (neg_inf, neg_inf, zero, zero,
                                                                     jnp.zeros(shape, jnp.int32)))
    rows_tab = tab[:, jnp.array([0, 1, 2, 3, 9, 10])]
    prow_tab = ptab[:, jnp.array([0, 1, 2, 5])]
    return e1, pid, prow_tab, bkey, zend, blo, bhi, bid, rows_tab


def _pick(tab, idx, shape):
    """Row ``idx`` of a small table, elementwise by a select chain (no gather: stays in one fusion)."""
    out = [jnp.zeros(shape, tab.dtype) for _ in range(tab.shape[1])]
    for slot in range(tab.shape[0]):
        hit = idx == slot
        out = [jnp.where(hit, tab[slot, j], o) for j, o in enumerate(out)]
    return out


def _answer_parts(sel1, sel2, x, z2, end2, has2, has1, Y, q, th):
    """Primal values of ``_answer``."""
    pa, pb, pL, pinvf = sel1
    _, _, _, _, rz0, _ = sel2
    u = jnp.where(pb < 0, (Y - pa) / jnp.where(pb < 0, pb, -1.0), -jnp.inf)
    e1 = jnp.where(has1, jnp.maximum(jnp.maximum(pL, q * pinvf), u), 1.0)
    k1 = jnp.where(has1, 2.0 * th * q / e1, 0.0)
    ok2 = has2 | end2
    z = jnp.where(ok2, jnp.where(end2, z2, rz0 + x), 0.0)
    k2 = jnp.where(ok2, 2.0 * th * jnp.exp(_LN10 * z), 0.0)
    return k1, k2, u, e1


@jax.custom_jvp
def _answer(rows_tab, prow_tab, sel1, sel2, x, z2, end2, has2, bid, has1, pid, Y, q, th):
    """k = max(k1, k2) from the winners of ``_exact_distance_impl``: k1 = 2 theta q / e1 (P1 closed form),
    k2 = 2 theta 10^(z_i + x) (P2 root x or a piece end z2). ``sel1`` / ``sel2``: the winning rows of
    ``prow_tab`` / ``rows_tab`` (indices ``pid`` / ``bid``), already picked. Custom derivative: closed
    forms for P1, the implicit-function derivative for the root, and the table constants' tangents
    gathered by the winners' indices (so a gradient with respect to the table is one scatter-add, not
    a batch reduction per constant)."""
    k1, k2, _, _ = _answer_parts(sel1, sel2, x, z2, end2, has2, has1, Y, q, th)
    return jnp.maximum(k1, k2)


@_answer.defjvp
def _answer_jvp(primals, tangents):
    rows_tab, prow_tab, sel1, sel2, x, z2, end2, has2, bid, has1, pid, Y, q, th = primals
    drows, dprow = tangents[0], tangents[1]
    dY, dq, dth = tangents[11:14]
    k1, k2, u, e1 = _answer_parts(sel1, sel2, x, z2, end2, has2, has1, Y, q, th)
    pa, pb, pL, pinvf = sel1
    _, rb, ral, rbe, _, rinvf = sel2
    # P1: e1 = max(L, q / f_i, u): the binding term carries the derivative
    da, db, dL, dinvf = (d[..., 0] for d in jnp.split(jnp.take(dprow, pid, axis=0), 4, axis=-1))
    qf = q * pinvf
    bsafe = jnp.where(pb < 0, pb, -1.0)
    du = (dY - da) / bsafe - (Y - pa) * db / (bsafe * bsafe)
    de1 = jnp.where((u >= pL) & (u >= qf), du, jnp.where(qf >= pL, dq * pinvf + q * dinvf, dL))
    dk1 = jnp.where(has1, 2.0 * (dth * q + th * dq) / e1 - k1 * de1 / e1, 0.0)
    # P2: implicit function of h(x) = a - Y + b e' + x (al + be e'), e' = q invf 10^-x
    ga, gb, gal, gbe, _, ginvf = (d[..., 0] for d in jnp.split(jnp.take(drows, bid, axis=0), 6, axis=-1))
    p10 = jnp.exp(-_LN10 * x)
    ep = q * rinvf * p10
    dep = (dq * rinvf + q * ginvf) * p10
    hx = ral + ep * (rbe - _LN10 * (rb + rbe * x))
    floor = jnp.sqrt(jnp.finfo(x.dtype).tiny)
    hx = jnp.where(jnp.abs(hx) > floor, hx, jnp.where(hx < 0, -floor, floor))
    dh = ga - dY + gb * ep + rb * dep + x * (gal + gbe * ep + rbe * dep)
    root = has2 & ~end2
    dx = jnp.where(root, -dh / hx, 0.0)
    dk2 = jnp.where(has2 | end2, k2 * (_LN10 * dx + dth / th), 0.0)
    k = jnp.maximum(k1, k2)
    return k, jnp.where(k1 >= k2, dk1, dk2)


def _exact_distance_impl(plan, freqs, eccs, ms, T2, c, theta, e):
    """Exact ``imperceptible_distance`` of an (f x e) table; ``plan`` from ``_plan`` or None (generic).

    Notation: z = log10 f, Y = log10 max(c, 1e-30), q = e / (2 theta); along the path k -> (f, e') =
    (k / 2 theta, e / k), i.e. e'(z) = q 10^-z, and k = 2 theta 10^z. The perceptible set is
    P = {z : y(z, e'(z)) <= Y}; the answer is k = 2 theta 10^sup(P) (0 if P is empty), the smallest k
    beyond which nothing is perceptible.

    Decomposition. With y~ the table surface WITHOUT the peak clamp (interpolation in z with constant
    extension below the first node and the min_slope extrapolation above the last), y = y~ above the
    peak frequency z_p(e') and y = y_p(e') = min_i col_i(e') below it, and y_p <= y~ everywhere, so
        P = P1 u P2,   P1 = {z < z_p(e'), y_p(e') <= Y},   P2 = {y~(z, e') <= Y}
    (where y~ <= Y below the peak, y_p <= y~ <= Y too; conversely P1 and P2 lie in P), and sup P is the
    larger of the two suprema, each computed exactly:

    * P1 in closed form. On each eccentricity band (node columns linear in e') node i is the HIGHEST
      node of lowest value exactly on an e' interval [L, H] (``_argmin_interval``, table only); there
      P1 = {e' > q / f_i, a_i + b_i e' <= Y}, an interval of e', and since z = log10(q / e') falls with
      e', sup P1 over the pair is at the smallest e' of that interval: k = 2 theta q / e' (= e / e').
    * P2 piece by piece (``_pieces``: band x frequency strip, split where the extrapolation slope
      changes branch). On a piece the surface is bilinear and along the path
          h(x) = y~ - Y = (a - Y) + b e' + x (alpha + beta e'),   x = z - z_i,  e' = E0 10^-x,  E0 = q / f_i;
      the path's ends in the piece are table nodes or band edges, so h there costs no transcendental.
      (i) If h has no interior local minimum on the piece (``_needs_witness``: h' one-signed or h
      concave on the piece's whole (x, e') box, decided from the table), the piece holds a perceptible
      point iff an end does, and at most one sign change: the sup is the upper end or the unique root
      in (x_a, x_b). (ii) Otherwise the piece is split where G(x) = b + beta x changes sign. Let
      N = Y - a - alpha x: h <= 0 iff G e' <= N, i.e. Phi(x) = x + log10(N / G) >= log10 E0 for G > 0
      (for G < 0: N >= 0, which reaches a piece end because N is linear, or Phi <= log10 E0).
      Phi' = (ln10 N G - alpha G - beta N) / (ln10 N G) has a QUADRATIC numerator, so Phi has at most
      one local maximum r- and one local minimum r+, in closed form. Lemma: if h(x_b) > 0, the piece's
      perceptible points lie below the unique root of h in (lo, x_b), lo = r (r- for G > 0, r+ for
      G < 0, clipped into the piece) if h(r) <= 0, else lo = x_a if h(x_a) <= 0, else there are none.
      Proof (G > 0): a maximal perceptible interval [u, v] strictly inside has Phi = log10 E0 at u and v
      and Phi >= log10 E0 between, so it holds a local maximum of Phi, i.e. r-, which is then
      perceptible; after r- Phi falls to r+ and rises to Phi(x_b) < log10 E0, crossing it once; if
      h(r) > 0 no such interval exists and Phi falls from x_a through log10 E0 once. G < 0 is the
      mirror image (minima). Any point of [x_a, x_b] is a sound test, so degenerate quadratics need no
      special care.
      Pieces are disjoint along the path, so the piece holding the highest perceptible point is the one
      whose lower bracket end lo is highest; its root is bracketed, lo < root < x_b with one sign
      change, and is found by ``_piece_root`` (second-order Taylor start, safeguarded Halley steps).

    The extrapolation strip is capped at x = (Y - min col_top) / min_slope + 0.01 decades, beyond which
    y >= min col_top + min_slope x > Y. Gradients: P1 through its closed form; a P2 root through one
    value-preserving implicit-function step x* - (h - h*) / h_x(x*) on the winning piece's margin (the
    margin equals h near the root); c, theta, e and the table all enter. A perceptible piece end above
    every root (only next to a pruned or sliver piece, see ``_plan``) is returned without gradient.
    """
    shape = jnp.broadcast_shapes(c.shape, theta.shape, e.shape)
    dtype = jnp.result_type(c, theta, e, T2)
    c, theta, e = (jnp.broadcast_to(x, shape).astype(dtype) for x in (c, theta, e))
    T2 = T2.astype(dtype)
    sg = jax.lax.stop_gradient
    pos = theta > 0
    th = jnp.where(pos, theta, 1.0)
    Y = jnp.log10(jnp.maximum(c, 1e-30))
    q = jnp.minimum(e / (2.0 * th), 1e30)
    Ys, qs = sg(Y), sg(q)
    Qs = jnp.log10(qs)  # -inf at e = 0: handled (every band edge term is guarded)
    pieces = _pieces(jnp, T2, freqs, eccs, ms)
    pairs = _p1_pairs(jnp, T2, eccs)
    Xu, pXu = _extrapolation_cap(T2, len(freqs), Ys, ms)
    if plan is None:  # traced table: every piece and pair, in loops (the same tests, decided per call)
        e1, pid, prow_tab, bkey, zend, blo, bhi, bid, rows_tab = _generic_search(
            pieces, pairs, freqs, Ys, qs, Qs, Xu, pXu, shape, dtype)
        has1 = jnp.isfinite(e1) & (e1 > 0)
        has2 = jnp.isfinite(bkey)
        # (the loops have split the kernel already: a gather is cheaper than long select chains)
        sel2 = [v[..., 0] for v in jnp.split(jnp.take(sg(rows_tab), bid, axis=0), 6, axis=-1)]
        sel1 = [v[..., 0] for v in jnp.split(jnp.take(sg(prow_tab), pid, axis=0), 4, axis=-1)]
    else:
        plan_pieces, plan_pairs, plan_sb = plan
        e1, pid, prow = _p1_planned(plan_pairs, plan_sb, pairs, freqs, Ys, qs, shape, dtype)
        has1 = jnp.isfinite(e1) & (e1 > 0)
        bkey, zend, blo, bhi, bid, rows = _p2_planned(plan_pieces, pieces, freqs, Ys, qs, Qs, Xu, pXu, shape, dtype)
        has2 = jnp.isfinite(bkey)
        rows_tab, prow_tab = _row_table(rows, 6, dtype), _row_table(prow, 4, dtype)
        sel2 = _pick(sg(rows_tab), bid, shape)
        sel1 = _pick(sg(prow_tab), pid, shape)
    x, z2, end2 = _winning_root(dict(zip(("a", "b", "al", "be", "z0", "invf"), sel2)), Ys, qs, blo, bhi, zend,
                                has2, dtype)
    # Everything above is computed without gradients; ``_answer`` assembles k from the winners with the
    # derivatives of the closed forms (P1) and of the implicit function (P2 root).
    k = _answer(rows_tab, prow_tab, tuple(sel1), tuple(sel2), *(sg(v) for v in (x, z2, end2, has2, bid, has1, pid)),
                Y, q, th)
    k = jnp.where(pos, k, 0.0)
    return jnp.where(jnp.isnan(c) | jnp.isnan(theta) | jnp.isnan(e), jnp.nan, k)  # NaN in, NaN out (jit)


def _extrapolation_cap(T2, F, Ys, ms):
    """``(Xu, 10^-Xu)``: the extrapolation strip ends Xu decades above the top node, beyond which
    y >= min col_top + min_slope x > Y (see ``_exact_distance_impl``)."""
    sg = jax.lax.stop_gradient
    Tmin_top = T2[F - 1, 0]
    for j in range(1, T2.shape[1]):
        Tmin_top = jnp.minimum(Tmin_top, T2[F - 1, j])
    Xu = jnp.maximum(Ys - sg(Tmin_top), 0.0) * (1.0 / ms) + 0.01
    return Xu, jnp.exp(-_LN10 * Xu)


def _row_table(rows, width, dtype):
    """The winners' constants of the planned pieces (pairs) as a (n, width) table (one zero row if none)."""
    if not rows:
        return jnp.zeros((1, width), dtype)
    return jnp.stack([jnp.stack([jnp.asarray(v, dtype) for v in r]) for r in rows])


def _p1_planned(plan_pairs, plan_sb, pairs, freqs, Ys, qs, shape, dtype):
    """P1 (below the peak), closed form, over the planned pairs, without gradients (the winning pair's
    closed form is differentiated in ``_answer``): ``(e1, pid, prow)``, the smallest perceptible e'
    (``inf`` if none), the slot of its pair and the pairs' rows."""
    sg = jax.lax.stop_gradient
    e1 = jnp.full(shape, jnp.inf, dtype)
    pid = jnp.zeros(shape, jnp.int32)
    prow = []
    for slot, (n, sb) in enumerate(zip(plan_pairs, plan_sb)):
        p = pairs[n]
        prow.append((p["a"], p["b"], p["L"], 1.0 / freqs[p["node"]]))
        a, b, L, H, empty = (p[k] if isinstance(p[k], (float, bool)) else sg(p[k]) for k in ("a", "b", "L", "H", "empty"))
        lo = jnp.maximum(L, qs * (1.0 / freqs[p["node"]]))
        hi = H
        ok = jnp.logical_not(empty)
        if p["const"] or sb == 0.0:
            ok = ok & (a <= Ys)
        else:
            u = (Ys - a) / (b if sb is not None else jnp.where(b == 0, 1.0, b))
            if sb is None:
                hi = jnp.where(b > 0, jnp.minimum(hi, u), hi)
                lo = jnp.where(b < 0, jnp.maximum(lo, u), lo)
                ok = ok & ((b != 0) | (a <= Ys))
            elif sb > 0:
                hi = jnp.minimum(hi, u)
            else:
                lo = jnp.maximum(lo, u)
        take = ok & (lo <= hi) & (lo < e1)
        e1 = jnp.where(take, lo, e1)
        pid = jnp.where(take, slot, pid)
    return e1, pid, prow


def _p2_planned(plan_pieces, pieces, freqs, Ys, qs, Qs, Xu, pXu, shape, dtype):
    """P2 (the unclamped surface) over the planned pieces, without gradients: ``(bkey, zend, blo, bhi,
    bid, rows)``: the highest lower bracket end (log10 f) of a piece with a root, the highest perceptible
    piece end, the winning piece's bracket [blo, bhi] (local x), its slot, and the pieces' rows."""
    neg_inf = jnp.full(shape, -jnp.inf, dtype)
    bkey, zend = neg_inf, neg_inf
    blo = bhi = jnp.zeros(shape, dtype)
    bid = jnp.zeros(shape, jnp.int32)
    rows = []
    F = len(freqs)
    zf = [math.log10(f) for f in freqs]
    for slot, (n, wit, sG) in enumerate(plan_pieces):
        p = pieces[n]
        i = p["strip"]
        rows.append((p["a"], p["b"], p["al"], p["be"], zf[i], 1.0 / freqs[i]))
        ne, endp, xb, lo, crs = _piece_bracket(p, wit, sG, i == F - 1, freqs[i], zf[i], Ys, qs, Qs, Xu, pXu, dtype)
        zend = jnp.where(endp, _fmax(zend, zf[i] + xb), zend)
        key = zf[i] + lo
        better = ne & ~endp & crs & (key > bkey)
        bkey = jnp.where(better, key, bkey)
        blo = jnp.where(better, lo, blo)
        bhi = jnp.where(better, xb, bhi)
        bid = jnp.where(better, slot, bid)
    return bkey, zend, blo, bhi, bid, rows


def _piece_bracket(p, wit, sG, top, fi, zi, Ys, qs, Qs, Xu, pXu, dtype):
    """One planned piece: ``(ne, endp, xb, lo, crs)``: the path crosses it (``ne``), its upper end is
    perceptible (``endp``), its upper end ``xb`` and the lower end ``lo`` of the bracket of its root,
    and whether it holds a perceptible point below ``xb`` (``crs``); local x = z - z_i."""
    sg = jax.lax.stop_gradient
    E0, Qi = qs * (1.0 / fi), Qs - zi
    a, b, al, be, xlo, xhi, blo_e, bhi_e = (p[name] if isinstance(p[name], float) else sg(p[name])
                                            for name in ("a", "b", "al", "be", "xlo", "xhi", "lo", "hi"))
    # the path's x range inside the piece and e' at its ends (no transcendental per element)
    xa = xlo if _is_inf(bhi_e) else _fmax(xlo, _cut(Qi, bhi_e))
    xb = xhi if _is_zero(blo_e) else _fmin(xhi, _cut(Qi, blo_e))
    if top:
        xb = _fmin(xb, Xu)
    plo = 10.0 ** (-xlo) if isinstance(xlo, float) else jnp.exp(-_LN10 * xlo)
    phi = (10.0 ** (-xhi) if xhi != _INF else 0.0) if isinstance(xhi, float) else jnp.exp(-_LN10 * xhi)
    ea = E0 * plo
    if not _is_inf(bhi_e):
        ea = _fmin(ea, bhi_e)
    eb = E0 * (_fmax(phi, pXu) if top else phi)
    if not _is_zero(blo_e):
        eb = _fmax(eb, blo_e)
    ne = xa < xb
    A = a - Ys
    ha = A + b * ea + xa * (al + be * ea)
    hb = A + b * eb + xb * (al + be * eb)
    endp = ne & (hb <= 0)
    lo = xa
    crs = ha <= 0
    if wit:
        xr, hr = _window_witness(p, sG, A, b, al, be, xa, xb, xlo, xhi, ea, E0, dtype)
        win = hr <= 0
        lo = jnp.where(win, xr, xa)
        crs = crs | win
    return ne, endp, xb, lo, crs


def _window_witness(p, sG, A, b, al, be, xa, xb, xlo, xhi, ea, E0, dtype):
    """``(xr, h(xr))``: the local extremum of Phi that witnesses a window (see ``_exact_distance_impl``),
    closed form, clipped into [xa, xb]; any point of [xa, xb] is a sound test point, so degenerate roots
    need no special care."""
    sg = jax.lax.stop_gradient
    n0 = -A
    a2 = -_LN10 * al * be
    a1 = _LN10 * (be * n0 - al * b)
    a0 = n0 * (_LN10 * b - be) - al * b
    sd = jnp.sqrt(_fmax(a1 * a1 - 4.0 * a2 * a0, 0.0))
    if sG is None:
        s_pos = sg(p["sG"]) > 0
        first = jnp.where(s_pos, a1 <= 0, a1 >= 0)
        num = jnp.where(first, 2.0 * a0, jnp.where(s_pos, -a1 - sd, sd - a1))
        den = jnp.where(first, jnp.where(s_pos, sd - a1, -a1 - sd), 2.0 * a2)
    elif sG > 0:  # the maximum of Phi: (-a1 - sd) / (2 a2) = 2 a0 / (sd - a1)
        first = a1 <= 0
        num = jnp.where(first, 2.0 * a0, -a1 - sd)
        den = jnp.where(first, sd - a1, 2.0 * a2)
    else:  # the minimum of Phi: (sd - a1) / (2 a2) = 2 a0 / (-a1 - sd)
        first = a1 >= 0
        num = jnp.where(first, 2.0 * a0, sd - a1)
        den = jnp.where(first, -a1 - sd, 2.0 * a2)
    # jnp.maximum / minimum, not _fmax / _fmin: the division must have ONE consumer, else XLA
    # materializes it as a pass of its own (an expensive op feeding two fusions)
    xr = jnp.minimum(jnp.maximum(num / den, xa), xb)  # NaN (0/0) stays NaN and fails the test below
    if isinstance(xhi, float) and xhi != _INF:  # bounded piece: e' = ea 10^-(xr - xa), polynomial
        er = ea * _pow10_neg(xr - xa, xhi - (xlo if isinstance(xlo, float) else 0.0), dtype)
    else:
        er = E0 * jnp.exp(-_LN10 * xr)
    return xr, A + b * er + xr * (al + be * er)


def _winning_root(bsel, Ys, qs, blo, bhi, zend, has2, dtype):
    """The root in the winning piece (``_piece_root`` on its bracket): ``(x, z2, end2)``, the local root,
    sup P2 in log10 f, and whether a perceptible piece END lies above every root (then no gradient)."""
    sg = jax.lax.stop_gradient
    a, b, al, be = (sg(bsel[name]) for name in ("a", "b", "al", "be"))
    A = a - Ys
    E0 = qs * sg(bsel["invf"])
    bep = E0 * jnp.exp(-_LN10 * blo)
    bhlo = A + b * bep + blo * (al + be * bep)
    ehi = E0 * jnp.exp(-_LN10 * bhi)
    bhhi = A + b * ehi + bhi * (al + be * ehi)
    x = _piece_root(A, b, al, be, E0, blo, bhi, bhlo, bhhi, bep, ehi, _HALLEY[jnp.dtype(dtype).itemsize])
    z2 = jnp.maximum(jnp.where(has2, bsel["z0"] + x, -jnp.inf), zend)
    end2 = jnp.isfinite(zend) & (zend >= z2)
    return x, z2, end2


_jit_exact_distance = jax.jit(_exact_distance_impl, static_argnums=(0, 1, 2, 3))

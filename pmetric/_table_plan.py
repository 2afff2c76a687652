"""The static plan of the exact imperceptible-distance solve of a :class:`pmetric.CalibratedCSF`:
the geometry of the distance path in an (f x e) table (eccentricity bands, pieces, pairs) and, for a
concrete table, which pieces can matter (``_plan``, cached by value in ``_plan_cached``).
"""

from __future__ import annotations

import functools
import math

import jax
import numpy as np

_LN10 = math.log(10.0)

# ---------------------------------------------------------------------------------------------------
# Exact imperceptible_distance for (f x e) tables: geometry of the path in the table.
#
# Along the distance path (k > 0) the frequency is f = k / (2 theta) and the eccentricity e' = e / k, so
# f * e' = q = e / (2 theta) is constant: in log10 frequency z = log10 f the path is e'(z) = q 10^-z.
# Eccentricity "bands" are the e' intervals on which every node column is linear in e':
# col_i(e') = a_i + b_i e' (interpolation segments; constant columns beyond the first / last node).
# A "piece" is a band x frequency strip (x = z - z_i local, x in [0, dz_i]; the top strip x >= 0 is the
# extrapolation) further split where the extrapolation slope max(last(e'), min_slope) switches branch and
# where G(x) = b + beta x (the e'-slope of the surface) changes sign. On a piece the UNCLAMPED surface is
#     y~(x, e') = a + b e' + x (alpha + beta e')          (bilinear),
# so along the path h(x) = y~ - Y = (a - Y) + b e' + x (alpha + beta e'),  e' = E0 10^-x, E0 = q / f_i.
# ---------------------------------------------------------------------------------------------------

_INF = math.inf


def _bands(xp, T2, eccs):
    """[(lo, hi, a, b)]: e' in [lo, hi] (static floats), node columns a + b e' with a, b arrays of shape
    (F,) (``b`` None: constant columns). Array operations, so a traced table costs a few ops only."""
    F, E = T2.shape
    if E == 1:
        return [(0.0, _INF, T2[:, 0], None)]
    out = []
    if eccs[0] > 0:
        out.append((0.0, eccs[0], T2[:, 0], None))
    w = np.asarray([1.0 / (eccs[s + 1] - eccs[s]) for s in range(E - 1)])
    B = (T2[:, 1:] - T2[:, :-1]) * w[None, :]
    A = T2[:, :-1] - B * np.asarray(eccs[:-1])[None, :]
    for s in range(E - 1):
        out.append((eccs[s], eccs[s + 1], A[:, s], B[:, s]))
    out.append((eccs[-1], _INF, T2[:, E - 1], None))
    return out


def _argmin_intervals(xp, a, b, lo, hi):
    """For every node i the e' interval [L_i, H_i] (within [lo, hi]) on which i is the HIGHEST node of
    lowest column value a + b e', and a flag ``empty_i`` (equal-slope lines that exclude it everywhere).
    Closure: ties at the interval ends are included (harmless for a supremum)."""
    F = a.shape[0]
    lower = np.arange(F)[None, :] < np.arange(F)[:, None]  # [i, j]: j < i (ties allowed against lower j)
    other = np.arange(F)[None, :] != np.arange(F)[:, None]
    da = a[:, None] - a[None, :]
    excl = xp.where(lower, da > 0, da >= 0) & other  # node i loses to node j at every e' with equal slope
    if b is None:
        return xp.full((F,), lo) + 0 * a, xp.full((F,), hi) + 0 * a, xp.any(excl, axis=1)
    db = b[:, None] - b[None, :]
    bound = -da / xp.where(db == 0, 1.0, db)
    H = xp.minimum(hi, xp.min(xp.where((db > 0) & other, bound, _INF), axis=1))
    L = xp.maximum(lo, xp.max(xp.where((db < 0) & other, bound, -_INF), axis=1))
    return L, H, xp.any(excl & (db == 0), axis=1)


def _pieces(xp, T2, freqs, eccs, ms):
    """Every candidate piece (see above) with its constants, in a fixed order; xp is numpy (static plan)
    or jax.numpy (values)."""
    F = len(freqs)
    zf = np.log10(np.asarray(freqs, np.float64))
    dz = np.diff(zf)
    inv_dz = 1.0 / dz
    out = []
    for k, (lo, hi, a, b) in enumerate(_bands(xp, T2, eccs)):
        al = (a[1:] - a[:-1]) * inv_dz
        if b is not None:
            be = (b[1:] - b[:-1]) * inv_dz
            xg = xp.where(be == 0, dz, xp.clip(-b[:-1] / xp.where(be == 0, 1.0, be), 0.0, dz))
            g0 = xp.where(b[:-1] + be * (0.5 * xg) >= 0, 1.0, -1.0)  # G's sign on [0, xg] and [xg, dz]
            g1 = xp.where(b[:-1] + be * (0.5 * (xg + dz)) >= 0, 1.0, -1.0)
        for i in range(F - 1):
            if b is None:  # constant columns: h is linear in x
                out.append(dict(band=k, strip=i, sub=0, half=0, lo=lo, hi=hi, a=a[i], b=0.0, al=al[i], be=0.0,
                                xlo=0.0, xhi=float(dz[i]), sG=0.0, lin=True))
                continue
            base = dict(band=k, strip=i, sub=0, lo=lo, hi=hi, a=a[i], b=b[i], al=al[i], be=be[i], lin=False)
            # unsplit (used when the plan proves that no window can occur, see _needs_witness); then the
            # halves where G(x) = b + be x changes sign
            out.append(dict(base, half=-1, xlo=0.0, xhi=float(dz[i]), sG=0.0))
            out.append(dict(base, half=0, xlo=0.0, xhi=xg[i], sG=g0[i]))
            out.append(dict(base, half=1, xlo=xg[i], xhi=float(dz[i]), sG=g1[i]))
        # extrapolation strip: slope max(L0 + L1 e', ms) per log10 f
        i = F - 1
        L0 = al[F - 2]
        if b is None:
            out.append(dict(band=k, strip=i, sub=0, half=0, lo=lo, hi=hi, a=a[i], b=0.0, al=xp.maximum(L0, ms),
                            be=0.0, xlo=0.0, xhi=_INF, sG=0.0, lin=True))
            continue
        L1 = be[F - 2]
        esw = xp.where(L1 == 0, hi, xp.clip((ms - L0) / xp.where(L1 == 0, 1.0, L1), lo, hi))
        bi = b[i]
        for sub, (slo, shi) in enumerate(((lo, esw), (esw, hi))):
            mid = xp.where(xp.isfinite(shi), 0.5 * (slo + shi), slo + 1.0)
            mid = xp.where(xp.isfinite(mid), mid, 0.0)
            steep = L0 + L1 * mid >= ms
            al_, be_ = xp.where(steep, L0, ms), xp.where(steep, L1, 0.0)
            base = dict(band=k, strip=i, sub=sub, lo=slo, hi=shi, a=a[i], b=bi, al=al_, be=be_, lin=False)
            out.append(dict(base, half=-1, xlo=0.0, xhi=_INF, sG=0.0))
            xg = xp.where(be_ == 0, _INF, xp.maximum(-bi / xp.where(be_ == 0, 1.0, be_), 0.0))
            xm0 = xp.where(xp.isfinite(xg), 0.5 * xg, 1.0)
            out.append(dict(base, half=0, xlo=0.0, xhi=xg, sG=xp.where(bi + be_ * xm0 >= 0, 1.0, -1.0)))
            xm1 = xp.where(xp.isfinite(xg), xg + 1.0, 0.0)
            out.append(dict(base, half=1, xlo=xg, xhi=_INF, sG=xp.where(bi + be_ * xm1 >= 0, 1.0, -1.0)))
    return out


def _p1_pairs(xp, T2, eccs):
    """Every (band, node) pair with its argmin interval (see ``_argmin_intervals``)."""
    out = []
    for k, (lo, hi, a, b) in enumerate(_bands(xp, T2, eccs)):
        L, H, empty = _argmin_intervals(xp, a, b, lo, hi)
        for i in range(a.shape[0]):
            out.append(dict(band=k, node=i, a=a[i], b=(0.0 if b is None else b[i]), L=L[i], H=H[i],
                            empty=empty[i], const=b is None))
    return out


_TOL = 1e-9


def _needs_witness(p) -> bool:
    """False when h can have no interior local MINIMUM along any path through the piece (numpy values):
    h' = al + e' (be - ln10 b) - ln10 be e' x is bilinear on the box x in [xlo, xhi], e' in [lo, hi], so
    if it has one sign at the corners h is monotone; and h'' = ln10 e' (ln10 (b + be x) - 2 be) <= 0
    means h is concave. Either way the piece's perceptible points are decided by its end values (a
    single crossing at most), and no window witness is needed."""
    al, b, be = float(p["al"]), float(p["b"]), float(p["be"])
    xlo, xhi, elo, ehi = float(p["xlo"]), float(p["xhi"]), float(p["lo"]), float(p["hi"])
    if not math.isfinite(ehi):
        return True
    d = lambda x, e: al + e * (be - _LN10 * b) - _LN10 * be * e * x  # noqa: E731
    corners = [d(xlo, elo), d(xlo, ehi)]
    if math.isfinite(xhi):
        corners += [d(xhi, elo), d(xhi, ehi)]
        dmin, dmax = min(corners), max(corners)
        concave = max(_LN10 * (b + be * x) - 2.0 * be for x in (xlo, xhi)) <= 0
    else:  # x unbounded: the x term grows like -ln10 be e' x
        dmin = min(corners) if be <= 0 else -_INF
        dmax = max(corners) if be >= 0 else _INF
        concave = be <= 0 and _LN10 * (b + be * xlo) - 2.0 * be <= 0
    return not (dmin > 0 or dmax < 0 or concave)


def _plan(T2, freqs, eccs, ms):
    """Static solver plan for a CONCRETE (F, E) table: which pieces and P1 pairs can matter, and the
    G sign of each piece. Decisions use float64 with a small tolerance that only ever KEEPS more work:
    a dropped piece provably holds no point that is not also covered by another piece or by the
    below-peak (P1) set."""
    T2 = np.asarray(T2, dtype=np.float64)
    scale = _TOL * (1.0 + float(np.abs(T2).max()))
    pairs = _p1_pairs(np, T2, eccs)
    keep_pairs, min_node = [], {}
    for n, p in enumerate(pairs):
        lo_ok = bool(np.asarray(p["L"] <= p["H"] + scale * (1.0 + abs(p["H"]) if np.isfinite(p["H"]) else 1.0)))
        if p["const"]:
            # constant band: node i is the argmin iff its value is (within tolerance) the minimum and no
            # higher node ties it
            a = [q["a"] for q in pairs if q["band"] == p["band"]]
            i = p["node"]
            ok = a[i] <= min(a) + scale and all(a[j] > a[i] - scale for j in range(i + 1, len(a)))
        else:
            ok = lo_ok  # (the 'empty' flag of equal-slope lines is recomputed per call; keep when unsure)
        if ok:
            keep_pairs.append(n)
            min_node[p["band"]] = min(min_node.get(p["band"], 10**9), p["node"])
    pieces = _pieces(np, T2, freqs, eccs, ms)
    groups: dict = {}
    for n, p in enumerate(pieces):
        groups.setdefault((p["band"], p["strip"], p["sub"]), []).append(n)
    keep = []
    for (band, strip, _), idxs in groups.items():
        p0 = pieces[idxs[0]]
        if strip < len(freqs) - 1 and strip + 1 <= min_node.get(band, 10**9):
            continue  # the whole strip lies at or below the peak frequency in this band: P1 covers it
        if not float(p0["hi"]) > float(p0["lo"]) + _TOL:
            continue  # empty sub-band (up to 1e-9 deg: a negligible sliver)
        if p0["lin"] or (abs(float(p0["b"])) <= scale and abs(float(p0["be"])) <= scale):
            keep.append((idxs[0], False, 0.0))
        elif not _needs_witness(p0):
            keep.append((idxs[0], False, 0.0))
        else:
            for n in idxs[1:]:
                p = pieces[n]
                if float(p["xhi"]) > float(p["xlo"]) + _TOL:
                    keep.append((n, True, float(p["sG"])))
    sb = tuple(0.0 if pairs[n]["const"] else float(np.sign(pairs[n]["b"])) for n in keep_pairs)
    return tuple(keep), tuple(keep_pairs), sb

@functools.lru_cache(maxsize=64)
def _plan_from_bytes(data: bytes, shape, freqs, eccs, ms):
    return _plan(np.frombuffer(data, dtype=np.float64).reshape(shape), freqs, eccs, ms)


def _plan_cached(T2, freqs, eccs, ms):
    """The static plan of a concrete table (cached by value); ``None`` for a traced table (generic plan)."""
    if isinstance(T2, jax.core.Tracer):
        return None
    t = np.ascontiguousarray(np.asarray(T2, dtype=np.float64))
    return _plan_from_bytes(t.tobytes(), t.shape, freqs, eccs, ms)

"""Empirical CSF lookup table from a per-user calibration (Luebke & Hallen 2001, seed 004 sections 3.2, 6.1).

The table holds log10 threshold contrast on a grid of spatial frequency (cycles/deg) x eccentricity
(deg), optionally x retinal velocity (deg/s). Between nodes it is interpolated **linearly in
log10 threshold vs log10 frequency** and **linearly in eccentricity and velocity** (bilinear /
trilinear). Outside the grid:

* below the peak frequency (the frequency of the lowest threshold at that eccentricity and velocity)
  the threshold is the peak's: the conservative clamp of seed 004 section 6.1 ("clamp the threshold
  contrast below the most sensitive frequencies"). Frequencies below the table's lowest node are
  therefore clamped too;
* above the highest frequency node log10 threshold is extrapolated along the last segment's slope
  (in log10 c_T per log10 f), but with at least ``min_slope`` (default 1): the threshold keeps rising
  so every contrast has a finite highest visible frequency;
* eccentricity and velocity are clamped to the table's range (the edge values are used).

Evaluation is elementwise: eccentricity / velocity interpolation uses the ramp basis of ``_ramps``
with the table entries as broadcast scalars, the peak is a static running minimum over the (few)
frequency nodes, so ``is_perceptible``, ``sensitivity`` and ``threshold_frequency`` compile to one fused
kernel without per-element gathers.

Because the interpolated threshold at fixed eccentricity and velocity is piecewise linear in log f,
``threshold_frequency`` has an exact closed form per segment, and so has ``imperceptible_distance``
when the eccentricity and velocity are zero (or the table has a single eccentricity and no velocity
axis): ``k = 2 theta f_max(c)``. For (f x e) tables ``imperceptible_distance`` is solved exactly and
elementwise by ``_exact_distance_impl`` (closed forms below the peak and per bilinear piece of the
table, a window test from a quadratic, one bracketed root by Halley steps; the proof is in its docstring).
Tables with a velocity axis of two or more nodes queried at non-zero velocity use the slower
table-aware scan ``_eccentric_distance_impl``.
"""

from __future__ import annotations

import functools
import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._base import CSFModel, _log_guard, check_inputs
from ._data import CalibrationData

__all__ = ["CalibratedCSF"]

_LN10 = math.log(10.0)


def _axis(name: str, values, *, positive: bool, allow_none=False) -> tuple[float, ...] | None:
    if values is None:
        if allow_none:
            return None
        raise ValueError(f"CalibratedCSF: {name} must be given")
    if isinstance(values, jax.core.Tracer):
        raise ValueError(f"CalibratedCSF: grid axis {name} must be concrete (it is a static field), not traced")
    a = np.asarray(values, dtype=np.float64)
    if a.ndim != 1 or a.size == 0:
        raise ValueError(f"CalibratedCSF: {name} must be a non-empty 1-D sequence, got shape {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"CalibratedCSF: {name} contains NaN or infinite values")
    if positive and (a <= 0).any():
        raise ValueError(f"CalibratedCSF: {name} must be > 0")
    if (a < 0).any():
        raise ValueError(f"CalibratedCSF: {name} must be >= 0")
    if (np.diff(a) <= 0).any():
        raise ValueError(f"CalibratedCSF: {name} must be strictly increasing, got {a.tolist()}")
    return tuple(float(x) for x in a)


def _ramps(x, nodes):
    """Clamped fractions ``clip((x - n_s) / (n_{s+1} - n_s), 0, 1)`` of ``x`` on every segment of a static
    node tuple: the ramp basis of piecewise-linear interpolation with constant extension,
    ``value(x) = v_0 + sum_s (v_{s+1} - v_s) r_s(x)``. Elementwise (no gathers), so it fuses."""
    return [jnp.clip((x - nodes[s]) * (1.0 / (nodes[s + 1] - nodes[s])), 0.0, 1.0) for s in range(len(nodes) - 1)]


def _ramp_interp(vals, ramps):
    """``vals[0] + sum_s (vals[s+1] - vals[s]) * ramps[s]`` (node values are scalars or arrays)."""
    acc = vals[0]
    for s, r in enumerate(ramps):
        acc = acc + (vals[s + 1] - vals[s]) * r
    return acc


def _running_peak(cols, values):
    """Static running minimum over the node columns from the top node down: ``(yp, value_p)`` where
    ``yp`` is the lowest column value and ``value_p`` is ``values[p]`` for p, the HIGHEST node attaining it
    (a strict ``<`` keeps the higher node on ties)."""
    yp, vp = cols[-1], values[-1]
    for i in range(len(cols) - 2, -1, -1):
        better = cols[i] < yp
        yp = jnp.where(better, cols[i], yp)
        vp = jnp.where(better, values[i], vp)
    return yp, vp


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

class CalibratedCSF(CSFModel):
    """Threshold-contrast lookup table, a :class:`CSFModel` (seed 004 section 6.1).

    Fields:

    * ``log_thresholds`` (array, fittable): log10 threshold Michelson contrast, shape (F, E) or
      (F, E, V) for frequencies x eccentricities [x velocities].
    * ``freqs`` (static tuple, F >= 2, cycles/deg, > 0, increasing), ``eccs`` (static, E >= 1, deg),
      ``vels`` (static or None, V >= 1, deg/s), ``min_slope`` (static float > 0: least slope of log10
      c_T per log10 f used above the top frequency node).

    ``CalibratedCSF(freqs, eccs, log_thresholds, vels=None, min_slope=1.0)``; or
    :meth:`from_data` / :meth:`from_csv` from calibration rows. See the module docstring for the
    interpolation and clamping rules.
    """

    log_thresholds: jax.Array
    freqs: tuple[float, ...] = eqx.field(static=True)
    eccs: tuple[float, ...] = eqx.field(static=True)
    vels: tuple[float, ...] | None = eqx.field(static=True, default=None)
    min_slope: float = eqx.field(static=True, default=1.0)

    inputs: ClassVar[tuple[str, ...]] = ("f", "e", "v")
    param_bounds: ClassVar[dict[str, tuple[float | None, float | None]]] = {"log_thresholds": (None, None)}

    def __init__(self, freqs, eccs, log_thresholds, vels=None, min_slope: float = 1.0):
        self.freqs = _axis("freqs (cycles/deg)", freqs, positive=True)
        self.eccs = _axis("eccs (deg)", eccs, positive=False)
        self.vels = _axis("vels (deg/s)", vels, positive=False, allow_none=True)
        if len(self.freqs) < 2:
            raise ValueError("CalibratedCSF: need at least 2 frequency nodes")
        try:
            ms = float(min_slope)
        except (TypeError, ValueError):
            raise ValueError(f"CalibratedCSF: min_slope must be a number, got {min_slope!r}") from None
        if not (ms > 0 and math.isfinite(ms)):
            raise ValueError(f"CalibratedCSF: min_slope must be > 0 and finite, got {min_slope!r}")
        self.min_slope = ms
        t = jnp.asarray(log_thresholds)
        if not jnp.issubdtype(t.dtype, jnp.floating) or t.weak_type:
            t = t.astype(jnp.result_type(float))
        want = (len(self.freqs), len(self.eccs)) + ((len(self.vels),) if self.vels is not None else ())
        if t.shape != want:
            raise ValueError(f"CalibratedCSF: log_thresholds must have shape (F, E{', V' if self.vels else ''}) = "
                             f"{want}, got {t.shape}")
        if not isinstance(t, jax.core.Tracer):
            tn = np.asarray(t)
            if not np.isfinite(tn).all():
                idx = tuple(int(i) for i in np.argwhere(~np.isfinite(tn))[0])
                raise ValueError(f"CalibratedCSF: log_thresholds has a NaN or infinite entry at index {idx}")
        self.log_thresholds = t

    # ------------------------------------------------------------------ construction from data
    @classmethod
    def from_data(cls, data: CalibrationData, freqs=None, eccs=None, vels=None, *, rtol_f: float = 0.1,
                  atol_e: float = 0.5, atol_v: float = 0.5, min_slope: float = 1.0) -> "CalibratedCSF":
        """Bin calibration rows onto a grid and average duplicates (N-weighted mean of log10 thresholds).

        ``freqs`` / ``eccs`` / ``vels``: grid axes; ``None`` (freqs, eccs) uses the distinct values in
        the data. ``vels=None`` builds a table without a velocity axis and requires every row to be
        static (velocity 0); ``vels="auto"`` uses the distinct velocities. A row is assigned to the
        nearest node; it must lie within ``rtol_f`` (relative, frequency), ``atol_e`` (deg) or
        ``atol_v`` (deg/s) of it. Rows at frequency 0 (disks) cannot be placed. Raises ValueError naming
        the first row that fits no node and, when the data cannot fill the grid, the empty cells.
        Rows are pooled regardless of luminance / area / dataset: select them first with ``subset``.
        """
        if not isinstance(data, CalibrationData):
            raise ValueError(f"CalibratedCSF.from_data: expected CalibrationData, got {type(data).__name__}")
        if len(data) == 0:
            raise ValueError("CalibratedCSF.from_data: no calibration rows")
        if (data.f <= 0).any():
            i = int(np.argmax(data.f <= 0))
            raise ValueError(f"CalibratedCSF.from_data: row {i} has spatial frequency 0 (a disk stimulus); "
                             "a frequency table cannot place it: drop it with subset(data.f > 0)")

        def distinct(x, rtol, atol):
            u = np.unique(x)
            keep = [u[0]]
            for val in u[1:]:
                if val - keep[-1] > max(atol, rtol * abs(keep[-1])):
                    keep.append(val)
            return keep

        fr = distinct(data.f, 1e-6, 0.0) if freqs is None else freqs
        ec = distinct(data.e, 0.0, 1e-9) if eccs is None else eccs
        use_v = vels is not None
        if isinstance(vels, str):
            if vels != "auto":
                raise ValueError(f"CalibratedCSF.from_data: vels must be None, 'auto' or a sequence, got {vels!r}")
            vels = distinct(data.velocity, 0.0, 1e-9)
        if not use_v and (data.velocity > 0).any():
            i = int(np.argmax(data.velocity > 0))
            raise ValueError(f"CalibratedCSF.from_data: row {i} has velocity {data.velocity[i]:.4g} deg/s but the "
                             "table has no velocity axis; pass vels='auto' (or a grid) or select static rows")
        fr = np.asarray(_axis("freqs (cycles/deg)", fr, positive=True))
        ec = np.asarray(_axis("eccs (deg)", ec, positive=False))
        axes = [(fr, np.log(data.f), np.log(fr), np.log1p(rtol_f), "frequency", "cycles/deg", data.f),
                (ec, data.e, ec, atol_e, "eccentricity", "deg", data.e)]
        if use_v:
            vv = np.asarray(_axis("vels (deg/s)", vels, positive=False))
            axes.append((vv, data.velocity, vv, atol_v, "velocity", "deg/s", data.velocity))
        idx = []
        for nodes, x, xn, tol, what, unit, raw in axes:
            j = np.argmin(np.abs(x[:, None] - xn[None, :]), axis=1)
            bad = np.abs(x - xn[j]) > tol
            if bad.any():
                i = int(np.argmax(bad))
                raise ValueError(f"CalibratedCSF.from_data: row {i} at {what} {raw[i]:.4g} {unit} is not within "
                                 f"tolerance of any grid node {nodes.tolist()}")
            idx.append(j)
        shape = tuple(len(a[0]) for a in axes)
        flat = np.ravel_multi_index(tuple(idx), shape)
        w = data.weights
        wsum = np.bincount(flat, weights=w, minlength=int(np.prod(shape)))
        ysum = np.bincount(flat, weights=w * data.log_threshold, minlength=int(np.prod(shape)))
        empty = wsum == 0
        if empty.any():
            cells = np.argwhere(empty.reshape(shape))[:5]
            names = ["f", "e", "v"]
            desc = "; ".join(", ".join(f"{names[k]}={axes[k][0][c[k]]:.4g}" for k in range(len(shape))) for c in cells)
            raise ValueError(f"CalibratedCSF.from_data: the data cannot fill the grid: {int(empty.sum())} of "
                             f"{empty.size} cells have no rows (e.g. {desc})")
        table = (ysum / wsum).reshape(shape)
        return cls(fr, ec, table, vels=vv if use_v else None, min_slope=min_slope)

    @classmethod
    def from_csv(cls, path, **kwargs) -> "CalibratedCSF":
        """``from_data(CalibrationData.from_csv(path), **kwargs)``."""
        return cls.from_data(CalibrationData.from_csv(path), **kwargs)

    # ------------------------------------------------------------------ the interpolated curve
    def _zf(self) -> list[float]:
        return [math.log10(f) for f in self.freqs]

    def _node_columns(self, e, v, shape, dtype):
        """Interpolated log10 threshold at every frequency node for (e, v): a list of F arrays of ``shape``.

        Elementwise: eccentricity (and velocity) enter through the ramp basis of ``_ramps`` and the table
        entries are scalars broadcast into the batch, so no per-element gather is needed."""
        T = self.log_thresholds.astype(dtype)
        F, E = len(self.freqs), len(self.eccs)
        re = _ramps(jnp.broadcast_to(e, shape).astype(dtype), self.eccs)
        if self.vels is None:
            cols = [_ramp_interp([T[i, j] for j in range(E)], re) for i in range(F)]
        else:
            rv = _ramps(jnp.broadcast_to(v, shape).astype(dtype), self.vels)
            V = len(self.vels)
            cols = [_ramp_interp([_ramp_interp([T[i, j, l] for l in range(V)], rv) for j in range(E)], re)
                    for i in range(F)]
        return [jnp.broadcast_to(col, shape) for col in cols]

    def _curve(self, cols, lf):
        """log10 threshold at log10 frequency ``lf`` from the node columns (peak clamp, interpolation,
        extrapolation of the module docstring), elementwise."""
        zf = self._zf()
        F = len(zf)
        yp, zp = _running_peak(cols, zf)
        y = _ramp_interp(cols, _ramps(lf, zf))
        last = (cols[-1] - cols[-2]) * (1.0 / (zf[-1] - zf[-2]))
        y = y + jnp.maximum(last, self.min_slope) * jnp.maximum(lf - zf[F - 1], 0.0)
        return jnp.where(lf < zp, yp, y)  # below the peak: the peak's threshold (equal to y at lf = zp)

    def _log10_threshold(self, f, e, v):
        shape = jnp.broadcast_shapes(jnp.shape(f), jnp.shape(e), jnp.shape(v))
        dtype = jnp.result_type(f, e, v, self.log_thresholds)
        cols = self._node_columns(e, v, shape, dtype)
        f = jnp.broadcast_to(f, shape).astype(dtype)
        pos = f > 0
        lf = jnp.where(pos, jnp.log10(jnp.where(pos, f, 1.0)), math.log10(self.freqs[0]) - 1.0)  # f = 0: below
        return self._curve(cols, lf)

    def log_sensitivity(self, f, e=0.0, v=0.0):
        """ln S = -ln(10) * (interpolated log10 threshold), broadcast shape of f, e, v."""
        f, e, v = (jnp.asarray(x) for x in (f, e, v))
        return -_LN10 * _jit_log10_threshold(self, f, e, v)

    def sensitivity(self, f, e=0.0, v=0.0):
        """S = 1 / c_T from the table at f (cycles/deg), e (deg), v (deg/s)."""
        f, e, v = check_inputs("sensitivity", f=f, e=e, v=v)
        return jnp.exp(self.log_sensitivity(f, e, v))

    def is_perceptible(self, c, f, e=0.0, v=0.0):
        """``c >= c_T(max(f, f_peak(e, v)), e, v)`` (see :meth:`CSFModel.is_perceptible`): one fused
        elementwise kernel (the table clamp below the peak is the base class's ``max(f, f_peak)``)."""
        c, f, e, v = check_inputs("is_perceptible", c=c, f=f, e=e, v=v)
        self = self._like(c, f, e, v)
        return _jit_perceptible(self, c, f, e, v)

    def _perceptible_impl(self, c, f, e, v):
        shape = jnp.broadcast_shapes(c.shape, f.shape, e.shape, v.shape)
        dtype = jnp.result_type(c, f, e, v, self.log_thresholds)
        cols = self._node_columns(e, v, shape, dtype)
        lf = jnp.log10(jnp.broadcast_to(f, shape).astype(dtype))  # f = 0 -> -inf: clamped to the peak
        y = self._curve(cols, lf)
        return _log_guard(jnp.broadcast_to(c, shape).astype(dtype)) + (-_LN10 * y) >= 0

    def _peak_frequency(self, e, v):
        shape = jnp.broadcast_shapes(jnp.shape(e), jnp.shape(v))
        dtype = jnp.result_type(e, v, self.log_thresholds)
        return _jit_peak(self, jnp.asarray(e), jnp.asarray(v), shape, dtype)

    def _peak_impl(self, e, v, shape, dtype):
        cols = self._node_columns(e, v, shape, dtype)
        _, fp = _running_peak([jax.lax.stop_gradient(col) for col in cols], [jnp.asarray(f, dtype) for f in self.freqs])
        return jnp.broadcast_to(fp, shape)

    # ------------------------------------------------------------------ exact inversions
    def _eccentric_distance(self, c, theta, e, v):
        return _jit_eccentric_distance(self, c, theta, e, v)

    def _threshold_frequency(self, c, e, v):
        return _jit_threshold_frequency(self, c, e, v)

    def _threshold_frequency_impl(self, c, e, v):
        shape = jnp.broadcast_shapes(c.shape, e.shape, v.shape)
        dtype = jnp.result_type(c, e, v, self.log_thresholds)
        cols = self._node_columns(e, v, shape, dtype)
        zf = self._zf()
        F = len(zf)
        yp, zp = _running_peak(cols, zf)
        colc = [jnp.where(zf[i] <= zp, yp, cols[i]) for i in range(F)]  # clamped below the peak
        c = jnp.broadcast_to(c, shape).astype(dtype)
        cpos = c > 0
        Y = jnp.where(cpos, jnp.log10(jnp.where(cpos, c, 1.0)), 0.0)
        visible = cpos & (Y >= yp)
        slope = jnp.maximum((colc[-1] - colc[-2]) * (1.0 / (zf[-1] - zf[-2])), self.min_slope)
        # above the table: colc_top + slope (lf - lf_top) = Y
        on_ext = Y >= colc[-1]
        lf_ext = zf[-1] + jnp.where(on_ext, Y - colc[-1], 0.0) / slope
        # inside: the crossing in the segment [j, j+1] of the LAST node j <= F-2 with colc_j <= Y
        lf_in = jnp.full(shape, zf[0], dtype)
        for j in range(F - 1):
            den = colc[j + 1] - colc[j]
            ok = den > 0
            t = jnp.clip(jnp.where(ok, (Y - colc[j]) / jnp.where(ok, den, 1.0), 0.0), 0.0, 1.0)
            lf_in = jnp.where(colc[j] <= Y, zf[j] + t * (zf[j + 1] - zf[j]), lf_in)
        lf_star = jnp.where(visible, jnp.where(on_ext, lf_ext, lf_in), 0.0)
        return jnp.where(visible, 10.0 ** lf_star, 0.0)

    def imperceptible_distance(self, c, theta, e=0.0, v=0.0):
        """Viewing-distance multiple beyond which the change is imperceptible (see ``CSFModel``).

        ``k = 2 theta threshold_frequency(c)`` when the table does not depend on the eccentricity /
        velocity of the query (single eccentricity node and no more than one velocity node) or when
        ``e`` and ``v`` are concrete zeros. Otherwise, for (f x e) tables (and tables with a velocity axis
        queried at a concrete zero ``v``), the exact elementwise solver ``_exact_distance_impl`` (its
        docstring has the method and the proof that it returns the LARGEST perceptible k): exact to
        rounding, about 50 M evaluations/s in float32 on 2 CPU cores for a 6 x 3 table. A concrete table
        gets a static plan (``_plan``: pieces that cannot matter are dropped at trace time); a traced
        table (under a gradient with respect to it) runs the same tests on every piece in loops.
        Tables with a velocity axis (V >= 2) queried at non-zero ``v`` use the slower table-aware scan
        ``_eccentric_distance_impl`` (a perceptible window narrower than 1/``_SUBDIV`` of a breakpoint
        interval can be missed there). Gradients: closed forms where the answer is a closed form, the
        implicit-function derivative -h_p / h_x of the local margin where it is a root; with respect to
        ``c``, ``theta``, ``e``, ``v`` and ``log_thresholds``.
        """
        c, theta, e, v = check_inputs("imperceptible_distance", c=c, theta=theta, e=e, v=v)
        indep = len(self.eccs) == 1 and (self.vels is None or len(self.vels) == 1)
        v_zero = not isinstance(v, jax.core.Tracer) and not np.asarray(v).any()
        e_zero = not isinstance(e, jax.core.Tracer) and not np.asarray(e).any()
        shape = jnp.broadcast_shapes(c.shape, theta.shape, e.shape, v.shape)
        dtype = jnp.result_type(c, theta, e, v, self.log_thresholds)
        if indep or (e_zero and v_zero):
            fmax = self._threshold_frequency(jnp.broadcast_to(c, shape), e, v)
            return (2.0 * jnp.broadcast_to(theta, shape) * fmax).astype(dtype)
        if self.vels is not None and len(self.vels) > 1 and not v_zero:
            return self._eccentric_distance(c, theta, e, v)
        T2 = self.log_thresholds if self.vels is None else self.log_thresholds[..., 0]
        plan = _plan_cached(T2, self.freqs, self.eccs, self.min_slope)
        k = _jit_exact_distance(plan, self.freqs, self.eccs, self.min_slope, T2, c, theta, e)
        return jnp.broadcast_to(k, shape).astype(dtype)


_SUBDIV = 16


def _eccentric_distance_impl(m: CalibratedCSF, c, theta, e, v):
    from ._inverse import bracketed_root, implicit_root

    shape = jnp.broadcast_shapes(c.shape, theta.shape, e.shape, v.shape)
    dtype = jnp.result_type(c, theta, e, v, m.log_thresholds)
    c, theta, e, v = (jnp.broadcast_to(x, shape).astype(dtype) for x in (c, theta, e, v))
    pos = theta > 0
    th = jnp.where(pos, theta, 1.0)
    sg = jax.lax.stop_gradient
    cpos = c > 0
    Y = sg(jnp.where(cpos, jnp.log10(jnp.where(cpos, c, 1.0)), -1e3))
    lf = np.log10(np.asarray(m.freqs))
    tmin_last = sg(jnp.min(m.log_thresholds[-1]).astype(dtype))
    lf_hi = lf[-1] + jnp.maximum(Y - tmin_last, 0.0) / m.min_slope + 0.01
    l2t = sg(jnp.log(2.0 * th))
    w_lo = l2t + (lf[0] - 3.0) * _LN10
    w_hi = l2t + lf_hi * _LN10
    bps = [w_lo, w_hi] + [l2t + math.log(fi) for fi in m.freqs]
    for x, nodes in ((e, m.eccs), (v, m.vels or ())):
        xs = sg(x)
        xpos = xs > 0
        for n in nodes:
            if n > 0:
                bps.append(jnp.where(xpos, jnp.log(jnp.where(xpos, xs, 1.0)) - math.log(n), w_lo))
    bps = jnp.sort(jnp.clip(jnp.stack(bps, axis=-1), w_lo[..., None], w_hi[..., None]), axis=-1)
    nb = bps.shape[-1]
    G = (nb - 1) * _SUBDIV + 1

    def point(j):
        i = jnp.minimum(j // _SUBDIV, nb - 2)
        t = (j - i * _SUBDIV).astype(dtype) / _SUBDIV
        a = jnp.take_along_axis(bps, i[..., None], axis=-1)[..., 0]
        b = jnp.take_along_axis(bps, (i + 1)[..., None], axis=-1)[..., 0]
        return a + t * (b - a)

    def g(w):
        return m._distance_margin(jnp.exp(w), c, th, e, v)

    def g_sg(w):
        return sg(m._distance_margin(jnp.exp(w), sg(c), sg(th), sg(e), sg(v)))

    def scan(j, last):
        jj = jnp.full(shape, j, jnp.int32)
        return jnp.where(g_sg(point(jj)) >= 0, jj, last)

    last = jax.lax.fori_loop(0, G, scan, jnp.full(shape, -1, jnp.int32))
    found = (last >= 0) & cpos & pos
    saturated = last == G - 1
    a = point(jnp.maximum(last, 0))
    b = point(jnp.minimum(jnp.maximum(last, 0) + 1, G - 1))
    root = bracketed_root(g_sg, a, jnp.maximum(b, a + 1e-6))
    ok = found & ~saturated
    w = implicit_root(g, jnp.where(ok, root, a), mask=ok)
    w = jnp.where(saturated, w_hi, w)
    return jnp.where(found, jnp.exp(w), 0.0).astype(dtype)


@functools.lru_cache(maxsize=64)
def _plan_from_bytes(data: bytes, shape, freqs, eccs, ms):
    return _plan(np.frombuffer(data, dtype=np.float64).reshape(shape), freqs, eccs, ms)


def _plan_cached(T2, freqs, eccs, ms):
    """The static plan of a concrete table (cached by value); ``None`` for a traced table (generic plan)."""
    if isinstance(T2, jax.core.Tracer):
        return None
    t = np.ascontiguousarray(np.asarray(T2, dtype=np.float64))
    return _plan_from_bytes(t.tobytes(), t.shape, freqs, eccs, ms)


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
    F = len(freqs)
    zf = [math.log10(f) for f in freqs]
    pos = theta > 0
    th = jnp.where(pos, theta, 1.0)
    Y = jnp.log10(jnp.maximum(c, 1e-30))
    q = jnp.minimum(e / (2.0 * th), 1e30)
    Ys, qs = sg(Y), sg(q)
    Qs = jnp.log10(qs)  # -inf at e = 0: handled (every band edge term is guarded)
    pieces = _pieces(jnp, T2, freqs, eccs, ms)
    pairs = _p1_pairs(jnp, T2, eccs)
    Tmin_top = T2[F - 1, 0]
    for j in range(1, T2.shape[1]):
        Tmin_top = jnp.minimum(Tmin_top, T2[F - 1, j])
    Xu = jnp.maximum(Ys - sg(Tmin_top), 0.0) * (1.0 / ms) + 0.01
    pXu = jnp.exp(-_LN10 * Xu)
    if plan is None:  # traced table: every piece and pair, in loops (the same tests, decided per call)
        e1, pid, prow_tab, bkey, zend, blo, bhi, bid, rows_tab = _generic_search(
            pieces, pairs, freqs, Ys, qs, Qs, Xu, pXu, shape, dtype)
        plan_pieces = plan_pairs = plan_sb = ()
    else:
        plan_pieces, plan_pairs, plan_sb = plan

    # ---------------------------------------------------------------- P1: below the peak, closed form
    # (found without gradients; the winning pair's closed form is differentiated below)
    if plan is not None:
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
    has1 = jnp.isfinite(e1) & (e1 > 0)

    # ---------------------------------------------------------------- P2: pieces of the unclamped surface
    if plan is not None:
        neg_inf = jnp.full(shape, -jnp.inf, dtype)
        bkey, zend = neg_inf, neg_inf
        blo = bhi = jnp.zeros(shape, dtype)
        bid = jnp.zeros(shape, jnp.int32)
    rows = []
    for slot, (n, wit, sG) in enumerate(plan_pieces):
        p = pieces[n]
        i = p["strip"]
        top = i == F - 1
        rows.append((p["a"], p["b"], p["al"], p["be"], zf[i], 1.0 / freqs[i]))
        E0, Qi = qs * (1.0 / freqs[i]), Qs - zf[i]
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
        zend = jnp.where(endp, _fmax(zend, zf[i] + xb), zend)
        lo, hlo, elo = xa, ha, ea
        crs = ha <= 0
        if wit:
            # the local extremum of Phi that witnesses a window (see the docstring), closed form; any
            # point of [xa, xb] is a sound test point, so degenerate roots need no special care
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
            hr = A + b * er + xr * (al + be * er)
            win = hr <= 0
            lo = jnp.where(win, xr, xa)
            hlo = jnp.where(win, hr, ha)
            elo = jnp.where(win, er, ea)
            crs = crs | win
        key = zf[i] + lo
        better = ne & ~endp & crs & (key > bkey)
        bkey = jnp.where(better, key, bkey)
        blo = jnp.where(better, lo, blo)
        bhi = jnp.where(better, xb, bhi)
        bid = jnp.where(better, slot, bid)
    has2 = jnp.isfinite(bkey)
    if plan is not None:
        rows_tab = jnp.stack([jnp.stack([jnp.asarray(v, dtype) for v in r]) for r in rows]) if rows \
            else jnp.zeros((1, 6), dtype)
        prow_tab = jnp.stack([jnp.stack([jnp.asarray(v, dtype) for v in r]) for r in prow]) if prow \
            else jnp.zeros((1, 4), dtype)
        sel2 = _pick(sg(rows_tab), bid, shape)
        sel1 = _pick(sg(prow_tab), pid, shape)
    else:  # (the loops have split the kernel already: a gather is cheaper than long select chains)
        sel2 = [v[..., 0] for v in jnp.split(jnp.take(sg(rows_tab), bid, axis=0), 6, axis=-1)]
        sel1 = [v[..., 0] for v in jnp.split(jnp.take(sg(prow_tab), pid, axis=0), 4, axis=-1)]
    bsel = dict(zip(("a", "b", "al", "be", "z0", "invf"), sel2))

    # ---------------------------------------------------------------- the root in the winning piece
    a, b, al, be = (sg(bsel[name]) for name in ("a", "b", "al", "be"))
    A = a - Ys
    E0 = qs * sg(bsel["invf"])
    bep = E0 * jnp.exp(-_LN10 * blo)
    bhlo = A + b * bep + blo * (al + be * bep)
    ehi = E0 * jnp.exp(-_LN10 * bhi)
    bhhi = A + b * ehi + bhi * (al + be * ehi)
    x = _piece_root(A, b, al, be, E0, blo, bhi, bhlo, bhhi, bep, ehi, _HALLEY[jnp.dtype(dtype).itemsize])
    z2 = jnp.maximum(jnp.where(has2, bsel["z0"] + x, -jnp.inf), zend)
    end2 = jnp.isfinite(zend) & (zend >= z2)  # a perceptible piece END above every root: no gradient
    # Everything above is computed without gradients; ``_answer`` assembles k from the winners with the
    # derivatives of the closed forms (P1) and of the implicit function (P2 root).
    k = _answer(rows_tab, prow_tab, tuple(sel1), tuple(sel2), *(sg(v) for v in (x, z2, end2, has2, bid, has1, pid)),
                Y, q, th)
    k = jnp.where(pos, k, 0.0)
    return jnp.where(jnp.isnan(c) | jnp.isnan(theta) | jnp.isnan(e), jnp.nan, k)  # NaN in, NaN out (jit)


# One compiled graph per (shape, dtype) instead of dozens of eagerly dispatched ops; nested inside an
# outer jit / grad these calls are simply inlined.
_jit_log10_threshold = eqx.filter_jit(lambda m, f, e, v: m._log10_threshold(f, e, v))
_jit_perceptible = eqx.filter_jit(lambda m, c, f, e, v: m._perceptible_impl(c, f, e, v))
_jit_peak = eqx.filter_jit(lambda m, e, v, shape, dtype: m._peak_impl(e, v, shape, dtype))
_jit_threshold_frequency = eqx.filter_jit(lambda m, c, e, v: m._threshold_frequency_impl(c, e, v))
_jit_eccentric_distance = eqx.filter_jit(_eccentric_distance_impl)
_jit_exact_distance = jax.jit(_exact_distance_impl, static_argnums=(0, 1, 2, 3))

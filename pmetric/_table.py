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

Because the interpolated threshold at fixed eccentricity and velocity is piecewise linear in log f,
``threshold_frequency`` has an exact closed form per segment, and so has ``imperceptible_distance``
when the eccentricity and velocity are zero (or the table has a single eccentricity and no velocity
axis): ``k = 2 theta f_max(c)``. Other cases use the base class's generic exact solver.
"""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._base import CSFModel, check_inputs
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


def _weights(x, nodes):
    """Segment index (..., int) and clamped fraction in [0, 1] of ``x`` on a static node tuple."""
    n = len(nodes)
    if n == 1:
        return jnp.zeros(jnp.shape(x), jnp.int32), jnp.zeros(jnp.shape(x), x.dtype)
    nd = jnp.asarray(nodes, dtype=x.dtype)
    i = jnp.clip(jnp.searchsorted(nd, x, side="right") - 1, 0, n - 2)
    x0, x1 = nd[i], nd[i + 1]
    t = jnp.clip((x - x0) / (x1 - x0), 0.0, 1.0)
    return i, t


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
    def _columns(self, e, v, shape, dtype):
        """Clamped log10 threshold at every frequency node for (e, v): (shape + (F,)), peak index, slope."""
        T = self.log_thresholds.astype(dtype)
        T = jnp.moveaxis(T, 0, -1)  # (E, [V,] F)
        e = jnp.broadcast_to(e, shape).astype(dtype)
        ie, te = _weights(e, self.eccs)
        E = len(self.eccs)
        ie1 = jnp.minimum(ie + 1, E - 1)
        if self.vels is None:
            col = T[ie] * (1 - te)[..., None] + T[ie1] * te[..., None]
        else:
            v = jnp.broadcast_to(v, shape).astype(dtype)
            iv, tv = _weights(v, self.vels)
            iv1 = jnp.minimum(iv + 1, len(self.vels) - 1)
            a = T[ie, iv] * (1 - tv)[..., None] + T[ie, iv1] * tv[..., None]
            b = T[ie1, iv] * (1 - tv)[..., None] + T[ie1, iv1] * tv[..., None]
            col = a * (1 - te)[..., None] + b * te[..., None]
        F = len(self.freqs)
        # peak = the HIGHEST node with the lowest threshold; the curve is flat at its value below it
        p = (F - 1) - jnp.argmin(jax.lax.stop_gradient(col)[..., ::-1], axis=-1)
        yp = jnp.take_along_axis(col, p[..., None], axis=-1)
        col = jnp.where(jnp.arange(F) <= p[..., None], yp, col)
        lf = jnp.log10(jnp.asarray(self.freqs, dtype))
        last = (col[..., -1] - col[..., -2]) / (lf[-1] - lf[-2])
        slope = jnp.maximum(last, self.min_slope)
        return col, p, slope

    def _log10_threshold(self, f, e, v):
        shape = jnp.broadcast_shapes(jnp.shape(f), jnp.shape(e), jnp.shape(v))
        dtype = jnp.result_type(f, e, v, self.log_thresholds)
        col, p, slope = self._columns(e, v, shape, dtype)
        f = jnp.broadcast_to(f, shape).astype(dtype)
        lf_nodes = jnp.asarray(self.freqs, dtype)
        lf_nodes = jnp.log10(lf_nodes)
        pos = f > 0
        lf = jnp.where(pos, jnp.log10(jnp.where(pos, f, 1.0)), lf_nodes[0] - 1.0)  # f = 0: below the table
        j, t = _weights(lf, tuple(float(x) for x in np.log10(self.freqs)))
        y0 = jnp.take_along_axis(col, j[..., None], axis=-1)[..., 0]
        y1 = jnp.take_along_axis(col, (j + 1)[..., None], axis=-1)[..., 0]
        inside = y0 + t * (y1 - y0)
        above = col[..., -1] + slope * (lf - lf_nodes[-1])
        return jnp.where(lf > lf_nodes[-1], above, inside)

    def log_sensitivity(self, f, e=0.0, v=0.0):
        """ln S = -ln(10) * (interpolated log10 threshold), broadcast shape of f, e, v."""
        f, e, v = (jnp.asarray(x) for x in (f, e, v))
        return -_LN10 * _jit_log10_threshold(self, f, e, v)

    def sensitivity(self, f, e=0.0, v=0.0):
        """S = 1 / c_T from the table at f (cycles/deg), e (deg), v (deg/s)."""
        f, e, v = check_inputs("sensitivity", f=f, e=e, v=v)
        return jnp.exp(self.log_sensitivity(f, e, v))

    def _peak_frequency(self, e, v):
        shape = jnp.broadcast_shapes(jnp.shape(e), jnp.shape(v))
        dtype = jnp.result_type(e, v, self.log_thresholds)
        return _jit_peak(self, jnp.asarray(e), jnp.asarray(v), shape, dtype)

    def _peak_impl(self, e, v, shape, dtype):
        _, p, _ = self._columns(e, v, shape, dtype)
        return jnp.asarray(self.freqs, dtype)[p]

    # ------------------------------------------------------------------ exact inversions
    def _eccentric_distance(self, c, theta, e, v):
        return _jit_eccentric_distance(self, c, theta, e, v)

    def _threshold_frequency(self, c, e, v):
        return _jit_threshold_frequency(self, c, e, v)

    def _threshold_frequency_impl(self, c, e, v):
        shape = jnp.broadcast_shapes(c.shape, e.shape, v.shape)
        dtype = jnp.result_type(c, e, v, self.log_thresholds)
        col, p, slope = self._columns(e, v, shape, dtype)
        c = jnp.broadcast_to(c, shape).astype(dtype)
        cpos = c > 0
        Y = jnp.where(cpos, jnp.log10(jnp.where(cpos, c, 1.0)), 0.0)
        yp = jnp.take_along_axis(col, p[..., None], axis=-1)[..., 0]
        visible = cpos & (Y >= yp)
        lf = jnp.log10(jnp.asarray(self.freqs, dtype))
        F = len(self.freqs)
        ylast = col[..., -1]
        # above the table: ylast + slope (lf - lf_last) = Y
        on_ext = Y >= ylast
        lf_ext = lf[-1] + jnp.where(on_ext, Y - ylast, 0.0) / slope
        # inside: the last node j with col_j <= Y; the crossing lies in segment [j, j+1]
        le = jax.lax.stop_gradient(col) <= jax.lax.stop_gradient(Y)[..., None]
        j = (F - 1) - jnp.argmax(le[..., ::-1], axis=-1)
        j = jnp.clip(j, 0, F - 2)
        y0 = jnp.take_along_axis(col, j[..., None], axis=-1)[..., 0]
        y1 = jnp.take_along_axis(col, (j + 1)[..., None], axis=-1)[..., 0]
        den = y1 - y0
        ok = den > 0
        t = jnp.where(ok, (Y - y0) / jnp.where(ok, den, 1.0), 0.0)
        lf_in = lf[j] + jnp.clip(t, 0.0, 1.0) * (lf[j + 1] - lf[j])
        lf_star = jnp.where(on_ext, lf_ext, lf_in)
        lf_star = jnp.where(visible, lf_star, 0.0)
        return jnp.where(visible, 10.0 ** lf_star, 0.0)

    def imperceptible_distance(self, c, theta, e=0.0, v=0.0):
        """Viewing-distance multiple beyond which the change is imperceptible (see ``CSFModel``).

        Exact closed form ``k = 2 theta threshold_frequency(c)`` when the table does not depend on the
        eccentricity / velocity of the query (single eccentricity node and no more than one velocity
        node) or when ``e`` and ``v`` are concrete zeros. Otherwise a table-aware search: the margin
        ``log c - log c_T(k / 2 theta, e / k, v / k)`` is scanned (in log k) over every breakpoint of the
        table (k where the frequency, eccentricity or velocity crosses a grid node) with
        ``_SUBDIV`` points between consecutive breakpoints, up to the provable bound beyond which the
        extrapolated threshold exceeds ``c``; the crossing above the last perceptible point is refined
        by safeguarded Newton, with the implicit-function gradient. A perceptible window narrower than
        1/``_SUBDIV`` of a breakpoint interval can be missed (the margin is smooth inside an interval).
        """
        c, theta, e, v = check_inputs("imperceptible_distance", c=c, theta=theta, e=e, v=v)
        indep = len(self.eccs) == 1 and (self.vels is None or len(self.vels) == 1)
        zero = all(not isinstance(x, jax.core.Tracer) and not np.asarray(x).any() for x in (e, v))
        if not (indep or zero):
            return self._eccentric_distance(c, theta, e, v)
        shape = jnp.broadcast_shapes(c.shape, theta.shape, e.shape, v.shape)
        dtype = jnp.result_type(c, theta, e, v, self.log_thresholds)
        fmax = self._threshold_frequency(jnp.broadcast_to(c, shape), e, v)
        return (2.0 * jnp.broadcast_to(theta, shape) * fmax).astype(dtype)


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


# One compiled graph per (shape, dtype) instead of dozens of eagerly dispatched ops; nested inside an
# outer jit / grad these calls are simply inlined.
_jit_log10_threshold = eqx.filter_jit(lambda m, f, e, v: m._log10_threshold(f, e, v))
_jit_peak = eqx.filter_jit(lambda m, e, v, shape, dtype: m._peak_impl(e, v, shape, dtype))
_jit_threshold_frequency = eqx.filter_jit(lambda m, c, e, v: m._threshold_frequency_impl(c, e, v))
_jit_eccentric_distance = eqx.filter_jit(_eccentric_distance_impl)

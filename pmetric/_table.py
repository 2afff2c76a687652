"""Empirical CSF lookup table from a per-user calibration [LH01 §3.2, §6.1].

The table holds log10 threshold contrast on a grid of spatial frequency (cycles/deg) x eccentricity
(deg), optionally x retinal velocity (deg/s). Between nodes it is interpolated **linearly in
log10 threshold vs log10 frequency** and **linearly in eccentricity and velocity** (bilinear /
trilinear). Outside the grid:

* below the peak frequency (the frequency of the lowest threshold at that eccentricity and velocity)
  the threshold is the peak's: the conservative clamp of [LH01 §6.1] ("clamp the threshold
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

import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._base import CSFModel
from ._errors import PlodError
from ._numerics import is_tracer, log_guard
from ._inverse import bracketed_root, implicit_root
from ._table_distance import _jit_exact_distance
from ._table_plan import _plan_cached

__all__ = ["CalibratedCSF"]

# attributes CalibratedCSF.from_data reads from its data (duck typing: optim.fit.CalibrationData has them)
_DATA_ATTRIBUTES = ("f", "e", "velocity", "log_threshold", "weights")

_LN10 = math.log(10.0)


def _axis(name: str, values, *, positive: bool, allow_none=False) -> tuple[float, ...] | None:
    if values is None:
        if allow_none:
            return None
        raise PlodError(f"CalibratedCSF: {name} must be given")
    if isinstance(values, jax.core.Tracer):
        raise PlodError(f"CalibratedCSF: grid axis {name} must be concrete (it is a static field), not traced")
    a = np.asarray(values, dtype=np.float64)
    if a.ndim != 1 or a.size == 0:
        raise PlodError(f"CalibratedCSF: {name} must be a non-empty 1-D sequence, got shape {a.shape}")
    if not np.isfinite(a).all():
        raise PlodError(f"CalibratedCSF: {name} contains NaN or infinite values")
    if positive and (a <= 0).any():
        raise PlodError(f"CalibratedCSF: {name} must be > 0")
    if (a < 0).any():
        raise PlodError(f"CalibratedCSF: {name} must be >= 0")
    if (np.diff(a) <= 0).any():
        raise PlodError(f"CalibratedCSF: {name} must be strictly increasing, got {a.tolist()}")
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


class CalibratedCSF(CSFModel):
    """Threshold-contrast lookup table, a :class:`CSFModel` [LH01 §6.1].

    Fields:

    * ``log_thresholds`` (array, fittable): log10 threshold Michelson contrast, shape (F, E) or
      (F, E, V) for frequencies x eccentricities [x velocities].
    * ``freqs`` (static tuple, F >= 2, cycles/deg, > 0, increasing), ``eccs`` (static, E >= 1, deg),
      ``vels`` (static or None, V >= 1, deg/s), ``min_slope`` (static float > 0: least slope of log10
      c_T per log10 f used above the top frequency node).

    ``CalibratedCSF(freqs, eccs, log_thresholds, vels=None, min_slope=1.0)``; or
    :meth:`from_data` from calibration rows. See the module docstring for the
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
            raise PlodError("CalibratedCSF: need at least 2 frequency nodes")
        try:
            ms = float(min_slope)
        except (TypeError, ValueError):
            raise PlodError(f"CalibratedCSF: min_slope must be a number, got {min_slope!r}") from None
        if not (ms > 0 and math.isfinite(ms)):
            raise PlodError(f"CalibratedCSF: min_slope must be > 0 and finite, got {min_slope!r}")
        self.min_slope = ms
        t = jnp.asarray(log_thresholds)
        if not jnp.issubdtype(t.dtype, jnp.floating) or t.weak_type:
            t = t.astype(jnp.result_type(float))
        want = (len(self.freqs), len(self.eccs)) + ((len(self.vels),) if self.vels is not None else ())
        if t.shape != want:
            raise PlodError(f"CalibratedCSF: log_thresholds must have shape (F, E{', V' if self.vels else ''}) = "
                             f"{want}, got {t.shape}")
        if not isinstance(t, jax.core.Tracer):
            tn = np.asarray(t)
            if not np.isfinite(tn).all():
                idx = tuple(int(i) for i in np.argwhere(~np.isfinite(tn))[0])
                raise PlodError(f"CalibratedCSF: log_thresholds has a NaN or infinite entry at index {idx}")
        self.log_thresholds = t

    # ------------------------------------------------------------------ construction from data
    @classmethod
    def from_data(cls, data, freqs=None, eccs=None, vels=None, *, rtol_f: float = 0.1,
                  atol_e: float = 0.5, atol_v: float = 0.5, min_slope: float = 1.0) -> "CalibratedCSF":
        """Bin calibration rows onto a grid and average duplicates (N-weighted mean of log10 thresholds).

        ``freqs`` / ``eccs`` / ``vels``: grid axes; ``None`` (freqs, eccs) uses the distinct values in
        the data. ``vels=None`` builds a table without a velocity axis and requires every row to be
        static (velocity 0); ``vels="auto"`` uses the distinct velocities. A row is assigned to the
        nearest node; it must lie within ``rtol_f`` (relative, frequency), ``atol_e`` (deg) or
        ``atol_v`` (deg/s) of it. Rows at frequency 0 (disks) cannot be placed. Raises PlodError naming
        the first row that fits no node and, when the data cannot fill the grid, the empty cells.
        Rows are pooled regardless of luminance / area / dataset: select them first with ``subset``.

        ``data``: any object with 1-D arrays ``f`` (cycles/deg), ``e`` (deg), ``velocity`` (deg/s),
        ``log_threshold`` (log10 threshold contrast) and ``weights``, and ``len()``, such as
        ``optim.fit.CalibrationData`` (read a CSV with ``optim.fit.CalibrationData.from_csv``).
        """
        missing = [a for a in _DATA_ATTRIBUTES if not hasattr(data, a)]
        if missing:
            raise PlodError(f"CalibratedCSF.from_data: expected calibration data (such as optim.fit.CalibrationData) "
                             f"with attributes {_DATA_ATTRIBUTES}; {type(data).__name__} lacks {missing}")
        if len(data) == 0:
            raise PlodError("CalibratedCSF.from_data: no calibration rows")
        if (data.f <= 0).any():
            i = int(np.argmax(data.f <= 0))
            raise PlodError(f"CalibratedCSF.from_data: row {i} has spatial frequency 0 (a disk stimulus); "
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
                raise PlodError(f"CalibratedCSF.from_data: vels must be None, 'auto' or a sequence, got {vels!r}")
            vels = distinct(data.velocity, 0.0, 1e-9)
        if not use_v and (data.velocity > 0).any():
            i = int(np.argmax(data.velocity > 0))
            raise PlodError(f"CalibratedCSF.from_data: row {i} has velocity {data.velocity[i]:.4g} deg/s but the "
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
                raise PlodError(f"CalibratedCSF.from_data: row {i} at {what} {raw[i]:.4g} {unit} is not within "
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
            raise PlodError(f"CalibratedCSF.from_data: the data cannot fill the grid: {int(empty.sum())} of "
                             f"{empty.size} cells have no rows (e.g. {desc})")
        table = (ysum / wsum).reshape(shape)
        return cls(fr, ec, table, vels=vv if use_v else None, min_slope=min_slope)

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

    def _log_sensitivity(self, f, e, v):
        """ln S = -ln(10) * (interpolated log10 threshold), broadcast shape of f, e, v."""
        return -_LN10 * _jit_log10_threshold(self, f, e, v)

    def _is_perceptible(self, c, f, e, v):
        """``c >= c_T(max(f, f_peak(e, v)), e, v)`` (see :meth:`CSFModel.is_perceptible`): one fused
        elementwise kernel (the table clamp below the peak is the base class's ``max(f, f_peak)``)."""
        return _jit_perceptible(self, c, f, e, v)

    def _perceptible_impl(self, c, f, e, v):
        shape = jnp.broadcast_shapes(c.shape, f.shape, e.shape, v.shape)
        dtype = jnp.result_type(c, f, e, v, self.log_thresholds)
        cols = self._node_columns(e, v, shape, dtype)
        lf = jnp.log10(jnp.broadcast_to(f, shape).astype(dtype))  # f = 0 -> -inf: clamped to the peak
        y = self._curve(cols, lf)
        return log_guard(jnp.broadcast_to(c, shape).astype(dtype)) + (-_LN10 * y) >= 0

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

    def _imperceptible_distance(self, c, theta, e, v):
        """Viewing-distance multiple beyond which the change is imperceptible (see ``CSFModel``).

        ``k = 2 theta threshold_frequency(c)`` when the table does not depend on the eccentricity /
        velocity of the query (single eccentricity node and no more than one velocity node) or when
        ``e`` and ``v`` are concrete zeros. Otherwise, for (f x e) tables (and tables with a velocity axis
        queried at a concrete zero ``v``), the exact elementwise solver ``_exact_distance_impl`` (its
        docstring has the method and the proof that it returns the LARGEST perceptible k): exact to
        rounding, elementwise and loop-free for a concrete table. A concrete table
        gets a static plan (``_plan``: pieces that cannot matter are dropped at trace time); a traced
        table (under a gradient with respect to it) runs the same tests on every piece in loops.
        Tables with a velocity axis (V >= 2) queried at non-zero ``v`` use the slower table-aware scan
        ``_eccentric_distance_impl`` (a perceptible window narrower than 1/``_SUBDIV`` of a breakpoint
        interval can be missed there). Gradients: closed forms where the answer is a closed form, the
        implicit-function derivative -h_p / h_x of the local margin where it is a root; with respect to
        ``c``, ``theta``, ``e``, ``v`` and ``log_thresholds``.
        """
        indep = len(self.eccs) == 1 and (self.vels is None or len(self.vels) == 1)
        v_zero = not is_tracer(v) and not np.asarray(v).any()
        e_zero = not is_tracer(e) and not np.asarray(e).any()
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


def _eccentric_distance_impl(m, c, theta, e, v):
    """The table-aware scan for tables with a velocity axis queried at non-zero v (``m`` a
    :class:`pmetric.CalibratedCSF`): breakpoints of the table along the path, ``_SUBDIV`` grid points
    between consecutive ones, the last perceptible point refined by safeguarded Newton."""
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
_jit_perceptible = eqx.filter_jit(lambda m, c, f, e, v: m._perceptible_impl(c, f, e, v))
_jit_peak = eqx.filter_jit(lambda m, e, v, shape, dtype: m._peak_impl(e, v, shape, dtype))
_jit_threshold_frequency = eqx.filter_jit(lambda m, c, e, v: m._threshold_frequency_impl(c, e, v))
_jit_eccentric_distance = eqx.filter_jit(_eccentric_distance_impl)

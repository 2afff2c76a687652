"""The achromatic stelaCSF [MAC22].

Reference: [MAC22], doi:10.1145/3528223.3530115. Port of the achromatic part of
``CSF_stelaCSF.m`` (gfxdisp/stelaCSF, parameters "fitted on run stela-csf_all_2022-04-16", the release
used for ``../shared/data/csf/reference_values_achromatic.csv``; a port matches that table within 1e-3
in log10 sensitivity).

The model (rho: spatial frequency, cycles/deg; omega: temporal frequency, Hz; L: luminance, cd/m2;
A: stimulus area, deg2; e: eccentricity, deg)::

    S(rho, omega, L, A, e) = [R_sust(omega) S_sust(rho, L, A) + R_trans(omega) S_trans(rho, L, A)]
                             * 10^(-(d + rho d_f) e)
    R_sust  = exp(-omega^beta_sust / sigma_sust)
    R_trans = exp(-(omega^beta_trans - omega_0^beta_trans)^2 / sigma_trans)
    S_x     = S_max(L) * LP(rho) * sqrt(Ac / (1 + Ac / A)) * rho,   Ac = A0 / (1 + (rho / f0)^2)
    LP      = 10^(-(log10 rho - log10 f_max(L))^2 / 2^bw), raised to 1 - a below f_max (truncated log-parabola)

with the luminance dependences S_max(L) = p0 (1 + p1/L)^-p2 (1 - (1 + p3/L)^-p4) (sustained),
p1 L^p0 (transient) and f_max(L) = p0 (1 + p1/L)^-p2 (sustained), constant (transient). The drop with
eccentricity interpolates between the temporal/superior/inferior (``ecc_drop``, ``ecc_drop_f``) and the
nasal (``*_nasal``) visual field: alpha = min(1, |vis_field - 180| / 90).

Everything is evaluated in log space (``logaddexp`` for the sum of the two channels, ``log1p`` /
``expm1`` for the luminance terms) so values and gradients stay finite over the whole documented domain
(f in [1e-3, 1e3] cycles/deg, e in [0, 120] deg, v in [0, 1e3] deg/s, luminance in [1e-3, 1e4] cd/m2,
area in [1e-3, 1e3] deg2). Sensitivities are floored at ``SENSITIVITY_FLOOR`` = 1e-30 so that the
threshold contrast 1/S stays finite where the model underflows (e.g. 1000 cycles/deg at 120 deg).
"""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jax import lax

from . import _stela_peak as _peak
from . import _stela_ray as _ray
from ._base import CSFModel, _public, check_constants, distance_margin_k, float_param
from ._errors import PlodError
from ._inverse import implicit_root, implicit_solution
from ._numerics import LN_FLOOR, SENSITIVITY_FLOOR, as_float, log_guard, pow_pos, rare_update, safe_log, where_pos

__all__ = ["StelaCSF", "SENSITIVITY_FLOOR"]

_LN10 = math.log(10.0)


# --------------------------------------------------------------------------- the model
class StelaCSF(CSFModel):
    """Achromatic stelaCSF [MAC22], 2022 parameters.

    Sensitivity S = 1/c_T (Michelson contrast) of a Gabor / disc stimulus of spatial frequency ``f``
    (cycles/deg) drifting with retinal velocity ``v`` (deg/s; temporal frequency omega = v f, Hz) at
    eccentricity ``e`` (deg), on a background of ``luminance`` (cd/m2) over ``area`` (deg2).
    ``sensitivity(f, e, v)`` uses the static defaults ``luminance = 100`` cd/m2 and ``area = 1`` deg2
    (the conditions of the reference table), and ``vis_field`` (deg; 0 temporal = default as in the
    reference code, 90 superior, 180 nasal, 270 inferior).

    All 30 published constants are array fields (fittable); see ``param_bounds``. The vector fields
    follow ``CSF_stelaCSF.m``: ``sust_s_max`` = (p0..p4) of the two-hyperbola luminance dependence,
    ``sust_f_max`` = (p0, p1, p2) of the single hyperbola, ``trans_s_max`` = (exponent, scale).
    Outputs broadcast over ``f, e, v, luminance, area`` and are floored at 1e-30.

    Gradients w.r.t. ``v`` at ``v == 0`` (and ``f == 0``) are those of the double-where guard (0 for the
    transient channel's omega^0.19, whose true derivative is infinite there).
    """

    sust_s_max: jax.Array = eqx.field(converter=float_param, default=(68.9501, 59.5023, 0.164274, 7.54866e-07, 7.77268e09))
    sust_f_max: jax.Array = eqx.field(converter=float_param, default=(1.62144, 36.6565, 0.255823))
    sust_bw: jax.Array = eqx.field(converter=float_param, default=0.000219263)
    sust_a: jax.Array = eqx.field(converter=float_param, default=0.103686)
    trans_s_max: jax.Array = eqx.field(converter=float_param, default=(0.500846, 57.3469))
    trans_f_max: jax.Array = eqx.field(converter=float_param, default=0.0267489)
    trans_bw: jax.Array = eqx.field(converter=float_param, default=1.75147)
    trans_a: jax.Array = eqx.field(converter=float_param, default=0.000273289)
    sigma_trans: jax.Array = eqx.field(converter=float_param, default=0.12314)
    sigma_sust: jax.Array = eqx.field(converter=float_param, default=5.79336)
    beta_sust: jax.Array = eqx.field(converter=float_param, default=1.3314)
    beta_trans: jax.Array = eqx.field(converter=float_param, default=0.1898)
    omega_0: jax.Array = eqx.field(converter=float_param, default=5.0)
    ecc_drop: jax.Array = eqx.field(converter=float_param, default=0.0296662)
    ecc_drop_nasal: jax.Array = eqx.field(converter=float_param, default=0.0113638)
    ecc_drop_f: jax.Array = eqx.field(converter=float_param, default=0.0190062)
    ecc_drop_f_nasal: jax.Array = eqx.field(converter=float_param, default=0.0193858)
    f0: jax.Array = eqx.field(converter=float_param, default=0.65)
    a0: jax.Array = eqx.field(converter=float_param, default=270.0)
    luminance: float = eqx.field(static=True, default=100.0)
    area: float = eqx.field(static=True, default=1.0)
    vis_field: float = eqx.field(static=True, default=0.0)

    inputs: ClassVar[tuple[str, ...]] = ("f", "e", "v", "luminance", "area", "vis_field")
    param_bounds: ClassVar[dict[str, tuple[float | None, float | None]]] = {
        "sust_s_max": (1e-12, None),
        "sust_f_max": (1e-12, None),
        "sust_bw": (0.0, 10.0),
        "sust_a": (0.0, 0.999),
        "trans_s_max": (1e-12, None),
        "trans_f_max": (1e-12, None),
        "trans_bw": (0.0, 10.0),
        "trans_a": (0.0, 0.999),
        "sigma_trans": (1e-6, None),
        "sigma_sust": (1e-6, None),
        "beta_sust": (1e-3, 5.0),
        "beta_trans": (1e-3, 5.0),
        "omega_0": (1e-3, 100.0),
        "ecc_drop": (0.0, 1.0),
        "ecc_drop_nasal": (0.0, 1.0),
        "ecc_drop_f": (0.0, 1.0),
        "ecc_drop_f_nasal": (0.0, 1.0),
        "f0": (1e-3, 100.0),
        "a0": (1e-3, 1e6),
    }

    def __check_init__(self):
        shapes = {"sust_s_max": (5,), "sust_f_max": (3,), "trans_s_max": (2,)}
        for name, shape in shapes.items():
            if jnp.shape(getattr(self, name)) != shape:
                raise PlodError(f"StelaCSF: {name} must have shape {shape}, got {jnp.shape(getattr(self, name))}")
        for name in self.param_bounds:
            if name not in shapes and jnp.shape(getattr(self, name)) != ():
                raise PlodError(f"StelaCSF: {name} must be a scalar, got shape {jnp.shape(getattr(self, name))}")
        for name in ("luminance", "area"):
            val = getattr(self, name)
            if not (isinstance(val, (int, float)) and math.isfinite(val) and val > 0):
                raise PlodError(f"StelaCSF: default {name} must be a finite positive number, got {val!r}")
        check_constants(self)

    # ---------------------------------------------------------------- components (natural log)
    @staticmethod
    def _ln_hyper(p0, p1, p2, L):
        """ln of p0 (1 + p1/L)^-p2."""
        return safe_log(p0) - p2 * jnp.log1p(p1 / L)

    def _ln_channel(self, lnf, f, L, lnA, ln_s_max, ln_f_max, bw, a):
        """ln of S_x(rho, L, A) for one channel (sustained or transient); L > 0, f > 0 here."""
        lnfm = ln_f_max
        ln_lp = -((lnf - lnfm) ** 2) / _LN10 / (2.0**bw)
        trunc = jnp.log1p(-jnp.clip(a, 0.0, 0.999999))
        ln_lp = jnp.where((lnf < lnfm) & (ln_lp < trunc), trunc, ln_lp)
        ln_ac = safe_log(self.a0) - jnp.log1p((f / self.f0) ** 2)
        size = 0.5 * (ln_ac - jnp.logaddexp(0.0, ln_ac - lnA))
        return ln_s_max + ln_lp + size + lnf

    @_public
    def log_sensitivity(self, f, e=0.0, v=0.0, luminance=None, area=None, vis_field=None):
        """:meth:`CSFModel.log_sensitivity` with the visual field ``vis_field`` (deg; default the field)."""
        return self._stimulus("log_sensitivity", True, f, e, v, luminance=luminance, area=area, vis_field=vis_field)

    @_public
    def stimulus_sensitivity(self, f, e=0.0, v=0.0, luminance=None, area=None, vis_field=None):
        """Sensitivity 1/c_T of a stimulus: f (cycles/deg), e (deg), v (deg/s), luminance (cd/m2), area (deg2).

        :meth:`CSFModel.stimulus_sensitivity` with the visual field ``vis_field`` (deg); ``luminance`` /
        ``area`` / ``vis_field`` default to the model's static fields; NaN entries of luminance and area
        (unknown in a data set) fall back to them too. Result >= 1e-30.
        """
        return self._stimulus("stimulus_sensitivity", False, f, e, v, luminance=luminance, area=area,
                              vis_field=vis_field)

    def _stimulus_log_sensitivity(self, f, e, v, luminance=None, area=None, vis_field=None):
        L = self.luminance if luminance is None else luminance
        A = self.area if area is None else area
        vf = self.vis_field if vis_field is None else vis_field
        return _jit_log_s(self, f, e, v, as_float(L), as_float(A), as_float(vf))

    def _stimulus_sensitivity(self, f, e, v, luminance=None, area=None, vis_field=None):
        return jnp.exp(self._stimulus_log_sensitivity(f, e, v, luminance, area, vis_field))

    def _log_sensitivity(self, f, e, v):
        return self._stimulus_log_sensitivity(f, e, v)

    def _log_s(self, f, e, v, L, A, vf):
        valid = (f > 0) & (L > 0) & (A > 0)
        one = jnp.ones_like(f)
        fs = jnp.where(f > 0, f, one)
        Ls = jnp.where(L > 0, L, jnp.ones_like(L))
        As = jnp.where(A > 0, A, jnp.ones_like(A))
        lnf, lnA = jnp.log(fs), jnp.log(As)
        es = jnp.maximum(e, 0.0)
        omega = fs * jnp.maximum(v, 0.0)

        # temporal responses
        ln_r_sust = -pow_pos(omega, self.beta_sust) / self.sigma_sust
        ln_r_trans = -((pow_pos(omega, self.beta_trans) - self.omega_0**self.beta_trans) ** 2) / self.sigma_trans

        # luminance dependences
        ps, pf, pt = self.sust_s_max, self.sust_f_max, self.trans_s_max
        x = ps[4] * jnp.log1p(ps[3] / Ls)
        ln_dip = where_pos(x, lambda s: jnp.log(-jnp.expm1(-s)), jnp.full_like(x, LN_FLOOR))
        ln_smax_sust = self._ln_hyper(ps[0], ps[1], ps[2], Ls) + ln_dip
        ln_fmax_sust = self._ln_hyper(pf[0], pf[1], pf[2], Ls)
        ln_smax_trans = safe_log(pt[1]) + pt[0] * jnp.log(Ls)
        ln_fmax_trans = safe_log(self.trans_f_max)

        ln_sust = self._ln_channel(lnf, fs, Ls, lnA, ln_smax_sust, ln_fmax_sust, self.sust_bw, self.sust_a)
        ln_trans = self._ln_channel(lnf, fs, Ls, lnA, ln_smax_trans, ln_fmax_trans, self.trans_bw, self.trans_a)
        ln_s = jnp.logaddexp(ln_r_sust + ln_sust, ln_r_trans + ln_trans)

        alpha = jnp.minimum(1.0, jnp.abs(vf - 180.0) / 90.0)
        drop = alpha * self.ecc_drop + (1 - alpha) * self.ecc_drop_nasal
        drop_f = alpha * self.ecc_drop_f + (1 - alpha) * self.ecc_drop_f_nasal
        ln_s = ln_s - _LN10 * (drop + fs * drop_f) * es
        return jnp.where(valid, jnp.maximum(ln_s, LN_FLOOR), LN_FLOOR)

    # ---------------------------------------------------------------- peak frequency
    _PEAK_GRID: ClassVar[int] = 17
    _PEAK_ITER: ClassVar[dict] = {"float32": 5, "float64": 7}  # Newton iterations per half-bracket

    def _peak_frequency(self, e, v):
        """Frequency of peak sensitivity at (e, v) and the default luminance / area / vis_field (see
        :meth:`_peak_log_frequency`), with the implicit-function gradient of ``d ln S / d ln f = 0``."""
        u_star, interior = self._peak_log_frequency(e, v)

        def dlog(u):
            return jax.jvp(lambda uu: self._log_sensitivity(jnp.exp(uu), e, v), (u,), (jnp.ones_like(u),))[1]

        return jnp.exp(implicit_root(dlog, u_star, mask=interior))

    def _peak_frequency_sg(self, e, v):
        """The peak frequency without gradient (what the distance margin needs): no implicit-root pass.
        Concrete constants: the table + Newton path of :meth:`_fast_peak`; else the generic search."""
        shape = jnp.broadcast_shapes(jnp.shape(e), jnp.shape(v))
        dtype = jnp.result_type(e, v, float)
        tab = self._fast_table(dtype)
        if tab is None:
            return jnp.exp(self._peak_log_frequency(e, v)[0])
        e1, v1 = (lax.stop_gradient(jnp.broadcast_to(x, shape).astype(dtype).reshape(-1)) for x in (e, v))
        up, _ = self._fast_peak(tab, e1, v1, dtype)
        return jnp.exp(up).reshape(shape)

    def _peak_log_frequency(self, e, v):
        """Frequency of peak sensitivity at (e, v) and the default luminance / area / vis_field.

        The best of a 17-point log grid over [1e-3, 1e3] cycles/deg (one step: a factor 2.37; the
        sustained and transient log-parabolas are several steps wide) brackets the global maximum in
        [ub - du, ub + du]. The truncated log-parabolas have a kink (a jump of d ln S / d ln f) where the
        truncation starts, and a second, local maximum can sit next to it (e.g. e = 15 deg, v = 2.7 deg/s
        at 0.89 and 0.95 cycles/deg), so the bracket is split at that kink when it lies inside (else at
        ub); safeguarded Newton on ``d ln S / d ln f = 0`` (second derivative by forward-over-forward
        autodiff; 5 iterations in float32, 7 in float64) runs on each side, and the best of the two
        roots, the kink and the grid point is kept. Checked against the base class's 49-point grid +
        golden-section search over e in [0, 120], v in [1e-3, 2e3]: never lower in ln S by more than
        2e-9 (float64), and higher by up to 1.4e-3 where golden-section stops at the local maximum.
        Fewer sensitivity evaluations than the base class's search (plus the implicit-gradient pass,
        skipped by :meth:`_peak_frequency_sg` where no gradient is needed: the distance margin).
        Returns ``(ln f_peak, interior)`` under stop_gradient; ``interior``: a stationary point inside the grid."""
        shape = jnp.broadcast_shapes(jnp.shape(e), jnp.shape(v))
        dtype = jnp.result_type(e, v, float)
        e_, v_, ms = lax.stop_gradient((e, v, self))
        logs = lambda u: ms._log_sensitivity(jnp.exp(u), e_, v_)  # noqa: E731
        n = self._PEAK_GRID
        u_lo, u_hi = math.log(1e-3), math.log(1e3)  # Python floats: weakly typed (no float64 under x64)
        du = (u_hi - u_lo) / (n - 1)

        def scan(j, state):
            best_u, best_s = state
            u = jnp.full(shape, u_lo + j * du, dtype)
            s = logs(u)
            better = s > best_s
            return jnp.where(better, u, best_u), jnp.where(better, s, best_s)

        init = (jnp.full(shape, u_lo, dtype), jnp.full(shape, -jnp.inf, dtype))
        ub, _ = lax.fori_loop(0, n, scan, init)
        d1 = lambda u: jax.jvp(logs, (u,), (jnp.ones_like(u),))[1]  # noqa: E731

        def newton(_, state):  # safeguarded Newton on d1 = 0 (bisection when the step leaves the bracket)
            lo, hi, u = state
            g, dg = jax.jvp(d1, (u,), (jnp.ones_like(u),))
            up = g >= 0
            lo, hi = jnp.where(up, u, lo), jnp.where(up, hi, u)
            step = u - g / jnp.where(dg < 0, dg, -1.0)
            # a step that leaves the bracket by rounding only (converged) is clipped, not bisected
            inside = (dg < 0) & (step >= lo - 1e-4) & (step <= hi + 1e-4)
            return lo, hi, jnp.where(inside, jnp.clip(step, lo, hi), 0.5 * (lo + hi))

        # The truncated log-parabolas have a kink (a jump of d ln S / d ln f) where the truncation starts:
        # a second, local maximum can sit next to it. Split the bracket [ub - du, ub + du] at the kink
        # when it lies inside (else at ub), run Newton on each side and keep the best candidate.
        L = jnp.asarray(self.luminance, dtype)
        ln_fm_s = ms._ln_hyper(ms.sust_f_max[0], ms.sust_f_max[1], ms.sust_f_max[2], L)
        ln_fm_t = safe_log(ms.trans_f_max)
        u_ks = ln_fm_s - jnp.sqrt(-jnp.log1p(-jnp.clip(ms.sust_a, 0.0, 0.999999)) * _LN10 * 2.0**ms.sust_bw)
        u_kt = ln_fm_t - jnp.sqrt(-jnp.log1p(-jnp.clip(ms.trans_a, 0.0, 0.999999)) * _LN10 * 2.0**ms.trans_bw)
        lo, hi = ub - du, ub + du
        inside = lambda k: (k > lo) & (k < hi)  # noqa: E731
        split = jnp.where(inside(u_ks), u_ks, jnp.where(inside(u_kt), u_kt, ub)).astype(dtype)
        u_star, s_star = ub, logs(ub)
        s_split = logs(split)
        better = s_split > s_star
        u_star, s_star = jnp.where(better, split, u_star), jnp.where(better, s_split, s_star)
        for a, b in ((lo, split), (split, hi)):
            _, _, root = lax.fori_loop(0, self._PEAK_ITER.get(jnp.dtype(dtype).name, 6), newton, (a, b, 0.5 * (a + b)))
            s_root = logs(root)
            better = s_root > s_star
            u_star, s_star = jnp.where(better, root, u_star), jnp.where(better, s_root, s_star)
        u_star = lax.stop_gradient(u_star)

        interior = (u_star != ub) & (u_star != split) & (u_star > u_lo + du) & (u_star < u_hi - du)
        return u_star, interior

    # ---------------------------------------------------------------- fast paths (concrete constants)
    def _fast_table(self, dtype):
        """The per-model peak table of :mod:`pmetric._stela_peak` (built once per constants, float64), or
        None: traced constants (fitting, gradients w.r.t. the model), a dtype other than float32 /
        float64, or constants the fast path does not cover."""
        vals = self._concrete_fields(_FIELDS, dtype)
        if vals is None:
            return None
        consts = _peak.consts_of(vals, self.luminance, self.area, self.vis_field)
        return None if consts is None else _peak.build_table(consts)

    def _fast_peak(self, tab, e, v, dtype):
        """``(ln f_peak, ln S_peak)`` at (e, v) (deg, deg/s; 1-D arrays) from the table, with the few
        unsettled elements (about 0.2 % of random inputs: near the kinks, outside the table) solved by
        the generic :meth:`_peak_log_frequency` after compaction. No gradient."""
        up, mp, settled = lax.optimization_barrier(_peak.fast_peak(tab, e, v, dtype))
        ms = lax.stop_gradient(self)
        up = rare_update(lambda e1, v1: ms._peak_log_frequency(e1, v1)[0], up, ~settled, (e, v))
        m_r = ms._log_s(jnp.exp(up), e, v, *self._defaults(dtype))
        mp = jnp.where(settled, jnp.maximum(mp, LN_FLOOR), m_r)
        return up, mp

    def _defaults(self, dtype):
        return tuple(jnp.asarray(x, dtype) for x in (self.luminance, self.area, self.vis_field))

    def _is_perceptible(self, c, f, e, v):
        """True where contrast ``c`` at frequency ``f`` (cycles/deg), eccentricity ``e`` (deg) and
        velocity ``v`` (deg/s) is visible at the default luminance / area / visual field:
        ``c >= 1 / S(max(f, f_peak(e, v)), e, v)`` (see :meth:`CSFModel.is_perceptible`).

        Concrete constants (a model closed over by ``jit``): the peak comes from the per-model table of
        :mod:`pmetric._stela_peak` (one analytic Newton step per candidate, exact to rounding) and ln S
        at f from the model's formula; otherwise the generic kink-aware search. Both agree except within
        rounding of the threshold ([MAC22] for the model)."""
        shape = jnp.broadcast_shapes(c.shape, f.shape, e.shape, v.shape)
        dtype = jnp.result_type(c, f, e, v, float)
        tab = self._fast_table(dtype)
        if tab is None:
            return super()._is_perceptible(c, f, e, v)
        c, f, e, v = (jnp.broadcast_to(x, shape).astype(dtype).reshape(-1) for x in (c, f, e, v))
        up, mp = lax.optimization_barrier(self._fast_peak(tab, e, v, dtype))  # no recomputation per consumer
        below = jnp.log(jnp.where(f > 0, f, 1.0)) < up
        below = below | (f <= 0)
        ls = self._log_s(f, e, v, *self._defaults(dtype))
        out = log_guard(c) + jnp.where(below, mp, ls) >= 0
        return out.reshape(shape)

    def _fast_ray(self, dtype):
        """(table, ray constants) of :mod:`pmetric._stela_peak` for concrete constants, else None."""
        tab = self._fast_table(dtype)
        if tab is None:
            return None
        fp_max = float(np.exp(np.nanmax(tab.cand[..., [0, 3]])))
        return tab, _ray.build_ray(tab.k, fp_max), _ray.build_ray(tab.k, fp_max, _ray.RAY_DU_FINE)

    def _generic_distance_value(self, c, th, e, v):
        """The base class's scan + safeguarded Newton (value only; ``th > 0``): k, or 0. The margin's peak
        frequency is the kink-aware search of :meth:`_peak_log_frequency` (no nested compaction: this
        runs on few elements, and compiles faster)."""
        w, found, _ = self._generic_scan(c, th, e, v, peak=lambda ek, vk: jnp.exp(self._peak_log_frequency(ek, vk)[0]))
        return jnp.where(found, jnp.exp(w), 0.0)

    def _imperceptible_distance(self, c, theta, e, v):
        """Viewing-distance multiple beyond which a change of Michelson contrast ``c`` spanning ``theta``
        deg at eccentricity ``e`` (deg) and retinal velocity ``v`` (deg/s) is imperceptible (definition:
        :meth:`CSFModel.imperceptible_distance`; model: [MAC22]). Seen k times farther away the change has f = k / (2 theta) cycles/deg, e / k and
        v / k; 0 where ``theta = 0`` or nothing is perceptible.

        Concrete constants (the usual case): a direct solve along the ray (:func:`pmetric._stela_ray.
        ray_distance`). The temporal frequency v / (2 theta) and the frequency-dependent eccentricity
        drop ``drop_f e / (2 theta)`` are constant along it, so the falling-limb margin
        m(u) = ln c + ln S(f, e / k, v / k) (u = ln f) is a closed form in which, on a static grid of u
        (step 0.3 over the range where any c <= 1 can be visible), only one exponential depends on the
        element. A top-down scan finds the highest grid cell with a root, certifying each cell above
        it free of roots by per-cell upper bounds of m and of m' (m is a sum of two log-concave channel
        terms); safeguarded Newton from the secant start then polishes the root (3 steps in float32, 5
        in float64). Below the peak frequency the threshold is the peak's: the answer is the largest
        falling-limb root wherever the peak sensitivity does not fall along the ray between that root
        and the highest peak frequency (checked per model, see :func:`pmetric._stela_ray.build_ray`).
        Elements this pass cannot certify (a root close to a tangency, a ray through the small region
        where the transient channel's gain with velocity beats the eccentricity drop, c > 1, a root
        not converged) -- about 0.1 % of random inputs -- are gathered (:func:`pmetric._numerics.
        rare_update`) and solved by the generic scan of :meth:`CSFModel.imperceptible_distance`.
        Traced constants (fitting): the generic method. Gradients w.r.t. c, theta, e, v and the
        constants: implicit-function theorem on the exact margin (the peak frequency under stop_gradient,
        exact by the envelope theorem where it binds)."""
        shape = jnp.broadcast_shapes(c.shape, theta.shape, e.shape, v.shape)
        dtype = jnp.result_type(c, theta, e, v, float)
        fast = self._fast_ray(dtype)
        if fast is None:
            return super()._imperceptible_distance(c, theta, e, v)
        tab, ray, fine = fast
        c, theta, e, v = (jnp.broadcast_to(x, shape).astype(dtype).reshape(-1) for x in (c, theta, e, v))
        sg = lax.stop_gradient
        c_, t_, e_, v_ = sg((c, theta, e, v))
        pos_ = t_ > 0
        th_ = jnp.where(pos_, t_, 1.0)
        k0 = _ray.ray_distance(tab.k, ray, c_, th_, e_, v_, dtype)
        k0 = jnp.where(pos_, k0, 0.0)
        ms = sg(self)

        def tier2(c1, t1, e1, v1):  # the same solve on a 6 times finer grid
            return _ray.ray_distance(tab.k, fine, c1, jnp.where(t1 > 0, t1, 1.0), e1, v1, dtype)

        def slow(c1, t1, e1, v1):
            return ms._generic_distance_value(c1, jnp.where(t1 > 0, t1, 1.0), e1, v1)

        k1 = rare_update(tier2, k0, jnp.isnan(k0), (c_, t_, e_, v_))
        # the generic scan is costly per element: gather few (up to n / 8192 elements, or their
        # blocks of 16; beyond that every element)
        cap = max(64, c_.size // 8192)
        k_star = rare_update(slow, k1, jnp.isnan(k1), (c_, t_, e_, v_), max_blocks=cap, cap=cap)
        ok = k_star > 0
        pos = theta > 0
        th = jnp.where(pos, theta, 1.0)
        k = implicit_solution(distance_margin_k, jnp.where(ok, k_star, 1.0), ok, self, c, th, e, v)
        return jnp.where(ok, k, 0.0).reshape(shape)

_FIELDS = tuple(StelaCSF.param_bounds)


@eqx.filter_jit
def _jit_log_s(model, f, e, v, L, A, vf):
    # one compiled kernel per shape/dtype: fast eager calls; inlined when traced inside an outer jit
    return model._log_s(f, e, v, L, A, vf)


"""Barten's (1999) physical model of foveal contrast sensitivity.

Reference: P. G. J. Barten, *Contrast Sensitivity of the Human Eye and Its Effects on Image Quality*,
SPIE Press, 1999, doi:10.1117/3.353254 (eq. 3.26 with the 2-D field size of ch. 3.4); also
P. G. J. Barten, "Formula for the contrast sensitivity of the human eye", Proc. SPIE 5294:231-238, 2004,
and ITU-R Report BT.2246-4 (2015), Figure 31. The formula with a given retinal illuminance E::

    S(u) = (M_opt(u) / k) / sqrt( 2/T * (1/X0^2 + 1/Xmax^2 + u^2/Nmax^2) * (1/Y0^2 + 1/Ymax^2 + u^2/Nmax^2)
                                  * (1/(eta p E) + Phi0 / (1 - exp(-(u/u0)^2))) )
    M_opt(u) = exp(-2 pi^2 sigma^2 u^2),       sigma = sqrt(sigma0^2 + (Cab d)^2)       (deg)
    d = 5 - 3 tanh(0.4 log10(L X0 Y0 / 40^2))  (pupil diameter, mm; L in cd/m2, X0 Y0 in deg2)
    E = pi d^2 / 4 * L * (1 - (d/9.7)^2 + (d/12.4)^4)   (Troland, with the Stiles-Crawford correction)

u: spatial frequency (cycles/deg); X0, Y0: field size (deg; a square stimulus of area A deg2 has
X0 = Y0 = sqrt(A)); k = 3 signal-to-noise ratio; T = 0.1 s integration time; Xmax = Ymax = 12 deg,
Nmax = 15 cycles integration limits; eta = 0.03 quantum efficiency; p = 1.2274e6 photons/(s deg2 Td)
photon conversion factor; Phi0 = 3e-8 s deg2 neural noise; u0 = 7 cycles/deg lateral inhibition.
With u = 4, sigma = 0.01, E = 65, X0 = Y0 = 60, p = 1.2e6 the formula gives S = 352.7613421.

Solvers: with concrete constants (the usual case: a model closed over by ``jit``) ``peak_frequency``,
``is_perceptible``, ``threshold_frequency`` and ``imperceptible_distance`` (at the default luminance
and area) use per-model scalars computed once at trace time in float64 (:func:`_limb`): the exact peak,
a linear-domain perceptibility test without logs, and the inverse of the falling limb as a piecewise
Chebyshev start in sqrt(ln(c S_peak)) followed by one Newton (float32) or Halley (float64) step on the
exact formula -- single fused elementwise passes, no loop. Traced constants (fitting, gradients with
respect to the model) use the generic solvers of :class:`CSFModel`. Both give the same answers
(within 1e-8 relative in float64).

The pupil formula uses log10 as in Barten's book (and Watson & Yellott 2012, J. Vis. 12(10):12); the
``colour`` package uses the natural log. The formula is binocular; monocular sensitivity is sqrt(2)
lower. Only the product eta * p is identifiable from thresholds.
"""

from __future__ import annotations

import functools
import math
from typing import ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._base import _F_HI, CSFModel, _is_tracer, _log_guard, check_inputs
from ._csf import _clenshaw
from ._inverse import implicit_solution
from ._stela import _LN_FLOOR, _float, _param, _safe_log, _where_pos, fill_nan

__all__ = ["Barten"]


class Barten(CSFModel):
    """Barten (1999) CSF: static, foveal, luminance- and field-size-dependent (see module docstring).

    ``stimulus_sensitivity(f, e, v, luminance, area)``: f in cycles/deg, luminance in cd/m2, area in
    deg2 (a square field X0 = Y0 = sqrt(area) deg). ``e`` and ``v`` are ignored (the model is foveal and
    static: wrap it in ``pmetric.Eccentric`` for eccentricity) but broadcast into the output shape.
    ``sensitivity(f, e, v)`` uses the static defaults ``luminance = 100`` cd/m2 and ``area = 3600`` deg2
    (X0 = Y0 = 60 deg, Barten's large-field condition). ``illuminance_sensitivity(u, E, sigma, x0, y0)``
    is the parametrization with the retinal illuminance E (Troland) and optical sigma (deg) given.
    Sensitivities are floored at 1e-30 (the optical MTF underflows at very high u).

    Fitted constants (array fields): ``sigma_0`` (deg), ``c_ab`` (deg/mm), ``k``, ``t`` (s), ``x_max``,
    ``y_max`` (deg), ``n_max`` (cycles), ``eta``, ``p`` (photons/(s deg2 Td)), ``phi_0`` (s deg2),
    ``u_0`` (cycles/deg). Static switch ``stiles_crawford`` (default True) applies the Stiles-Crawford
    correction to the Troland value.
    """

    sigma_0: jax.Array = eqx.field(converter=_param, default=0.5 / 60)
    c_ab: jax.Array = eqx.field(converter=_param, default=0.08 / 60)
    k: jax.Array = eqx.field(converter=_param, default=3.0)
    t: jax.Array = eqx.field(converter=_param, default=0.1)
    x_max: jax.Array = eqx.field(converter=_param, default=12.0)
    y_max: jax.Array = eqx.field(converter=_param, default=12.0)
    n_max: jax.Array = eqx.field(converter=_param, default=15.0)
    eta: jax.Array = eqx.field(converter=_param, default=0.03)
    p: jax.Array = eqx.field(converter=_param, default=1.2274e6)
    phi_0: jax.Array = eqx.field(converter=_param, default=3e-8)
    u_0: jax.Array = eqx.field(converter=_param, default=7.0)
    luminance: float = eqx.field(static=True, default=100.0)
    area: float = eqx.field(static=True, default=3600.0)
    stiles_crawford: bool = eqx.field(static=True, default=True)

    inputs: ClassVar[tuple[str, ...]] = ("f", "luminance", "area")
    param_bounds: ClassVar[dict[str, tuple[float | None, float | None]]] = {
        "sigma_0": (1e-6, 1.0),
        "c_ab": (0.0, 1.0),
        "k": (1e-3, None),
        "t": (1e-4, 10.0),
        "x_max": (1e-3, None),
        "y_max": (1e-3, None),
        "n_max": (1e-3, None),
        "eta": (1e-6, 1.0),
        "p": (1.0, None),
        "phi_0": (1e-15, None),
        "u_0": (1e-3, None),
    }

    def __check_init__(self):
        for name in self.param_bounds:
            if jnp.shape(getattr(self, name)) != ():
                raise ValueError(f"Barten: {name} must be a scalar, got shape {jnp.shape(getattr(self, name))}")
        for name in ("luminance", "area"):
            val = getattr(self, name)
            if not (isinstance(val, (int, float)) and math.isfinite(val) and val > 0):
                raise ValueError(f"Barten: default {name} must be a finite positive number, got {val!r}")

    # ---------------------------------------------------------------- ancillary formulas
    def pupil_diameter(self, luminance, area):
        """Pupil diameter (mm) for a field of ``luminance`` cd/m2 and ``area`` = X0 Y0 deg2 (Barten 1999)."""
        la = _float(luminance) * _float(area)
        lg = _where_pos(la, lambda s: jnp.log10(s / 1600.0), jnp.full_like(la, -60.0))
        return 5.0 - 3.0 * jnp.tanh(0.4 * lg)

    def retinal_illuminance(self, luminance, d):
        """Retinal illuminance (Troland) of ``luminance`` cd/m2 through a pupil of ``d`` mm."""
        d = _float(d)
        e = math.pi * d**2 / 4.0 * _float(luminance)
        if self.stiles_crawford:
            e = e * (1.0 - (d / 9.7) ** 2 + (d / 12.4) ** 4)
        return e

    def optical_sigma(self, d):
        """Standard deviation (deg) of the eye's line-spread function for a pupil of ``d`` mm."""
        s2 = self.sigma_0**2 + (self.c_ab * _float(d)) ** 2
        return _where_pos(s2, jnp.sqrt, jnp.zeros_like(s2))

    # ---------------------------------------------------------------- the CSF
    def log_illuminance_sensitivity(self, u, E, sigma, x0, y0=None):
        """Natural log of ``illuminance_sensitivity`` (no validation), floored at ln(1e-30)."""
        u, E, sigma, x0 = _float(u), _float(E), _float(sigma), _float(x0)
        y0 = x0 if y0 is None else _float(y0)
        inv_x2 = _where_pos(x0, lambda s: 1.0 / s**2, jnp.full_like(x0, jnp.inf))
        inv_y2 = _where_pos(y0, lambda s: 1.0 / s**2, jnp.full_like(y0, jnp.inf))
        return self._ln_s(u, E, sigma, inv_x2, inv_y2)

    def _ln_s(self, u, E, sigma, inv_x2, inv_y2):
        valid = (u > 0) & (E > 0) & jnp.isfinite(inv_x2) & jnp.isfinite(inv_y2)
        us = jnp.where(u > 0, u, jnp.ones_like(u))
        Es = jnp.where(E > 0, E, jnp.ones_like(E))
        ix = jnp.where(jnp.isfinite(inv_x2), inv_x2, jnp.ones_like(inv_x2))
        iy = jnp.where(jnp.isfinite(inv_y2), inv_y2, jnp.ones_like(inv_y2))
        n2 = (us / self.n_max) ** 2
        ln_mx = jnp.log(ix + 1.0 / self.x_max**2 + n2)
        ln_my = jnp.log(iy + 1.0 / self.y_max**2 + n2)
        x = (us / self.u_0) ** 2
        ln_m = _where_pos(x, lambda s: jnp.log(-jnp.expm1(-s)), jnp.full_like(x, _LN_FLOOR))
        ln_noise = jnp.logaddexp(-(_safe_log(self.eta * self.p) + jnp.log(Es)), _safe_log(self.phi_0) - ln_m)
        ln_s = (
            -2.0 * math.pi**2 * sigma**2 * us**2
            - _safe_log(self.k)
            - 0.5 * (math.log(2.0) - _safe_log(self.t) + 0.5 * (ln_mx + ln_my) + ln_noise)
        )
        return jnp.where(valid, jnp.maximum(ln_s, _LN_FLOOR), _LN_FLOOR)

    def illuminance_sensitivity(self, u, E, sigma, x0, y0=None):
        """Barten's S for spatial frequency ``u`` (cycles/deg), retinal illuminance ``E`` (Troland),
        optical line-spread ``sigma`` (deg) and field size ``x0`` by ``y0`` deg (``y0`` defaults to x0).

        Uses the model's k, T, Xmax, Ymax, Nmax, eta, p, Phi0 and u0 (not sigma_0, c_ab or the pupil).
        """
        u, E, sigma, x0, y0 = check_inputs("Barten.illuminance_sensitivity", u=u, E=E, sigma=sigma, x0=x0, y0=y0)
        return jnp.exp(self.log_illuminance_sensitivity(u, E, sigma, x0, y0))

    def log_sensitivity(self, f, e=0.0, v=0.0, luminance=None, area=None):
        """Natural log of ``stimulus_sensitivity`` (no validation); broadcast over f, e, v, luminance, area."""
        f, e, v = _float(f), _float(e), _float(v)
        L = _float(self.luminance if luminance is None else luminance)
        A = _float(self.area if area is None else area)
        # the defaults are weakly typed: under x64 they must not promote float32 inputs to float64
        dtype = jnp.result_type(f, e, v, L, A)
        return _jit_log_s(self, f, e, v, L.astype(dtype), A.astype(dtype))

    def _log_s(self, f, e, v, L, A):
        d = self.pupil_diameter(L, A)
        E = self.retinal_illuminance(L, d)
        sigma = self.optical_sigma(d)
        inv_a = _where_pos(A, lambda s: 1.0 / s, jnp.full_like(A, jnp.inf))
        ln_s = self._ln_s(f, E, sigma, inv_a, inv_a)
        shape = jnp.broadcast_shapes(jnp.shape(ln_s), jnp.shape(e), jnp.shape(v))
        return jnp.broadcast_to(ln_s, shape)

    def stimulus_sensitivity(self, f, e=0.0, v=0.0, luminance=None, area=None):
        """Sensitivity 1/c_T at f (cycles/deg), luminance (cd/m2), square field of ``area`` deg2.

        ``e`` (deg) and ``v`` (deg/s) are ignored (foveal, static model) but validated and broadcast.
        ``luminance`` / ``area`` default to the static fields (100 cd/m2, 3600 deg2); NaN entries (unknown
        in a data set) fall back to them. Concrete negative or NaN inputs raise ValueError.
        """
        L = fill_nan(luminance, self.luminance)
        A = fill_nan(area, self.area)
        f, e, v, L, A = check_inputs("Barten.stimulus_sensitivity", f=f, e=e, v=v, luminance=L, area=A)
        return jnp.exp(self.log_sensitivity(f, e, v, L, A))

    def sensitivity(self, f, e=0.0, v=0.0):
        """Sensitivity at the default luminance (100 cd/m2) and field (60 x 60 deg); e, v ignored."""
        return self.stimulus_sensitivity(f, e, v)

    # ---------------------------------------------------------------- fast exact solvers
    # With concrete constants the peak, the falling limb's inverse and the perceptibility test are
    # evaluated from per-model scalars computed once at trace time (``_limb``); with traced constants
    # (fitting, grad w.r.t. the model) the generic solvers of CSFModel are used.
    def _limb_of(self, dtype, inverse: bool = True) -> _Limb | None:
        """The fast solvers' scalars for this model in ``dtype`` (None: traced constants, a dtype other
        than float32 / float64, or constants the fast path does not cover -- use the generic solvers).
        ``inverse=False``: the peak and the formula only (cheaper to build)."""
        dtype = jnp.dtype(dtype)
        if dtype not in (jnp.dtype(jnp.float32), jnp.dtype(jnp.float64)):
            return None
        vals = [getattr(self, name) for name in _FIELDS]
        if any(_is_tracer(x) for x in vals):
            return None
        # the values the generic path computes with (the fields cast to dtype), as float64
        consts = tuple(float(np.asarray(x).astype(dtype)) for x in vals)
        statics = (float(self.luminance), float(self.area), bool(self.stiles_crawford))
        return _limb(consts, *statics, dtype.name) if inverse else _limb_peak(consts, *statics)

    def _peak_frequency(self, e, v):
        """Peak frequency (cycles/deg) at the default luminance and area: for concrete constants the
        root of d ln S / du = 0 computed once (float64, to rounding); otherwise the generic search."""
        shape = jnp.broadcast_shapes(jnp.shape(e), jnp.shape(v))
        dtype = jnp.result_type(e, v, float)
        limb = self._limb_of(dtype, inverse=False)
        if limb is None:
            return super()._peak_frequency(e, v)
        return jnp.full(shape, limb.u_p, dtype)

    def is_perceptible(self, c, f, e=0.0, v=0.0):
        """True where ``c >= c_T(max(f, f_peak))`` at the default luminance and area (see
        :meth:`CSFModel.is_perceptible`; e, v ignored but broadcast). Concrete constants: one fused
        pass of the linear-domain form of Barten's formula, ``(c S)^4 >= 1`` (two exps and a square root,
        no log)::

            (c k0 e^(-a u^2))^2 m  >=  sqrt((1 + ra u^2) (1 + rb u^2)) (w1 m + w0),   u = max(f, f_peak)

        (u in cycles/deg, ``m = 1 - exp(-(u/u0)^2)``, constants of :class:`_Limb`), or ``c >= 1e30`` (the
        1e-30 floor of the sensitivity). Equal to the generic test up to rounding at the boundary."""
        c, f, e, v = check_inputs("is_perceptible", c=c, f=f, e=e, v=v)
        shape = jnp.broadcast_shapes(c.shape, f.shape, e.shape, v.shape)
        dtype = jnp.result_type(c, f, e, v, float)
        self = self._like(c, f, e, v)
        limb = self._limb_of(dtype, inverse=False)
        if limb is None:
            fe = jnp.maximum(f, self._peak_frequency_sg(e, v))
            out = _log_guard(c) + self.log_sensitivity(fe, e, v) >= 0
            return jnp.broadcast_to(out, shape)
        c, f = c.astype(dtype), f.astype(dtype)
        q = jnp.square(jnp.maximum(f, limb.u_p))
        _, m = _ex_m(limb, q)
        lhs = jnp.square(jnp.minimum(c, 1e30) * limb.k0 * jnp.exp(-limb.a * q)) * m
        rhs = jnp.sqrt((1.0 + limb.ra * q) * (1.0 + limb.rb * q)) * (limb.w1 * m + limb.w0)
        return jnp.broadcast_to((lhs >= rhs) | (c >= 1e30), shape)

    def _threshold_frequency(self, c, e, v):
        """Inverse of the falling limb (see :meth:`CSFModel.threshold_frequency`). Concrete constants: one
        fused elementwise pass -- ``s = ln(c S_peak)``, a piecewise Chebyshev start for u in ``sqrt(s)``
        (fitted once per model to the exact inverse, its error checked on a dense grid), then one Newton
        (float32) / Halley (float64) step on ``ln c + ln S(u) = 0`` in ``q = u^2`` (one exp and one log),
        so the result is the exact root to rounding. Implicit-function gradient (no forward cost)."""
        shape = jnp.broadcast_shapes(c.shape, e.shape, v.shape)
        dtype = jnp.result_type(c, e, v, float)
        limb = self._limb_of(dtype)
        if limb is None:
            return super()._threshold_frequency(c, e, v)
        c = jnp.broadcast_to(c, shape).astype(dtype)
        logc = jax.lax.stop_gradient(_log_guard(c))
        s = logc + limb.ln_s_p  # ln(c S_peak): visible iff >= 0
        # ... up to rounding: c = threshold_contrast(peak_frequency()) is visible (root: the peak)
        visible = s >= -8.0 * float(jnp.finfo(dtype).eps) * max(1.0, abs(limb.ln_s_p))
        saturated = s >= limb.s_max
        u = _limb_root(limb, logc)
        ok = visible & ~saturated
        u = implicit_solution(_tf_margin, jnp.where(ok, u, limb.u_p), ok, self, c)
        return jnp.where(visible, jnp.where(saturated, jnp.asarray(_F_HI, dtype), u), 0.0)

    def imperceptible_distance(self, c, theta, e=0.0, v=0.0):
        """Viewing-distance multiple beyond which a change of contrast ``c`` and angular size ``theta``
        (deg) is imperceptible (definition: :meth:`CSFModel.imperceptible_distance`). Barten's CSF
        depends on f only, so ``k = 2 theta threshold_frequency(c)`` exactly (0 where theta = 0 or c is
        invisible at every frequency); e (deg) and v (deg/s) are ignored but broadcast. Concrete
        constants: the fused closed-form-start solve of :meth:`_threshold_frequency`; gradients with
        respect to c and theta exact (implicit function theorem), with respect to the constants through
        the generic solver (traced constants)."""
        return super().imperceptible_distance(c, theta, e, v)


def _tf_margin(u, model, c):
    """ln c + ln S(u): the threshold-frequency equation (for the implicit-function derivative)."""
    return _log_guard(c) + model.log_sensitivity(u)


@eqx.filter_jit
def _jit_log_s(model, f, e, v, L, A):
    # one compiled kernel per shape/dtype: fast eager calls; inlined when traced inside an outer jit
    return model._log_s(f, e, v, L, A)


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
    if not -_LN_FLOOR - 1.0 > ln_s_p > _LN_FLOOR + 1.0:
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
    above = ls[:-1] > _LN_FLOOR
    if not (np.all(np.diff(ls)[above] < 0) and np.all(_np_dln_s(np.exp(lq[1:]), terms)[above] < 0)):
        return None
    s_max = pk.ln_s_p - max(_LN_FLOOR, float(ls[-1]))
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
    return _clenshaw(x, [pick([cf[j] for cf in limb.coeffs]) for j in range(deg)])


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

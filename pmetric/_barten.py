"""Barten's physical model of foveal contrast sensitivity [Bar99].

Reference: [Bar99], doi:10.1117/3.353254 (eq. 3.26 with the 2-D field size of ch. 3.4); also
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

The pupil formula uses log10 as in Barten's book (and [WY12]); the
``colour`` package uses the natural log. The formula is binocular; monocular sensitivity is sqrt(2)
lower. Only the product eta * p is identifiable from thresholds.
"""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp

from ._barten_limb import _FIELDS, _Limb, _ex_m, _limb, _limb_peak, _limb_root
from ._base import _F_HI, CSFModel, check_constants, check_inputs, float_param
from ._errors import PlodError
from ._inverse import implicit_solution
from ._numerics import LN_FLOOR, as_float, log_guard, safe_log, where_pos

__all__ = ["Barten"]

#: ln of the smallest (u / u0)^2 Barten's ln M_opt follows (see ``log_sensitivity``)
_LN_X_MIN = math.log(1e-36)


class Barten(CSFModel):
    """Barten's CSF [Bar99]: static, foveal, luminance- and field-size-dependent (see module docstring).

    ``stimulus_sensitivity(f, e, v, luminance, area)``: f in cycles/deg, luminance in cd/m2, area in
    deg2 (a square field X0 = Y0 = sqrt(area) deg). ``e`` and ``v`` are ignored (the model is foveal and
    static: wrap it in ``pmetric.Eccentric`` for eccentricity) but broadcast into the output shape.
    ``sensitivity(f, e, v)`` uses the static defaults ``luminance = 100`` cd/m2 and ``area = 3600`` deg2
    (X0 = Y0 = 60 deg, Barten's large-field condition). ``illuminance_sensitivity(u, E, sigma, x0, y0)``
    is the parametrization with the retinal illuminance E (Troland) and optical sigma (deg) given.
    Sensitivities are floored at 1e-30 (the optical MTF underflows at very high u).
    ``imperceptible_distance`` is ``2 theta threshold_frequency(c)`` exactly (the generic hook: the
    model depends on f only); with concrete constants it uses the fused solve of ``_threshold_frequency``.

    Fitted constants (array fields): ``sigma_0`` (deg), ``c_ab`` (deg/mm), ``k``, ``t`` (s), ``x_max``,
    ``y_max`` (deg), ``n_max`` (cycles), ``eta``, ``p`` (photons/(s deg2 Td)), ``phi_0`` (s deg2),
    ``u_0`` (cycles/deg). Static switch ``stiles_crawford`` (default True) applies the Stiles-Crawford
    correction to the Troland value.
    """

    sigma_0: jax.Array = eqx.field(converter=float_param, default=0.5 / 60)
    c_ab: jax.Array = eqx.field(converter=float_param, default=0.08 / 60)
    k: jax.Array = eqx.field(converter=float_param, default=3.0)
    t: jax.Array = eqx.field(converter=float_param, default=0.1)
    x_max: jax.Array = eqx.field(converter=float_param, default=12.0)
    y_max: jax.Array = eqx.field(converter=float_param, default=12.0)
    n_max: jax.Array = eqx.field(converter=float_param, default=15.0)
    eta: jax.Array = eqx.field(converter=float_param, default=0.03)
    p: jax.Array = eqx.field(converter=float_param, default=1.2274e6)
    phi_0: jax.Array = eqx.field(converter=float_param, default=3e-8)
    u_0: jax.Array = eqx.field(converter=float_param, default=7.0)
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
                raise PlodError(f"Barten: {name} must be a scalar, got shape {jnp.shape(getattr(self, name))}")
        for name in ("luminance", "area"):
            val = getattr(self, name)
            if not (isinstance(val, (int, float)) and math.isfinite(val) and val > 0):
                raise PlodError(f"Barten: default {name} must be a finite positive number, got {val!r}")
        check_constants(self)

    # ---------------------------------------------------------------- ancillary formulas
    def pupil_diameter(self, luminance, area):
        """Pupil diameter (mm) for a field of ``luminance`` cd/m2 and ``area`` = X0 Y0 deg2 [Bar99]."""
        la = as_float(luminance) * as_float(area)
        lg = where_pos(la, lambda s: jnp.log10(s / 1600.0), jnp.full_like(la, -60.0))
        return 5.0 - 3.0 * jnp.tanh(0.4 * lg)

    def retinal_illuminance(self, luminance, d):
        """Retinal illuminance (Troland) of ``luminance`` cd/m2 through a pupil of ``d`` mm."""
        d = as_float(d)
        e = math.pi * d**2 / 4.0 * as_float(luminance)
        if self.stiles_crawford:
            e = e * (1.0 - (d / 9.7) ** 2 + (d / 12.4) ** 4)
        return e

    def optical_sigma(self, d):
        """Standard deviation (deg) of the eye's line-spread function for a pupil of ``d`` mm."""
        s2 = self.sigma_0**2 + (self.c_ab * as_float(d)) ** 2
        return where_pos(s2, jnp.sqrt, jnp.zeros_like(s2))

    # ---------------------------------------------------------------- the CSF
    def log_illuminance_sensitivity(self, u, E, sigma, x0, y0=None):
        """Natural log of ``illuminance_sensitivity`` (no validation), floored at ln(1e-30)."""
        u, E, sigma, x0 = as_float(u), as_float(E), as_float(sigma), as_float(x0)
        y0 = x0 if y0 is None else as_float(y0)
        inv_x2 = where_pos(x0, lambda s: 1.0 / s**2, jnp.full_like(x0, jnp.inf))
        inv_y2 = where_pos(y0, lambda s: 1.0 / s**2, jnp.full_like(y0, jnp.inf))
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
        # ln M_opt's ln(1 - exp(-x)): for x < 1e-4 in log form, 2 ln(u / u0) - x / 2 + x^2 / 24 (error
        # O(x^3)), so the gradient never holds 1 / x (in float32 it overflowed to -inf for f of 1e-18 to
        # 3e-14 cycles/deg), held at x = 1e-36 below (f under about 1e-17 cycles/deg: there the threshold's
        # gradient, ~threshold / f, would leave float32's range); the direct form (double where) elsewhere
        small = x < 1e-4
        ln_small = jnp.maximum(2.0 * (jnp.log(us) - jnp.log(self.u_0)) - 0.5 * x + x * x / 24.0, _LN_X_MIN)
        ln_big = where_pos(jnp.where(small, 1.0, x), lambda s: jnp.log(-jnp.expm1(-s)), jnp.full_like(x, LN_FLOOR))
        ln_m = jnp.where(small, ln_small, ln_big)
        ln_noise = jnp.logaddexp(-(safe_log(self.eta * self.p) + jnp.log(Es)), safe_log(self.phi_0) - ln_m)
        ln_s = (
            -2.0 * math.pi**2 * sigma**2 * us**2
            - safe_log(self.k)
            - 0.5 * (math.log(2.0) - safe_log(self.t) + 0.5 * (ln_mx + ln_my) + ln_noise)
        )
        return jnp.where(valid, jnp.maximum(ln_s, LN_FLOOR), LN_FLOOR)

    def illuminance_sensitivity(self, u, E, sigma, x0, y0=None):
        """Barten's S for spatial frequency ``u`` (cycles/deg), retinal illuminance ``E`` (Troland),
        optical line-spread ``sigma`` (deg) and field size ``x0`` by ``y0`` deg (``y0`` defaults to x0).

        Uses the model's k, T, Xmax, Ymax, Nmax, eta, p, Phi0 and u0 (not sigma_0, c_ab or the pupil).
        """
        u, E, sigma, x0, y0 = check_inputs("Barten.illuminance_sensitivity", u=u, E=E, sigma=sigma, x0=x0, y0=y0)
        return jnp.exp(self.log_illuminance_sensitivity(u, E, sigma, x0, y0))

    def _stimulus_log_sensitivity(self, f, e, v, luminance=None, area=None):
        """ln S (floored at ln 1e-30); ``luminance`` / ``area`` default to the static fields."""
        L = as_float(self.luminance if luminance is None else luminance)
        A = as_float(self.area if area is None else area)
        # the defaults are weakly typed: under x64 they must not promote float32 inputs to float64
        dtype = jnp.result_type(f, e, v, L, A)
        return _jit_log_s(self, f, e, v, L.astype(dtype), A.astype(dtype))

    def _stimulus_sensitivity(self, f, e, v, luminance=None, area=None):
        return jnp.exp(self._stimulus_log_sensitivity(f, e, v, luminance, area))

    def _log_sensitivity(self, f, e, v):
        return self._stimulus_log_sensitivity(f, e, v)

    def _log_s(self, f, e, v, L, A):
        d = self.pupil_diameter(L, A)
        E = self.retinal_illuminance(L, d)
        sigma = self.optical_sigma(d)
        inv_a = where_pos(A, lambda s: 1.0 / s, jnp.full_like(A, jnp.inf))
        ln_s = self._ln_s(f, E, sigma, inv_a, inv_a)
        shape = jnp.broadcast_shapes(jnp.shape(ln_s), jnp.shape(e), jnp.shape(v))
        return jnp.broadcast_to(ln_s, shape)

    # ---------------------------------------------------------------- fast exact solvers
    # With concrete constants the peak, the falling limb's inverse and the perceptibility test are
    # evaluated from per-model scalars computed once at trace time (``_limb``); with traced constants
    # (fitting, grad w.r.t. the model) the generic solvers of CSFModel are used.
    def _limb_of(self, dtype, inverse: bool = True) -> _Limb | None:
        """The fast solvers' scalars for this model in ``dtype`` (None: traced constants, a dtype other
        than float32 / float64, or constants the fast path does not cover -- use the generic solvers).
        ``inverse=False``: the peak and the formula only (cheaper to build)."""
        vals = self._concrete_fields(_FIELDS, dtype)
        if vals is None:
            return None
        consts = tuple(float(x) for x in vals)
        statics = (float(self.luminance), float(self.area), bool(self.stiles_crawford))
        return _limb(consts, *statics, jnp.dtype(dtype).name) if inverse else _limb_peak(consts, *statics)

    def _peak_frequency(self, e, v):
        """Peak frequency (cycles/deg) at the default luminance and area: for concrete constants the
        root of d ln S / du = 0 computed once (float64, to rounding); otherwise the generic search."""
        shape = jnp.broadcast_shapes(jnp.shape(e), jnp.shape(v))
        dtype = jnp.result_type(e, v, float)
        limb = self._limb_of(dtype, inverse=False)
        if limb is None:
            return super()._peak_frequency(e, v)
        return jnp.full(shape, limb.u_p, dtype)

    def _is_perceptible(self, c, f, e, v):
        """True where ``c >= c_T(max(f, f_peak))`` at the default luminance and area (see
        :meth:`CSFModel.is_perceptible`; e, v ignored but broadcast). Concrete constants: one fused
        pass of the linear-domain form of Barten's formula, ``(c S)^4 >= 1`` (two exps and a square root,
        no log)::

            (c k0 e^(-a u^2))^2 m  >=  sqrt((1 + ra u^2) (1 + rb u^2)) (w1 m + w0),   u = max(f, f_peak)

        (u in cycles/deg, ``m = 1 - exp(-(u/u0)^2)``, constants of :class:`_Limb`), or ``c >= 1e30`` (the
        1e-30 floor of the sensitivity). Equal to the generic test up to rounding at the boundary."""
        shape = jnp.broadcast_shapes(c.shape, f.shape, e.shape, v.shape)
        dtype = jnp.result_type(c, f, e, v, float)
        limb = self._limb_of(dtype, inverse=False)
        if limb is None:
            return super()._is_perceptible(c, f, e, v)
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
        logc = jax.lax.stop_gradient(log_guard(c))
        s = logc + limb.ln_s_p  # ln(c S_peak): visible iff >= 0
        # ... up to rounding: c = threshold_contrast(peak_frequency()) is visible (root: the peak)
        visible = s >= -8.0 * float(jnp.finfo(dtype).eps) * max(1.0, abs(limb.ln_s_p))
        saturated = s >= limb.s_max
        u = _limb_root(limb, logc)
        ok = visible & ~saturated
        u = implicit_solution(_tf_margin, jnp.where(ok, u, limb.u_p), ok, self, c)
        return jnp.where(visible, jnp.where(saturated, jnp.asarray(_F_HI, dtype), u), 0.0)

def _tf_margin(u, model, c):
    """ln c + ln S(u): the threshold-frequency equation (for the implicit-function derivative)."""
    z = jnp.zeros((), u.dtype)
    return log_guard(c) + model._log_sensitivity(u, z, z)


@eqx.filter_jit
def _jit_log_s(model, f, e, v, L, A):
    # one compiled kernel per shape/dtype: fast eager calls; inlined when traced inside an outer jit
    return model._log_s(f, e, v, L, A)

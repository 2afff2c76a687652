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

The pupil formula uses log10 as in Barten's book (and Watson & Yellott 2012, J. Vis. 12(10):12); the
``colour`` package uses the natural log. The formula is binocular; monocular sensitivity is sqrt(2)
lower. Only the product eta * p is identifiable from thresholds.
"""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp

from ._base import CSFModel, check_inputs
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
        return _jit_log_s(self, f, e, v, L, A)

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


@eqx.filter_jit
def _jit_log_s(model, f, e, v, L, A):
    # one compiled kernel per shape/dtype: fast eager calls; inlined when traced inside an outer jit
    return model._log_s(f, e, v, L, A)

"""Classic analytic contrast-sensitivity functions, with exact inversions.

* :class:`ManosSakrison` -- Manos & Sakrison 1974 (IEEE Trans. Inf. Theory 20(4)), as printed in
  Reddy 2001 (seed 000) Eq 1 with the published constant 0.114.
* :class:`KellyAbstract` -- Kelly 1975's abstract CSF ``alpha^2 e^-alpha`` scaled by delta with the
  temporal-retina cortical magnification (Luebke et al. 2000, seed 001 Eq 1-2, 5).
* :class:`KellySpatioTemporal` -- Kelly 1979 (JOSA 69(10):1340) stabilized spatio-temporal CSF (seed 001
  Eq 4) and Reddy's refit (seed 000 Eq 2).
* :class:`RovamoVirsu` -- Rovamo & Virsu 1979 (Exp. Brain Res. 37:495) cortical magnification
  (seed 000 Eq 3), and :class:`Eccentric` which applies a magnification to any foveal CSF.

Units: f cycles/deg, e deg, v deg/s, c Michelson contrast (0..1), theta deg.
"""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from ._base import CSFModel, _is_tracer, _log_guard, check_inputs
from ._inverse import implicit_root, implicit_solution, lambertw_m1, largest_crossing
from ._kelly import kelly_clamped_root, kelly_fast, kelly_slow, kelly_structure, rare_update

__all__ = ["ManosSakrison", "KellyAbstract", "KellySpatioTemporal", "RovamoVirsu", "Eccentric"]


def _param(value, name: str, *, positive: bool = True):
    """A model constant as a float array; concrete values are checked (finite, > 0)."""
    arr = jnp.asarray(value, dtype=jnp.result_type(float))
    if not _is_tracer(arr):
        a = np.asarray(arr)
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name} must be finite, got {value!r}")
        if positive and np.any(a <= 0):
            raise ValueError(f"{name} must be > 0, got {value!r}")
    return arr


def _pow_pos(x, p):
    """x**p for x >= 0 with finite value and gradient at x = 0 (double-where)."""
    pos = x > 0
    xs = jnp.where(pos, x, 1.0)
    return jnp.where(pos, jnp.exp(p * jnp.log(xs)), 0.0)


# --------------------------------------------------------------------------- Manos-Sakrison
_MS_A = 0.0192
_MS_XP = 0.899564265442084  # argmax of (a + x) exp(-x^1.1): solves 1/(a+x) = 1.1 x^0.1
_MS_LOGAMAX = math.log(2.6 * (_MS_A + _MS_XP)) - _MS_XP**1.1  # ln A_max, A_max = 0.98088
_MS_GMAX = math.log(_MS_A + _MS_XP) - _MS_XP**1.1
_MS_SMAX = 60.0  # start polynomial fitted for s = ln(P c) in [0, 60]


def _ms_bisect_root(s):
    """Falling-limb root x(s) of ln(a + x) - x^1.1 - G_max + s = 0 by 200-step float64 bisection (numpy)."""
    lo = np.full_like(s, _MS_XP)
    hi = np.full_like(s, 200.0)
    for _ in range(200):
        m = 0.5 * (lo + hi)
        ok = np.log(_MS_A + m) - m**1.1 - _MS_GMAX + s >= 0
        lo = np.where(ok, m, lo)
        hi = np.where(ok, hi, m)
    return lo


def _ms_start_coeffs(deg: int = 16):
    """Chebyshev coefficients of the falling-limb root x(s) in r = sqrt(s), s = ln(P c) in [0, 60].

    Interpolated at 4 deg Chebyshev nodes; x(s) is analytic in r (sqrt branch at the peak), so degree 16
    reaches the conditioning floor of the root itself (|error| < 7e-8 in x, about 1e-8 near the peak
    where g is flat). Only a starting point: one Newton step (float32) or one Halley step (float64)
    follows, whose error is then at the precision of g."""
    k = np.arange(4 * deg)
    t = np.cos(np.pi * (k + 0.5) / (4 * deg))
    r = (t + 1.0) * (0.5 * math.sqrt(_MS_SMAX))
    cheb = np.polynomial.chebyshev.chebfit(t, _ms_bisect_root(r * r), deg)
    return tuple(float(x) for x in cheb)


_MS_CHEB = _ms_start_coeffs()
_MS_DG_FLOOR = -1e-18  # d g/dx on the falling limb is < 0; kept away from 0 at the peak


@jax.custom_jvp
def _ms_root(s):
    """Falling-limb root x >= x_p of ``ln(a + x) - x^1.1 - G_max + s = 0`` for ``s >= 0`` (elementwise).

    Start: Chebyshev fit in sqrt(s) (clipped to the fitted range s <= 60), then one Newton step in
    float32 or one Halley step in float64 (the start is within 1e-7, so either lands at the precision
    of g). Derivative by the implicit-function theorem: dx/ds = -1 / g'(x) (custom_jvp; the forward
    pass evaluates nothing for it)."""
    r = jnp.sqrt(jnp.minimum(s, _MS_SMAX))
    x = _clenshaw(r * (2.0 / math.sqrt(_MS_SMAX)) - 1.0, _MS_CHEB)
    x = jnp.maximum(x, _MS_XP * (1 + 1e-6))
    ax = _MS_A + x
    p01 = jnp.exp(0.1 * jnp.log(x))  # x^0.1
    gx = jnp.log(ax) - x * p01 - _MS_GMAX + s
    dg = jnp.minimum(1.0 / ax - 1.1 * p01, _MS_DG_FLOOR)
    if s.dtype == jnp.float64:  # Halley: cubic convergence from the ~1e-8 start
        d2g = -1.0 / (ax * ax) - 0.11 * p01 / x
        step = gx / (dg - 0.5 * gx * d2g / dg)
    else:
        step = gx / dg
    return jnp.maximum(x - step, _MS_XP)


@_ms_root.defjvp
def _ms_root_jvp(primals, tangents):
    (s,), (ds,) = primals, tangents
    x = _ms_root(s)
    dg = jnp.minimum(1.0 / (_MS_A + x) - 1.1 * jnp.exp(0.1 * jnp.log(x)), _MS_DG_FLOOR)
    return x, -ds / dg


def _ms_log_shape(x):
    """ln[(a + x) exp(-x^1.1)] - ln[(a + x_p) exp(-x_p^1.1)] <= 0 for x = b f >= 0."""
    x = jnp.minimum(x, 1e30)
    return jnp.log(_MS_A + x) - _pow_pos(x, 1.1) - _MS_GMAX


class ManosSakrison(CSFModel):
    """Manos & Sakrison (1974) foveal CSF, seed 000 Eq 1 (Reddy 2001) with the published constant.

    Normalized shape ``A(f) = 2.6 (0.0192 + b f) exp(-(b f)^1.1)`` with ``b = 0.114`` (``printed_constant=True``
    uses the seed's misprint 0.144); A peaks at 0.9809 at 7.89 cycles/deg. Absolute sensitivity
    ``S(f) = peak_sensitivity * A(f) / A_max``. Default ``peak_sensitivity = 250``: with it contrast 1
    is visible up to 61 cycles/deg, matching the 60 cycles/deg acuity limit of seed 000 (Reddy's G(0)).
    No eccentricity or velocity dependence (``e`` and ``v`` are accepted and ignored; wrap it in
    :class:`Eccentric` for an eccentricity term).

    Domain: f in [0, 1e30] cycles/deg (values and gradients finite, f = 0 included); c in [0, 1].
    ``threshold_frequency`` is exact for ``peak_sensitivity * c`` up to e^60.
    """

    peak_sensitivity: jax.Array
    printed_constant: bool = eqx.field(static=True, default=False)

    inputs: ClassVar[tuple[str, ...]] = ("f",)
    param_bounds: ClassVar[dict] = {"peak_sensitivity": (1e-6, None)}

    def __init__(self, peak_sensitivity=250.0, printed_constant: bool = False):
        self.peak_sensitivity = _param(peak_sensitivity, "ManosSakrison.peak_sensitivity")
        self.printed_constant = bool(printed_constant)

    @property
    def _b(self) -> float:
        return 0.144 if self.printed_constant else 0.114

    @staticmethod
    def shape(f, printed_constant: bool = False):
        """The normalized shape A(f) of seed 000 Eq 1 (peak 0.9809 at 7.89 cycles/deg); f cycles/deg."""
        b = 0.144 if printed_constant else 0.114
        x = jnp.minimum(jnp.asarray(f, jnp.result_type(f, float)) * b, 1e30)
        return 2.6 * (_MS_A + x) * jnp.exp(-_pow_pos(x, 1.1))

    def log_sensitivity(self, f, e=0.0, v=0.0):
        f = jnp.asarray(f)
        logp = jnp.log(self.peak_sensitivity)
        out = logp + _ms_log_shape(self._b * f)
        return jnp.broadcast_to(out, jnp.broadcast_shapes(out.shape, jnp.shape(e), jnp.shape(v)))

    def sensitivity(self, f, e=0.0, v=0.0):
        """S(f) = peak_sensitivity A(f)/A_max (e, v ignored); broadcast shape of f, e, v."""
        f, e, v = check_inputs("sensitivity", f=f, e=e, v=v)
        self = self._like(f, e, v)
        return jnp.exp(self.log_sensitivity(f, e, v))

    def _peak_frequency(self, e, v):
        shape = jnp.broadcast_shapes(jnp.shape(e), jnp.shape(v))
        dtype = jnp.result_type(e, v, self.peak_sensitivity, float)
        return jnp.full(shape, _MS_XP / self._b, dtype)

    def _threshold_frequency(self, c, e, v):
        s = _log_guard(c) + jnp.log(self.peak_sensitivity)  # ln(c S_peak): visible iff >= 0
        s = jnp.broadcast_to(s, jnp.broadcast_shapes(s.shape, e.shape, v.shape))
        visible = s >= 0
        x = _ms_root(jnp.where(visible, s, 0.0))  # double where: no gradient leaks from invisible c
        return jnp.where(visible, x / self._b, 0.0)

    def imperceptible_distance(self, c, theta, e=0.0, v=0.0):
        """Closed in terms of the threshold frequency (no e, v dependence): k = 2 theta f*(c).
        See :meth:`CSFModel.imperceptible_distance` for the definition; theta in deg."""
        c, theta, e, v = check_inputs("imperceptible_distance", c=c, theta=theta, e=e, v=v)
        self = self._like(c, theta, e, v)
        return 2.0 * theta * self._threshold_frequency(c, e, v)


def _clenshaw(t, coeffs):
    """Chebyshev series sum_k coeffs[k] T_k(t), elementwise (Clenshaw recurrence)."""
    b1 = jnp.zeros_like(t)
    b2 = jnp.zeros_like(t)
    for ck in coeffs[:0:-1]:
        b1, b2 = 2.0 * t * b1 - b2 + ck, b1
    return t * b1 - b2 + coeffs[0]


# --------------------------------------------------------------------------- Kelly abstract
_E2_4 = math.e**2 / 4.0  # 1 / max(alpha^2 e^-alpha), attained at alpha = 2


class KellyAbstract(CSFModel):
    """Kelly's abstract CSF with delta scaling and cortical magnification (seed 001 Eq 1-5).

    ``1/c_T = delta alpha^2 exp(-alpha)``, ``alpha = 2 (1 + 0.29 e) f / f0``. With ``f0 = 2`` this is
    the seed's ``alpha = (1 + 0.29 e) f`` exactly; ``f0`` (cycles/deg) is the foveal peak frequency,
    a fittable frequency scale (seed 001 measured f in units of its own display; its ``delta = 0.4``
    makes every contrast below 1 invisible when f is in cycles/deg). Defaults: ``f0 = 4`` cycles/deg
    (a realistic foveal peak) and ``delta = 200 e^2 / 4 = 369.45`` so that the peak sensitivity is 200.
    The peak sensitivity is ``4 delta / e^2`` at every eccentricity; the peak frequency is
    ``f0 / (1 + 0.29 e)``. No velocity term (``v`` accepted and ignored).

    Inversions are closed forms through the lower Lambert W branch:
    ``alpha* = -2 W_{-1}(-1 / (2 sqrt(delta c)))`` on the falling limb (alpha >= 2).

    Domain: f in [0, 1e30] cycles/deg, e in [0, 1e4] deg, c in [0, 1]; values and gradients finite.
    """

    delta: jax.Array
    f0: jax.Array

    inputs: ClassVar[tuple[str, ...]] = ("f", "e")
    param_bounds: ClassVar[dict] = {"delta": (1e-6, None), "f0": (1e-3, None)}

    def __init__(self, delta=200.0 * _E2_4, f0=4.0):
        self.delta = _param(delta, "KellyAbstract.delta")
        self.f0 = _param(f0, "KellyAbstract.f0")

    def _alpha(self, f, e):
        return 2.0 * (1.0 + 0.29 * e) * jnp.minimum(f, 1e30) / self.f0

    def log_sensitivity(self, f, e=0.0, v=0.0):
        a = self._alpha(jnp.asarray(f), jnp.asarray(e))
        out = jnp.log(self.delta) + 2.0 * _log_guard(a) - a
        return jnp.broadcast_to(out, jnp.broadcast_shapes(out.shape, jnp.shape(v)))

    def sensitivity(self, f, e=0.0, v=0.0):
        """S = delta alpha^2 exp(-alpha), alpha = 2 (1 + 0.29 e) f / f0; broadcast shape of f, e, v."""
        f, e, v = check_inputs("sensitivity", f=f, e=e, v=v)
        self = self._like(f, e, v)
        a = self._alpha(f, e)
        out = self.delta * a * a * jnp.exp(-a)
        return jnp.broadcast_to(out, jnp.broadcast_shapes(out.shape, jnp.shape(v)))

    def _peak_frequency(self, e, v):
        out = self.f0 / (1.0 + 0.29 * e)
        return jnp.broadcast_to(out, jnp.broadcast_shapes(out.shape, jnp.shape(v)))

    def _alpha_star(self, c):
        """Falling-limb alpha where delta c alpha^2 e^-alpha = 1; visible mask (delta c >= e^2/4)."""
        dc = self.delta * c
        visible = dc >= _E2_4
        dcs = jnp.where(visible, dc, 1.0)
        x = jnp.where(visible, -0.5 * lax.rsqrt(dcs), -0.25)
        return -2.0 * lambertw_m1(x), visible

    def is_perceptible(self, c, f, e=0.0, v=0.0):
        """c >= c_T(max(f, f_peak)); fused closed form (see :meth:`CSFModel.is_perceptible`)."""
        c, f, e, v = check_inputs("is_perceptible", c=c, f=f, e=e, v=v)
        self = self._like(c, f, e, v)
        a = jnp.maximum(self._alpha(f, e), 2.0)
        out = _log_guard(c) + jnp.log(self.delta) + 2.0 * jnp.log(a) - a >= 0
        return jnp.broadcast_to(out, jnp.broadcast_shapes(out.shape, v.shape))

    def _threshold_frequency(self, c, e, v):
        a, visible = self._alpha_star(c)
        f = a * self.f0 / (2.0 * (1.0 + 0.29 * e))
        out = jnp.where(visible, f, 0.0)
        return jnp.broadcast_to(out, jnp.broadcast_shapes(out.shape, v.shape))

    def imperceptible_distance(self, c, theta, e=0.0, v=0.0):
        """Closed form: at distance multiple k, alpha(k) = (k + 0.29 e) / (theta f0) grows with k, so
        ``k = max(0, theta f0 alpha* - 0.29 e)`` (0 where c is invisible even at the peak).
        See :meth:`CSFModel.imperceptible_distance` for the definition; theta in deg."""
        c, theta, e, v = check_inputs("imperceptible_distance", c=c, theta=theta, e=e, v=v)
        self = self._like(c, theta, e, v)
        a, visible = self._alpha_star(c)
        k = jnp.maximum(theta * self.f0 * a - 0.29 * e, 0.0)
        out = jnp.where(visible, k, 0.0)
        return jnp.broadcast_to(out, jnp.broadcast_shapes(out.shape, v.shape))


# --------------------------------------------------------------------------- Kelly spatio-temporal
_KELLY_CONSTANTS = {
    # a0, a1 in [a0 + a1 |log10(v/3)|^3] v f^2 exp(-b f (v + 2))
    "kelly1979": (6.1, 7.3, 2.0 / 45.9),  # seed 001 Eq 4 (Kelly 1979)
    "reddy": (250.1, 299.3, 5.5 * math.log(10.0) / 45.9),  # seed 000 Eq 2: 10^(-5.5 f (v+2)/45.9)
}


def _kelly_c0():
    """max over t > 0 of 6 t / (1 + t^3) - 9 t^4 / (1 + t^3)^2 (curvature bound of ln(a0 + a1 |x|^3))."""
    t = np.linspace(1e-4, 5.0, 200001)
    return float((6 * t / (1 + t**3) - 9 * t**4 / (1 + t**3) ** 2).max()) * (1 + 1e-6)


_KELLY_C0 = _kelly_c0()  # 2.2300


def _kelly_margin_k(k, model, c, theta, v):
    """The fused margin of :class:`KellySpatioTemporal` at distance multiple ``k`` (for implicit
    derivatives)."""
    return model._margin(c, k, theta, v)


class KellySpatioTemporal(CSFModel):
    """Kelly (1979) stabilized spatio-temporal CSF: sensitivity to a grating drifting at ``v`` deg/s.

    ``S(f, v) = [a0 + a1 |log10(v/3)|^3] v f^2 exp(-b f (v + 2))``. ``constants="kelly1979"``:
    a0 = 6.1, a1 = 7.3, b = 2/45.9 (seed 001 Eq 4); ``"reddy"``: a0 = 250.1, a1 = 299.3,
    b = 5.5 ln(10)/45.9 (seed 000 Eq 2, ``10^(-5.5 f (v+2)/45.9)``). The fit is valid for v > 0.1 deg/s:
    velocities below 0.1 deg/s (including 0, a stabilized/tracked target) are treated as 0.1 deg/s.
    Peak frequency ``2 / (b (v + 2))`` (9.18 cycles/deg at v = 3 for Kelly's constants). No eccentricity
    term (``e`` ignored; wrap in :class:`Eccentric`).

    ``threshold_frequency`` is a closed form (Lambert W, as for :class:`KellyAbstract` with
    ``delta = K(v) v / (b (v+2))^2``). ``imperceptible_distance`` is a direct solve (closed form where
    the answer lies beyond ``k = 10 v``, monotone Newton on a margin that is concave in ``k / v``
    below it, certified brackets for the rare rest; see the method and ``_kelly.py``).

    Domain: f in [0, 1e30], v in [0, 1e4]; values and gradients finite.
    """

    a0: jax.Array
    a1: jax.Array
    b: jax.Array
    constants: str = eqx.field(static=True, default="kelly1979")

    inputs: ClassVar[tuple[str, ...]] = ("f", "v")
    param_bounds: ClassVar[dict] = {"a0": (1e-6, None), "a1": (0.0, None), "b": (1e-6, None)}

    def __init__(self, constants: str = "kelly1979", *, a0=None, a1=None, b=None):
        if constants not in _KELLY_CONSTANTS:
            raise ValueError(f"unknown Kelly constant set {constants!r}; choose one of {sorted(_KELLY_CONSTANTS)}")
        d0, d1, db = _KELLY_CONSTANTS[constants]
        self.constants = constants
        self.a0 = _param(d0 if a0 is None else a0, "KellySpatioTemporal.a0")
        self.a1 = _param(d1 if a1 is None else a1, "KellySpatioTemporal.a1", positive=False)
        self.b = _param(db if b is None else b, "KellySpatioTemporal.b")

    @staticmethod
    def _v(v):
        return jnp.clip(v, 0.1, 1e30)

    def _log_amp(self, v):
        """ln(K(v) v) for the clamped velocity."""
        lv = jnp.abs(jnp.log10(v / 3.0))
        return jnp.log(self.a0 + self.a1 * lv * lv * lv) + jnp.log(v)

    def log_sensitivity(self, f, e=0.0, v=0.0):
        f = jnp.minimum(jnp.asarray(f), 1e30)
        vv = self._v(jnp.asarray(v))
        out = self._log_amp(vv) + 2.0 * _log_guard(f) - self.b * f * (vv + 2.0)
        return jnp.broadcast_to(out, jnp.broadcast_shapes(out.shape, jnp.shape(e)))

    def sensitivity(self, f, e=0.0, v=0.0):
        """S(f, v) of Kelly 1979 (v clamped to >= 0.1 deg/s); broadcast shape of f, e, v."""
        f, e, v = check_inputs("sensitivity", f=f, e=e, v=v)
        self = self._like(f, e, v)
        return jnp.exp(self.log_sensitivity(f, e, v))

    def _peak_frequency(self, e, v):
        out = 2.0 / (self.b * (self._v(v) + 2.0))
        return jnp.broadcast_to(out, jnp.broadcast_shapes(out.shape, jnp.shape(e)))

    def is_perceptible(self, c, f, e=0.0, v=0.0):
        """Fused closed form of :meth:`CSFModel.is_perceptible`."""
        c, f, e, v = check_inputs("is_perceptible", c=c, f=f, e=e, v=v)
        self = self._like(c, f, e, v)
        vv = self._v(v)
        beta = self.b * (vv + 2.0)
        a = jnp.maximum(beta * jnp.minimum(f, 1e30), 2.0)  # alpha = beta f, clamped at the peak
        out = _log_guard(c) + self._log_amp(vv) - 2.0 * jnp.log(beta) + 2.0 * jnp.log(a) - a >= 0
        return jnp.broadcast_to(out, jnp.broadcast_shapes(out.shape, e.shape))

    def _threshold_frequency(self, c, e, v):
        vv = self._v(v)
        beta = self.b * (vv + 2.0)
        log_dc = _log_guard(c) + self._log_amp(vv) - 2.0 * jnp.log(beta)  # ln(delta_eff c)
        visible = log_dc >= math.log(_E2_4)
        x = jnp.where(visible, -0.5 * jnp.exp(-0.5 * jnp.where(visible, log_dc, 0.0)), -0.25)
        out = jnp.where(visible, -2.0 * lambertw_m1(x) / beta, 0.0)
        return jnp.broadcast_to(out, jnp.broadcast_shapes(out.shape, e.shape))

    def _margin(self, c, k, theta, v):
        """Fused ``log c - log c_T(max(f, f_peak))`` at distance multiple k (f = k / 2 theta, v / k)."""
        vv = self._v(v / k)
        beta = self.b * (vv + 2.0)
        a = jnp.maximum(beta * k / (2.0 * theta), 2.0)
        return _log_guard(c) + self._log_amp(vv) - 2.0 * jnp.log(beta) + 2.0 * jnp.log(a) - a

    def imperceptible_distance(self, c, theta, e=0.0, v=0.0):
        """See :meth:`CSFModel.imperceptible_distance`; theta deg, v deg/s. Direct solve (``_kelly.py``):

        1. For ``k >= 10 v`` the retinal velocity v/k is clamped at 0.1 deg/s and perceptibility falls
           with k; where the change is perceptible at ``k = 10 v`` (or ``v = 0``) the answer is the root
           of ``2 ln y - 1.05 y + C`` (``y = b k / theta``; the Lambert W closed form
           ``k0 = 2 theta f*(c, 0.1)``), found by Newton from a fitted start within 1e-5 of it.
        2. Elsewhere every perceptible k is below ``10 v``. In ``s = k / v`` the margin on the falling
           limb is ``h(s) = ln c + ln K(1/s) + ln s - 2 A s + 2 ln(A / b) - A`` (``A = b v / 2 theta``),
           strictly concave in s for these constants (checked per model by :func:`kelly_structure`):
           Newton from an upper bound descends monotonically onto its largest root (every iterate is an
           upper bound, so k errs on the conservative side, converged to 1e-5 relative) or certifies
           that there is none. Below the peak frequency the margin is a fixed function of ``ln(v / k)``
           whose local maxima are found once per model; a root there is bracketed from them.
           Steps 1 and 2 are one elementwise pass of four Newton steps (:func:`kelly_fast`).
        3. The few elements that pass cannot settle (a root close to a tangency, or a root below the
           peak frequency; about 1 in 1000 random inputs) are gathered and solved with certified
           brackets (:func:`kelly_slow`, :func:`kelly_clamped_root`).
        Constants for which concavity cannot be certified (``a1 / a0`` above about 1.37; Kelly's and
        Reddy's are 1.197) fall back to a scan: monotone Newton where the margin is concave in ln k,
        a 129-point grid plus safeguarded Newton elsewhere (it can miss a perceptible window narrower
        than one grid step).
        Gradients: implicit-function theorem on the fused margin.
        """
        c, theta, e, v = check_inputs("imperceptible_distance", c=c, theta=theta, e=e, v=v)
        self = self._like(c, theta, e, v)
        shape = jnp.broadcast_shapes(c.shape, theta.shape, e.shape, v.shape)
        dtype = jnp.result_type(c, theta, e, v, float)
        c, theta, v = (jnp.broadcast_to(x, shape).astype(dtype) for x in (c, theta, v))
        pos = theta > 0
        th = jnp.where(pos, theta, 1.0)
        sg = lax.stop_gradient
        ms, c_, t_, v_ = sg((self, c, theta, v))
        if _is_tracer(self.a0) or _is_tracer(self.a1):
            struct = kelly_structure(ms.a0, ms.a1, dtype)
        else:  # concrete constants (the usual case): decide the solver at trace time
            with jax.ensure_compile_time_eval():
                struct = kelly_structure(self.a0, self.a1, dtype)

        def direct(_):
            # one elementwise pass from the raw inputs (nothing else reads its intermediates, so XLA
            # keeps it one fused loop): k, 0 = none, NaN = undecided
            w = kelly_fast(ms.a0, ms.a1, ms.b, c_, jnp.where(t_ > 0, t_, 1.0), v_, struct)
            w = jnp.where(t_ > 0, w, 0.0)

            def slow(c1, t1, v1):  # certified brackets and the Lambert W closed form
                k0 = kelly_clamped_root(ms.a0, ms.a1, ms.b, c1, t1)
                k, found = kelly_slow(ms.a0, ms.a1, ms.b, c1, t1, v1, struct)
                return jnp.where(k0 >= 10.0 * v1, k0, jnp.where(found & (v1 > 0), k, 0.0))

            def rare(c1, t1, v1):  # the gathered few: more Newton steps first (one pass, no loop)
                t1 = jnp.where(t1 > 0, t1, 1.0)
                w1 = kelly_fast(ms.a0, ms.a1, ms.b, c1, t1, v1, struct, n_newton=12)
                nb = max(16, c1.size // 16)
                return rare_update(slow, w1, jnp.isnan(w1), (c1, t1, v1), block=1, max_blocks=nb, cap=nb)

            return rare_update(rare, w, jnp.isnan(w), (c_, t_, v_))

        def scan(_):
            z0 = jnp.zeros((), dtype)  # v = 0 (clamped to 0.1): scalar terms, folded once
            th_ = jnp.where(t_ > 0, t_, 1.0)
            k0 = 2.0 * th_ * ms._threshold_frequency(c_, z0, z0)
            easy = k0 >= 10.0 * v_
            w, found = ms._distance_scan(c_, th_, v_, easy)
            return jnp.where(t_ > 0, jnp.where(easy, k0, jnp.where(found, jnp.exp(w), 0.0)), 0.0)

        if _is_tracer(struct[0]):
            k_star = lax.cond(struct[0], direct, scan, None)
        else:  # XLA on CPU runs the branches of a cond on one thread: avoid it when possible
            k_star = direct(None) if bool(struct[0]) else scan(None)
        ok = k_star > 0
        k = implicit_solution(_kelly_margin_k, jnp.where(ok, k_star, 1.0), ok, self, c, th, v)
        return jnp.where(ok, k, 0.0)

    def _distance_scan(self, c_, th_, v_, easy):
        """The general solver (any a0, a1): monotone Newton where the margin is concave in ln k, a
        scan elsewhere. Used when :func:`kelly_structure` cannot certify the direct solve.
        Returns ``(ln k, found)`` under stop_gradient."""
        ms = self
        dtype = c_.dtype
        eps = jnp.finfo(dtype).eps
        vpos = v_ > 0
        vs = jnp.where(vpos, v_, 1.0)
        b = ms.b
        r = jnp.maximum(ms.a1 / ms.a0, 0.0)
        kappa = 1.01 * r ** (2.0 / 3.0) * _KELLY_C0 / math.log(10.0) ** 2
        k_c = jnp.maximum(2.0 * th_ / b - 0.5 * v_, kappa * th_ / b)
        w_c = jnp.log(jnp.maximum(k_c, 2e-4 * th_))
        w_top = jnp.log(10.0 * vs)
        const = _log_guard(c_) + jnp.log(vs) - 2.0 * jnp.log(2.0 * th_) - b * v_ / (2.0 * th_)
        l10 = math.log(10.0)
        x0 = jnp.log10(vs / 3.0)

        def h_dh(w):
            x = x0 - w / l10
            ax = jnp.abs(x)
            kk = ms.a0 + ms.a1 * ax * ax * ax
            bk = b * jnp.exp(w) / th_
            return const + jnp.log(kk) + w - bk, -3.0 * ms.a1 * x * ax / (l10 * kk) + 1.0 - bk

        def newton(_, w):
            h, dh = h_dh(w)
            return w - jnp.where((h < 0) & (dh < 0), h / jnp.minimum(dh, -eps), 0.0)

        regA = vpos & ~easy & (w_c < w_top)
        wA = lax.fori_loop(0, 12, newton, jnp.where(regA, w_top, 0.0))
        hA, _ = h_dh(wA)
        foundA = regA & (hA >= -64.0 * eps) & (wA >= w_c - 1e-6)
        needB = vpos & ~easy & ~foundA
        g_sg = lambda w: ms._margin(c_, jnp.exp(w), th_, v_)  # noqa: E731
        w_lo = jnp.log(2e-4 * th_)
        w_hiB = jnp.maximum(jnp.minimum(w_c, w_top), w_lo + 1e-3)

        def search_b(c1, th1, v1, lo1, hi1):
            g1 = lambda w: ms._margin(c1, jnp.exp(w), th1, v1)  # noqa: E731
            w, found, _sat = largest_crossing(g1, lo1, hi1, n_grid=129, n_iter=40)
            return w, found

        def search_nan(*a):  # not found: NaN
            w, found = search_b(*a)
            return jnp.where(found, w, jnp.nan)

        # up to a quarter of the batch gathered element by element (the whole batch when more)
        wB = rare_update(search_nan, jnp.full_like(c_, jnp.nan), needB, (c_, th_, v_, w_lo, w_hiB),
                         block=1, max_blocks=max(1, c_.size // 4), cap=max(1, c_.size // 4))
        foundB = needB & ~jnp.isnan(wB)
        w_star = jnp.where(foundA, wA, jnp.where(foundB, wB, 0.0))
        return w_star, (foundA | foundB)


# --------------------------------------------------------------------------- Rovamo-Virsu
class RovamoVirsu(eqx.Module):
    """Rovamo & Virsu (1979) cortical magnification factor relative to the fovea (seed 000 Eq 3).

    ``form="cubic"``: ``M(e) = 1 / (1 + k1 e + k3 e^3)`` with k1 = 0.29, k3 = 0.000012 (published for
    0 <= e <= 80 deg; evaluated beyond). ``form="linear"``: ``M(e) = 1 / (1 + k1 e)``, the most sensitive
    (temporal) retina used by seed 001 Eq 3. ``e`` in deg, result dimensionless in (0, 1].
    Call it: ``RovamoVirsu()(e)``.
    """

    k1: jax.Array
    k3: jax.Array
    form: str = eqx.field(static=True, default="cubic")

    param_bounds: ClassVar[dict] = {"k1": (0.0, None), "k3": (0.0, None)}

    def __init__(self, form: str = "cubic", k1=0.29, k3=0.000012):
        if form not in ("cubic", "linear"):
            raise ValueError(f"unknown RovamoVirsu form {form!r}; choose 'cubic' or 'linear'")
        self.form = form
        self.k1 = _param(k1, "RovamoVirsu.k1", positive=False)
        self.k3 = _param(k3, "RovamoVirsu.k3", positive=False)

    def inverse(self, e):
        """1 / M(e) = 1 + k1 e (+ k3 e^3); e in deg (any shape)."""
        e = jnp.minimum(jnp.asarray(e), 1e9)
        out = 1.0 + self.k1 * e
        if self.form == "cubic":
            out = out + self.k3 * e * e * e
        return out

    def __call__(self, e):
        """M(e), e in deg (>= 0, checked outside jit)."""
        (e,) = check_inputs("RovamoVirsu", e=e)
        return 1.0 / self.inverse(e)


def _ecc_cheb(deg: int):
    """Chebyshev coefficients (in 2 tau - 1) of h(tau) = (1 + 2 cos(2/3 asin sqrt(1 - tau^2))) / 3 on [0, 1].

    h is the largest root of the normalized cubic u^3 - u^2 + y / 27 * 4 = 0 (y = 1 - tau^2); it is
    analytic in tau, so the interpolant converges fast: relative error 3e-9 at degree 8, 2e-12 at 12."""
    j = np.arange(4 * deg)
    x = np.cos(np.pi * (j + 0.5) / (4 * deg))
    tau = 0.5 * (x + 1.0)
    h = (1.0 + 2.0 * np.cos((2.0 / 3.0) * np.arcsin(np.sqrt(1.0 - tau * tau)))) / 3.0
    return tuple(float(c) for c in np.polynomial.chebyshev.chebfit(x, h, deg))


_ECC_CHEB32 = _ecc_cheb(8)
_ECC_CHEB64 = _ecc_cheb(12)


class Eccentric(CSFModel):
    """Gives a foveal CSF an eccentricity dependence by cortical magnification (spatial scaling).

    ``S(f, e, v) = csf.sensitivity(f / M(e), 0, v)``: a grating at eccentricity ``e`` is seen like a
    foveal grating of frequency ``f / M(e)`` (Rovamo & Virsu 1979; seed 001 Eq 5 uses exactly this with
    the linear M). The peak frequency becomes ``M(e) f_peak``; ``threshold_frequency`` is
    ``M(e) csf.threshold_frequency(c, 0, v)``. ``imperceptible_distance`` is closed (a cubic solved by
    a Chebyshev-interpolated closed form) when the inner model has no velocity term, generic otherwise.
    """

    csf: CSFModel
    magnification: RovamoVirsu

    param_bounds: ClassVar[dict] = {}

    def __init__(self, csf: CSFModel, magnification: RovamoVirsu | None = None):
        if not isinstance(csf, CSFModel):
            raise ValueError(f"Eccentric needs a CSFModel, got {type(csf).__name__}")
        if "e" in type(csf).inputs:
            raise ValueError(f"{type(csf).__name__} already depends on eccentricity; wrap a foveal CSF")
        self.csf = csf
        self.magnification = RovamoVirsu() if magnification is None else magnification

    @property
    def inputs(self):  # type: ignore[override]
        return tuple(dict.fromkeys(tuple(type(self.csf).inputs) + ("e",)))

    def log_sensitivity(self, f, e=0.0, v=0.0):
        fs = jnp.asarray(f) * self.magnification.inverse(jnp.asarray(e))
        return self.csf.log_sensitivity(fs, jnp.zeros_like(jnp.asarray(e)), v)

    def sensitivity(self, f, e=0.0, v=0.0):
        """csf S(f / M(e), 0, v); broadcast shape of f, e, v."""
        f, e, v = check_inputs("sensitivity", f=f, e=e, v=v)
        self = self._like(f, e, v)
        return jnp.exp(self.log_sensitivity(f, e, v))

    def _peak_frequency(self, e, v):
        return self.csf._peak_frequency(jnp.zeros_like(e), v) / self.magnification.inverse(e)

    def _threshold_frequency(self, c, e, v):
        return self.csf._threshold_frequency(c, jnp.zeros_like(e), v) / self.magnification.inverse(e)

    def imperceptible_distance(self, c, theta, e=0.0, v=0.0):
        """See :meth:`CSFModel.imperceptible_distance`. Without a velocity term: perceptible at k iff
        ``phi(k) = k + k1 e + k3 e^3 / k^2 <= F = 2 theta f*(c)`` (the inner threshold frequency);
        phi is convex with minimum ``1.5 k_m + k1 e`` at ``k_m = (2 k3)^(1/3) e`` (perceptible somewhere iff
        ``6.75 k3 e^3 <= ku^3``, ``ku = F - k1 e``). The largest root of ``k^3 - ku k^2 + k3 e^3 = 0`` is
        ``ku h(tau)``, ``tau = sqrt(1 - 6.75 k3 e^3 / ku^3)``, with ``h`` (analytic in tau, the trigonometric
        cubic root) a Chebyshev interpolant: degree 8 (relative error 3e-9) in float32, degree 12 plus one
        Newton step in float64. No iteration, no transcendental function."""
        if "v" in type(self.csf).inputs:
            return CSFModel.imperceptible_distance(self, c, theta, e, v)
        c, theta, e, v = check_inputs("imperceptible_distance", c=c, theta=theta, e=e, v=v)
        self = self._like(c, theta, e, v)
        F = 2.0 * theta * self.csf._threshold_frequency(c, jnp.zeros_like(e), v)
        k1, k3 = self.magnification.k1, self.magnification.k3
        ku = F - k1 * e
        if self.magnification.form == "linear":
            return jnp.maximum(ku, 0.0)
        e3 = k3 * e * e * e
        feasible = (ku > 0) & (6.75 * e3 <= ku * ku * ku)
        e3s, kus = lax.stop_gradient((e3, ku))
        kus = jnp.where(feasible, kus, 1.0)
        # largest root k = ku h(tau) of k^3 - ku k^2 + e3 = 0: y = 6.75 e3 / ku^3 in [0, 1] (1: double root)
        # and h = (1 + 2 cos(2/3 asin sqrt(y))) / 3 is analytic in tau = sqrt(1 - y) on [0, 1]
        y = 6.75 * e3s / (kus * kus * kus)
        tau = jnp.sqrt(jnp.clip(1.0 - y, 0.0, 1.0))
        if kus.dtype == jnp.float64:
            k = kus * _clenshaw(2.0 * tau - 1.0, _ECC_CHEB64)
            # one Newton step on k^2 (k - ku) + e3 (one division), skipped at the double root
            p = k * k * (k - kus) + e3s
            dp = k * (3.0 * k - 2.0 * kus)
            k = jnp.where(dp > 0, k - p / jnp.where(dp > 0, dp, 1.0), k)
        else:
            k = kus * _clenshaw(2.0 * tau - 1.0, _ECC_CHEB32)
        g = lambda kk: F - (kk + k1 * e + e3 / (kk * kk))  # noqa: E731  (>= 0 where perceptible)
        k = implicit_root(g, k, mask=feasible)
        return jnp.where(feasible, k, 0.0)

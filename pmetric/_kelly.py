"""Kelly's CSFs, with exact inversions.

* :class:`KellyAbstract` -- the abstract CSF ``alpha^2 e^-alpha`` of [Kel75] scaled by delta with the
  temporal-retina cortical magnification [LHNW00 Eq 1-2, 5].
* :class:`KellySpatioTemporal` -- the stabilized spatio-temporal CSF of [Kel79] ([LHNW00 Eq 4]) and
  Reddy's refit [Red01 Eq 2]; its distance solve lives in ``_kelly_distance.py``.

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

from ._base import CSFModel, distance_margin_k, param
from ._errors import PlodError
from ._inverse import implicit_solution, lambertw_m1, largest_crossing
from ._kelly_distance import kelly_clamped_root, kelly_fast, kelly_slow, kelly_structure
from ._numerics import is_tracer, log_guard, rare_update

__all__ = ["KellyAbstract", "KellySpatioTemporal"]


_E2_4 = math.e**2 / 4.0  # 1 / max(alpha^2 e^-alpha), attained at alpha = 2


class KellyAbstract(CSFModel):
    """Kelly's abstract CSF [Kel75] with delta scaling and cortical magnification [LHNW00 Eq 1-5].

    ``1/c_T = delta alpha^2 exp(-alpha)``, ``alpha = 2 (1 + 0.29 e) f / f0``. With ``f0 = 2`` this is
    ``alpha = (1 + 0.29 e) f`` of [LHNW00 Eq 2] exactly; ``f0`` (cycles/deg) is the foveal peak frequency,
    a fittable frequency scale ([LHNW00] measured f in units of its own display; its ``delta = 0.4``
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
        self.delta = param(delta, "KellyAbstract.delta")
        self.f0 = param(f0, "KellyAbstract.f0")

    def _alpha(self, f, e):
        return 2.0 * (1.0 + 0.29 * e) * jnp.minimum(f, 1e30) / self.f0

    def _log_sensitivity(self, f, e, v):
        a = self._alpha(f, e)
        out = jnp.log(self.delta) + 2.0 * log_guard(a) - a
        return jnp.broadcast_to(out, jnp.broadcast_shapes(out.shape, jnp.shape(v)))

    def _sensitivity(self, f, e, v):
        """S = delta alpha^2 exp(-alpha), alpha = 2 (1 + 0.29 e) f / f0 (no log: exact to rounding)."""
        a = self._alpha(f, e)
        # alpha^2 e^-alpha is 0 in float64 beyond alpha = 1e3 (and in float32 long before); there alpha^2
        # itself overflows float32 from 1.8e19 and inf * 0 is NaN: 0 there, alpha clamped (double where)
        small = a < 1e3
        a = jnp.where(small, a, 1e3)
        out = jnp.where(small, self.delta * a * a * jnp.exp(-a), 0.0)
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

    def _is_perceptible(self, c, f, e, v):
        """c >= c_T(max(f, f_peak)); fused closed form (see :meth:`CSFModel.is_perceptible`)."""
        a = jnp.maximum(self._alpha(f, e), 2.0)
        out = log_guard(c) + jnp.log(self.delta) + 2.0 * jnp.log(a) - a >= 0
        return jnp.broadcast_to(out, jnp.broadcast_shapes(out.shape, v.shape))

    def _threshold_frequency(self, c, e, v):
        a, visible = self._alpha_star(c)
        f = a * self.f0 / (2.0 * (1.0 + 0.29 * e))
        out = jnp.where(visible, f, 0.0)
        return jnp.broadcast_to(out, jnp.broadcast_shapes(out.shape, v.shape))

    def _imperceptible_distance(self, c, theta, e, v):
        """Closed form: at distance multiple k, alpha(k) = (k + 0.29 e) / (theta f0) grows with k, so
        ``k = max(0, theta f0 alpha* - 0.29 e)`` (0 where c is invisible even at the peak)."""
        a, visible = self._alpha_star(c)
        k = jnp.maximum(theta * self.f0 * a - 0.29 * e, 0.0)
        out = jnp.where(visible, k, 0.0)
        return jnp.broadcast_to(out, jnp.broadcast_shapes(out.shape, v.shape))


# --------------------------------------------------------------------------- Kelly spatio-temporal
_KELLY_CONSTANTS = {
    # a0, a1 in [a0 + a1 |log10(v/3)|^3] v f^2 exp(-b f (v + 2))
    "kelly1979": (6.1, 7.3, 2.0 / 45.9),  # [Kel79], [LHNW00 Eq 4]
    "reddy": (250.1, 299.3, 5.5 * math.log(10.0) / 45.9),  # [Red01 Eq 2]: 10^(-5.5 f (v+2)/45.9)
}


def _kelly_c0():
    """max over t > 0 of 6 t / (1 + t^3) - 9 t^4 / (1 + t^3)^2 (curvature bound of ln(a0 + a1 |x|^3))."""
    t = np.linspace(1e-4, 5.0, 200001)
    return float((6 * t / (1 + t**3) - 9 * t**4 / (1 + t**3) ** 2).max()) * (1 + 1e-6)


_KELLY_C0 = _kelly_c0()  # 2.2300


class KellySpatioTemporal(CSFModel):
    """Kelly's stabilized spatio-temporal CSF [Kel79]: sensitivity to a grating drifting at ``v`` deg/s.

    ``S(f, v) = [a0 + a1 |log10(v/3)|^3] v f^2 exp(-b f (v + 2))``. ``constants="kelly1979"``:
    a0 = 6.1, a1 = 7.3, b = 2/45.9 ([LHNW00 Eq 4]); ``"reddy"``: a0 = 250.1, a1 = 299.3,
    b = 5.5 ln(10)/45.9 ([Red01 Eq 2], ``10^(-5.5 f (v+2)/45.9)``). The fit is valid for v > 0.1 deg/s:
    velocities below 0.1 deg/s (including 0, a stabilized/tracked target) are treated as 0.1 deg/s.
    Peak frequency ``2 / (b (v + 2))`` (9.18 cycles/deg at v = 3 for Kelly's constants). No eccentricity
    term (``e`` ignored; wrap in :class:`Eccentric`).

    ``threshold_frequency`` is a closed form (Lambert W, as for :class:`KellyAbstract` with
    ``delta = K(v) v / (b (v+2))^2``). ``imperceptible_distance`` is a direct solve (closed form where
    the answer lies beyond ``k = 10 v``, monotone Newton on a margin that is concave in ``k / v``
    below it, certified brackets for the rare rest; see ``_imperceptible_distance`` and
    ``_kelly_distance.py``).

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
            raise PlodError(f"unknown Kelly constant set {constants!r}; choose one of {sorted(_KELLY_CONSTANTS)}")
        d0, d1, db = _KELLY_CONSTANTS[constants]
        self.constants = constants
        self.a0 = param(d0 if a0 is None else a0, "KellySpatioTemporal.a0")
        self.a1 = param(d1 if a1 is None else a1, "KellySpatioTemporal.a1", positive=False)
        self.b = param(db if b is None else b, "KellySpatioTemporal.b")

    @staticmethod
    def _v(v):
        return jnp.clip(v, 0.1, 1e30)

    def _log_amp(self, v):
        """ln(K(v) v) for the clamped velocity."""
        lv = jnp.abs(jnp.log10(v / 3.0))
        return jnp.log(self.a0 + self.a1 * lv * lv * lv) + jnp.log(v)

    def _log_sensitivity(self, f, e, v):
        f = jnp.minimum(f, 1e30)
        vv = self._v(v)
        out = self._log_amp(vv) + 2.0 * log_guard(f) - self.b * f * (vv + 2.0)
        return jnp.broadcast_to(out, jnp.broadcast_shapes(out.shape, jnp.shape(e)))

    def _peak_frequency(self, e, v):
        out = 2.0 / (self.b * (self._v(v) + 2.0))
        return jnp.broadcast_to(out, jnp.broadcast_shapes(out.shape, jnp.shape(e)))

    def _is_perceptible(self, c, f, e, v):
        """Fused closed form of :meth:`CSFModel.is_perceptible`."""
        vv = self._v(v)
        beta = self.b * (vv + 2.0)
        a = jnp.maximum(beta * jnp.minimum(f, 1e30), 2.0)  # alpha = beta f, clamped at the peak
        out = log_guard(c) + self._log_amp(vv) - 2.0 * jnp.log(beta) + 2.0 * jnp.log(a) - a >= 0
        return jnp.broadcast_to(out, jnp.broadcast_shapes(out.shape, e.shape))

    def _threshold_frequency(self, c, e, v):
        vv = self._v(v)
        beta = self.b * (vv + 2.0)
        log_dc = log_guard(c) + self._log_amp(vv) - 2.0 * jnp.log(beta)  # ln(delta_eff c)
        visible = log_dc >= math.log(_E2_4)
        x = jnp.where(visible, -0.5 * jnp.exp(-0.5 * jnp.where(visible, log_dc, 0.0)), -0.25)
        out = jnp.where(visible, -2.0 * lambertw_m1(x) / beta, 0.0)
        return jnp.broadcast_to(out, jnp.broadcast_shapes(out.shape, e.shape))

    def _distance_margin(self, k, c, theta, e, v, peak=None):
        """Fused ``log c - log c_T(max(f, f_peak))`` at distance multiple k (f = k / 2 theta, v / k;
        no e term, and the peak is the closed form: ``peak`` is ignored)."""
        vv = self._v(v / k)
        beta = self.b * (vv + 2.0)
        a = jnp.maximum(beta * k / (2.0 * theta), 2.0)
        return log_guard(c) + self._log_amp(vv) - 2.0 * jnp.log(beta) + 2.0 * jnp.log(a) - a

    def _imperceptible_distance(self, c, theta, e, v):
        """See :meth:`CSFModel.imperceptible_distance`; theta deg, v deg/s. Direct solve
        (``_kelly_distance.py``):

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
        shape = jnp.broadcast_shapes(c.shape, theta.shape, e.shape, v.shape)
        dtype = jnp.result_type(c, theta, e, v, float)
        c, theta, v = (jnp.broadcast_to(x, shape).astype(dtype) for x in (c, theta, v))
        pos = theta > 0
        th = jnp.where(pos, theta, 1.0)
        sg = lax.stop_gradient
        ms, c_, t_, v_ = sg((self, c, theta, v))
        if is_tracer(self.a0) or is_tracer(self.a1):
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

        if is_tracer(struct[0]):
            k_star = lax.cond(struct[0], direct, scan, None)
        else:  # XLA on CPU runs the branches of a cond on one thread: avoid it when possible
            k_star = direct(None) if bool(struct[0]) else scan(None)
        ok = k_star > 0
        k = implicit_solution(distance_margin_k, jnp.where(ok, k_star, 1.0), ok, self, c, th, e, v)
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
        const = log_guard(c_) + jnp.log(vs) - 2.0 * jnp.log(2.0 * th_) - b * v_ / (2.0 * th_)
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
        g_sg = lambda w: ms._distance_margin(jnp.exp(w), c_, th_, 0.0, v_)  # noqa: E731
        w_lo = jnp.log(2e-4 * th_)
        w_hiB = jnp.maximum(jnp.minimum(w_c, w_top), w_lo + 1e-3)

        def search_b(c1, th1, v1, lo1, hi1):
            g1 = lambda w: ms._distance_margin(jnp.exp(w), c1, th1, 0.0, v1)  # noqa: E731
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

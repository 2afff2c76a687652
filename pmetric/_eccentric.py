"""Eccentricity by cortical magnification: :class:`RovamoVirsu` [RV79] ([Red01 Eq 3]) and
:class:`Eccentric`, which applies a magnification to any foveal CSF ([LHNW00 Eq 5]).

Units: f cycles/deg, e deg, v deg/s, c Michelson contrast (0..1), theta deg.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from ._base import CSFModel, check_constants, check_inputs, param
from ._errors import PlodError
from ._inverse import implicit_root
from ._numerics import clenshaw

__all__ = ["RovamoVirsu", "Eccentric"]


class RovamoVirsu(eqx.Module):
    """Rovamo & Virsu's cortical magnification factor relative to the fovea [RV79], [Red01 Eq 3].

    ``form="cubic"``: ``M(e) = 1 / (1 + k1 e + k3 e^3)`` with k1 = 0.29, k3 = 0.000012 (published for
    0 <= e <= 80 deg; evaluated beyond). ``form="linear"``: ``M(e) = 1 / (1 + k1 e)``, the most sensitive
    (temporal) retina used by [LHNW00 Eq 3]. ``e`` in deg, result dimensionless in (0, 1].
    Call it: ``RovamoVirsu()(e)``.
    """

    k1: jax.Array
    k3: jax.Array
    form: str = eqx.field(static=True, default="cubic")

    param_bounds: ClassVar[dict] = {"k1": (0.0, None), "k3": (0.0, None)}

    def __init__(self, form: str = "cubic", k1=0.29, k3=0.000012):
        if form not in ("cubic", "linear"):
            raise PlodError(f"unknown RovamoVirsu form {form!r}; choose 'cubic' or 'linear'")
        self.form = form
        self.k1 = param(k1, "RovamoVirsu.k1", positive=False)
        self.k3 = param(k3, "RovamoVirsu.k3", positive=False)
        check_constants(self)  # k1, k3 >= 0 (their param_bounds, as load_model reads them)

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
    foveal grating of frequency ``f / M(e)`` ([RV79]; [LHNW00 Eq 5] uses exactly this with the
    linear M). The peak frequency becomes ``M(e) f_peak``; ``threshold_frequency`` is
    ``M(e) csf.threshold_frequency(c, 0, v)``. ``imperceptible_distance`` is closed (a cubic solved by
    a Chebyshev-interpolated closed form) when the inner model has no velocity term, generic otherwise.
    """

    csf: CSFModel
    magnification: RovamoVirsu

    param_bounds: ClassVar[dict] = {}

    def __init__(self, csf: CSFModel, magnification: RovamoVirsu | None = None):
        if not isinstance(csf, CSFModel):
            raise PlodError(f"Eccentric needs a CSFModel, got {type(csf).__name__}")
        if "e" in csf.inputs:  # (the instance: an Eccentric's inputs are a property)
            raise PlodError(f"{type(csf).__name__} already depends on eccentricity; wrap a foveal CSF")
        if magnification is not None and not isinstance(magnification, RovamoVirsu):
            raise PlodError(f"Eccentric: magnification must be a RovamoVirsu, got {type(magnification).__name__}")
        self.csf = csf
        self.magnification = RovamoVirsu() if magnification is None else magnification

    @property
    def inputs(self):  # type: ignore[override]
        return tuple(dict.fromkeys(tuple(type(self.csf).inputs) + ("e",)))

    def _log_sensitivity(self, f, e, v):
        """ln of the inner csf's S(f / M(e), 0, v)."""
        fs = f * self.magnification.inverse(e)
        return self.csf._log_sensitivity(fs, jnp.zeros_like(e), v)

    def _peak_frequency(self, e, v):
        return self.csf._peak_frequency(jnp.zeros_like(e), v) / self.magnification.inverse(e)

    def _threshold_frequency(self, c, e, v):
        return self.csf._threshold_frequency(c, jnp.zeros_like(e), v) / self.magnification.inverse(e)

    def _imperceptible_distance(self, c, theta, e, v):
        """See :meth:`CSFModel.imperceptible_distance`. Without a velocity term: perceptible at k iff
        ``phi(k) = k + k1 e + k3 e^3 / k^2 <= F = 2 theta f*(c)`` (the inner threshold frequency);
        phi is convex with minimum ``1.5 k_m + k1 e`` at ``k_m = (2 k3)^(1/3) e`` (perceptible somewhere iff
        ``6.75 k3 e^3 <= ku^3``, ``ku = F - k1 e``). The largest root of ``k^3 - ku k^2 + k3 e^3 = 0`` is
        ``ku h(tau)``, ``tau = sqrt(1 - 6.75 k3 e^3 / ku^3)``, with ``h`` (analytic in tau, the trigonometric
        cubic root) a Chebyshev interpolant: degree 8 (relative error 3e-9) in float32, degree 12 plus one
        Newton step in float64. No iteration, no transcendental function."""
        if "v" in type(self.csf).inputs:
            return CSFModel._imperceptible_distance(self, c, theta, e, v)
        F = 2.0 * theta * self.csf._threshold_frequency(c, jnp.zeros_like(e), v)
        # phi(k) = F is homogeneous of degree 1 in (k, F, e): solve it for (F, e) scaled by a power of two
        # near 1 / max(F, e) (exact) and scale k back, so that no cube or square of a tiny theta's k
        # underflows (k^3 of a 1e-15 deg change is below float32's range: 0 / 0 in the cubic's ratio)
        dt = jnp.result_type(F, e)
        _, n = jnp.frexp(lax.stop_gradient(jnp.maximum(F, e)).astype(dt))

        def scale(x, m):  # x 2^m as two constant factors (each within range): jnp.ldexp's derivative is 1,
            x = x.astype(dt)  # not 2^m, at x = 0 (the fovea: d/de 64x too large) and NaN at subnormal x
            h = m // 2
            two = lambda j: lax.stop_gradient(jnp.ldexp(jnp.ones_like(x), j).astype(dt))  # noqa: E731
            return x * two(h) * two(m - h)

        return scale(self._cubic_distance(scale(F, -n), scale(e, -n)), n)

    def _cubic_distance(self, F, e):
        """The largest k with k + k1 e + k3 e^3 / k^2 <= F (0 where there is none); F and e of order 1."""
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
            k = kus * clenshaw(2.0 * tau - 1.0, _ECC_CHEB64)
            # one Newton step on k^2 (k - ku) + e3 (one division), skipped at the double root
            p = k * k * (k - kus) + e3s
            dp = k * (3.0 * k - 2.0 * kus)
            k = jnp.where(dp > 0, k - p / jnp.where(dp > 0, dp, 1.0), k)
        else:
            k = kus * clenshaw(2.0 * tau - 1.0, _ECC_CHEB32)
        g = lambda kk: F - (kk + k1 * e + e3 / (kk * kk))  # noqa: E731  (>= 0 where perceptible)
        k = implicit_root(g, k, mask=feasible)
        return jnp.where(feasible, k, 0.0)

"""The common interface of every contrast-sensitivity model: :class:`CSFModel`.

Units: spatial frequency ``f`` in cycles/deg, eccentricity ``e`` in deg, retinal velocity ``v`` in
deg/s, Michelson contrast ``c`` (dimensionless, in [0, 1]), angular size ``theta`` in deg.

A subclass only has to implement :meth:`CSFModel.sensitivity` (or :meth:`CSFModel.log_sensitivity`
plus ``sensitivity = exp(log_sensitivity)``); the base class derives every other question from it with
generic, exact numerical methods (grid bracketing + safeguarded Newton, implicit-function gradients).
Subclasses override them with closed forms where these exist (see ``_csf.py``).

Input checking: outside ``jax.jit`` (concrete inputs) a negative or NaN frequency / eccentricity /
velocity / contrast / size raises ``ValueError`` naming the argument. Under ``jit`` values are not
checked: NaN inputs propagate to NaN outputs (``is_perceptible`` then returns False) and negative
inputs give unspecified results. Shapes that do not broadcast raise ``ValueError`` at trace time.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from ._inverse import bracketed_root, implicit_root, largest_crossing

__all__ = ["CSFModel", "as_float", "check_inputs", "LOG_CT_MAX"]

#: threshold contrasts are capped at exp(LOG_CT_MAX) (about 1e26): finite in float32, "invisible".
LOG_CT_MAX = 60.0

# Search range (cycles/deg) of the generic numerical inversions.
_F_LO, _F_HI = 1e-4, 1e4
_N_GRID = 257  # grid points of the generic distance scan: ln(1e8) / 256 = 0.072 per step


def _is_tracer(x) -> bool:
    return isinstance(x, jax.core.Tracer)


def as_float(x):
    """``x`` as a floating JAX array (integers and bools become the default float dtype)."""
    x = jnp.asarray(x)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    return x


def check_inputs(_method: str, **arrays):
    """Convert keyword arrays to float arrays, check they broadcast and (when concrete) their values.

    Every argument must be >= 0 and not NaN (``+inf`` is allowed). Raises ``ValueError`` naming the
    argument. Returns the converted arrays in the order given.
    """
    out = []
    shapes = {}
    for name, x in arrays.items():
        if x is None:
            out.append(None)
            continue
        if isinstance(x, (str, bytes)):
            raise ValueError(f"{_method}: {name} must be a number or an array, got {x!r}")
        try:
            xa = as_float(x)
        except TypeError as err:
            raise ValueError(f"{_method}: {name} must be a number or an array of numbers ({err})") from None
        if not _is_tracer(xa):
            xn = np.asarray(xa)
            if np.isnan(xn).any():
                raise ValueError(f"{_method}: {name} contains NaN")
            if (xn < 0).any():
                raise ValueError(f"{_method}: {name} must be >= 0 (got min {xn.min()!r})")
        shapes[name] = xa.shape
        out.append(xa)
    try:
        np.broadcast_shapes(*shapes.values())
    except ValueError:
        desc = ", ".join(f"{k} {v}" for k, v in shapes.items())
        raise ValueError(f"{_method}: argument shapes do not broadcast: {desc}") from None
    return out


def _log_guard(x):
    """log(x) for x >= 0 with finite value and gradient at 0 (log of the smallest normal instead)."""
    x = jnp.asarray(x)
    # floor 1e-30 (log = -69, beyond LOG_CT_MAX): 1/floor stays finite in float32 gradients
    return jnp.log(jnp.maximum(x, 1e-30))


class CSFModel(eqx.Module):
    """Abstract contrast-sensitivity model (a frozen ``equinox.Module``).

    Fitted constants are floating array fields; switches are static fields. All methods broadcast
    their arguments (numpy rules) and are jit / vmap / grad clean in float32 and float64.

    Subclasses implement :meth:`sensitivity` (S = 1 / threshold contrast) and set the class variables
    ``inputs`` (which of ``"f", "e", "v", "luminance", "area"`` the model depends on) and
    ``param_bounds`` (valid range of each fittable field, ``None`` = unbounded).

    Generic methods assume, as every CSF here satisfies, that sensitivity falls monotonically with
    frequency above the peak frequency (the "falling limb"). Reference: Luebke & Hallen 2001 (seed 004)
    sections 3.1, 5.3 and 6.1 for the worst-case use of the peak below it and the distance key.
    """

    inputs: ClassVar[tuple[str, ...]] = ("f",)
    param_bounds: ClassVar[dict[str, tuple[float | None, float | None]]] = {}

    # ----------------------------------------------------------------- dtype
    def _like(self, *xs):
        """The model with its floating array fields cast to the inputs' floating dtype.

        A model built under ``jax_enable_x64`` (float64 fields) then used without it (or on float32
        inputs) computes in the inputs' dtype instead of mixing dtypes (which warns). Gradients flow
        through the cast. A no-op when the dtypes already agree."""
        # the arrays themselves, not their .dtype: a weakly typed input (a Python scalar) must not
        # promote float32 inputs to the model's float64 (jit loop carries would then mix dtypes)
        dtype = jnp.result_type(*(x for x in xs if x is not None), float)

        def cast(x):
            if eqx.is_inexact_array(x) and x.dtype != dtype:
                return x.astype(dtype)
            return x

        # concrete fields are cast eagerly: under jit a staged cast would hide the constants from the
        # per-model fast paths that precompute from them at trace time (Barten, stelaCSF, Kelly)
        with jax.ensure_compile_time_eval():
            return jax.tree_util.tree_map(cast, self)

    # ----------------------------------------------------------------- the model
    @abc.abstractmethod
    def sensitivity(self, f, e=0.0, v=0.0):
        """Contrast sensitivity S = 1/c_T at frequency ``f`` (cycles/deg), eccentricity ``e`` (deg) and
        retinal velocity ``v`` (deg/s); broadcast shape of the inputs."""

    def log_sensitivity(self, f, e=0.0, v=0.0):
        """Natural log of :meth:`sensitivity` (finite: sensitivities below the smallest normal float
        are clamped). Subclasses override it with a closed form that never underflows."""
        return _log_guard(self.sensitivity(f, e, v))

    def stimulus_sensitivity(self, f, e=0.0, v=0.0, luminance=None, area=None):
        """Sensitivity for a calibration stimulus of mean ``luminance`` (cd/m2) and ``area`` (deg2).

        The base implementation ignores luminance and area (models without such terms); models with
        them (Barten, stelaCSF) override it.
        """
        return self.sensitivity(f, e, v)

    # ----------------------------------------------------------------- thresholds
    def threshold_contrast(self, f, e=0.0, v=0.0):
        """Threshold Michelson contrast c_T = 1/S (capped at ``exp(LOG_CT_MAX)``, about 1e26)."""
        f, e, v = check_inputs("threshold_contrast", f=f, e=e, v=v)
        self = self._like(f, e, v)
        return jnp.exp(jnp.minimum(-self.log_sensitivity(f, e, v), LOG_CT_MAX))

    def peak_frequency(self, e=0.0, v=0.0):
        """Frequency (cycles/deg) of peak sensitivity at eccentricity ``e`` and velocity ``v``.

        Generic: the best of a 49-point log grid over [1e-3, 1e3] cycles/deg refined by golden-section
        search to ~1e-5 relative; its gradient is the implicit-function derivative of
        d(log S)/d(log f) = 0. Subclasses override with closed forms.
        """
        e, v = check_inputs("peak_frequency", e=e, v=v)
        self = self._like(e, v)
        return self._peak_frequency(e, v)

    def _peak_frequency(self, e, v):
        shape = jnp.broadcast_shapes(jnp.shape(e), jnp.shape(v))
        dtype = jnp.result_type(e, v, float)
        if shape and "e" not in self.inputs and "v" not in self.inputs:
            # the peak does not depend on e, v: search once (a scalar) and broadcast
            return jnp.broadcast_to(self._peak_frequency(jnp.zeros((), dtype), jnp.zeros((), dtype)), shape)
        e_, v_, ms = lax.stop_gradient((e, v, self))
        logs = lambda u: ms.log_sensitivity(jnp.exp(u), e_, v_)  # noqa: E731
        n = 49
        u_lo, u_hi = np.log(1e-3), np.log(1e3)
        du = (u_hi - u_lo) / (n - 1)

        def scan(j, state):
            best_u, best_s = state
            u = jnp.full(shape, u_lo + j * du, dtype)
            s = lax.stop_gradient(logs(u))
            better = s > best_s
            return jnp.where(better, u, best_u), jnp.where(better, s, best_s)

        init = (jnp.full(shape, u_lo, dtype), jnp.full(shape, -jnp.inf, dtype))
        ub, _ = lax.fori_loop(0, n, scan, init)
        a, b = ub - du, ub + du
        gr = 0.6180339887498949

        def golden(_, state):
            a, b = state
            x1 = b - gr * (b - a)
            x2 = a + gr * (b - a)
            s1 = lax.stop_gradient(logs(x1))
            s2 = lax.stop_gradient(logs(x2))
            left = s1 >= s2
            return jnp.where(left, a, x1), jnp.where(left, x2, b)

        a, b = lax.fori_loop(0, 24, golden, (a, b))
        u_star = lax.stop_gradient(0.5 * (a + b))

        # implicit derivative of d logS / du = 0 with respect to e, v and the model constants
        def dlog(u):
            return jax.jvp(lambda uu: self.log_sensitivity(jnp.exp(uu), e, v), (u,), (jnp.ones_like(u),))[1]

        interior = (u_star > u_lo + du) & (u_star < u_hi - du)
        u = implicit_root(dlog, u_star, mask=interior)
        return jnp.exp(u)

    def _peak_frequency_sg(self, e, v):
        """The peak frequency under ``stop_gradient`` (used where its derivative is not needed, e.g. the
        distance margin). Subclasses whose ``_peak_frequency`` pays for an implicit-gradient pass in the
        forward computation override it with the bare search."""
        return lax.stop_gradient(self._peak_frequency(e, v))

    def is_perceptible(self, c, f, e=0.0, v=0.0):
        """True where contrast ``c`` at frequency ``f`` (cycles/deg), eccentricity ``e`` (deg) and
        velocity ``v`` (deg/s) is visible: ``c >= c_T(max(f, f_peak(e, v)), e, v)`` (below the peak
        frequency the peak's threshold is used, the worst case of seed 004 sections 3.1 and 6.1).
        Bool array of the broadcast shape. NaN inputs under jit give False."""
        c, f, e, v = check_inputs("is_perceptible", c=c, f=f, e=e, v=v)
        self = self._like(c, f, e, v)
        fe = jnp.maximum(f, self._peak_frequency_sg(e, v))  # a bool: no gradient needed
        return _log_guard(c) + self.log_sensitivity(fe, e, v) >= 0

    def threshold_frequency(self, c, e=0.0, v=0.0):
        """Highest frequency (cycles/deg) at which Michelson contrast ``c`` is still visible at
        eccentricity ``e`` and velocity ``v``; 0 where ``c`` is invisible at every frequency.

        Inverse of the falling limb: ``threshold_contrast(threshold_frequency(c)) == c`` where the
        result is positive. Generic: safeguarded Newton in log f between the peak frequency and 1e4
        cycles/deg (results are capped at 1e4); exact implicit-function gradient.
        """
        c, e, v = check_inputs("threshold_frequency", c=c, e=e, v=v)
        self = self._like(c, e, v)
        return self._threshold_frequency(c, e, v)

    def _threshold_frequency(self, c, e, v):
        shape = jnp.broadcast_shapes(c.shape, e.shape, v.shape)
        dtype = jnp.result_type(c, e, v, float)
        fp = lax.stop_gradient(jnp.broadcast_to(self._peak_frequency(e, v), shape).astype(dtype))
        logc = _log_guard(c)

        def g(u):
            return logc + self.log_sensitivity(jnp.exp(u), e, v)

        logc_, e_, v_, ms = lax.stop_gradient((logc, e, v, self))
        g_sg = lambda u: logc_ + ms.log_sensitivity(jnp.exp(u), e_, v_)  # noqa: E731
        u_lo = jnp.log(fp)
        u_hi = jnp.full(shape, np.log(_F_HI), dtype)
        visible = g_sg(u_lo) >= 0
        saturated = g_sg(u_hi) >= 0
        u_star = bracketed_root(g_sg, u_lo, jnp.maximum(u_hi, u_lo + 1e-6))
        ok = visible & ~saturated
        u = implicit_root(g, jnp.where(ok, u_star, u_lo), mask=ok)
        return jnp.where(visible, jnp.where(saturated, jnp.asarray(_F_HI, dtype), jnp.exp(u)), 0.0)

    # ----------------------------------------------------------------- distance key
    def _distance_margin(self, k, c, theta, e, v, peak=None):
        """log c - log c_T at distance multiple ``k`` (perceptible iff >= 0).

        The peak frequency (``peak(e, v)``, default :meth:`_peak_frequency_sg`) enters under
        ``stop_gradient``: where it binds (f below the peak) the margin is log S at its maximum over f,
        so by the envelope theorem its derivative with respect to the peak location is 0 and every
        derivative of the margin stays exact, without differentiating the peak search."""
        f = k / (2.0 * theta)
        ek, vk = e / k, v / k
        fe = jnp.maximum(f, (self._peak_frequency_sg if peak is None else peak)(ek, vk))
        return _log_guard(c) + self.log_sensitivity(fe, ek, vk)

    def _generic_scan(self, c, theta, e, v, peak=None):
        """The scan of :meth:`imperceptible_distance` (no gradient; ``theta > 0``): ``(ln k*, found,
        saturated)`` from :func:`largest_crossing` of :meth:`_distance_margin` over ``ln k`` in
        ``[ln(2 theta _F_LO), ln(2 theta _F_HI)]``, ``_N_GRID`` points."""
        shape = jnp.broadcast_shapes(*(jnp.shape(x) for x in (c, theta, e, v)))
        dtype = jnp.result_type(c, theta, e, v, float)
        g = lambda w: self._distance_margin(jnp.exp(w), c, theta, e, v, peak)  # noqa: E731
        w_lo = jnp.broadcast_to(jnp.log(2.0 * theta * _F_LO), shape).astype(dtype)
        w_hi = jnp.broadcast_to(jnp.log(2.0 * theta * _F_HI), shape).astype(dtype)
        return largest_crossing(g, w_lo, w_hi, n_grid=_N_GRID, n_iter=40)

    def imperceptible_distance(self, c, theta, e=0.0, v=0.0):
        """Viewing-distance multiple beyond which a change is imperceptible (seed 004 section 5.3).

        ``c``: Michelson contrast of the change; ``theta``: its angular size (deg); ``e``: its
        eccentricity (deg); ``v``: its retinal velocity (deg/s), all at the current viewpoint. At ``k``
        times the distance the change has frequency ``k / (2 theta)`` cycles/deg, eccentricity ``e / k``
        and velocity ``v / k``. Returns the smallest ``k >= 0`` such that the change is imperceptible
        at every ``k' > k``; at ``k`` itself it is perceptible (within 1e-4 relative) unless k = 0.
        ``k <= 1`` means imperceptible from the current viewpoint. ``theta = 0`` gives 0.

        Generic method. A model whose ``inputs`` include neither ``"e"`` nor ``"v"`` is perceptible at
        ``k`` iff ``k / (2 theta) <= threshold_frequency(c)``, so ``k = 2 theta threshold_frequency(c)``
        exactly. Otherwise the LARGEST perceptible ``k`` is found by scanning a log grid of
        ``f = k / (2 theta)`` over [1e-4, 1e4] cycles/deg (``_N_GRID`` = 257 points, one step = 7.5 % in
        k) from the bottom, keeping the last perceptible grid point and refining the crossing above
        it by safeguarded Newton (so perceptibility that is not monotone in ``k``, through an
        eccentricity or velocity term, is handled). Guarantee: the answer is exact (to the root
        finder's precision) unless the set of perceptible ``k`` has a component lying entirely above
        the last perceptible grid point and strictly between two grid points, i.e. a perceptible
        window narrower than one grid step (7.5 % in k) above every other perceptible k; such a
        window is missed. Results are capped at ``2e4 theta``; perceptibility only below
        ``2e-4 theta`` reports 0. Implicit-function gradient. Subclasses override it with closed forms.
        """
        c, theta, e, v = check_inputs("imperceptible_distance", c=c, theta=theta, e=e, v=v)
        self = self._like(c, theta, e, v)
        shape = jnp.broadcast_shapes(c.shape, theta.shape, e.shape, v.shape)
        dtype = jnp.result_type(c, theta, e, v, float)
        pos = theta > 0
        if "e" not in self.inputs and "v" not in self.inputs:
            k = 2.0 * theta * self._threshold_frequency(c, e, v)
            return jnp.broadcast_to(jnp.where(pos, k, 0.0), shape).astype(dtype)
        th = jnp.where(pos, theta, 1.0)
        th_sg = lax.stop_gradient(th)

        def g(w):
            return self._distance_margin(jnp.exp(w), c, th, e, v)

        c_, e_, v_, ms = lax.stop_gradient((c, e, v, self))
        w_star, found, saturated = ms._generic_scan(c_, th_sg, e_, v_)
        ok = found & ~saturated & pos
        w = implicit_root(g, w_star, mask=ok)
        k = jnp.where(found & pos, jnp.exp(w), 0.0)
        return k.astype(dtype)

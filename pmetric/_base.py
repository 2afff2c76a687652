"""The common interface of every contrast-sensitivity model: :class:`CSFModel`, and its input checks.

Units: spatial frequency ``f`` in cycles/deg, eccentricity ``e`` in deg, retinal velocity ``v`` in
deg/s, Michelson contrast ``c`` (dimensionless, in [0, 1]), angular size ``theta`` in deg.

The contract (see :class:`CSFModel`): the public methods are written once, here; each checks and casts
its inputs once and calls a private hook that a model implements. Generic, exact numerical hooks
(grid bracketing + safeguarded Newton, implicit-function gradients) derive every question from
``_log_sensitivity``; models override them with closed forms where these exist.

Input checking: outside ``jax.jit`` (concrete inputs) a negative or NaN frequency / eccentricity /
velocity / contrast / size raises :class:`pmetric.PlodError` (a ``ValueError``) naming the argument.
Under ``jit`` values cannot be refused: NaN or negative inputs give NaN outputs
(``is_perceptible`` then returns False; :func:`_nan_propagating`). Shapes that do not broadcast raise
``PlodError`` at trace time.
"""

from __future__ import annotations

import functools
import inspect
import types
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from equinox._module._prebuilt import BoundMethod
from jax import lax

from ._errors import PlodError
from ._inverse import bracketed_root, implicit_root, largest_crossing
from ._numerics import as_float, is_tracer, log_guard

__all__ = ["CSFModel", "as_float", "check_inputs", "fill_nan", "param", "float_param", "distance_margin_k",
           "LOG_CT_MAX"]

#: threshold contrasts are capped at exp(LOG_CT_MAX) (about 1e26): finite in float32, "invisible".
LOG_CT_MAX = 60.0

# Search range (cycles/deg) of the generic numerical inversions.
_F_LO, _F_HI = 1e-4, 1e4
_N_GRID = 257  # grid points of the generic distance scan: ln(1e8) / 256 = 0.072 per step


# --------------------------------------------------------------------------- inputs and constants
#: stimulus arguments that must be given (None is an error); the others (luminance, area, vis_field) may
#: be None: "unknown", the model's default
_REQUIRED_ARGS = ("f", "c", "theta", "e", "v", "u", "E", "sigma", "x0", "y0")


def check_inputs(_method: str, **arrays):
    """Convert keyword arrays to float arrays, check they broadcast and (when concrete) their values.

    Every argument must be >= 0 and not NaN (``+inf`` is allowed). Raises :class:`PlodError` naming the
    argument. Returns the converted arrays in the order given (``None`` stays ``None`` for the arguments
    that may be unknown, luminance, area and the like; for a stimulus argument it is an error).
    """
    out = []
    shapes = {}
    for name, x in arrays.items():
        if x is None:
            if name in _REQUIRED_ARGS:  # before: a raw TypeError (float * NoneType) further in
                raise PlodError(f"{_method}: {name} is required (a number or an array), got None")
            out.append(None)
            continue
        if isinstance(x, (str, bytes)):
            raise PlodError(f"{_method}: {name} must be a number or an array, got {x!r}")
        try:
            xa = as_float(x)
        except TypeError as err:
            raise PlodError(f"{_method}: {name} must be a number or an array of numbers ({err})") from None
        except ValueError:  # numpy's "inhomogeneous shape"
            raise PlodError(f"{_method}: {name} must be a number or a rectangular array of numbers (a ragged "
                            "list?)") from None
        if not is_tracer(xa):
            xn = np.asarray(xa)
            if np.isnan(xn).any():
                raise PlodError(f"{_method}: {name} contains NaN")
            if (xn < 0).any():
                raise PlodError(f"{_method}: {name} must be >= 0 (got min {xn.min()!r})")
        shapes[name] = xa.shape
        out.append(xa)
    check_broadcast(_method, **shapes)
    return out


def check_broadcast(who: str, **shapes) -> tuple:
    """The shape the arguments' ``shapes`` broadcast to; PlodError naming them when they do not (shapes
    are static, so this works under jit too)."""
    try:
        return np.broadcast_shapes(*shapes.values())
    except ValueError:
        items = [f"{k} {tuple(v)}" for k, v in shapes.items()]
        got = items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]
        raise PlodError(f"{who}: the shapes of {got} do not broadcast") from None


def fill_nan(x, default):
    """Concrete NaN entries of ``x`` (unknown luminance/area in a data set) replaced by ``default``."""
    if x is None:
        return default
    if not is_tracer(x):
        a = np.asarray(x)
        if np.issubdtype(a.dtype, np.floating) and np.isnan(a).any():
            return jnp.asarray(np.where(np.isnan(a), default, a), dtype=jnp.asarray(x).dtype)
    return x


def float_param(value):
    """A model constant as an array of the default float dtype (no check)."""
    return jnp.asarray(value, dtype=jnp.result_type(float))


def param(value, name: str, *, positive: bool = True):
    """A model constant as a float array; concrete values are checked (finite, > 0 unless
    ``positive=False``), else :class:`PlodError` naming ``name``."""
    arr = float_param(value)
    if not is_tracer(arr):
        a = np.asarray(arr)
        if not np.all(np.isfinite(a)):
            raise PlodError(f"{name} must be finite, got {value!r}")
        if positive and np.any(a <= 0):
            raise PlodError(f"{name} must be > 0, got {value!r}")
    return arr


def check_constants(model) -> None:
    """PlodError naming the first concrete constant of ``model`` (its ``param_bounds``' fields) that is not
    finite or lies outside its bounds, as ``load_model`` would refuse it (traced constants are skipped):
    for models whose fields are converted, not built through :func:`param` (before, ``Barten(k=nan)``
    returned plausible-looking distances)."""
    for name, (lo, hi) in type(model).param_bounds.items():
        val = getattr(model, name)
        if is_tracer(val):
            continue
        a = np.asarray(val)
        ok = np.isfinite(a) & (True if lo is None else a >= lo) & (True if hi is None else a <= hi)
        if not np.all(ok):
            rule = ("finite" if lo is None and hi is None else f">= {lo:g}" if hi is None else
                    f"<= {hi:g}" if lo is None else f"in [{lo:g}, {hi:g}]")
            bad = a.ravel()[np.flatnonzero(~np.asarray(ok).ravel())[0]].item()
            raise PlodError(f"{type(model).__name__}: {name} must be {rule}, got {bad!r}")


def distance_margin_k(k, model, c, theta, e, v):
    """``model._distance_margin`` at distance multiple ``k`` as a function of its arguments only (the
    margin :func:`pmetric._inverse.implicit_solution` differentiates)."""
    return model._distance_margin(k, c, theta, e, v)


# --------------------------------------------------------------------------- the method contract
class _BoundCSFMethod(BoundMethod):
    """A public method bound to a model: an equinox ``BoundMethod`` (a pytree, so ``eqx.filter_jit`` /
    ``eqx.filter_grad`` of ``model.method`` treat the model's arrays as inputs) that hashes and compares
    like a Python bound method (its function and the identity of the model), so that
    ``jax.jit(model.method)`` works too (the model's constants are then compile-time constants).
    The model itself keeps equinox's value semantics."""

    def __hash__(self):
        return hash((self.__func__, id(self.__self__)))

    def __eq__(self, other):
        return (type(other) is type(self) and self.__func__ is other.__func__
                and self.__self__ is other.__self__)


#: the stimulus arguments of the public methods whose invalid entries (NaN or negative) give NaN
#: results (luminance and area are excluded: NaN there means "unknown, use the model's default")
_NAN_ARGS = ("f", "e", "v", "c", "theta")


def _nan_propagating(fn):
    """``fn`` with invalid in, NaN out under tracing: concrete NaN or negative inputs are refused by
    :func:`check_inputs`, but inside ``jax.jit`` they cannot be, and the models' guarded arithmetic
    would turn them into plausible finite values (0, 1e-30, a clamp: "invisible"). A float result is
    NaN wherever a stimulus argument (:data:`_NAN_ARGS`) is NaN or negative; a bool result
    (``is_perceptible``) is False there."""
    sig = inspect.signature(fn)

    @functools.wraps(fn)
    def method(self, *args, **kwargs):
        out = fn(self, *args, **kwargs)
        bound = sig.bind(self, *args, **kwargs)
        traced = [x for k, x in bound.arguments.items() if k in _NAN_ARGS and is_tracer(x)]
        if not traced:
            return out
        bad = functools.reduce(jnp.logical_or, (jnp.isnan(x) | (x < 0) for x in traced))
        if out.dtype == jnp.bool_:
            return jnp.where(bad, False, out)
        return jnp.where(bad, jnp.asarray(jnp.nan, out.dtype), out)

    return method


class jittable:
    """Decorator of a module's public array method: binds it as a :class:`_BoundCSFMethod`, so that
    ``jax.jit(obj.method)`` works (a plain equinox bound method of a module with array fields is not
    hashable) as well as ``eqx.filter_jit``. Accessed on the class it gives the plain function."""

    def __init__(self, fn):
        self.fn = fn
        functools.update_wrapper(self, fn)

    def __get__(self, obj, objtype=None):
        return self.fn if obj is None else _BoundCSFMethod(self.fn, obj)


class _public(jittable):
    """Decorator of the public methods of :class:`CSFModel`: :class:`jittable`, and NaN-propagating under
    tracing (:func:`_nan_propagating`). Accessed on the class it gives the plain function
    (``CSFModel.imperceptible_distance(m, ...)``)."""

    def __init__(self, fn):
        super().__init__(_nan_propagating(fn))
        functools.update_wrapper(self, fn)


class _hook_with_legacy:
    """The base ``_log_sensitivity``: abstract (the model cannot be built) unless the subclass
    implements ``_log_sensitivity``, ``_sensitivity``, or (the former contract) overrides the public
    ``log_sensitivity`` or ``sensitivity``, from which the default then derives log S."""

    __isabstractmethod__ = True  # on CSFModel itself

    def __init__(self, fn):
        self.fn = fn
        functools.update_wrapper(self, fn)

    def __get__(self, obj, objtype=None):
        if obj is not None:
            return types.MethodType(self.fn, obj)
        if any(getattr(objtype, n) is not getattr(CSFModel, n)
               for n in ("_sensitivity", "log_sensitivity", "sensitivity")):
            return self.fn
        return _abstract(self.fn)


def _abstract(fn):
    @functools.wraps(fn)
    def hook(*a, **k):
        return fn(*a, **k)

    hook.__isabstractmethod__ = True
    return hook


class CSFModel(eqx.Module):
    """Abstract contrast-sensitivity model (a frozen ``equinox.Module``).

    Fitted constants are floating array fields; switches are static fields. All methods broadcast
    their arguments (numpy rules) and are jit / vmap / grad clean in float32 and float64.

    **Contract.** The public methods -- :meth:`sensitivity`, :meth:`log_sensitivity`,
    :meth:`stimulus_sensitivity`, :meth:`threshold_contrast`, :meth:`peak_frequency`,
    :meth:`is_perceptible`, :meth:`threshold_frequency`, :meth:`imperceptible_distance` -- are written
    once, here. Each checks its inputs once (:func:`check_inputs`: float arrays that broadcast; when
    concrete, >= 0 and not NaN, else :class:`pmetric.PlodError`), casts the model's constants to the
    inputs' dtype once (:meth:`_like`), calls the matching private hook and broadcasts the result to
    the inputs' shape. Arguments come in the order ``(f, e, v)`` (contrast ``c`` and size ``theta``
    first where they apply). A model implements hooks only; they receive checked float arrays of a
    common dtype and may assume the model is cast to it:

    * ``_log_sensitivity(f, e, v)`` -- ln S, finite (required; or ``_sensitivity``, from which the
      default takes a guarded log);
    * ``_sensitivity(f, e, v)`` -- S (default ``exp(_log_sensitivity)``);
    * ``_stimulus_log_sensitivity(f, e, v, luminance, area)`` / ``_stimulus_sensitivity(...)`` -- for
      models with luminance / area terms (defaults ignore them);
    * ``_peak_frequency(e, v)``, ``_is_perceptible(c, f, e, v)``, ``_threshold_frequency(c, e, v)``,
      ``_imperceptible_distance(c, theta, e, v)`` -- generic exact defaults below, closed forms in the
      models;
    * ``_distance_margin(k, c, theta, e, v)`` -- THE perceptibility margin ``ln c - ln c_T`` at
      distance multiple ``k`` (perceptible iff >= 0), what the distance solvers and their
      implicit-function gradients use.

    Also set the class variables ``inputs`` (which of ``"f", "e", "v", "luminance", "area"`` the model
    depends on) and ``param_bounds`` (valid range of each fittable field, ``None`` = unbounded). A
    subclass written for the former contract (overriding the public ``sensitivity`` or
    ``log_sensitivity`` without checks) still works: the default hooks derive from it.

    **jit.** ``jax.jit(model.imperceptible_distance)`` works (the bound method hashes by the model's
    identity; the constants are baked into the compiled function, which is recompiled for every
    model). To trace the constants instead (one compilation for many models, gradients with respect to
    them) write ``eqx.filter_jit(model.imperceptible_distance)`` or
    ``jax.jit(lambda m, c, t: m.imperceptible_distance(c, t))(model, c, t)``.

    Generic hooks assume, as every CSF here satisfies, that sensitivity falls monotonically with
    frequency above the peak frequency (the "falling limb"); below it the peak's threshold is used,
    the worst case of [LH01 §3.1, §6.1], and the distance key is that of [LH01 §5.3].
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

    def _concrete_fields(self, names, dtype):
        """The fields ``names`` as float64 numpy arrays of their values in ``dtype`` (what the generic
        path computes with), for the per-model fast paths that precompute at trace time; None for a
        dtype other than float32 / float64 or when a field is traced (fitting, gradients)."""
        dtype = jnp.dtype(dtype)
        vals = [getattr(self, name) for name in names]
        if dtype not in (jnp.dtype(jnp.float32), jnp.dtype(jnp.float64)) or any(is_tracer(x) for x in vals):
            return None
        return [np.asarray(x).astype(dtype).astype(np.float64) for x in vals]

    def _checked(self, method: str, **arrays):
        """``(model cast to the inputs' dtype, checked inputs..., broadcast shape)``."""
        xs = check_inputs(method, **arrays)
        shape = jnp.broadcast_shapes(*(x.shape for x in xs if x is not None))
        return (self._like(*xs), *xs, shape)

    # ----------------------------------------------------------------- public methods (written once)
    @_public
    def sensitivity(self, f, e=0.0, v=0.0):
        """Contrast sensitivity S = 1/c_T at frequency ``f`` (cycles/deg), eccentricity ``e`` (deg) and
        retinal velocity ``v`` (deg/s); broadcast shape of the inputs."""
        m, f, e, v, shape = self._checked("sensitivity", f=f, e=e, v=v)
        return jnp.broadcast_to(m._sensitivity(f, e, v), shape)

    @_public
    def log_sensitivity(self, f, e=0.0, v=0.0, luminance=None, area=None):
        """Natural log of :meth:`stimulus_sensitivity` (finite: a closed form that never underflows, or
        sensitivities below 1e-30 clamped); ``luminance`` (cd/m2) and ``area`` (deg2) as there."""
        return self._stimulus("log_sensitivity", True, f, e, v, luminance=luminance, area=area)

    @_public
    def stimulus_sensitivity(self, f, e=0.0, v=0.0, luminance=None, area=None):
        """Sensitivity for a calibration stimulus of mean ``luminance`` (cd/m2) and ``area`` (deg2).

        Models without such terms ignore luminance and area (they are then not checked); models with
        them (Barten, stelaCSF) default them to their fields, also for NaN entries (unknown in a data
        set)."""
        return self._stimulus("stimulus_sensitivity", False, f, e, v, luminance=luminance, area=area)

    def _stimulus(self, method, log, f, e, v, **extra):
        """Shared body of :meth:`log_sensitivity` and :meth:`stimulus_sensitivity` (``extra``:
        luminance, area and, for stelaCSF, vis_field)."""
        for name in ("luminance", "area"):
            if name not in self.inputs:
                extra[name] = None
            elif getattr(self, name, None) is not None:
                extra[name] = fill_nan(extra[name], getattr(self, name))
        m, f, e, v, *xs, shape = self._checked(f"{type(self).__name__}.{method}", f=f, e=e, v=v, **extra)
        kw = dict(zip(extra, xs))
        out = m._stimulus_log_sensitivity(f, e, v, **kw) if log else m._stimulus_sensitivity(f, e, v, **kw)
        return jnp.broadcast_to(out, shape)

    @_public
    def threshold_contrast(self, f, e=0.0, v=0.0):
        """Threshold Michelson contrast c_T = 1/S (capped at ``exp(LOG_CT_MAX)``, about 1e26)."""
        m, f, e, v, shape = self._checked("threshold_contrast", f=f, e=e, v=v)
        return jnp.broadcast_to(jnp.exp(jnp.minimum(-m._log_sensitivity(f, e, v), LOG_CT_MAX)), shape)

    @_public
    def peak_frequency(self, e=0.0, v=0.0):
        """Frequency (cycles/deg) of peak sensitivity at eccentricity ``e`` and velocity ``v``.

        Generic: the best of a 49-point log grid over [1e-3, 1e3] cycles/deg refined by golden-section
        search to ~1e-5 relative; its gradient is the implicit-function derivative of
        d(log S)/d(log f) = 0. Models override ``_peak_frequency`` with closed forms.
        """
        m, e, v, shape = self._checked("peak_frequency", e=e, v=v)
        return jnp.broadcast_to(m._peak_frequency(e, v), shape)

    @_public
    def is_perceptible(self, c, f, e=0.0, v=0.0):
        """True where contrast ``c`` at frequency ``f`` (cycles/deg), eccentricity ``e`` (deg) and
        velocity ``v`` (deg/s) is visible: ``c >= c_T(max(f, f_peak(e, v)), e, v)`` (below the peak
        frequency the peak's threshold is used, the worst case of [LH01 §3.1, §6.1]).
        Bool array of the broadcast shape. NaN inputs under jit give False."""
        m, c, f, e, v, shape = self._checked("is_perceptible", c=c, f=f, e=e, v=v)
        return jnp.broadcast_to(m._is_perceptible(c, f, e, v), shape)

    @_public
    def threshold_frequency(self, c, e=0.0, v=0.0):
        """Highest frequency (cycles/deg) at which Michelson contrast ``c`` is still visible at
        eccentricity ``e`` and velocity ``v``; 0 where ``c`` is invisible at every frequency.

        Inverse of the falling limb: ``threshold_contrast(threshold_frequency(c)) == c`` where the
        result is positive. Generic: safeguarded Newton in log f between the peak frequency and 1e4
        cycles/deg (results are capped at 1e4); exact implicit-function gradient.
        """
        m, c, e, v, shape = self._checked("threshold_frequency", c=c, e=e, v=v)
        return jnp.broadcast_to(m._threshold_frequency(c, e, v), shape)

    @_public
    def imperceptible_distance(self, c, theta, e=0.0, v=0.0):
        """Viewing-distance multiple beyond which a change is imperceptible [LH01 §5.3].

        ``c``: Michelson contrast of the change; ``theta``: its angular size (deg); ``e``: its
        eccentricity (deg); ``v``: its retinal velocity (deg/s), all at the current viewpoint. At ``k``
        times the distance the change has frequency ``k / (2 theta)`` cycles/deg, eccentricity ``e / k``
        and velocity ``v / k``. Returns the smallest ``k >= 0`` such that the change is imperceptible
        at every ``k' > k``; at ``k`` itself it is perceptible (within 1e-4 relative) unless k = 0.
        ``k <= 1`` means imperceptible from the current viewpoint. ``theta = 0`` gives 0. Values are finite for
        every ``theta >= 0``; on the generic path below (and the paths built on it: KellySpatioTemporal,
        Eccentric of a velocity model, calibrated tables), gradients are finite for ``theta = 0`` and
        ``theta`` above about 1e-19 deg in float32 (the square root of the smallest normal float; 1.5e-154
        in float64): below it ``theta^2`` underflows in the implicit derivative (measured, NaN at 1e-20
        and 1e-30 deg in float32; far below any change a display can show, so not guarded).

        Generic hook (:meth:`_imperceptible_distance`). A model whose ``inputs`` include neither
        ``"e"`` nor ``"v"`` is perceptible at ``k`` iff ``k / (2 theta) <= threshold_frequency(c)``, so
        ``k = 2 theta threshold_frequency(c)`` exactly. Otherwise the LARGEST perceptible ``k`` is found
        by scanning a log grid of ``f = k / (2 theta)`` over [1e-4, 1e4] cycles/deg (``_N_GRID`` = 257
        points, one step = 7.5 % in k) from the bottom, keeping the last perceptible grid point and
        refining the crossing above it by safeguarded Newton (so perceptibility that is not monotone
        in ``k``, through an eccentricity or velocity term, is handled). Guarantee: the answer is exact
        (to the root finder's precision) unless the set of perceptible ``k`` has a component lying
        entirely above the last perceptible grid point and strictly between two grid points, i.e. a
        perceptible window narrower than one grid step (7.5 % in k) above every other perceptible k;
        such a window is missed. Results are capped at ``2e4 theta``; perceptibility only below
        ``2e-4 theta`` reports 0. Implicit-function gradient. Models override the hook with closed
        forms.
        """
        m, c, theta, e, v, shape = self._checked("imperceptible_distance", c=c, theta=theta, e=e, v=v)
        return jnp.broadcast_to(m._imperceptible_distance(c, theta, e, v), shape)

    # ----------------------------------------------------------------- hooks: the model
    @_hook_with_legacy
    def _log_sensitivity(self, f, e, v):
        """ln S at checked inputs. Default (a model implementing ``_sensitivity``, or one written for
        the former contract): the guarded log of its sensitivity."""
        cls = type(self)
        if cls.log_sensitivity is not CSFModel.log_sensitivity:
            return cls.log_sensitivity(self, f, e, v)
        if cls.sensitivity is not CSFModel.sensitivity:
            return log_guard(cls.sensitivity(self, f, e, v))
        return log_guard(self._sensitivity(f, e, v))

    def _sensitivity(self, f, e, v):
        """S at checked inputs; default ``exp(_log_sensitivity)``."""
        cls = type(self)
        if cls.sensitivity is not CSFModel.sensitivity:  # the former contract
            return cls.sensitivity(self, f, e, v)
        return jnp.exp(self._log_sensitivity(f, e, v))

    def _stimulus_log_sensitivity(self, f, e, v, luminance=None, area=None):
        """ln S of a stimulus of ``luminance`` and ``area``; default: ignores them."""
        return self._log_sensitivity(f, e, v)

    def _stimulus_sensitivity(self, f, e, v, luminance=None, area=None):
        """S of a stimulus of ``luminance`` and ``area``; default: ignores them."""
        return self._sensitivity(f, e, v)

    # ----------------------------------------------------------------- hooks: generic solvers
    def _peak_frequency(self, e, v):
        """Generic peak search (see :meth:`peak_frequency`)."""
        shape = jnp.broadcast_shapes(jnp.shape(e), jnp.shape(v))
        dtype = jnp.result_type(e, v, float)
        if shape and "e" not in self.inputs and "v" not in self.inputs:
            # the peak does not depend on e, v: search once (a scalar) and broadcast
            return jnp.broadcast_to(self._peak_frequency(jnp.zeros((), dtype), jnp.zeros((), dtype)), shape)
        e_, v_, ms = lax.stop_gradient((e, v, self))
        logs = lambda u: ms._log_sensitivity(jnp.exp(u), e_, v_)  # noqa: E731
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
            return jax.jvp(lambda uu: self._log_sensitivity(jnp.exp(uu), e, v), (u,), (jnp.ones_like(u),))[1]

        interior = (u_star > u_lo + du) & (u_star < u_hi - du)
        u = implicit_root(dlog, u_star, mask=interior)
        return jnp.exp(u)

    def _peak_frequency_sg(self, e, v):
        """The peak frequency under ``stop_gradient`` (used where its derivative is not needed, e.g. the
        distance margin). Models whose ``_peak_frequency`` pays for an implicit-gradient pass in the
        forward computation override it with the bare search."""
        return lax.stop_gradient(self._peak_frequency(e, v))

    def _is_perceptible(self, c, f, e, v):
        """Generic: ``ln c + ln S(max(f, f_peak)) >= 0`` (the peak needs no gradient: a bool)."""
        fe = jnp.maximum(f, self._peak_frequency_sg(e, v))
        return log_guard(c) + self._log_sensitivity(fe, e, v) >= 0

    def _threshold_frequency(self, c, e, v):
        """Generic inverse of the falling limb (see :meth:`threshold_frequency`)."""
        shape = jnp.broadcast_shapes(c.shape, e.shape, v.shape)
        dtype = jnp.result_type(c, e, v, float)
        fp = lax.stop_gradient(jnp.broadcast_to(self._peak_frequency(e, v), shape).astype(dtype))
        logc = log_guard(c)

        def g(u):
            return logc + self._log_sensitivity(jnp.exp(u), e, v)

        logc_, e_, v_, ms = lax.stop_gradient((logc, e, v, self))
        g_sg = lambda u: logc_ + ms._log_sensitivity(jnp.exp(u), e_, v_)  # noqa: E731
        u_lo = jnp.log(fp)
        u_hi = jnp.full(shape, np.log(_F_HI), dtype)
        visible = g_sg(u_lo) >= 0
        saturated = g_sg(u_hi) >= 0
        u_star = bracketed_root(g_sg, u_lo, jnp.maximum(u_hi, u_lo + 1e-6))
        ok = visible & ~saturated
        u = implicit_root(g, jnp.where(ok, u_star, u_lo), mask=ok)
        return jnp.where(visible, jnp.where(saturated, jnp.asarray(_F_HI, dtype), jnp.exp(u)), 0.0)

    # ----------------------------------------------------------------- hooks: distance key
    def _distance_margin(self, k, c, theta, e, v, peak=None):
        """The perceptibility margin: ``ln c - ln c_T`` at distance multiple ``k`` (perceptible iff >= 0).

        The peak frequency (``peak(e, v)``, default :meth:`_peak_frequency_sg`) enters under
        ``stop_gradient``: where it binds (f below the peak) the margin is log S at its maximum over f,
        so by the envelope theorem its derivative with respect to the peak location is 0 and every
        derivative of the margin stays exact, without differentiating the peak search."""
        f = k / (2.0 * theta)
        ek, vk = e / k, v / k
        fe = jnp.maximum(f, (self._peak_frequency_sg if peak is None else peak)(ek, vk))
        return log_guard(c) + self._log_sensitivity(fe, ek, vk)

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

    def _imperceptible_distance(self, c, theta, e, v):
        """Generic distance solve (see :meth:`imperceptible_distance`)."""
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

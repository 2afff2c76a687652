"""Fitting the constants of a CSF model to measured contrast thresholds (least squares).

The residual of row ``i`` is the error in log10 sensitivity (equivalently, in log10 threshold contrast)::

    r_i = log10 S_model(f_i, e_i, v_i, L_i, A_i) + log10 m_{d(i)} - log10 S_i

with an optional free sensitivity multiplier ``m_d`` per dataset ``d`` (the published castleCSF /
stelaCSF fits allow one, about 0.5-1.7x: Mantiuk et al. 2022, ACM TOG 41(4):145; Ashraf et al. 2024,
JoV 24(4):5). The multipliers are constrained to a geometric mean of 1 (``sum_d log10 m_d = 0``) so
that they never trade off against the model's own gain constant (the problem stays identifiable).

Which constants are fitted: the floating array leaves of the model (``eqx.partition`` with
``eqx.is_inexact_array``), optionally restricted by ``fit=[field names]``. Each is reparametrised by the
model's ``param_bounds`` so that every step of every solver stays inside the valid range (no clipping):

=================  ==================================  ===================
bounds             natural value ``x`` from ``u``        inverse
=================  ==================================  ===================
``(None, None)``   ``x = u``                           ``u = x``
``(lo, None)``     ``x = lo + exp(u)``                 ``u = log(x - lo)``
``(None, hi)``     ``x = hi - exp(u)``                 ``u = log(hi - x)``
``(lo, hi)``       ``x = lo + (hi - lo) sigmoid(u)``   ``u = logit((x - lo) / (hi - lo))``
=================  ==================================  ===================

The covariance of the natural parameters is ``D (J^T J)^+ D^T s^2`` with ``J`` the Jacobian of the
residuals in ``u``, ``s^2 = SSR / (n - p)`` and ``D = dx/du`` (the delta method through the
reparametrisation).

Fitting runs in float64: every public function here switches ``jax_enable_x64`` on locally (the
fitted model is returned with its original leaf dtypes).
"""

from __future__ import annotations

import dataclasses
import inspect
import math
from typing import Any, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "FitResult",
    "expressible_rows",
    "fit_least_squares",
    "fitted_fields",
]

SOLVERS = ("lm", "gauss-newton", "bfgs")
BACKENDS = ("optimistix", "jaxopt")

# Kinds of reparametrisation.
_IDENT, _LOWER, _UPPER, _INTERVAL = 0, 1, 2, 3

# Rows a model without a luminance term can express: photopic luminance (cd/m2), where the CSF
# is close to Weber behaviour. Rows a model without an area term can express: area >= this (deg2).
PHOTOPIC_RANGE = (10.0, 1000.0)
MIN_AREA_DEG2 = 0.5


# ----------------------------------------------------------------------------- parameter layout
@dataclasses.dataclass(frozen=True)
class _Leaf:
    name: str            # dotted field path, e.g. "p_peak" or "display.gamma"
    field: str           # top-level field name (the key of param_bounds)
    index: int           # position among the flattened inexact leaves
    shape: tuple
    size: int
    kind: int
    lo: float
    hi: float


def _path_name(path) -> str:
    parts = []
    for k in path:
        if isinstance(k, jax.tree_util.GetAttrKey):
            parts.append(k.name)
        elif isinstance(k, jax.tree_util.SequenceKey):
            parts.append(f"[{k.idx}]")
        elif isinstance(k, jax.tree_util.DictKey):
            parts.append(f"[{k.key!r}]")
        else:  # pragma: no cover - other key kinds
            parts.append(str(k))
    out = ""
    for p in parts:
        out += p if (p.startswith("[") or not out) else "." + p
    return out


def _kind(bounds) -> tuple[int, float, float]:
    lo, hi = (None, None) if bounds is None else bounds
    if lo is not None and hi is not None:
        if not hi > lo:
            raise ValueError(f"param_bounds {bounds} must have lo < hi")
        return _INTERVAL, float(lo), float(hi)
    if lo is not None:
        return _LOWER, float(lo), math.inf
    if hi is not None:
        return _UPPER, -math.inf, float(hi)
    return _IDENT, -math.inf, math.inf


def fitted_fields(model, fit: Sequence[str] | None = None) -> list[str]:
    """Names (dotted paths) of the array leaves of ``model`` that fitting adjusts.

    All floating array leaves unless ``fit`` restricts them (top-level field names or dotted paths).
    """
    return [leaf.name for leaf in _layout(model, fit)[2]]


def _layout(model, fit):
    if not isinstance(model, eqx.Module):
        raise ValueError(f"model must be a pmetric CSF model (an equinox Module), got {type(model).__name__}")
    if not hasattr(model, "stimulus_sensitivity"):
        raise ValueError(f"{type(model).__name__} has no stimulus_sensitivity method; it cannot be fitted")
    params, static = eqx.partition(model, eqx.is_inexact_array)
    with_path, treedef = jax.tree_util.tree_flatten_with_path(params)
    names = [_path_name(p) for p, _ in with_path]
    if not names:
        raise ValueError(f"{type(model).__name__} has no floating array fields to fit")
    if fit is not None:
        if isinstance(fit, str):
            fit = [fit]
        unknown = [n for n in fit if n not in names and not any(m.split(".")[0] == n for m in names)]
        if unknown:
            raise ValueError(f"fit= names unknown fields {unknown} of {type(model).__name__}; "
                             f"fittable fields: {names}")
        if not fit:
            raise ValueError("fit= is empty: name at least one field to fit")
    leaves, spec = [], []
    for i, ((path, leaf), name) in enumerate(zip(with_path, names)):
        field = name.split(".")[0].split("[")[0]
        chosen = fit is None or name in fit or field in fit
        arr = np.asarray(leaf, dtype=np.float64)
        leaves.append(arr)
        if not chosen:
            continue
        kind, lo, hi = _kind(_leaf_bounds(model, path))
        bad = ~np.isfinite(arr) | (arr < lo) | (arr > hi)
        if bad.any():
            raise ValueError(f"{type(model).__name__}.{name} = {arr.ravel()[np.argmax(bad.ravel())]!r} lies "
                             f"outside its param_bounds ({lo}, {hi}); cannot start a fit there")
        spec.append(_Leaf(name, field, i, tuple(arr.shape), int(arr.size), kind, lo, hi))
    return treedef, static, tuple(spec), leaves, params


def _leaf_bounds(model, path):
    """``param_bounds`` entry of the module that owns the leaf at ``path`` (nested modules too)."""
    owner, field, obj = model, None, model
    for k in path:
        if isinstance(k, jax.tree_util.GetAttrKey):
            owner, field = obj, k.name
            obj = getattr(obj, k.name)
        elif isinstance(k, jax.tree_util.SequenceKey):
            obj = obj[k.idx]
        elif isinstance(k, jax.tree_util.DictKey):
            obj = obj[k.key]
    bounds = getattr(type(owner), "param_bounds", None) or {}
    return bounds.get(field) if field is not None else None


def _to_u(x: np.ndarray, leaf: _Leaf) -> np.ndarray:
    """Natural value -> unconstrained value (numpy, float64); values on a bound move just inside."""
    x = np.asarray(x, dtype=np.float64).ravel()
    if leaf.kind == _IDENT:
        return x
    if leaf.kind == _LOWER:
        d = x - leaf.lo
        return np.log(np.maximum(d, 1e-12 * max(1.0, abs(leaf.lo))))
    if leaf.kind == _UPPER:
        d = leaf.hi - x
        return np.log(np.maximum(d, 1e-12 * max(1.0, abs(leaf.hi))))
    p = np.clip((x - leaf.lo) / (leaf.hi - leaf.lo), 1e-9, 1.0 - 1e-9)
    return np.log(p) - np.log1p(-p)


def _from_u_np(u: np.ndarray, leaf: _Leaf) -> np.ndarray:
    """Numpy twin of ``_from_u`` (natural value only), for host-side bookkeeping."""
    u = np.asarray(u, np.float64)
    if leaf.kind == _IDENT:
        return u
    lim = float(np.log(np.finfo(np.float64).max)) - 2.0
    if leaf.kind == _LOWER:
        return leaf.lo + np.exp(np.clip(u, -lim, lim))
    if leaf.kind == _UPPER:
        return leaf.hi - np.exp(np.clip(u, -lim, lim))
    return leaf.lo + (leaf.hi - leaf.lo) / (1.0 + np.exp(-np.clip(u, -lim, lim)))


def _safe_exp(u):
    # exp guarded against overflow: beyond +-(log max - 2) the value saturates (gradient 0 there only)
    lim = float(np.log(np.finfo(jnp.result_type(u)).max)) - 2.0
    return jnp.exp(jnp.clip(u, -lim, lim))


def _from_u(u, leaf: _Leaf):
    """Unconstrained -> natural value and its derivative dx/du (both shape (size,))."""
    if leaf.kind == _IDENT:
        return u, jnp.ones_like(u)
    if leaf.kind == _LOWER:
        ex = _safe_exp(u)
        return leaf.lo + ex, ex
    if leaf.kind == _UPPER:
        ex = _safe_exp(u)
        return leaf.hi - ex, -ex
    s = jax.nn.sigmoid(u)
    w = leaf.hi - leaf.lo
    return leaf.lo + w * s, w * s * (1.0 - s)


# ----------------------------------------------------------------------------- rows a model can express
def expressible_rows(model, data) -> tuple[np.ndarray, list[str]]:
    """Rows of ``data`` the model can express, given the inputs it declares (``type(model).inputs``).

    Returns ``(mask (n,) bool, reasons)``, ``reasons`` a list of the rules applied, in words:

    * every model: spatial frequency > 0 (disk stimuli, f = 0, are left out);
    * no ``"v"`` input: static stimuli only (t_frequency = 0);
    * no ``"e"`` input: foveal stimuli only (eccentricity = 0);
    * no ``"luminance"`` input: photopic rows only (10 <= L <= 1000 cd/m2; unknown L is kept);
    * no ``"area"`` input: large stimuli only (area >= 0.5 deg2; unknown area is kept).
    """
    inputs = tuple(getattr(model, "inputs", ("f", "e", "v")))
    mask = np.asarray(data.f > 0)
    reasons = ["f > 0 (gratings and Gabors; disks are not CSF stimuli)"]
    if "v" not in inputs:
        mask &= (data.velocity == 0) & (data.t_frequency == 0)
        reasons.append("static only (t_frequency = 0)")
    if "e" not in inputs:
        mask &= data.e == 0
        reasons.append("foveal only (e = 0)")
    if "luminance" not in inputs:
        lum = data.luminance
        mask &= np.isnan(lum) | ((lum >= PHOTOPIC_RANGE[0]) & (lum <= PHOTOPIC_RANGE[1]))
        reasons.append(f"photopic only ({PHOTOPIC_RANGE[0]:g} <= L <= {PHOTOPIC_RANGE[1]:g} cd/m2)")
    if "area" not in inputs:
        mask &= np.isnan(data.area) | (data.area >= MIN_AREA_DEG2)
        reasons.append(f"large stimuli only (area >= {MIN_AREA_DEG2:g} deg2)")
    return mask, reasons


# ----------------------------------------------------------------------------- the problem
@dataclasses.dataclass(frozen=True)
class _Static:
    """Hashable, static description of a fitting problem (part of the jit cache key)."""

    treedef: Any
    static_model: Any
    spec: tuple
    n_groups: int
    multipliers: bool
    has_lum: bool
    has_area: bool
    has_vis: bool

    @property
    def n_model(self) -> int:
        return sum(leaf.size for leaf in self.spec)

    @property
    def n_free(self) -> int:
        return self.n_model + (self.n_groups - 1 if self.multipliers else 0)


def _check_data(data):
    for attr in ("f", "e", "velocity", "luminance", "area", "log_threshold", "dataset"):
        if not hasattr(data, attr):
            raise ValueError(f"data must be a pmetric.CalibrationData (missing attribute {attr!r}), "
                             f"got {type(data).__name__}")
    if len(data) == 0:
        raise ValueError("data has no rows")


class _Problem:
    """A model + data pair laid out for the solvers (float64 numpy on the host)."""

    def __init__(self, model, data, *, fit=None, multipliers=False, weighted=False, rows="auto"):
        _check_data(data)
        treedef, static_model, spec, leaves, _ = _layout(model, fit)
        if isinstance(rows, str) and rows not in ("auto", "all"):
            raise ValueError(f"rows must be 'auto', 'all' (or None) or a boolean mask, got {rows!r}")
        if isinstance(rows, str) and rows == "auto":
            mask, reasons = expressible_rows(model, data)
        elif rows is None or isinstance(rows, str):
            mask, reasons = np.ones(len(data), bool), []
        else:
            mask = np.asarray(rows)
            if mask.dtype != bool or mask.shape != (len(data),):
                raise ValueError(f"rows mask must be boolean of shape ({len(data)},), got {mask.dtype} {mask.shape}")
            reasons = ["rows given by the caller"]
        if not mask.any():
            raise ValueError(f"no rows of the data can be expressed by {type(model).__name__} "
                             f"(inputs {getattr(model, 'inputs', '?')}; rules: {'; '.join(reasons)})")
        sub = data.subset(mask)
        self.model, self.mask, self.reasons, self.data = model, mask, reasons, sub
        self.group_names = sub.datasets
        gid = {g: i for i, g in enumerate(self.group_names)}
        self.group = np.array([gid[d] for d in sub.dataset.tolist()], dtype=np.int32)
        lum, area = np.asarray(sub.luminance), np.asarray(sub.area)
        has_lum = bool(np.isfinite(lum).any())
        has_area = bool(np.isfinite(area).any())
        inputs = tuple(getattr(model, "inputs", ()))
        if has_lum and "luminance" in inputs and not np.isfinite(lum).all():
            raise ValueError("data mixes known and unknown (NaN) luminance; fill it in or drop those rows")
        if has_area and "area" in inputs and not np.isfinite(area).all():
            raise ValueError("data mixes known and unknown (NaN) area; fill it in or drop those rows")
        # vis_field (deg) goes to models whose stimulus_sensitivity accepts it (stelaCSF)
        vis = np.asarray(sub.vis_field, np.float64)
        try:
            takes_vis = "vis_field" in inspect.signature(model.stimulus_sensitivity).parameters
        except (TypeError, ValueError):  # pragma: no cover
            takes_vis = False
        has_vis = takes_vis and bool(np.isfinite(vis).any())
        vis_default = float(getattr(model, "vis_field", 0.0) or 0.0)
        self.static = _Static(treedef, static_model, spec, len(self.group_names), bool(multipliers),
                              has_lum, has_area, has_vis)
        n = len(sub)
        p = self.static.n_free
        if n < p:
            raise ValueError(f"{n} data rows cannot determine {p} free constants; give more data or fit= fewer")
        w = np.asarray(sub.weights, dtype=np.float64) if weighted else np.ones(n)
        self.arrays = dict(
            f=np.asarray(sub.f, np.float64), e=np.asarray(sub.e, np.float64),
            v=np.asarray(sub.velocity, np.float64),
            lum=np.where(np.isfinite(lum), lum, 1.0), area=np.where(np.isfinite(area), area, 1.0),
            vis=np.where(np.isfinite(vis), vis, vis_default),
            y=np.asarray(-sub.log_threshold, np.float64),  # log10 sensitivity
            sw=np.sqrt(w / w.mean()), group=self.group,
        )
        self.leaves = leaves
        self.theta0 = np.concatenate(
            [_to_u(leaves[s.index], s) for s in spec]
            + ([np.zeros(len(self.group_names) - 1)] if multipliers else [])
        )

    def theta_to_model(self, theta: np.ndarray, dtype_like=True):
        """Model with the natural values of ``theta`` (numpy, float64), in the original leaf dtypes."""
        leaves = jax.tree_util.tree_leaves(eqx.partition(self.model, eqx.is_inexact_array)[0])
        out = list(leaves)
        off = 0
        for s in self.static.spec:
            x = _from_u_np(theta[off:off + s.size], s)
            dt = leaves[s.index].dtype if dtype_like else jnp.float64
            with np.errstate(over="ignore"):  # a diverged fit (result code says so) may overflow float32
                out[s.index] = jnp.asarray(x.reshape(s.shape).astype(dt))
            off += s.size
        return eqx.combine(jax.tree_util.tree_unflatten(self.static.treedef, out), self.static.static_model)


def _model_from_theta(theta, fixed, st: _Static):
    leaves = list(fixed)
    off = 0
    for s in st.spec:
        x, _ = _from_u(theta[off:off + s.size], s)
        leaves[s.index] = x.reshape(s.shape)
        off += s.size
    params = jax.tree_util.tree_unflatten(st.treedef, leaves)
    return eqx.combine(params, st.static_model)


def _log10_multipliers(theta, st: _Static):
    if not st.multipliers or st.n_groups == 1:
        return jnp.zeros(st.n_groups, theta.dtype)
    w = theta[st.n_model:]
    return jnp.concatenate([w, -jnp.sum(w, keepdims=True)])


def _safe_log10(s):
    tiny = jnp.finfo(jnp.result_type(s)).tiny
    ok = jnp.isfinite(s) & (s > tiny)
    return jnp.where(ok, jnp.log10(jnp.where(ok, s, 1.0)), jnp.log10(tiny))


def _predict_log10(theta, fixed, arrays, st: _Static):
    """log10 sensitivity of every row (model only, no multipliers), shape (n,)."""
    model = _model_from_theta(theta, fixed, st)
    kw = {"vis_field": arrays["vis"]} if st.has_vis else {}
    s = model.stimulus_sensitivity(
        arrays["f"], arrays["e"], arrays["v"],
        luminance=arrays["lum"] if st.has_lum else None,
        area=arrays["area"] if st.has_area else None,
        **kw,
    )
    return _safe_log10(jnp.broadcast_to(s, arrays["f"].shape))


def _residuals(theta, fixed, arrays, st: _Static):
    """Weighted residuals in log10 sensitivity, shape (n,)."""
    pred = _predict_log10(theta, fixed, arrays, st) + _log10_multipliers(theta, st)[arrays["group"]]
    return arrays["sw"] * (pred - arrays["y"])


def _natural_jacobian(theta, st: _Static):
    """Linear map from d theta to d(natural model params, log10 multipliers of all groups)."""
    blocks = []
    off = 0
    for s in st.spec:
        _, d = _from_u(theta[off:off + s.size], s)
        blocks.append(d)
        off += s.size
    dmodel = jnp.concatenate(blocks) if blocks else jnp.zeros((0,), theta.dtype)
    p = st.n_free
    m = jnp.zeros((st.n_model + (st.n_groups if st.multipliers else 0), p), theta.dtype)
    m = m.at[jnp.arange(st.n_model), jnp.arange(st.n_model)].set(dmodel)
    if st.multipliers and st.n_groups > 1:
        g = st.n_groups
        pm = jnp.concatenate([jnp.eye(g - 1, dtype=theta.dtype), -jnp.ones((1, g - 1), theta.dtype)])
        m = m.at[st.n_model:, st.n_model:].set(pm)
    return m


_OPTX_CODES = None


def _optx_code_names():
    global _OPTX_CODES
    if _OPTX_CODES is None:
        import optimistix as optx

        _OPTX_CODES = {int(item._value): name for name, item in optx.RESULTS._name_to_item.items()}
    return _OPTX_CODES


@eqx.filter_jit
def _solve(theta0, fixed, arrays, st: _Static, solver: str, backend: str, rtol: float, atol: float,
           max_steps: int):
    """Run one solver; returns (theta, residuals, cov_natural, code, steps, grad_norm)."""

    def resid(theta, args=None):
        return _residuals(theta, fixed, arrays, st)

    # BFGS works on Jacobi-preconditioned coordinates z: theta = theta0 + z / sqrt(diag(J^T J)) at
    # theta0, so that its first (steepest-descent) step is sensibly scaled in every constant.
    j0 = jax.jacfwd(resid)(theta0)
    scale = 1.0 / jnp.sqrt(jnp.maximum(jnp.sum(j0 * j0, axis=0), 1e-12))

    def loss(z, args=None):
        r = resid(theta0 + scale * z)
        return 0.5 * jnp.sum(r * r)

    if backend == "optimistix":
        import optimistix as optx

        if solver == "lm":
            sol = optx.least_squares(resid, optx.LevenbergMarquardt(rtol=rtol, atol=atol), theta0,
                                     max_steps=max_steps, throw=False)
        elif solver == "gauss-newton":
            sol = optx.least_squares(resid, optx.GaussNewton(rtol=rtol, atol=atol), theta0,
                                     max_steps=max_steps, throw=False)
        else:
            sol = optx.minimise(loss, optx.BFGS(rtol=rtol, atol=atol), jnp.zeros_like(theta0),
                                max_steps=max_steps, throw=False)
        theta = theta0 + scale * sol.value if solver == "bfgs" else sol.value
        code = sol.result._value
        steps = sol.stats["num_steps"]
    else:
        import jaxopt

        if solver == "lm":
            opt = jaxopt.LevenbergMarquardt(resid, maxiter=max_steps, tol=atol, xtol=rtol, gtol=atol,
                                            solver="cholesky", materialize_jac=True,
                                            implicit_diff=False)
        elif solver == "gauss-newton":
            opt = jaxopt.GaussNewton(resid, maxiter=max_steps, tol=atol, implicit_diff=False)
        else:
            opt = jaxopt.BFGS(loss, maxiter=max_steps, tol=atol, implicit_diff=False)
        if solver == "bfgs":
            z, state = opt.run(jnp.zeros_like(theta0))
            theta = theta0 + scale * z
        else:
            theta, state = opt.run(theta0)
        steps = state.iter_num
        # jaxopt has no result enum: successful when the stopping criterion was met
        # (its loop runs at most max_steps - 1 iterations and stops early on a NaN gradient norm)
        code = jnp.where(state.error <= atol, 0,
                         jnp.where(jnp.isnan(state.error), 9, jnp.where(steps >= max_steps - 1, 1, 4)))
    r = resid(theta)
    finite = jnp.all(jnp.isfinite(theta)) & jnp.all(jnp.isfinite(r))
    code = jnp.where(finite, code, 9)
    jac = jax.jacfwd(resid)(theta)
    n, p = r.shape[0], theta.shape[0]
    s2 = jnp.sum(r * r) / jnp.maximum(n - p, 1)
    cov_u = jnp.linalg.pinv(jac.T @ jac, hermitian=True) * s2
    m = _natural_jacobian(theta, st)
    cov = m @ cov_u @ m.T
    grad = jac.T @ r
    return theta, r, cov, code, steps, jnp.max(jnp.abs(grad), initial=0.0)


# ----------------------------------------------------------------------------- results
@dataclasses.dataclass(frozen=True)
class FitResult:
    """Outcome of ``fit_least_squares``.

    Attributes:
        model: the fitted model (same class as the input; unfitted fields unchanged).
        rmse_log10: root-mean-square residual in log10 sensitivity over the fitted rows (multipliers
            applied when fitted).
        rmse_db: the same in dB of sensitivity (20 * rmse_log10).
        rmse_per_dataset: {dataset: RMSE in dB}.
        multipliers: {dataset: sensitivity multiplier} (all 1.0 without ``multipliers=True``).
        param_names: names of the natural parameters in ``covariance`` order (array fields expand to
            ``name[i]``), then ``log10_multiplier[dataset]`` when fitted.
        values: natural parameter values, shape (p,).
        covariance: (p, p) covariance of the natural parameters (delta method), ``stderr`` its sqrt diag.
        result: the solver's result code ("successful", "max_steps_reached", "nonfinite", ...).
        steps: solver iterations; n_rows: rows fitted; rows: (n_data,) bool mask of the rows used;
        row_rules: the rules that chose them (see ``expressible_rows``); residuals: (n_rows,) log10
        residuals (model - data); solver, backend: what ran; grad_max: largest |gradient| of the
        loss at the optimum; theta: the optimum in the unconstrained (log / logit) coordinates.
    """

    model: Any
    rmse_log10: float
    rmse_db: float
    rmse_per_dataset: dict
    multipliers: dict
    param_names: list
    values: np.ndarray
    covariance: np.ndarray
    stderr: np.ndarray
    result: str
    steps: int
    n_rows: int
    rows: np.ndarray
    row_rules: list
    residuals: np.ndarray
    solver: str
    backend: str
    grad_max: float
    theta: np.ndarray

    @property
    def success(self) -> bool:
        return self.result == "successful"

    def summary(self) -> str:
        lines = [f"{type(self.model).__name__}: RMSE {self.rmse_db:.3f} dB ({self.rmse_log10:.4f} log10) "
                 f"on {self.n_rows} rows; {self.solver}/{self.backend}: {self.result} after {self.steps} steps"]
        for name, v, se in zip(self.param_names, self.values, self.stderr):
            lines.append(f"  {name:<28} {v: .6g}  +- {se:.3g}")
        return "\n".join(lines)


def _param_names(prob: _Problem) -> list[str]:
    names = []
    for s in prob.static.spec:
        if s.size == 1 and s.shape == ():
            names.append(s.name)
        else:
            names += [f"{s.name}[{i}]" for i in range(s.size)]
    if prob.static.multipliers:
        names += [f"log10_multiplier[{g}]" for g in prob.group_names]
    return names


def _natural_values(prob: _Problem, theta: np.ndarray) -> np.ndarray:
    out, off = [], 0
    for s in prob.static.spec:
        out.append(_from_u_np(theta[off:off + s.size], s))
        off += s.size
    if prob.static.multipliers:
        st = prob.static
        w = np.asarray(theta[st.n_model:], np.float64)
        out.append(np.concatenate([w, [-w.sum()]]) if st.n_groups > 1 else np.zeros(st.n_groups))
    return np.concatenate(out)


def _device_args(prob: _Problem):
    # one batched host-to-device transfer (the caller has x64 enabled: float64 stays float64)
    return jax.device_put(([np.asarray(x, np.float64) for x in prob.leaves], dict(prob.arrays)))


def fit_least_squares(
    model,
    data,
    *,
    solver: str = "lm",
    backend: str = "optimistix",
    multipliers: bool = False,
    fit: Sequence[str] | None = None,
    weighted: bool = False,
    rows="auto",
    max_steps: int = 400,
    rtol: float = 1e-8,
    atol: float = 1e-8,
) -> FitResult:
    """Fit ``model``'s constants to ``data`` by least squares in log10 sensitivity.

    Args:
        model: a ``pmetric.CSFModel`` giving the starting values (must lie inside ``param_bounds``).
        data: a ``pmetric.CalibrationData`` (thresholds; f cycles/deg, v deg/s, e deg, L cd/m2, A deg2).
        solver: ``"lm"`` (Levenberg-Marquardt), ``"gauss-newton"`` or ``"bfgs"``.
        backend: ``"optimistix"`` or ``"jaxopt"``.
        multipliers: fit one free sensitivity multiplier per dataset (geometric mean constrained to 1),
            as the published castleCSF / stelaCSF fits do.
        fit: restrict fitting to these fields (default: every floating array field).
        weighted: weight rows by ``data.weights`` (the ``N`` column) instead of equally.
        rows: ``"auto"`` (the rows the model can express, see ``expressible_rows``), ``"all"`` or
            ``None`` (every row) or a boolean mask of shape (n,).
        max_steps, rtol, atol: solver limits and tolerances.

    Returns:
        A ``FitResult`` (fitted model, RMSE in log10 and dB, per-dataset RMSE, covariance, result code).
    """
    if solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}; choose one of {SOLVERS}")
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; choose one of {BACKENDS}")
    if not (isinstance(max_steps, int) and max_steps > 0):
        raise ValueError(f"max_steps must be a positive int, got {max_steps!r}")
    if not (rtol > 0 and atol > 0):
        raise ValueError(f"rtol and atol must be > 0, got {rtol}, {atol}")
    with jax.enable_x64(True):
        prob = _Problem(model, data, fit=fit, multipliers=multipliers, weighted=weighted, rows=rows)
        fixed, arrays = _device_args(prob)
        theta, r, cov, code, steps, gmax = _solve(
            jnp.asarray(prob.theta0), fixed, arrays, prob.static, solver, backend, float(rtol), float(atol),
            int(max_steps))
        theta = np.asarray(theta, np.float64)
        fitted = prob.theta_to_model(theta)
        r = np.asarray(r, np.float64) / prob.arrays["sw"]  # unweighted residuals
        cov = np.asarray(cov, np.float64)
        values = _natural_values(prob, theta)
    code = int(code)
    name = "nonfinite" if code == 9 else _optx_code_names().get(code, f"code {code}")
    rmse = float(np.sqrt(np.mean(r * r)))
    per = {g: float(20.0 * np.sqrt(np.mean(r[prob.group == i] ** 2))) for i, g in enumerate(prob.group_names)}
    if multipliers:
        lm = values[prob.static.n_model:]
        mult = {g: float(10.0 ** lm[i]) for i, g in enumerate(prob.group_names)}
    else:
        mult = {g: 1.0 for g in prob.group_names}
    return FitResult(
        model=fitted, rmse_log10=rmse, rmse_db=20.0 * rmse, rmse_per_dataset=per, multipliers=mult,
        param_names=_param_names(prob), values=values, covariance=cov,
        stderr=np.sqrt(np.clip(np.diag(cov), 0.0, None)), result=name, steps=int(steps), n_rows=len(r),
        rows=prob.mask, row_rules=list(prob.reasons), residuals=r, solver=solver, backend=backend,
        grad_max=float(gmax), theta=theta,
    )

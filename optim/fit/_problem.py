"""The fitting problem shared by least squares and MCMC: parameter layout, bounds, rows, residuals.

The residual of row ``i`` is the error in log10 sensitivity (equivalently, in log10 threshold contrast)::

    r_i = log10 S_model(f_i, e_i, v_i, L_i, A_i) + log10 m_{d(i)} - log10 S_i

with an optional free sensitivity multiplier ``m_d`` per dataset ``d`` (the published castleCSF /
stelaCSF fits allow one, about 0.5-1.7x: [MAC22], [Ash24]). The multipliers are constrained to a
geometric mean of 1 (``sum_d log10 m_d = 0``) so that they never trade off against the model's own gain
constant (the problem stays identifiable).

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

Which inputs a model receives is what it declares in ``type(model).inputs`` (see
``pmetric.CSFModel``): ``"luminance"``, ``"area"`` and ``"vis_field"`` (deg) are passed to
``stimulus_sensitivity`` only when declared and known in the data.

The data may be any object with the attributes of :class:`optim.fit.CalibrationData` that fitting
reads (see ``DATA_ATTRIBUTES``), a ``subset(mask)`` method and ``len()``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from pmetric import PlodError

__all__ = ["expressible_rows", "fitted_fields"]

# Kinds of reparametrisation.
IDENT, LOWER, UPPER, INTERVAL = 0, 1, 2, 3

# Rows a model without a luminance term can express: photopic luminance (cd/m2), where the CSF
# is close to Weber behaviour. Rows a model without an area term can express: area >= this (deg2).
PHOTOPIC_RANGE = (10.0, 1000.0)
MIN_AREA_DEG2 = 0.5

#: attributes of the data that fitting reads (besides ``len()``, ``subset``, ``datasets``, ``weights``)
DATA_ATTRIBUTES = ("f", "e", "velocity", "t_frequency", "luminance", "area", "vis_field", "log_threshold",
                   "dataset")


# ----------------------------------------------------------------------------- parameter layout
@dataclasses.dataclass(frozen=True)
class Leaf:
    """One fitted array leaf of a model and its reparametrisation."""

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


def bounds_kind(bounds) -> tuple[int, float, float]:
    """``(kind, lo, hi)`` of a ``param_bounds`` entry ``(lo | None, hi | None)`` (or None)."""
    lo, hi = (None, None) if bounds is None else bounds
    if lo is not None and hi is not None:
        if not hi > lo:
            raise PlodError(f"param_bounds {bounds} must have lo < hi")
        return INTERVAL, float(lo), float(hi)
    if lo is not None:
        return LOWER, float(lo), math.inf
    if hi is not None:
        return UPPER, -math.inf, float(hi)
    return IDENT, -math.inf, math.inf


def fitted_fields(model, fit: Sequence[str] | None = None, *, arg: str = "fit=") -> list[str]:
    """Names (dotted paths) of the array leaves of ``model`` that fitting adjusts.

    All floating array leaves unless ``fit`` restricts them (top-level field names or dotted paths).
    ``arg``: how an error names ``fit`` (a command line passes its flag, e.g. ``"--fit"``).
    """
    return [leaf.name for leaf in layout(model, fit, arg=arg)[2]]


def _check_fit_names(model, fit, names, arg="fit="):
    if isinstance(fit, str):
        fit = [fit]
    unknown = [n for n in fit if n not in names and not any(m.split(".")[0] == n for m in names)]
    if unknown:
        raise PlodError(f"{arg} names unknown fields {unknown} of {type(model).__name__}; "
                        f"fittable fields: {names}")
    if not fit:
        raise PlodError(f"{arg} is empty: name at least one field to fit")
    return fit


def layout(model, fit, arg="fit="):
    """``(treedef, static part, spec (tuple of Leaf), float64 leaves, params)`` of ``model``; ``arg``: how
    an error names ``fit``."""
    if not isinstance(model, eqx.Module):
        raise PlodError(f"model must be a pmetric CSF model (an equinox Module), got {type(model).__name__}")
    if not hasattr(model, "stimulus_sensitivity"):
        raise PlodError(f"{type(model).__name__} has no stimulus_sensitivity method; it cannot be fitted")
    params, static = eqx.partition(model, eqx.is_inexact_array)
    with_path, treedef = jax.tree_util.tree_flatten_with_path(params)
    names = [_path_name(p) for p, _ in with_path]
    if not names:
        raise PlodError(f"{type(model).__name__} has no floating array fields to fit")
    if fit is not None:
        fit = _check_fit_names(model, fit, names, arg)
    leaves, spec = [], []
    for i, ((path, leaf), name) in enumerate(zip(with_path, names)):
        field = name.split(".")[0].split("[")[0]
        chosen = fit is None or name in fit or field in fit
        arr = np.asarray(leaf, dtype=np.float64)
        leaves.append(arr)
        if not chosen:
            continue
        kind, lo, hi = bounds_kind(_leaf_bounds(model, path))
        bad = ~np.isfinite(arr) | (arr < lo) | (arr > hi)
        if bad.any():
            raise PlodError(f"{type(model).__name__}.{name} = {arr.ravel()[np.argmax(bad.ravel())]!r} lies "
                            f"outside its param_bounds ({lo}, {hi}); cannot start a fit there")
        spec.append(Leaf(name, field, i, tuple(arr.shape), int(arr.size), kind, lo, hi))
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


# ----------------------------------------------------------------------------- bounds reparametrisation
def to_u(x: np.ndarray, leaf: Leaf) -> np.ndarray:
    """Natural value -> unconstrained value (numpy, float64); values on a bound move just inside."""
    x = np.asarray(x, dtype=np.float64).ravel()
    if leaf.kind == IDENT:
        return x
    if leaf.kind == LOWER:
        d = x - leaf.lo
        return np.log(np.maximum(d, 1e-12 * max(1.0, abs(leaf.lo))))
    if leaf.kind == UPPER:
        d = leaf.hi - x
        return np.log(np.maximum(d, 1e-12 * max(1.0, abs(leaf.hi))))
    p = np.clip((x - leaf.lo) / (leaf.hi - leaf.lo), 1e-9, 1.0 - 1e-9)
    return np.log(p) - np.log1p(-p)


def from_u_np(u: np.ndarray, leaf: Leaf) -> np.ndarray:
    """Numpy twin of ``from_u`` (natural value only), for host-side bookkeeping."""
    u = np.asarray(u, np.float64)
    if leaf.kind == IDENT:
        return u
    lim = float(np.log(np.finfo(np.float64).max)) - 2.0
    if leaf.kind == LOWER:
        return leaf.lo + np.exp(np.clip(u, -lim, lim))
    if leaf.kind == UPPER:
        return leaf.hi - np.exp(np.clip(u, -lim, lim))
    return leaf.lo + (leaf.hi - leaf.lo) / (1.0 + np.exp(-np.clip(u, -lim, lim)))


def _safe_exp(u):
    # exp guarded against overflow: beyond +-(log max - 2) the value saturates (gradient 0 there only)
    lim = float(np.log(np.finfo(jnp.result_type(u)).max)) - 2.0
    return jnp.exp(jnp.clip(u, -lim, lim))


def from_u(u, leaf: Leaf):
    """Unconstrained -> natural value and its derivative dx/du (both shape (size,))."""
    if leaf.kind == IDENT:
        return u, jnp.ones_like(u)
    if leaf.kind == LOWER:
        ex = _safe_exp(u)
        return leaf.lo + ex, ex
    if leaf.kind == UPPER:
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


def _check_data(data):
    for attr in DATA_ATTRIBUTES:
        if not hasattr(data, attr):
            raise PlodError(f"data must be an optim.fit.CalibrationData (missing attribute {attr!r}), "
                            f"got {type(data).__name__}")
    if len(data) == 0:
        raise PlodError("data has no rows")


def select_rows(model, data, rows) -> tuple[np.ndarray, list[str]]:
    """``(mask, reasons)`` for ``rows`` = "auto" (``expressible_rows``), "all" / None, or a boolean mask."""
    if isinstance(rows, str) and rows not in ("auto", "all"):
        raise PlodError(f"rows must be 'auto', 'all' (or None) or a boolean mask, got {rows!r}")
    if isinstance(rows, str) and rows == "auto":
        mask, reasons = expressible_rows(model, data)
    elif rows is None or isinstance(rows, str):
        mask, reasons = np.ones(len(data), bool), []
    else:
        mask = np.asarray(rows)
        if mask.dtype != bool or mask.shape != (len(data),):
            raise PlodError(f"rows mask must be boolean of shape ({len(data)},), got {mask.dtype} {mask.shape}")
        reasons = ["rows given by the caller"]
    if not mask.any():
        raise PlodError(f"no rows of the data can be expressed by {type(model).__name__} "
                        f"(inputs {getattr(model, 'inputs', '?')}; rules: {'; '.join(reasons)})")
    return mask, reasons


# ----------------------------------------------------------------------------- the problem
@dataclasses.dataclass(frozen=True)
class ProblemStatic:
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


def _known_inputs(model, sub) -> tuple[bool, bool, bool]:
    """Whether luminance, area and vis_field go to the model: declared in ``inputs`` and known."""
    inputs = tuple(getattr(model, "inputs", ()))
    lum, area = np.asarray(sub.luminance), np.asarray(sub.area)
    has_lum = bool(np.isfinite(lum).any())
    has_area = bool(np.isfinite(area).any())
    if has_lum and "luminance" in inputs and not np.isfinite(lum).all():
        raise PlodError("data mixes known and unknown (NaN) luminance; fill it in or drop those rows")
    if has_area and "area" in inputs and not np.isfinite(area).all():
        raise PlodError("data mixes known and unknown (NaN) area; fill it in or drop those rows")
    has_vis = "vis_field" in inputs and bool(np.isfinite(np.asarray(sub.vis_field, np.float64)).any())
    return has_lum, has_area, has_vis


class Problem:
    """A model + data pair laid out for the solvers (float64 numpy on the host)."""

    def __init__(self, model, data, *, fit=None, multipliers=False, weighted=False, rows="auto", min_rows=True):
        _check_data(data)
        treedef, static_model, spec, leaves, _ = layout(model, fit)
        mask, reasons = select_rows(model, data, rows)
        sub = data.subset(mask)
        self.model, self.mask, self.reasons, self.data = model, mask, reasons, sub
        self.group_names = sub.datasets
        gid = {g: i for i, g in enumerate(self.group_names)}
        self.group = np.array([gid[d] for d in sub.dataset.tolist()], dtype=np.int32)
        has_lum, has_area, has_vis = _known_inputs(model, sub)
        self.static = ProblemStatic(treedef, static_model, spec, len(self.group_names), bool(multipliers),
                                    has_lum, has_area, has_vis)
        n = len(sub)
        p = self.static.n_free
        if min_rows and n < p:  # min_rows=False: a problem only to predict (no fit), any row count
            raise PlodError(f"{n} data rows cannot determine {p} free constants; give more data or fit= fewer")
        self.arrays = self._arrays(model, sub, weighted)
        self.leaves = leaves
        self.theta0 = np.concatenate(
            [to_u(leaves[s.index], s) for s in spec]
            + ([np.zeros(len(self.group_names) - 1)] if multipliers else [])
        )

    def _arrays(self, model, sub, weighted) -> dict:
        return row_arrays(model, sub, weighted, self.group)

    def theta_to_model(self, theta: np.ndarray, dtype_like=True):
        """Model with the natural values of ``theta`` (numpy, float64), in the original leaf dtypes."""
        leaves = jax.tree_util.tree_leaves(eqx.partition(self.model, eqx.is_inexact_array)[0])
        out = list(leaves)
        off = 0
        for s in self.static.spec:
            x = from_u_np(theta[off:off + s.size], s)
            dt = leaves[s.index].dtype if dtype_like else jnp.float64
            with np.errstate(over="ignore"):  # a diverged fit (result code says so) may overflow float32
                out[s.index] = jnp.asarray(x.reshape(s.shape).astype(dt))
            off += s.size
        return eqx.combine(jax.tree_util.tree_unflatten(self.static.treedef, out), self.static.static_model)


def row_arrays(model, sub, weighted: bool, group) -> dict:
    """The per-row arrays the residuals read (float64 numpy), for the rows of ``sub``.

    ``group``: (n,) int dataset index of every row (into the problem's ``group_names``). Unknown
    luminance / area become 1 (passed to the model only when the problem's flags say so).
    """
    lum, area = np.asarray(sub.luminance), np.asarray(sub.area)
    vis = np.asarray(sub.vis_field, np.float64)
    vis_default = float(getattr(model, "vis_field", 0.0) or 0.0)
    w = np.asarray(sub.weights, dtype=np.float64) if weighted else np.ones(len(sub))
    return dict(
        f=np.asarray(sub.f, np.float64), e=np.asarray(sub.e, np.float64),
        v=np.asarray(sub.velocity, np.float64),
        lum=np.where(np.isfinite(lum), lum, 1.0), area=np.where(np.isfinite(area), area, 1.0),
        vis=np.where(np.isfinite(vis), vis, vis_default),
        y=np.asarray(-sub.log_threshold, np.float64),  # log10 sensitivity
        sw=np.sqrt(w / w.mean()), group=np.asarray(group, np.int32),
    )


def device_args(prob: Problem):
    """``(fixed leaves, arrays)`` on the device in one batched transfer (call with x64 enabled)."""
    return jax.device_put(([np.asarray(x, np.float64) for x in prob.leaves], dict(prob.arrays)))


def param_names(prob: Problem) -> list[str]:
    """Natural parameter names (array fields expand to ``name[i]``; then ``log10_multiplier[dataset]``)."""
    names = []
    for s in prob.static.spec:
        if s.size == 1 and s.shape == ():
            names.append(s.name)
        else:
            names += [f"{s.name}[{i}]" for i in range(s.size)]
    if prob.static.multipliers:
        names += [f"log10_multiplier[{g}]" for g in prob.group_names]
    return names


def natural_values(prob: Problem, theta: np.ndarray) -> np.ndarray:
    """Natural values (in ``param_names`` order) of the unconstrained vector ``theta`` (numpy)."""
    out, off = [], 0
    for s in prob.static.spec:
        out.append(from_u_np(theta[off:off + s.size], s))
        off += s.size
    if prob.static.multipliers:
        st = prob.static
        w = np.asarray(theta[st.n_model:], np.float64)
        out.append(np.concatenate([w, [-w.sum()]]) if st.n_groups > 1 else np.zeros(st.n_groups))
    return np.concatenate(out)


# ----------------------------------------------------------------------------- residuals (traced)
def model_from_theta(theta, fixed, st: ProblemStatic):
    """The model at the unconstrained vector ``theta`` (traced), unfitted leaves from ``fixed``."""
    leaves = list(fixed)
    off = 0
    for s in st.spec:
        x, _ = from_u(theta[off:off + s.size], s)
        leaves[s.index] = x.reshape(s.shape)
        off += s.size
    params = jax.tree_util.tree_unflatten(st.treedef, leaves)
    return eqx.combine(params, st.static_model)


def log10_multipliers(theta, st: ProblemStatic):
    """log10 multiplier of every dataset, shape (n_groups,) (zeros without multipliers)."""
    if not st.multipliers or st.n_groups == 1:
        return jnp.zeros(st.n_groups, theta.dtype)
    w = theta[st.n_model:]
    return jnp.concatenate([w, -jnp.sum(w, keepdims=True)])


def _safe_log10(s):
    tiny = jnp.finfo(jnp.result_type(s)).tiny
    ok = jnp.isfinite(s) & (s > tiny)
    return jnp.where(ok, jnp.log10(jnp.where(ok, s, 1.0)), jnp.log10(tiny))


def predict_log10(theta, fixed, arrays, st: ProblemStatic):
    """log10 sensitivity of every row (model only, no multipliers), shape (n,)."""
    model = model_from_theta(theta, fixed, st)
    kw = {"vis_field": arrays["vis"]} if st.has_vis else {}
    s = model.stimulus_sensitivity(
        arrays["f"], arrays["e"], arrays["v"],
        luminance=arrays["lum"] if st.has_lum else None,
        area=arrays["area"] if st.has_area else None,
        **kw,
    )
    return _safe_log10(jnp.broadcast_to(s, arrays["f"].shape))


def residuals(theta, fixed, arrays, st: ProblemStatic):
    """Weighted residuals in log10 sensitivity, shape (n,)."""
    pred = predict_log10(theta, fixed, arrays, st) + log10_multipliers(theta, st)[arrays["group"]]
    return arrays["sw"] * (pred - arrays["y"])


def natural_jacobian(theta, st: ProblemStatic):
    """Linear map from d theta to d(natural model params, log10 multipliers of all groups)."""
    blocks = []
    off = 0
    for s in st.spec:
        _, d = from_u(theta[off:off + s.size], s)
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

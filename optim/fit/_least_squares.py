"""Fitting the constants of a CSF model to measured contrast thresholds by least squares.

The residuals, the reparametrisation by ``param_bounds`` and the rows fitted are those of
``optim.fit._problem``. Solvers: Levenberg-Marquardt, Gauss-Newton or BFGS, from optimistix or jaxopt.

The covariance of the natural parameters is ``D (J^T J)^+ D^T s^2`` with ``J`` the Jacobian of the
residuals in ``u``, ``s^2 = SSR / (n - p)`` and ``D = dx/du`` (the delta method through the
reparametrisation). With ``n <= p`` rows the constants are not identifiable from the data: the
covariance and standard errors are NaN (never a spuriously tiny number); so are those of a constant
in a null direction of ``J^T J`` (eigenvalue under 1e-10 of the largest), which the rows do not determine.

Regularisation (``prior_strength=lambda > 0``): a Gaussian prior on the fitted constants in the
unconstrained coordinates ``u`` of ``optim.fit._problem``, centred on the starting model's constants
``u0`` (the published values when the model is made by name). Least squares then minimises
``SSR + lambda * sum_j (u_j - u0_j)^2`` (``lambda`` is dimensionless: ``u`` is a log / logit of the
constant, so the prior s.d. of each ``u_j`` is ``sigma / sqrt(lambda)`` for data noise ``sigma``): the
maximum a posteriori estimate under ``optim.fit._priors.ridge_log_prior``, the same prior ``fit_mcmc``
uses. The multipliers are not penalised. ``J`` above then includes the prior rows.

Outcomes are members of optimistix's ``optx.RESULTS`` enumeration, for both backends
(``FitResult.outcome``; ``FitResult.result`` is the member's name). jaxopt's final state maps to:
stopping criterion met -> ``successful``; NaN error -> ``nonfinite``; iteration limit ->
``nonlinear_max_steps_reached``; stopped early otherwise -> ``stagnation``. For either backend, a
non-finite optimum or residual gives ``nonfinite`` (the one outcome this module adds to the solver's own).

Fitting runs in float64: every public function here switches ``jax_enable_x64`` on locally (the
fitted model is returned with its original leaf dtypes).
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

from ._problem import Problem, ProblemStatic, device_args, natural_jacobian, natural_values, param_names, residuals

__all__ = ["BACKENDS", "FitResult", "OUTCOMES", "SOLVERS", "fit_least_squares", "outcome_name", "solve_problem"]

SOLVERS = ("lm", "gauss-newton", "bfgs")
BACKENDS = ("optimistix", "jaxopt")

#: names of the ``optx.RESULTS`` members an outcome can be (lineax's linear-solve members first)
OUTCOMES = ("successful", "max_steps_reached", "singular", "breakdown", "stagnation", "conlim",
            "nonfinite_input", "nonlinear_max_steps_reached", "nonlinear_divergence", "nonfinite")


def _results():
    import optimistix as optx

    return optx.RESULTS


def outcome_name(item) -> str:
    """The name of an ``optx.RESULTS`` member (concrete), e.g. ``"successful"``."""
    results = _results()
    for name in OUTCOMES:
        member = getattr(results, name, None)
        if member is not None and bool(item == member):
            return name
    return "unknown"


# ----------------------------------------------------------------------------- the solvers (traced)
def _run_optimistix(resid, loss, theta0, scale, solver, rtol, atol, max_steps):
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
    return theta, sol.result, sol.stats["num_steps"]


def _run_jaxopt(resid, loss, theta0, scale, solver, rtol, atol, max_steps):
    import jaxopt

    if solver == "lm":
        opt = jaxopt.LevenbergMarquardt(resid, maxiter=max_steps, tol=atol, xtol=rtol, gtol=atol,
                                        solver="cholesky", materialize_jac=True, implicit_diff=False)
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
    R = _results()
    result = R.where(state.error <= atol, R.successful,
                     R.where(jnp.isnan(state.error), R.nonfinite,
                             R.where(steps >= max_steps - 1, R.nonlinear_max_steps_reached, R.stagnation)))
    return theta, result, steps


@eqx.filter_jit
def _solve(theta0, fixed, arrays, st: ProblemStatic, solver: str, backend: str, rtol: float, atol: float,
           max_steps: int, prior=None):
    """Run one solver; returns (theta, data residuals, cov_natural, optx.RESULTS member, steps, grad_norm).

    ``prior``: None or ``(u0 (n_model,), sqrt(lambda))`` (device arrays: a new strength does not
    recompile); its rows ``sqrt(lambda) (u - u0)`` are appended to the residuals. ``arrays["n_rows"]``
    (when present) is the number of real rows: padding rows have weight 0 (see ``_cv``).
    """
    n_data = arrays["f"].shape[0]

    def resid(theta, args=None):
        r = residuals(theta, fixed, arrays, st)
        if prior is None:
            return r
        u0, sq = prior
        return jnp.concatenate([r, sq * (theta[: st.n_model] - u0)])

    # BFGS works on Jacobi-preconditioned coordinates z: theta = theta0 + z / sqrt(diag(J^T J)) at
    # theta0, so that its first (steepest-descent) step is sensibly scaled in every constant.
    j0 = jax.jacfwd(resid)(theta0)
    scale = 1.0 / jnp.sqrt(jnp.maximum(jnp.sum(j0 * j0, axis=0), 1e-12))

    def loss(z, args=None):
        r = resid(theta0 + scale * z)
        return 0.5 * jnp.sum(r * r)

    run = _run_optimistix if backend == "optimistix" else _run_jaxopt
    theta, result, steps = run(resid, loss, theta0, scale, solver, rtol, atol, max_steps)
    r = resid(theta)
    finite = jnp.all(jnp.isfinite(theta)) & jnp.all(jnp.isfinite(r))
    result = _results().where(finite, result, _results().nonfinite)
    jac = jax.jacfwd(resid)(theta)
    rd = r[:n_data]
    n, p = arrays.get("n_rows", n_data), theta.shape[0]
    # n <= p: not identifiable from the data; NaN, not SSR / 1 ~ 0 (a fit through p points)
    s2 = jnp.where(n > p, jnp.sum(rd * rd) / jnp.maximum(n - p, 1), jnp.nan)
    jtj = jac.T @ jac
    cov_u = jnp.linalg.pinv(jtj, hermitian=True) * s2
    m = natural_jacobian(theta, st)
    cov = m @ cov_u @ m.T
    # constants the rows do not determine (a zero or dependent column of J: e.g. eccentricity constants
    # fitted to foveal rows only): pinv gives them 0 variance, a spuriously exact "+- 0"; NaN instead
    w, vec = jnp.linalg.eigh(jtj)
    null = w <= 1e-10 * jnp.maximum(w[-1], 1e-300)
    dead_u = jnp.sum(jnp.where(null[None, :], vec * vec, 0.0), axis=1) > 1e-6
    dead = (jnp.abs(m) > 0).astype(theta.dtype) @ dead_u.astype(theta.dtype) > 0
    cov = jnp.where(dead[:, None] | dead[None, :], jnp.nan, cov)
    grad = jac.T @ r
    return theta, rd, cov, result, steps, jnp.max(jnp.abs(grad), initial=0.0)


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
        result: the name of the ``optx.RESULTS`` member of the outcome ("successful",
            "nonlinear_max_steps_reached", "nonfinite", ...; see the module docstring); ``outcome``
            is the member itself.
        steps: solver iterations; n_rows: rows fitted; rows: (n_data,) bool mask of the rows used;
        row_rules: the rules that chose them (see ``expressible_rows``); residuals: (n_rows,) log10
        residuals (model - data); solver, backend: what ran; grad_max: largest |gradient| of the
        loss at the optimum; theta: the optimum in the unconstrained (log / logit) coordinates;
        n_input_rows: rows of the input data (``n_dropped`` = those not fitted); prior_strength: the
        lambda of the prior (0: none). With ``n_rows <= p`` the covariance and stderr are NaN
        (``identifiable`` is False); so are those of constants the rows do not determine (a null
        direction of ``J^T J``, e.g. eccentricity constants fitted to foveal rows only).
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
    n_input_rows: int = 0
    prior_strength: float = 0.0

    @property
    def n_dropped(self) -> int:
        """Rows of the input data not fitted (not expressible by the model, e.g. s_frequency 0)."""
        return int(self.n_input_rows - self.n_rows)

    @property
    def identifiable(self) -> bool:
        """More rows than free constants, each determined by them: the standard errors are defined (NaN
        otherwise)."""
        return bool(np.all(np.isfinite(self.stderr)))

    @property
    def success(self) -> bool:
        return self.result == "successful"

    @property
    def outcome(self):
        """The outcome as an ``optx.RESULTS`` member (compare with ``optx.RESULTS.successful`` etc.)."""
        return getattr(_results(), self.result)

    def summary(self) -> str:
        lines = [f"{type(self.model).__name__}: RMSE {self.rmse_db:.3f} dB ({self.rmse_log10:.4f} log10) "
                 f"on {self.n_rows} rows; {self.solver}/{self.backend}: {self.result} after {self.steps} steps"
                 + (f"; prior strength {self.prior_strength:g}" if self.prior_strength else "")]
        if not self.identifiable and self.n_rows <= len(self.values):
            lines.append(f"  not identifiable: {self.n_rows} rows for {len(self.values)} constants "
                         "(no uncertainty can be given)")
        elif not self.identifiable:
            dead = [n for n, se in zip(self.param_names, self.stderr) if not np.isfinite(se)]
            lines.append(f"  not identifiable from these rows: {', '.join(dead)} (the data do not constrain "
                         "them; no uncertainty can be given)")
        for name, v, se in zip(self.param_names, self.values, self.stderr):
            lines.append(f"  {name:<28} {v: .6g}" + (f"  +- {se:.3g}" if np.isfinite(se) else ""))
        return "\n".join(lines)


def _check_solver_args(solver, backend, max_steps, rtol, atol):
    if solver not in SOLVERS:
        raise PlodError(f"unknown solver {solver!r}; choose one of {SOLVERS}")
    if backend not in BACKENDS:
        raise PlodError(f"unknown backend {backend!r}; choose one of {BACKENDS}")
    if not (isinstance(max_steps, int) and max_steps > 0):
        raise PlodError(f"max_steps must be a positive int, got {max_steps!r}")
    if not (rtol > 0 and atol > 0):
        raise PlodError(f"rtol and atol must be > 0, got {rtol}, {atol}")


def _fit_result(prob: Problem, theta, r, cov, result, steps, gmax, solver, backend, prior_strength=0.0) -> FitResult:
    """Collect a solver's raw output (device arrays; x64 enabled) into a ``FitResult``."""
    theta = np.asarray(theta, np.float64)
    fitted = prob.theta_to_model(theta)
    r = np.asarray(r, np.float64) / prob.arrays["sw"]  # unweighted residuals
    cov = np.asarray(cov, np.float64)
    values = natural_values(prob, theta)
    rmse = float(np.sqrt(np.mean(r * r)))
    per = {g: float(20.0 * np.sqrt(np.mean(r[prob.group == i] ** 2))) for i, g in enumerate(prob.group_names)}
    if prob.static.multipliers:
        lm = values[prob.static.n_model:]
        mult = {g: float(10.0 ** lm[i]) for i, g in enumerate(prob.group_names)}
    else:
        mult = {g: 1.0 for g in prob.group_names}
    return FitResult(
        model=fitted, rmse_log10=rmse, rmse_db=20.0 * rmse, rmse_per_dataset=per, multipliers=mult,
        param_names=param_names(prob), values=values, covariance=cov,
        stderr=np.sqrt(np.clip(np.diag(cov), 0.0, None)), result=outcome_name(result), steps=int(steps),
        n_rows=len(r), rows=prob.mask, row_rules=list(prob.reasons), residuals=r, solver=solver,
        backend=backend, grad_max=float(gmax), theta=theta, n_input_rows=len(prob.mask),
        prior_strength=float(prior_strength),
    )


def _check_prior_strength(prior_strength) -> float:
    try:
        lam = float(prior_strength)
    except (TypeError, ValueError):
        raise PlodError(f"prior_strength must be a number >= 0, got {prior_strength!r}") from None
    if not (math.isfinite(lam) and lam >= 0) or isinstance(prior_strength, bool):
        raise PlodError(f"prior_strength must be a finite number >= 0, got {prior_strength!r}")
    return lam


def pad_arrays(arrays: dict, n_pad: int) -> dict:
    """``arrays`` (``Problem.arrays``) padded to ``n_pad`` rows by repeating row 0 with weight 0.

    The padding rows add nothing to the residuals, the Jacobian or the gradient (their weight ``sw`` is
    0), and ``n_rows`` keeps the real row count for the covariance: fits of different row counts padded
    to one size share one compiled solver (cross-validation folds).
    """
    n = len(arrays["f"])
    if n_pad < n:
        raise PlodError(f"cannot pad {n} rows to {n_pad}")
    out = {}
    for k, a in arrays.items():
        extra = np.zeros(n_pad - n, a.dtype) if k == "sw" else np.repeat(a[:1], n_pad - n)
        out[k] = np.concatenate([a, extra])
    out["n_rows"] = np.asarray(n, np.int64)
    return out


def solve_problem(prob: Problem, *, solver: str = "lm", backend: str = "optimistix", max_steps: int = 400,
                  rtol: float = 1e-8, atol: float = 1e-8, prior_strength: float = 0.0,
                  pad_to: int | None = None) -> FitResult:
    """Least-squares fit of a built ``Problem`` (call with x64 enabled); ``pad_to``: see ``pad_arrays``.

    The prior (``prior_strength > 0``) is centred on the problem's starting constants ``prob.theta0``.
    """
    _check_solver_args(solver, backend, max_steps, rtol, atol)
    lam = _check_prior_strength(prior_strength)
    fixed, arrays = device_args(prob)
    if pad_to is not None:
        arrays = jax.device_put(pad_arrays(prob.arrays, int(pad_to)))
    prior = None
    if lam > 0:
        prior = (jnp.asarray(prob.theta0[: prob.static.n_model]), jnp.asarray(math.sqrt(lam)))
    theta, r, cov, result, steps, gmax = _solve(jnp.asarray(prob.theta0), fixed, arrays, prob.static, solver,
                                                backend, float(rtol), float(atol), int(max_steps), prior)
    n = len(prob.arrays["f"])
    return _fit_result(prob, theta, r[:n], cov, result, steps, gmax, solver, backend, lam)


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
    prior_strength: float = 0.0,
) -> FitResult:
    """Fit ``model``'s constants to ``data`` by least squares in log10 sensitivity.

    Args:
        model: a ``pmetric.CSFModel`` giving the starting values (must lie inside ``param_bounds``).
        data: an ``optim.fit.CalibrationData`` (thresholds; f cycles/deg, v deg/s, e deg, L cd/m2, A deg2).
        solver: ``"lm"`` (Levenberg-Marquardt), ``"gauss-newton"`` or ``"bfgs"``.
        backend: ``"optimistix"`` or ``"jaxopt"``.
        multipliers: fit one free sensitivity multiplier per dataset (geometric mean constrained to 1),
            as the published castleCSF / stelaCSF fits do.
        fit: restrict fitting to these fields (default: every floating array field).
        weighted: weight rows by ``data.weights`` (the ``N`` column) instead of equally.
        rows: ``"auto"`` (the rows the model can express, see ``expressible_rows``), ``"all"`` or
            ``None`` (every row) or a boolean mask of shape (n,).
        max_steps, rtol, atol: solver limits and tolerances.
        prior_strength: ``lambda >= 0`` of the Gaussian prior centred on ``model``'s constants (see the
            module docstring; 0, the default: no prior, the plain least-squares fit).

    Returns:
        A ``FitResult`` (fitted model, RMSE in log10 and dB, per-dataset RMSE, covariance, outcome).
    """
    _check_solver_args(solver, backend, max_steps, rtol, atol)
    lam = _check_prior_strength(prior_strength)
    with jax.enable_x64(True):
        prob = Problem(model, data, fit=fit, multipliers=multipliers, weighted=weighted, rows=rows)
        return solve_problem(prob, solver=solver, backend=backend, max_steps=max_steps, rtol=rtol, atol=atol,
                             prior_strength=lam)

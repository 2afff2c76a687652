"""Bayesian fitting of CSF constants with emcee, and the conservative model for imperceptible LOD.

Likelihood: the residuals of ``optim.fit._problem`` (log10 sensitivity, model - data, optional
per-dataset multipliers) are independent Gaussians of standard deviation ``sigma`` (log10 units; free,
with a prior flat in ln sigma on [1e-4, 10], unless given). Parameters are sampled in the unconstrained
coordinates of the problem (log / logit by ``param_bounds``); priors are densities of the *natural*
values, so the log-Jacobian of the reparametrisation is added. The ensemble sampler is the
affine-invariant stretch move [GW10] as implemented by emcee [FM13] with a jitted, vmapped
log-probability (``vectorize=True``: one call per half-ensemble).

Convergence: the integrated autocorrelation time tau of every parameter (emcee's estimator, [Sok97])
must satisfy ``nsteps >= 50 tau``; otherwise a ``ChainTooShortWarning`` is issued and
``Posterior.converged`` is False.

Progress: ``fit_mcmc(progress=callback)`` calls ``callback(stage, done, total)`` with ``stage`` one of
``"least squares"`` and ``"sampling"`` (steps done of ``nsteps``); ``done`` never decreases within a
stage. The library prints nothing; ``experiments`` renders the callback.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from typing import Any, Callable, Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from pmetric import PlodError

from ._data import CalibrationData
from ._least_squares import fit_least_squares
from ._least_squares import _check_prior_strength
from ._priors import as_prior, ridge_log_prior
from ._problem import Problem, device_args, from_u, log10_multipliers, param_names, predict_log10, residuals

__all__ = ["ChainTooShortWarning", "Posterior", "conservative", "fit_mcmc"]

_SIGMA_RANGE = (1e-4, 10.0)  # prior range of the noise s.d., log10 units
_AUTOCORR_FACTOR = 50  # emcee's recommendation: nsteps >= 50 tau
_PROGRESS_EVERY = 50  # sampling steps between progress calls
#: fewest steps per walker: emcee's autocorrelation estimate is NaN below 3 (a cryptic error otherwise)
MIN_STEPS = 3

Progress = Callable[[str, int, int], None]


class ChainTooShortWarning(RuntimeWarning):
    """The chain is shorter than 50 integrated autocorrelation times: estimates are unreliable."""


# ----------------------------------------------------------------------------- posterior
@dataclasses.dataclass(frozen=True)
class Posterior:
    """Samples of the constants of a model given calibration data (from ``fit_mcmc``).

    Attributes:
        samples: (n_samples, p) natural values after burn-in and thinning, columns ``param_names``
            (array fields expand to ``name[i]``; then ``log10_multiplier[dataset]`` when fitted).
        sigma: (n_samples,) noise s.d. in log10 units.
        log_prob: (n_samples,) log posterior of each sample.
        acceptance_fraction: mean acceptance fraction of the walkers (0.2-0.5 is healthy).
        tau: (p + 1,) integrated autocorrelation time of each sampled coordinate (steps).
        converged: nsteps >= 50 max(tau); ``warning`` says why not otherwise.
        lsq: the least-squares fit the walkers started from (``FitResult``).
    """

    samples: np.ndarray
    sigma: np.ndarray
    log_prob: np.ndarray
    param_names: list
    acceptance_fraction: float
    tau: np.ndarray
    converged: bool
    warning: str | None
    nwalkers: int
    nsteps: int
    burn: int
    lsq: Any
    _problem: Any = dataclasses.field(repr=False)
    _theta: np.ndarray = dataclasses.field(repr=False)  # (n_samples, p) unconstrained values

    @property
    def n_model(self) -> int:
        return self._problem.static.n_model

    def interval(self, q: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
        """Central ``q`` credible interval of every parameter: (lo (p,), hi (p,))."""
        if not 0 < q < 1:
            raise PlodError(f"q must be in (0, 1), got {q}")
        a = (1 - q) / 2
        return np.quantile(self.samples, a, axis=0), np.quantile(self.samples, 1 - a, axis=0)

    def median(self) -> np.ndarray:
        """Posterior median of every parameter, shape (p,)."""
        return np.median(self.samples, axis=0)

    def model(self, index: int | None = None):
        """The model at posterior sample ``index`` (None: at the coordinate-wise posterior median)."""
        if index is None:
            theta = np.median(self._theta, axis=0)  # monotone reparametrisation: median commutes
        else:
            theta = self._theta[int(index)]
        with jax.enable_x64(True):
            return self._problem.theta_to_model(theta)

    def log10_sensitivity(self, n: int = 200, seed: int = 0) -> np.ndarray:
        """log10 model sensitivity of ``n`` random posterior samples at the fitted rows: (n, rows)."""
        rng = np.random.default_rng(seed)
        idx = rng.choice(len(self._theta), size=min(n, len(self._theta)), replace=False)
        prob = self._problem
        with jax.enable_x64(True):
            fixed, arrays = device_args(prob)
            return np.asarray(_log10_batch(jnp.asarray(self._theta[idx]), fixed, arrays, prob.static))

    def summary(self) -> str:
        lo, hi = self.interval(0.95)
        med = self.median()
        lines = [f"MCMC: {self.nwalkers} walkers x {self.nsteps} steps (burn {self.burn}); acceptance "
                 f"{self.acceptance_fraction:.2f}; max tau {np.max(self.tau):.1f} steps; "
                 f"{'converged' if self.converged else 'NOT converged'}"]
        for name, m, a, b in zip(self.param_names, med, lo, hi):
            lines.append(f"  {name:<28} {m: .5g}  [{a:.5g}, {b:.5g}]")
        lines.append(f"  {'sigma (log10)':<28} {np.median(self.sigma): .4g}")
        return "\n".join(lines)


# ----------------------------------------------------------------------------- log posterior (traced)
def _log_prior(theta, theta_ref, st, per_leaf, box, ridge=None, ln_s=None):
    """Log prior of the unconstrained vector ``theta`` (natural-value priors plus the log-Jacobian).

    ``ridge``: None or ``(u0 (n_model,), lam)``: the constants without an explicit prior get
    ``ridge_log_prior`` (needs ``ln_s``, the log noise s.d.) instead of the flat box.
    """
    lp = jnp.zeros((), theta.dtype)
    off = 0
    for leaf, prior in zip(st.spec, per_leaf):
        u = theta[off:off + leaf.size]
        if prior is None and ridge is not None:
            u0, lam = ridge
            lp = lp + ridge_log_prior(u - u0[off:off + leaf.size], lam, ln_s)
        elif prior is None:
            # default: flat in the unconstrained coordinate within +-box of the least-squares value
            ref = theta_ref[off:off + leaf.size]
            lp = lp + jnp.sum(jnp.where(jnp.abs(u - ref) <= box, 0.0, -jnp.inf))
        else:
            val, dxdu = from_u(u, leaf)
            adx = jnp.abs(dxdu)
            ok = adx > 0
            logjac = jnp.where(ok, jnp.log(jnp.where(ok, adx, 1.0)), -jnp.inf)
            lp = lp + jnp.sum(prior.log_prob(val) + logjac)
        off += leaf.size
    if st.n_free > st.n_model:  # multipliers: flat in log10 m within +-box
        w = theta[st.n_model:]
        lp = lp + jnp.sum(jnp.where(jnp.abs(w) <= box, 0.0, -jnp.inf))
    return lp


def _logpost_one(x, theta_ref, fixed, arrays, st, per_leaf, sigma, box, ridge=None):
    """Log posterior of one coordinate vector x = (theta, [ln sigma]) (see the module docstring)."""
    n = arrays["y"].shape[0]
    ln_lo, ln_hi = math.log(_SIGMA_RANGE[0]), math.log(_SIGMA_RANGE[1])
    theta = x[: st.n_free]
    lp = jnp.zeros((), x.dtype)
    if sigma is None:
        ln_s = x[st.n_free]
        lp = lp + jnp.where((ln_s >= ln_lo) & (ln_s <= ln_hi), 0.0, -jnp.inf)
        ln_s = jnp.clip(ln_s, ln_lo, ln_hi)
    else:
        ln_s = jnp.log(jnp.asarray(sigma, x.dtype))
    lp = lp + _log_prior(theta, theta_ref, st, per_leaf, box, ridge, ln_s)
    r = residuals(theta, fixed, arrays, st)
    ll = -0.5 * jnp.sum(r * r) * jnp.exp(-2.0 * ln_s) - n * ln_s - 0.5 * n * math.log(2 * math.pi)
    out = lp + ll
    return jnp.where(jnp.isnan(out), -jnp.inf, out)


@eqx.filter_jit
def _logpost_batch(x, theta_ref, fixed, arrays, st, per_leaf, sigma, box, ridge=None):
    """Vectorised log posterior, x of shape (nwalkers, ndim) -> (nwalkers,); compiled once per problem."""
    return jax.vmap(lambda xi: _logpost_one(xi, theta_ref, fixed, arrays, st, per_leaf, sigma, box, ridge))(x)


@eqx.filter_jit
def _jacobian(theta, fixed, arrays, st):
    return jax.jacfwd(lambda th: residuals(th, fixed, arrays, st))(theta)


@eqx.filter_jit
def _natural_batch(thetas, st):
    """Natural values of a batch of unconstrained vectors: (n, p_free) -> (n, p_natural)."""

    def one(theta):
        out, off = [], 0
        for s in st.spec:
            x, _ = from_u(theta[off:off + s.size], s)
            out.append(x)
            off += s.size
        if st.multipliers:
            out.append(log10_multipliers(theta, st))
        return jnp.concatenate(out)

    return jax.vmap(one)(thetas)


@eqx.filter_jit
def _log10_batch(thetas, fixed, arrays, st):
    return jax.vmap(lambda th: predict_log10(th, fixed, arrays, st))(thetas)


def _build_logpost(prob: Problem, priors: Mapping[str, Any], sigma: float | None, theta_ref: np.ndarray,
                   box: float, *, batched: bool = False, prior_strength: float = 0.0):
    """Return (log posterior of one coordinate vector -- or of a batch with ``batched`` --, dimension).

    ``prior_strength > 0``: the constants without an entry in ``priors`` get ``ridge_log_prior``
    centred on the problem's starting constants (``prob.theta0``), as ``fit_least_squares`` uses.
    """
    st = prob.static
    fixed, arrays = device_args(prob)
    per_leaf = tuple(priors.get(leaf.name, priors.get(leaf.field)) for leaf in st.spec)
    ridge = None
    if prior_strength > 0:
        ridge = (jnp.asarray(prob.theta0[: st.n_model]), float(prior_strength))
    args = (jnp.asarray(theta_ref), fixed, arrays, st, per_leaf, None if sigma is None else float(sigma),
            float(box), ridge)
    ndim = st.n_free + (1 if sigma is None else 0)
    if batched:
        return (lambda x: _logpost_batch(x, *args)), ndim
    return (lambda x: _logpost_one(x, *args)), ndim


# ----------------------------------------------------------------------------- fit_mcmc, by stage
def _check_mcmc_args(nwalkers, nsteps, burn, thin, sigma, box, progress) -> int:
    """Validate the sampler settings; returns the burn-in."""
    if not isinstance(nwalkers, int) or not isinstance(nsteps, int) or nwalkers < 1:
        raise PlodError(f"nwalkers and nsteps must be positive ints, got {nwalkers!r}, {nsteps!r}")
    if nsteps < MIN_STEPS:
        raise PlodError(f"nsteps must be >= {MIN_STEPS} (emcee needs {MIN_STEPS} steps per walker to estimate "
                        f"the autocorrelation time), got {nsteps}")
    burn = nsteps // 4 if burn is None else int(burn)
    if not 0 <= burn < nsteps:
        raise PlodError(f"burn must be in [0, nsteps), got {burn}")
    if thin < 1:
        raise PlodError(f"thin must be >= 1, got {thin}")
    if sigma is not None and not (sigma > 0 and math.isfinite(sigma)):
        raise PlodError(f"sigma must be > 0 (log10 units), got {sigma}")
    if box <= 0:
        raise PlodError(f"box must be > 0, got {box}")
    if progress is not None and progress is not False and not callable(progress):
        raise PlodError(f"progress must be None or a callable progress(stage, done, total), got {progress!r}")
    return burn


def _check_priors(priors: dict, prob: Problem, names: list[str]) -> dict:
    spec = prob.static.spec
    known = set(names) | {leaf.field for leaf in spec} | {leaf.name for leaf in spec}
    unknown = [k for k in priors if k not in known]
    if unknown:
        raise PlodError(f"priors name unknown or unfitted fields {unknown}; fitted: {[leaf.name for leaf in spec]}")
    return {k: as_prior(k, p) for k, p in priors.items()}


def _start_ball(prob: Problem, lsq, sigma, vlogpost, ndim: int, nwalkers: int, seed: int) -> np.ndarray:
    """Walkers in a small ball around the least-squares optimum, scaled by its standard errors in u."""
    if nwalkers < 2 * ndim or nwalkers % 2:
        raise PlodError(f"nwalkers must be even and >= 2 x {ndim} (the dimension), got {nwalkers}")
    theta_hat = np.asarray(lsq.theta, np.float64)
    fixed, arrays = device_args(prob)
    r_hat = np.asarray(lsq.residuals) * prob.arrays["sw"]
    jac = np.asarray(_jacobian(jnp.asarray(theta_hat), fixed, arrays, prob.static))
    s2 = float(np.sum(r_hat ** 2) / max(len(r_hat) - len(theta_hat), 1))
    cov_u = np.linalg.pinv(jac.T @ jac, hermitian=True) * s2
    sd_u = np.sqrt(np.clip(np.diag(cov_u), 1e-16, None))
    rng = np.random.default_rng(seed)
    centre = theta_hat if sigma is not None else np.append(theta_hat, 0.5 * math.log(max(s2, 1e-8)))
    spread = sd_u if sigma is not None else np.append(sd_u, 0.05)
    p0 = centre + 0.5 * spread * rng.standard_normal((nwalkers, ndim))
    if not np.isfinite(np.asarray(vlogpost(jnp.asarray(p0)))).all():
        raise PlodError("the starting ball has walkers outside the prior support; widen the priors "
                        "or start the model inside them")
    return p0


def _sample(vlogpost, p0: np.ndarray, nsteps: int, seed: int, progress: Progress | None):
    """Run emcee's ensemble sampler from ``p0``; returns the sampler."""
    import emcee

    nwalkers, ndim = p0.shape

    def log_prob(x):
        return np.asarray(vlogpost(jnp.asarray(x)))

    sampler = emcee.EnsembleSampler(nwalkers, ndim, log_prob, vectorize=True)
    sampler.random_state = np.random.RandomState(seed).get_state()
    if progress is None:
        sampler.run_mcmc(p0, nsteps)
        return sampler
    progress("sampling", 0, nsteps)
    for i, _ in enumerate(sampler.sample(p0, iterations=nsteps)):
        done = i + 1
        if done % _PROGRESS_EVERY == 0 or done == nsteps:
            progress("sampling", done, nsteps)
    return sampler


def _convergence(tau: np.ndarray, nsteps: int) -> tuple[bool, str | None]:
    tau_max = float(np.max(tau))
    converged = bool(np.isfinite(tau_max) and nsteps >= _AUTOCORR_FACTOR * tau_max)
    if converged:
        return True, None
    return False, (f"chain too short: {nsteps} steps < {_AUTOCORR_FACTOR} x the largest integrated "
                   f"autocorrelation time ({tau_max:.1f} steps); run >= {int(math.ceil(50 * tau_max))} steps")


def fit_mcmc(
    model,
    data,
    priors: Mapping[str, Any] | None = None,
    nwalkers: int = 32,
    nsteps: int = 2000,
    *,
    burn: int | None = None,
    thin: int = 1,
    sigma: float | None = None,
    multipliers: bool = False,
    fit: Sequence[str] | None = None,
    rows="auto",
    seed: int = 0,
    box: float = 10.0,
    prior_strength: float = 0.0,
    progress: Progress | None = None,
) -> Posterior:
    """Sample the posterior of ``model``'s constants given thresholds ``data`` with emcee.

    Args:
        model: a ``pmetric.CSFModel`` (starting point; a least-squares fit is run first and the walkers
            start in a small ball around it, scaled by its standard errors).
        data: ``optim.fit.CalibrationData``.
        priors: {field name: ``Uniform(lo, hi)`` | ``LogUniform(lo, hi)`` | ``Normal(mean, sd)`` | (lo, hi)}
            on natural values (array fields: elementwise). Fields without a prior get a flat prior on
            the unconstrained coordinate (log / logit) within ``box`` of the least-squares value.
        nwalkers: ensemble size (>= 2 x dimension, even). nsteps: steps per walker.
        burn: steps discarded (default nsteps // 4). thin: keep every ``thin``-th step.
        sigma: fixed noise s.d. in log10 units (default: sampled, prior flat in ln sigma on [1e-4, 10]).
        multipliers, fit, rows: as in ``fit_least_squares``.
        seed: seeds the initial ball and emcee's random state.
        prior_strength: lambda > 0: the constants without an entry in ``priors`` get the Gaussian
            ``ridge_log_prior`` centred on ``model``'s constants (the prior of
            ``fit_least_squares(prior_strength=lambda)``, whose fit is then the starting point); 0: the
            flat box prior.
        progress: None or a callback ``progress(stage, done, total)`` (see the module docstring).

    Returns:
        ``Posterior``; warns ``ChainTooShortWarning`` when nsteps < 50 x the largest autocorrelation time.
    """
    progress = progress or None
    burn = _check_mcmc_args(nwalkers, nsteps, burn, thin, sigma, box, progress)
    lam = _check_prior_strength(prior_strength)
    with jax.enable_x64(True):
        prob = Problem(model, data, fit=fit, multipliers=multipliers, rows=rows)
    n_rows, n_par = len(prob.data), prob.static.n_free + (1 if sigma is None else 0)
    if n_rows <= n_par:
        raise PlodError(f"{n_rows} usable data rows cannot sample {n_par} parameters"
                        f"{' (the constants and sigma)' if sigma is None else ''}: need at least {n_par + 1} rows")
    if progress is not None:
        progress("least squares", 0, 1)
    lsq = fit_least_squares(model, data, multipliers=multipliers, fit=fit, rows=rows, prior_strength=lam)
    if progress is not None:
        progress("least squares", 1, 1)
    with jax.enable_x64(True):
        names = param_names(prob)
        priors = _check_priors(dict(priors or {}), prob, names)
        vlogpost, ndim = _build_logpost(prob, priors, sigma, np.asarray(lsq.theta, np.float64), box, batched=True,
                                        prior_strength=lam)
        p0 = _start_ball(prob, lsq, sigma, vlogpost, ndim, nwalkers, seed)
        sampler = _sample(vlogpost, p0, nsteps, seed, progress)
        import emcee

        chain = sampler.get_chain()  # (nsteps, nwalkers, ndim)
        tau = np.asarray(emcee.autocorr.integrated_time(chain, tol=0, quiet=True), np.float64)
        flat = chain[burn::thin].reshape(-1, ndim)
        lps = sampler.get_log_prob()[burn::thin].reshape(-1)
        theta_s = flat[:, : prob.static.n_free]
        samples = np.asarray(_natural_batch(jnp.asarray(theta_s), prob.static))
        sig = np.exp(flat[:, -1]) if sigma is None else np.full(len(flat), float(sigma))
    converged, warning = _convergence(tau, nsteps)
    if warning is not None:
        warnings.warn(warning, ChainTooShortWarning, stacklevel=2)
    return Posterior(
        samples=samples, sigma=sig, log_prob=lps, param_names=names,
        acceptance_fraction=float(np.mean(sampler.acceptance_fraction)), tau=tau, converged=converged,
        warning=warning, nwalkers=nwalkers, nsteps=nsteps, burn=burn, lsq=lsq, _problem=prob, _theta=theta_s,
    )


def conservative(posterior: Posterior, q: float = 0.95, *, predictive: bool = True, n_draws: int = 400,
                 seed: int = 0):
    """A model (same class) whose thresholds sit at the lower ``q`` quantile of the posterior.

    At every fitted stimulus, the ``1 - q`` quantile of threshold contrast (= the ``q`` quantile of
    log10 sensitivity) is taken over ``n_draws`` posterior draws; with ``predictive`` (default) each
    draw includes the observer noise ``sigma`` (posterior predictive: where a fresh measurement would
    fall), otherwise only the uncertainty of the constants. The model family is then refitted by
    Levenberg-Marquardt to those quantile thresholds, so the result is an ordinary model of the same
    class that ``save_model`` stores and the simplifier uses. With q = 0.95, a change the returned model
    calls imperceptible is (to the accuracy of the refit) imperceptible for 95 % of the posterior.
    """
    if not 0 < q < 1:
        raise PlodError(f"q must be in (0, 1), got {q}")
    if n_draws < 10:
        raise PlodError(f"n_draws must be >= 10, got {n_draws}")
    prob = posterior._problem
    rng = np.random.default_rng(seed)
    ls = posterior.log10_sensitivity(n=n_draws, seed=seed)  # (n, rows)
    if predictive:
        idx = rng.choice(len(posterior.sigma), size=ls.shape[0], replace=True)
        ls = ls + posterior.sigma[idx, None] * rng.standard_normal(ls.shape)
    target = np.quantile(ls, q, axis=0)
    d = prob.data
    pseudo = CalibrationData.from_arrays(
        d.f, log_threshold=-target, e=d.e, velocity=d.velocity, luminance=d.luminance, area=d.area,
        vis_field=d.vis_field, dataset="conservative",
    )
    fitted = [leaf.name for leaf in prob.static.spec]
    res = fit_least_squares(posterior.model(None), pseudo, fit=fitted, rows=None)
    return res.model

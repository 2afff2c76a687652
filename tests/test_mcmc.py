"""Bayesian fitting with emcee (optim.fit_mcmc), posterior intervals and the conservative model."""

from __future__ import annotations

import math
import sys
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from test_fit import TRUE, ToyCSF, simulate  # noqa: E402  (the small model shared with test_fit)

import optim  # noqa: E402
from optim.fit import _mcmc, _problem  # noqa: E402

START = ToyCSF(gain=80.0, f_peak=6.0, width=2.0, drop=0.06)
NAMES = ["gain", "f_peak", "width", "drop"]


def _quiet(fn, *a, **k):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", _mcmc.ChainTooShortWarning)
        return fn(*a, **k)


def test_true_constants_inside_95_interval_in_18_of_20_runs():
    hits = np.zeros(4, int)
    for seed in range(20):
        data = simulate(seed=1000 + seed, n=100, noise=0.05)
        post = _quiet(optim.fit_mcmc, START, data, nwalkers=16, nsteps=300, burn=75, seed=seed)
        lo, hi = post.interval(0.95)
        true = np.array([TRUE[n] for n in NAMES])
        hits += (lo <= true) & (true <= hi)
        assert post.lsq.success, (seed, post.lsq.result)
        assert 0.15 < post.acceptance_fraction < 0.9, seed
        # the noise s.d. is learned: the posterior median sits at the residual RMS of the best fit
        assert np.median(post.sigma) == pytest.approx(post.lsq.rmse_log10, rel=0.15), seed
    assert np.all(hits >= 18), hits


def test_log_probability_matches_numpy():
    data = simulate(seed=5, n=60, noise=0.05)
    priors = {"gain": optim.LogUniform(1.0, 1e4), "f_peak": optim.Uniform(0.5, 20.0), "width": optim.Normal(1.0, 0.5)}
    with jax.enable_x64(True):
        prob = _problem.Problem(START, data)
        theta = prob.theta0 + 0.1
        logpost, ndim = _mcmc._build_logpost(prob, {k: v for k, v in priors.items()}, 0.07, prob.theta0, 10.0)
        got = float(logpost(jnp.asarray(theta)))
        assert ndim == 4
        fixed, arrays = _problem.device_args(prob)
        r = np.asarray(_problem.residuals(jnp.asarray(theta), fixed, arrays, prob.static))
    x = _problem.natural_values(prob, theta)
    n = r.size
    ll = -0.5 * np.sum(r**2) / 0.07**2 - n * math.log(0.07) - 0.5 * n * math.log(2 * math.pi)
    gain, f_peak, width, _ = x
    lp = -math.log(gain) - math.log(math.log(1e4)) + math.log(gain)  # log-uniform density x dgain/du (= gain)
    s = (f_peak - 0.1) / (60.0 - 0.1)
    lp += -math.log(19.5) + math.log((60.0 - 0.1) * s * (1 - s))
    s = (width - 0.05) / (20.0 - 0.05)
    lp += -0.5 * ((width - 1.0) / 0.5) ** 2 - math.log(0.5 * math.sqrt(2 * math.pi)) + math.log(19.95 * s * (1 - s))
    assert got == pytest.approx(ll + lp, rel=1e-10, abs=1e-8)


def test_short_chain_warns_and_reports_not_converged():
    data = simulate(seed=2, n=100, noise=0.05)
    with pytest.warns(optim.ChainTooShortWarning, match="chain too short"):
        post = optim.fit_mcmc(START, data, nwalkers=16, nsteps=60, seed=0)
    assert not post.converged and "50 x" in post.warning
    assert post.samples.shape == (16 * 45, 4) and post.sigma.shape == (16 * 45,)
    assert post.tau.shape == (5,) and np.all(post.tau > 0)


def test_conservative_model_sits_at_the_lower_quantile():
    data = simulate(seed=4, n=100, noise=0.05)
    post = _quiet(optim.fit_mcmc, START, data, nwalkers=16, nsteps=300, seed=0)
    med = post.model()
    f = np.geomspace(0.5, 15, 6)
    cons = optim.conservative(post, q=0.95)
    assert type(cons) is ToyCSF
    ratio = np.asarray(cons.sensitivity(f)) / np.asarray(med.sensitivity(f))
    # predictive: observer noise sigma = 0.05 log10 dominates -> factor 10^(1.645 sigma)
    np.testing.assert_allclose(ratio, 10 ** (1.645 * 0.05), rtol=0.06)
    tight = optim.conservative(post, q=0.95, predictive=False)
    r2 = np.asarray(tight.sensitivity(f)) / np.asarray(med.sensitivity(f))
    assert np.all(r2 >= 0.999) and np.all(r2 < ratio)
    # lower thresholds everywhere = more changes count as visible
    thr = lambda m: 1.0 / np.asarray(m.stimulus_sensitivity(f))  # noqa: E731
    assert np.all(thr(cons) < thr(med))


def test_bad_arguments():
    data = simulate(seed=2, n=100, noise=0.05)
    with pytest.raises(ValueError, match="nwalkers must be even"):
        optim.fit_mcmc(START, data, nwalkers=7, nsteps=10)
    with pytest.raises(ValueError, match="unknown or unfitted"):
        optim.fit_mcmc(START, data, priors={"nope": (0, 1)}, nsteps=10)
    with pytest.raises(ValueError, match="prior for 'gain'"):
        optim.fit_mcmc(START, data, priors={"gain": "wide"}, nsteps=10)
    with pytest.raises(ValueError, match="Uniform prior"):
        optim.Uniform(2.0, 1.0)
    with pytest.raises(ValueError, match="burn"):
        optim.fit_mcmc(START, data, nsteps=10, burn=10)
    with pytest.raises(ValueError, match="q must be"):
        optim.conservative(None, q=1.5)


def test_progress_callback_is_monotone_and_nothing_is_printed(capsys):
    from pmetric import PlodError

    data = simulate(seed=2, n=100, noise=0.05)  # the problem of test_short_chain: compiled once
    calls = []
    _quiet(optim.fit_mcmc, START, data, nwalkers=16, nsteps=120, seed=0,
           progress=lambda stage, done, total: calls.append((stage, done, total)))
    assert [c[0] for c in calls][0] == "least squares" and calls[-1] == ("sampling", 120, 120)
    for stage in ("least squares", "sampling"):
        seen = [(d, t) for s, d, t in calls if s == stage]
        assert len({t for _, t in seen}) == 1 and seen[-1][0] == seen[-1][1]
        assert all(a[0] <= b[0] for a, b in zip(seen, seen[1:])), seen
    out = capsys.readouterr()
    assert out.out == "" and out.err == ""
    with pytest.raises(PlodError, match="progress must be"):
        optim.fit_mcmc(START, data, nwalkers=16, nsteps=10, progress="yes")

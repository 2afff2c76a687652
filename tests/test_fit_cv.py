"""Cross-validated and regularised fits (optim.fit.cross_validate, prior_strength) and ``plod fit --cv``."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from test_fit import TRUE, ToyCSF, _cli  # noqa: E402  (the small model shared with test_fit)

import optim  # noqa: E402
from optim.fit import CalibrationData, _cv, _mcmc, _problem  # noqa: E402
from pmetric import PlodError  # noqa: E402

NAMES = ["gain", "f_peak", "width", "drop"]


def simulate(seed, n, noise, n_datasets=3, mult=(1.25, 0.8, 1.0)):
    """ToyCSF(**TRUE) thresholds with one multiplier per dataset and N(0, noise) log10 noise.

    Returns (data, the realised noise vector in log10 units)."""
    rng = np.random.default_rng(seed)
    f = 10 ** rng.uniform(-0.5, 1.2, n)
    e = np.where(rng.uniform(size=n) < 0.5, 0.0, rng.uniform(0, 10, n))
    g = np.arange(n) % n_datasets
    with jax.enable_x64(True):
        ls = np.log10(np.asarray(ToyCSF(**TRUE).stimulus_sensitivity(f, e), np.float64))
    eps = noise * rng.standard_normal(n)
    ls = ls + np.log10(np.asarray(mult))[g] + eps
    ds = np.array([f"d{i}" for i in g])
    return CalibrationData.from_arrays(f, log_threshold=-ls, e=e, dataset=ds, luminance=50.0, area=2.0), eps


@pytest.fixture(scope="module")
def noisy():
    return simulate(seed=3, n=240, noise=0.05)


# ------------------------------------------------------------------------------ cross-validation
@pytest.mark.parametrize("cv", ["dataset", 4])
def test_held_out_rmse_is_not_below_the_noise_floor(noisy, cv):
    data, eps = noisy
    floor = 20 * math.sqrt(np.mean(eps ** 2))  # the realised noise, dB (1 dB for sigma = 0.05 log10)
    res = optim.fit.cross_validate(ToyCSF(**TRUE), data, cv=cv, multipliers=True)
    assert res.n_rows == 240 and res.k == (3 if cv == "dataset" else 4)
    # the training fit absorbs a little noise (p constants), the held-out error cannot
    assert res.train_rmse_db < res.test_rmse_db
    assert floor * 0.97 <= res.test_rmse_db <= floor * 1.12, (floor, res.test_rmse_db)
    for f in res.folds:
        assert f.result == "successful"
        assert f.test_rmse_db >= 0.85 * floor
    # pooled figures are the RMS of the folds' residuals
    all_r = np.concatenate([f.test_residuals for f in res.folds])
    assert res.test_rmse_db == pytest.approx(20 * math.sqrt(np.mean(all_r ** 2)), rel=1e-12)


def test_leave_one_dataset_out_never_uses_the_held_out_rows(noisy, monkeypatch):
    data, _ = noisy
    seen = []
    real = _cv.solve_problem

    def spy(prob, **kw):
        seen.append(prob)
        return real(prob, **kw)

    monkeypatch.setattr(_cv, "solve_problem", spy)
    res = optim.fit.cross_validate(ToyCSF(**TRUE), data, cv="dataset")
    assert len(seen) == len(res.folds) == 3
    every = np.arange(len(data))
    for prob, fold in zip(seen, res.folds):
        assert np.intersect1d(fold.train_rows, fold.test_rows).size == 0
        np.testing.assert_array_equal(np.union1d(fold.train_rows, fold.test_rows), every)
        assert set(data.dataset[fold.test_rows]) == {fold.name}
        # what the training problem holds is exactly the training rows, nothing of the held-out dataset
        assert fold.name not in prob.group_names and len(prob.data) == len(fold.train_rows)
        np.testing.assert_array_equal(prob.data.f, data.f[fold.train_rows])
        np.testing.assert_array_equal(prob.data.log_threshold, data.log_threshold[fold.train_rows])
        # the held-out multiplier is refitted on the held-out rows alone: residual mean exactly 0 there
        assert fold.refitted == (fold.name,)
        assert abs(np.mean(fold.test_residuals)) < 1e-12
    # and it finds the simulated multiplier relative to the training datasets' (whose geometric mean
    # the training fit holds at 1, its gain absorbing the rest)
    true = {"d0": 1.25, "d1": 0.8, "d2": 1.0}
    for f in res.folds:
        others = [v for d, v in true.items() if d != f.name]
        want = true[f.name] / math.sqrt(others[0] * others[1])
        assert f.test_multipliers[f.name] == pytest.approx(want, rel=0.05)


def test_kfold_folds_are_deterministic_and_partition_the_rows():
    labels = np.array(list("aabbbcccc"))
    a = _cv.make_folds(labels, 3, seed=7)
    b = _cv.make_folds(labels, 3, seed=7)
    c = _cv.make_folds(labels, 3, seed=8)
    assert all(np.array_equal(x[2], y[2]) for x, y in zip(a, b))
    assert not all(np.array_equal(x[2], y[2]) for x, y in zip(a, c))
    np.testing.assert_array_equal(np.sort(np.concatenate([t for _, _, t in a])), np.arange(9))
    assert [len(t) for _, _, t in a] == [3, 3, 3]
    for bad in ["1", 0, "x", -2, True, 1.5]:
        with pytest.raises(PlodError, match="cv must be"):
            _cv.parse_cv(bad)
    with pytest.raises(PlodError, match="at least 2 datasets"):
        _cv.make_folds(np.array(["a"] * 5), "dataset")
    with pytest.raises(PlodError, match="10 folds need"):
        _cv.make_folds(labels, 10)


# ------------------------------------------------------------------------------ the prior
def test_prior_pulls_a_small_fit_toward_the_published_values():
    data, _ = simulate(seed=11, n=12, noise=0.1, n_datasets=1, mult=(1.0,))
    centre = ToyCSF(gain=120.0, f_peak=3.5, width=1.0, drop=0.03)  # the "published" constants
    plain = optim.fit_least_squares(centre, data)
    zero = optim.fit_least_squares(centre, data, prior_strength=0.0)
    np.testing.assert_array_equal(zero.values, plain.values)
    with jax.enable_x64(True):
        u0 = _problem.Problem(centre, data).theta0
    dist = []
    for lam in (1e-3, 1.0, 10.0, 100.0, 1e6):
        r = optim.fit_least_squares(centre, data, prior_strength=lam)
        assert r.success and r.prior_strength == lam
        dist.append(float(np.linalg.norm(r.theta - u0)))
    assert dist[0] == pytest.approx(float(np.linalg.norm(plain.theta - u0)), rel=1e-2)  # ~ the plain fit
    assert all(a > b for a, b in zip(dist, dist[1:]))  # stronger prior, closer to it
    assert dist[-1] < 1e-4  # lambda -> infinity: the prior's centre
    for bad in (-1.0, math.nan, "strong"):
        with pytest.raises(PlodError, match="prior_strength"):
            optim.fit_least_squares(centre, data, prior_strength=bad)


def test_mcmc_log_prior_is_the_least_squares_penalty():
    """fit_mcmc's ridge prior is the one least squares uses: the log posterior at fixed sigma differs
    from the unregularised one by -lambda |u - u0|^2 / (2 sigma^2) + const, and the regularised
    least-squares fit is its mode."""
    data, _ = simulate(seed=11, n=12, noise=0.1, n_datasets=1, mult=(1.0,))  # the data of the test above
    centre = ToyCSF(gain=120.0, f_peak=3.5, width=1.0, drop=0.03)
    lam, sigma = 3.0, 0.1
    fit = optim.fit_least_squares(centre, data, prior_strength=lam)
    with jax.enable_x64(True):
        prob = _problem.Problem(centre, data)
        flat, _ = _mcmc._build_logpost(prob, {}, sigma, prob.theta0, 10.0)
        ridge, _ = _mcmc._build_logpost(prob, {}, sigma, prob.theta0, 10.0, prior_strength=lam)
        theta = prob.theta0 + np.array([0.3, -0.2, 0.1, 0.4])
        du = theta - prob.theta0
        want = -0.5 * lam * du @ du / sigma ** 2 + 2 * math.log(lam / (2 * math.pi)) - 4 * math.log(sigma)
        assert float(ridge(jnp.asarray(theta)) - flat(jnp.asarray(theta))) == pytest.approx(want, rel=1e-10)
        grad = np.asarray(jax.grad(ridge)(jnp.asarray(fit.theta)))
        grad0 = np.asarray(jax.grad(ridge)(jnp.asarray(prob.theta0)))
    assert np.max(np.abs(grad)) < 1e-6 * np.max(np.abs(grad0))


def test_select_prior_strength_takes_the_least_held_out_error(noisy):
    data, _ = noisy
    start = ToyCSF(gain=120.0, f_peak=3.5, width=1.0, drop=0.03)
    best, grid = optim.fit.select_prior_strength(start, data, grid=(0.0, 10.0, 1e4), cv="dataset")
    assert set(grid) == {0.0, 10.0, 1e4}
    assert grid[best].test_rmse_db == min(r.test_rmse_db for r in grid.values())
    assert best == 0.0  # 240 rows of the true model: the data beats a wrong prior
    assert grid[1e4].test_rmse_db > grid[0.0].test_rmse_db


# ------------------------------------------------------------------------------ issue 13 leftovers
def test_unidentifiable_fit_reports_no_uncertainty_and_mcmc_refuses_too_little():
    data, _ = simulate(seed=1, n=4, noise=0.05, n_datasets=1, mult=(1.0,))
    r = optim.fit_least_squares(ToyCSF(**TRUE), data)  # 4 rows, 4 constants: a fit through the points
    assert r.n_rows == 4 and not r.identifiable and np.all(np.isnan(r.stderr))
    assert "not identifiable" in r.summary()
    with pytest.raises(PlodError, match="usable data rows cannot sample 5 parameters"):
        optim.fit_mcmc(ToyCSF(**TRUE), data, nwalkers=10, nsteps=10)
    big, _ = simulate(seed=1, n=30, noise=0.05, n_datasets=1, mult=(1.0,))
    for n in (1, 2):
        with pytest.raises(PlodError, match="nsteps must be >= 3"):
            optim.fit_mcmc(ToyCSF(**TRUE), big, nwalkers=10, nsteps=n)


# ------------------------------------------------------------------------------ the CLI
def test_cli_cv_json_and_table_equal_the_library(tmp_path, capsys, noisy):
    data, _ = noisy
    csv = tmp_path / "cal.csv"
    data.to_csv(csv)
    import pmetric

    lib = optim.fit.cross_validate(pmetric.KellyAbstract(), CalibrationData.from_csv(csv), cv="dataset",
                                   multipliers=True)
    assert _cli(["fit", str(csv), "--model", "kellyabstract", "--multipliers", "--cv", "dataset", "--json"]) == 0
    got = json.loads(capsys.readouterr().out)["cv"]
    assert got["test_rmse_db"] == pytest.approx(lib.test_rmse_db, rel=1e-9)
    assert got["train_rmse_db"] == pytest.approx(lib.train_rmse_db, rel=1e-9)
    for d in lib.datasets:
        assert got["test_rmse_per_dataset_db"][d] == pytest.approx(lib.test_rmse_per_dataset[d], rel=1e-9)
    assert [f["test_rows"] for f in got["folds"]] == [f.test_rows.tolist() for f in lib.folds]
    assert _cli(["fit", str(csv), "--model", "kellyabstract", "--multipliers", "--cv", "dataset"]) == 0
    out = capsys.readouterr().out
    assert "held-out" in out and f"{lib.test_rmse_db:.2f}" in out and f"{lib.train_rmse_db:.2f}" in out
    for d in lib.datasets:
        assert f"{lib.test_rmse_per_dataset[d]:.2f}" in out


@pytest.mark.parametrize("extra, message", [
    (["--cv", "1"], "--cv must be"), (["--cv", "abc"], "--cv must be"), (["--cv", "-3"], "--cv must be"),
    (["--cv", "0"], "--cv must be"), (["--cv", "500"], "500 folds need"),
    (["--fit", "nope"], "--fit names unknown fields ['nope']"), (["--fit", "gain,nope"], "--fit names unknown"),
    (["--fit", ","], "--fit is empty"),
    (["--cv", "dataset", "--method", "mcmc"], "cannot be combined"),
    (["--prior", "lots"], "--prior must be"), (["--prior-strength", "-1"], "--prior-strength must be"),
    (["--prior", "cv", "--prior-strength", "3"], "disagree"),
    (["--method", "mcmc", "--nsteps", "1"], "--nsteps must be >= 3"), (["--seed", "-1"], "--seed must be"),
])
def test_cli_bad_cv_and_prior_values_give_one_line(tmp_path, capsys, extra, message):
    data, _ = simulate(seed=2, n=30, noise=0.05)
    csv = tmp_path / "cal.csv"
    data.to_csv(csv)
    assert _cli(["fit", str(csv), "--model", "kellyabstract", *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and err.count("\n") == 1, err


def test_cli_prior_strength_and_dropped_zero_frequency_rows(tmp_path, capsys):
    data, _ = simulate(seed=2, n=30, noise=0.05, n_datasets=1, mult=(1.0,))
    f = np.concatenate([data.f, [0.0, 0.0]])
    lt = np.concatenate([data.log_threshold, [-2.0, -2.0]])
    csv = tmp_path / "cal.csv"
    CalibrationData.from_arrays(f, log_threshold=lt, e=np.concatenate([data.e, [0.0, 0.0]])).to_csv(csv)
    assert _cli(["fit", str(csv), "--model", "kellyabstract", "--prior-strength", "5", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["n_dropped_zero_frequency"] == 2 and rep["prior_strength"] == 5.0
    import pmetric

    lib = optim.fit_least_squares(pmetric.KellyAbstract(), CalibrationData.from_csv(csv), prior_strength=5.0)
    assert rep["rmse_db"] == pytest.approx(lib.rmse_db, rel=1e-9) and lib.n_dropped == 2
    assert _cli(["fit", str(csv), "--model", "kellyabstract"]) == 0
    assert "2 with s_frequency 0" in capsys.readouterr().out

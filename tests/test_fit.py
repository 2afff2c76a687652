"""Least-squares fitting of CSF constants (optim.fit_least_squares) and the ``plod fit`` command."""

from __future__ import annotations

import json
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import optim
from optim.fit import CalibrationData, _problem
from pmetric._base import CSFModel as _Base


# ------------------------------------------------------------------------------ a small test model
def _arr(x):
    return jnp.asarray(x, dtype=jnp.result_type(float))


class ToyCSF(_Base):
    """log-parabola CSF with an eccentricity drop: 4 constants, bounds of every kind.

    log10 S = log10 gain - (log10 f - log10 f_peak)^2 / width - drop * e * f
    """

    gain: jax.Array = eqx.field(converter=_arr, default=200.0)
    f_peak: jax.Array = eqx.field(converter=_arr, default=4.0)
    width: jax.Array = eqx.field(converter=_arr, default=1.2)
    drop: jax.Array = eqx.field(converter=_arr, default=0.01)

    inputs: ClassVar[tuple[str, ...]] = ("f", "e")
    param_bounds: ClassVar[dict] = {
        "gain": (0.0, None), "f_peak": (0.1, 60.0), "width": (0.05, 20.0), "drop": (0.0, 1.0),
    }

    def sensitivity(self, f, e=0.0, v=0.0):
        f = jnp.asarray(f)
        ok = f > 0
        lf = jnp.log10(jnp.where(ok, f, 1.0))
        ls = jnp.log10(self.gain) - (lf - jnp.log10(self.f_peak)) ** 2 / self.width - self.drop * e * f
        return jnp.where(ok, 10.0 ** ls, 0.0)

    def stimulus_sensitivity(self, f, e=0.0, v=0.0, luminance=None, area=None):
        return self.sensitivity(f, e, v)


TRUE = dict(gain=150.0, f_peak=3.0, width=0.9, drop=0.02)


def simulate(seed=0, n=800, noise=0.01, n_datasets=2, mult=None, model=None):
    """Thresholds of ``model`` (default ToyCSF(**TRUE)) with log10 Gaussian noise of s.d. ``noise``."""
    rng = np.random.default_rng(seed)
    model = model or ToyCSF(**TRUE)
    f = 10 ** rng.uniform(-0.5, 1.2, n)
    e = np.where(rng.uniform(size=n) < 0.5, 0.0, rng.uniform(0, 10, n))
    ds = np.array([f"d{i % n_datasets}" for i in range(n)])
    with jax.enable_x64(True):
        ls = np.log10(np.asarray(model.stimulus_sensitivity(f, e), np.float64))
    if mult is not None:
        ls = ls + np.log10(np.asarray(mult))[np.arange(n) % n_datasets]
    ls = ls + noise * rng.standard_normal(n)
    return CalibrationData.from_arrays(f, log_threshold=-ls, e=e, dataset=ds, luminance=50.0, area=2.0)


# ------------------------------------------------------------------------------ least squares

START = ToyCSF(gain=80.0, f_peak=6.0, width=2.0, drop=0.06)
NAMES = ["gain", "f_peak", "width", "drop"]


@pytest.fixture(scope="module")
def clean():
    return simulate(seed=0, noise=0.01)


@pytest.mark.parametrize("solver", ["lm", "gauss-newton", "bfgs"])
def test_recovers_constants_within_5_percent(clean, solver):
    res = optim.fit_least_squares(START, clean, solver=solver)
    assert res.result == "successful", res.result
    for name in NAMES:
        got, want = float(getattr(res.model, name)), TRUE[name]
        assert abs(got - want) <= 0.05 * abs(want), (solver, name, got, want)
    # the residual RMSE is the simulated noise (0.01 log10 = 0.2 dB)
    assert res.rmse_log10 == pytest.approx(0.01, rel=0.1)
    assert res.rmse_db == pytest.approx(20 * res.rmse_log10)
    assert set(res.rmse_per_dataset) == {"d0", "d1"}
    assert res.n_rows == len(clean) and res.rows.all()


@pytest.mark.parametrize("solver", ["lm", "gauss-newton", "bfgs"])
def test_optimistix_and_jaxopt_agree(clean, solver):
    a = optim.fit_least_squares(START, clean, solver=solver, backend="optimistix")
    b = optim.fit_least_squares(START, clean, solver=solver, backend="jaxopt")
    assert a.success and b.success, (a.result, b.result)
    np.testing.assert_allclose(a.values, b.values, rtol=1e-4)
    np.testing.assert_allclose(a.covariance, b.covariance, rtol=1e-3, atol=1e-12)
    assert a.rmse_log10 == pytest.approx(b.rmse_log10, rel=1e-6)


def test_multipliers_recovered_with_geometric_mean_one():
    data = simulate(seed=3, noise=0.01, mult=[0.6, 1.5])
    res = optim.fit_least_squares(START, data, multipliers=True)
    m = np.array([res.multipliers[k] for k in ("d0", "d1")])
    assert np.prod(m) == pytest.approx(1.0, rel=1e-9)
    # true multipliers normalised to geometric mean 1; the gain absorbs the common factor
    g = np.sqrt(0.6 * 1.5)
    np.testing.assert_allclose(m, np.array([0.6, 1.5]) / g, rtol=0.01)
    assert float(res.model.gain) == pytest.approx(TRUE["gain"] * g, rel=0.02)
    without = optim.fit_least_squares(START, data)
    assert res.rmse_db < 0.5 * without.rmse_db
    assert res.param_names[-2:] == ["log10_multiplier[d0]", "log10_multiplier[d1]"]


def test_covariance_matches_scatter_over_seeds():
    """The delta-method standard errors predict the spread of estimates across simulated data sets."""
    fits = [optim.fit_least_squares(START, simulate(seed=100 + s, noise=0.05)) for s in range(24)]
    est = np.array([f.values for f in fits])
    se = np.mean([f.stderr for f in fits], axis=0)
    ratio = est.std(axis=0, ddof=1) / se
    assert np.all((ratio > 0.55) & (ratio < 1.6)), ratio


def test_constants_the_rows_do_not_determine_have_no_uncertainty():
    """Foveal rows only (e = 0) say nothing about ``drop`` (the eccentricity term): its standard error is
    NaN and the fit is not identifiable (before: pinv's null space gave it "+- 0", a spuriously exact
    value); the other constants keep their finite errors, as with rows across eccentricities."""
    d = simulate(seed=2, noise=0.02)
    fov = CalibrationData.from_arrays(np.asarray(d.f)[np.asarray(d.e) == 0],
                                      log_threshold=np.asarray(d.log_threshold)[np.asarray(d.e) == 0], e=0.0,
                                      dataset="d0", luminance=50.0, area=2.0)
    res = optim.fit_least_squares(START, fov)
    se = dict(zip(res.param_names, res.stderr))
    assert np.isnan(se["drop"]) and all(np.isfinite(se[n]) and se[n] > 0 for n in ("gain", "f_peak", "width"))
    assert not res.identifiable and "not identifiable from these rows: drop" in res.summary()
    full = optim.fit_least_squares(START, d)
    assert full.identifiable and np.all(full.stderr > 0)


def test_bounds_respected_by_reparametrisation():
    # data generated with drop < 0 (outside its bounds (0, 1)): the fit stays inside, near the edge
    data = simulate(seed=1, noise=0.01, model=ToyCSF(**{**TRUE, "drop": -0.01}))
    res = optim.fit_least_squares(START, data)
    d = float(res.model.drop)
    assert 0.0 <= d < 1e-3
    assert np.isfinite(res.values).all() and np.isfinite(res.rmse_db)


def test_fit_restricts_fields(clean):
    res = optim.fit_least_squares(START, clean, fit=["gain", "f_peak"])
    assert res.param_names == ["gain", "f_peak"]
    assert float(res.model.width) == float(START.width) and float(res.model.drop) == float(START.drop)
    assert float(res.model.gain) != float(START.gain)
    assert optim.fitted_fields(START) == NAMES
    assert optim.fitted_fields(START, ["drop"]) == ["drop"]


def test_loss_gradients_finite_at_domain_edges(clean):
    with jax.enable_x64(True):
        prob = _problem.Problem(START, clean)
        fixed, arrays = _problem.device_args(prob)

        @jax.jit
        def loss(theta):
            r = _problem.residuals(theta, fixed, arrays, prob.static)
            return jnp.sum(r * r)

        base = jnp.asarray(prob.theta0)
        grad = jax.jit(jax.grad(loss))
        for theta in (base, base + 50.0, base - 50.0, base * 0.0, base + 1e3):
            g = grad(theta)
            assert np.isfinite(np.asarray(g)).all(), theta
        # analytic gradient agrees with central finite differences at the start
        g = np.asarray(jax.jit(jax.grad(loss))(base))
        eps = 1e-6
        fd = [(loss(base.at[i].add(eps)) - loss(base.at[i].add(-eps))) / (2 * eps) for i in range(base.size)]
        np.testing.assert_allclose(g, np.asarray(fd), rtol=1e-5)


def test_reparametrisation_round_trip():
    for bounds in [(None, None), (0.0, None), (None, 2.0), (-1.0, 3.0)]:
        kind, lo, hi = _problem.bounds_kind(bounds)
        leaf = _problem.Leaf("x", "x", 0, (3,), 3, kind, lo, hi)
        x = np.array([0.5, 1.0, 1.9])
        with jax.enable_x64(True):
            back, d = _problem.from_u(jnp.asarray(_problem.to_u(x, leaf)), leaf)
            np.testing.assert_allclose(np.asarray(back), x, rtol=1e-12)
            fd = (np.asarray(_problem.from_u(jnp.asarray(_problem.to_u(x, leaf)) + 1e-6, leaf)[0]) - x) / 1e-6
            np.testing.assert_allclose(np.asarray(d), fd, rtol=1e-4)


def test_result_dtype_follows_model(clean, dtype):
    res = optim.fit_least_squares(START, clean)
    assert res.model.gain.dtype == START.gain.dtype
    assert float(res.model.gain) == pytest.approx(TRUE["gain"], rel=0.05)


def test_expressible_rows_rules():
    data = CalibrationData.from_arrays(
        [1.0, 2.0, 0.0, 4.0, 4.0, 4.0, 4.0], log_threshold=-2.0,
        t_frequency=[0, 0, 0, 8.0, 0, 0, 0], e=[0, 5, 0, 0, 0, 0, 0],
        luminance=[50, 50, 50, 50, 1.0, 50, 50], area=[2, 2, 2, 2, 2, 0.01, np.nan])
    mask, rules = optim.expressible_rows(START, data)  # inputs (f, e)
    assert mask.tolist() == [True, True, False, False, False, False, True]
    assert any("static" in r for r in rules) and any("photopic" in r for r in rules)


def test_bad_arguments_raise_clear_errors(clean):
    with pytest.raises(ValueError, match="unknown solver"):
        optim.fit_least_squares(START, clean, solver="newton")
    with pytest.raises(ValueError, match="unknown backend"):
        optim.fit_least_squares(START, clean, backend="scipy")
    with pytest.raises(ValueError, match="fit= names unknown fields"):
        optim.fit_least_squares(START, clean, fit=["nope"])
    with pytest.raises(ValueError, match="outside its param_bounds"):
        optim.fit_least_squares(ToyCSF(drop=-0.5), clean)
    with pytest.raises(ValueError, match="cannot determine"):
        optim.fit_least_squares(START, clean.subset(np.arange(3)))
    with pytest.raises(ValueError, match="rows must be"):
        optim.fit_least_squares(START, clean, rows="most")
    with pytest.raises(ValueError, match="CalibrationData"):
        optim.fit_least_squares(START, {"f": [1.0]})
    with pytest.raises(ValueError, match="no rows"):
        v = CalibrationData.from_arrays([1.0, 2.0], log_threshold=-2.0, t_frequency=4.0)
        optim.fit_least_squares(START, v)


# ------------------------------------------------------------------------------ the CLI
def _cli(args):
    """The real ``plod`` entry point, with only this subcommand registered (others may be in progress)."""
    from experiments import cli

    saved = cli.COMMANDS
    cli.COMMANDS = ["fit"]
    try:
        return cli.main(args)
    finally:
        cli.COMMANDS = saved


def test_cli_fit_writes_model_that_loads_back(tmp_path, capsys):
    pmetric = pytest.importorskip("pmetric")
    if not hasattr(pmetric, "load_model") or not hasattr(pmetric, "KellyAbstract"):
        pytest.skip("pmetric.load_model / KellyAbstract not available yet")
    rng = np.random.default_rng(0)
    f = np.geomspace(0.5, 20, 30)
    true = pmetric.KellyAbstract()
    with jax.enable_x64(True):
        s = np.asarray(true.stimulus_sensitivity(f), np.float64) * 1.3
    csv = tmp_path / "cal.csv"
    CalibrationData.from_arrays(f, sensitivity=s * 10 ** (0.01 * rng.standard_normal(f.size))).to_csv(csv)
    out = tmp_path / "fitted.json"
    assert _cli(["fit", str(csv), "--model", "kellyabstract", "--out", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["rmse_db"] < 0.5 and report["result"] == "successful"
    back = pmetric.load_model(out)
    assert type(back).__name__ == "KellyAbstract"
    np.testing.assert_allclose(np.asarray(back.stimulus_sensitivity(f)), s, rtol=0.05)


@pytest.mark.parametrize("content, message", [
    ("", "empty file"),
    ("s_frequency,foo\n1,2\n", "log_cone_contrast"),
    ("s_frequency,log_cone_contrast\n1,abc\n", "not a number"),
    ("s_frequency,log_cone_contrast\n-1,-2\n", "negative spatial frequency"),
])
def test_cli_bad_csv_gives_one_line_error(tmp_path, capsys, content, message):
    csv = tmp_path / "bad.csv"
    csv.write_text(content)
    assert _cli(["fit", str(csv), "--model", "kellyabstract"]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and err.count("\n") == 1


def test_cli_rejects_unknown_model_and_input_overwrite(tmp_path, capsys):
    csv = tmp_path / "cal.csv"
    CalibrationData.from_arrays(np.geomspace(1, 10, 8), log_threshold=-2.0).to_csv(csv)
    assert _cli(["fit", str(csv), "--model", "nosuchmodel"]) == 2
    assert "unknown model" in capsys.readouterr().err
    assert _cli(["fit", str(tmp_path / "missing.csv"), "--model", "kellyabstract"]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert _cli(["fit", str(csv), "--model", "kellyabstract", "--out", str(csv)]) == 2
    assert "overwrite" in capsys.readouterr().err


def test_nested_model_uses_inner_bounds_and_recovers_constants():
    """Eccentric(ManosSakrison, RovamoVirsu('linear')): fields csf.peak_sensitivity, magnification.k1/k3."""
    pm = pytest.importorskip("pmetric")
    true = pm.Eccentric(pm.ManosSakrison(300.0), pm.RovamoVirsu("linear", k1=0.4, k3=0.0))
    rng = np.random.default_rng(7)
    f = 10 ** rng.uniform(-0.3, 1.3, 400)
    e = rng.uniform(0, 15, 400)
    with jax.enable_x64(True):
        ls = np.log10(np.asarray(true.stimulus_sensitivity(f, e), np.float64)) + 0.01 * rng.standard_normal(400)
    data = CalibrationData.from_arrays(f, log_threshold=-ls, e=e, luminance=50.0, area=2.0)
    start = pm.Eccentric(pm.ManosSakrison(150.0), pm.RovamoVirsu("linear", k1=0.2, k3=0.0))
    res = optim.fit_least_squares(start, data, fit=["csf", "magnification.k1"])
    assert res.param_names == ["csf.peak_sensitivity", "magnification.k1"]
    assert float(res.model.csf.peak_sensitivity) == pytest.approx(300.0, rel=0.02)
    assert float(res.model.magnification.k1) == pytest.approx(0.4, rel=0.02)
    # k1 has bounds (0, inf) from RovamoVirsu.param_bounds: a negative start is refused (by the constructor
    # itself since 2026-12-06, as load_model refuses it)
    with pytest.raises(ValueError, match="k1 must be >= 0"):
        optim.fit_least_squares(pm.Eccentric(pm.ManosSakrison(), pm.RovamoVirsu("linear", k1=-0.1)), data)


# ------------------------------------------------------------------------------ issue 9: one home for fitting
class ToyVisCSF(ToyCSF):
    """ToyCSF whose sensitivity falls with the visual field: declares the ``vis_field`` input."""

    inputs: ClassVar[tuple[str, ...]] = ("f", "e", "vis_field")

    def stimulus_sensitivity(self, f, e=0.0, v=0.0, luminance=None, area=None, vis_field=None):
        s = self.sensitivity(f, e, v)
        return s if vis_field is None else s * 10.0 ** (-0.05 * jnp.asarray(vis_field))


class ToyVisUndeclared(ToyVisCSF):
    """Accepts ``vis_field`` in its signature but does not declare it: fitting must not pass it."""

    inputs: ClassVar[tuple[str, ...]] = ("f", "e")


def test_fitting_passes_vis_field_only_to_models_declaring_it():
    import pmetric

    assert "vis_field" in pmetric.StelaCSF.inputs
    rng = np.random.default_rng(3)
    f = 10 ** rng.uniform(-0.5, 1.2, 200)
    vis = rng.uniform(1.0, 20.0, 200)
    truth = ToyVisCSF(**TRUE)
    with jax.enable_x64(True):
        ls = np.log10(np.asarray(truth.stimulus_sensitivity(f, 0.0, vis_field=vis), np.float64))
    data = CalibrationData.from_arrays(f, log_threshold=-ls, vis_field=vis, luminance=50.0, area=2.0)
    with jax.enable_x64(True):
        assert _problem.Problem(ToyVisCSF(), data).static.has_vis
        assert not _problem.Problem(ToyVisUndeclared(), data).static.has_vis
    declared = optim.fit_least_squares(ToyVisCSF(**TRUE), data, fit=["gain"])
    undeclared = optim.fit_least_squares(ToyVisUndeclared(**TRUE), data, fit=["gain"])
    assert declared.rmse_log10 < 1e-6  # the model saw vis_field: the data are its own outputs
    assert undeclared.rmse_log10 > 0.05  # the vis_field term was left out


@pytest.mark.parametrize("backend", ["optimistix", "jaxopt"])
def test_outcomes_are_optimistix_results_members(clean, backend):
    import optimistix as optx

    ok = optim.fit_least_squares(START, clean, backend=backend)
    assert ok.result == "successful" and ok.result in optim.fit.OUTCOMES
    assert bool(ok.outcome == optx.RESULTS.successful)
    short = optim.fit_least_squares(START, clean, backend=backend, max_steps=2)
    assert short.result == "nonlinear_max_steps_reached", short.result
    assert bool(short.outcome == optx.RESULTS.nonlinear_max_steps_reached) and not short.success
    assert optim.fit.outcome_name(optx.RESULTS.nonfinite) == "nonfinite"


def test_optim_fit_exposes_every_old_name():
    import subprocess
    import sys

    import pmetric

    old_optim = ["FitResult", "expressible_rows", "fit_least_squares", "fitted_fields", "ChainTooShortWarning",
                 "LogUniform", "Normal", "Posterior", "Uniform", "conservative", "fit_mcmc"]
    for name in old_optim:
        assert getattr(optim, name) is getattr(optim.fit, name), name
    for name in ["CalibrationData", "SimulatedObserver", "Stimuli", "stimulus_grid", "fade_in_session",
                 "staircase_2afc", "RULES"]:
        assert hasattr(optim.fit, name), name
    assert not hasattr(pmetric, "CalibrationData")
    # data flows pmetric <- optim: importing pmetric loads no optim module
    code = "import sys, pmetric; print(sorted(m for m in sys.modules if m.split('.')[0] == 'optim'))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "[]", out.stdout + out.stderr


def test_user_input_errors_are_plod_errors(clean, tmp_path):
    from pmetric import PlodError

    with pytest.raises(PlodError, match="unknown solver"):
        optim.fit_least_squares(START, clean, solver="newton")
    with pytest.raises(PlodError, match="outside its param_bounds"):
        optim.fit_least_squares(ToyCSF(drop=-0.5), clean)
    with pytest.raises(PlodError, match="not a number"):
        CalibrationData.from_csv_text("s_frequency,log_cone_contrast\n1,abc\n")

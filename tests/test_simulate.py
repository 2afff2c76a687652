"""Tests of optim.fit._simulate (fade-in method of adjustment, 2AFC staircase) and `plod calibrate`."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import ndtri

import pmetric
from experiments.cli import main
from optim.fit import RULES, CalibrationData, SimulatedObserver, Stimuli, fade_in_session, staircase_2afc, stimulus_grid


@pytest.fixture(scope="module")
def model():
    return pmetric.Barten()


def _true(obs, d):
    return np.log10(obs.threshold(Stimuli(d.f, d.e, d.velocity, d.luminance, d.area)))


def test_psychometric_function_closed_forms(model):
    obs = SimulatedObserver(model, slope=4.0, lapse=0.02, guess=0.0)
    c_t = np.array([0.01, 0.1])
    np.testing.assert_allclose(obs.p_core(c_t, c_t), 0.5)
    np.testing.assert_allclose(obs.p_correct(c_t * 10 ** 0.25, c_t, guess=0.5), 0.5 + 0.48 * 0.8413447460685429)
    p = 0.5 ** (1 / 3)
    want = c_t * 10 ** (ndtri((p - 0.5) / 0.48) / 4.0)
    np.testing.assert_allclose(obs.contrast_at(p, c_t, guess=0.5), want)
    np.testing.assert_allclose(obs.p_correct(obs.contrast_at(p, c_t, guess=0.5), c_t, guess=0.5), p)
    np.testing.assert_allclose(obs.threshold(stimulus_grid([4.0])), 1 / float(model.sensitivity(4.0)), rtol=1e-6)


def test_fade_in_noise_free_is_exact(model):
    st = stimulus_grid(np.logspace(-0.3, 1.3, 12), [0.0, 5.0], [0.0, 3.0])
    obs = SimulatedObserver(model, slope=math.inf, seed=3)
    d = fade_in_session(obs, st, rate_db_per_s=4.0, reaction_time_s=0.35, start_contrast=1e-4)
    assert len(d) == len(st)  # every grating visible below contrast 1
    np.testing.assert_allclose(d.log_threshold, _true(obs, d), atol=1e-12)
    assert set(d.dataset) == {"simulated_fade"}
    # per-frame display: detection and response snap to frames: error within one frame's contrast step
    d2 = fade_in_session(SimulatedObserver(model, slope=math.inf), st, 4.0, 0.35, start_contrast=1e-4,
                         frame_rate=10.0)
    err = d2.log_threshold - _true(obs, d2)
    assert (np.abs(err) <= 4.0 / 20 / 10 + 1e-9).all() and np.abs(err).max() > 0


def test_fade_in_noisy_is_unbiased(model):
    st = stimulus_grid(np.logspace(-0.3, 1.0, 25), [0.0, 2.0, 5.0, 8.0], [0.0, 1.0, 4.0, 8.0])
    obs = SimulatedObserver(model, slope=5.0, seed=11)
    d = fade_in_session(obs, st, rate_db_per_s=6.0, reaction_time_s=0.4, reaction_sd_s=0.1,
                        start_contrast=1e-5)
    assert len(d) == len(st)
    err = d.log_threshold - _true(obs, d)
    # log-normal detection contrast (sd 0.2) + reaction-time jitter (sd 6/20*0.1 = 0.03 log10)
    assert abs(err.mean()) < 4 * math.hypot(0.2, 0.03) / math.sqrt(len(d))
    assert err.std() == pytest.approx(math.hypot(0.2, 0.03), rel=0.1)
    # reproducible with the seed
    d_again = fade_in_session(SimulatedObserver(model, slope=5.0, seed=11), st, 6.0, 0.4, reaction_sd_s=0.1,
                              start_contrast=1e-5)
    np.testing.assert_array_equal(d.log_threshold, d_again.log_threshold)


def test_fade_in_lapses_are_caught_by_verification(model):
    st = stimulus_grid(np.logspace(-0.3, 1.0, 40), [0.0, 5.0], [0.0, 2.0])
    obs = SimulatedObserver(model, slope=math.inf, lapse=0.5, seed=5)
    d = fade_in_session(obs, st, start_contrast=1e-4, positions=1_000_000)
    # with a near-certain verification only genuine detections survive, and they are exact
    assert 0.3 * len(st) < len(d) < 0.7 * len(st)
    np.testing.assert_allclose(d.log_threshold, _true(obs, d), atol=1e-12)


def test_staircase_noise_free_within_steps(model):
    st = stimulus_grid(np.logspace(-0.3, 1.3, 12), [0.0, 5.0], [0.0, 3.0])
    obs = SimulatedObserver(model, slope=math.inf, seed=2)
    d = staircase_2afc(obs, st, trials=150, start_contrast=0.3, step_db=2.0)
    assert len(d) == len(st)
    err = d.log_threshold - _true(obs, d)
    step = 2.0 / 20
    assert np.abs(err).max() <= 2 * step
    assert abs(np.median(err)) <= step


def test_staircase_3down1up_converges_to_79_percent(model):
    st = stimulus_grid(np.logspace(-0.3, 1.0, 30), [0.0, 3.0, 6.0], [0.0, 1.0, 4.0])
    obs = SimulatedObserver(model, slope=3.0, seed=7)
    d = staircase_2afc(obs, st, rule="3down1up", trials=200, start_contrast=0.05, step_db=2.0)
    assert len(d) > 0.95 * len(st)
    c79 = obs.contrast_at(RULES["3down1up"][1], 10 ** _true(obs, d), guess=0.5)
    c50 = obs.contrast_at(0.75, 10 ** _true(obs, d), guess=0.5)
    err79 = d.log_threshold - np.log10(c79)
    assert abs(np.median(err79)) < 0.04
    # and clearly not the 75 % point of a 2down/1up-like rule or the 50 % core point
    assert abs(np.median(d.log_threshold - _true(obs, d)) - np.median(np.log10(c79) - _true(obs, d))) < 0.04
    assert np.median(np.log10(c79) - np.log10(c50)) > 0.02


def test_gratings_seen_at_the_ramp_start_are_dropped(model):
    """A grating visible at the fade-in's start contrast measures nothing (its row would record the start
    contrast, censored): it is dropped, and the rows kept are exact (before: written as thresholds of
    1e-3, biasing a refit)."""
    st = stimulus_grid(np.logspace(-0.3, 1.3, 12), [0.0])
    obs = SimulatedObserver(model, slope=math.inf, seed=3)
    c_t = np.asarray(obs.threshold(st))
    start = float(np.sqrt(c_t.min() * np.median(c_t)))  # some thresholds below the start, some above
    d = fade_in_session(obs, st, rate_db_per_s=4.0, reaction_time_s=0.35, start_contrast=start)
    assert 0 < len(d) == int((c_t > start).sum()) < len(st)
    np.testing.assert_allclose(d.log_threshold, _true(obs, d), atol=1e-12)


def test_invisible_gratings_are_dropped(model):
    st = stimulus_grid([4.0, 200.0])  # 200 cycles/deg is invisible at every contrast
    obs = SimulatedObserver(model, slope=math.inf)
    assert obs.threshold(st)[1] > 1
    assert list(fade_in_session(obs, st).f) == [4.0]
    assert list(staircase_2afc(obs, st, trials=150, start_contrast=0.05).f) == [4.0]


def test_bad_arguments(model):
    with pytest.raises(ValueError, match="slope"):
        SimulatedObserver(model, slope=0.0)
    with pytest.raises(ValueError, match="lapse"):
        SimulatedObserver(model, lapse=1.5)
    with pytest.raises(ValueError, match="model"):
        SimulatedObserver("stela")
    obs = SimulatedObserver(model)
    st = stimulus_grid([1.0])
    with pytest.raises(ValueError, match="rule"):
        staircase_2afc(obs, st, rule="5up")
    with pytest.raises(ValueError, match="rate_db_per_s"):
        fade_in_session(obs, st, rate_db_per_s=-1)
    with pytest.raises(ValueError, match="f must be > 0"):
        Stimuli([0.0, 1.0], 0.0, 0.0, np.nan, np.nan)
    with pytest.raises(ValueError, match="broadcast"):
        Stimuli([1.0, 2.0], [0.0, 1.0, 2.0], 0.0, np.nan, np.nan)


# ---------------------------------------------------------------- the CLI
def test_cli_calibrate_writes_csv(tmp_path, capsys):
    out = tmp_path / "sim.csv"
    rc = main(["calibrate", "--simulate", "--model", "barten", "--noise", "0", "--grid", "1,2,4,8x0,5x0,2",
               "--observer-seed", "4", "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    d = CalibrationData.from_csv(out)
    assert len(d) == 16
    obs = SimulatedObserver(pmetric.Barten(), slope=math.inf)
    np.testing.assert_allclose(d.log_threshold, _true(obs, d), atol=1e-9)
    assert set(d.observer) == {"sim4"}
    # staircase, noisy, reproducible with the seed
    out2, out3 = tmp_path / "a.csv", tmp_path / "b.csv"
    for o in (out2, out3):
        assert main(["calibrate", "--simulate", "--model", "Barten", "--method", "staircase", "--trials", "40",
                     "--grid", "2,4x0", "--noise", "0.2", "--observer-seed", "9", "--out", str(o)]) == 0
    assert out2.read_text() == out3.read_text()
    assert set(CalibrationData.from_csv(out2).dataset) == {"simulated_2afc"}


def test_cli_errors(tmp_path, capsys):
    out = tmp_path / "x.csv"
    assert main(["calibrate", "--model", "barten", "--out", str(out)]) == 2
    assert "--simulate" in capsys.readouterr().err
    assert main(["calibrate", "--simulate", "--model", "nosuch", "--out", str(out)]) == 2
    assert "unknown model" in capsys.readouterr().err
    assert main(["calibrate", "--simulate", "--grid", "1,2xaxb", "--out", str(out)]) == 2
    assert "--grid" in capsys.readouterr().err
    assert main(["calibrate", "--simulate", "--noise", "-1", "--out", str(out)]) == 2
    assert main(["calibrate", "--simulate", "--model", "barten", "--grid", "300x0", "--out", str(out)]) == 2
    assert "visible" in capsys.readouterr().err
    # thresholds far below what the staircase measures: not "not visible" (the opposite of the truth)
    assert main(["calibrate", "--simulate", "--model", "reddy", "--method", "staircase", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "could be measured by --method staircase" in err and "not visible" not in err
    for trials in ("1", "1000000000"):  # 1e9 ran silently for hours
        assert main(["calibrate", "--simulate", "--method", "staircase", "--trials", trials, "--out", str(out)]) == 2
        assert "--trials must be in 2..100000" in capsys.readouterr().err
    assert not out.exists()
    if hasattr(pmetric, "save_model"):
        mf = tmp_path / "model.json"
        pmetric.save_model(pmetric.Barten(), mf)
        before = mf.read_text()
        assert main(["calibrate", "--simulate", "--model-file", str(mf), "--out", str(mf)]) == 2
        assert "input" in capsys.readouterr().err
        assert mf.read_text() == before

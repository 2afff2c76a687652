"""Tests for pmetric.CalibratedCSF (the calibrated threshold lookup table of seed 004 section 6.1)."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import pmetric
from pmetric import CalibratedCSF, CalibrationData

FREQS = [1.0, 2.0, 4.0, 8.0, 16.0]
ECCS = [0.0, 10.0]
TABLE = np.array([[-2.0, -1.5], [-2.3, -1.8], [-2.2, -1.9], [-1.8, -1.2], [-1.0, -0.5]])
TOL = {"float32": 3e-5, "float64": 1e-11}


def _model():
    return CalibratedCSF(FREQS, ECCS, TABLE)


def test_nodes_and_midpoints(dtype):
    m = _model()
    assert m.log_thresholds.dtype == jnp.dtype(dtype)
    # nodes above the peak (2 cycles/deg at e = 0)
    ct = m.threshold_contrast(jnp.array([2.0, 4.0, 8.0, 16.0]), 0.0)
    assert ct.dtype == jnp.dtype(dtype)
    np.testing.assert_allclose(np.log10(ct), [-2.3, -2.2, -1.8, -1.0], atol=TOL[dtype])
    # geometric midpoint of 4 and 8 -> mean of the logs; linear in eccentricity
    np.testing.assert_allclose(np.log10(m.threshold_contrast(math.sqrt(32), 0.0)), -2.0, atol=TOL[dtype])
    np.testing.assert_allclose(np.log10(m.threshold_contrast(8.0, 5.0)), -1.5, atol=TOL[dtype])
    # bilinear centre of the (4..8) x (0..10) cell: mean of the four corners
    np.testing.assert_allclose(np.log10(m.threshold_contrast(math.sqrt(32), 5.0)), (-2.2 - 1.9 - 1.8 - 1.2) / 4,
                               atol=TOL[dtype])
    # a quarter of the way in log f: 4 * 2**0.25
    np.testing.assert_allclose(np.log10(m.threshold_contrast(4 * 2 ** 0.25, 0.0)), -2.2 + 0.25 * 0.4, atol=TOL[dtype])
    np.testing.assert_allclose(m.sensitivity(4.0, 0.0), 10 ** 2.2, rtol=10 * TOL[dtype])


def test_clamped_below_peak_and_outside(dtype):
    m = _model()
    # e = 0: the peak node is 2 cycles/deg (-2.3); everything below it gets the peak's threshold
    np.testing.assert_allclose(np.log10(m.threshold_contrast(jnp.array([0.0, 0.1, 1.0, 1.5, 2.0]), 0.0)),
                               -2.3, atol=TOL[dtype])
    np.testing.assert_allclose(m.peak_frequency(jnp.array([0.0, 10.0])), [2.0, 4.0])
    # e = 5: column [-1.75, -2.05, -2.05, -1.5, -0.75]: a tie, the peak is the HIGHER node (4)
    np.testing.assert_allclose(m.peak_frequency(5.0), 4.0)
    # eccentricity clamped beyond the table
    np.testing.assert_allclose(m.threshold_contrast(8.0, 40.0), m.threshold_contrast(8.0, 10.0), rtol=1e-6)
    # above 16 c/deg: last segment's slope (0.8 / log10 2) in log-log
    slope = 0.8 / math.log10(2.0)
    np.testing.assert_allclose(np.log10(m.threshold_contrast(32.0, 0.0)), -1.0 + slope * math.log10(2), atol=TOL[dtype])
    # min_slope floor when the last segment falls
    m2 = CalibratedCSF([1.0, 10.0], [0.0], np.array([[-1.0], [-2.0]]), min_slope=2.0)
    np.testing.assert_allclose(np.log10(m2.threshold_contrast(100.0)), -2.0 + 2.0, atol=TOL[dtype])


def test_threshold_frequency_exact(dtype):
    m = _model()
    c = jnp.array([0.001, 10 ** -2.3, 0.01, 0.1, 1.0])
    want = [0.0, 2.0, 4 * 2 ** 0.5, 16.0, 16.0 * 10 ** (1.0 / (0.8 / math.log10(2)))]
    np.testing.assert_allclose(m.threshold_frequency(c), want, rtol=20 * TOL[dtype])
    # round trip on the falling limb
    f = jnp.array([2.5, 3.0, 5.0, 11.0, 20.0, 40.0])
    np.testing.assert_allclose(m.threshold_frequency(m.threshold_contrast(f, 3.0), 3.0), f, rtol=50 * TOL[dtype])
    # exact derivative on a segment: f = 4 * 2**((log10 c + 2.2) / 0.4)  =>  df/dc = f / (c * 0.4 * log2(10))
    g = jax.grad(lambda cc: m.threshold_frequency(cc))(jnp.asarray(0.01, dtype))
    assert g.dtype == jnp.dtype(dtype)
    np.testing.assert_allclose(g, 4 * 2 ** 0.5 / (0.01 * 0.4 * math.log2(10)), rtol=100 * TOL[dtype])


def test_threshold_frequency_non_monotone():
    # a dip on the falling limb: the HIGHEST visible frequency is returned
    m = CalibratedCSF([1.0, 2.0, 4.0, 8.0], [0.0], np.array([[-2.0], [-1.0], [-1.5], [0.0]]))
    np.testing.assert_allclose(m.threshold_frequency(10 ** -1.25), 4 * 2 ** (0.25 / 1.5), rtol=1e-5)
    assert not m.is_perceptible(10 ** -1.25, 2.0)  # invisible at 2 c/deg but visible at 4
    assert m.is_perceptible(10 ** -1.25, 4.0)


def test_imperceptible_distance(dtype):
    m = _model()
    c = jnp.array([0.004, 0.01, 0.1])
    theta = jnp.array([0.1, 0.2, 0.05])
    k = m.imperceptible_distance(c, theta)
    np.testing.assert_allclose(k, 2 * theta * m.threshold_frequency(c), rtol=1e-6)
    assert float(k[0]) == 0.0  # below the peak threshold everywhere
    # definition: perceptible just below k, not just above
    for kk, cc, th in zip(np.asarray(k)[1:], np.asarray(c)[1:], np.asarray(theta)[1:]):
        assert m.is_perceptible(cc, kk * 0.999 / (2 * th))
        assert not m.is_perceptible(cc, kk * 1.001 / (2 * th))
    # under jit the generic solver is used: it agrees with the closed form
    kj = jax.jit(lambda c, t, e: m.imperceptible_distance(c, t, e))(c, theta, jnp.zeros(3))
    np.testing.assert_allclose(kj, k, rtol=2e-4)
    # single-eccentricity tables take the closed form for any e
    m1 = CalibratedCSF(FREQS, [0.0], TABLE[:, :1])
    np.testing.assert_allclose(m1.imperceptible_distance(c, theta, 7.0), k, rtol=1e-6)


def test_imperceptible_distance_eccentric_vs_brute_force():
    m = _model()
    cases = [(0.01, 0.1, 5.0), (0.05, 0.1, 20.0), (0.006, 0.3, 3.0), (0.02, 0.02, 30.0), (0.03, 0.5, 12.0)]
    c, th, e = (jnp.array(x) for x in zip(*cases))
    k = np.asarray(m.imperceptible_distance(c, th, e))
    # slow reference: the largest perceptible k on a fine log grid (step 0.07 %)
    ks = np.exp(np.linspace(np.log(1e-3), np.log(1e3), 20001))
    for i, (ci, ti, ei) in enumerate(cases):
        vis = np.asarray(m.is_perceptible(ci, ks / (2 * ti), ei / ks))
        kb = ks[vis].max() if vis.any() else 0.0
        np.testing.assert_allclose(k[i], kb, rtol=2e-3, atol=1e-9, err_msg=str(cases[i]))
    # the narrow window of case 0 (about k in [0.75, 0.82]) is found: seed-004 keys must not miss it
    assert 0.8 < k[0] < 0.82
    # definition at the answer for case 1
    assert m.is_perceptible(0.05, k[1] * 0.999 / 0.2, 20.0 / (k[1] * 0.999))
    for kk in (1.001 * k[1], 1.5 * k[1], 3 * k[1], 10 * k[1]):
        assert not m.is_perceptible(0.05, kk / 0.2, 20.0 / kk)
    # implicit gradient vs finite difference in c
    fn = jax.jit(lambda cc: m.imperceptible_distance(cc, 0.1, 20.0))
    h = 1e-3
    fd = (fn(0.05 + h) - fn(0.05 - h)) / (2 * h)
    np.testing.assert_allclose(jax.grad(fn)(0.05), fd, rtol=2e-2)


def test_gradients_finite_at_nodes():
    m = _model()
    ff, ee = np.meshgrid([1.0, 2.0, 4.0, 16.0, 0.0, 40.0], [0.0, 10.0, 5.0])
    grad_fe = jax.vmap(jax.grad(lambda f, e: m.log_sensitivity(f, e), argnums=(0, 1)))
    gf, ge = grad_fe(jnp.asarray(ff.ravel()), jnp.asarray(ee.ravel()))
    assert np.all(np.isfinite(gf)) and np.all(np.isfinite(ge))
    gt = jax.grad(lambda mm: jnp.sum(mm.log_sensitivity(jnp.array([1.0, 4.0, 5.0, 30.0]), 3.0)))(m)
    assert np.all(np.isfinite(gt.log_thresholds))
    # d log S / d table at an interior point: -ln10 times the bilinear weights (f = 4*2**0.5, e = 2.5)
    gt = jax.grad(lambda mm: mm.log_sensitivity(4 * 2 ** 0.5, 2.5))(m)
    want = np.zeros_like(TABLE)
    want[2, 0] = want[3, 0] = 0.5 * 0.75
    want[2, 1] = want[3, 1] = 0.5 * 0.25
    np.testing.assert_allclose(gt.log_thresholds, -math.log(10) * want, rtol=1e-4, atol=1e-6)
    # d log S / d log f on a segment: -ln10 * slope / ln10 = -(0.4 / log10 2) / f ... per unit f
    np.testing.assert_allclose(jax.grad(lambda f: m.log_sensitivity(f, 0.0))(5.0),
                               -(0.4 / math.log10(2.0)) / 5.0, rtol=1e-4)
    # threshold_frequency gradient vs finite difference
    fn = jax.jit(lambda c: m.threshold_frequency(c, 3.0))
    c0, h = 0.02, 1e-4
    fd = (fn(c0 + h) - fn(c0 - h)) / (2 * h)
    np.testing.assert_allclose(jax.grad(fn)(c0), fd, rtol=2e-2)


_PROP_MODEL = None


def _prop_fns():
    global _PROP_MODEL
    if _PROP_MODEL is None:
        m = CalibratedCSF(FREQS, ECCS, TABLE.astype(np.float32))
        ls = jax.jit(lambda f, e: m.log_sensitivity(f, e))
        gls = jax.jit(jax.grad(lambda f, e: m.log_sensitivity(f, e), argnums=(0, 1)))
        tf = jax.jit(lambda c, e: m.threshold_frequency(c, e))
        gtf = jax.jit(jax.grad(lambda c, e: m.threshold_frequency(c, e)))
        _PROP_MODEL = (ls, gls, tf, gtf)
    return _PROP_MODEL


@given(st.floats(0.0, 100.0), st.floats(0.0, 60.0), st.floats(0.0, 1.0))
def test_property_finite(f, e, c):
    ls, gls, tf, gtf = _prop_fns()
    f, e, c = jnp.float32(f), jnp.float32(e), jnp.float32(c)
    assert np.isfinite(ls(f, e))
    assert np.all(np.isfinite(gls(f, e)))
    t = tf(c, e)
    assert np.isfinite(t) and t >= 0
    assert np.isfinite(gtf(c, e))


def test_velocity_axis():
    T = np.stack([TABLE, TABLE + 0.5], axis=-1)  # (F, E, V): moving stimuli are 10**0.5 times harder
    m = CalibratedCSF(FREQS, ECCS, T, vels=[0.0, 4.0])
    np.testing.assert_allclose(np.log10(m.threshold_contrast(4.0, 0.0, 2.0)), -2.2 + 0.25, atol=1e-5)
    np.testing.assert_allclose(np.log10(m.threshold_contrast(4.0, 0.0, 100.0)), -2.2 + 0.5, atol=1e-5)


def test_from_data_bins_and_averages(tmp_path):
    # every node twice, with log thresholds +-0.1 around the table: the mean recovers the table
    ff, ee = np.meshgrid(FREQS, ECCS, indexing="ij")
    f = np.concatenate([ff.ravel(), ff.ravel() * 1.02])
    e = np.concatenate([ee.ravel(), ee.ravel() + 0.1])
    y = np.concatenate([TABLE.ravel() + 0.1, TABLE.ravel() - 0.1])
    d = CalibrationData.from_arrays(f, y, e=e)
    m = CalibratedCSF.from_data(d, freqs=FREQS, eccs=ECCS)
    np.testing.assert_allclose(m.log_thresholds, TABLE, atol=1e-6)
    assert m.freqs == tuple(FREQS) and m.eccs == tuple(ECCS)
    # N-weighted mean
    d2 = CalibrationData.from_arrays([1.0, 1.0, 2.0], [-1.0, -2.0, -1.5], n=[1.0, 3.0, 1.0])
    np.testing.assert_allclose(CalibratedCSF.from_data(d2).log_thresholds[:, 0], [-1.75, -1.5])
    # CSV path
    d.to_csv(tmp_path / "cal.csv")
    m3 = CalibratedCSF.from_csv(tmp_path / "cal.csv", freqs=FREQS, eccs=ECCS)
    np.testing.assert_allclose(m3.log_thresholds, TABLE, atol=1e-6)


def test_from_data_velocity_axis():
    ff, ee, vv = np.meshgrid(FREQS, ECCS, [0.0, 4.0], indexing="ij")
    T = np.stack([TABLE, TABLE + 0.5], axis=-1)
    d = CalibrationData.from_arrays(ff.ravel(), T.ravel(), e=ee.ravel(), velocity=vv.ravel())
    m = CalibratedCSF.from_data(d, vels="auto")
    assert m.vels == (0.0, 4.0)
    np.testing.assert_allclose(m.log_thresholds, T, atol=1e-12)
    with pytest.raises(ValueError, match="vels must be None, 'auto'"):
        CalibratedCSF.from_data(d, vels="yes")


def test_from_data_errors():
    d = CalibrationData.from_arrays([1.0, 2.0, 4.0], [-2.0, -2.0, -1.0], e=[0.0, 0.0, 10.0])
    with pytest.raises(ValueError, match=r"cannot fill the grid: 3 of 6 cells"):
        CalibratedCSF.from_data(d)
    with pytest.raises(ValueError, match=r"row 2 at frequency 4 cycles/deg is not within tolerance"):
        CalibratedCSF.from_data(d, freqs=[1.0, 2.0, 8.0], eccs=[0.0, 10.0])
    mv = CalibrationData.from_arrays([1.0, 2.0], [-2.0, -2.0], velocity=[0.0, 3.0])
    with pytest.raises(ValueError, match="no velocity axis"):
        CalibratedCSF.from_data(mv)
    with pytest.raises(ValueError, match="frequency 0"):
        CalibratedCSF.from_data(CalibrationData.from_arrays([0.0, 2.0], [-2.0, -2.0]))


@pytest.mark.parametrize(
    "args, kwargs, pattern",
    [
        (([1.0], [0.0], np.zeros((1, 1))), {}, "at least 2 frequency"),
        (([1.0, 2.0], [0.0], np.zeros((2, 2))), {}, r"shape \(F, E\) = \(2, 1\)"),
        (([2.0, 1.0], [0.0], np.zeros((2, 1))), {}, "strictly increasing"),
        (([0.0, 1.0], [0.0], np.zeros((2, 1))), {}, "must be > 0"),
        (([1.0, 2.0], [-1.0], np.zeros((2, 1))), {}, "must be >= 0"),
        (([1.0, 2.0], [0.0], np.array([[0.0], [np.nan]])), {}, r"NaN or infinite entry at index \(1, 0\)"),
        (([1.0, 2.0], [0.0], np.zeros((2, 1))), {"min_slope": 0.0}, "min_slope"),
    ],
)
def test_construction_errors(args, kwargs, pattern):
    with pytest.raises(ValueError, match=pattern):
        CalibratedCSF(*args, **kwargs)


def test_query_errors():
    m = _model()
    with pytest.raises(ValueError, match="f must be >= 0"):
        m.sensitivity(-1.0)
    with pytest.raises(ValueError, match="do not broadcast"):
        m.threshold_contrast(jnp.ones(3), jnp.ones(2))


@pytest.mark.shared
def test_modelfest_observer_table(shared_dir):
    d = CalibrationData.from_csv(shared_dir / "data" / "csf" / "modelfest_individual.csv")
    obs = d.subset((d.observer == "obs_54") & (np.abs(d.area - 0.785398163397448) < 1e-9))
    m = CalibratedCSF.from_data(obs)
    assert len(m.freqs) == 10 and m.eccs == (0.0,)
    for i, f in enumerate(m.freqs):
        rows = obs.log_threshold[np.isclose(obs.f, f)]
        np.testing.assert_allclose(m.log_thresholds[i, 0], rows.mean(), atol=1e-6)
    # a plausible observer: peak sensitivity between 1 and 8 cycles/deg, at most 30 c/deg resolvable at 10 %
    assert 1.0 <= float(m.peak_frequency()) <= 8.0
    assert 10.0 < float(m.threshold_frequency(0.1)) < 60.0


def test_export():
    assert pmetric.CalibratedCSF is CalibratedCSF and issubclass(CalibratedCSF, pmetric.CSFModel)

"""Tests for pmetric.CalibratedCSF (the calibrated threshold lookup table [LH01 §6.1])."""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import pmetric
from optim.fit import CalibrationData
from pmetric import CalibratedCSF

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
    m3 = CalibratedCSF.from_data(CalibrationData.from_csv(tmp_path / "cal.csv"), freqs=FREQS, eccs=ECCS)
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


# ----------------------------------------------------------------------------------------------------
# Slow references (the original gather-based formulas, numpy float64) and the elementwise / exact
# implementations checked against them.

BENCH_FREQS = [1.0, 2.0, 4.0, 8.0, 16.0, 32.0]
BENCH_ECCS = [0.0, 10.0, 30.0]
BENCH_TABLE = np.log10(1.0 / np.array([[60, 120, 150, 100, 30, 4], [40, 70, 60, 25, 5, 1],
                                       [20, 25, 15, 4, 1, 0.5]], float)).T


def _tables():
    """(f x e) tables with different features: the benchmark's, the module's, a non-monotone falling
    limb (dips, peak switches), a first eccentricity node > 0 with a steep min_slope."""
    return {
        "bench": (BENCH_FREQS, BENCH_ECCS, BENCH_TABLE, 1.0),
        "test": (FREQS, ECCS, TABLE, 1.0),
        "dip": ([1.0, 2.0, 4.0, 8.0], [0.0, 5.0, 20.0],
                np.array([[-2.0, -1.8, -1.0], [-1.0, -1.5, -0.5], [-1.5, -1.2, -1.4], [0.0, -0.2, 0.5]]), 1.0),
        "e0pos": ([0.5, 3.0, 12.0], [2.0, 15.0], np.array([[-1.5, -1.0], [-2.2, -1.4], [-0.8, -0.9]]), 2.0),
    }


def _weights_ref(x, nodes):
    nodes = np.asarray(nodes, float)
    if len(nodes) == 1:
        return np.zeros(x.shape, int), np.zeros(x.shape)
    i = np.clip(np.searchsorted(nodes, x, side="right") - 1, 0, len(nodes) - 2)
    return i, np.clip((x - nodes[i]) / (nodes[i + 1] - nodes[i]), 0.0, 1.0)


def _ref_columns(m, e, v):
    """Clamped node columns (..., F), peak index and extrapolation slope: the original gather formula."""
    T = np.asarray(m.log_thresholds, np.float64)
    vels = m.vels
    if vels is None:
        T, vels = T[..., None], (0.0,)
    Tm = np.moveaxis(T, 0, -1)  # (E, V, F)
    ie, te = _weights_ref(e, m.eccs)
    iv, tv = _weights_ref(v, vels)
    ie1, iv1 = np.minimum(ie + 1, Tm.shape[0] - 1), np.minimum(iv + 1, Tm.shape[1] - 1)
    a = Tm[ie, iv] * (1 - tv)[..., None] + Tm[ie, iv1] * tv[..., None]
    b = Tm[ie1, iv] * (1 - tv)[..., None] + Tm[ie1, iv1] * tv[..., None]
    col = a * (1 - te)[..., None] + b * te[..., None]
    F = len(m.freqs)
    p = (F - 1) - np.argmin(col[..., ::-1], axis=-1)
    yp = np.take_along_axis(col, p[..., None], axis=-1)
    col = np.where(np.arange(F) <= p[..., None], yp, col)
    lfn = np.log10(m.freqs)
    slope = np.maximum((col[..., -1] - col[..., -2]) / (lfn[-1] - lfn[-2]), m.min_slope)
    return col, p, slope


def _ref_log10_threshold(m, f, e, v=0.0):
    f, e, v = np.broadcast_arrays(*(np.asarray(x, np.float64) for x in (f, e, v)))
    col, _, slope = _ref_columns(m, e, v)
    lfn = np.log10(m.freqs)
    lf = np.where(f > 0, np.log10(np.where(f > 0, f, 1.0)), lfn[0] - 1.0)
    j, t = _weights_ref(lf, lfn)
    y0 = np.take_along_axis(col, j[..., None], axis=-1)[..., 0]
    y1 = np.take_along_axis(col, (j + 1)[..., None], axis=-1)[..., 0]
    return np.where(lf > lfn[-1], col[..., -1] + slope * (lf - lfn[-1]), y0 + t * (y1 - y0))


def _ref_threshold_frequency(m, c, e, v=0.0):
    c, e, v = np.broadcast_arrays(*(np.asarray(x, np.float64) for x in (c, e, v)))
    col, p, slope = _ref_columns(m, e, v)
    lfn = np.log10(m.freqs)
    F = len(lfn)
    Y = np.log10(np.where(c > 0, c, 1.0))
    yp = np.take_along_axis(col, p[..., None], axis=-1)[..., 0]
    visible = (c > 0) & (Y >= yp)
    lf_ext = lfn[-1] + (Y - col[..., -1]) / slope
    j = np.clip((F - 1) - np.argmax((col <= Y[..., None])[..., ::-1], axis=-1), 0, F - 2)
    y0 = np.take_along_axis(col, j[..., None], axis=-1)[..., 0]
    y1 = np.take_along_axis(col, (j + 1)[..., None], axis=-1)[..., 0]
    t = np.clip(np.where(y1 > y0, (Y - y0) / np.where(y1 > y0, y1 - y0, 1.0), 0.0), 0.0, 1.0)
    lf = np.where(Y >= col[..., -1], lf_ext, lfn[j] + t * (lfn[j + 1] - lfn[j]))
    return np.where(visible, 10.0 ** lf, 0.0)


def _random_queries(n, seed):
    rng = np.random.default_rng(seed)
    c = rng.uniform(0.0, 1.0, n)
    c[::5] = 10 ** rng.uniform(-3, 0, len(c[::5]))
    f = np.exp(rng.uniform(np.log(1e-3), np.log(1e3), n))
    f[::7] = rng.choice([0.5, 1.0, 2.0, 3.0, 4.0, 8.0, 12.0, 16.0, 32.0, 0.0], len(f[::7]))  # at nodes, 0
    e = rng.uniform(0.0, 60.0, n)
    e[::6] = rng.choice([0.0, 2.0, 5.0, 10.0, 15.0, 20.0, 30.0, 200.0], len(e[::6]))  # at / beyond nodes
    v = np.where(rng.uniform(size=n) < 0.5, 0.0, rng.uniform(0.0, 10.0, n))
    theta = np.exp(rng.uniform(np.log(0.01), np.log(5.0), n))
    return c, f, e, v, theta


def test_elementwise_curve_matches_gather_reference(x64):
    c, f, e, v, _ = _random_queries(4000, 0)
    T3 = np.stack([TABLE, TABLE + 0.5, TABLE + 0.2], axis=-1)
    models = [CalibratedCSF(fr, ec, t, min_slope=ms) for fr, ec, t, ms in _tables().values()]
    models.append(CalibratedCSF(FREQS, ECCS, T3, vels=[0.0, 4.0, 10.0]))
    for m in models:
        want = _ref_log10_threshold(m, f, e, v)
        got = np.asarray(m.log_sensitivity(f, e, v)) / -math.log(10.0)
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
        # is_perceptible: the same decision except within rounding of the threshold
        margin = np.log10(np.maximum(c, 1e-30)) - want
        got_p = np.asarray(jax.jit(lambda c, f, e, v, m=m: m.is_perceptible(c, f, e, v))(c, f, e, v))
        sure = np.abs(margin) > 1e-9
        np.testing.assert_array_equal(got_p[sure], (margin >= 0)[sure])
        np.testing.assert_allclose(m.threshold_frequency(c, e, v), _ref_threshold_frequency(m, c, e, v),
                                   rtol=1e-11, atol=1e-300)
        _, p, _ = _ref_columns(m, e, v)
        np.testing.assert_array_equal(m.peak_frequency(e, v), np.asarray(m.freqs)[p])


def test_is_perceptible_nan_and_float32():
    m = CalibratedCSF(BENCH_FREQS, BENCH_ECCS, BENCH_TABLE.astype(np.float32))
    fn = jax.jit(lambda c, f, e, v: m.is_perceptible(c, f, e, v))
    nan = jnp.float32(jnp.nan)
    out = fn(jnp.array([nan, 0.5, 0.5, 0.5, 1.0, 0.0]), jnp.array([4.0, nan, 4.0, 0.0, jnp.inf, 4.0]),
             jnp.array([0.0, 0.0, nan, 0.0, 0.0, 0.0]), jnp.zeros(6))
    np.testing.assert_array_equal(out, [False, False, False, True, False, False])
    dist = jax.jit(lambda c, t, e: m.imperceptible_distance(c, t, e))(
        jnp.array([nan, 0.5, 0.5, 0.5]), jnp.array([0.1, nan, 0.1, 0.1]), jnp.array([3.0, 3.0, nan, 3.0]))
    assert np.all(np.isnan(dist[:3])) and np.isfinite(dist[3]) and dist[3] > 0
    c, f, e, v, _ = _random_queries(2000, 1)
    want = np.log10(np.maximum(c, 1e-30)) >= _ref_log10_threshold(m, f, e, v)
    got = np.asarray(fn(*(jnp.asarray(x, jnp.float32) for x in (c, f, e, v))))
    assert (got != want).mean() < 2e-3  # float32 rounding at the threshold only


def _brute_distance(m, c, theta, e, n=20001):
    """The definition on a dense log grid of f in [1e-5, 1e6] cycles/deg: the largest perceptible k (0 if
    none), and the grid ratio. Perceptibility from the numpy reference curve."""
    fs = np.exp(np.linspace(np.log(1e-5), np.log(1e6), n))
    out = np.zeros(len(c))
    for s in range(0, len(c), 16):
        sl = slice(s, s + 16)
        k = 2.0 * np.asarray(theta[sl])[:, None] * fs[None, :]
        y = _ref_log10_threshold(m, fs[None, :], np.asarray(e[sl])[:, None] / k)
        vis = np.log10(np.maximum(np.asarray(c[sl]), 1e-30))[:, None] >= y
        out[sl] = np.where(vis.any(axis=1), np.where(vis, k, 0.0).max(axis=1), 0.0)
    return out, fs[1] / fs[0]


def _check_distance(m, c, theta, e, k, kb, ratio):
    """k is the supremum of the perceptible k: no grid point above it is perceptible, it is at most one
    grid step above the last perceptible grid point unless a window narrower than a step lies above it,
    and the change is perceptible just below it."""
    c, theta, e, k, kb = (np.asarray(x, np.float64) for x in (c, theta, e, k, kb))
    assert np.all(np.isfinite(k)) and np.all(k >= 0)
    assert np.all(k >= kb * (1 - 1e-9)), np.where(k < kb * (1 - 1e-9))
    pos = k > 0
    kk = k[pos] * (1 - 1e-7)
    below = np.log10(np.maximum(c[pos], 1e-30)) - _ref_log10_threshold(m, kk / (2 * theta[pos]), e[pos] / kk)
    assert np.all(below >= -1e-12), np.where(below < -1e-12)
    far = k > kb * ratio * (1 + 1e-9)  # only a narrow window (perceptible just below k, checked above)
    assert far.mean() < 0.01


def test_exact_distance_vs_brute_force_fixed_tables(x64):
    c, _, e, _, theta = _random_queries(200, 2)
    edge = np.array([(0.0, 0.1, 5.0), (1.0, 0.1, 5.0), (1.0, 5.0, 60.0), (0.3, 1e-3, 30.0), (0.3, 50.0, 3.0),
                     (1e-4, 0.2, 10.0), (0.05, 0.3, 0.0), (0.05, 0.3, 200.0), (0.02, 0.7, 10.0), (0.9, 0.01, 45.0)])
    c, theta, e = (np.concatenate([x, edge[:, j]]) for j, x in enumerate((c, theta, e)))
    for name, (fr, ec, t, ms) in _tables().items():
        m = CalibratedCSF(fr, ec, t, min_slope=ms)
        k = np.asarray(jax.jit(lambda c, t, e, m=m: m.imperceptible_distance(c, t, e))(c, theta, e))
        kb, ratio = _brute_distance(m, c, theta, e)
        _check_distance(m, c, theta, e, k, kb, ratio)
        assert k[len(c) - len(edge)] == 0.0  # c = 0
        # the traced-table (generic) solver agrees with the planned one
        kg = eqx.filter_jit(lambda mm, c, t, e: mm.imperceptible_distance(c, t, e))(m, c, theta, e)
        np.testing.assert_allclose(kg, k, rtol=1e-10, atol=1e-300, err_msg=name)


@given(st.integers(2, 4), st.integers(1, 3), st.integers(0, 2**31 - 1), st.floats(1e-3, 1.0),
       st.floats(-2.0, 0.7), st.floats(0.0, 60.0))
def test_exact_distance_random_tables_vs_brute_force(F, E, seed, c, log_theta, e):
    from conftest import x64_mode

    with x64_mode(True):
        rng = np.random.default_rng(seed)
        freqs = np.cumprod(np.r_[rng.uniform(0.3, 2.0), rng.uniform(1.3, 5.0, F - 1)])
        eccs = np.cumsum(np.r_[rng.choice([0.0, rng.uniform(0.5, 5.0)]), rng.uniform(2.0, 25.0, E - 1)])
        m = CalibratedCSF(freqs, eccs, rng.uniform(-3.0, 0.3, (F, E)), min_slope=rng.uniform(0.5, 3.0))
        # several eccentricities and contrasts for one size, including e = 0, the nodes and beyond
        es = np.r_[e, 0.0, eccs, 2 * eccs[-1] + 1, rng.uniform(0.0, 60.0, 8)]
        cs = np.r_[np.full(len(es) - 8, c), 10 ** rng.uniform(-3.0, 0.0, 8)]
        ts = np.full(len(es), 10.0**log_theta)
        k = np.asarray(m.imperceptible_distance(cs, ts, es))  # the static plan of this concrete table
        kb, ratio = _brute_distance(m, cs, ts, es)
        _check_distance(m, cs, ts, es, k, kb, ratio)


def test_exact_distance_gradients_vs_finite_differences(x64):
    rng = np.random.default_rng(3)
    n = 60
    c, e, theta = rng.uniform(0.003, 1.0, n), rng.uniform(0.0, 60.0, n), np.exp(rng.uniform(np.log(0.01), np.log(5), n))
    for name, (fr, ec, t, ms) in _tables().items():
        if name not in ("bench", "dip"):  # (the other tables' gradients: finiteness test below)
            continue
        m = CalibratedCSF(fr, ec, t, min_slope=ms)
        fn = jax.jit(lambda c, t, e, m=m: m.imperceptible_distance(c, t, e))
        grads = jax.jit(jax.vmap(jax.grad(lambda c, t, e, m=m: m.imperceptible_distance(c, t, e), argnums=(0, 1, 2))))(
            c, theta, e)
        k0 = np.asarray(fn(c, theta, e))
        checked = 0
        for j, g in enumerate(grads):
            x = (c, theta, e)[j]
            h = 1e-6 * np.maximum(np.abs(x), 1e-3)

            def at(dx, j=j):
                return np.asarray(fn(*[a + dx if i == j else a for i, a in enumerate((c, theta, e))]))

            fd, fd2 = (at(h) - at(-h)) / (2 * h), (at(2 * h) - at(-2 * h)) / (4 * h)
            smooth = (np.abs(fd - fd2) <= 1e-4 * (np.abs(fd) + 1e-6)) & (k0 > 0) & (x - 2 * h > 0)
            np.testing.assert_allclose(np.asarray(g)[smooth], fd[smooth], rtol=1e-4, atol=1e-6, err_msg=name)
            checked += smooth.sum()
        assert checked > n  # most points are smooth
        if name != "dip":
            continue
        # d(sum k) / d table (a traced table: the generic solver)
        total = lambda T, fr=fr, ec=ec, ms=ms: jnp.sum(  # noqa: E731
            CalibratedCSF(fr, ec, T, min_slope=ms).imperceptible_distance(c[:20], theta[:20], e[:20]))
        tj = jax.jit(total)
        gT, fd = np.asarray(jax.jit(jax.grad(total))(jnp.asarray(t))), np.zeros(t.shape)
        for idx in np.ndindex(*t.shape):
            d = np.zeros(t.shape)
            d[idx] = 1e-6
            fd[idx] = (tj(t + d) - tj(t - d)) / 2e-6
        np.testing.assert_allclose(gT, fd, rtol=1e-4, atol=1e-4 * np.abs(fd).max(), err_msg=name)


@pytest.mark.parametrize("prec", ["float32", "float64"])
def test_exact_distance_finite_values_and_gradients(prec):
    from conftest import x64_mode

    with x64_mode(prec == "float64"):
        dt = jnp.dtype(prec)
        cc, tt, ee = np.meshgrid([0.0, 1e-4, 0.004, 0.05, 0.3, 1.0], [1e-6, 0.01, 0.3, 5.0, 200.0],
                                 [0.0, 1e-3, 2.0, 10.0, 30.0, 1e4], indexing="ij")
        c, theta, e = (jnp.asarray(x.ravel(), dt) for x in (cc, tt, ee))
        for name, (fr, ec, t, ms) in _tables().items():
            m = CalibratedCSF(fr, ec, np.asarray(t, dt), min_slope=ms)
            k = jax.jit(lambda c, t, e, m=m: m.imperceptible_distance(c, t, e))(c, theta, e)
            assert k.dtype == dt and np.all(np.isfinite(k)) and np.all(np.asarray(k) >= 0), name
            if name not in ("bench", "e0pos"):
                continue
            gs = jax.jit(jax.vmap(jax.grad(lambda c, t, e, m=m: m.imperceptible_distance(c, t, e),
                                           argnums=(0, 1, 2))))(c, theta, e)
            for g in gs:
                assert np.all(np.isfinite(g)), name
            if name != "bench":
                continue
            gT = jax.jit(jax.grad(lambda T, fr=fr, ec=ec, ms=ms: jnp.sum(
                CalibratedCSF(fr, ec, T, min_slope=ms).imperceptible_distance(c, theta, e))))(m.log_thresholds)
            assert np.all(np.isfinite(gT)), name
        # float32 against float64 away from near-tangent crossings: close
        if prec == "float32":
            m = CalibratedCSF(BENCH_FREQS, BENCH_ECCS, BENCH_TABLE.astype(np.float32))
            c, _, e, _, theta = _random_queries(20000, 4)
            k32 = np.asarray(jax.jit(lambda c, t, e: m.imperceptible_distance(c, t, e))(
                *(jnp.asarray(x, jnp.float32) for x in (c, theta, e))))
            with x64_mode(True):
                m64 = CalibratedCSF(BENCH_FREQS, BENCH_ECCS, BENCH_TABLE)
                k64 = np.asarray(m64.imperceptible_distance(c, theta, e))
            rel = np.abs(k32 - k64) / np.maximum(k64, 1e-30)
            assert np.quantile(rel, 0.999) < 1e-4 and (rel > 1e-2).sum() <= 2


def test_velocity_axis_distance(x64):
    T = np.stack([TABLE, TABLE + 0.5], axis=-1)
    m = CalibratedCSF(FREQS, ECCS, T, vels=[0.0, 4.0])
    m0 = CalibratedCSF(FREQS, ECCS, TABLE)
    c, theta, e = jnp.array([0.01, 0.05, 0.03]), jnp.array([0.1, 0.1, 0.5]), jnp.array([5.0, 20.0, 12.0])
    # a concrete zero velocity uses the exact (f x e) solver on the v = 0 slice
    np.testing.assert_allclose(m.imperceptible_distance(c, theta, e, 0.0), m0.imperceptible_distance(c, theta, e),
                               rtol=1e-12)
    # moving: the table-aware scan; its answer is perceptible just below and not above
    v = jnp.array([2.0, 8.0, 1.0])
    c = jnp.array([0.03, 0.08, 0.05])
    k = np.asarray(jax.jit(lambda c, t, e, v: m.imperceptible_distance(c, t, e, v))(c, theta, e, v))
    for kk, cc, th, ee, vv in zip(k, np.asarray(c), np.asarray(theta), np.asarray(e), np.asarray(v)):
        if kk > 0:
            assert m.is_perceptible(cc, kk * 0.999 / (2 * th), ee / (kk * 0.999), vv / (kk * 0.999))
        assert kk > 0
        for mult in (1.001, 1.5, 3.0, 10.0):
            assert not m.is_perceptible(cc, kk * mult / (2 * th), ee / (kk * mult), vv / (kk * mult))

"""Exact inversions: Lambert W_{-1}, threshold frequency, imperceptible distance (vs brute force)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.special
from hypothesis import given, settings
from hypothesis import strategies as st

import pmetric as pm
from pmetric._base import CSFModel

from _definition import check_distance_definition, generic_distance, generic_threshold_frequency  # noqa: E402

FACTORIES = {
    "manos": lambda: pm.ManosSakrison(),
    "kelly_abstract": lambda: pm.KellyAbstract(),
    "kelly1979": lambda: pm.KellySpatioTemporal("kelly1979"),
    "reddy_st": lambda: pm.KellySpatioTemporal("reddy"),
    "eccentric_cubic": lambda: pm.Eccentric(pm.ManosSakrison()),
    "eccentric_linear": lambda: pm.Eccentric(pm.ManosSakrison(), pm.RovamoVirsu("linear")),
    "eccentric_kelly": lambda: pm.Eccentric(pm.KellySpatioTemporal()),
}
with jax.enable_x64(True):  # float64 constants (tests below run in float64)
    MODELS = {k: f() for k, f in FACTORIES.items()}


@pytest.fixture
def x64():
    with jax.enable_x64(True):
        yield


def test_lambertw_m1_matches_scipy_float64(x64):
    x = -np.concatenate([np.geomspace(1e-300, 0.3, 200), np.linspace(0.3, 1 / np.e, 200)])
    w = np.asarray(pm.lambertw_m1(jnp.asarray(x)))
    ref = scipy.special.lambertw(x, -1).real
    ref[-1] = -1.0  # scipy returns NaN exactly at the branch point -1/e
    np.testing.assert_allclose(w, ref, rtol=1e-12, atol=1e-7)  # atol: sqrt-sensitivity at -1/e
    np.testing.assert_allclose(w * np.exp(w), x, rtol=1e-12, atol=1e-15)


def test_lambertw_m1_float32_and_gradient():
    x = -np.geomspace(1e-30, 0.367, 100).astype(np.float32)
    w = np.asarray(pm.lambertw_m1(jnp.asarray(x)))
    np.testing.assert_allclose(w, scipy.special.lambertw(x.astype(float), -1).real, rtol=1e-5)
    g = np.asarray(jax.jit(jax.vmap(jax.grad(pm.lambertw_m1)))(jnp.asarray(x)))
    ref = w / (x * (1 + w))
    np.testing.assert_allclose(g, ref, rtol=1e-4)
    gb = jax.grad(pm.lambertw_m1)(jnp.float32(-1 / np.e))  # branch point: finite
    assert np.isfinite(gb)


@pytest.mark.parametrize("name", list(MODELS))
def test_threshold_frequency_inverts_falling_limb(name, x64):
    m = MODELS[name]
    c = jnp.asarray(np.geomspace(0.01, 1.0, 25))
    for e, v in [(0.0, 0.0), (10.0, 0.0), (0.0, 5.0), (20.0, 30.0)]:
        f = m.threshold_frequency(c, e, v)
        vis = np.asarray(f) > 0
        fp = np.asarray(m.peak_frequency(e, v))
        ok = vis & (np.asarray(f) > fp * 1.05)  # strictly on the falling limb
        if ok.any():
            ct = np.asarray(m.threshold_contrast(f, e, v))
            np.testing.assert_allclose(ct[ok], np.asarray(c)[ok], rtol=1e-8)
        # invisible at peak <=> f == 0
        peak_ct = float(m.threshold_contrast(fp, e, v))
        np.testing.assert_array_equal(vis, np.asarray(c) >= peak_ct * (1 - 1e-9))
        # closed form agrees with the generic base-class solver
        fg = generic_threshold_frequency(m, c, e, v)
        np.testing.assert_allclose(np.asarray(fg)[ok], np.asarray(f)[ok], rtol=1e-6)


_KK = np.geomspace(1e-4, 1e5, 4001)


@pytest.mark.parametrize("name", list(MODELS))
@settings(max_examples=8, deadline=None)
@given(
    c=st.floats(1e-3, 1.0),
    theta=st.floats(0.01, 5.0),
    e=st.sampled_from([0.0, 0.5, 5.0, 40.0]) | st.floats(0.0, 80.0),
    v=st.sampled_from([0.0, 1.0, 30.0]) | st.floats(0.0, 200.0),
)
def test_imperceptible_distance_definition(name, c, theta, e, v):
    """Brute force: coarse grid over 9 decades of k plus a fine grid just above k."""
    check_distance_definition(MODELS[name], c, theta, e, v, _KK, rel=1e-4, n_fine=2000)


@pytest.mark.parametrize("name", ["manos", "kelly_abstract", "eccentric_cubic", "kelly1979"])
def test_closed_form_distance_matches_generic(name, x64):
    m = MODELS[name]
    rng = np.random.default_rng(0)
    c = rng.uniform(0.005, 1, 64)
    theta = rng.uniform(0.02, 2, 64)
    e = rng.uniform(0, 60, 64)
    v = np.where(rng.uniform(size=64) < 0.5, 0.0, rng.uniform(0, 100, 64))
    k = np.asarray(m.imperceptible_distance(c, theta, e, v))
    kg = np.asarray(generic_distance(m, c, theta, e, v))
    np.testing.assert_allclose(k, kg, rtol=1e-5, atol=1e-9)


@pytest.mark.parametrize("name", list(MODELS))
def test_distance_gradients_match_finite_differences(name, x64):
    m = MODELS[name]
    c, theta, e, v = 0.3, 0.2, 3.0, 0.5
    fun = jax.jit(lambda *a: m.imperceptible_distance(*a))
    g = jax.jit(jax.grad(fun, argnums=(0, 1, 2, 3)))(c, theta, e, v)
    x0 = np.array([c, theta, e, v])
    for i in range(4):
        h = 1e-6 * max(abs(x0[i]), 1.0)
        xp, xm = x0.copy(), x0.copy()
        xp[i] += h
        xm[i] -= h
        fd = (float(fun(*xp)) - float(fun(*xm))) / (2 * h)
        assert float(g[i]) == pytest.approx(fd, rel=1e-4, abs=1e-7), (i, g[i], fd)


def test_theta_zero_and_zero_contrast_give_zero(x64):
    for m in MODELS.values():
        assert float(m.imperceptible_distance(0.5, 0.0)) == 0.0
        assert float(m.imperceptible_distance(0.0, 1.0)) == 0.0
        assert float(m.threshold_frequency(0.0)) == 0.0


def test_kelly_abstract_closed_form_by_hand(x64):
    # delta = e^2 -> peak sensitivity 4: c = 1 visible; alpha* solves alpha^2 e^-alpha = e^-2
    m = pm.KellyAbstract(delta=np.e**2, f0=2.0)
    a = float(m.threshold_frequency(1.0))  # f0 = 2 -> alpha = f
    assert a**2 * np.exp(-a) == pytest.approx(np.exp(-2.0), rel=1e-12)
    assert a == pytest.approx(-2 * scipy.special.lambertw(-0.5 / np.e, -1).real, rel=1e-12)
    # distance: alpha(k) = (k + 0.29 e) / (theta f0)
    k = float(m.imperceptible_distance(1.0, 0.5, 2.0))
    assert k == pytest.approx(a * 0.5 * 2.0 - 0.29 * 2.0, rel=1e-12)


class _BumpCSF(CSFModel):
    """Falling in f, visible only near eccentricity e0 (a Gaussian bump in ln S): narrow windows in k."""

    s0: jax.Array
    bump: jax.Array
    inputs = ("f", "e")

    def __init__(self, s0=0.5, bump=3.0):
        self.s0, self.bump = jnp.asarray(s0), jnp.asarray(bump)

    def _log_sensitivity(self, f, e, v):  # the only hook a model must implement
        out = jnp.log(self.s0) - f / 10.0 + self.bump * jnp.exp(-(((e - 5.0) / 0.22) ** 2))
        return jnp.broadcast_to(out, jnp.broadcast_shapes(out.shape, jnp.shape(v)))


def test_generic_distance_finds_narrow_window(x64):
    """A perceptible window ~8-9 % wide in k (e / k within the bump) above nothing else perceptible:
    the 257-point scan (7.5 % steps) finds it exactly; a 65-point scan (the former default) misses it."""
    from pmetric._inverse import largest_crossing

    m = _BumpCSF()
    c, theta, e = np.array([0.8, 0.85, 0.9]), np.array([0.1, 0.2, 0.1]), np.array([5.0, 4.0, 5.5])
    k = np.asarray(m.imperceptible_distance(c, theta, e))
    kk = np.geomspace(0.1, 10.0, 200001)[:, None]
    p = np.asarray(m.is_perceptible(c, kk / (2 * theta), e / kk))
    lo, hi = np.where(p, kk, np.inf).min(0), np.where(p, kk, 0.0).max(0)
    assert ((hi / lo > 1.075) & (hi / lo < 1.10)).all(), hi / lo  # narrow windows
    np.testing.assert_allclose(k, hi, rtol=5e-5)  # brute-force grid resolution
    ks = k * (1 + 1e-9)
    assert not np.asarray(m.is_perceptible(c, ks / (2 * theta), e / ks)).any()
    ks = k * (1 - 1e-9)
    assert np.asarray(m.is_perceptible(c, ks / (2 * theta), e / ks)).all()
    # the former 65-point scan misses at least one of them
    g = lambda w: m._distance_margin(jnp.exp(w), c, theta, e, 0.0)  # noqa: E731
    _, found65, _ = largest_crossing(g, jnp.log(2 * theta * 1e-4), jnp.log(2 * theta * 1e4), n_grid=65)
    assert not np.asarray(found65).all()


def test_fast_closed_forms_float32_match_float64():
    """ManosSakrison (Chebyshev start + one Newton step) and Eccentric (Chebyshev closed form of the cubic)
    in float32 agree with float64, including contrasts just above the peak threshold and distances
    next to the double root of Eccentric's cubic (where the old Newton iteration was 0.2 % off)."""
    rng = np.random.default_rng(3)
    n = 20_000
    c = np.concatenate([rng.uniform(0, 1, n), np.geomspace(1 / 250 * (1 + 1e-3), 0.05, 200)])
    theta = np.exp(rng.uniform(np.log(0.01), np.log(5), c.size))
    e = rng.uniform(0, 60, c.size)
    for make in (pm.ManosSakrison, lambda: pm.Eccentric(pm.ManosSakrison())):
        k32 = np.asarray(jax.jit(lambda *a, m=make(): m.imperceptible_distance(*a))(
            *(jnp.asarray(x, jnp.float32) for x in (c, theta, e))))
        with jax.enable_x64(True):
            k64 = np.asarray(jax.jit(lambda *a, m=make(): m.imperceptible_distance(*a))(c, theta, e))
        np.testing.assert_array_equal(k32 > 0, k64 > 0)
        np.testing.assert_allclose(k32, k64, rtol=1e-4, atol=1e-6)
    with jax.enable_x64(True):  # Eccentric next to the double root: largest root of k^3 - ku k^2 + k3 e^3
        m = pm.Eccentric(pm.ManosSakrison())
        k3, k1, e = 1.2e-5, 0.29, 40.0
        ku = np.cbrt(6.75 * k3 * e**3) * (1 + np.geomspace(1e-12, 1.0, 50))
        F = ku + k1 * e
        k = np.asarray(jax.vmap(lambda F: m.imperceptible_distance(
            1.0, F / (2 * m.csf.threshold_frequency(1.0)), e))(F))
        assert np.all(np.abs(k * k * (k - ku) + k3 * e**3) <= 1e-9 * ku**3)
        assert np.all(k >= (2 * k3) ** (1 / 3) * e * (1 - 1e-6))


@pytest.mark.parametrize("name", list(MODELS))
def test_float32_input_with_python_scalars_under_x64(name, x64):
    """A float64-built model, a float32 contrast and Python-scalar theta, e, v: the computation runs in
    float32 (weak scalars do not promote it) and the gradient w.r.t. the model's constants works
    (it used to fail: the model was cast to float64 and mixed dtypes in the solver loops)."""
    m = MODELS[name]
    k = m.imperceptible_distance(jnp.float32(0.5), 0.2, 3.0, 40.0)
    assert k.dtype == jnp.float32
    g = jax.grad(lambda mm: mm.imperceptible_distance(jnp.float32(0.5), 0.2, 3.0, 40.0))(m)
    leaves = [x for x in jax.tree_util.tree_leaves(g) if hasattr(x, "dtype")]
    assert leaves and all(np.isfinite(np.asarray(x)).all() for x in leaves)
    k64 = float(m.imperceptible_distance(0.5, 0.2, 3.0, 40.0))
    assert float(k) == pytest.approx(k64, rel=1e-4)

"""Analytic CSF models: published / hand-computed points, gradients, edges, jit/vmap, bad input."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import pmetric as pm

FACTORIES = {
    "manos": lambda: pm.ManosSakrison(),
    "kelly_abstract": lambda: pm.KellyAbstract(),
    "kelly1979": lambda: pm.KellySpatioTemporal("kelly1979"),
    "reddy_st": lambda: pm.KellySpatioTemporal("reddy"),
    "eccentric": lambda: pm.Eccentric(pm.KellySpatioTemporal()),
}


@pytest.fixture
def x64():
    with jax.enable_x64(True):
        yield


def test_manos_sakrison_published_peak():
    f = np.linspace(7.0, 9.0, 2001)
    a = np.asarray(pm.ManosSakrison.shape(f))
    assert a.max() == pytest.approx(0.9809, abs=5e-5)
    assert f[a.argmax()] == pytest.approx(7.89, abs=5e-3)  # float32: the peak is flat
    m = pm.ManosSakrison(peak_sensitivity=250.0)
    assert float(m.peak_frequency()) == pytest.approx(7.891, abs=1e-3)
    assert float(m.sensitivity(m.peak_frequency())) == pytest.approx(250.0, rel=1e-5)
    # the seed's printed 0.144 moves the peak to 7.89 * 0.114 / 0.144
    mp = pm.ManosSakrison(printed_constant=True)
    assert float(mp.peak_frequency()) == pytest.approx(7.8909 * 0.114 / 0.144, rel=1e-4)
    # hand-computed: A(20) = 2.6 (0.0192 + 2.28) exp(-2.28^1.1)
    assert float(pm.ManosSakrison.shape(20.0)) == pytest.approx(2.6 * 2.2992 * math.exp(-(2.28**1.1)), rel=1e-5)


def test_kelly_spatiotemporal_hand_points(x64):
    k = pm.KellySpatioTemporal("kelly1979")
    ref = (6.1 + 7.3 * abs(math.log10(10 / 3)) ** 3) * 10 * 25 * math.exp(-2 * 5 * 12 / 45.9)
    assert float(k.sensitivity(5.0, v=10.0)) == pytest.approx(ref, rel=1e-12)
    r = pm.KellySpatioTemporal("reddy")
    ref = (250.1 + 299.3 * abs(math.log10(10 / 3)) ** 3) * 10 * 4 * 10 ** (-5.5 * 2 * 12 / 45.9)
    assert float(r.sensitivity(2.0, v=10.0)) == pytest.approx(ref, rel=1e-12)
    # velocity below 0.1 deg/s is treated as 0.1
    assert float(k.sensitivity(3.0, v=0.0)) == float(k.sensitivity(3.0, v=0.1))
    assert float(k.peak_frequency(v=3.0)) == pytest.approx(45.9 / 5, rel=1e-12)
    with pytest.raises(ValueError, match="unknown Kelly constant set"):
        pm.KellySpatioTemporal("kelly1975")


def test_kelly_abstract_and_rovamo_virsu(x64):
    m = pm.KellyAbstract(delta=0.4, f0=2.0)  # the seed's own form: 1/c_T = 0.4 f^2 e^-f
    assert float(m.sensitivity(3.0)) == pytest.approx(0.4 * 9 * math.exp(-3), rel=1e-12)
    assert float(m.sensitivity(3.0, e=10.0)) == pytest.approx(0.4 * 3.9**2 * 9 * math.exp(-3 * 3.9), rel=1e-12)
    d = pm.KellyAbstract()
    assert float(d.sensitivity(4.0)) == pytest.approx(200.0, rel=1e-12)
    assert float(d.peak_frequency(10.0)) == pytest.approx(4.0 / 3.9, rel=1e-12)
    rv = pm.RovamoVirsu()
    assert float(rv(10.0)) == pytest.approx(1 / (1 + 2.9 + 0.012), rel=1e-12)
    assert float(pm.RovamoVirsu("linear")(10.0)) == pytest.approx(1 / 3.9, rel=1e-12)
    with pytest.raises(ValueError, match="unknown RovamoVirsu form"):
        pm.RovamoVirsu("quadratic")
    ecc = pm.Eccentric(pm.ManosSakrison())
    ms = pm.ManosSakrison()
    assert float(ecc.sensitivity(2.0, 10.0)) == pytest.approx(float(ms.sensitivity(2.0 * 3.912)), rel=1e-12)
    assert float(ecc.peak_frequency(10.0)) == pytest.approx(float(ms.peak_frequency()) / 3.912, rel=1e-12)
    with pytest.raises(ValueError, match="already depends on eccentricity"):
        pm.Eccentric(pm.KellyAbstract())


def _fd_check(fun, x0, rel=1e-5):
    g = jax.grad(fun)(x0)
    flat, unravel = jax.flatten_util.ravel_pytree(x0)
    gflat, _ = jax.flatten_util.ravel_pytree(g)
    for i in range(flat.size):
        h = 1e-6 * max(abs(float(flat[i])), 1.0)
        fp = fun(unravel(flat.at[i].add(h)))
        fm = fun(unravel(flat.at[i].add(-h)))
        fd = (float(fp) - float(fm)) / (2 * h)
        assert float(gflat[i]) == pytest.approx(fd, rel=rel, abs=1e-8), (i, gflat[i], fd)


@pytest.mark.parametrize("name", list(FACTORIES))
def test_gradients_match_finite_differences(name, x64):
    import jax.flatten_util  # noqa: F401

    model = FACTORIES[name]()
    # w.r.t. inputs
    _fd_check(lambda x: model.log_sensitivity(x[0], x[1], x[2]), jnp.array([6.0, 4.0, 2.0]))
    _fd_check(lambda x: model.threshold_frequency(x[0], x[1], x[2]), jnp.array([0.2, 4.0, 2.0]))
    # w.r.t. constants (every array field)
    params, static = eqx.partition(model, eqx.is_inexact_array)
    _fd_check(lambda p: eqx.combine(p, static).log_sensitivity(6.0, 4.0, 2.0), params)
    _fd_check(lambda p: eqx.combine(p, static).imperceptible_distance(0.2, 0.3, 4.0, 2.0), params, rel=1e-4)


@pytest.mark.parametrize("dtype", ["float32", "float64"])
@pytest.mark.parametrize("name", list(FACTORIES))
def test_finite_values_and_gradients_on_dense_grid(name, dtype):
    with jax.enable_x64(dtype == "float64"):
        model = FACTORIES[name]()
        dt = jnp.dtype(dtype)
        f = jnp.asarray(np.concatenate([[0.0], np.geomspace(1e-3, 1e3, 13)]), dt)[:, None, None, None]
        e = jnp.asarray([0.0, 1.0, 30.0, 120.0], dt)[None, :, None, None]
        v = jnp.asarray([0.0, 0.05, 3.0, 1000.0], dt)[None, None, :, None]
        c = jnp.asarray([0.0, 1e-3, 0.5, 1.0], dt)[None, None, None, :]
        for fn in (
            lambda f, e, v, c: model.threshold_contrast(f, e, v),
            lambda f, e, v, c: model.log_sensitivity(f, e, v),
            lambda f, e, v, c: model.threshold_frequency(c, e, v),
            lambda f, e, v, c: model.imperceptible_distance(c, f, e, v),
        ):
            val = jax.jit(fn)(f, e, v, c)
            assert val.dtype == dt
            assert np.isfinite(np.asarray(val)).all()
            grads = jax.jit(jax.grad(lambda *a: fn(*a).sum(), argnums=(0, 1, 2, 3)))(f, e, v, c)
            for g in grads:
                assert np.isfinite(np.asarray(g)).all()
        p = model.is_perceptible(c, f, e, v)
        assert p.dtype == jnp.bool_ and p.shape == (14, 4, 4, 4)
        assert not np.asarray(p)[..., 0].any()  # zero contrast is never visible


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_domain_edges_found_by_fuzzing(dtype):
    """Two failures a sweep of extreme inputs found (each fails on the code before the fix):
    KellyAbstract's sensitivity was NaN from f = 1.8e19 cycles/deg in float32 (alpha^2 overflowed against
    exp(-alpha) = 0) although its documented domain runs to 1e30; Eccentric's closed-form distance was
    NaN for a change under 1e-15 deg in float32 (its cubic's ku^3 underflowed: 0 / 0); the float32 case fails on
    the code before the fix. Now both are finite
    with finite gradients, and a foveal change's distance is the closed form k = 2 theta f*(c)."""
    with jax.enable_x64(dtype == "float64"):
        dt = jnp.dtype(dtype)
        f = jnp.asarray(np.concatenate([[0.0], np.geomspace(1e-30, 1e30, 61)]), dt)
        for model in (pm.KellyAbstract(), pm.ManosSakrison()):
            s = model.sensitivity(f, jnp.asarray(30.0, dt))
            g = jax.vmap(jax.grad(lambda x: model.sensitivity(x, jnp.asarray(30.0, dt))))(f)
            assert np.isfinite(np.asarray(s)).all() and np.isfinite(np.asarray(g)).all(), type(model).__name__
        ecc = pm.Eccentric(pm.ManosSakrison())
        th = jnp.asarray(np.geomspace(1e-37, 10.0, 39), dt)
        c = jnp.asarray(0.01, dt)
        for e in (0.0, 1e-20, 0.3, 10.0):
            e = jnp.asarray(e, dt)
            k = np.asarray(ecc.imperceptible_distance(c, th, e))
            dk = jax.vmap(jax.grad(ecc.imperceptible_distance, (1, 2)), (None, 0, None))(c, th, e)
            assert np.isfinite(k).all() and all(np.isfinite(np.asarray(x)).all() for x in dk)
        fstar = float(ecc.threshold_frequency(c, 0.0))
        k0 = np.asarray(ecc.imperceptible_distance(c, th, jnp.asarray(0.0, dt)))
        np.testing.assert_allclose(k0, 2.0 * np.asarray(th, np.float64) * fstar, rtol=1e-5)


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_gradients_at_the_fovea_and_at_tiny_frequencies(dtype):
    """Found by a second sweep: Eccentric's distance had d/de 64x too large at e = 0 (jnp.ldexp's derivative
    is 1 there, not 2^n) and NaN at subnormal e in float32; Barten's threshold gradient was -inf in float32
    for f of 1e-18 .. 3e-14 cycles/deg (1 / (1 - exp(-x)) overflowed). Now d/de at 0 is the slope just
    beside it and a finite difference's, and Barten's gradient is finite over f = 0 .. 1e3 and matches a
    finite difference where the series form takes over."""
    with jax.enable_x64(dtype == "float64"):
        dt = jnp.dtype(dtype)
        for inner in (pm.ManosSakrison(), pm.Barten()):
            ecc = pm.Eccentric(inner)
            k = lambda e: ecc.imperceptible_distance(jnp.asarray(0.05, dt), jnp.asarray(0.5, dt), e)  # noqa: E731
            g0 = float(jax.grad(k)(jnp.asarray(0.0, dt)))
            beside = float(jax.grad(k)(jnp.asarray(1e-6, dt)))
            fd = float((k(jnp.asarray(1e-3, dt)) - k(jnp.asarray(0.0, dt))) / 1e-3)
            assert g0 == pytest.approx(beside, rel=1e-5) and g0 == pytest.approx(fd, rel=2e-3)
            assert float(jax.grad(k)(jnp.asarray(1e-39, dt))) == pytest.approx(g0, rel=1e-5)  # subnormal in float32
        b = pm.Barten()
        f = jnp.asarray(np.concatenate([[0.0], np.geomspace(1e-30, 1e3, 34)]), dt)
        g = np.asarray(jax.vmap(jax.grad(b.threshold_contrast))(f))
        assert np.isfinite(g).all()
        for f0 in (1e-6, 1e-3, 0.05):  # x = (f / u0)^2 below and above the series' 1e-4
            x = jnp.asarray(f0, dt)
            h = f0 * (1e-3 if dtype == "float32" else 1e-6)
            fd = float((b.threshold_contrast(x + h) - b.threshold_contrast(x - h)) / (2 * h))
            assert float(jax.grad(b.threshold_contrast)(x)) == pytest.approx(fd, rel=1e-2 if dtype == "float32" else 1e-6)


@pytest.mark.parametrize("name", list(FACTORIES))
def test_jit_vmap_match_eager(name, x64):
    model = FACTORIES[name]()
    rng = np.random.default_rng(1)
    c, f, e, v = rng.uniform(0, 1, 16), rng.uniform(0.1, 50, 16), rng.uniform(0, 40, 16), rng.uniform(0, 50, 16)
    eager = np.asarray(model.imperceptible_distance(c, f, e, v))
    jitted = np.asarray(jax.jit(lambda *a: model.imperceptible_distance(*a))(c, f, e, v))
    vm = np.asarray(jax.vmap(model.imperceptible_distance)(c, f, e, v))
    np.testing.assert_allclose(jitted, eager, rtol=1e-12)
    np.testing.assert_allclose(vm, eager, rtol=1e-9)
    pe = np.asarray(model.is_perceptible(c, f, e, v))
    np.testing.assert_array_equal(np.asarray(jax.vmap(model.is_perceptible)(c, f, e, v)), pe)


@pytest.mark.parametrize("name", list(FACTORIES))
def test_bad_input_raises_outside_jit_and_propagates_under_jit(name):
    model = FACTORIES[name]()
    with pytest.raises(ValueError, match="f must be >= 0"):
        model.sensitivity(-1.0)
    with pytest.raises(ValueError, match="f contains NaN"):
        model.threshold_contrast(np.nan)
    with pytest.raises(ValueError, match="c must be >= 0"):
        model.is_perceptible(-0.1, 3.0)
    with pytest.raises(ValueError, match="do not broadcast"):
        model.is_perceptible(np.ones(3), np.ones(4))
    with pytest.raises(ValueError, match="theta"):
        model.imperceptible_distance(0.5, -1.0)
    with pytest.raises(ValueError, match="must be a number"):
        model.sensitivity("3")
    # documented behaviour under jit: NaN propagates, NaN is never perceptible
    assert np.isnan(float(jax.jit(lambda x: model.threshold_contrast(x))(jnp.nan)))
    assert not bool(jax.jit(lambda a, b: model.is_perceptible(a, b))(jnp.nan, 3.0))


def test_constructor_rejects_bad_constants():
    with pytest.raises(ValueError, match="peak_sensitivity must be > 0"):
        pm.ManosSakrison(-1.0)
    with pytest.raises(ValueError, match="delta must be finite"):
        pm.KellyAbstract(delta=np.nan)


# ------------------------------------------------------------------------------ the CSFModel contract
class _OnlyLog(pm.CSFModel):
    """A model implementing nothing but the ``_log_sensitivity`` hook (peak 1 / e^2 s0 at f = 2)."""

    s0: jax.Array
    inputs = ("f", "e")

    def __init__(self, s0=400.0):
        self.s0 = jnp.asarray(s0)

    def _log_sensitivity(self, f, e, v):
        from pmetric._numerics import log_guard

        return jnp.log(self.s0) + 2.0 * log_guard(f) - f - 0.05 * e


class _Legacy(pm.CSFModel):
    """Written for the former contract: overrides the public ``sensitivity`` only."""

    def sensitivity(self, f, e=0.0, v=0.0):
        f = jnp.asarray(f)
        return 300.0 * f * jnp.exp(-f / 3.0)


def test_minimal_subclass_gets_every_public_method(x64):
    m = _OnlyLog()
    c, th = np.array([0.05, 0.2, 1.0]), np.array([0.1, 0.5, 1.0])
    e, v = np.array([0.0, 5.0, 20.0]), 1.0
    f = np.array([0.5, 2.0, 8.0])
    ls = np.asarray(m.log_sensitivity(f, e, v))
    np.testing.assert_allclose(ls, np.log(400.0) + 2 * np.log(f) - f - 0.05 * e, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(m.sensitivity(f, e, v)), np.exp(ls), rtol=1e-12)
    np.testing.assert_allclose(np.asarray(m.stimulus_sensitivity(f, e, v, luminance=50.0)), np.exp(ls), rtol=1e-12)
    np.testing.assert_allclose(np.asarray(m.threshold_contrast(f, e, v)), np.exp(-ls), rtol=1e-12)
    np.testing.assert_allclose(np.asarray(m.peak_frequency(e, v)), 2.0, rtol=1e-5)
    p = np.asarray(m.is_perceptible(c, f, e, v))
    assert p.dtype == bool and p.shape == (3,)
    tf = np.asarray(m.threshold_frequency(c, e, v))
    ok = tf > 2.1
    assert ok.any()
    np.testing.assert_allclose(np.asarray(m.threshold_contrast(tf, e, v))[ok], c[ok], rtol=1e-8)
    k = np.asarray(m.imperceptible_distance(c, th, e, v))
    assert k.shape == (3,) and np.isfinite(k).all() and (k >= 0).all()
    # the answer's definition: perceptible just below k, imperceptible just above
    for kk, expect in ((k * (1 - 1e-6), True), (k * (1 + 1e-6), False)):
        got = np.asarray(m.is_perceptible(c, kk / (2 * th), e / kk, v / kk))
        assert (got[k > 0] == expect).all()
    # broadcasting: scalar defaults give the broadcast shape
    assert m.threshold_contrast(np.ones((2, 1)), np.zeros(3)).shape == (2, 3)
    # gradients flow through every hook's generic default
    g = jax.grad(lambda cc: jnp.sum(m.imperceptible_distance(cc, th, e, v)))(jnp.asarray(c))
    assert np.isfinite(np.asarray(g)).all()


@pytest.mark.parametrize("call", [
    lambda m: m.sensitivity(-1.0),
    lambda m: m.log_sensitivity(np.nan),
    lambda m: m.stimulus_sensitivity(1.0, -2.0),
    lambda m: m.threshold_contrast(1.0, 0.0, -1.0),
    lambda m: m.peak_frequency(np.nan),
    lambda m: m.is_perceptible(-0.1, 1.0),
    lambda m: m.threshold_frequency(0.5, np.nan),
    lambda m: m.imperceptible_distance(0.5, -1.0),
    lambda m: m.imperceptible_distance(np.ones(3), np.ones(4)),
    lambda m: m.sensitivity("x"),
])
def test_public_methods_check_inputs_with_plod_error(call):
    for m in (_OnlyLog(), pm.KellyAbstract(), pm.ReddyAcuity()):  # (a legacy subclass overriding a
        # public method bypasses its checks)
        with pytest.raises(pm.PlodError):
            call(m)


def test_model_without_a_hook_is_abstract_and_legacy_subclass_works():
    class _Nothing(pm.CSFModel):
        pass

    with pytest.raises(TypeError):
        _Nothing()
    with pytest.raises(TypeError):
        pm.CSFModel()
    m = _Legacy()
    f = np.array([1.0, 3.0, 10.0])
    np.testing.assert_allclose(np.asarray(m.log_sensitivity(f)), np.log(300.0 * f * np.exp(-f / 3.0)), rtol=1e-6)
    np.testing.assert_allclose(float(m.peak_frequency()), 3.0, rtol=5e-3)  # float32: a flat peak
    assert float(m.imperceptible_distance(0.1, 0.5)) > 0


@pytest.mark.parametrize("name", ["kelly_abstract", "kelly1979", "eccentric", "manos"])
def test_jit_of_bound_method(name):
    """``jax.jit(model.imperceptible_distance)`` works (the bound method hashes by the model's identity),
    as do ``eqx.filter_jit`` of it and the lambda form; the model keeps equinox's value semantics."""
    m = FACTORIES[name]()
    c, th = jnp.asarray([0.05, 0.5]), jnp.asarray([0.2, 1.0])
    e, v = jnp.asarray([0.0, 10.0]), jnp.asarray([1.0, 4.0])
    want = np.asarray(m.imperceptible_distance(c, th, e, v))
    np.testing.assert_allclose(np.asarray(jax.jit(m.imperceptible_distance)(c, th, e, v)), want, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(eqx.filter_jit(m.imperceptible_distance)(c, th, e, v)), want, rtol=1e-6)
    lam = jax.jit(lambda mm, cc, tt: mm.imperceptible_distance(cc, tt, e, v))
    np.testing.assert_allclose(np.asarray(lam(m, c, th)), want, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(jax.jit(m.is_perceptible)(c, th, e, v)), np.asarray(m.is_perceptible(c, th, e, v)))
    # bound methods compare like Python's: same function and the same model object
    assert m.imperceptible_distance == m.imperceptible_distance
    assert hash(m.imperceptible_distance) == hash(m.imperceptible_distance)
    twin = FACTORIES[name]()
    assert m.imperceptible_distance != twin.imperceptible_distance
    assert m.imperceptible_distance != m.is_perceptible
    # ... while models keep value equality and stay unhashable (array fields), as in equinox
    assert bool(m == twin)
    with pytest.raises(TypeError):
        hash(m)
    # a bound method is still a pytree: gradients with respect to the model through it
    g = eqx.filter_grad(lambda bm: jnp.sum(bm(c, th, e, v)))(m.imperceptible_distance)
    assert all(np.isfinite(np.asarray(x)).all() for x in jax.tree_util.tree_leaves(g))

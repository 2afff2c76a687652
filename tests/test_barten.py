"""Tests of pmetric.Barten: published check values, closed forms, edges, gradients, generic solvers."""

from __future__ import annotations

import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pmetric import Barten


def ref_barten(u, sigma, E, X0, Y0, k=3.0, T=0.1, Xmax=12.0, Ymax=12.0, Nmax=15.0, eta=0.03, p=1.2274e6,
               phi0=3e-8, u0=7.0):
    """Barten 1999 eq. 3.26 (2-D field), straight in the linear domain (numpy float64)."""
    mopt = np.exp(-2 * np.pi**2 * sigma**2 * u**2)
    X = (1 / X0**2 + 1 / Xmax**2 + u**2 / Nmax**2) ** -0.5
    Y = (1 / Y0**2 + 1 / Ymax**2 + u**2 / Nmax**2) ** -0.5
    return (mopt / k) / np.sqrt(2 / (X * Y * T) * (1 / (eta * p * E) + phi0 / (1 - np.exp(-((u / u0) ** 2)))))


def test_published_check_values(dtype):
    m = Barten(p=1.2e6)
    s = m.illuminance_sensitivity(jnp.array([4.0, 8.0, 4.0]), jnp.array([65.0, 65.0, 130.0]), 0.01, 60.0, 60.0)
    assert s.dtype == jnp.dtype(dtype)
    rtol = 1e-9 if dtype == "float64" else 2e-6
    np.testing.assert_allclose(np.asarray(s, np.float64), [352.7613421, 177.7063388, 455.1713158], rtol=rtol)


def test_ancillary_closed_forms(x64):
    m = Barten()
    # pupil: 5 mm at L * X0 * Y0 = 40^2, tending to 2 and 8 mm at the extremes
    assert float(m.pupil_diameter(1.0, 1600.0)) == pytest.approx(5.0)
    assert float(m.pupil_diameter(100.0, 3600.0)) == pytest.approx(5 - 3 * math.tanh(0.4 * math.log10(225.0)))
    for L, A in [(1e4, 1e3), (1e-3, 1e-3), (0.5, 7.0)]:
        d = float(m.pupil_diameter(L, A))
        assert d == pytest.approx(5 - 3 * math.tanh(0.4 * math.log10(L * A / 1600)), rel=1e-12)
        assert 2.0 < d < 8.0
    # Troland with the Stiles-Crawford correction; without it pi d^2 / 4 L
    d = 2.1
    assert float(m.retinal_illuminance(100.0, d)) == pytest.approx(
        math.pi * d**2 / 4 * 100 * (1 - (d / 9.7) ** 2 + (d / 12.4) ** 4))
    assert float(Barten(stiles_crawford=False).retinal_illuminance(100.0, d)) == pytest.approx(
        math.pi * d**2 / 4 * 100)
    assert float(m.optical_sigma(2.1)) == pytest.approx(math.hypot(0.5 / 60, 0.08 / 60 * 2.1))
    # the stimulus path equals the E-parametrized formula with the derived pupil, E and sigma
    L, A, f = 30.0, 4.0, np.array([0.5, 3.0, 20.0])
    dd = float(m.pupil_diameter(L, A))
    E = float(m.retinal_illuminance(L, dd))
    want = ref_barten(f, math.hypot(0.5 / 60, 0.08 / 60 * dd), E, 2.0, 2.0)
    np.testing.assert_allclose(m.stimulus_sensitivity(f, luminance=L, area=A), want, rtol=1e-10)


@settings(max_examples=30, deadline=None)
@given(lu=st.floats(-2.0, 1.7), lE=st.floats(-2.0, 5.0), sig=st.floats(0.003, 0.03), lX=st.floats(-1.0, 2.0),
       lY=st.floats(-1.0, 2.0))
def test_matches_linear_formula(lu, lE, sig, lX, lY):
    u, E, X0, Y0 = 10**lu, 10**lE, 10**lX, 10**lY
    want = ref_barten(u, sig, E, X0, Y0)
    got = float(Barten().illuminance_sensitivity(np.float32(u), np.float32(E), np.float32(sig), np.float32(X0),
                                                 np.float32(Y0)))
    assert got == pytest.approx(want, rel=2e-4)


def test_defaults_and_ignored_inputs():
    m = Barten()
    f = np.array([1.0, 4.0, 16.0])
    np.testing.assert_allclose(m.sensitivity(f), m.stimulus_sensitivity(f, luminance=100.0, area=3600.0), rtol=1e-6)
    # e and v are ignored (foveal, static) but broadcast into the result
    s = m.sensitivity(f[:, None], np.array([0.0, 10.0, 30.0]), 5.0)
    assert s.shape == (3, 3)
    np.testing.assert_allclose(s, np.broadcast_to(m.sensitivity(f)[:, None], (3, 3)), rtol=1e-6)
    np.testing.assert_allclose(m.stimulus_sensitivity(f, luminance=np.nan, area=np.nan), m.sensitivity(f), rtol=1e-6)
    assert Barten.inputs == ("f", "luminance", "area")
    # larger fields and brighter backgrounds raise sensitivity (Barten 1999 figs 3.x)
    s_small, s_big = m.stimulus_sensitivity(4.0, luminance=100.0, area=[0.25, 100.0])
    assert s_big > s_small
    s_dim, s_bright = m.stimulus_sensitivity(4.0, luminance=[0.1, 100.0], area=100.0)
    assert s_bright > s_dim


@settings(max_examples=40, deadline=None)
@given(
    f=st.one_of(st.sampled_from([1e-3, 1e3, 60.0]), st.floats(1e-3, 1e3)),
    L=st.one_of(st.sampled_from([1e-3, 1e4]), st.floats(1e-3, 1e4)),
    A=st.one_of(st.sampled_from([1e-3, 1e3]), st.floats(1e-3, 1e3)),
    e=st.floats(0.0, 120.0), v=st.floats(0.0, 1e3),
)
def test_finite_values_and_gradients_on_domain(f, L, A, e, v):
    m = Barten()
    x = jnp.array([f, e, v, L, A], jnp.float32)
    fun = lambda mm, xx: mm.log_sensitivity(xx[0], xx[1], xx[2], xx[3], xx[4])  # noqa: E731
    assert np.isfinite(float(fun(m, x)))
    gx = jax.grad(lambda xx: fun(m, xx))(x)
    gm = eqx.filter_grad(fun)(m, x)
    leaves = [gx] + jax.tree_util.tree_leaves(eqx.filter(gm, eqx.is_inexact_array))
    assert all(np.isfinite(np.asarray(g)).all() for g in leaves)
    s = float(m.stimulus_sensitivity(f, e, v, L, A))
    assert np.isfinite(s) and s > 0
    assert np.isfinite(float(m.threshold_contrast(f, e, v)))


def test_gradients_match_finite_differences(x64):
    m = Barten()
    for p in [(4.0, 0.0, 0.0, 100.0, 3600.0), (0.2, 0.0, 0.0, 0.5, 2.0), (25.0, 0.0, 0.0, 2000.0, 0.3)]:
        x0 = np.array(p)
        g = np.asarray(jax.grad(lambda x: m.log_sensitivity(*x))(jnp.asarray(x0)))
        for i in (0, 3, 4):
            h = 1e-6 * abs(x0[i])
            xp, xm = x0.copy(), x0.copy()
            xp[i] += h
            xm[i] -= h
            fd = (float(m.log_sensitivity(*xp)) - float(m.log_sensitivity(*xm))) / (2 * h)
            assert g[i] == pytest.approx(fd, rel=1e-5, abs=1e-8), (p, i)
        assert g[1] == 0 and g[2] == 0
    x = (4.0, 0.0, 0.0, 30.0, 10.0)
    gm = eqx.filter_grad(lambda mm: mm.log_sensitivity(*x))(m)
    for name in Barten.param_bounds:
        val = float(getattr(m, name))
        h = 1e-6 * abs(val)
        mp = eqx.tree_at(lambda mm: getattr(mm, name), m, jnp.asarray(val + h))
        mn = eqx.tree_at(lambda mm: getattr(mm, name), m, jnp.asarray(val - h))
        fd = (float(mp.log_sensitivity(*x)) - float(mn.log_sensitivity(*x))) / (2 * h)
        assert float(getattr(gm, name)) == pytest.approx(fd, rel=1e-5, abs=1e-9 / abs(val)), name


def test_jit_vmap_agree_with_eager(dtype):
    m = Barten()
    f = jnp.asarray(np.logspace(-1, 1.5, 5), dtype)
    L = jnp.asarray([0.01, 1.0, 10.0, 100.0, 1e4], dtype)
    A = jnp.asarray([0.01, 1.0, 10.0, 100.0, 1e3], dtype)
    eager = m.stimulus_sensitivity(f, 0.0, 0.0, L, A)
    assert eager.dtype == jnp.dtype(dtype)
    jitted = eqx.filter_jit(lambda mm, a, b, c: mm.stimulus_sensitivity(a, 0.0, 0.0, b, c))(m, f, L, A)
    vm = jax.vmap(lambda a, b, c: m.stimulus_sensitivity(a, 0.0, 0.0, b, c))(f, L, A)
    np.testing.assert_allclose(jitted, eager, rtol=1e-5)
    np.testing.assert_allclose(vm, eager, rtol=1e-5)


def test_bad_input_errors():
    m = Barten()
    with pytest.raises(ValueError, match="f"):
        m.sensitivity(-4.0)
    with pytest.raises(ValueError, match="NaN"):
        m.sensitivity(np.nan)
    with pytest.raises(ValueError, match="area"):
        m.stimulus_sensitivity(4.0, area=-1.0)
    with pytest.raises(ValueError, match="broadcast"):
        m.stimulus_sensitivity(np.ones(2), luminance=np.ones(3))
    with pytest.raises(ValueError, match="E"):
        m.illuminance_sensitivity(4.0, -1.0, 0.01, 60.0)
    with pytest.raises(ValueError, match="k"):
        Barten(k=jnp.ones(2))
    with pytest.raises(ValueError, match="luminance"):
        Barten(luminance=-1.0)
    names = {f.name for f in dataclasses.fields(Barten)}
    for name, (lo, hi) in Barten.param_bounds.items():
        assert name in names
        val = float(getattr(m, name))
        assert (lo is None or val >= lo) and (hi is None or val <= hi), name


def test_generic_solvers_meet_definitions():
    m = Barten()
    c = jnp.array([0.005, 0.05, 0.5])
    tf = np.asarray(m.threshold_frequency(c))
    np.testing.assert_allclose(np.asarray(m.threshold_contrast(tf)), np.asarray(c), rtol=1e-3)
    grid = np.logspace(-1, 2.5, 4001)
    ctg = np.asarray(m.threshold_contrast(grid))
    for ci, t in zip(np.asarray(c), tf):
        assert t == pytest.approx(grid[ctg <= ci].max(), rel=3e-3)
    # imperceptible distance: largest k at which c (size theta) is perceptible (f = k / (2 theta))
    theta = 0.05
    k = np.asarray(m.imperceptible_distance(c, theta))
    fpk = grid[np.argmin(ctg)]
    ks = np.logspace(-2, 3, 3001)
    ct = np.asarray(m.threshold_contrast(np.maximum(ks / (2 * theta), fpk)))
    for ci, ki in zip(np.asarray(c), k):
        assert ki == pytest.approx(ks[ct <= ci].max(), rel=5e-3)


# ------------------------------------------------------------------ fast solvers (concrete constants)
from pmetric import CSFModel  # noqa: E402
from pmetric._barten_limb import _START_FIT, _limb  # noqa: E402

_generic_tf = eqx.filter_jit(lambda mm, c: mm.threshold_frequency(c))  # traced constants: generic solvers
_generic_k = eqx.filter_jit(lambda mm, c, t: mm.imperceptible_distance(c, t))
_generic_p = eqx.filter_jit(lambda mm, c, f: mm.is_perceptible(c, f))


def _contrasts(rng, n=400):
    """Random contrasts over the visible range and beyond (c > 1 up to 1e40), plus edge values."""
    return np.concatenate([rng.uniform(0, 1, n), np.exp(rng.uniform(-9, 0, n)), np.exp(rng.uniform(0, 92, 40)),
                           [0.0, 1e-30, 1e-8, 1.0, 1e29, 1e31]])


def test_fast_path_is_taken_and_built_to_its_targets():
    m = Barten()
    for dtype in ("float32", "float64"):
        limb = m._limb_of(jnp.dtype(dtype))
        assert limb is not None and limb.err <= 1.5 * _START_FIT[dtype][1]
        assert 1 <= len(limb.coeffs) <= 8
    assert m._limb_of(jnp.float16) is None
    # traced constants: no fast path (the generic solvers run)
    eqx.filter_jit(lambda mm: (mm._limb_of(jnp.float32) is None) or pytest.fail("traced fast path"))(m)


def test_fast_peak_is_the_root_of_the_slope(x64):
    m = Barten()
    fp = float(m.peak_frequency())
    dlog = jax.grad(lambda lf: m.log_sensitivity(jnp.exp(lf)))
    assert abs(float(dlog(jnp.log(fp)))) < 1e-9
    assert float(dlog(jnp.log(fp * 0.999))) > 0 > float(dlog(jnp.log(fp * 1.001)))
    # the generic golden-section search (traced constants) agrees to its precision (~1e-5)
    assert float(eqx.filter_jit(lambda mm: mm.peak_frequency())(m)) == pytest.approx(fp, rel=2e-5)
    assert np.asarray(m.peak_frequency(np.zeros((2, 3)), 1.0)).shape == (2, 3)


def test_fast_threshold_frequency_matches_generic_and_definition(x64):
    rng = np.random.default_rng(0)
    m = Barten()
    c = _contrasts(rng)
    tf = np.asarray(m.threshold_frequency(c))
    # the generic root solver of CSFModel (same exact peak) and the fully generic traced path
    gen = np.asarray(CSFModel._threshold_frequency(m, jnp.asarray(c), jnp.zeros(()), jnp.zeros(())))
    np.testing.assert_allclose(tf, gen, rtol=1e-7)
    ct_peak = float(m.threshold_contrast(m.peak_frequency()))
    away = np.abs(np.log(np.maximum(c, 1e-300) / ct_peak)) > 1e-6  # the generic peak is ~1e-5 off
    np.testing.assert_allclose(tf[away], np.asarray(_generic_tf(m, c))[away], rtol=1e-7)
    # definition: c_T(tf) = c on the falling limb; 0 where invisible; 1e4 where visible up to 1e4
    ls = lambda f: np.asarray(m.log_sensitivity(f))  # noqa: E731
    lc = np.log(np.maximum(c, 1e-30))
    inside = (tf > 0) & (tf < 1e4)
    assert inside.sum() > 700
    np.testing.assert_allclose(lc[inside] + ls(tf[inside]), 0.0, atol=1e-10)
    assert np.all(lc[inside] + ls(tf[inside] * (1 + 1e-6)) < 0)
    np.testing.assert_array_equal(tf == 0, c < ct_peak)
    np.testing.assert_array_equal(tf == 1e4, c >= 1e30)
    assert np.all(tf[inside] >= float(m.peak_frequency()))
    # brute force: the largest frequency of a dense grid at which c is visible
    grid = np.logspace(np.log10(float(m.peak_frequency())), 4, 20001)
    lsg = ls(grid)
    for ci, ti in zip(c[inside][::40], tf[inside][::40]):
        assert ti == pytest.approx(grid[lsg >= -np.log(ci)].max(), rel=1e-3)


def test_fast_threshold_frequency_near_the_peak(dtype):
    m = Barten()
    ct_peak = float(m.threshold_contrast(m.peak_frequency()))
    fp = float(m.peak_frequency())
    d = np.array([0.0, 1e-12, 1e-8, 1e-6, 1e-4, 1e-2])
    c = (ct_peak * np.exp(d)).astype(dtype)
    tf = np.asarray(m.threshold_frequency(c))
    assert np.all(np.isfinite(tf)) and np.all(tf >= fp * (1 - 1e-6))  # c_T(peak) itself is visible
    z = jnp.zeros((), dtype)
    gen = np.asarray(jax.jit(lambda cc: CSFModel._threshold_frequency(m, cc, z, z))(c))
    # at the peak ln S is flat: float32 rounding of ln S (~1e-6) moves the root by ~sqrt(1e-6 / 0.35) = 0.2 %
    np.testing.assert_allclose(tf, gen, rtol=1e-6 if dtype == "float64" else 3e-3)
    g = jax.jit(jax.vmap(jax.grad(lambda cc: m.threshold_frequency(cc))))(jnp.asarray(c))
    assert np.all(np.isfinite(np.asarray(g)))


def test_fast_imperceptible_distance_matches_generic_and_definition(x64):
    rng = np.random.default_rng(1)
    m = Barten()
    c = _contrasts(rng, 200)
    theta = np.exp(rng.uniform(np.log(1e-4), np.log(50.0), c.size))
    theta[:3] = [0.0, 1e-12, 1e4]
    e, v = rng.uniform(0, 60, c.size), rng.uniform(0, 100, c.size)
    k = np.asarray(jax.jit(lambda *a: m.imperceptible_distance(*a))(c, theta, e, v))
    np.testing.assert_allclose(k, 2 * theta * np.asarray(m.threshold_frequency(c)), rtol=1e-15)
    assert k[0] == 0
    ct_peak = float(m.threshold_contrast(m.peak_frequency()))
    away = np.abs(np.log(np.maximum(c, 1e-300) / ct_peak)) > 1e-6
    np.testing.assert_allclose(k[away], np.asarray(_generic_k(m, c, theta))[away], rtol=1e-7)
    # perceptible just inside k, imperceptible just beyond (f = k / (2 theta))
    inside = (k > 0) & (k < 2e4 * theta)
    f_at = k[inside] / (2 * theta[inside])
    assert np.all(np.asarray(m.is_perceptible(c[inside], f_at * (1 - 1e-9))))
    assert not np.any(np.asarray(m.is_perceptible(c[inside], f_at * (1 + 1e-6))))


def test_fast_is_perceptible_matches_the_definition(dtype):
    rng = np.random.default_rng(2)
    m = Barten()
    n = 20000
    c = np.concatenate([rng.uniform(0, 1, n), np.exp(rng.uniform(-9, 80, 200)), [0.0, 1e30, 1e38, 0.5, 0.5, 0.5]])
    f = np.concatenate([np.exp(rng.uniform(np.log(1e-4), np.log(1e4), n + 200)), [1.0, 1e6, 3.0, 0.0, 1e30, 1e-30]])
    c, f = c.astype(dtype), f.astype(dtype)
    got = np.asarray(jax.jit(lambda a, b: m.is_perceptible(a, b, 0.0, np.zeros(3)[:, None]))(c, f))
    assert got.shape == (3, c.size) and got.dtype == bool
    with x64_on():
        m64 = Barten()
        fp = float(m64.peak_frequency())
        margin = (np.log(np.maximum(c.astype(float), 1e-30))
                  + np.asarray(m64.log_sensitivity(np.maximum(f.astype(float), fp))))
    want = margin >= 0
    tol = 1e-5 if dtype == "float32" else 1e-12
    bad = (got[0] != want) & (np.abs(margin) > tol)
    assert not bad.any(), (c[bad][:5], f[bad][:5], margin[bad][:5])
    assert got[0][-6:].tolist() == [False, True, True, True, False, True]
    # the generic test (traced constants) agrees away from the boundary
    gen = np.asarray(_generic_p(m, c, f))
    assert not ((gen != got[0]) & (np.abs(margin) > tol)).any()


def x64_on():
    from conftest import x64_mode
    return x64_mode(True)


def test_fast_gradients_match_finite_differences(x64):
    m = Barten()
    k_of = lambda mm, c, t: mm.imperceptible_distance(c, t)  # noqa: E731
    c0 = np.array([0.003, 0.02, 0.4, 0.9, 5.0])
    t0 = np.array([0.05, 1.0, 0.01, 3.0, 0.2])
    gc, gt = jax.jit(jax.vmap(jax.grad(lambda c, t: k_of(m, c, t), argnums=(0, 1))))(c0, t0)
    kk = jax.jit(lambda c, t: k_of(m, c, t))
    h = 1e-6 * c0
    np.testing.assert_allclose(gc, (kk(c0 + h, t0) - kk(c0 - h, t0)) / (2 * h), rtol=1e-6)
    np.testing.assert_allclose(gt, kk(c0, t0) / t0, rtol=1e-12)
    # the traced (generic) path gives the same derivative
    gc_gen = jax.vmap(jax.grad(lambda mm, c, t: _generic_k(mm, c, t), argnums=1), in_axes=(None, 0, 0))(m, c0, t0)
    np.testing.assert_allclose(gc, gc_gen, rtol=1e-7)
    # model constants: the gradient (traced constants) vs finite differences of the fast path
    c0, t0 = 0.004, 0.3  # f* = 6 cycles/deg: every term of the formula matters
    gm = eqx.filter_grad(lambda mm: k_of(mm, c0, t0))(m)
    for name in ("sigma_0", "k", "n_max", "phi_0", "u_0"):
        val = float(getattr(m, name))
        h = 1e-5 * val
        kp = float(k_of(eqx.tree_at(lambda mm: getattr(mm, name), m, jnp.asarray(val + h)), c0, t0))
        kn = float(k_of(eqx.tree_at(lambda mm: getattr(mm, name), m, jnp.asarray(val - h)), c0, t0))
        assert float(getattr(gm, name)) == pytest.approx((kp - kn) / (2 * h), rel=1e-5), name


@pytest.mark.parametrize("x64_", [False, True])
def test_fast_paths_finite_values_and_gradients(x64_):
    with (x64_on() if x64_ else _nullcontext()):
        m = Barten()
        ct_peak = float(m.threshold_contrast(m.peak_frequency()))
        c = jnp.asarray([0.0, 1e-30, 1e-8, ct_peak * (1 - 1e-7), ct_peak, ct_peak * (1 + 1e-7), 0.01, 0.5, 1.0,
                         1e10, 1e30, 1e36])
        theta = jnp.asarray([0.0, 1e-6, 0.01, 5.0, 1e3])
        cc, tt = (x.ravel() for x in jnp.meshgrid(c, theta))
        fns = {
            "k": lambda a, b: m.imperceptible_distance(a, b),
            "tf": lambda a, b: m.threshold_frequency(a) * b,
        }
        for name, fn in fns.items():
            val = jax.jit(fn)(cc, tt)
            ga, gb = jax.jit(jax.vmap(jax.grad(fn, argnums=(0, 1))))(cc, tt)
            for x in (val, ga, gb):
                assert x.dtype == cc.dtype
                assert np.all(np.isfinite(np.asarray(x))), name
        p = jax.jit(lambda a, f: m.is_perceptible(a, f))(cc, jnp.abs(tt))
        assert p.dtype == bool


def _nullcontext():
    import contextlib
    return contextlib.nullcontext()


def test_traced_constants_and_mixed_dtypes(x64):
    m = Barten()  # float64 constants
    c32 = np.array([0.002, 0.01, 0.1, 0.7], np.float32)
    # float32 inputs: computed in float32 with the fast path, also under jit with the model closed over
    calls = []
    out = jax.jit(lambda c: (calls.append(m._limb_of(jnp.float32) is not None), m.threshold_frequency(c))[1])(c32)
    assert out.dtype == jnp.float32 and calls == [True]
    np.testing.assert_allclose(out, m.threshold_frequency(c32.astype(np.float64)), rtol=1e-5)
    k32 = jax.jit(lambda c: m.imperceptible_distance(c, 0.1))(c32)
    assert k32.dtype == jnp.float32
    # traced constants in float32 and float64 (generic path) agree with the fast path
    for c in (c32, c32.astype(np.float64)):
        np.testing.assert_allclose(_generic_tf(m, c), m.threshold_frequency(c), rtol=2e-5)
        np.testing.assert_array_equal(_generic_p(m, c, np.full(4, 20.0, c.dtype)), m.is_perceptible(c, 20.0))
    # gradient w.r.t. the constants with float32 inputs and a float64-built model (generic path in float32)
    g = eqx.filter_jit(eqx.filter_grad(lambda mm, cc: mm.imperceptible_distance(cc, 0.1).sum()))(m, c32)
    assert all(np.isfinite(float(x)) for x in jax.tree_util.tree_leaves(eqx.filter(g, eqx.is_inexact_array)))
    # vmap over a constant (batched tracer: generic path)
    s0 = jnp.array([0.006, 0.012])
    got = jax.jit(jax.vmap(lambda s: Barten(sigma_0=s).threshold_frequency(0.05)))(s0)
    want = [float(Barten(sigma_0=s).threshold_frequency(0.05)) for s in (0.006, 0.012)]
    np.testing.assert_allclose(got, want, rtol=1e-7)


def test_fast_path_on_other_constants_and_fallback(x64):
    rng = np.random.default_rng(3)
    c = _contrasts(rng, 100)
    d = Barten()
    for i in range(2):
        kw = {n: float(getattr(d, n)) * math.exp(rng.uniform(-1.0, 1.0)) for n in Barten.param_bounds}
        m = Barten(**kw, luminance=float(10 ** rng.uniform(-2, 4)), area=float(10 ** rng.uniform(-2, 3)),
                   stiles_crawford=bool(i % 2))
        assert m._limb_of(jnp.float64) is not None
        ct_peak = float(m.threshold_contrast(m.peak_frequency()))
        away = np.abs(np.log(np.maximum(c, 1e-300) / ct_peak)) > 1e-6
        np.testing.assert_allclose(np.asarray(m.threshold_frequency(c))[away], np.asarray(_generic_tf(m, c))[away],
                                   rtol=1e-7)
    # a peak sensitivity beyond e^68 (the 1e-30 floors would matter): no fast path, generic results. The
    # constructor refuses k below its bound (1e-3); such constants arise only by editing a model (tree_at)
    import equinox as eqx

    m = eqx.tree_at(lambda b: b.k, Barten(), jnp.asarray(1e-31, Barten().k.dtype))
    assert m._limb_of(jnp.float64) is None and _limb.cache_info().currsize > 0
    np.testing.assert_allclose(m.threshold_frequency(c[:50]), _generic_tf(m, c[:50]), rtol=1e-12)

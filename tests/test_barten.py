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

"""Tests of pmetric.StelaCSF: published reference values, an independent numpy port, edges, gradients."""

from __future__ import annotations

import dataclasses
import csv

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import pmetric
from pmetric import StelaCSF

from conftest import x64_mode


# ---------------------------------------------------------------- an independent numpy reference
# Written straight from CSF_stelaCSF.m / CSF_base.get_lum_dep (gfxdisp/stelaCSF), linear domain.
P2022 = dict(
    Ss=[68.9501, 59.5023, 0.164274, 7.54866e-07, 7.77268e09], fs=[1.62144, 36.6565, 0.255823],
    bws=0.000219263, as_=0.103686, St=[0.500846, 57.3469], ft=0.0267489, bwt=1.75147, at=0.000273289,
    sig_t=0.12314, sig_s=5.79336, ed=0.0296662, edn=0.0113638, edf=0.0190062, edfn=0.0193858,
)


def _lumdep(p, L):
    p = np.atleast_1d(p)
    if len(p) == 1:
        return p[0] * np.ones_like(L)
    if len(p) == 2:
        return p[1] * L ** p[0]
    if len(p) == 3:
        return p[0] * (1 + p[1] / L) ** (-p[2])
    return p[0] * (1 + p[1] / L) ** (-p[2]) * (1 - (1 + p[3] / L) ** (-p[4]))


def _achrom(f, A, L, smax, fmax, bw, a):
    sm, fm = _lumdep(smax, L), _lumdep(fmax, L)
    lp = 10 ** (-((np.log10(f) - np.log10(fm)) ** 2) / (2**bw))
    lp = np.where((f < fm) & (lp < 1 - a), 1 - a, lp)
    ac = 270 / (1 + (f / 0.65) ** 2)
    return sm * lp * np.sqrt(ac / (1 + ac / A)) * f


def ref_stela(f, omega, L, A, e, vf, p=P2022):
    rs = np.exp(-(omega**1.3314) / p["sig_s"])
    rt = np.exp(-np.abs(omega**0.1898 - 5**0.1898) ** 2 / p["sig_t"])
    s = rs * _achrom(f, A, L, p["Ss"], p["fs"], p["bws"], p["as_"]) + rt * _achrom(
        f, A, L, p["St"], p["ft"], p["bwt"], p["at"]
    )
    al = np.minimum(1, np.abs(vf - 180) / 90)
    a = al * p["ed"] + (1 - al) * p["edn"] + f * (al * p["edf"] + (1 - al) * p["edfn"])
    return s * 10 ** (-a * e)


# ---------------------------------------------------------------- published values
@pytest.mark.shared
def test_reference_table(shared_dir, dtype):
    with open(shared_dir / "data/csf/reference_values_achromatic.csv", newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r["model"].startswith("stelaCSF_2022")]
    assert len(rows) == 28
    g = lambda k: np.array([float(r[k]) for r in rows])  # noqa: E731
    f, w = g("s_frequency_cpd"), g("t_frequency_hz")
    vf = np.array([0.0 if r["vis_field_deg"] == "any" else float(r["vis_field_deg"]) for r in rows])
    m = StelaCSF()
    s = m.stimulus_sensitivity(f, g("eccentricity_deg"), w / f, g("luminance_cdm2"), g("area_deg2"), vf)
    assert s.dtype == jnp.dtype(dtype)
    err = np.abs(np.log10(np.asarray(s, np.float64)) - np.log10(g("sensitivity")))
    assert err.max() < 1e-3, err


def test_defaults_are_100cd_1deg2():
    m = StelaCSF()
    f = np.array([0.5, 4.0, 16.0])
    np.testing.assert_allclose(m.sensitivity(f, 3.0, 2.0), m.stimulus_sensitivity(f, 3.0, 2.0, 100.0, 1.0), rtol=1e-6)
    # NaN luminance / area (unknown in a data set) fall back to the defaults
    np.testing.assert_allclose(m.stimulus_sensitivity(f, 0.0, 0.0, np.nan, [np.nan, 1.0, np.nan]),
                               m.sensitivity(f), rtol=1e-6)
    # the reference values at 4 cycles/deg: 157.0005 (default conditions)
    assert abs(float(m.sensitivity(4.0)) - 157.0005) / 157.0005 < 2e-3
    assert m.inputs == ("f", "e", "v", "luminance", "area")


@settings(max_examples=30, deadline=None)
@given(
    lf=st.floats(-1.0, 1.8), w=st.floats(0.0, 40.0), lL=st.floats(-2.0, 4.0), lA=st.floats(-2.0, 3.0),
    e=st.floats(0.0, 60.0), vf=st.sampled_from([0.0, 90.0, 135.0, 180.0, 270.0]),
)
def test_matches_numpy_port(lf, w, lL, lA, e, vf):
    f, L, A = 10**lf, 10**lL, 10**lA
    want = ref_stela(f, w, L, A, e, vf)
    with x64_mode():
        got = float(StelaCSF().stimulus_sensitivity(f, e, w / f, L, A, vis_field=vf))
    if want > 1e-25:
        assert got == pytest.approx(want, rel=1e-9)


# ---------------------------------------------------------------- edges: finite values and gradients
def _all_grads(m, f, e, v, L, A):
    def fun(mm, x):
        return mm.log_sensitivity(x[0], x[1], x[2], x[3], x[4])

    x = jnp.stack([jnp.asarray(t, jnp.result_type(float)) for t in (f, e, v, L, A)])
    gm, gx = eqx.filter_grad(lambda mm, xx: fun(mm, xx))(m, x), jax.grad(lambda xx: fun(m, xx))(x)
    leaves = jax.tree_util.tree_leaves(eqx.filter(gm, eqx.is_inexact_array)) + [gx]
    return fun(m, x), leaves


@settings(max_examples=40, deadline=None)
@given(
    f=st.one_of(st.sampled_from([1e-3, 1e3, 0.0163, 1.0]), st.floats(1e-3, 1e3)),
    e=st.one_of(st.sampled_from([0.0, 120.0]), st.floats(0.0, 120.0)),
    v=st.one_of(st.sampled_from([0.0, 1e3]), st.floats(0.0, 1e3)),
    L=st.one_of(st.sampled_from([1e-3, 1e4]), st.floats(1e-3, 1e4)),
    A=st.one_of(st.sampled_from([1e-3, 1e3]), st.floats(1e-3, 1e3)),
)
def test_finite_values_and_gradients_on_domain(f, e, v, L, A):
    m = StelaCSF()
    val, leaves = _all_grads(m, f, e, v, L, A)
    assert np.isfinite(float(val))
    assert all(np.all(np.isfinite(np.asarray(g))) for g in leaves)
    s = m.stimulus_sensitivity(f, e, v, L, A)
    assert np.isfinite(float(s)) and float(s) >= pmetric._stela.SENSITIVITY_FLOOR * 0.999
    assert np.isfinite(float(m.threshold_contrast(f, e, v)))


def test_gradients_match_finite_differences(x64):
    m = StelaCSF()
    pts = [(2.0, 5.0, 1.5, 30.0, 2.0), (0.3, 0.0, 20.0, 0.5, 0.2), (12.0, 20.0, 0.1, 500.0, 30.0)]
    for p in pts:
        x0 = np.array(p)
        g = np.asarray(jax.grad(lambda x: m.log_sensitivity(*x))(jnp.asarray(x0)))
        for i in range(5):
            h = 1e-6 * max(1.0, abs(x0[i]))
            xp, xm = x0.copy(), x0.copy()
            xp[i] += h
            xm[i] -= h
            fd = (float(m.log_sensitivity(*xp)) - float(m.log_sensitivity(*xm))) / (2 * h)
            assert g[i] == pytest.approx(fd, rel=1e-5, abs=1e-7), (p, i)
    # w.r.t. the constants (every scalar field plus one element of each vector field)
    x = (2.0, 5.0, 1.5, 30.0, 2.0)
    gm = eqx.filter_grad(lambda mm: mm.log_sensitivity(*x))(m)
    for name in StelaCSF.param_bounds:
        val = np.asarray(getattr(m, name), np.float64)
        gval = np.asarray(getattr(gm, name))
        for idx in np.ndindex(val.shape):
            h = 1e-6 * max(abs(val[idx]), 1e-6)
            vp, vm = val.copy(), val.copy()
            vp[idx] += h
            vm[idx] -= h
            mp = eqx.tree_at(lambda mm: getattr(mm, name), m, jnp.asarray(vp))
            mn = eqx.tree_at(lambda mm: getattr(mm, name), m, jnp.asarray(vm))
            fd = (float(mp.log_sensitivity(*x)) - float(mn.log_sensitivity(*x))) / (2 * h)
            assert gval[idx] == pytest.approx(fd, rel=1e-4, abs=1e-6 / max(abs(val[idx]), 1e-6)), (name, idx)


def test_jit_vmap_agree_with_eager(dtype):
    m = StelaCSF()
    f = jnp.asarray(np.logspace(-1, 1.5, 6), dtype)
    e = jnp.asarray([0.0, 5.0, 10.0, 20.0, 40.0, 80.0], dtype)
    v = jnp.asarray([0.0, 0.5, 1.0, 2.0, 5.0, 10.0], dtype)
    eager = m.sensitivity(f, e, v)
    jitted = eqx.filter_jit(lambda mm, a, b, c: mm.sensitivity(a, b, c))(m, f, e, v)
    vm = jax.vmap(lambda a, b, c: m.stimulus_sensitivity(a, b, c, 100.0, 1.0))(f, e, v)
    assert eager.dtype == jnp.dtype(dtype) and eager.shape == (6,)
    np.testing.assert_allclose(jitted, eager, rtol=1e-5)
    np.testing.assert_allclose(vm, eager, rtol=1e-5)
    # broadcasting
    assert m.sensitivity(f[:, None], e[None, :]).shape == (6, 6)


def test_bad_input_errors():
    m = StelaCSF()
    with pytest.raises(ValueError, match="f"):
        m.sensitivity(-1.0)
    with pytest.raises(ValueError, match="NaN"):
        m.sensitivity(1.0, np.nan)
    with pytest.raises(ValueError, match="luminance"):
        m.stimulus_sensitivity(1.0, luminance=-5.0)
    with pytest.raises(ValueError, match="broadcast"):
        m.sensitivity(np.ones(3), np.ones(4))
    with pytest.raises(ValueError, match="sust_s_max"):
        StelaCSF(sust_s_max=(1.0, 2.0))
    with pytest.raises(ValueError, match="area"):
        StelaCSF(area=0.0)
    assert set(StelaCSF.param_bounds) <= {f.name for f in dataclasses.fields(StelaCSF)}
    for name, (lo, hi) in StelaCSF.param_bounds.items():
        val = np.asarray(getattr(m, name))
        assert (lo is None or (val >= lo).all()) and (hi is None or (val <= hi).all()), name


# ---------------------------------------------------------------- the base class's generic solvers
def test_threshold_frequency_meets_definition_vs_grid():
    m = StelaCSF()
    c = jnp.array([0.02, 0.1, 0.5])
    e, v = 2.0, 1.0
    tf = np.asarray(m.threshold_frequency(c, e, v))
    ct = np.asarray(m.threshold_contrast(tf, e, v))
    np.testing.assert_allclose(ct, np.asarray(c), rtol=1e-3)
    grid = np.logspace(-1, 2.5, 4001)
    ctg = np.asarray(m.threshold_contrast(grid, e, v))
    for ci, t in zip(np.asarray(c), tf):
        brute = grid[ctg <= ci].max()
        assert t == pytest.approx(brute, rel=3e-3)


def brute_distance(m, c, theta, e, v):
    """Largest k on a log grid at which contrast c (size theta, at e, v) is perceptible, using a dense
    frequency grid for the peak (worst case below the peak frequency)."""
    ks = np.logspace(-1, 2.5, 1401)
    fg = np.logspace(-2, 2, 801)
    ek, vk = (e / ks)[:, None], (v / ks)[:, None]
    ct_grid = np.asarray(m.threshold_contrast(fg[None, :], ek, vk))
    fp = fg[np.argmin(ct_grid, axis=1)]
    f = np.maximum(ks / (2 * theta), fp)
    ct = np.asarray(m.threshold_contrast(f, e / ks, v / ks))
    return np.array([ks[ct <= ci].max() for ci in np.atleast_1d(c)])


def test_imperceptible_distance_vs_grid():
    m = StelaCSF()
    c, theta, e, v = jnp.array([0.2, 0.6]), 0.1, 8.0, 2.0
    k = np.asarray(m.imperceptible_distance(c, theta, e, v))
    brute = brute_distance(m, np.asarray(c), theta, e, v)
    np.testing.assert_allclose(k, brute, rtol=1e-2)
    assert (k > 1.0).all()


def test_peak_frequency_at_least_as_high_as_generic_search():
    """The kink-aware Newton peak search finds a peak at least as high as the base class's grid +
    golden-section search (it can be higher: a kink of the truncated log-parabola puts a second local
    maximum next to the global one, e.g. e = 15.34, v = 2.73, maxima at 0.89 and 0.95 cycles/deg)."""
    with jax.enable_x64(True):
        m = StelaCSF()
        rng = np.random.default_rng(0)
        e = np.concatenate([rng.uniform(0, 120, 3000), [15.344208731179236, 35.52, 0.0]])
        v = np.concatenate([np.exp(rng.uniform(np.log(1e-3), np.log(2e3), 3000)), [2.729800915542238, 0.03, 0.0]])
        v[:300] = 0.0
        fp = np.asarray(jax.jit(lambda a, b: m._peak_frequency(a, b))(e, v))
        fg = np.asarray(jax.jit(lambda a, b: pmetric.CSFModel._peak_frequency(m, a, b))(e, v))
        ls, lg = np.asarray(m.log_sensitivity(fp, e, v)), np.asarray(m.log_sensitivity(fg, e, v))
        assert (ls >= lg - 1e-8).all(), (ls - lg).min()
        np.testing.assert_allclose(np.asarray(m.peak_frequency(e[:50], v[:50])), fp[:50], rtol=1e-12)
        # the derivative of ln S in ln f vanishes at the peak (or the peak sits at the kink / grid edge)
        g = jax.grad(lambda u: m.log_sensitivity(jnp.exp(u), 15.344208731179236, 2.729800915542238))
        assert abs(float(g(jnp.log(fp[-3])))) < 1e-8

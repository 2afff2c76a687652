"""Reddy's acuity model [Red01 Eq 4-5]: the printed pieces, the smooth variant, the distance key."""

import math

import equinox as eqx
import jax.flatten_util  # noqa: F401
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import pmetric as pm

from _definition import check_distance_definition  # noqa: E402
from _definition import distance as _dist  # noqa: E402
from _definition import perceptible as _perc  # noqa: E402
from _definition import generic_distance  # noqa: E402


def _g_printed(v):
    """Seed 000 Eq 4, G(v) exactly as printed (three pieces)."""
    v = np.asarray(v, float)
    return np.where(v <= 0.825, 60.0, np.where(v <= 118.3, 57.69 - 27.78 * np.log10(np.maximum(v, 1e-300)), 0.1))


def _m_printed(e):
    e = np.asarray(e, float)
    return np.where(e <= 5.79, 1.0, 7.49 / (0.3 * e + 1.0) ** 2)


with jax.enable_x64(True):
    EXACT = pm.ReddyAcuity()
    CAPPED = pm.ReddyAcuity(xi=30.0)
    SMOOTH = pm.ReddyAcuity(smooth=True)
    SMOOTH_CAPPED = pm.ReddyAcuity(xi=30.0, smooth=True)
MODELS = {"exact": EXACT, "capped": CAPPED, "smooth": SMOOTH, "smooth_capped": SMOOTH_CAPPED}

_acuity = jax.jit(lambda m, v, e: m.acuity(e, v))  # note: acuity takes (e, v)


def test_printed_pieces_and_knots(x64):
    v = np.concatenate([[0.0, 0.1, 0.5, 0.825], np.geomspace(0.826, 118.2, 200), [118.31, 200.0, 1e4]])
    e = np.concatenate([[0.0, 1.0, 5.79], np.geomspace(5.8, 200.0, 100)])
    h = np.asarray(_acuity(EXACT, v[:, None], e[None, :]))
    ref = _g_printed(v)[:, None] * _m_printed(e)[None, :]
    # the printed knots are rounded: the continuous form (G = clip(57.69 - 27.78 log10 v, 0.1, 60))
    # differs from the printed one by < 0.2 %, except just above 118.3 deg/s where the printed G
    # jumps from 0.1026 to 0.1 and the continuous one reaches 0.1 at v_f = 10^(57.59 / 27.78)
    v_f = 10 ** ((57.69 - 0.1) / 27.78)
    assert v_f == pytest.approx(118.3, rel=1e-2)
    band = (v > 118.3) & (v < v_f)
    np.testing.assert_allclose(h[~band], ref[~band], rtol=2e-3)
    np.testing.assert_allclose(h[band], ref[band], rtol=3e-2)
    g = np.asarray(_acuity(EXACT, v, 0.0))
    assert g[v <= 0.825] == pytest.approx(60.0, rel=1e-14)  # G(v <= 0.825) = 60
    assert g[v >= v_f] == pytest.approx(0.1, rel=1e-12)  # G above the floor knot = 0.1
    assert g[v > 118.3] == pytest.approx(0.1, rel=3e-2)
    mid = (v > 0.83) & (v < 118.0)
    np.testing.assert_allclose(g[mid], 57.69 - 27.78 * np.log10(v[mid]), rtol=1e-12)
    m = np.asarray(_acuity(EXACT, 0.0, e)) / 60.0
    assert m[e <= 5.78] == pytest.approx(1.0, rel=1e-14)  # M(e <= 5.79) = 1
    np.testing.assert_allclose(m[e > 5.8], 7.49 / (0.3 * e[e > 5.8] + 1) ** 2, rtol=1e-12)
    # the pieces meet at the knots (to the rounding of the printed constants)
    assert 57.69 - 27.78 * math.log10(0.825) == pytest.approx(60.0, rel=2e-4)
    assert 57.69 - 27.78 * math.log10(118.3) == pytest.approx(0.1, abs=3e-3)
    assert 7.49 / (0.3 * 5.79 + 1) ** 2 == pytest.approx(1.0, rel=2e-4)
    # Eq 5: the display cap, H' = min(xi, G M)
    hc = np.asarray(_acuity(CAPPED, v[:, None], e[None, :]))
    np.testing.assert_allclose(hc, np.minimum(30.0, h), rtol=1e-12)


def test_feature_imperceptible_when_half_period_exceeds_acuity(x64):
    """Seed 000: a feature of angular size s is imperceptible when 1 / (2 s) > H'."""
    s = np.geomspace(1e-3, 10.0, 61)[:, None]
    v = np.array([0.0, 5.0, 50.0, 500.0])[None, :]
    for m in (EXACT, CAPPED):
        h = np.asarray(_acuity(m, v, 10.0))
        p = np.asarray(_perc(m, 1.0, 1.0 / (2 * s), 10.0, v))
        np.testing.assert_array_equal(p, ~(1.0 / (2 * s) > h))
        assert not np.asarray(_perc(m, 0.0, 1e-3, 10.0, v)).any()  # zero contrast never visible
    # a 1-arcmin feature (f = 30 c/deg) is visible in the fovea at rest, not at 10 deg eccentricity
    assert bool(EXACT.is_perceptible(1.0, 30.0)) and not bool(EXACT.is_perceptible(1.0, 30.0, e=10.0))


def test_smooth_within_one_percent_everywhere(x64):
    v = np.concatenate([[0.0], np.geomspace(1e-3, 1e6, 400)])[:, None]
    e = np.concatenate([[0.0], np.geomspace(1e-3, 1e4, 300)])[None, :]
    for ex, sm in ((EXACT, SMOOTH), (CAPPED, SMOOTH_CAPPED)):
        r = np.asarray(_acuity(sm, v, e)) / np.asarray(_acuity(ex, v, e))
        assert np.abs(r - 1).max() < 0.01, np.abs(r - 1).max()


_KK = np.geomspace(1e-6, 1e4, 6001)


@settings(max_examples=25, deadline=None)
@given(
    name=st.sampled_from(list(MODELS)),
    c=st.sampled_from([0.0, 1e-3, 1.0]) | st.floats(0.0, 1.0),
    theta=st.floats(1e-3, 5.0),
    e=st.sampled_from([0.0, 5.79, 40.0]) | st.floats(0.0, 500.0),
    v=st.sampled_from([0.0, 0.825, 118.3]) | st.floats(0.0, 1e5),
)
def test_distance_definition_brute_force(name, c, theta, e, v):
    """The largest perceptible k of a dense k grid lies at or just below the answer."""
    k, kk, p = check_distance_definition(MODELS[name], c, theta, e, v, _KK, rel=1e-7, n_fine=500)
    if k > 0:
        # the grid finds nothing perceptible more than one grid step (0.4 %) below either
        assert kk[p].max() >= k * (1 - 4e-3)
    else:
        assert not p.any() or c == 0.0


def test_exact_distance_vectorized_vs_brute_force(dtype):
    """Many cases at once (incl. knots, v = 0, e = 0, c = 0, c = 1) against a dense grid, f32 and f64."""
    rng = np.random.default_rng(3)
    n = 600
    c = np.concatenate([[0.0, 1.0, 1.0, 1.0, 1.0], rng.uniform(0, 1, n - 5)])
    theta = np.exp(rng.uniform(np.log(1e-3), np.log(5.0), n))
    e = np.where(rng.uniform(size=n) < 0.2, 0.0, np.exp(rng.uniform(np.log(0.01), np.log(500.0), n)))
    v = np.where(rng.uniform(size=n) < 0.2, 0.0, np.exp(rng.uniform(np.log(0.01), np.log(1e5), n)))
    e[1:5], v[1:5] = [5.79, 0.0, 5.79, 100.0], [0.825, 118.3, 0.0, 0.825]
    dt = np.dtype(dtype)
    args = [jnp.asarray(x, dt) for x in (c, theta, e, v)]
    kk = np.geomspace(1e-6, 1e4, 4001)[:, None]
    rtol = 1e-4 if dtype == "float32" else 1e-9
    # m_scale < 4: M's outer piece is no longer increasing in k, so answers fall inside it too
    flat_m = pm.ReddyAcuity(m_scale=2.0, m_rate=0.1)
    for m in (pm.ReddyAcuity(), pm.ReddyAcuity(xi=30.0), flat_m, pm.ReddyAcuity(xi=20.0, m_scale=2.0, m_rate=0.1)):
        k = np.asarray(_dist(m, *args))
        assert k.dtype == dt
        p = np.asarray(_perc(m, c, kk / (2 * theta), e / kk, v / kk))
        kb = np.where(p.any(0), np.where(p, kk, 0.0).max(0), 0.0)
        assert ((k > 0) == (kb > 0)).all()
        pos = kb > 0
        np.testing.assert_allclose(k[pos], kb[pos], rtol=6e-3)  # one grid step (ln 1e10 / 4000)
        # exactness: perceptible just below k, imperceptible just above (in float64)
        ks = np.where(pos, k.astype(float), 1.0)
        for fac, want in ((1 - rtol, True), (1 + rtol, False)):
            kf = ks * fac
            pp = np.asarray(_perc(m, c, kf / (2 * theta), e / kf, v / kf))
            assert (pp[pos] == want).all(), (fac, np.where(pp[pos] != want))


def test_distance_hand_cases(x64):
    # fovea, at rest: k = 2 theta 60; with the cap xi = 30: 2 theta 30
    assert float(EXACT.imperceptible_distance(0.5, 0.1)) == pytest.approx(12.0, rel=1e-12)
    assert float(CAPPED.imperceptible_distance(0.5, 0.1)) == pytest.approx(6.0, rel=1e-12)
    # v = 0: in M's outer piece (e/k > 5.79) 2 theta G M / k grows with k (M ~ k^2), so the answer is
    # 2 theta 60 when e / (2 theta 60) <= 5.79 and 0 (invisible at every distance) otherwise
    e_knot = (math.sqrt(7.49) - 1) / 0.3  # 5.789..., where the printed M's pieces meet
    assert float(EXACT.imperceptible_distance(1.0, 0.05, 6.0 * e_knot * 0.999)) == pytest.approx(6.0, rel=1e-12)
    assert float(EXACT.imperceptible_distance(1.0, 0.05, 6.0 * e_knot * 1.001)) == 0.0
    # v > 0, e = 0, answer on G's middle piece: k = 2 theta (57.69 - 27.78 log10(v / k))
    th, v = 0.2, 100.0
    k = float(EXACT.imperceptible_distance(1.0, th, 0.0, v))
    assert k == pytest.approx(2 * th * (57.69 - 27.78 * math.log10(v / k)), rel=1e-12)
    assert 0.825 < v / k < 118.3
    # zero contrast or zero size: 0
    assert float(EXACT.imperceptible_distance(0.0, 1.0, 3.0, 3.0)) == 0.0
    assert float(EXACT.imperceptible_distance(1.0, 0.0, 3.0, 3.0)) == 0.0


def _dist_sum(m, c, t, e, v):
    return m.imperceptible_distance(c, t, e, v).sum()


_dist_grad = jax.jit(jax.grad(_dist_sum, argnums=(0, 1, 2, 3, 4)))


@pytest.mark.parametrize("name", list(MODELS))
def test_gradients_match_finite_differences(name, x64):
    """Three regimes at once (vectorized): G middle x M outer, G middle x M = 1, G = 60 x M = 1."""
    import jax.flatten_util  # noqa: F401

    m = MODELS[name]
    x0 = [np.array(a) for a in ((0.3, 0.3, 0.3), (0.2, 0.2, 0.05), (30.0, 0.5, 2.0), (20.0, 50.0, 0.0))]
    grads = _dist_grad(m, *x0)
    for i in range(4):  # inputs, elementwise
        h = 1e-6 * np.maximum(np.abs(x0[i]), 1.0)
        xp, xm = list(x0), list(x0)
        # one-sided at the domain edge 0 (a negative input is invalid: NaN under jit)
        lo = np.maximum(x0[i] - h, 0.0)
        xp[i], xm[i] = x0[i] + h, lo
        fd = (np.asarray(_dist(m, *xp)) - np.asarray(_dist(m, *xm))) / (x0[i] + h - lo)
        np.testing.assert_allclose(np.asarray(grads[i + 1]), fd, rtol=1e-4, atol=1e-7)
    flat, unravel = jax.flatten_util.ravel_pytree(m)  # constants: the three cases summed
    gflat, _ = jax.flatten_util.ravel_pytree(grads[0])
    for j in range(flat.size):
        h = 1e-6 * max(abs(float(flat[j])), 1.0)
        fp = float(np.asarray(_dist(unravel(flat.at[j].add(h)), *x0)).sum())
        fm = float(np.asarray(_dist(unravel(flat.at[j].add(-h)), *x0)).sum())
        assert float(gflat[j]) == pytest.approx((fp - fm) / (2 * h), rel=1e-4, abs=1e-7), j
    # the acuity surface itself
    va, ea = np.array([1.0, 21.0, 51.0]), np.array([31.0, 1.5, 3.0])
    ga = jax.vmap(jax.grad(lambda v, e: m.log_acuity(e, v), argnums=(0, 1)))(va, ea)
    for i, (dv, de) in enumerate(((1e-6, 0.0), (0.0, 1e-6))):
        fd = (np.asarray(m.log_acuity(ea + de, va + dv)) - np.asarray(m.log_acuity(ea - de, va - dv))) / 2e-6
        np.testing.assert_allclose(np.asarray(ga[i]), fd, rtol=1e-5, atol=1e-9)


def _all_fns(m, c, t, e, v):
    return (m.imperceptible_distance(c, t, e, v), m.log_acuity(e, v), m.threshold_frequency(c, e, v))


_all_jit = jax.jit(_all_fns)
_all_grad = jax.jit(jax.grad(lambda *a: sum(x.sum() for x in _all_fns(*a)), argnums=(1, 2, 3, 4)))


def test_finite_values_and_gradients_on_dense_grid(dtype):
    dt = jnp.dtype(dtype)
    th = jnp.asarray(np.concatenate([[0.0], np.geomspace(1e-4, 10.0, 9)]), dt)[:, None, None, None]
    e = jnp.asarray([0.0, 1.0, 5.79, 30.0, 1e4], dt)[None, :, None, None]
    v = jnp.asarray([0.0, 0.05, 0.825, 118.3, 1e6], dt)[None, None, :, None]
    c = jnp.asarray([0.0, 1e-3, 1.0], dt)[None, None, None, :]
    for m in (pm.ReddyAcuity(), pm.ReddyAcuity(xi=30.0), pm.ReddyAcuity(smooth=True), pm.ReddyAcuity(xi=30.0, smooth=True)):
        for val in _all_jit(m, c, th, e, v):
            assert val.dtype == dt and np.isfinite(np.asarray(val)).all()
        for g in _all_grad(m, c, th, e, v):
            assert g.dtype == dt and np.isfinite(np.asarray(g)).all()
        p = m.is_perceptible(c, th, e, v)
        assert p.dtype == jnp.bool_ and p.shape == (10, 5, 5, 3)


def test_model_built_under_x64_runs_in_float32():
    # EXACT was built under x64 (float64 fields); float32 inputs must give float32 without warnings
    with jax.enable_x64(False):
        k = EXACT.imperceptible_distance(jnp.float32(0.5), jnp.float32(0.1), jnp.float32(10.0), jnp.float32(5.0))
        assert k.dtype == jnp.float32 and np.isfinite(float(k))
        assert EXACT.acuity(1.0, 1.0).dtype == jnp.float32


def test_bad_input_raises():
    m = pm.ReddyAcuity()
    with pytest.raises(ValueError, match="v must be >= 0"):
        m.acuity(0.0, -1.0)
    with pytest.raises(ValueError, match="e contains NaN"):
        m.acuity(np.nan, 0.0)
    with pytest.raises(ValueError, match="theta"):
        m.imperceptible_distance(0.5, -1.0)
    with pytest.raises(ValueError, match="do not broadcast"):
        m.imperceptible_distance(np.ones(3), np.ones(4))
    with pytest.raises(ValueError, match="xi must be > 0"):
        pm.ReddyAcuity(xi=0.0)
    with pytest.raises(ValueError, match="g_slope must be finite"):
        pm.ReddyAcuity(g_slope=np.inf)


def _random_distance_inputs(rng, n):
    """c, theta (deg), e (deg), v (deg/s) with zeros, the printed knots and the knots in k-space."""
    c = np.where(rng.uniform(size=n) < 0.05, 0.0, rng.uniform(0, 1, n))
    theta = np.exp(rng.uniform(np.log(1e-3), np.log(5.0), n))
    e = np.where(rng.uniform(size=n) < 0.15, 0.0, np.exp(rng.uniform(np.log(0.01), np.log(300.0), n)))
    v = np.where(rng.uniform(size=n) < 0.15, 0.0, np.exp(rng.uniform(np.log(0.01), np.log(1e4), n)))
    e[:40] = rng.choice([5.79, (math.sqrt(7.49) - 1) / 0.3, 40.0], 40)
    v[40:80] = rng.choice([0.825, 118.3, 10 ** ((57.69 - 0.1) / 27.78)], 40)
    e[80:100] = (math.sqrt(7.49) - 1) / 0.3 * 120.0 * theta[80:100]  # e/k on M's knot at k = 2 theta 60
    return c, theta, e, v


_generic_dist = jax.jit(generic_distance)
_VARIANTS = {  # Reddy's constants, the cap, M's outer piece (m_scale < 4, < 1), G's middle beyond u = 11.4
    "reddy": {}, "capped": dict(xi=30.0), "flat_m": dict(m_scale=2.0, m_rate=0.1),
    "m_below_1": dict(m_scale=0.5, m_rate=0.05), "shallow_g": dict(g_slope=3.0), "steep_g": dict(g_slope=200.0),
}


@pytest.mark.parametrize("name", list(_VARIANTS))
def test_exact_solver_matches_generic_scan(name, x64):
    """The direct solve equals the slow generic largest-crossing scan (257-point grid + safeguarded Newton),
    with the model traced (``lax.switch`` on its constants) and concrete (static variant)."""
    kw = dict(_VARIANTS[name])
    m = pm.ReddyAcuity(kw.pop("xi", None), **kw)
    c, theta, e, v = _random_distance_inputs(np.random.default_rng(11), 1500)
    k = np.asarray(_dist(m, c, theta, e, v))
    k_static = np.asarray(jax.jit(lambda c, t, e, v: m.imperceptible_distance(c, t, e, v))(c, theta, e, v))
    np.testing.assert_allclose(k_static, k, rtol=1e-13, atol=0)
    kg = np.asarray(_generic_dist(m, c, theta, e, v))
    # the scan never finds a larger perceptible k; it misses a perceptible window narrower than its grid
    # step (7.5 %) above its last positive grid point (by construction at 80:100, where e/k sits on M's knot
    # at k = 2 theta 60, and rarely elsewhere); there k is perceptible (checked below)
    assert (kg <= k * (1 + 1e-9)).all()
    miss = kg < k * (1 - 1e-9)
    assert miss[100:].mean() < 0.01, miss[100:].sum()
    np.testing.assert_allclose(kg[~miss], k[~miss], rtol=1e-9, atol=0)
    pos = k > 0
    ks = np.where(pos, k, 1.0)
    isolated = np.zeros(k.shape, bool)
    isolated[80:100] = True  # there the perceptible set can be the single point k = 2 theta 60
    checks = ((1 - 1e-9, True, pos & ~isolated), (1.0, True, pos & isolated), (1 + 1e-9, False, pos))
    for fac, want, sel in checks:
        kf = ks * fac
        p = np.asarray(_perc(m, c, kf / (2 * theta), e / kf, v / kf))
        assert (p[sel] == want).all(), (name, fac, np.where(sel & (p != want)))


@pytest.mark.parametrize("m_scale", [4.0, 5.0, 7.49, 30.0])
def test_m_outer_candidates_never_win_for_m_scale_at_least_4(m_scale, x64):
    """For m_scale >= 4 (k_m <= q) G M / k grows with k on M's outer piece, so no answer lies inside it:
    the fast variant (outer=False, no Newton) equals the full candidate set (outer=True)."""
    c, theta, e, v = (jnp.asarray(x) for x in _random_distance_inputs(np.random.default_rng(12), 4000))
    for m_rate, xi in ((0.3, None), (0.05, 30.0), (3.0, None)):
        m = pm.ReddyAcuity(xi, m_scale=m_scale, m_rate=m_rate)
        fast = np.asarray(m._exact_distance(c, theta, e, v, outer=False, far=False))
        full = np.asarray(m._exact_distance(c, theta, e, v, outer=True, far=True))
        np.testing.assert_allclose(fast, full, rtol=1e-12, atol=0)
        assert (full > 0).mean() > 0.3


def test_u_root_lower_lambert_branch(dtype):
    """_u_root(t): the root u >= 1 of u - ln u = t (u = -W_{-1}(-e^-t)), to a few ulp of the exact root
    of the rounded t (Chebyshev start for u <= 11.4; the asymptotic start above with far=True)."""
    from pmetric._acuity import _U_FAR, _u_of_p, _u_root

    u_true = np.concatenate([1 + np.geomspace(1e-6, 1.0, 400), np.linspace(2.0, 11.4, 2000),
                             np.geomspace(11.5, 1e4, 300)])
    t = (u_true - np.log(u_true)).astype(dtype)
    u_ref = _u_of_p(np.sqrt(2.0 * np.maximum(t.astype(float) - 1.0, 0.0)))  # exact, for the rounded t
    eps = np.finfo(dtype).eps
    for far in (False, True):
        u = np.asarray(_u_root(jnp.asarray(t), far)).astype(float)
        sel = (u_ref <= _U_FAR) | far
        # conditioning: du/dt = u / (u - 1), so an ulp of t moves u by eps t u / (u - 1)
        bound = 8 * eps * u_ref * (1 + t.astype(float) / (u_ref - 1))
        assert (np.abs(u - u_ref)[sel] <= bound[sel]).all(), np.max((np.abs(u - u_ref) / bound)[sel])
    assert (np.asarray(_u_root(jnp.asarray(t), True)) >= 1).all()


def test_gradients_finite_on_random_inputs_float32():
    """Float32, the benchmark's input ranges plus zeros and knots: values and gradients finite, and the
    value equals float64 to float32 precision."""
    rng = np.random.default_rng(13)
    n = 20000
    c = rng.uniform(0, 1, n)
    e = np.where(rng.uniform(size=n) < 0.1, 0.0, rng.uniform(0, 60, n))
    v = np.where(rng.uniform(size=n) < 0.5, 0.0, rng.uniform(0, 100, n))
    theta = np.exp(rng.uniform(np.log(0.01), np.log(5), n))
    c[:10], e[10:20], v[20:30] = 0.0, 5.79, 0.825
    args = [jnp.asarray(x, jnp.float32) for x in (c, theta, e, v)]
    grad = jax.jit(jax.grad(_dist_sum, argnums=(0, 1, 2, 3, 4)))
    for m in (pm.ReddyAcuity(), pm.ReddyAcuity(xi=30.0), pm.ReddyAcuity(m_scale=2.0, m_rate=0.1)):
        k = np.asarray(_dist(m, *args))
        assert k.dtype == np.float32 and np.isfinite(k).all()
        g = grad(m, *args)
        for leaf in jax.tree_util.tree_leaves(g):
            assert np.isfinite(np.asarray(leaf)).all()
        with jax.enable_x64(True):
            k64 = np.asarray(_dist(m, *(np.asarray(a, np.float64) for a in args)))
        close = np.abs(k - k64) <= 1e-5 * k64
        assert close.mean() > 0.999 and ((k > 0) == (k64 > 0)).mean() > 0.999


def test_exact_distance_is_one_loop_free_pass():
    """Reddy's constants (concrete): the solve has no loop, cond or switch (it fuses into a few
    elementwise kernels); under differentiation the forward pass is the same solve
    (implicit_solution, a custom_jvp)."""
    m = pm.ReddyAcuity(xi=30.0)
    x = jnp.ones(8, jnp.float32)
    jaxpr = str(jax.make_jaxpr(lambda c, t, e, v: m.imperceptible_distance(c, t, e, v))(x, x, x, x))
    for prim in ("while", "scan", "cond", "switch"):
        assert prim not in jaxpr, prim


def test_acuity_takes_e_then_v():
    """``acuity(e, v)`` / ``log_acuity(e, v)``: the (f, e, v) order of every method."""
    m = pm.ReddyAcuity()
    g10 = 57.69 - 27.78 * math.log10(10.0)  # G(10 deg/s), M(0) = 1
    m20 = 60.0 * 7.49 / (0.3 * 20.0 + 1.0) ** 2  # G(0) M(20 deg)
    assert float(m.acuity(0.0, 10.0)) == pytest.approx(g10, rel=1e-5)
    assert float(m.acuity(v=10.0)) == pytest.approx(g10, rel=1e-5)
    assert float(m.acuity(20.0, 0.0)) == pytest.approx(m20, rel=1e-5)
    assert float(m.acuity(e=20.0)) == pytest.approx(m20, rel=1e-5)
    assert float(m.log_acuity(20.0, 0.0)) == pytest.approx(math.log(m20), rel=1e-5)
    assert float(m.threshold_frequency(1.0, 20.0, 0.0)) == pytest.approx(m20, rel=1e-5)
    with pytest.raises(pm.PlodError, match="acuity: v must be >= 0"):
        m.acuity(0.0, -1.0)

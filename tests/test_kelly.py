"""The direct imperceptible-distance solve of Kelly's spatio-temporal CSF (pmetric/_kelly_distance.py)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import pmetric as pm
from pmetric import _kelly_distance as K
from pmetric._numerics import rare_update

from _definition import generic_distance  # noqa: E402


def _inputs(n, seed):
    rng = np.random.default_rng(seed)
    c = rng.uniform(0.0, 1.0, n)
    theta = np.exp(rng.uniform(np.log(0.01), np.log(5.0), n))
    v = rng.uniform(0.0, 100.0, n)
    return c, theta, v


def test_structure_kelly_constants(x64):
    m = pm.KellySpatioTemporal("kelly1979")
    ok, tmax, prev, pmax, pglob = K.kelly_structure(m.a0, m.a1, jnp.float64)
    assert bool(ok)
    # p(t) = ln K + t - 2 ln(e^t + 2): maxima and the minimum between them from a dense grid
    t = np.linspace(np.log(0.1), np.log(1e4), 2_000_001)
    x = np.log10(np.exp(t) / 3.0)
    p = np.log(6.1 + 7.3 * np.abs(x) ** 3) + t - 2 * np.log(np.exp(t) + 2)
    d = np.sign(np.diff(p))
    i_max = np.where((d[:-1] > 0) & (d[1:] < 0))[0] + 1
    i_min = np.where((d[:-1] < 0) & (d[1:] > 0))[0] + 1
    np.testing.assert_allclose(np.asarray(tmax)[: len(i_max)], t[i_max], atol=1e-4)
    assert np.isinf(np.asarray(tmax)[len(i_max):]).all()
    np.testing.assert_allclose(float(prev[1]), t[i_min[0]], atol=1e-4)
    assert float(prev[0]) == -np.inf
    np.testing.assert_allclose(np.asarray(pmax)[: len(i_max)], p[i_max], atol=1e-9)
    assert float(pglob) == pytest.approx(p.max(), abs=1e-9)


def test_structure_rejects_strongly_curved_k(x64):
    # r = a1 / a0 = 20: l1 + l2 reaches ~4 > 1, h is not concave: the caller must use its scan
    ok = K.kelly_structure(jnp.asarray(1.0), jnp.asarray(20.0), jnp.float64)[0]
    assert not bool(ok)


def _brute(m, c, theta, v, kk):
    """Largest perceptible k on the grid kk (n, G) and perceptibility at k (1 +- 1e-4)."""
    p = np.asarray(m.is_perceptible(c[:, None], kk / (2 * theta[:, None]), 0.0, v[:, None] / kk))
    return np.where(p.any(axis=1), np.where(p, kk, 0.0).max(axis=1), 0.0)


@pytest.mark.parametrize("constants", ["kelly1979", "reddy"])
def test_direct_solve_meets_definition(constants, x64):
    """Against a dense brute-force grid (0.05 % steps over 6 decades around the answer)."""
    m = pm.KellySpatioTemporal(constants)
    c, theta, v = _inputs(300, 1)
    k = np.asarray(jax.jit(lambda c, t, v: m.imperceptible_distance(c, t, 0.0, v))(c, theta, v))
    kk = np.geomspace(1e-3, 1e3, 28_000)[None, :] * theta[:, None] * 20
    kb = _brute(m, c, theta, v, kk)
    step = kk[0, 1] / kk[0, 0]
    # the grid answer lies within one grid step below k (k is exact; the grid is discrete)
    has = kb > 0
    assert np.array_equal(has, k > 0)
    assert (kb[has] <= k[has] * (1 + 1e-4)).all()
    assert (kb[has] >= k[has] / step ** 1.01).all()
    # perceptible just below k, nothing perceptible just above it
    for f, want in ((1 - 1e-4, True), (1 + 1e-4, False)):
        ks = k[has] * f
        got = np.asarray(m.is_perceptible(c[has], ks / (2 * theta[has]), 0.0, v[has] / ks))
        assert (got == want).all(), (f, np.flatnonzero(got != want))


@pytest.mark.parametrize("constants", ["kelly1979", "reddy"])
def test_fast_pass_agrees_with_slow_solver(constants, x64):
    """The one-pass solve (both regimes) against the certified brackets and the Lambert W closed form."""
    m = pm.KellySpatioTemporal(constants)
    c, theta, v = _inputs(20_000, 2)
    v[:5000] = 0.0  # v = 0: the clamped regime only
    c, theta, v = (jnp.asarray(x) for x in (c, theta, v))
    st = K.kelly_structure(m.a0, m.a1, jnp.float64)
    k_f = np.asarray(K.kelly_fast(m.a0, m.a1, m.b, c, theta, v, st))
    k0 = np.asarray(K.kelly_clamped_root(m.a0, m.a1, m.b, c, theta))
    # the clamped root is the model's Lambert W threshold frequency
    np.testing.assert_allclose(k0, 2 * np.asarray(theta) * np.asarray(m.threshold_frequency(c, 0.0, 0.0)),
                               rtol=1e-12)
    k_s, found_s = K.kelly_slow(m.a0, m.a1, m.b, c, theta, v, st)
    easy = k0 >= 10 * np.asarray(v)
    k_ref = np.where(easy, k0, np.where(np.asarray(found_s) & (np.asarray(v) > 0), np.asarray(k_s), 0.0))
    rare = np.isnan(k_f)
    assert rare.mean() < 0.005  # the fast pass settles almost everything
    # the clamped regime always converges (start within 1e-5); only elements at its edge k0 = 10 v,
    # where the two tests of perceptibility at k = 10 v can differ by rounding, may be left over
    edge = np.abs(k0 - 10 * np.asarray(v)) <= 1e-6 * k0
    assert not rare[easy & ~edge].any()
    ok = ~rare
    assert np.array_equal(k_f[ok] > 0, k_ref[ok] > 0)
    both = ok & (k_ref > 0)
    # fast iterates approach from above (conservative): within 2e-5 relative in k
    dk = k_f[both] / k_ref[both] - 1
    assert dk.min() > -1e-9 and dk.max() < 2e-5


def test_clamped_start_series():
    """The fitted start of the clamped regime is within 1e-5 of the root for 0 <= D <= 12."""
    d = np.concatenate([np.geomspace(1e-12, 1e-3, 1000), np.linspace(1e-3, K._R1_D_MAX, 20_001)])
    x = np.sqrt(d)
    # reference root a = 2 + delta of 2 log1p(delta / 2) - delta + D = 0 (Newton in float64; accurate at
    # the branch point D -> 0, where scipy's lambertw loses digits)
    delta = 2 * x + d
    for _ in range(60):
        g = 2 * np.log1p(delta / 2) - delta + d
        delta = delta - g / (2 / (2 + delta) - 1)
    a = 2 + delta
    assert np.abs(2 * np.log(a) - a + d + 2 - 2 * np.log(2)).max() < 1e-12
    a0 = 2 + 2 * x + d * np.polyval(K._R1_Q, x)
    assert np.abs(a0 / a - 1).max() < 1e-5


def test_window_the_old_scan_missed(x64):
    """Reddy's constants, c = 0.7985, theta = 0.0958 deg, v = 6.388 deg/s: perceptible up to k = 0.09880
    (brute force); the previous grid scan reported 0."""
    m = pm.KellySpatioTemporal("reddy")
    c, th, v = 0.79848744, 0.09576683, 6.38809911
    k = float(m.imperceptible_distance(c, th, 0.0, v))
    kk = np.geomspace(1e-3, 10.0, 400_001)
    p = np.asarray(m.is_perceptible(c, kk / (2 * th), 0.0, v / kk))
    assert k == pytest.approx(kk[p].max(), rel=1e-4)


def test_fallback_scan_for_other_constants(x64):
    """Constants outside the certified range (r = a1 / a0 = 20) use the scan; it meets the generic solver."""
    m = pm.KellySpatioTemporal(a0=1.0, a1=20.0)
    c, theta, v = _inputs(64, 3)
    k = np.asarray(m.imperceptible_distance(c, theta, 0.0, v))
    kg = np.asarray(generic_distance(m, c, theta, 0.0, v))
    np.testing.assert_allclose(k, kg, rtol=1e-5, atol=1e-9)


@pytest.mark.parametrize("density", [0.0, 0.001, 0.02, 0.5])
@pytest.mark.parametrize("n", [5000, 5003])
def test_rare_update_equals_full(density, n):
    """Every branch (none, elements, gathered blocks, everything) writes exactly the masked elements."""
    rng = np.random.default_rng(4)
    x = jnp.asarray(rng.uniform(size=n), jnp.float32)
    base = jnp.asarray(rng.uniform(size=n), jnp.float32)
    mask = jnp.asarray(rng.uniform(size=n) < density)

    def fn(a):
        return a * 2.0 + 1.0

    w = jax.jit(lambda b, m, a: rare_update(fn, b, m, (a,), block=16, max_blocks=64, cap=40))(base, mask, x)
    want = np.where(np.asarray(mask), np.asarray(x) * 2 + 1, np.asarray(base))
    np.testing.assert_allclose(np.asarray(w), want, rtol=1e-6)


def test_gradients_on_the_direct_path(x64):
    m = pm.KellySpatioTemporal("kelly1979")
    x0 = np.array([0.6, 0.1, 40.0])  # c, theta, v: not perceptible at k = 10 v, falling-limb root
    fun = jax.jit(lambda c, t, v: m.imperceptible_distance(c, t, 0.0, v))
    assert 0 < float(fun(*x0)) < 10 * x0[2]
    g = jax.grad(fun, argnums=(0, 1, 2))(*x0)
    for i in range(3):
        h = 1e-6 * x0[i]
        xp, xm = x0.copy(), x0.copy()
        xp[i] += h
        xm[i] -= h
        fd = (float(fun(*xp)) - float(fun(*xm))) / (2 * h)
        assert float(g[i]) == pytest.approx(fd, rel=1e-5), i


def test_float32_values_and_gradients_finite():
    m = pm.KellySpatioTemporal("kelly1979")
    c, theta, v = (jnp.asarray(x, jnp.float32) for x in _inputs(4000, 5))
    k = m.imperceptible_distance(c, theta, 0.0, v)
    assert np.isfinite(np.asarray(k)).all()
    g = jax.grad(lambda c, t, v: m.imperceptible_distance(c, t, 0.0, v).sum(), argnums=(0, 1, 2))(c, theta, v)
    for gi in g:
        assert np.isfinite(np.asarray(gi)).all()
    with jax.enable_x64(True):
        c64, t64, v64 = (np.asarray(x, np.float64) for x in (c, theta, v))
        k64 = np.asarray(m.imperceptible_distance(c64, t64, 0.0, v64))
    np.testing.assert_allclose(np.asarray(k), k64, rtol=2e-3, atol=1e-6)

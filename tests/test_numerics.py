"""The guarded primitives of pmetric._numerics: finite values and gradients at the edges (0, tiny,
huge, inf) in float32 and float64, and rare_update against a full evaluation."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from pmetric import _numerics as N

from conftest import x64_mode

_EDGES = [0.0, 1e-45, 1e-38, 1e-30, 1e-12, 1e-3, 1.0, 7.0, 1e3, 1e30]


def _grid(dtype):
    return jnp.asarray(np.asarray(_EDGES, np.float64).astype(dtype))


_UNARY = {
    "log_guard": N.log_guard,
    "safe_log": N.safe_log,
    "pow_pos_1.1": lambda x: N.pow_pos(x, 1.1),
    "pow_pos_0.19": lambda x: N.pow_pos(x, 0.19),
    "where_pos_sqrt": lambda x: N.where_pos(x, jnp.sqrt, jnp.zeros_like(x)),
    "safe_div_den": lambda x: N.safe_div(1.0, x),
    "safe_div_num": lambda x: N.safe_div(x, 3.0),
    "div_or_zero_den": lambda x: N.div_or_zero(2.0, x),
    "div_or_zero_num": lambda x: N.div_or_zero(x, 0.0),
    "clenshaw": lambda x: N.clenshaw(jnp.minimum(x, 1.0), (0.5, 0.25, -0.125, 0.0625)),
}


@pytest.mark.parametrize("dtype", ["float32", "float64"])
@pytest.mark.parametrize("name", sorted(_UNARY))
def test_finite_values_and_gradients_on_edge_grid(name, dtype):
    with x64_mode(dtype == "float64"):
        fn = _UNARY[name]
        x = _grid(dtype)
        if name.endswith("_den"):  # 1 / den^2 overflows above the guard, as for any division
            x = x[np.abs(np.asarray(x, np.float64) - 1e-30) > 1e-31]
        y = fn(x)
        g = jax.vmap(jax.grad(lambda t: fn(t)))(x)
        assert y.dtype == jnp.dtype(dtype) and g.dtype == jnp.dtype(dtype)
        assert np.isfinite(np.asarray(y)).all(), (name, np.asarray(y))
        assert np.isfinite(np.asarray(g)).all(), (name, np.asarray(g))
        # + inf: no NaN in the value (log and powers give inf, the guarded divisions 0)
        yi = fn(jnp.asarray([np.inf], dtype))
        assert not np.isnan(np.asarray(yi)).any(), name


def test_edge_values():
    with x64_mode(True):
        z = jnp.zeros(())
        assert float(N.log_guard(z)) == pytest.approx(np.log(1e-30))
        assert float(N.safe_log(z)) == N.LN_FLOOR and float(jax.grad(N.safe_log)(z)) == 0.0
        assert float(N.pow_pos(z, 1.1)) == 0.0 and float(jax.grad(lambda t: N.pow_pos(t, 1.1))(z)) == 0.0
        # safe_div: den pushed to +-tiny (sign kept); div_or_zero: exactly 0 where den == 0
        tiny = float(jnp.finfo(jnp.float64).tiny) * 1e4
        assert float(N.safe_div(1.0, 0.0)) == pytest.approx(1.0 / tiny)
        assert float(N.safe_div(1.0, -1e-306)) == pytest.approx(-1.0 / tiny)  # (subnormals flush to 0)
        assert float(N.safe_div(6.0, 3.0)) == 2.0
        assert float(N.div_or_zero(1.0, 0.0)) == 0.0 and float(N.div_or_zero(6.0, 3.0)) == 2.0
        assert float(jax.grad(lambda d: N.div_or_zero(1.0, d))(z)) == 0.0
        assert N.as_float(3).dtype == jnp.float64 and N.as_float(np.float32(1)).dtype == jnp.float32
        assert not N.is_tracer(z)
        assert jax.jit(lambda t: jnp.asarray(N.is_tracer(t)))(z)


@given(st.lists(st.floats(0.0, 1e6, allow_nan=False), min_size=1, max_size=8),  # x^p stays finite in float32
       st.floats(0.05, 3.0), st.sampled_from(["float32", "float64"]))
def test_pow_pos_matches_power_with_finite_gradient(xs, p, dtype):
    with x64_mode(dtype == "float64"):
        x = jnp.asarray(np.asarray(xs).astype(dtype))
        y = N.pow_pos(x, p)
        xd = np.asarray(xs, np.float64).astype(dtype).astype(np.float64)
        xd = np.where(xd < np.finfo(dtype).tiny, 0.0, xd)  # XLA flushes subnormal inputs to 0
        np.testing.assert_allclose(np.asarray(y, np.float64), xd ** p,
                                   rtol=1e-4 if dtype == "float32" else 1e-10, atol=1e-30)  # subnormals flush
        g = jax.vmap(jax.grad(lambda t: N.pow_pos(t, p)))(x)
        assert np.isfinite(np.asarray(g)).all()


@pytest.mark.parametrize("density", [0.0, 0.01, 0.3])
def test_rare_update_writes_exactly_the_mask(density):
    rng = np.random.default_rng(2)
    n = 3001
    x = jnp.asarray(rng.uniform(size=n), jnp.float32)
    mask = jnp.asarray(rng.uniform(size=n) < density)
    out = jax.jit(lambda m, a: N.rare_update(lambda t: t + 1.0, jnp.zeros_like(a), m, (a,), block=8,
                                             max_blocks=40, cap=30))(mask, x)
    np.testing.assert_allclose(np.asarray(out), np.where(np.asarray(mask), np.asarray(x) + 1.0, 0.0), rtol=1e-6)

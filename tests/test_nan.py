"""Invalid in, NaN out: every buildable model refuses a concrete NaN or negative input with one error
naming it and, inside ``jax.jit`` (where it cannot refuse), returns NaN there (``is_perceptible``:
False) and the normal value elsewhere, in float32 and float64 (guarded arithmetic used to turn them
into 0, 1e-30 or a clamp: "imperceptible")."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import pmetric as pm
from tests.conftest import x64_mode

NAMES = [n for n in pm.model_entries() if n not in ("CalibratedCSF", "Display", "RovamoVirsu")]

# (method, arguments as (name, value) with the NaN slot marked None)
CALLS = [
    ("sensitivity", ("f",), lambda m, x: m.sensitivity(x, 2.0)),
    ("sensitivity", ("e",), lambda m, x: m.sensitivity(4.0, x)),
    ("imperceptible_distance", ("theta",), lambda m, x: m.imperceptible_distance(0.05, x, 1.0)),
    ("imperceptible_distance", ("c",), lambda m, x: m.imperceptible_distance(x, 0.5, 1.0)),
    ("threshold_contrast", ("f",), lambda m, x: m.threshold_contrast(x)),
]


def _all_calls(m, x):
    return [call(m, x) for _, _, call in CALLS] + [m.is_perceptible(x, 4.0)]


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("x64", [False, True])
def test_nan_in_nan_out_under_jit(name, x64):
    with x64_mode(x64):
        model = pm.make_model(name)
        dt = jnp.float64 if x64 else jnp.float32
        outs = jax.jit(_all_calls)(model, jnp.asarray([np.nan, -0.05, 0.5], dt))  # one program per model
        for (method, _, call), out in zip(CALLS, outs[:-1]):
            out = np.asarray(out)
            assert np.isnan(out[:2]).all(), (name, method, out)
            want = np.asarray(call(model, jnp.asarray(0.5, dt)))
            np.testing.assert_allclose(out[2], want, rtol=1e-5, err_msg=f"{name}.{method}")
        assert not np.asarray(outs[-1][:2]).any()


@pytest.mark.parametrize("name", NAMES)
def test_concrete_nan_is_one_error_naming_the_argument(name):
    model = pm.make_model(name)
    for method, (arg,), call in CALLS:
        with pytest.raises(pm.PlodError, match=f"{arg} contains NaN"):
            call(model, np.float32(np.nan))
        with pytest.raises(pm.PlodError, match=f"{arg} must be >= 0"):
            call(model, np.float32(-0.05))

"""A fuzz round over pmetric's API (2026-12-06, reports/robustness.md): inputs that raised raw exceptions
or gave plausible-looking garbage before the fix are one-line PlodErrors now, and Display's methods jit."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import pmetric as pm
from pmetric import PlodError

CASES = {
    "required-none": (lambda: pm.ManosSakrison().imperceptible_distance(0.1, None), "theta is required"),
    "ragged-list": (lambda: pm.ManosSakrison().imperceptible_distance([0.1, [0.2]], 0.5), "rectangular array"),
    # constants outside their bounds: before, Barten(k=nan) gave a distance of 207.5 and StelaCSF(sust_bw=-1) 12.6
    "barten-nan": (lambda: pm.Barten(k=np.nan), "Barten: k must be >= 0.001"),
    "barten-zero": (lambda: pm.Barten(k=0.0), "Barten: k must be >= 0.001"),
    "stela-nan": (lambda: pm.StelaCSF(sust_bw=np.nan), "StelaCSF: sust_bw must be in"),
    "stela-negative": (lambda: pm.StelaCSF(sust_bw=-1.0), "StelaCSF: sust_bw must be in"),
    "rovamo-negative": (lambda: pm.RovamoVirsu(k1=-1.0), "RovamoVirsu: k1 must be >= 0"),
    "eccentric-magnification-text": (lambda: pm.Eccentric(pm.ManosSakrison(), "cubic"), "must be a RovamoVirsu"),
    "eccentric-twice": (lambda: pm.Eccentric(pm.Eccentric(pm.ManosSakrison())), "already depends on eccentricity"),
    "name-too-long": (lambda: pm.make_model("x" * 5000), "unknown model"),  # was OSError: File name too long
    "save-to-folder": (lambda: pm.save_model(pm.ManosSakrison(), "/"), "is a directory"),
    "diagonal-text": (lambda: pm.Display.from_diagonal("24"), "diagonal"),
    "aspect-one-number": (lambda: pm.Display.from_diagonal(24, aspect=(16,)), "aspect must be two"),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_bad_input_is_one_plod_error(name):
    call, msg = CASES[name]
    with pytest.raises(PlodError, match=msg) as exc:
        call()
    assert "\n" not in str(exc.value)


def test_display_methods_jit_like_the_models():
    """``jax.jit(display.method)`` works (before: 'unhashable type: ArrayImpl') and gives the eager values."""
    d = pm.Display.default()
    rgb = jnp.array([[0.2, 0.5, 0.9], [1.0, 0.0, 0.3]])
    np.testing.assert_allclose(jax.jit(d.luminance)(rgb), d.luminance(rgb), rtol=1e-6)
    xy = jnp.array([[100.0, 200.0], [960.0, 540.0]])
    np.testing.assert_allclose(jax.jit(d.eccentricity)(xy), d.eccentricity(xy), rtol=1e-6)
    np.testing.assert_allclose(jax.jit(d.contrast)(rgb[0], rgb[1]), d.contrast(rgb[0], rgb[1]), rtol=1e-4)  # float32, fused
    assert jax.jit(d.luminance) is not None and hash(d.luminance) == hash(d.luminance)

"""Tests for pmetric.Display, Michelson contrast and the RGB transfer functions."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import pmetric
from pmetric import Display, michelson, michelson_range, relative_luminance

RTOL = {"float32": 2e-5, "float64": 1e-12}


def test_closed_form_fov(dtype):
    d = Display(0.5, 0.25, (1000, 500), 0.5)
    fx, fy = d.field_of_view
    assert fx.dtype == jnp.dtype(dtype)
    np.testing.assert_allclose(fx, math.degrees(2 * math.atan(0.5)), rtol=RTOL[dtype])
    np.testing.assert_allclose(fy, math.degrees(2 * math.atan(0.25)), rtol=RTOL[dtype])
    # the two side edges of the screen, through its centre line, are the full field of view apart
    np.testing.assert_allclose(d.visual_angle(jnp.array([0.0, 250.0]), jnp.array([1000.0, 250.0])),
                               math.degrees(2 * math.atan(0.5)), rtol=RTOL[dtype])
    # opposite corners: angle between 3-D vectors (-.25,-.125,.5) and (.25,.125,.5)
    a, b = np.array([-0.25, -0.125, 0.5]), np.array([0.25, 0.125, 0.5])
    want = math.degrees(math.acos(a @ b / (np.linalg.norm(a) * np.linalg.norm(b))))
    np.testing.assert_allclose(d.visual_angle(jnp.array([0.0, 0.0]), jnp.array([1000.0, 500.0])), want,
                               rtol=10 * RTOL[dtype])


def test_degrees_per_pixel_and_xi(dtype):
    d = Display(0.5, 0.25, (1000, 500), 0.5)
    pitch = 0.5 / 1000
    dpp = math.degrees(2 * math.atan(pitch / 1.0))
    np.testing.assert_allclose(d.degrees_per_pixel(), dpp, rtol=RTOL[dtype])
    np.testing.assert_allclose(d.xi, 1 / (2 * dpp), rtol=RTOL[dtype])  # [Red01 Eq 5]
    np.testing.assert_allclose(d.max_frequency(), 1 / (2 * dpp), rtol=RTOL[dtype])
    # off-centre pixel on the horizontal midline: atan difference of its edges
    x = 900.0
    want = math.degrees(math.atan((x + 0.5 - 500) * pitch / 0.5) - math.atan((x - 0.5 - 500) * pitch / 0.5))
    got = d.degrees_per_pixel(jnp.array([x, 250.0]))
    np.testing.assert_allclose(got, want, rtol=2e-3 if dtype == "float32" else 1e-9)
    assert got < d.degrees_per_pixel()
    # centre pixel via the general path equals the closed form
    np.testing.assert_allclose(d.degrees_per_pixel(jnp.array([500.0, 250.0])), dpp, rtol=1e-3 if dtype == "float32" else 1e-10)


def test_eccentricity(dtype):
    d = Display(0.4, 0.3, (800, 600), 0.7)
    pts = jnp.array([[400.0, 300.0], [700.0, 300.0], [400.0, 50.0]])
    e = d.eccentricity(pts)
    want = [0.0, math.degrees(math.atan(300 * 0.0005 / 0.7)), math.degrees(math.atan(250 * 0.0005 / 0.7))]
    np.testing.assert_allclose(e, want, rtol=RTOL[dtype] * 10, atol=1e-6)
    # gaze elsewhere: eccentricity of the gaze point itself is 0, symmetric in its arguments
    g = jnp.array([100.0, 100.0])
    np.testing.assert_allclose(d.eccentricity(g, gaze=g), 0.0, atol=1e-6)
    np.testing.assert_allclose(d.visual_angle(pts, g), d.visual_angle(g, pts), rtol=1e-6)
    # gradients finite, also at the gaze point itself
    grad = jax.grad(lambda p: d.eccentricity(p))(jnp.array([400.0, 300.0]))
    assert np.all(np.isfinite(grad))
    gdist = jax.grad(lambda dist: d.with_distance(dist).eccentricity(jnp.array([700.0, 300.0])))(0.7)
    np.testing.assert_allclose(gdist, -math.degrees(0.15 / (0.7 ** 2 + 0.15 ** 2)), rtol=1e-4)


def test_default_display():
    d = Display.default()
    np.testing.assert_allclose(d.field_of_view[0], 46.0, rtol=1e-6)
    np.testing.assert_allclose(d.width, 24 * 0.0254 * 16 / math.hypot(16, 9), rtol=1e-6)
    assert d.resolution == (1920, 1080) and d.transfer == "srgb"
    np.testing.assert_allclose(d.luminance(jnp.ones(3)), 200.0, rtol=1e-6)
    np.testing.assert_allclose(d.luminance(jnp.zeros(3)), 0.5, rtol=1e-6)
    assert 19 < float(d.xi) < 21  # about 20 cycles/deg at 0.63 m


def test_from_diagonal():
    d = Display.from_diagonal(24, (16, 10), (1920, 1200), 0.6)
    np.testing.assert_allclose(math.hypot(float(d.width), float(d.height)), 24 * 0.0254, rtol=1e-6)
    np.testing.assert_allclose(float(d.width) / float(d.height), 1.6, rtol=1e-6)
    with pytest.raises(ValueError, match="diagonal"):
        Display.from_diagonal(-3)


def test_srgb_known_values(dtype):
    np.testing.assert_allclose(pmetric.srgb_to_linear(0.5), 0.214041140, rtol=1e-6)
    np.testing.assert_allclose(pmetric.srgb_to_linear(jnp.array([0.0, 0.04045, 1.0])),
                               [0.0, 0.04045 / 12.92, 1.0], rtol=1e-6)
    np.testing.assert_allclose(pmetric.linear_to_srgb(0.214041140), 0.5, rtol=1e-6)
    np.testing.assert_allclose(relative_luminance(jnp.array([1.0, 1.0, 1.0])), 1.0, rtol=1e-6)
    np.testing.assert_allclose(relative_luminance(jnp.eye(3)), [0.2126, 0.7152, 0.0722], rtol=1e-6)
    d = Display(0.5, 0.3, (100, 60), 0.5, peak_luminance=100.0, black_level=1.0)
    np.testing.assert_allclose(d.luminance(jnp.array([0.5, 0.5, 0.5])), 1 + 99 * 0.214041140, rtol=1e-6)
    np.testing.assert_allclose(d.luminance(jnp.array([0.0, 1.0, 0.0])), 1 + 99 * 0.7152, rtol=1e-6)
    assert d.luminance(jnp.zeros((4, 5, 3))).shape == (4, 5)


@given(st.floats(0.0, 1.0))
def test_srgb_round_trip(v):
    np.testing.assert_allclose(pmetric.linear_to_srgb(pmetric.srgb_to_linear(v)), v, atol=2e-6)
    g = jax.grad(lambda x: pmetric.srgb_to_linear(x))(jnp.float32(v))
    assert np.isfinite(g) and g >= 0


@given(st.floats(0.0, 1.0), st.floats(0.3, 3.0))
def test_gamma_transfer_and_gradient(v, gamma):
    d = Display(0.5, 0.3, (100, 60), 0.5, transfer="gamma", gamma=gamma, peak_luminance=150.0, black_level=0.0)
    np.testing.assert_allclose(d.gray_luminance(v), 150.0 * v ** gamma, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(d.gray_level(d.gray_luminance(v)), v, atol=2e-4)
    g = jax.grad(lambda x: d.gray_luminance(x))(jnp.float32(v))
    assert np.isfinite(g)


def _lut_display():
    levels = [0.0, 0.5, 1.0]
    lum = [[0.5, 0.5, 0.5],  # black with each channel at 0
           [10.5, 30.5, 3.5],
           [40.5, 120.5, 10.5]]
    return Display.from_lut(0.5, 0.3, (100, 60), 0.5, levels, lum)


def test_lut_interpolation():
    d = _lut_display()
    assert d.transfer == "lut"
    np.testing.assert_allclose(d.black_level, 0.5)
    np.testing.assert_allclose(d.peak_luminance, 0.5 + 40 + 120 + 10)
    # nodes
    np.testing.assert_allclose(d.luminance(jnp.array([0.5, 0.0, 0.0])), 10.5, rtol=1e-6)
    np.testing.assert_allclose(d.luminance(jnp.array([1.0, 1.0, 1.0])), 170.5, rtol=1e-6)
    # channel midpoints, interpolated per channel and summed above black
    # R at 0.25 -> 5, G at 0.75 -> 30 + 0.5 * 90 = 75, B at 0.5 -> 3
    np.testing.assert_allclose(d.luminance(jnp.array([0.25, 0.75, 0.5])), 0.5 + 5 + 75 + 3, rtol=1e-6)
    # exact inverse of the gray curve
    for v in (0.0, 0.1, 0.5, 0.8, 1.0):
        np.testing.assert_allclose(d.gray_level(d.gray_luminance(v)), v, atol=1e-6)
    np.testing.assert_allclose(d.linearize(jnp.array([1.0, 0.5, 0.0])), [1.0, 0.25, 0.0], rtol=1e-6)


def test_michelson_values_and_edges(dtype):
    np.testing.assert_allclose(michelson(100.0, 50.0), 50 / 150, rtol=RTOL[dtype])
    np.testing.assert_allclose(michelson(50.0, 100.0), 50 / 150, rtol=RTOL[dtype])
    np.testing.assert_allclose(michelson(0.0, 0.0), 0.0)
    np.testing.assert_allclose(michelson(0.0, 3.0), 1.0)
    assert michelson(jnp.ones((3, 1)), jnp.ones(4)).shape == (3, 4)
    assert michelson(1.0, 2.0).dtype == jnp.dtype(dtype)
    np.testing.assert_allclose(michelson_range(jnp.array([[1.0, 3.0, 2.0], [0.0, 0.0, 0.0]])), [0.5, 0.0])
    for x, y in ((0.0, 0.0), (1.0, 1.0), (0.0, 2.0)):
        g = jax.grad(michelson, argnums=(0, 1))(x, y)
        assert np.all(np.isfinite(g))
    # finite difference away from the edges: d/dl1 (l1-l2)/(l1+l2) = 2 l2 / (l1+l2)^2
    np.testing.assert_allclose(jax.grad(michelson)(3.0, 1.0), 2 * 1 / 16, rtol=1e-5)


@given(st.floats(0.0, 1e4), st.floats(0.0, 1e4))
def test_michelson_property(a, b):
    c = float(michelson(a, b))
    assert 0.0 <= c <= 1.0 + 1e-6
    assert np.all(np.isfinite(jax.grad(michelson, argnums=(0, 1))(a, b)))


def test_jit_and_grad_through_display():
    d = Display.default()
    f = jax.jit(lambda disp, rgb: disp.luminance(rgb))
    np.testing.assert_allclose(f(d, jnp.array([0.5, 0.5, 0.5])), 0.5 + 199.5 * 0.214041140, rtol=1e-5)
    g = jax.grad(lambda disp: disp.xi)(d)
    # xi = 1 / (2 deg(2 atan(p/2d))): grows with distance
    assert float(g.distance) > 0 and np.isfinite(float(g.width))
    # under jit out-of-range RGB is clipped instead of raising
    np.testing.assert_allclose(f(d, jnp.array([2.0, 2.0, 2.0])), 200.0, rtol=1e-5)


@pytest.mark.parametrize(
    "kwargs, pattern",
    [
        (dict(transfer="linearish"), "transfer must be one of"),
        (dict(resolution=(0, 10)), "resolution"),
        (dict(resolution=(10.5, 10)), "resolution"),
        (dict(width=-0.5), r"width \(m\) must be > 0"),
        (dict(distance=float("nan")), r"distance \(m\) contains NaN"),
        (dict(black_level=300.0), "black_level 300.0 must be below"),
        (dict(transfer="lut"), "needs lut_levels"),
        (dict(transfer="lut", lut_levels=[0, 0.7, 0.5, 1], lut_luminance=np.ones((4, 3))), "strictly increasing"),
        (dict(transfer="lut", lut_levels=[0, 1], lut_luminance=np.ones((3, 3))), r"\(K, 3\)"),
        (dict(transfer="lut", lut_levels=[0.1, 1], lut_luminance=np.ones((2, 3))), r"span \[0, 1\]"),
        (dict(lut_levels=[0, 1]), "only apply to transfer='lut'"),
    ],
)
def test_display_errors(kwargs, pattern):
    base = dict(width=0.5, height=0.3, resolution=(100, 60), distance=0.5)
    base.update(kwargs)
    with pytest.raises(ValueError, match=pattern):
        Display(**base)


def test_input_errors():
    d = Display.default()
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 3\)"):
        d.luminance(jnp.ones(4))
    with pytest.raises(ValueError, match="must be <= 1"):
        d.luminance(jnp.array([0.2, 1.5, 0.0]))
    with pytest.raises(ValueError, match="NaN"):
        d.luminance(jnp.array([0.2, jnp.nan, 0.0]))
    with pytest.raises(ValueError, match=r"\(\.\.\., 2\)"):
        d.eccentricity(jnp.ones(3))
    with pytest.raises(ValueError, match="l1 must be >= 0"):
        michelson(-1.0, 2.0)
    with pytest.raises(ValueError, match=r"relative_luminance.*\(\.\.\., 3\)"):
        relative_luminance(jnp.ones(2))


def test_shape_mismatches_are_one_line_errors():
    """Arguments whose shapes do not broadcast are refused naming them (before: JAX's 'add got incompatible
    shapes' TypeError), also under jit; shapes that broadcast still do."""
    d = Display.default()
    with pytest.raises(pmetric.PlodError, match=r"michelson: the shapes of l1 \(3,\) and l2 \(4,\) do not broadcast"):
        michelson(np.ones(3), np.ones(4))
    with pytest.raises(pmetric.PlodError, match="michelson: the shapes"):
        jax.jit(michelson)(np.ones(3), np.ones(4))
    with pytest.raises(pmetric.PlodError, match=r"visual_angle: the shapes of p \(3, 2\) and q \(4, 2\)"):
        d.eccentricity(np.ones((3, 2)), np.ones((4, 2)))
    assert michelson(np.ones((3, 1)), np.full(4, 3.0)).shape == (3, 4)
    np.testing.assert_allclose(michelson(np.ones((3, 1)), np.full(4, 3.0)), 0.5)
    assert d.visual_angle(np.zeros((3, 1, 2)), np.ones((4, 2))).shape == (3, 4)

"""Headless rendering and FLIP: pixel values, not just that it runs (skipped without an OpenGL context)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import optim
from experiments import render as R

SIZE = (160, 90)


@pytest.fixture(scope="module")
def sphere_view():
    v, f = optim.icosphere(3)
    return v, f, optim.View.framing(v, background=0.0)


def _render_or_skip(*a, **k):
    try:
        return R.render(*a, **k)
    except RuntimeError as exc:  # no EGL on this machine
        pytest.skip(str(exc))


def test_flat_colour_is_rendered_exactly(sphere_view):
    v, f, view = sphere_view
    grey = np.full((len(v), 3), 0.5, dtype=np.float32)
    img = _render_or_skip(v, f, grey, view, size=SIZE)
    assert img.shape == (SIZE[1], SIZE[0], 3)
    # Pre-lit vertex colours are drawn unlit (Gouraud interpolation of a constant is the constant).
    assert np.allclose(img[SIZE[1] // 2, SIZE[0] // 2], 0.5, atol=1.5 / 255)
    assert np.allclose(img[0, 0], 0.0)  # background luminance 0 -> black corner
    # The sphere subtends 30 deg of a 46-deg-wide screen: its width in pixels is 2 tan(15)/(2 tan(23)) of W.
    covered = (img[SIZE[1] // 2].max(axis=1) > 0.25).sum()
    expect = SIZE[0] * np.tan(np.radians(15)) / np.tan(np.radians(23))
    assert abs(covered - expect) <= 3


def test_background_and_prelighting(sphere_view):
    v, f, _ = sphere_view
    view = optim.View.framing(v, background=1.0)
    img = _render_or_skip(v, f, None, view, size=SIZE)
    assert np.allclose(img[0, 0], 1.0)  # white background
    lum = optim.vertex_luminance(v, f)
    centre = img[SIZE[1] // 2, SIZE[0] // 2, 0]
    # The centre pixel lies among the pre-lit intensities of the vertices facing the camera.
    import pmetric as pm

    front = np.asarray(pm.linear_to_srgb(lum[v[:, 2] > 0.9]))
    assert front.min() - 2 / 255 <= centre <= front.max() + 2 / 255


def test_flip_zero_for_identical_and_positive_for_different():
    rng = np.random.default_rng(0)
    a = rng.uniform(size=(32, 48, 3)).astype(np.float32)
    emap, mean = R.flip(a, a, 40.0)
    assert emap.shape == (32, 48) and mean == 0.0
    b = a.copy()
    b[8:24, 12:36] = 1.0 - b[8:24, 12:36]
    emap, mean = R.flip(a, b, 40.0)
    assert mean > 0.05 and emap[16, 24] > emap[0, 0]
    with pytest.raises(ValueError, match="must both be"):
        R.flip(a, a[:, :10], 40.0)


def test_simplify_render_writes_png_and_never_the_input(tmp_path, monkeypatch, capsys):
    from experiments.cli import main

    monkeypatch.setenv("PLOD_CACHE", str(tmp_path / "cache"))
    v, f = optim.icosphere(3)
    mesh = tmp_path / "sphere.ply"
    optim.save_mesh(mesh, v, f)
    out = tmp_path / "cmp.png"
    rc = main(["simplify", str(mesh), "--budget", "200", "--render", str(out), "--render-size", "160,90",
               "--json"])
    if rc != 0:
        err = capsys.readouterr().err
        if "OpenGL" in err:
            pytest.skip(err)
        raise AssertionError(err)
    res = json.loads(capsys.readouterr().out)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert res["render"]["mean_flip"] > 0 and res["output_triangles"] <= 200
    assert abs(res["render"]["pixels_per_degree"] - 160 / 1920 / np.degrees(2 * np.tan(np.radians(23)) / 1920)) < 1e-2
    before = mesh.read_bytes()
    assert main(["simplify", str(mesh), "--budget", "200", "--render", str(mesh)]) == 2
    # refused before any work: the render path is the input mesh (and not a .png)
    assert "is the input mesh" in capsys.readouterr().err and mesh.read_bytes() == before


def test_back_faces_are_culled_in_both_modes():
    v, f = optim.grid_mesh(1, 1, (2.0, 2.0))
    v = v - v.mean(0)
    view = optim.View.framing(v, 30.0, background=0.0)  # the eye is on +z: the grid faces it
    for mode in R.MODES:
        front = _render_or_skip(v, f, None, view, mode=mode, size=SIZE)
        back = _render_or_skip(v, f[:, ::-1], None, view, mode=mode, size=SIZE)  # reversed winding
        assert front[SIZE[1] // 2, SIZE[0] // 2].min() > 0.2 and back.max() == 0.0


def test_relit_without_diffuse_is_the_baked_colours(sphere_view):
    v, f, view = sphere_view
    rng = np.random.default_rng(1)
    colors = rng.uniform(0.2, 0.9, size=(len(v), 3)).astype(np.float32)
    flat = optim.Lighting(ambient=1.0, diffuse=0.0)
    relit = _render_or_skip(v, f, colors, view, lighting=flat, mode="relit", size=SIZE)
    baked = _render_or_skip(v, f, colors, view, mode="baked", size=SIZE)
    drawn = np.pad((baked.max(axis=2) > 0) & (relit.max(axis=2) > 0), 1)
    inner = drawn[1:-1, 1:-1] & drawn[:-2, 1:-1] & drawn[2:, 1:-1] & drawn[1:-1, :-2] & drawn[1:-1, 2:]  # no edges
    assert inner.sum() > 1000
    assert np.abs(relit - baked)[inner].max() <= 1.5 / 255  # same interpolation, shading a no-op

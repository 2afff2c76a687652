"""optim.View: camera geometry, display geometry, gaze and input checks (closed forms)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import pmetric
from optim import View


def test_projection_closed_form():
    v = View(eye=(0, 0, 5), target=(0, 0, 0), fov_deg=60.0, image_size=(800, 600))
    f = 300.0 / math.tan(math.radians(30.0))
    assert v.focal_px == pytest.approx(f)
    xy, depth = v.project([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 6]])
    assert xy[0] == pytest.approx([400.0, 300.0])
    assert xy[1] == pytest.approx([400.0 + f / 5.0, 300.0])  # x to the right
    assert xy[2] == pytest.approx([400.0, 300.0 - f / 5.0])  # y up in the world = up on the screen
    assert depth[:3] == pytest.approx([5.0, 5.0, 5.0])
    assert depth[3] == pytest.approx(-1.0) and np.isinf(xy[3]).all()  # behind the camera


def test_rotation_is_orthonormal_and_looks_at_target():
    v = View(eye=(3, -2, 7), target=(1, 1, 1), up=(0, 0, 1))
    r = v.rotation
    assert r @ r.T == pytest.approx(np.eye(3), abs=1e-12)
    fwd = (v.target - v.eye) / np.linalg.norm(v.target - v.eye)
    assert -r[2] == pytest.approx(fwd)


def test_default_display_geometry():
    d = pmetric.Display.default()
    v = View(eye=(0, 0, 5))
    assert (v.width, v.height) == d.resolution
    # the image spans the screen: its left edge is 23 deg from the centre (46 deg screen [LH01 §6.2])
    assert v.visual_angle_px([0, 540], [960, 540]) == pytest.approx(23.0, abs=1e-6)
    # default camera field of view = what the screen subtends vertically
    h_deg = math.degrees(2 * math.atan(float(d.height) / (2 * float(d.distance))))
    assert v.fov_deg == pytest.approx(h_deg)
    assert v.degrees_per_pixel == pytest.approx(float(d.degrees_per_pixel()))


def test_framing_subtends_object_deg():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(200, 3)) * [1.0, 2.0, 0.5] + [3.0, -1.0, 2.0]
    v = View.framing(pts, 30.0, direction=(1, 1, 0))
    centre = 0.5 * (pts.min(0) + pts.max(0))
    radius = np.sqrt(((pts - centre) ** 2).sum(1).max())
    dist = np.linalg.norm(v.eye - centre)
    assert 2 * math.degrees(math.asin(radius / dist)) == pytest.approx(30.0)
    assert v.target == pytest.approx(centre)
    # a direction parallel to the default up still gives a valid camera
    View.framing(pts, 30.0, direction=(0, 1, 0))
    # but a zero up is an error, not silently replaced (`plod simplify --up 0,0,0` used to run)
    with pytest.raises(ValueError, match="up must be a nonzero vector"):
        View.framing(pts, 30.0, up=(0, 0, 0))


def test_framing_from_a_given_sphere_is_the_same_view():
    """``View.framing(sphere=framing_sphere(v))`` (what ``direction_keys`` does once per object, not per
    view) frames exactly as from the vertices; a malformed sphere is a one-line error."""
    from optim import framing_sphere

    rng = np.random.default_rng(1)
    pts = rng.normal(size=(300, 3)) * [2.0, 0.5, 1.0] + [-4.0, 1.0, 7.0]
    sphere = framing_sphere(pts)
    for d in ((1, 0, 0), (0.3, -2, 1), (0, 1, 0)):
        a = View.framing(pts, 12.0, direction=d, gaze=None)
        b = View.framing(None, 12.0, direction=d, gaze=None, sphere=sphere)
        for name in ("eye", "target", "up"):
            assert np.array_equal(getattr(a, name), getattr(b, name))
    for bad, msg in ((None.__class__, "sphere must be"), ((np.zeros(2), 1.0), "finite centre"),
                     ((np.zeros(3), -1.0), "radius >= 0"), ((np.full(3, np.nan), 1.0), "finite centre"),
                     ((np.zeros(3), "r"), "sphere must be")):
        with pytest.raises(ValueError, match=msg):
            View.framing(None, 12.0, sphere=bad)


def test_the_default_display_is_built_once_per_float_width():
    import jax

    a, b = pmetric.Display.default(), pmetric.Display.default()
    assert a is b and View(eye=(0, 0, 5.0), target=(0, 0, 0)).display is a
    with jax.enable_x64(True):
        c = pmetric.Display.default()
        assert c is pmetric.Display.default() and c.width.dtype == np.float64
    assert a.width.dtype == (np.float64 if jax.config.jax_enable_x64 else np.float32)
    assert float(c.distance) == pytest.approx(float(a.distance), rel=1e-6)


def test_gaze_forms():
    v = View(eye=(0, 0, 5))
    assert v.gaze_px == pytest.approx(np.array([[960.0, 540.0]]))
    assert View(eye=(0, 0, 5), gaze=None).gaze_px is None
    g = View(eye=(0, 0, 5), gaze=[[10, 20], [30, 40]]).gaze_px
    assert g.shape == (2, 2) and g[1] == pytest.approx([30, 40])
    # a gaze direction is projected: looking at the target = the image centre
    d = View(eye=(0, 0, 5), gaze=[0, 0, -1]).gaze_px
    assert d == pytest.approx(np.array([[960.0, 540.0]]))


def test_previous_view_and_dt():
    a = View(eye=(0, 0, 5))
    b = View(eye=(0.1, 0, 5), previous=a, dt_s=1 / 60)
    assert b.previous is a and b.dt_s == pytest.approx(1 / 60)
    assert a.dt_s == 0.0


@pytest.mark.parametrize(
    "kw, msg",
    [
        (dict(eye=(1, 2)), "eye must be three numbers"),
        (dict(eye=(0, 0, 0)), "eye and target coincide"),
        (dict(eye=(0, 5, 0)), "up must not be parallel"),
        (dict(eye=(0, 0, 5), up=(0, 0, 0)), "up must be a nonzero vector"),
        (dict(eye=(0, 0, 5), fov_deg=180), "fov_deg"),
        (dict(eye=(0, 0, 5), fov_deg=-1), "fov_deg"),
        (dict(eye=(0, 0, 5), gaze="left"), "gaze must be"),
        (dict(eye=(0, 0, 5), gaze=np.zeros((2, 4))), "gaze must be"),
        (dict(eye=(0, 0, 5), gaze=[0, 0, 1]), "behind the camera"),
        (dict(eye=(0, 0, 5), gaze_error_deg=-1), "gaze_error_deg"),
        (dict(eye=(0, 0, 5), dt_s=0.1), "dt_s given without a previous view"),
        (dict(eye=(0, 0, 5), display="46deg"), "pmetric.Display"),
        (dict(eye=(0, 0, 5), image_size=(0, 10)), "image_size"),
        (dict(eye=(0, 0, float("nan"))), "finite"),
        (dict(eye=(0, 0, 5), background=2.0), "background"),
    ],
)
def test_bad_input_names_the_problem(kw, msg):
    with pytest.raises(ValueError, match=msg):
        View(**kw)


def test_previous_needs_dt():
    with pytest.raises(ValueError, match="dt_s"):
        View(eye=(0, 0, 5), previous=View(eye=(0, 0, 4)))


def test_a_gaze_direction_keeps_its_pixel_far_from_0():
    """A (G, 3) gaze direction is rotated into the camera, not added to the eye: the view scaled by 2^k
    puts it on the same pixel (before: eye + g rounded g away, 4.6 deg off at 2^49, and at 2^56 it
    "pointed behind the camera")."""
    g = [[0.3, 0.1, -1.0], [-0.2, 0.4, -0.7]]
    ref = View(eye=(3, 2, 10), target=(0, 0, 0), gaze=g).gaze_px
    assert not np.allclose(ref, 960.0)
    for k in range(0, 60, 7):
        s = 2.0 ** k
        v = View(eye=(3 * s, 2 * s, 10 * s), target=(0, 0, 0), gaze=g)
        np.testing.assert_array_equal(v.gaze_px, ref)
    # an ordinary view: the same pixel as projecting the point eye + g
    v = View(eye=(0.3, -1.2, 4.0), target=(0.1, 0.2, -0.3), gaze=g)
    np.testing.assert_allclose(v.gaze_px, v.project(v.eye + np.array(g))[0], rtol=1e-13)
    with pytest.raises(ValueError, match="gaze direction is zero"):
        View(eye=(0, 0, 5), gaze=[0, 0, 0])


def test_views_refuse_what_overflows_and_frame_from_any_direction_length():
    """2026-12-07 fuzz round: an eye at 1e300 said "eye and target coincide" (its squared length overflowed);
    a gaze error of 1e300 deg overflowed the float32 terms; a display 1e-100 m away was stored as 0 m (a
    ZeroDivisionError); a 1e-320 framing direction was "zero"."""
    with pytest.raises(ValueError, match="eye must lie within 1e"):
        View(eye=(1e300, 0, 0))
    with pytest.raises(ValueError, match=r"gaze_error_deg must be an angle in \[0, 180\]"):
        View(eye=(0, 0, 5), gaze_error_deg=1e300)
    with pytest.raises(ValueError, match="distance .m. 1e-100 is outside what float"):
        pmetric.Display(0.5, 0.3, (1920, 1080), 1e-100)
    verts = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    ref = View.framing(verts, direction=(0.3, 0.2, 1.0))
    for k in (1e-300, 1e-200, 1e200):
        v = View.framing(verts, direction=(0.3 * k, 0.2 * k, 1.0 * k))
        np.testing.assert_allclose(v.eye, ref.eye, rtol=1e-12)
        np.testing.assert_allclose(v.rotation, ref.rotation, atol=1e-12)
    v = View.framing(verts, direction=(0.0, 0.0, 1e-320))  # subnormal, but a direction
    np.testing.assert_allclose(v.eye / np.linalg.norm(v.eye), [0.0, 0.0, 1.0], atol=1e-12)


def test_an_integer_beyond_float_range_is_a_one_line_error():
    """``real_or_nan`` let float()'s OverflowError through: View(gaze_error_deg=10**400) was a traceback."""
    import optim

    with pytest.raises(pmetric.PlodError, match="gaze_error_deg must be an angle"):
        View(eye=(0, 0, 5), gaze_error_deg=10 ** 400)
    with pytest.raises(pmetric.PlodError, match="object_distance: radius"):
        optim.object_distance(10, 10 ** 400)

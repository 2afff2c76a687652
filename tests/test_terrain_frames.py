"""Terrain frames judged by rendering (experiments.terrain.terrain_view / judge_frames) [Red01, Man21].

The window's geometry is checked in closed form without a renderer; the judged cases are skipped without
torch / pyfvvdp (the ``judge`` extra) or an OpenGL context.
"""

import math

import numpy as np
import pytest

from experiments.judge import pixels_per_degree
from experiments.terrain import FLIGHT, flight_cameras, judge_frames, terrain_view
from optim._terrain import Heightfield, TerrainCamera, TerrainCriteria, fractal_heightfield
from pmetric import PlodError


@pytest.mark.parametrize("ppd, fov", [(6.4, (90.0, 60.0)), (12.0, (40.0, 30.0))])
def test_window_geometry_closed_form(ppd, fov):
    cam = TerrainCamera(eye=np.array([1.0, 50.0, 2.0]), forward=np.array([0.3, -0.4, 0.8]))
    v = terrain_view(cam, fov_deg=fov, px_per_deg=ppd)
    assert pixels_per_degree(v) == pytest.approx(ppd, rel=1e-3)
    assert v.fov_deg == pytest.approx(fov[1], abs=0.2)  # vertical field of the pinhole window
    w_expected = 2 * math.tan(math.radians(fov[0] / 2)) / math.tan(math.radians(1 / ppd))
    assert abs(v.width - w_expected) <= 1
    f = np.asarray(cam.forward) / np.linalg.norm(cam.forward)
    d = (v.target - v.eye) / np.linalg.norm(v.target - v.eye)
    np.testing.assert_allclose(d, f, atol=1e-12)  # looks along the camera's forward direction
    with pytest.raises(PlodError, match="judged window"):
        terrain_view(cam, fov_deg=(200.0, 135.0))


@pytest.fixture(scope="module")
def judged():
    pytest.importorskip("torch")
    pytest.importorskip("pyfvvdp")
    hf = Heightfield(fractal_heightfield(65, seed=3, relief=40.0), 10.0)
    cams = flight_cameras(hf, dict(FLIGHT))
    crits = {"cull": TerrainCriteria(size=False, periphery=False, velocity=False, xi=3.2),
             "coarse": TerrainCriteria(periphery=False, velocity=False, xi=0.05)}
    try:
        return judge_frames(hf, cams, crits, [30], FLIGHT["fps"], size=(366, 212), px_per_deg=3.2)
    except RuntimeError as exc:
        if "OpenGL" in str(exc):
            pytest.skip(str(exc))
        raise


def test_culling_alone_is_invisible_and_coarse_terrain_is_not(judged):
    rows = {r["criteria"]: r for r in judged}
    # culling drops only what the window cannot show: the rendering is the full terrain's
    assert rows["cull"]["jod"] > 9.98 and rows["cull"]["flip"] < 1e-3
    assert rows["coarse"]["triangles"] < rows["cull"]["triangles"]
    assert rows["coarse"]["jod"] < rows["cull"]["jod"] - 0.2 and rows["coarse"]["flip"] > 1e-3


def test_bad_frame_index():
    hf = Heightfield(fractal_heightfield(17, seed=0), 1.0)
    cams = flight_cameras(hf, dict(FLIGHT))
    with pytest.raises(PlodError, match="judged frame 1"):
        judge_frames(hf, cams, {"all": TerrainCriteria(xi=3.2)}, [1], 30.0)

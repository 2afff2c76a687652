"""Reddy's perceptual terrain quadtree (optim._terrain) [Red01 Table 1]: refinement, cracks, monotonicity."""

import numpy as np
import pytest

from optim._terrain import (Heightfield, TerrainCamera, TerrainCriteria, fractal_heightfield, full_mesh,
                            refine_terrain, terrain_mesh)
from pmetric import PlodError

ALL = TerrainCriteria(xi=4.0)
NONE = TerrainCriteria(size=False, periphery=False, velocity=False, cull=False)


def _cam(n, spacing, height=60.0, yaw=0.0):
    side = (n - 1) * spacing
    return TerrainCamera(eye=np.array([0.5 * side, height, -0.1 * side]),
                         forward=np.array([np.sin(yaw), -0.35, np.cos(yaw)]))


def _check_crack_free(hf, lod):
    """The drawn mesh tiles the grid square exactly: positive 2-D areas summing to (N-1)^2, every interior
    edge shared by exactly two faces in opposite directions, boundary edges only on the border."""
    V, F, G = terrain_mesh(hf, lod)
    assert len(F) == lod.triangles
    np.testing.assert_allclose(V[:, 1], hf.heights[G[:, 0], G[:, 1]])  # shared vertices = the samples
    p = G[:, ::-1].astype(float)  # (column, row)
    a, b, c = p[F[:, 0]], p[F[:, 1]], p[F[:, 2]]
    area = 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
    assert (area < 0).all() or (area > 0).all()  # one winding everywhere (row axis flips the sign)
    assert abs(np.abs(area).sum() - (hf.n - 1) ** 2) < 1e-9
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    fwd = {tuple(x) for x in e.tolist()}
    assert len(fwd) == len(e)  # no directed edge twice (no overlap)
    for i, j in fwd:
        if (j, i) not in fwd:  # a boundary edge: both ends on the same border line
            gi, gj = G[i], G[j]
            on = [(gi[k] == gj[k] == 0) or (gi[k] == gj[k] == hf.n - 1) for k in (0, 1)]
            assert any(on), f"crack / T-junction at edge {gi} - {gj}"


def test_flat_terrain_refines_to_one_square():
    hf = Heightfield(np.full((65, 65), 12.0), 5.0)
    for crit in (ALL, NONE):
        lod = refine_terrain(hf, _cam(65, 5.0), crit)
        assert lod.triangles == 2 and not any(s.any() for s in lod.split)
    tilted = Heightfield(np.add.outer(np.arange(33) * 0.3, np.arange(33) * -0.2), 1.0)  # a plane
    assert refine_terrain(tilted, _cam(33, 1.0), NONE).triangles == 2


def test_point_bump_refines_only_near_it():
    z = np.zeros((129, 129))
    z[40, 90] = 5.0
    hf = Heightfield(z, 1.0)
    lod = refine_terrain(hf, _cam(129, 1.0), NONE)
    _check_crack_free(hf, lod)
    assert lod.split[-1].sum() >= 1  # refined to the finest level at the bump
    L = hf.levels
    for l in range(L):
        s = 2 ** (L - l)
        for i, j in np.argwhere(lod.split[l]):
            # every split square lies within a few squares of its level around the bump (restriction halo)
            assert abs(i * s + s / 2 - 40) <= 2.5 * s and abs(j * s + s / 2 - 90) <= 2.5 * s
    assert lod.triangles < 0.02 * hf.full_triangles


def test_no_criteria_is_the_full_mesh():
    hf = Heightfield(fractal_heightfield(33, seed=3, relief=10.0), 2.0)
    lod = refine_terrain(hf, _cam(33, 2.0), NONE)
    V, F = full_mesh(hf)
    assert lod.triangles == len(F) == hf.full_triangles
    _check_crack_free(hf, lod)


@pytest.mark.parametrize("seed", [0, 1])
def test_crack_free_with_perception(seed):
    hf = Heightfield(fractal_heightfield(129, seed=seed, relief=40.0), 4.0)
    cam = _cam(129, 4.0, yaw=0.3 * seed)
    prev = (_cam(129, 4.0, yaw=0.3 * seed - 0.05), _cam(129, 4.0, yaw=0.3 * seed - 0.1))
    crit = TerrainCriteria(cull=False, xi=6.0)
    lod = refine_terrain(hf, cam, crit, prev, dt_s=1 / 30)
    assert 2 < lod.triangles < hf.full_triangles
    _check_crack_free(hf, lod)
    # restricted: leaves adjacent across an edge differ by at most one level
    depth = np.zeros((hf.n - 1,) * 2, int)
    for l, rc in enumerate(lod.drawn):
        s = 2 ** (hf.levels - l)
        for i, j in rc:
            depth[i * s:(i + 1) * s, j * s:(j + 1) * s] = l
    assert np.abs(np.diff(depth, axis=0)).max() <= 1 and np.abs(np.diff(depth, axis=1)).max() <= 1


def test_adding_a_criterion_never_adds_triangles():
    hf = Heightfield(fractal_heightfield(129, seed=5, relief=60.0), 8.0)
    cam = _cam(129, 8.0, height=80.0, yaw=0.4)
    cam = TerrainCamera(cam.eye, cam.forward, fov_deg=(90.0, 60.0), gaze_deg=(10.0, -5.0))
    prev = (TerrainCamera(cam.eye - [3.0, 0, 0], cam.forward + [0.05, 0, 0], fov_deg=(90.0, 60.0)),)
    names = ("size", "periphery", "velocity", "cull")
    counts = {}
    for mask in range(16):
        on = {k: bool(mask >> b & 1) for b, k in enumerate(names)}
        counts[mask] = refine_terrain(hf, cam, TerrainCriteria(xi=1.0, **on), prev).triangles
    for mask in range(16):
        for b in range(4):
            if not mask >> b & 1:
                assert counts[mask | 1 << b] <= counts[mask], (mask, names[b])
    assert counts[15] < counts[9] < counts[0] == hf.full_triangles  # all < size + cull < none


def test_culling_drops_everything_behind():
    hf = Heightfield(fractal_heightfield(65, seed=2, relief=10.0), 1.0)
    cam = TerrainCamera(eye=np.array([32.0, 20.0, -10.0]), forward=np.array([0.0, 0.0, -1.0]), fov_deg=(90.0, 60.0))
    assert refine_terrain(hf, cam, TerrainCriteria(size=False, periphery=False, velocity=False)).triangles == 0
    wide = TerrainCamera(cam.eye, cam.forward, fov_deg=(359.0, 179.0))
    assert refine_terrain(hf, wide, TerrainCriteria(size=False, periphery=False, velocity=False)).triangles \
        == hf.full_triangles


def test_velocity_and_eccentricity_lower_the_count():
    hf = Heightfield(fractal_heightfield(129, seed=7, relief=50.0), 4.0)
    cam = _cam(129, 4.0)
    base = refine_terrain(hf, cam, TerrainCriteria(periphery=False, velocity=False, xi=10.0)).triangles
    counts = [refine_terrain(hf, cam, TerrainCriteria(periphery=False, velocity_deg_s=v, xi=10.0)).triangles
              for v in (0.5, 20.0, 80.0, 200.0)]
    assert counts[0] == base and counts[0] >= counts[1] >= counts[2] >= counts[3] and counts[3] < base


@pytest.mark.parametrize("z, msg", [
    (np.zeros((0, 0)), "empty"),
    (np.zeros((10, 10)), "2^n + 1"),
    (np.zeros((9, 17)), "square"),
    (np.where(np.eye(9) > 0, np.nan, 0.0), "non-finite"),
])
def test_bad_heightfields(z, msg):
    with pytest.raises(PlodError, match=msg.replace("^", r"\^").replace("+", r"\+")) as err:
        Heightfield(z, 1.0)
    assert "\n" not in str(err.value)

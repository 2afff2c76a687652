"""Reddy's perceptual terrain quadtree (optim._terrain) [Red01 Table 1]: refinement, cracks, monotonicity."""

import re

import numpy as np
import pytest

from optim._terrain import (Heightfield, TerrainCamera, TerrainCriteria, crop_heightfield, fractal_heightfield,
                            TerrainLOD, full_mesh, refine_terrain, straddle_triangles, terrain_mesh)
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


def _scripts_on_path():
    """reports/terrain/scripts on sys.path (monotone.py's scene generator and checks)."""
    import sys
    from pathlib import Path

    p = str(Path(__file__).resolve().parents[1] / "reports" / "terrain" / "scripts")
    if p not in sys.path:
        sys.path.insert(0, p)


@pytest.mark.parametrize("seed", [3, 10, 29])
def test_adding_a_criterion_adds_triangles_only_where_the_view_boundary_crosses(seed):
    """On random scenes (reports/terrain/scripts/monotone.py's generator): the split sets are nested, and a
    criterion adds triangles only with cull on both sides, at most the straddling leaves' triangles.
    Seeds 10 and 29 are scenes where a criterion does add triangles; in 29 as many as the bound allows."""
    _scripts_on_path()
    from monotone import check, scene

    pairs, worse = check(*scene(np.random.default_rng(seed)))
    assert pairs == 32
    assert all(mask >> 3 & 1 and 0 < added <= bound for mask, _, added, bound in worse)
    assert bool(worse) == (seed in (10, 29))


@pytest.mark.parametrize("seed", [3, 10, 29, 41])
def test_split_view_edge_makes_adding_a_criterion_never_add_triangles(seed):
    """TerrainCriteria(split_view_edge=True): the squares the view's edge crosses split to the finest level,
    so on the scenes where a criterion adds triangles by default (10 and 29) none does: for all 32 pairs
    (mask, mask + one criterion) the split sets nest and the count does not grow. Every drawn leaf above
    the finest level is then wholly in view (straddle_triangles counts only finest leaves), the mesh has
    no crack (checked without cull, where the leaves tile the grid), and the option only adds splits to the
    default refinement."""
    _scripts_on_path()
    from monotone import NAMES, scene

    hf, cam, prev, xi = scene(np.random.default_rng(seed))
    lods, default = {}, {}
    for mask in range(16):
        on = {k: bool(mask >> b & 1) for b, k in enumerate(NAMES)}
        lods[mask] = refine_terrain(hf, cam, TerrainCriteria(xi=xi, split_view_edge=True, **on), prev)
        default[mask] = refine_terrain(hf, cam, TerrainCriteria(xi=xi, **on), prev)
        for a, b in zip(default[mask].split, lods[mask].split):
            assert not (a & ~b).any()
    added = []
    for mask in range(16):
        for b in range(4):
            if not mask >> b & 1:
                fine, coarse = lods[mask], lods[mask | 1 << b]
                for sf, sc in zip(fine.split, coarse.split):
                    assert not (sc & ~sf).any(), (mask, NAMES[b])
                added.append(default[mask | 1 << b].triangles - default[mask].triangles)
                assert coarse.triangles <= fine.triangles, (mask, NAMES[b])
    assert (max(added) > 0) == (seed in (10, 29))  # what the default does on these scenes
    for mask in (8, 15):  # cull alone, everything
        lod = lods[mask]
        edge_leaves = TerrainLOD(lod.split, [rc if l == hf.levels else rc[:0] for l, rc in enumerate(lod.drawn)],
                                 [f if l == hf.levels else f[:0] for l, f in enumerate(lod.fans)], 0, hf.levels)
        assert straddle_triangles(hf, cam, lod) == straddle_triangles(hf, cam, edge_leaves)
    _check_crack_free(hf, lods[7])  # (without cull the leaves tile the grid: the forced splits leave no crack)


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
    (np.full((9, 9), 1e300), "within 1e"),
    ([["a"] * 3] * 3, "must be real numbers"),
    (np.zeros((9, 9)) + 1j, "must be real numbers"),  # 2026-12-07: the imaginary part was dropped
])
def test_bad_heightfields(z, msg):
    with pytest.raises(PlodError, match=msg.replace("^", r"\^").replace("+", r"\+")) as err:
        Heightfield(z, 1.0)
    assert "\n" not in str(err.value)


_EYE, _FWD = np.array([16.0, 20.0, -5.0]), np.array([0.0, -0.3, 1.0])


@pytest.mark.parametrize("make, msg", [
    # each used to return a silently wrong frame (2 or 0 triangles, or the whole grid) or a raw traceback
    (lambda: TerrainCamera(np.array([np.nan, 1.0, 1.0]), _FWD), r"eye must be 3 finite numbers, got \[nan"),
    (lambda: TerrainCamera(_EYE, np.zeros(3)), "forward must be a nonzero vector"),
    (lambda: TerrainCamera(_EYE, _FWD, up=(0.0, 0.0, 0.0)), "up must be a nonzero vector"),
    (lambda: TerrainCamera(np.array([1e13, 0.0, 0.0]), _FWD), "eye must lie within"),
    (lambda: TerrainCamera(_EYE, _FWD, fov_deg=(0.0, 30.0)), r"fov_deg must be in \(0, 360\]"),
    (lambda: TerrainCamera(_EYE, _FWD, fov_deg=(400.0, 30.0)), r"fov_deg must be in \(0, 360\]"),
    (lambda: TerrainCamera(_EYE, _FWD, fov_deg=(float("nan"), 30.0)), "fov_deg must be 2 finite numbers"),
    (lambda: TerrainCamera(_EYE, _FWD, gaze_deg=(0.0, 120.0)), r"gaze_deg must be in \[-180, 180\]"),
    (lambda: TerrainCriteria(xi=0.0), r"xi must be a finite number in \[1e-06, 1e\+30\]"),
    (lambda: TerrainCriteria(xi=1e-300), r"xi must be a finite number in \[1e-06"),  # was refused late, as ReddyAcuity.xi
    (lambda: TerrainCriteria(xi=1e308), r"xi must be a finite number in \[1e-06"),
    (lambda: TerrainCriteria(velocity_deg_s=-5.0), r"velocity_deg_s must be a finite number in \[0, 1e\+30\]"),
    (lambda: TerrainCriteria(velocity_deg_s=float("nan")), "velocity_deg_s must be a finite number in"),
    (lambda: TerrainCriteria(tol=float("nan")), "tol must be a finite number in"),
    (lambda: TerrainCriteria(cull="yes"), "cull must be True or False"),
    (lambda: TerrainCriteria(split_view_edge=1), "split_view_edge must be True or False"),
    (lambda: refine_terrain(Heightfield(np.zeros((9, 9)), 1.0), TerrainCamera(_EYE, _FWD), previous=(1,)),
     r"previous\[0\] must be a TerrainCamera"),
    # 2026-12-07 fuzz round: raw TypeError / AttributeError / ValueError before
    (lambda: refine_terrain(Heightfield(np.zeros((9, 9)), 1.0), TerrainCamera(_EYE, _FWD), previous=None),
     "previous must be a sequence of TerrainCamera"),
    (lambda: refine_terrain(Heightfield(np.zeros((9, 9)), 1.0), TerrainCamera(_EYE, _FWD),
                            previous=TerrainCamera(_EYE, _FWD)), "previous must be a sequence of TerrainCamera"),
    (lambda: refine_terrain(Heightfield(np.zeros((9, 9)), 1.0), TerrainCamera(_EYE, _FWD), None),
     "criteria must be a TerrainCriteria"),
    (lambda: refine_terrain(np.zeros((9, 9)), TerrainCamera(_EYE, _FWD)), "hf must be a Heightfield"),
    (lambda: refine_terrain(Heightfield(np.zeros((9, 9)), 1.0), TerrainCamera(_EYE, _FWD), dt_s="0.1"),
     "dt_s must be a finite positive time step"),
    (lambda: refine_terrain(Heightfield(np.zeros((9, 9)), 1.0), TerrainCamera(_EYE, _FWD), dt_s=1e-310),
     "dt_s must be a finite positive time step"),  # 1 / dt overflowed: a NaN velocity, 2 triangles
    (lambda: refine_terrain(Heightfield(np.zeros((9, 9)), 1.0), TerrainCamera(_EYE, _FWD), dt_s=float("inf")),
     "dt_s must be a finite positive time step"),
    (lambda: Heightfield(np.zeros((9, 9)), "2"), "spacing must be a positive number"),
    (lambda: Heightfield(np.zeros((9, 9)), np.array([2.0])), "spacing must be a positive number"),
    (lambda: Heightfield(np.zeros((9, 9)), 1 + 2j), "spacing must be a positive number"),
    (lambda: TerrainCamera(_EYE, _FWD, up=_FWD * 3).rotation(), "up is parallel to its forward"),
    (lambda: terrain_mesh(Heightfield(np.zeros((17, 17)), 1.0),
                                refine_terrain(Heightfield(np.zeros((33, 33)), 1.0), TerrainCamera(_EYE, _FWD))),
     "the refinement is of a 33-sample grid, the heightfield has 17"),  # was 0 faces, silently
    (lambda: straddle_triangles(Heightfield(np.zeros((33, 33)), 1.0), TerrainCamera(_EYE, _FWD),
                                refine_terrain(Heightfield(np.zeros((17, 17)), 1.0), TerrainCamera(_EYE, _FWD))),
     "the refinement is of a 17-sample grid"),  # was an IndexError
    (lambda: fractal_heightfield(17.0), "n must be an integer >= 2"),
    (lambda: fractal_heightfield(17, seed=-1), "seed must be an integer >= 0"),
    (lambda: fractal_heightfield(17, relief=-5.0), "relief must be a finite number > 0"),  # was an inverted terrain
    (lambda: fractal_heightfield(65, beta=1e6), "gives non-finite heights"),
    (lambda: fractal_heightfield(65, dtype=np.int16), "dtype must be a floating type"),  # was all zeros
    (lambda: crop_heightfield(np.zeros((9, 9)), 5.0), "crop size must be an integer"),
    (lambda: crop_heightfield(np.zeros((9, 9)), -3), "crop size must be an integer >= 1"),  # was a (0, 0) grid
    (lambda: crop_heightfield(np.zeros((9, 9)), 3, row=-1), "crop row must be an integer >= 0"),
])
def test_bad_cameras_and_criteria(make, msg):
    with pytest.raises(PlodError, match=msg) as err:
        make()
    assert "\n" not in str(err.value) and "np.float64" not in str(err.value)


# ---------------------------------------------------------------------------------- slow reference
def _unit(x):
    return x / np.linalg.norm(x)


def _deg(a, b):
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


def _ref_arc(g, a, b):
    """Angle (deg) from g to the minor great-circle arc a-b, by projecting g onto the arc's plane."""
    n = np.cross(a, b)
    if np.linalg.norm(n) > 1e-12:
        n = _unit(n)
        q = g - np.dot(n, g) * n
        if np.linalg.norm(q) > 0:
            q = _unit(q)
            if np.dot(np.cross(a, q), n) >= 0 and np.dot(np.cross(q, b), n) >= 0:  # q between a and b
                return min(float(np.degrees(np.arcsin(min(1.0, abs(np.dot(n, g)))))), _deg(a, g), _deg(b, g))
    return min(_deg(a, g), _deg(b, g))


def _ref_culled(hf, cam, l, i, j):
    s = 2 ** (hf.levels - l) * hf.spacing
    lo, hi = hf.zmin[l][i, j], hf.zmax[l][i, j]
    centre = np.array([(j + 0.5) * s, 0.5 * (lo + hi), (i + 0.5) * s])
    r = np.sqrt(0.5 * s * s + 0.25 * (hi - lo) ** 2)
    d = cam.rotation() @ (centre - cam.eye)
    dist = np.linalg.norm(d)
    if dist <= r:
        return False
    u, rho = d / dist, np.arcsin(r / dist)
    hx, hy = (np.radians(a / 2) for a in cam.fov_deg)
    out_p = u[0] * np.cos(hx) + u[2] * np.sin(hx) > r / dist
    out_m = -u[0] * np.cos(hx) + u[2] * np.sin(hx) > r / dist
    side = (out_p and out_m) if hx >= np.pi / 2 else (out_p or out_m)
    el = np.arcsin(np.clip(u[1], -1, 1))
    return bool(side or el - rho > hy or el + rho < -hy)


def _reference_refine(hf, cam, crit, previous, dt_s):
    """One square at a time, straight from the module docstring: (raw split sets, triangles)."""
    from optim import _terrain as T

    L, g = hf.levels, cam.gaze()
    split = [np.zeros((2 ** l, 2 ** l), bool) for l in range(L)]

    def visit(l, i, j):
        if l == L or hf.err[l][i, j] <= crit.tol or (crit.cull and _ref_culled(hf, cam, l, i, j)):
            return
        if crit.size:
            s = 2 ** (L - l)
            corners = [(i * s, j * s), (i * s, (j + 1) * s), ((i + 1) * s, (j + 1) * s), ((i + 1) * s, j * s)]
            P = [hf.points(np.array(r), np.array(c)) for r, c in corners]
            D = [_unit(cam.rotation() @ (p - cam.eye)) for p in P]
            ext = max(_deg(D[a], D[b]) for a in range(4) for b in range(a + 1, 4))
            e = 0.0
            if crit.periphery:
                sides = [np.dot(np.cross(D[k], D[(k + 1) % 4]), g) for k in range(4)]
                inside = (all(x >= 0 for x in sides) or all(x <= 0 for x in sides)) and all(np.dot(d, g) > 0 for d in D)
                e = 0.0 if inside else min(_ref_arc(g, D[k], D[(k + 1) % 4]) for k in range(4))
            v = 0.0
            if crit.velocity:
                if crit.velocity_deg_s is not None:
                    v = float(crit.velocity_deg_s)
                elif previous:
                    per_corner = []
                    for p, d in zip(P, D):
                        prev, acc = d, 0.0
                        for cp in previous:
                            dp = _unit(cp.rotation() @ (p - cp.eye))
                            acc += _deg(prev, dp)
                            prev = dp
                        per_corner.append(acc / (len(previous) * dt_s))
                    v = min(per_corner)
            H = float(T._acuity(crit.xi, np.array([e]), np.array([v]))[0])
            if ext < 1.0 / (2.0 * H):
                return
        split[l][i, j] = True
        for di in (0, 1):
            for dj in (0, 1):
                visit(l + 1, 2 * i + di, 2 * j + dj)

    visit(0, 0, 0)
    raw = [s.copy() for s in split]
    T._restrict(split)
    tri = 0
    for l in range(L + 1):
        for i in range(2 ** l):
            for j in range(2 ** l):
                parent_split = l == 0 or split[l - 1][i // 2, j // 2]
                if not parent_split or (l < L and split[l][i, j]):
                    continue
                if crit.cull and _ref_culled(hf, cam, l, i, j):
                    continue
                k = 0
                if l < L:
                    for di, dj in ((-1, 0), (0, 1), (1, 0), (0, -1)):
                        a, b = i + di, j + dj
                        k += bool(0 <= a < 2 ** l and 0 <= b < 2 ** l and split[l][a, b])
                tri += 2 if k == 0 else 4 + k
    return raw, split, tri


# (eye, field of view, gaze, xi): far and near, wide and narrow, gaze on and off the terrain
REF_CASES = [((16, 40, -30), (200, 135), (60, 0), 0.12), ((-20, 25, 10), (40, 30), (10, -5), 0.15),
             ((16, 6, 16), (120, 90), (-40, 20), 3.0), ((40, 60, 40), (200, 135), (5, -30), 0.15)]


@pytest.mark.parametrize("case", range(len(REF_CASES)))
def test_vectorized_refinement_equals_the_slow_reference(case, monkeypatch):
    """Every criteria combination, measured and imposed velocity: the vectorized-by-level refinement
    (with its bounds that skip exact work) splits exactly the squares the one-square-at-a-time reference
    splits and draws the same triangles, with the coarse levels' batched float64 test (the default on
    this grid) and with the float32 bound pass on every level."""
    from optim import _terrain as T

    default = T._SMALL_LEVELS

    eye, fov, gaze, xi = REF_CASES[case]
    hf = Heightfield(fractal_heightfield(33, seed=10 + case, relief=8.0), 1.0)
    eye = np.array(eye, float)
    fwd = np.array([16.0, 0.0, 16.0]) - eye if case != 2 else np.array([1.0, -0.3, 0.2])
    cam = TerrainCamera(eye, fwd, fov_deg=fov, gaze_deg=gaze)
    prev = tuple(TerrainCamera(eye - [1.0 * k, 0.3 * k, 0.0], fwd + np.array([0.2 * k, 0, -0.1 * k]) * np.linalg.norm(fwd),
                               fov_deg=fov) for k in (1, 2, 3))
    names = ("size", "periphery", "velocity", "cull")
    counts = set()
    for mask in range(16):
        on = {k: bool(mask >> b & 1) for b, k in enumerate(names)}
        for imposed in ((None, 45.0) if on["velocity"] else (None,)):
            crit = TerrainCriteria(xi=xi, velocity_deg_s=imposed, **on)
            raw, split, tri = _reference_refine(hf, cam, crit, prev, 1 / 30)
            for small in (default, -1):
                monkeypatch.setattr(T, "_SMALL_LEVELS", small)
                lod = refine_terrain(hf, cam, crit, prev, dt_s=1 / 30)
                for l in range(hf.levels):
                    np.testing.assert_array_equal(lod.split[l], split[l], err_msg=f"{on} {imposed} {small} level {l}")
                assert lod.triangles == tri, (on, imposed, small)
            counts.add(tri)
    assert len(counts) >= 4  # the criteria act in this case (not all full or all empty)


# ------------------------------------------------------------------ the float32 bound pass
def test_bound_pass_equals_the_float64_path(monkeypatch):
    """The float32 bound pass (strips of a few rows here, so several per level) with its float64 fallback
    splits exactly the squares the float64 test alone splits, for every criteria combination over frames
    of a fast flight (measured and imposed velocity, the motion bound and the velocity pass)."""
    from experiments.terrain import FLIGHT, flight_cameras
    from optim import _terrain as T

    hf = Heightfield(fractal_heightfield(129, seed=4, relief=60.0), 10.0)
    cams = flight_cameras(hf, dict(FLIGHT))
    names = ("size", "periphery", "velocity", "cull")
    monkeypatch.setattr(T, "_STRIP_NODES", 600)
    counts = set()
    for k in (40, 301):
        prev = (cams[k - 1], cams[k - 2], cams[k - 3])
        for mask in range(16):
            on = {n: bool(mask >> b & 1) for b, n in enumerate(names)}
            if not on["size"]:
                continue
            for imposed in ((None, 45.0) if on["velocity"] else (None,)):
                crit = TerrainCriteria(xi=0.8, velocity_deg_s=imposed, **on)
                monkeypatch.setattr(T, "_BOUND_MIN", 0)
                fast = refine_terrain(hf, cams[k], crit, prev)
                monkeypatch.setattr(T, "_BOUND_MIN", 1 << 40)  # the float64 test everywhere
                ref = refine_terrain(hf, cams[k], crit, prev)
                for l in range(hf.levels):
                    np.testing.assert_array_equal(fast.split[l], ref.split[l], err_msg=f"{k} {on} {imposed} level {l}")
                assert fast.triangles == ref.triangles
                counts.add(ref.triangles)
    assert len(counts) >= 8  # the criteria act (not all full or all empty)


def test_bound_pass_error_budget():
    """The error bounds the bound pass relies on hold with room: float32 directions against float64 (world
    axes and rotated), the chord series bound, and JAX's float32 H' against the closed form on its
    float32 constants."""
    from optim import _terrain as T
    from optim._terrain_bounds import dirs32

    rng = np.random.default_rng(0)
    z = rng.uniform(0.0, 600.0, (40, 50))
    X, Z = np.arange(50) * 10.0, np.arange(40) * 10.0
    worst = 0.0
    for _ in range(20):
        eye = rng.uniform([-100.0, 0.0, -100.0], [600.0, 900.0, 500.0])
        R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        P = np.stack(np.broadcast_arrays(X[None, :], z, Z[:, None]), -1) - eye
        for rot in (None, R):
            d = P if rot is None else P @ rot.T
            d = d / np.linalg.norm(d, axis=-1, keepdims=True)
            got = dirs32(z, X, Z, eye, rot)
            worst = max(worst, float(np.max(np.linalg.norm(np.stack(got, -1) - d, axis=-1))))
    assert worst < T._EPS_DIR / 4, worst
    c = np.linspace(1e-4, T._CHORD_MAX, 10001)
    exact = 2 * np.arcsin(c / 2)
    assert np.all(exact <= c + c ** 3 * T._SERIES) and np.all(exact >= c + c ** 3 / 24)
    assert np.all(2 * np.arcsin(np.linspace(0, 2, 1001) / 2) <= np.pi / 2 * np.linspace(0, 2, 1001) + 1e-12)
    for xi in (3.2, 0.4, None):
        e = np.concatenate([rng.uniform(0, 180, 20000), rng.uniform(0, 10, 5000), [0.0]])
        v = np.concatenate([10 ** rng.uniform(-3, 4, 20000), 10 ** rng.uniform(-1, 2.5, 5000), [0.0]])
        xi32, gmax, gint, gsl, gmin, ms, mr = T._acuity_consts(xi)
        e32, v32 = e.astype(np.float32).astype(float), v.astype(np.float32).astype(float)
        G = np.clip(gint - gsl * np.log(np.maximum(v32, 1e-300)), gmin, gmax)
        H = np.minimum(xi32, G * np.minimum(1.0, ms / (1 + mr * e32) ** 2))
        assert np.max(np.abs(T._acuity(xi, e, v) / H - 1)) < T._MU / 10


def test_bound_pass_decisions_agree_with_the_float64_test():
    """The compiled float32 bound pass (optim._terrain_bounds) over whole levels: every square it decides
    has the float64 test's answer (yes: perceptible, no: not), it decides nearly all of them, and a corner
    at the eye (no direction: NaN) leaves its squares to the float64 test instead of deciding them."""
    from optim import _terrain as T

    hf = Heightfield(fractal_heightfield(129, seed=3, relief=30.0), 1.0)
    decided = total = balance = 0
    # (xi, eye scale, gaze): the display's cap binding; no cap, far, gaze off-centre (e and v matter)
    for xi, sc, gaze in ((3.2, 1.0, (4.0, -2.0)), (None, 6.0, (25.0, -10.0))):
        eye = np.array([-900.0, 360.0, -600.0]) * sc
        fwd = 64.0 - eye
        cam = TerrainCamera(eye, fwd, fov_deg=(120, 90), gaze_deg=gaze)
        prev = [TerrainCamera(eye - [2.0 * k * sc, 0.1 * k, -1.5 * k * sc], fwd + np.array([0.0, 0, -12.0 * k * sc]),
                              fov_deg=(120, 90)) for k in (1, 2, 3)]
        R, g = cam.rotation(), cam.gaze()
        moves = [(np.asarray(c.eye, float), c.rotation()) for c in prev]
        mo = T._motion(eye, R, moves, 1 / 30)
        for per in (False, True):
            for vel in (None, "measured", 5.0):
                crit = TerrainCriteria(periphery=per, velocity=vel is not None,
                                       velocity_deg_s=vel if isinstance(vel, float) else None, xi=xi)
                for l in (6, 7):
                    m = 2 ** l
                    with np.errstate(all="ignore"):
                        yes, no = T._strip_bounds(hf, eye, R.T @ g, crit, mo, 1 / 30, l, 0, m, 0, m, np.ones((m, m), bool))
                    a, b = np.divmod(np.arange(m * m), m)
                    exact = T._perceptible_exact(hf, cam, R, g, crit, moves, 1 / 30, l, a, b).reshape(m, m)
                    assert not np.any(yes & ~exact) and not np.any(no & exact), (xi, per, vel, l)
                    decided += np.count_nonzero(yes | no)
                    total += m * m
                    balance += 0.1 < exact.mean() < 0.95
    assert decided > 0.97 * total, decided / total
    assert balance >= 8  # the answers are mixed (a test that decides everything one way proves nothing)
    # the eye exactly at a grid node: its four squares are left open, the others decided as before
    i, j = 64, 40
    eye = np.array([j * 1.0, hf.heights[i, j], i * 1.0])
    crit = TerrainCriteria(periphery=True, velocity=False, xi=3.2)
    with np.errstate(all="ignore"):
        yes, no = T._strip_bounds(hf, eye, np.array([1.0, 0.0, 0.0]), crit, None, 1 / 30, 7, 0, 128, 0, 128,
                                  np.ones((128, 128), bool))
    around = np.zeros((128, 128), bool)
    around[i - 1:i + 1, j - 1:j + 1] = True
    assert not np.any((yes | no) & around) and np.count_nonzero(yes | no) > 0.9 * 128 * 128


@pytest.mark.parametrize("line, msg", [
    # each ran (a negative relief, one resolution number), or failed with a message naming no key
    # ("range() arg 3 must not be zero", a ZeroDivisionError traceback for pixel_errors = [0])
    ("fractal_size = 1000", "'fractal_size' must be 2^n + 1"),
    ("fractal_relief_m = -5.0", "'fractal_relief_m' must be a finite number of metres > 0"),
    ("resolution = [1280]", "'resolution' must be two pixel counts"),
    ("frame_step = 0", "'frame_step' must be an integer >= 1"),
    ("pixel_errors = [0]", "'pixel_errors' must be a non-empty list of pixel errors in (0, 10000]"),
    # 2026-12-07 fuzz round: each failed late (an xi the acuity model refused, a Display of negative width, an
    # IndexError traceback for a 3-frame flight, 'Maximum allowed size exceeded', a render never tried)
    ("pixel_errors = [1e300]", "'pixel_errors' must be a non-empty list of pixel errors in (0, 10000]"),
    ("judge_px_per_deg = 0.011", "'judge_px_per_deg' must be 0 (twice xi) or 1 .. 40 pixels per degree"),
    ("judge_px_per_deg = 1000.0", "'judge_px_per_deg' must be 0 (twice xi) or 1 .. 40 pixels per degree"),
    ("resolution = [1, 864]\njudge_frames = [10]", "judge_px_per_deg = 0 takes twice xi, 0.005 pixels per degree"),
    ("judge_frames = [5000]", "'judge_frames' has frame 5000, outside the flight's 3 .. 600"),
    ('flight = "SHORT"', "'duration_s' must be such that duration_s x fps (= 1.5) gives 4 .. 1,000,000 frames"),
    ('flight = "LONG"', "'duration_s' must be such that duration_s x fps (= 3e+301) gives 4"),
    ("fig4_fovs = [400.0]", "'fig4_fovs' must be a non-empty list of square fields of view"),
    ("fig4_velocities = [-10.0]", "'fig4_velocities' must be a non-empty list of velocities >= 0"),
    ("judge_frames = [1]", "'judge_frames' must be a list of flight frames >= 3"),
    ('flight = "FLIGHT"', "'fov_deg' must be two angles"),
])
def test_terrain_config_values_are_checked_before_work(tmp_path, line, msg):
    from experiments.terrain import run_config

    (tmp_path / "flight.toml").write_text("fov_deg = [200.0, 0.0]\n")
    (tmp_path / "short.toml").write_text("duration_s = 0.05\n")
    (tmp_path / "long.toml").write_text("duration_s = 1e300\n")
    cfg = tmp_path / "t.toml"
    size = "" if line.startswith("fractal_size") else "fractal_size = 33\n"
    for word, name in (("FLIGHT", "flight"), ("SHORT", "short"), ("LONG", "long")):
        line = line.replace(word, str(tmp_path / f"{name}.toml"))
    cfg.write_text('kind = "terrain"\n' + size + line + "\n")
    with pytest.raises(PlodError, match=re.escape(msg)) as err:
        run_config(cfg, out=tmp_path / "out")
    assert "\n" not in str(err.value) and not (tmp_path / "out").exists()


def _pgm(path, magic, w, h, maxval, values):
    v = np.asarray(values)
    if magic == b"P2":
        body = " ".join(map(str, v.ravel())).encode()
    else:
        body = v.astype(">u2" if maxval > 255 else "u1").tobytes()
    path.write_bytes(magic + b"\n# a comment\n" + f"{w} {h}\n{maxval}\n".encode() + body)
    return path


@pytest.mark.parametrize("magic, maxval", [(b"P5", 2543), (b"P5", 65535), (b"P5", 200), (b"P5", 255),
                                           (b"P2", 2543), (b"P2", 100)])
def test_pgm_samples_are_read_as_stored(tmp_path, magic, maxval):
    """Pillow rescales a PGM's samples to 0..255 / 0..65535 from its maxval: a DEM whose maxval is its top
    elevation (2543 m) read 25.8 x too tall."""
    from experiments.terrain import read_pgm

    v = np.random.default_rng(maxval).integers(0, maxval + 1, (5, 7))
    v[0, 0], v[0, 1] = 0, maxval
    got = read_pgm(_pgm(tmp_path / "t.pgm", magic, 7, 5, maxval, v))
    assert got.dtype == np.float64 and np.array_equal(got, v)


@pytest.mark.parametrize("content", [b"", b"garbage, not an image", b"P5\n7 5\n2543\n\x00\x01",
                                     b"P6\n1 1\n255\n\x00\x00\x00", b"P5\n7 5\n70000\n" + bytes(70)])
def test_bad_pgm_files_are_one_line(tmp_path, content):
    from experiments.terrain import read_pgm

    (tmp_path / "t.pgm").write_bytes(content)
    with pytest.raises(PlodError, match="t.pgm") as err:
        read_pgm(tmp_path / "t.pgm")
    assert "\n" not in str(err.value)


def test_random_valid_scenes_are_crack_free_and_bounded():
    """hypothesis over the cameras and criteria monotone.py draws (grids 33, 65), cull off: the drawn mesh
    tiles the grid with no crack, its triangles are counted right, and adding the cull criterion never adds
    triangles (the case the straddling bound allows none); with cull on, the counts agree too."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    _scripts_on_path()
    from monotone import scene

    @settings(max_examples=20, deadline=None, derandomize=True)
    @given(seed=st.integers(0, 2**31 - 1), size=st.booleans(), periphery=st.booleans(), velocity=st.booleans())
    def check(seed, size, periphery, velocity):
        hf, cam, prev, xi = scene(np.random.default_rng(seed), sizes=(33, 65))
        crit = dict(size=size, periphery=periphery, velocity=velocity, xi=xi)
        lod = refine_terrain(hf, cam, TerrainCriteria(cull=False, **crit), prev)
        _check_crack_free(hf, lod)
        culled = refine_terrain(hf, cam, TerrainCriteria(cull=True, **crit), prev)
        assert culled.triangles <= lod.triangles
        assert len(terrain_mesh(hf, culled)[1]) == culled.triangles

    check()


def test_bound_pass_answers_as_the_float64_test_at_any_scale(monkeypatch):
    """hypothesis over monotone.py's scenes with every length scaled by 1e-7 .. 3e8 (the error budget is in
    angles, so it must not depend on units), any criteria, imposed or measured velocity, display cap or
    none, time steps 1 ms .. 1 s: the refinement with the compiled float32 bound pass on every level splits
    exactly what the float64 test alone splits."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from optim import _terrain as T

    _scripts_on_path()
    from monotone import scene

    small = T._SMALL_LEVELS

    @settings(max_examples=15, deadline=None, derandomize=True)
    @given(seed=st.integers(0, 2**31 - 1), log_k=st.floats(-7.0, 8.5), flags=st.integers(0, 63),
           v=st.floats(0.0, 200.0), log_dt=st.floats(-3.0, 0.0))
    def check(seed, log_k, flags, v, log_dt):
        hf0, cam0, prev0, xi = scene(np.random.default_rng(seed), sizes=(17, 33))
        k = 10.0 ** log_k
        hf = Heightfield(hf0.heights * k, hf0.spacing * k)
        cams = [TerrainCamera(np.asarray(c.eye) * k, c.forward, fov_deg=c.fov_deg, gaze_deg=c.gaze_deg)
                for c in (cam0, *prev0)]
        crit = TerrainCriteria(periphery=bool(flags & 1), velocity=bool(flags & 2), cull=bool(flags & 4),
                               xi=None if flags & 8 else xi, velocity_deg_s=v if flags & 16 else None)
        got = []
        for bound_min in (0, 1 << 40):  # the bound pass on every level; the float64 test alone
            monkeypatch.setattr(T, "_BOUND_MIN", bound_min)
            monkeypatch.setattr(T, "_SMALL_LEVELS", 0 if flags & 32 else small)  # coarse levels batched or not
            got.append(refine_terrain(hf, cams[0], crit, tuple(cams[1:]), dt_s=10.0 ** log_dt))
        assert got[0].triangles == got[1].triangles
        for a, b in zip(got[0].split, got[1].split):
            np.testing.assert_array_equal(a, b)

    check()


# ------------------------------------------------------------------- 2026-12-07 fuzz round: silent answers
def _scene33():
    z = fractal_heightfield(33, seed=1, relief=8.0)
    cam = TerrainCamera(np.array([16.0, 20.0, -5.0]), np.array([0.0, -0.3, 1.0]))
    prev = tuple(TerrainCamera(cam.eye - [k, 0.3 * k, 0], np.array([0.2 * k, -0.3, 1.0])) for k in (1, 2, 3))
    return z, cam, prev


def test_previous_cameras_may_come_from_a_generator():
    """A generator of previous cameras was used up by the type check: the velocity then came out 0."""
    z, cam, prev = _scene33()
    hf, crit = Heightfield(z, 1.0), TerrainCriteria(xi=0.3, periphery=False)
    want = refine_terrain(hf, cam, crit, prev)
    assert want.triangles < refine_terrain(hf, cam, crit, ()).triangles  # the velocity bites here
    assert refine_terrain(hf, cam, crit, (c for c in prev)).triangles == want.triangles


def test_flatness_is_rounding_in_any_unit_and_offset():
    """Flat meant an error below 1e-9 (1 + max |h|): relief at 1e-9 m units, or 1 mm on a 1e6 m base, was
    flattened (2 triangles for 2048). Now only rounding of a plane counts as flat, in any unit."""
    z, cam, _ = _scene33()
    want = refine_terrain(Heightfield(z, 1.0), cam, NONE).triangles
    assert want == 2048
    for k in (1e-9, 1e-10, 2.0 ** -40):  # the whole scene in other length units
        hf = Heightfield(z * k, k)
        got = refine_terrain(hf, TerrainCamera(cam.eye * k, cam.forward), NONE)
        assert got.triangles == want, k
    base = Heightfield(z / 8e3 + 1e6, 1.0)  # 1 mm of relief at 1,000 km
    assert refine_terrain(base, TerrainCamera(cam.eye + [0, 1e6, 0], cam.forward), NONE).triangles == want
    plane = np.add.outer(np.arange(33) * 0.37, np.arange(33) * -1.3) + 1e6  # a tilted plane far from 0
    assert refine_terrain(Heightfield(plane, 1.0), cam, NONE).triangles == 2


def test_a_still_camera_has_no_velocity_at_any_time_step():
    """The float64 velocity was acos of a dot product: ~1e-6 deg of rounding per step for a still corner,
    which a short time step made a large velocity (2,038 or 2 triangles for 2,048)."""
    z, cam, _ = _scene33()
    hf, crit = Heightfield(z, 1.0), TerrainCriteria(xi=0.3, periphery=False)
    want = refine_terrain(hf, cam, crit, ()).triangles
    for dt in (1 / 30, 1e-9, 1e-300):
        assert refine_terrain(hf, cam, crit, (cam, cam), dt_s=dt).triangles == want, dt


def test_cameras_of_any_vector_length():
    """A 1e-300 forward gave a NaN rotation (2 triangles); 1e308 components or a 1e-13 up were called
    parallel."""
    z, cam, _ = _scene33()
    hf = Heightfield(z, 1.0)
    want = refine_terrain(hf, cam, ALL)
    for fwd, up in ((cam.forward * 1e-300, (0, 1, 0)), (cam.forward * 1e300, (0, 1, 0)),
                    (cam.forward, (0, 1e-13, 0)), (cam.forward, (0, 1e300, 0))):
        c = TerrainCamera(cam.eye, fwd, up=up)
        np.testing.assert_allclose(c.rotation(), cam.rotation(), atol=1e-15)
        assert refine_terrain(hf, c, ALL).triangles == want.triangles


def test_heightfield_keeps_its_own_heights():
    """The heightfield shared the caller's array: changed afterwards, the refinement used the old pyramid
    and the mesh the new heights."""
    z, cam, _ = _scene33()
    hf = Heightfield(z, 1.0)
    before = refine_terrain(hf, cam, NONE)
    z[:] = 0.0
    assert not hf.heights.flags.writeable and hf.heights.any()
    V, F, _ = terrain_mesh(hf, before)
    assert V[:, 1].max() > 0 and refine_terrain(hf, cam, NONE).triangles == before.triangles


def test_fractal_heightfield_types():
    z = fractal_heightfield(17, seed=3, relief=5.0, dtype=np.float32)
    assert z.dtype == np.float32 and z.min() == 0.0 and abs(float(z.max()) - 5.0) < 1e-5
    np.testing.assert_allclose(z, fractal_heightfield(17, seed=3, relief=5.0), rtol=1e-6, atol=1e-6)

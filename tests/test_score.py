"""optim.score / node_terms / imperceptible_cut: silhouettes, culling, eccentricity, velocity,
contrast and keys against hand-computed geometry and slow numpy references."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import optim
import pmetric
from optim import View, imperceptible_cut, node_terms, score
from pmetric import PlodError
from tests._folds import incident_faces, left_faces, supported

EYE = np.array([0.0, 0.0, 4.0])


@pytest.fixture(scope="module")
def sphere_tree():
    v, f = optim.icosphere(3)
    return optim.build_tree(v, f, method="octree")


@pytest.fixture(scope="module")
def two_spheres_tree():
    """One sphere in front of a camera at the origin looking down -z, one behind it."""
    v, f = optim.icosphere(2, radius=0.5)
    verts = np.concatenate([v + [0, 0, -5], v + [0, 0, 5]])
    faces = np.concatenate([f, f + len(v)])
    return optim.build_tree(verts, faces, method="octree")


def _supported_triangles(tree, n):
    return incident_faces(tree, supported(tree, n))


def _left_cos(tree, n, eye):
    """:func:`_facing_cos` of the faces a fold of node ``n`` alone leaves (inside corners at its proxy)."""
    nn, p = left_faces(tree, n, corners=True)
    d = eye - p.mean(1)
    ok = np.linalg.norm(nn, axis=1) > 0
    return (nn[ok] * d[ok]).sum(1) / np.linalg.norm(nn[ok], axis=1) / np.linalg.norm(d[ok], axis=1)


def _facing_cos(tree, eye):
    """cos of the angle between each triangle's normal and the direction from its centroid to the eye."""
    p = tree.vertices[tree.faces]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    d = eye - p.mean(1)
    return (n * d).sum(1) / np.linalg.norm(n, axis=1) / np.linalg.norm(d, axis=1)


def test_sphere_rim_nodes_are_silhouette_interior_are_not(sphere_tree):
    tree = sphere_tree
    t = node_terms(tree, View(eye=EYE))
    cos = _facing_cos(tree, EYE)
    rim, interior, back = [], [], []
    for n in tree.internal:
        c = cos[_supported_triangles(tree, n)]
        # what the fold touches: the faces of the 2-ring of its vertices and the faces it leaves
        ring = np.unique(tree.faces[_supported_triangles(tree, n)])
        touched = np.concatenate([cos[incident_faces(tree, ring)], _left_cos(tree, n, EYE)])
        if (c > 0).any() and (c < 0).any():
            rim.append(n)  # supports front- and back-facing triangles: a true silhouette node
        elif (touched > 0.5).all():
            interior.append(n)  # every normal it touches within 60 deg of the eye direction
        elif (touched < -0.5).all():
            back.append(n)
    assert len(rim) > 10 and len(interior) > 10 and len(back) > 10
    assert t.silhouette[rim].all()  # conservative: every rim node is a silhouette node
    assert not t.silhouette[interior].any()
    assert not t.culled[interior].any()
    assert t.backfacing[back].all() and t.culled[back].all()  # wholly back facing: folded
    assert not t.backfacing[rim].any()


def test_silhouette_contrast_uses_scene_extremes(sphere_tree):
    tree = sphere_tree
    view = View(eye=EYE, background=0.0)
    t = node_terms(tree, view)
    d = view.display
    black, peak = float(d.black_level), float(d.peak_luminance)
    cd = lambda rel: black + (peak - black) * np.clip(rel, 0, 1)  # noqa: E731
    mich = lambda a, b: abs(a - b) / (a + b)  # noqa: E731
    cols = optim.region_columns(tree)  # what the triangles a fold changes show (baked: no lighting)
    lum_min, lum_max, fold_delta = cols["lum_min"], cols["lum_max"], cols["fold_delta"]
    lo_scene = min(lum_min.min(), 0.0)
    hi_scene = lum_max.max()
    for n in tree.internal[:200]:
        own = mich(cd(lum_min[n] + fold_delta[n]), cd(lum_min[n]))
        if t.silhouette[n]:
            sil = max(mich(cd(lum_max[n]), cd(lo_scene)), mich(cd(hi_scene), cd(lum_min[n])))
            want = max(own, sil)
        else:
            want = own
        assert t.contrast[n] == pytest.approx(want, rel=1e-4, abs=1e-6)
    # a black background against a lit model: silhouette folds reach nearly full contrast
    assert t.contrast[t.silhouette].max() > 0.95


def _reference_theta_ecc(tree, view, nodes, gaze):
    xy, depth = view.project(tree.center[nodes])
    dist = np.linalg.norm(tree.center[nodes] - view.eye, axis=1)
    s = tree.radius[nodes] / dist
    size = 2 * view.focal_px * s / np.sqrt(1 - s * s)
    theta = size * view.degrees_per_pixel
    ang = np.min([view.visual_angle_px(xy, np.broadcast_to(g, xy.shape)) for g in gaze], axis=0)
    return theta, np.maximum(ang - theta / 2 - view.gaze_error_deg, 0.0)


def test_eccentricity_matches_reference_and_clamps_at_zero(sphere_tree):
    tree = sphere_tree
    gaze = np.array([[700.0, 400.0]])
    view = View(eye=EYE, gaze=gaze, gaze_error_deg=1.0)
    t = node_terms(tree, view)
    nodes = tree.internal[~t.culled[tree.internal]]
    theta, ecc = _reference_theta_ecc(tree, view, nodes, gaze)
    assert t.theta[nodes] == pytest.approx(theta, rel=1e-4)
    assert t.eccentricity[nodes] == pytest.approx(ecc, rel=1e-3, abs=2e-3)
    assert (t.eccentricity[nodes] == 0).any() and (t.eccentricity[nodes] > 1).any()
    assert (t.eccentricity >= 0).all()
    # several viewers: the minimum eccentricity [LH01 §8.4]
    g2 = np.array([[1200.0, 700.0]])
    both = node_terms(tree, View(eye=EYE, gaze=np.concatenate([gaze, g2]))).eccentricity
    other = node_terms(tree, View(eye=EYE, gaze=g2)).eccentricity
    assert both[nodes] == pytest.approx(np.minimum(t.eccentricity, other)[nodes], abs=1e-5)
    # no gaze: every node foveal
    assert (node_terms(tree, View(eye=EYE, gaze=None)).eccentricity == 0).all()


def test_gaze_ring_is_the_nearest_point_of_the_circle(sphere_tree):
    """A gaze ring of radius r around a gaze point: eccentricity |angle - r| less theta/2 and the gaze error
    (closed form), equal to many gaze points spread on that circle (a slow reference), and the plain gaze
    when r = 0."""
    tree = sphere_tree
    gaze = np.array([[960.0, 540.0]])
    ring = 6.0
    view = View(eye=EYE, gaze=gaze, gaze_error_deg=0.5, gaze_ring_deg=ring)
    t = node_terms(tree, view)
    nodes = tree.internal[~t.culled[tree.internal]]
    xy, _ = view.project(tree.center[nodes])
    ang = view.visual_angle_px(xy, np.broadcast_to(gaze[0], xy.shape))
    theta, _ = _reference_theta_ecc(tree, view, nodes, gaze)
    want = np.maximum(np.abs(ang - ring) - theta / 2 - 0.5, 0.0)
    assert t.eccentricity[nodes] == pytest.approx(want, rel=1e-3, abs=2e-3)
    assert (want == 0).any() and (want > 2).any()  # nodes on the circle and well inside / outside it
    # the same as gaze directions spread on the circle (4,096 of them: within 0.005 deg of every point)
    c = view.rotation.T @ np.array([0.0, 0.0, -1.0])  # the screen centre's direction = gaze (960, 540)
    a = np.cross(c, [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(c, a)
    phi = np.linspace(0, 2 * np.pi, 4096, endpoint=False)[:, None]
    r = np.radians(ring)
    dirs = np.cos(r) * c + np.sin(r) * (np.cos(phi) * a + np.sin(phi) * b)
    many = node_terms(tree, View(eye=EYE, gaze=dirs, gaze_error_deg=0.5)).eccentricity
    assert t.eccentricity[nodes] == pytest.approx(many[nodes], abs=0.01)
    # radius 0 is the gaze point itself, bit for bit
    plain = node_terms(tree, View(eye=EYE, gaze=gaze, gaze_error_deg=0.5)).eccentricity
    zero = node_terms(tree, View(eye=EYE, gaze=gaze, gaze_error_deg=0.5, gaze_ring_deg=0.0)).eccentricity
    assert np.array_equal(plain, zero)


@pytest.mark.parametrize("bad", [-1.0, 181.0, float("nan"), "x", 1j])
def test_gaze_ring_out_of_range_is_refused(bad):
    with pytest.raises(PlodError, match="gaze_ring_deg"):
        View(eye=EYE, gaze_ring_deg=bad)


def test_gaze_ring_needs_a_gaze():
    with pytest.raises(PlodError, match="needs a gaze"):
        View(eye=EYE, gaze=None, gaze_ring_deg=5.0)


def test_huge_gaze_error_clamps_everything(sphere_tree):
    t = node_terms(sphere_tree, View(eye=EYE, gaze=[[0.0, 0.0]], gaze_error_deg=60.0))
    assert (t.eccentricity == 0).all()


def test_velocity_from_previous_view(sphere_tree):
    tree = sphere_tree
    a = View(eye=EYE)
    b = View(eye=(0.3, 0.0, 4.0), target=(0, 0, 0), previous=a, dt_s=0.05)
    t = node_terms(tree, b)
    nodes = tree.internal[~t.culled[tree.internal]][:50]
    xa, _ = a.project(tree.center[nodes])
    xb, _ = b.project(tree.center[nodes])
    want = b.visual_angle_px(xb, xa) / 0.05
    assert t.velocity[nodes] == pytest.approx(want, rel=1e-3, abs=1e-2)
    assert (node_terms(tree, a).velocity == 0).all()


def test_nodes_behind_the_camera_are_culled(two_spheres_tree):
    tree = two_spheres_tree
    view = View(eye=(0, 0, 0), target=(0, 0, -1))
    t = node_terms(tree, view)
    z = np.array([tree.vertices[supported(tree, n), 2].min() for n in tree.internal])
    behind = tree.internal[z > 0]
    front = tree.internal[np.array([tree.vertices[supported(tree, n), 2].max() < 0 for n in tree.internal])]
    assert len(behind) > 5 and len(front) > 5
    assert t.culled[behind].all()
    for metric in ("perceptual", "size", "geometric"):
        k = score(tree, view, metric=metric)
        assert (k[behind] == 0).all()
        assert (k[front] > 0).any()
    # a sphere outside the side planes of the frustum is culled too
    side = View(eye=(0, 0, 0), target=(1, 0, -0.2), fov_deg=20.0)
    ts = node_terms(tree, side)
    assert ts.culled[front].all()


def test_size_key_closed_form(sphere_tree):
    tree = sphere_tree
    view = View(eye=EYE)
    k = score(tree, view, metric="size")
    d = np.linalg.norm(tree.center[0] - EYE)
    s = tree.radius[0] / d
    assert k[0] == pytest.approx(2 * view.focal_px * s / math.sqrt(1 - s * s), rel=1e-5)
    g = score(tree, view, metric="geometric")
    assert g[0] >= view.focal_px * tree.geom_error[0] / d * (1 - 1e-5)
    assert (k[tree.child_count == 0] == 0).all()  # leaves have nothing to fold


def _check_monotone(tree, k):
    assert k.shape == (tree.n_nodes,) and k.dtype == np.float32
    assert np.isfinite(k).all() and (k >= 0).all()
    assert (k[tree.parent[1:]] >= k[1:]).all()


@settings(max_examples=6, deadline=None)
@given(az=st.floats(0, 2 * math.pi), el=st.floats(-1.2, 1.2), dist=st.floats(1.5, 20.0),
       metric=st.sampled_from(["perceptual", "size", "geometric"]))
def test_keys_are_monotone(sphere_tree, az, el, dist, metric):
    eye = dist * np.array([math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)])
    _check_monotone(sphere_tree, score(sphere_tree, View(eye=eye), metric=metric))


def _reference_key(model, t, nodes):
    """The key of each node from its terms, written out: the own fold's distance; for a silhouette,
    the larger of it and the thin-band key min(k(c, theta), max(k(c w / theta, theta), k(c, w),
    min(2 c w M, 2 theta f*)))."""
    from optim._score import band_bound

    bb = band_bound(model)
    d = lambda c, th: np.asarray(model.imperceptible_distance(c, th, t.eccentricity[nodes]), np.float64)  # noqa: E731
    c, c_own, th, w = t.contrast[nodes], t.own_contrast[nodes], t.theta[nodes], t.band_deg[nodes]
    k_own = d(c_own, th)
    kb = [_band_key_written(2 * ci * wi, ei, bb) for ci, wi, ei in zip(c, w, t.eccentricity[nodes])]
    inner = np.minimum(kb, 2 * th * float(bb.f_star))
    thin = np.minimum(d(c, th), np.maximum(np.maximum(d(c * np.where(th > 0, w / np.where(th > 0, th, 1), 0), th),
                                                      d(c, w)), inner))
    return np.where(t.silhouette[nodes], np.maximum(k_own, thin), k_own)


def _band_key_written(kc, e, bb):
    """optim._score.band_key written out for one band in Python floats: K0 = kc M0, then the least of
    b_i K0 - e / a_i over the envelopes, not below K0 tail."""
    k0 = float(np.float32(kc) * bb.m0)
    return max(min(float(b) * k0 - e * float(ia) for b, ia in zip(bb.b, bb.inv_a)), k0 * float(bb.tail))


def _band_fixed_point(kc, e, m_e, rounds=400):
    """The largest k with k <= kc M_e[cell(e / k)] on band_constants' grid (exact cells), by iterating from
    the foveal bound (many rounds: a slow reference)."""
    from optim._score import BAND_ECCENTRICITIES

    k = kc * m_e[0]
    for _ in range(rounds):
        at = np.where(k > 0, e / np.where(k > 0, k, 1.0), 0.0)
        k = kc * m_e[np.clip(np.searchsorted(BAND_ECCENTRICITIES, at, side="right") - 1, 0, len(m_e) - 1)]
    return k


def _thin_band_cases(seed, velocities=None):
    """64 random silhouette bands: (theta, w, c, e, v) (deg, deg, contrast, deg, deg/s or zeros)."""
    rng = np.random.default_rng(seed)
    n = 64
    theta = 10 ** rng.uniform(-2, 0.5, n)
    w = theta * 10 ** rng.uniform(-3, 0, n)
    c = 10 ** rng.uniform(-2, 0, n)
    e = rng.choice([0.0, 2.0, 10.0], n)
    v = np.zeros(n) if velocities is None else rng.choice(velocities, n)
    return theta, w, c, e, v


def _check_thin_band(model, band, cases):
    """The thin-band key (band constants ``band``) holds every channel's distance (half-period s in
    [w, theta], contrast c w / s) and is at most the whole node's key; returns it with the distance."""
    from optim._score import thin_band_key

    from optim._score import band_key

    theta, w, c, e, v = cases
    d = lambda cc, th: np.asarray(model.imperceptible_distance(cc, th, e, v), np.float64)  # noqa: E731
    kb = band_key((2 * c * w).astype(np.float32), e.astype(np.float32), band, np)
    key = thin_band_key(np.zeros(len(c)), d(c, theta), d(c * w / theta, theta), d(c, w),
                        kb, 2 * theta * float(band.f_star), np.ones(len(c), bool), np)
    for s_frac in np.linspace(0, 1, 41):
        s = w * (theta / w) ** s_frac
        assert (d(c * w / s, s) <= key * (1 + 1e-4) + 1e-9).all()
    assert (key <= d(c, theta) * (1 + 1e-6)).all()
    return d


def test_thin_band_key_bounds_every_channel():
    """The silhouette key holds the distance of every channel that sees the band (half-period s in
    [w, theta], contrast c w / s), and is at most the whole node's key."""
    from optim._score import band_bound, thin_band_key

    model = pmetric.KellyAbstract()
    bb = band_bound(model)
    m_band, f_star = float(bb.m0), float(bb.f_star)
    theta, w, c, e, v = cases = _thin_band_cases(3)
    d = _check_thin_band(model, bb, cases)
    # a band that spans the node is the whole node: no reduction
    full = thin_band_key(np.zeros(len(c)), d(c, theta), d(c, theta), d(c, theta), 2 * c * theta * m_band,
                         2 * theta * f_star, np.ones(len(c), bool), np)
    np.testing.assert_allclose(full, d(c, theta), rtol=1e-6)


@pytest.mark.parametrize("name", ["stela", "kellyabstract", "barten"])
def test_band_constants_bound_every_eccentricity(name):
    """The per-eccentricity band constants never increase, start at band_constant's M, and bound
    max_f f S(f, e) at eccentricities between the grid points (200 random ones, 0 .. 100 deg), the
    assumption band_key's cells rest on."""
    from optim._score import BAND_ECCENTRICITIES, band_constant, band_constants

    model = pmetric.make_model(name)
    m_e, f_star = band_constants(model)
    assert m_e[0] == band_constant(model)[0] and f_star == band_constant(model)[1]
    assert (np.diff(m_e) <= 0).all()
    e = np.concatenate([[0.0, 0.05], 10 ** np.random.default_rng(1).uniform(-1.5, 2.0, 198)])
    f = np.logspace(-2.0, 2.5, 8193)
    sens = np.asarray(model.sensitivity(f[None, :], e[:, None], 0.0), np.float64)
    peak = np.where(np.isfinite(sens), f * sens, 0.0).max(axis=1)
    cell = np.searchsorted(BAND_ECCENTRICITIES, e.astype(np.float32), side="right") - 1
    assert (peak <= m_e[cell] * (1 + 1e-6)).all()
    if name == "stela":  # a real fall-off: a tenth of the foveal bound by 10 deg
        assert m_e[cell[e > 10]].max() < 0.1 * m_e[0]


@pytest.mark.parametrize("name", ["stela", "kellyabstract", "barten"])
def test_band_key_bounds_the_fixed_point_and_tightens_off_the_gaze(name):
    """band_key's closed forms (XLA, numpy alike, and written out) lie above the band's largest
    perceptible distance on band_constants' grid (the fixed point of k <= kc M(e / k), found slowly), never
    above the foveal bound kc M0, equal to it without gaze or at eccentricity 0, and close to the fixed
    point: for stelaCSF well below the foveal bound off the gaze."""
    import jax.numpy as jnp

    from optim._score import band_bound, band_constants, band_key

    model = pmetric.make_model(name)
    m_e, _ = band_constants(model)
    bb = band_bound(model)
    rng = np.random.default_rng(4)
    n = 400
    kc = (10 ** rng.uniform(-1, 3, n) / bb.m0).astype(np.float32)  # foveal bounds 0.1 .. 1000
    e = np.where(rng.random(n) < 0.2, 0.0, 10 ** rng.uniform(-1, 2.2, n)).astype(np.float32)
    got = np.asarray(band_key(jnp.asarray(kc), jnp.asarray(e), bb), np.float64)
    np.testing.assert_allclose(band_key(kc, e, bb, np), got, rtol=1e-6)
    np.testing.assert_allclose(got, [_band_key_written(a, b, bb) for a, b in zip(kc, e)], rtol=1e-5, atol=1e-6)
    fixed = _band_fixed_point(kc.astype(np.float64), e.astype(np.float64), m_e)
    foveal = kc * bb.m0
    assert (got >= fixed * (1 - 1e-5) - 1e-6).all()
    assert (got <= foveal).all()
    np.testing.assert_array_equal(got[e == 0], foveal[e == 0])
    np.testing.assert_array_equal(band_key(kc, None, bb, np), foveal)
    near = (foveal > 1) & (foveal < 30) & (e > 0)  # the folds a decision hinges on
    assert np.median(got[near] - fixed[near]) < 0.25 * np.median(foveal[near])  # close to the fixed point
    if name == "stela":
        off = near & (e > 5)
        assert np.median(got[off] / foveal[off]) < 0.5
    if name == "barten":  # no eccentricity term: nothing changes
        np.testing.assert_array_equal(got, foveal)


def test_perceptual_keys_match_the_model(sphere_tree):
    tree = sphere_tree
    model = pmetric.KellyAbstract()
    view = View(eye=EYE, gaze=[[800.0, 500.0]])
    exact = score(tree, view, model, exact=True)
    table = score(tree, view, model)
    _check_monotone(tree, exact)
    _check_monotone(tree, table)
    # the table is conservative and close: never below the exact key, at most a few percent above
    assert (table >= exact * (1 - 1e-5) - 1e-6).all()
    big = exact > 0.1
    assert (table[big] <= exact[big] * 1.06 + 0.05).all()
    # deepest internal nodes (all children are leaves): key = the model's distance for its own terms
    t = node_terms(tree, view)
    deep = np.array([n for n in tree.internal
                     if (tree.child_count[tree.child_start[n]:tree.child_start[n] + tree.child_count[n]] == 0).all()])
    deep = deep[~t.culled[deep]]
    want = _reference_key(model, t, deep)
    assert exact[deep] == pytest.approx(want, rel=1e-4, abs=1e-6)
    # farther away, every fold is at most as important (smaller angles, larger frequencies)
    far = score(tree, View(eye=EYE * 3, gaze=[[800.0, 500.0]]), model, exact=True)
    assert far[0] < exact[0]


def test_imperceptible_cut(sphere_tree):
    tree = sphere_tree
    model = pmetric.KellyAbstract()
    near = imperceptible_cut(tree, View(eye=EYE), model)
    # gaze at a corner: peripheral folds vanish sooner; head tracking (15 deg error) keeps more of them
    tracked = imperceptible_cut(tree, View(eye=EYE, gaze=[[0.0, 0.0]], gaze_error_deg=1.0), model)
    head = imperceptible_cut(tree, View(eye=EYE, gaze=[[0.0, 0.0]], gaze_error_deg=15.0), model)
    assert near.stop_reason in ("imperceptible", "all_unfolded")
    k = score(tree, View(eye=EYE), model)
    unf = near.unfolded
    assert (k[unf] > 1).all()
    pu = np.r_[True, unf[tree.parent[1:]]]
    boundary = pu & ~unf & (tree.child_count > 0)
    assert (k[boundary] <= 1).all()
    assert near.distance <= 1.0
    assert tracked.triangles <= head.triangles <= near.triangles
    # eccentricity only ever lowers a key [LHNW00 §4.4], and does for peripheral nodes
    foveal = score(tree, View(eye=EYE, gaze=None), model, exact=True)
    corner = score(tree, View(eye=EYE, gaze=[[0.0, 0.0]]), model, exact=True)
    assert (corner <= foveal * (1 + 1e-5) + 1e-6).all()
    assert (corner < 0.95 * foveal).any()
    assert near.triangles == int(tree.num_subtris[unf].sum())


def test_bad_input(sphere_tree):
    view = View(eye=EYE)
    with pytest.raises(ValueError, match="metric must be one of"):
        score(sphere_tree, view, metric="loudness")
    with pytest.raises(ValueError, match="optim.View"):
        score(sphere_tree, (0, 0, 4))
    with pytest.raises(ValueError, match="pmetric.CSFModel"):
        score(sphere_tree, view, model="KellyAbstract")
    with pytest.raises(ValueError, match="lacks the field"):
        score(object(), view)


@pytest.mark.parametrize("gaze", [None, "center", [[300.0, 200.0], [1500.0, 900.0]]])
def test_fast_table_path_equals_xla_path(sphere_tree, gaze):
    """The numpy-gather fast path of the table-mode keys gives identical raw keys and cull flags."""
    from optim import _score as S
    from optim._terms import view_params

    tree = sphere_tree
    ctx = optim.scoring_context(tree)
    ktab = S._model_table(S.default_model())
    for az in np.linspace(0, 2 * math.pi, 5, endpoint=False):
        eye = 3.0 * np.array([math.sin(az), 0.4, math.cos(az)])
        vp = view_params(View(eye=eye, gaze=gaze), ctx.scene_lum)
        fast = S._raw_keys(ctx, vp, None, ktab, "perceptual", gaze is not None, False, fast=True)
        slow = S._raw_keys(ctx, vp, None, ktab, "perceptual", gaze is not None, False, fast=False)
        assert np.array_equal(fast[0], slow[0]) and np.array_equal(fast[1], slow[1])


def test_gather_path_follows_backend_and_cores(monkeypatch):
    """Numpy gathers only on the CPU backend with few usable cores; the XLA programs on a GPU or four+
    cores (reports/bench_optim_device.md); score's default follows it."""
    from optim import _score as S

    for backend, cores, host in (("cpu", 1, True), ("cpu", 2, True), ("cpu", 3, True), ("cpu", 4, False),
                                 ("cpu", 16, False), ("gpu", 2, False), ("gpu", 16, False)):
        monkeypatch.setattr(S.jax, "default_backend", lambda b=backend: b)
        monkeypatch.setattr(S, "_usable_cores", lambda c=cores: c)
        assert S._host_gathers() is host, (backend, cores)
    class HostPath(Exception):
        pass

    def host_path(*args):
        raise HostPath

    monkeypatch.setattr(S, "_table_keys_host", host_path)
    monkeypatch.setattr(S.jax, "default_backend", lambda: "cpu")
    monkeypatch.setattr(S, "_usable_cores", lambda: 2)
    with pytest.raises(HostPath):
        S._raw_keys(None, None, None, object(), "perceptual", False, False)


def test_monotone_gathers_equal_reduceat(sphere_tree):
    lv = optim.scoring_context(sphere_tree).levels
    rng = np.random.default_rng(0)
    for _ in range(5):
        key = rng.random(len(lv.parent)).astype(np.float32)
        key[rng.random(key.size) < 0.4] = 0.0
        assert np.array_equal(lv.max_up(key.copy()), lv.reduce_up(key.copy(), np.maximum, include_self=True))


@pytest.mark.parametrize("max_arity", [1, 2, 3, 8])
def test_slot_gathers_with_wide_groups_equal_reduceat(max_arity):
    """Levels whose groups exceed ``max_arity`` children (the rest reduced by reduceat) give the same
    maxima as reduceat over whole levels; a random breadth-first tree with arities 1 to 12."""
    from optim._levels import Levels

    rng = np.random.default_rng(max_arity)
    parent, depth, frontier = [-1], [0], [0]
    for d in range(1, 6):
        nxt = []
        for p in frontier:
            for _ in range(int(rng.integers(0, 13)) if d < 5 else 0):
                nxt.append(len(parent))
                parent.append(p)
                depth.append(d)
        frontier = nxt or frontier[:1]
    lv = Levels.from_depth(np.array(parent), np.array(depth), max_arity=max_arity)
    assert any(sl is not None and sl[2] is not None for sl in lv.slots[1:])  # some group is wider
    for _ in range(5):
        key = rng.random(len(parent)).astype(np.float32)
        key[rng.random(key.size) < 0.4] = 0.0
        assert np.array_equal(lv.max_up(key.copy()), lv.reduce_up(key.copy(), np.maximum, include_self=True))


def test_padded_chunks_give_the_same_keys(sphere_tree, monkeypatch):
    """Several chunks of odd lengths (padded internally) give the keys of a single chunk."""
    from optim import _context as C

    view = View(eye=EYE)
    want = score(sphere_tree, view)
    tree = optim.build_tree(sphere_tree.vertices, sphere_tree.faces, method="octree")
    monkeypatch.setattr(C, "_CHUNK", 77)
    got = score(tree, view)
    assert len(optim.scoring_context(tree).chunks) > 1
    assert np.array_equal(got, want)


def test_scoring_context_is_cached_and_immutable(sphere_tree):
    ctx = optim.scoring_context(sphere_tree)
    assert optim.scoring_context(sphere_tree) is ctx
    assert sphere_tree.derived("scoring_context", lambda: None) is ctx
    with pytest.raises(AttributeError):
        ctx.chunks = ()


def test_score_errors_are_plod_errors(sphere_tree):
    with pytest.raises(pmetric.PlodError, match="metric must be one of"):
        score(sphere_tree, View(eye=EYE), metric="loudness")
    with pytest.raises(pmetric.PlodError, match="optim.View"):
        score(sphere_tree, (0, 0, 4))


def test_silhouette_choice_is_one_function():
    """select_contrast picks the silhouette value exactly where the node is a silhouette (numpy and jax)."""
    import jax.numpy as jnp

    from optim._terms import select_contrast

    sil = np.array([True, False, True])
    own, other = np.array([1.0, 2.0, 3.0]), np.array([10.0, 20.0, 30.0])
    assert np.array_equal(select_contrast(sil, own, other, np), [10.0, 2.0, 30.0])
    assert np.array_equal(np.asarray(select_contrast(jnp.asarray(sil), jnp.asarray(own), jnp.asarray(other))),
                          [10.0, 2.0, 30.0])


@pytest.mark.slow  # a fresh stelaCSF table: 10-30 s of compilation and solves
def test_shipped_key_table_is_the_default_models_fresh_table(tmp_path):
    """The key table shipped for the default model (stelaCSF's takes about 10 s to build) is what a
    fresh build gives, is used only for that model and grid, and is rewritten atomically."""
    from optim import _score as S

    model = S.default_model()
    shipped = S._shipped_table(model)
    assert shipped is not None, "optim/data/key_table_default.npz is missing or not the default model's"
    fresh = S._perceptual_table(model)
    np.testing.assert_allclose(shipped, fresh, rtol=1e-5)  # XLA:CPU float32 of another vector width
    assert S._shipped_table(pmetric.StelaCSF(sust_bw=0.0003)) is None  # other constants: built afresh
    assert S._shipped_table(pmetric.KellyAbstract()) is None
    out = S.write_shipped_table(tmp_path / "t.npz")
    with np.load(out) as z:
        np.testing.assert_allclose(z["table"], fresh, rtol=1e-5)
        assert str(z["digest"]) == S._table_digest(model)


def test_damaged_shipped_table_is_rebuilt_not_trusted(tmp_path, monkeypatch):
    """A truncated, foreign or wrong-sized shipped table file is ignored (the table is built afresh),
    never read as keys."""
    from optim import _score as S

    model = S.default_model()
    good = S.SHIPPED_TABLE.read_bytes()
    for name, data in (("truncated", good[: len(good) // 2]), ("not a zip", b"plod"), ("empty", b"")):
        bad = tmp_path / f"{name}.npz"
        bad.write_bytes(data)
        monkeypatch.setattr(S, "SHIPPED_TABLE", bad)
        assert S._shipped_table(model) is None, name
    short = tmp_path / "short.npz"
    np.savez(short, table=np.ones(7, np.float32), digest=np.asarray(S._table_digest(model)))
    monkeypatch.setattr(S, "SHIPPED_TABLE", short)
    assert S._shipped_table(model) is None
    monkeypatch.setattr(S, "SHIPPED_TABLE", tmp_path / "missing.npz")
    assert S._shipped_table(model) is None



def _random_moving_terms(n, seed):
    rng = np.random.default_rng(seed)
    c = 10 ** rng.uniform(-3, 0, n)
    th = 10 ** rng.uniform(-3, 0.5, n)
    e = rng.uniform(0, 30, n) * (rng.random(n) < 0.8)
    v = 10 ** rng.uniform(-1, 2.7, n) * (rng.random(n) < 0.9)
    return c, th, e, v


def _motion_table_keys(S, host, c, th, e, v):
    import jax.numpy as jnp

    idx = np.asarray(S.table_index(*(jnp.asarray(x, jnp.float32) for x in (c, th, e, v))))
    return np.asarray(S.table_gather(host, idx, th.astype(np.float32), np), np.float64)


def _exact_keys(model, c, th, e, v):
    import jax
    import jax.numpy as jnp

    f = jax.jit(lambda m, *a: m.imperceptible_distance(*a))
    return np.asarray(f(model, *(jnp.asarray(x, jnp.float32) for x in (c, th, e, v))), np.float64)


@pytest.fixture(scope="module")
def moving_model():
    """A model with eccentricity and velocity inputs and a direct solve, its motion table prepared
    (about 12 s on one core)."""
    model = pmetric.Eccentric(pmetric.KellySpatioTemporal())
    optim.prepare_motion_table(model)
    return model


def test_motion_table_bounds_the_moving_key(moving_model):
    """k(c, theta, e, v) = theta K(c, e / theta, v / theta): the motion table read at random moving
    folds is never below the model's key, and close to it at the median."""
    from optim import _score as S

    model = moving_model
    host = S._motion_table_for(model).host
    c, th, e, v = _random_moving_terms(4096, 3)
    exact = _exact_keys(model, c, th, e, v)
    table = _motion_table_keys(S, host, c, th, e, v)
    assert (table >= exact * (1 - 1e-4) - 1e-6).all()
    pos = exact > 1e-3
    assert pos.sum() > 1000
    assert np.median(table[pos] / exact[pos]) < 1.05
    # velocity matters: the same folds at rest read other entries, with other keys
    rest = _motion_table_keys(S, host, c, th, e, np.zeros_like(v))
    assert np.mean(np.abs(rest - table) > 1e-3 * table) > 0.3


def test_shipped_motion_table_bounds_the_default_models_key():
    """The shipped motion table of the default model (stelaCSF: minutes to build) is the default
    model's, and is never below the model's key at random moving folds (checked against the model's
    own per-element solve)."""
    from optim import _score as S

    model = S.default_model()
    host = S._shipped_table(model, motion=True)
    assert host is not None, "optim/data/motion_table_default.npz is missing or not the default model's"
    assert S._shipped_table(pmetric.KellyAbstract(), motion=True) is None
    c, th, e, v = _random_moving_terms(256, 4)
    exact = _exact_keys(model, c, th, e, v)
    table = _motion_table_keys(S, host, c, th, e, v)
    assert (table >= exact * (1 - 1e-4) - 1e-6).all()
    pos = exact > 1e-3
    assert np.median(table[pos] / exact[pos]) < 1.1


def test_moving_view_keys_come_from_the_motion_table(sphere_tree, moving_model):
    """A moving view scores from the motion table when the model has one (shipped or prepared): keys
    at least the per-node keys and close to them; a model without one uses the per-node key."""
    tree = sphere_tree
    a = View(eye=EYE, gaze=[[800.0, 500.0]])
    b = View(eye=(0.3, 0.1, 4.0), target=(0, 0, 0), gaze=[[800.0, 500.0]], previous=a, dt_s=0.02)
    other = pmetric.KellyAbstract(f0=3.0)  # not prepared, not shipped: the per-node key
    assert np.array_equal(score(tree, b, other), score(tree, b, other, exact=True))
    exact = score(tree, b, moving_model, exact=True)
    table = score(tree, b, moving_model)
    _check_monotone(tree, table)
    assert (table >= exact * (1 - 1e-5) - 1e-6).all()
    big = exact > 0.1
    assert big.sum() > 20 and not np.array_equal(table, exact)
    assert np.median(table[big] / exact[big]) < 1.1
    with pytest.raises(pmetric.PlodError, match="CSFModel"):
        optim.prepare_motion_table("stela")


@pytest.mark.slow  # 40-55 s (a moving stelaCSF table per channel): the default tier stays under 10 minutes
def test_moving_thin_band_key_bounds_every_channel(moving_model):
    """With motion the silhouette's thin-band key uses the band constant over velocities too
    (``band_constant(model, motion=True)``), so it still holds the distance of every channel that sees
    the moving band (half-period s in [w, theta], contrast c w / s, velocity v)."""
    from optim._score import band_constant

    from optim._score import band_bound

    m0, f0 = band_constant(moving_model)
    m_band, f_star = band_constant(moving_model, motion=True)
    assert m_band >= m0 and f_star >= f0
    bb = band_bound(moving_model, motion=True)
    assert bb.m0 == np.float32(m_band) and bb.f_star == np.float32(f_star)
    _check_thin_band(moving_model, bb, _thin_band_cases(5, [0.0, 1.0, 8.0, 40.0]))


def test_keys_are_continuous_as_the_motion_stops():
    """A view whose previous view is almost the same (retinal velocities ~1e-4 deg/s) scores as the
    still view: the motion table and its thin-band silhouette bound agree with the static ones at rest
    (before the motion path kept silhouettes at their whole-node key: up to 300x the still key)."""
    v, f = optim.bumpy_sphere(3, seed=1)[:2]
    tree = optim.build_tree(v, f)
    a = View.framing(v, 30.0, (0.3, 0.2, 1.0))
    eye = a.eye + np.array([1e-7, 0.0, 0.0])
    b = View(eye=eye, target=a.target, up=a.up, previous=a, dt_s=1 / 60)
    ks, km = score(tree, a), score(tree, b)
    live = ks > 0
    assert live.sum() > 100
    assert optim.node_terms(tree, b).velocity.max() < 1e-3
    r = km[live] / ks[live]
    assert r.min() >= 1 - 1e-4 and r.max() < 1.1  # the motion table's first velocity cell rounds up
    assert np.median(r) < 1.01

"""The point hierarchy and its perceptual traversal (optim._points; [LH01 §4], QSplat)."""

from __future__ import annotations

import numpy as np
import pytest

import optim
import pmetric as pm
from optim._points import (build_points, load_points, point_terms, points_from_mesh, save_points, splat_discs,
                           traverse)


# ----------------------------------------------------------------------------------------------- point sets
def _sheet(n=40, amp=0.03, colors="bumps", seed=0):
    """A wavy square sheet z = amp sin(3 x) cos(2 y) over [-1, 1]^2 facing +z (analytic normals)."""
    x, y = np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n))
    x, y = x.ravel(), y.ravel()
    z = amp * np.sin(3 * x) * np.cos(2 * y)
    nrm = np.stack([-amp * 3 * np.cos(3 * x) * np.cos(2 * y), amp * 2 * np.sin(3 * x) * np.sin(2 * y),
                    np.ones_like(x)], 1)
    pts = np.stack([x, y, z], 1)
    if colors == "uniform":
        col = np.full((len(x), 3), 0.6)
    elif colors == "halves":
        col = np.where((x < 0)[:, None], 0.2, 0.8) * np.ones((1, 3))
    else:
        rng = np.random.default_rng(seed)
        col = np.clip(0.5 + 0.3 * np.sin(7 * x)[:, None] * np.cos(5 * y)[:, None] + 0.05 * rng.random((len(x), 3)), 0, 1)
    return pts, nrm, col


@pytest.fixture(scope="module")
def sheet():
    pts, nrm, col = _sheet()
    return pts, build_points(pts, nrm, col)


@pytest.fixture(scope="module")
def sphere():
    v, f, c = optim.bumpy_sphere(3, colors=True)
    p, n, col = points_from_mesh(v, f, c)
    return p, build_points(p, n, col)


def _cover_counts(h, nodes) -> np.ndarray:
    """Per leaf, the number of nodes of ``nodes`` that are the leaf or one of its ancestors."""
    chosen = np.zeros(h.n_nodes, bool)
    chosen[nodes] = True
    cur = h.leaves.copy()
    out = np.zeros(len(cur), int)
    alive = np.ones(len(cur), bool)
    while alive.any():
        out[alive] += chosen[cur[alive]]
        nxt = np.where(alive, h.parent[cur], -1)
        alive = nxt >= 0
        cur = np.maximum(nxt, 0)
    return out


def _is_ancestor_pair(h, nodes) -> bool:
    """True when some node of ``nodes`` has a proper ancestor in ``nodes``."""
    chosen = np.zeros(h.n_nodes, bool)
    chosen[nodes] = True
    cur = h.parent[np.asarray(nodes)]
    while (cur >= 0).any():
        cur = cur[cur >= 0]
        if chosen[cur].any():
            return True
        cur = h.parent[cur]
    return False


# ----------------------------------------------------------------------------------------------- hierarchy
def test_hierarchy_spheres_cones_colours(sphere):
    p, h = sphere
    assert h.n_points == len(p) and len(h.leaves) == len(p)
    assert np.array_equal(np.sort(h.point[h.leaves]), np.arange(len(p)))  # each point is one leaf
    kid = np.flatnonzero(h.parent >= 0)
    par = h.parent[kid]
    # every sphere holds its children's spheres (hence all its descendants')
    reach = np.linalg.norm(h.center[kid] - h.center[par], axis=1) + h.radius[kid]
    assert (reach <= h.radius[par] * (1 + 1e-9)).all()
    # cones and colour means, against a per-node reference over the node's points
    v, f, c = optim.bumpy_sphere(3, colors=True)
    _, n_pts, col = points_from_mesh(v, f, c)
    lin = np.asarray(pm.srgb_to_linear(np.asarray(col, np.float32)), np.float64)
    for node in np.flatnonzero(h.child_count > 0)[:: max(1, h.n_nodes // 400)]:
        pts = h.order[h.point_lo[node]:h.point_hi[node]]
        ang = np.arccos(np.clip(n_pts[pts] @ h.normal[node], -1, 1))
        assert ang.max() <= h.cone_half[node] + 1e-6
        assert ang.max() >= h.cone_half[node] - 1e-4  # exact, not a loose merge
        np.testing.assert_allclose(h.rgb[node], lin[pts].mean(0), rtol=1e-6, atol=1e-7)
        assert h.lum_min[node] <= h.lum[node] <= h.lum_max[node]
        np.testing.assert_allclose(h.fold_delta[node], max(h.lum_max[node] - h.lum[node], h.lum[node] - h.lum_min[node]))
    assert (h.sil_half >= h.cone_half - 1e-12).all()


def test_contrast_range_counts_intersecting_nodes():
    """Two sheets side by side, one dark and one bright: a node on the bright side whose sphere meets
    a dark node gets the dark luminance in its range (the seed's Figure 4), one far from it does not."""
    pts, nrm, col = _sheet(32, amp=0.0, colors="halves")
    h = build_points(pts, nrm, col)
    dark, bright = (float(optim._tree._srgb_luminance(np.array([[g, g, g]]))[0]) for g in (0.2, 0.8))
    leaf_lum = h.lum[h.leaves]
    np.testing.assert_allclose(np.sort(np.unique(leaf_lum.round(6))), np.round([dark, bright], 6), atol=1e-6)
    depth = int(h.depth.max()) - 3
    nodes = np.flatnonzero((h.depth == depth) & (h.child_count > 0))
    pts_of = lambda k: h.order[h.point_lo[k]:h.point_hi[k]]  # noqa: E731
    pure_bright = [k for k in nodes if (pts[pts_of(k), 0] > 0).all()]
    for k in pure_bright:
        others = nodes[np.linalg.norm(h.center[nodes] - h.center[k], axis=1) <= h.radius[nodes] + h.radius[k]]
        meets_dark = any((pts[pts_of(o), 0] < 0).any() for o in others)
        assert np.isclose(h.lum_min[k], dark if meets_dark else bright, atol=1e-6)


# ----------------------------------------------------------------------------------------------- traversal
@pytest.mark.parametrize("criterion", ["perceptual", "size"])
@pytest.mark.parametrize("gaze_deg", [0.0, 29.0])
def test_traversal_is_a_cut(sphere, criterion, gaze_deg):
    from experiments.judge import offset_gaze_view

    p, h = sphere
    view = offset_gaze_view(p, gaze_deg, object_deg=10.0)
    t = traverse(h, view, criterion=criterion)
    assert t.splats > 0 and len(t.skipped) > 0  # the back of the sphere is culled
    assert not _is_ancestor_pair(h, t.drawn)  # a node and its descendant are never both drawn
    cover = _cover_counts(h, np.concatenate([t.drawn, t.skipped]))
    assert (cover == 1).all()  # every leaf is drawn or culled exactly once
    assert t.terms.culled[t.skipped].all() and not t.terms.culled[t.drawn].any()
    assert len(np.unique(t.drawn)) == t.splats


def test_front_facing_sheet_draws_every_leaf_once(sheet):
    pts, h = sheet
    view = optim.View.framing(pts, 30.0)
    for crit in ("perceptual", "size"):
        t = traverse(h, view, criterion=crit)
        assert len(t.skipped) == 0
        assert (_cover_counts(h, t.drawn) == 1).all()
    # the size-only traversal at 30 deg: every leaf (about 10 px) is above a pixel
    assert traverse(h, view, criterion="size").splats == h.n_points


def test_uniform_colour_draws_the_root():
    """Uniform colour and a flat, front-facing sheet: every contrast is 0, so the root's splat is
    imperceptible and is the only one drawn (even without the pixel-size stop)."""
    pts, nrm, col = _sheet(24, amp=0.0, colors="uniform")
    h = build_points(pts, nrm, col)
    view = optim.View.framing(pts, 30.0)
    t = traverse(h, view, min_px=0.0)
    assert t.terms.contrast[0] == 0.0 and not t.terms.perceptible[0] and not t.terms.silhouette[0]
    assert t.drawn.tolist() == [0] and t.visited == 1
    assert traverse(h, view, criterion="size").splats == len(pts)


def test_root_contrast_closed_form_and_test():
    """Half dark, half bright flat sheet: the root's contrast is the Michelson contrast of its splat's
    luminance change on the display ([LH01 §4]: the node's colour against its range), its frequency
    1 / (2 theta), and it is perceptible as the model says."""
    pts, nrm, col = _sheet(24, amp=0.0, colors="halves")
    h = build_points(pts, nrm, col)
    view = optim.View.framing(pts, 30.0)
    model = pm.make_model("kellyabstract")
    t = point_terms(h, view, model)
    disp = view.display
    lo, hi = (float(optim._tree._srgb_luminance(np.array([[g, g, g]]))[0]) for g in (0.2, 0.8))
    mean = 0.5 * (lo + hi)  # equal halves: the splat is the mean in linear light
    delta = max(hi - mean, mean - lo)
    cd = lambda rel: float(disp.black_level) + (float(disp.peak_luminance) - float(disp.black_level)) * rel  # noqa: E731
    c_closed = (cd(lo + delta) - cd(lo)) / (cd(lo + delta) + cd(lo))
    assert not t.silhouette[0] and t.eccentricity[0] == 0.0  # the gaze is on the sheet
    np.testing.assert_allclose(t.contrast[0], c_closed, rtol=1e-5)
    np.testing.assert_allclose(t.frequency[0], 0.5 / t.theta[0], rtol=1e-6)
    # the object spans 30 deg: 1/60 cycles/deg, below the peak: the peak threshold 1/200 applies
    assert t.theta[0] > 30.0 and c_closed > 1 / 200 and t.perceptible[0]
    assert 0 not in traverse(h, view, model).drawn
    # a contrast below the peak threshold is not perceptible at any frequency
    assert not bool(model.is_perceptible(0.9 / 200, t.frequency[0], 0.0))


def _reference_traverse(h, t, model, min_px):
    """The seed's recursive TraverseHierarchy, one node at a time (a slow reference)."""
    drawn, skipped = [], []

    def visit(node):
        if t.culled[node]:
            skipped.append(node)
            return
        leaf = h.child_count[node] == 0
        seen = bool(model.is_perceptible(float(t.contrast[node]), float(t.frequency[node]),
                                         float(t.eccentricity[node]))) if t.theta[node] > 0 else False
        if leaf or not seen or t.size_px[node] <= min_px:
            drawn.append(node)
            return
        for k in range(h.child_start[node], h.child_start[node] + h.child_count[node]):
            visit(k)

    visit(0)
    return np.array(drawn), np.array(skipped)


def test_traversal_matches_recursive_reference(sphere):
    from experiments.judge import offset_gaze_view

    p, h = sphere
    model = pm.make_model("kellyabstract")
    view = offset_gaze_view(p, 12.0, object_deg=8.0)
    t = traverse(h, view, model, min_px=0.5)
    ref_drawn, ref_skipped = _reference_traverse(h, t.terms, model, 0.5)
    assert np.array_equal(np.sort(t.drawn), np.sort(ref_drawn))
    assert np.array_equal(np.sort(t.skipped), np.sort(ref_skipped))
    assert 0 < t.splats < h.n_points  # the test is not trivial here: some nodes are simplified


def test_counts_fall_with_eccentricity(sheet):
    """The gaze moves away from an object spanning 4 deg: every node's eccentricity grows, so the
    splat count never rises; far enough away the sheet is drawn with far fewer splats."""
    from experiments.judge import offset_gaze_view

    pts, h = sheet
    counts = [traverse(h, offset_gaze_view(pts, g, object_deg=4.0), min_px=0.0).splats
              for g in (2.0, 5.0, 8.0, 12.0, 18.0, 29.0, 45.0)]
    assert all(a >= b for a, b in zip(counts, counts[1:])), counts
    assert counts[0] == h.n_points and counts[-1] < 0.5 * counts[0], counts
    full = traverse(h, offset_gaze_view(pts, 29.0, object_deg=4.0), criterion="size").splats
    assert counts[5] < full == h.n_points


def test_size_only_draws_the_root_when_tiny(sheet):
    pts, h = sheet
    view = optim.View.framing(pts, 0.01)  # the whole sheet under half a pixel
    t = traverse(h, view, criterion="size")
    assert t.drawn.tolist() == [0]
    assert t.terms.size_px[0] <= 1.0


# ----------------------------------------------------------------------------------------------- splats, files
def test_splat_discs_wind_towards_their_normals(sphere):
    _, h = sphere
    nodes = np.array([0, 1, 2, h.leaves[0], h.leaves[-1]])
    v, f, c = splat_discs(h, nodes, segments=8)
    assert v.shape == (5 * 9, 3) and f.shape == (5 * 8, 3) and c.shape == (5 * 9, 3)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    owner = np.repeat(np.arange(5), 8)
    assert (np.einsum("ij,ij->i", fn, h.normal[nodes][owner]) > 0).all()
    rim = v.reshape(5, 9, 3)[:, 1:] - h.center[nodes][:, None]
    np.testing.assert_allclose(np.linalg.norm(rim, axis=2), np.repeat(h.radius[nodes][:, None], 8, 1), rtol=1e-9)
    np.testing.assert_allclose(c[::9], h.srgb(nodes), atol=1e-6)


def test_point_cloud_ply_round_trip(tmp_path):
    pts, nrm, col = _sheet(10)
    path = tmp_path / "cloud.ply"
    save_points(path, pts, nrm, col)
    p2, n2, c2 = load_points(path)
    np.testing.assert_allclose(p2, pts, atol=1e-6)
    np.testing.assert_allclose(n2, nrm / np.linalg.norm(nrm, axis=1, keepdims=True), atol=1e-6)
    np.testing.assert_allclose(c2, np.round(col * 255) / 255, atol=1e-9)


def test_load_points_from_mesh(tmp_path):
    v, f = optim.bumpy_sphere(2)
    path = tmp_path / "m.ply"
    optim.save_mesh(path, v, f)
    p, n, c = load_points(path)
    assert p.shape == n.shape == (len(v), 3) and c is None
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, rtol=1e-9)


# ----------------------------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("case, match", [
    ("empty", "empty point set"),
    ("nan", "NaN or infinite coordinates"),
    ("normals_shape", r"normals must have shape \(5, 3\)"),
    ("zero_normal", "normal\\(s\\) are zero"),
    ("colors_shape", "colors must have shape"),
    ("leaf_k", "leaf_k must be a positive integer"),
    ("huge", r"coordinates up to 1e\+200 exceed 1e\+15"),  # was scipy's "data must be finite" (they were)
    ("large", r"coordinates up to \S+e\+29 exceed 1e\+15"),  # was accepted: one splat for the whole cloud
    ("tiny", r"diagonal \S+e-20 is below 1e-15"),  # was accepted: every leaf drawn
    ("coincide", r"all points coincide"),  # was accepted: one splat of radius 0
])
def test_bad_input_one_line(case, match):
    p = np.random.default_rng(0).random((5, 3))
    n = np.tile([0.0, 0.0, 1.0], (5, 1))
    kw = {}
    if case == "empty":
        p, n = np.zeros((0, 3)), np.zeros((0, 3))
    elif case == "nan":
        p[2, 1] = np.nan
    elif case == "normals_shape":
        n = n[:, :2]
    elif case == "zero_normal":
        n[3] = 0
    elif case == "colors_shape":
        kw["colors"] = np.zeros((4, 3))
    elif case == "leaf_k":
        kw["leaf_k"] = 0
    elif case == "huge":
        p[1, 0] = 1e200
    elif case == "large":
        p *= 1e30
    elif case == "tiny":
        p *= 1e-20
    elif case == "coincide":
        p[:] = p[0]
    with pytest.raises(pm.PlodError, match=match) as exc:
        build_points(p, n, **kw)
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize("scale", [1e-14, 1e14])
def test_the_scales_the_traversal_handles(scale):
    """Near the accepted scales' ends (diagonal >= 1e-15, coordinates <= 1e15) a cloud draws the splats it
    draws at its own size, and normals of any length are directions (1e-200 or 1e200 long: before, one
    was refused as "zero" and the other overflowed to a zero normal)."""
    P, N, _ = optim.points_from_mesh(*optim.bumpy_sphere(2))
    ref = traverse(build_points(P, N), optim.View(eye=(0, 0, 4)))
    got = traverse(build_points(P * scale, N * (1e-200 if scale < 1 else 1e200)), optim.View(eye=(0, 0, 4 * scale)))
    assert got.splats == ref.splats > 1


def test_bad_traversal_and_files(sheet, tmp_path):
    pts, h = sheet
    view = optim.View.framing(pts, 30.0)
    with pytest.raises(pm.PlodError, match="criterion must be one of"):
        traverse(h, view, criterion="distance")
    with pytest.raises(pm.PlodError, match="min_px"):
        traverse(h, view, min_px=-1)
    with pytest.raises(pm.PlodError, match="PointHierarchy"):
        traverse("tree", view)
    with pytest.raises(pm.PlodError, match="does not exist"):
        load_points(tmp_path / "missing.ply")
    bare = tmp_path / "bare.ply"
    bare.write_text("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
                    "property float z\nend_header\n0 0 0\n1 0 0\n")
    with pytest.raises(pm.PlodError, match="needs per-point normals"):
        load_points(bare)


# ----------------------------------------------------------------------------------------------- the report command
def test_points_command_quick(tmp_path):
    """``python -m experiments.points --quick --no-judge`` on a tiny config: the report, the figures and
    counts that order as the traversals must (perceptual <= size-only <= facing points)."""
    import json

    from experiments import points as P

    cfg = tmp_path / "c.toml"
    cfg.write_text('paths = ["sphere:3"]\nobject_deg = [4.0]\ncurve_gaze_deg = [0.0, 29.0]\nrepeats = 1\n')
    out = tmp_path / "rep"
    try:
        assert P.main(["--quick", "--no-judge", "--config", str(cfg), "--out", str(out)]) == 0
    except RuntimeError as exc:  # no OpenGL context on this machine
        pytest.skip(str(exc))
    res = json.loads((out / "results.json").read_text())
    (row,) = res["rows"]
    assert row["perceptual_29"]["splats"] <= row["perceptual_0"]["splats"] <= row["size"]["splats"]
    assert row["size"]["splats"] <= row["visible_leaves"] <= row["points"]
    assert row["curve"]["29"] == row["perceptual_29"]["splats"]
    for name in ("report.md", "counts.png", "curve.png", "run_info.json", row["figure"]):
        assert (out / name).stat().st_size > 0
    bad = tmp_path / "bad.toml"
    bad.write_text('paths = ["sphere:3", "sphere:2"]\n')
    with pytest.raises(pm.PlodError, match="'names' has 1 entries, 'paths' has 2"):
        P.main(["--quick", "--no-judge", "--config", str(bad), "--out", str(out)])
    bad.write_text('pathz = ["sphere:3"]\n')
    with pytest.raises(pm.PlodError, match="unknown config key 'pathz'"):
        P.main(["--quick", "--config", str(bad), "--out", str(out)])


def test_plod_experiment_runs_a_points_config(tmp_path, capsys):
    """``plod experiment CONFIG`` with ``kind = "points"`` (configs/points_fig7.toml) runs this experiment
    (before: refused, "unknown config key 'kind'"); its rows order as the traversals must, and its run
    info names the config. (``python -m experiments.points`` takes the same path, ``_write_all``.)"""
    import json

    from experiments import points as P
    from experiments.cli import main as cli

    body = ('paths = ["sphere:3"]\nnames = ["s"]\npoint_cloud = [false]\ndirections = [[0.0, 0.0, 1.0]]\n'
            'ups = [[0.0, 1.0, 0.0]]\nobject_deg = [4.0]\ncurve_gaze_deg = [0.0, 29.0]\nrepeats = 1\n'
            'judge = false\n')
    (tmp_path / "k.toml").write_text('kind = "points"\n' + body)
    try:
        assert cli(["experiment", str(tmp_path / "k.toml"), "--out", str(tmp_path / "a")]) == 0
    except RuntimeError as exc:  # no OpenGL context on this machine
        pytest.skip(str(exc))
    (row,) = json.loads((tmp_path / "a" / "results.json").read_text())["rows"]
    assert row["perceptual_29"]["splats"] <= row["perceptual_0"]["splats"] <= row["size"]["splats"] <= row["points"]
    info = json.loads((tmp_path / "a" / "run_info.json").read_text())
    assert info["config"]["kind"] == "points" and "--config" in info["command"]
    (tmp_path / "t.toml").write_text('kind = "terrain"\n' + body)
    with pytest.raises(pm.PlodError, match="config kind must be 'points'"):
        P.run_config(tmp_path / "t.toml", tmp_path / "c")
    assert not (tmp_path / "c").exists()
    capsys.readouterr()


def test_a_far_point_cloud_traverses_like_the_same_cloud_near_0():
    """Georeferenced scans lie far from 0 for their size: the float32 columns are relative to an origin
    (optim.local_origin), so the cloud moved by 1e7 draws the same splats (before: about 1 unit of
    precision at 1e7 for a cloud of size 2)."""
    from experiments.judge import offset_gaze_view

    v, f, c = optim.bumpy_sphere(3, colors=True)
    p, n, col = points_from_mesh(v, f, c)
    p = np.round(p * 2.0 ** 20) / 2.0 ** 20  # on a grid: p + offset is exact
    off = np.array([1e7, -5e6, 4096.0])
    near, far = build_points(p, n, col), build_points(p + off, n, col)
    for gaze_deg in (0.0, 29.0):
        t0 = traverse(near, offset_gaze_view(p, gaze_deg, object_deg=10.0))
        t1 = traverse(far, offset_gaze_view(p + off, gaze_deg, object_deg=10.0))
        assert t0.splats > 100 and np.array_equal(np.sort(t1.drawn), np.sort(t0.drawn))


# ----------------------------------------------------------------------------------------------- fuzzer findings
def test_a_far_cloud_round_trips_exactly_through_a_point_ply(tmp_path):
    """save_points writes float64 coordinates: a cloud near 1e7 reads back exactly (before: float32, up
    to 0.5 units off and 42 of 50 points merged)."""
    rng = np.random.default_rng(0)
    p = rng.random((50, 3)) + np.array([1e7, -3e9, 12345.678])
    n = rng.normal(size=(50, 3))
    save_points(tmp_path / "far.ply", p, n)
    q, m, _ = load_points(tmp_path / "far.ply")
    np.testing.assert_array_equal(q, p)
    np.testing.assert_allclose(m, n / np.linalg.norm(n, axis=1, keepdims=True), atol=1e-6)


@pytest.mark.parametrize("as_path", [str, __import__("pathlib").Path])
def test_save_points_protects_a_single_input_path(tmp_path, as_path):
    """``protect=src`` (one str or Path, not a tuple) protects src (before: a str was taken as its
    characters and the input overwritten; a Path raised a TypeError)."""
    src = tmp_path / "in.ply"
    p = np.random.default_rng(1).random((20, 3))
    save_points(src, p, np.tile([0.0, 0.0, 1.0], (20, 1)))
    before = src.read_bytes()
    with pytest.raises(pm.PlodError, match="refusing to overwrite the input file"):
        save_points(src, p[:5], np.tile([0.0, 0.0, 1.0], (5, 1)), protect=as_path(src))
    assert src.read_bytes() == before


def test_coincident_copies_do_not_shrink_leaf_radii():
    """A leaf's radius is the distance to its leaf_k-th nearest *distinct* position: every point doubled
    gives the radii of the cloud itself (before: 0, so a size-only traversal drew 451 empty splats)."""
    P, N = optim.points_from_mesh(*optim.bumpy_sphere(3))[:2]
    for k in (1, 4):
        one = build_points(P, N, leaf_k=k)
        two = build_points(np.repeat(P, 2, 0), np.repeat(N, 2, 0), leaf_k=k)
        r1 = one.radius[one.leaves][np.argsort(one.point[one.leaves])]
        r2 = two.radius[two.leaves][np.argsort(two.point[two.leaves])]
        np.testing.assert_array_equal(r2, np.repeat(r1, 2))
        assert r1.min() > 0
    t = traverse(two, optim.View.framing(P, 10.0), criterion="size")
    assert t.splats > 0 and (two.radius[t.drawn] > 0).all()


def test_cancelling_normals_give_a_unit_normal():
    """A node whose points' normals cancel gets its first child's normal (a unit vector; before: (0, 0, 0)),
    with the cone of every direction."""
    h = build_points([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]], [[0, 0, 1], [0, 0, -1], [0, 0, 1], [0, 0, -1.0]])
    np.testing.assert_allclose(np.linalg.norm(h.normal, axis=1), 1.0, rtol=1e-12)
    assert h.cone_half[0] == np.pi
    np.testing.assert_array_equal(h.normal[0], h.normal[h.child_start[0]])
    v, f, _ = splat_discs(h, np.array([0]))
    np.testing.assert_allclose(np.linalg.norm(v[1:] - v[0], axis=1), h.radius[0], rtol=1e-9)  # a disc, not a point


_PLY6 = "ply\nformat ascii 1.0\nelement vertex {}\n" + "".join(f"property float {a}\n" for a in
                                                              ("x", "y", "z", "nx", "ny", "nz")) + "end_header\n"


@pytest.mark.parametrize("count, body, match", [
    (5, "0 0 0 0 0 1\n1 0 0 0 0 1\n0 1 0 0 0 1\n", r"declares 5 data rows \(5 vertex\) but the file has 3"),
    (3, "0 0 0 0 0 1 1 0 0 0 0 1 0 1 0 0 0 1\n", r"declares 3 data rows \(3 vertex\) but the file has 1"),
    (3, "0 0 0 0 0 1\n1 0 0 0 0 1\n0 1 0 0\n", "vertex row 2 has 4 values, the header declares 6"),
    (3, "0 0 0 0 0 1\n1 0 0 0 0 1 7\n0 1 0 0 0 1\n", "vertex row 1 has 7 values"),
    (2, "0 0 0 0 0 1\n1 0 zero 0 0 1\n", "not a number"),
])
def test_malformed_ascii_point_ply_is_refused(tmp_path, count, body, match):
    """An ASCII PLY whose rows disagree with its header is refused naming the file (before: a truncated
    file silently lost points, three points on one line read as one, a short row gave numpy's traceback)."""
    path = tmp_path / "bad.ply"
    path.write_text(_PLY6.format(count) + body)
    with pytest.raises(pm.PlodError, match=match) as exc:
        load_points(path)
    assert "bad.ply" in str(exc.value) and "\n" not in str(exc.value)
    path.write_text(_PLY6.format(2) + "0 0 0 0 0 1\n1 0 0 0 0 1\n\n")  # a trailing blank line is fine
    np.testing.assert_array_equal(load_points(path)[0], [[0, 0, 0], [1, 0, 0]])


def test_bad_paths_indices_and_values_are_one_line_errors(tmp_path):
    P, N = optim.points_from_mesh(*optim.bumpy_sphere(2))[:2]
    h = build_points(P, N)
    cases = [
        (lambda: save_points(tmp_path, P, N), "is a directory"),
        (lambda: (tmp_path / "f.ply").write_text("x") and save_points(tmp_path / "f.ply" / "x.ply", P, N),
         "a file is in the way"),
        (lambda: load_points(None), "load_points: path must be a file name"),
        (lambda: load_points(3), "load_points: path must be a file name"),
        (lambda: h.srgb([h.n_nodes]), rf"srgb: node indices must lie in \[0, {h.n_nodes}\)"),
        (lambda: h.srgb([-1]), r"got -1\.\.-1"),  # before: wrapped to the last node
        (lambda: splat_discs(h, np.array([2 ** 63], np.uint64)), "got 9223372036854775808"),  # was -9.2e18
        (lambda: build_points(P + 1j, N), "points must be real numbers, got complex"),
        (lambda: build_points(P, N * (1 + 1j)), "normals must be real numbers"),
        (lambda: build_points(P, N, np.full(P.shape, 0.5 + 0j)), "colors must be real numbers"),
        (lambda: build_points(P, N, np.full(P.shape, 1000, np.uint16)),
         r"integer colors must lie in \[0, 255\] \(got 1000\.\.1000\)"),
        (lambda: build_points(P, N, leaf_k=10 ** 9), "leaf_k must be a positive integer up to 64"),
        (lambda: traverse(h, "view"), "traverse: view must be an optim.View"),
    ]
    for fn, match in cases:
        with pytest.raises(pm.PlodError, match=match) as exc:
            fn()
        assert "\n" not in str(exc.value)
    v = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0.0]])
    optim.save_mesh(tmp_path / "flat.ply", v, np.array([[0, 1, 2], [0, 2, 1]]))
    with pytest.raises(pm.PlodError, match=r"flat\.ply.*every face is degenerate"):  # before: (0, 3) arrays
        load_points(tmp_path / "flat.ply")
    np.testing.assert_allclose(h.srgb([0, h.n_nodes - 1]), h.srgb()[[0, -1]])
    np.testing.assert_allclose(build_points(P, N, np.full(P.shape, 255, np.uint8)).srgb([0]), 1.0, rtol=1e-6)


@pytest.mark.parametrize("toml, match", [
    ('point_cloud = ["no"]', "'point_cloud' must be a list of true / false"),
    ('names = [3]', "'names' must be a list of strings"),
    ('object_deg = ["a"]', r"'object_deg' must be a list of object sizes in \(0, 180\)"),
    ('object_deg = [10.0, 10]', "'object_deg' must be a list of different values"),
    ('curve_gaze_deg = [5.0, 5.0]', "'curve_gaze_deg' must be a list of different values"),
    ('min_px = -1', "'min_px' must be a finite number of pixels >= 0"),
    ('leaf_k = 0', r"'leaf_k' must be an integer in \[1, 64\]"),
    ('leaf_k = true', r"'leaf_k' must be an integer in \[1, 64\]"),
    ('repeats = -3', "'repeats' must be an integer >= 1"),
    ('gaze_error_deg = -1.0', "'gaze_error_deg' must be a finite angle"),
    ('directions = [[0, 0, 0]]', "'directions' must be a list of nonzero 3-vectors"),
    ('paths = ["sphere:x"]', "must be 'sphere:SUBDIV' with an integer"),
    ('paths = ["no/such/file.ply"]', "point file 'no/such/file.ply' does not exist"),
])
def test_points_config_is_checked_before_any_work(tmp_path, toml, match):
    """Every config value is checked before the output folder is made (before: ["no"] counted as true,
    names = [3] failed after the work, min_px = -1 after the folder was made, repeats = -3 was taken, a
    repeated object_deg overwrote its own figure)."""
    from experiments import points as P

    lines = {"paths": '["sphere:2"]', "names": '["s"]', "point_cloud": "[false]", "directions": "[[0, 0, 1]]",
             "ups": "[[0, 1, 0]]"}
    key, value = toml.split(" = ", 1)
    lines[key] = value
    cfg = tmp_path / "c.toml"
    cfg.write_text("".join(f"{k} = {v}\n" for k, v in lines.items()))
    out = tmp_path / "rep"
    with pytest.raises(pm.PlodError, match=match) as exc:
        P.main(["--quick", "--no-judge", "--config", str(cfg), "--out", str(out)])
    assert "\n" not in str(exc.value) and not out.exists()

"""A fuzz round over the ``optim`` API (2026-12-06, reports/robustness.md): each case below gave a raw
exception (TypeError, IndexError, AttributeError, numpy's "truth value is ambiguous"), a silently wrong
answer or a compile time growing with the input before it was fixed; every bad input must now be one
``PlodError`` line, and every fixed silent answer is checked against the right one."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import optim
from pmetric import PlodError


@pytest.fixture(scope="module")
def case():
    v, f = optim.bumpy_sphere(2)
    tree = optim.build_tree(v, f)
    view = optim.View.framing(v)
    keys = optim.score(tree, view, metric="size")
    return v, f, tree, view, keys


@pytest.fixture(scope="module")
def points():
    P, N, _ = optim.points_from_mesh(*optim.bumpy_sphere(2))
    return optim.build_points(P, N), optim.View(eye=(0.0, 0.0, 4.0))


# ----------------------------------------------------------------------------------- silent answers
def test_extract_ignores_leaves_marked_unfolded(case):
    """A leaf has nothing to unfold: an all-True mask is the whole mesh (before: one vertex, every face
    collapsed onto it), and leaves added to a cut's mask change nothing."""
    v, f, tree, _, keys = case
    vv, ff, _ = optim.extract(tree, np.ones(tree.n_nodes, bool))
    np.testing.assert_array_equal(vv, tree.vertices)
    np.testing.assert_array_equal(ff, tree.faces)
    cut = optim.budget_cut(tree, keys, 200)
    extra = cut.unfolded | (tree.child_count == 0)
    for a, b in zip(optim.extract(tree, cut), optim.extract(tree, extra)):
        assert (a is None and b is None) or np.array_equal(a, b)
    assert optim.cut_flips(tree, extra).triangles == cut.triangles


def test_light_and_normals_of_any_length_are_directions(points):
    """A light direction or point normal 1e-170 or 1e200 long is a direction (before: 'must be nonzero',
    and a 1e200 light shaded everything with its ambient only; 1e200 normals became zero)."""
    v, f = optim.bumpy_sphere(1)
    ref = optim.vertex_luminance(v, f, lighting=optim.Lighting(direction=(1.0, 2.0, 0.0)))
    for s in (1e-170, 1e200):
        got = optim.vertex_luminance(v, f, lighting=optim.Lighting(direction=(s, 2 * s, 0.0)))
        np.testing.assert_allclose(got, ref, rtol=1e-6)
        assert got.max() > 0.9  # lit, not ambient only
    P, N, _ = optim.points_from_mesh(*optim.bumpy_sphere(2))
    h, view = points
    for s in (1e-200, 1e200):
        np.testing.assert_allclose(optim.build_points(P, N * s).normal, h.normal, rtol=1e-6, atol=1e-7)


def test_vertex_luminance_checks_its_colours():
    """Integer colours are 0..255 as everywhere else (before: uint8 255 gave a luminance of 524,947); NaN,
    out-of-range and mis-shaped colours are errors (before: returned as NaN, 43 or 2 values)."""
    v, f = optim.bumpy_sphere(1)
    rng = np.random.default_rng(0)
    c8 = rng.integers(0, 256, (len(v), 3)).astype(np.uint8)
    np.testing.assert_allclose(optim.vertex_luminance(v, f, c8), optim.vertex_luminance(v, f, c8 / 255.0),
                               rtol=1e-6)
    for bad, msg in ((np.full((len(v), 3), np.nan), "NaN"), (np.full((len(v), 3), 5.0), r"\[0, 1\]"),
                     (np.zeros((2, 3)), "shape"), (np.full((len(v), 3), 300), "0..255")):
        with pytest.raises(PlodError, match=msg):
            optim.vertex_luminance(v, f, bad)
    with pytest.raises(PlodError, match="out of range"):
        optim.vertex_luminance(v, f + len(v))
    with pytest.raises(PlodError, match="NaN"):
        optim.vertex_luminance(np.full_like(v, np.nan), f)


def test_views_and_trees_keep_their_own_arrays():
    """Changing the caller's arrays after the fact changes neither the tree nor the view (before: the tree's
    vertices and the view's eye and gaze were the caller's arrays, so its cached geometry went stale)."""
    v, f = optim.bumpy_sphere(1)
    v0 = v.copy()
    tree = optim.build_tree(v, f)
    v[0] += 10.0
    np.testing.assert_array_equal(tree.vertices[0], v0[0])
    eye, gaze = np.array([0.0, 0.0, 5.0]), np.array([[100.0, 200.0]])
    view = optim.View(eye=eye, gaze=gaze)
    eye[2], gaze[0, 0] = 50.0, 1e6
    assert view.eye[2] == 5.0 and view.gaze_px[0, 0] == 100.0
    with pytest.raises(ValueError):
        view.eye[0] = 1.0  # read-only


def test_many_gaze_points_compile_once_and_score_as_unrolled(case, monkeypatch):
    """Twelve gaze points take the loop (the program no longer grows with G: 1,000 points took 53 s to
    compile), with the keys of the unrolled minimum."""
    import optim._terms as T

    v, f, tree, _, _ = case
    gaze = np.random.default_rng(1).random((12, 2)) * [1920, 1080]
    view = optim.View.framing(v, gaze=gaze)
    assert gaze.shape[0] > T._UNROLL_GAZE
    looped = optim.score(tree, view)
    monkeypatch.setattr(T, "_UNROLL_GAZE", 100)
    jax.clear_caches()
    unrolled = optim.score(tree, view)
    jax.clear_caches()
    np.testing.assert_array_equal(looped, unrolled)
    nearest = optim.score(tree, optim.View.framing(v, gaze=gaze[:1]))
    assert (looped >= nearest - 1e-6).all()  # more gaze points: never a larger eccentricity


# -------------------------------------------------------------------------------- one-line errors
def _bad_cases(v, f, tree, view, keys, h, pview):
    other_h = optim.build_points(np.random.default_rng(0).random((30, 3)), np.tile([0.0, 0.0, 1.0], (30, 1)))
    other_terms = optim.point_terms(other_h, pview)
    L = optim.Lighting()
    return {
        "colors-text": (lambda: optim.build_tree(v, f, colors=np.full((len(v), 3), "a")), "colors must be real"),
        "method-array": (lambda: optim.build_tree(v, f, method=np.array(["qem", "x"])), "method must be one of"),
        "agg-nan": (lambda: optim.build_tree(v, f, method="qem", qem_aggressiveness=np.nan), "qem_aggressiveness"),
        "agg-negative": (lambda: optim.build_tree(v, f, method="qem", qem_aggressiveness=-1), "qem_aggressiveness"),
        "agg-text": (lambda: optim.build_tree(v, f, method="qem", qem_aggressiveness="x"), "qem_aggressiveness"),
        "faces-1e20": (lambda: optim.build_tree(v, np.full((3, 3), 1e20)), "out of range"),
        "metric-array": (lambda: optim.score(tree, view, metric=np.array(["size"])), "metric must be one of"),
        "exact-text": (lambda: optim.score(tree, view, exact="no"), "exact must be True or False"),
        "threshold-text": (lambda: optim.threshold_cut(tree, keys, "x"), "threshold must be a number"),
        "repair-length": (lambda: optim.repair_monotone(tree, keys[:5]), r"keys must have shape"),
        "repair-nan": (lambda: optim.repair_monotone(tree, np.full(tree.n_nodes, np.nan)), "NaN"),
        "budget-tree-none": (lambda: optim.budget_cut(None, keys, 10), "tree must be an optim.VertexTree"),
        "extract-tree-none": (lambda: optim.extract(None, np.zeros(3, bool)), "tree must be an optim.VertexTree"),
        "visible-tree-none": (lambda: optim.visible_budget_cut(None, keys, 10, view), "tree must be"),
        "visible-margin-text": (lambda: optim.visible_budget_cut(tree, keys, 10, view, margin_deg="x"), "margin_deg"),
        "visible-tolerance-text": (lambda: optim.visible_budget_cut(tree, keys, 10, view, tolerance="x"), "tolerance"),
        "visible-evaluations-nan": (lambda: optim.visible_budget_cut(tree, keys, 10, view, max_evaluations=np.nan),
                                    "max_evaluations"),
        "visible-evaluations-fraction": (lambda: optim.visible_budget_cut(tree, keys, 10, view, max_evaluations=1.9),
                                         "max_evaluations"),
        "visible-eye-text": (lambda: optim.visible_budget_cut(tree, keys, 10, "abc"), "the eye must be"),
        "facing-eye-1e300": (lambda: optim.facing_away(v, f, (1e300,) * 3, margin_deg=1.0), "within 1e150"),
        "facing-faces-range": (lambda: optim.facing_away(v, f + len(v), view), "out of range"),
        "facing-quads": (lambda: optim.facing_away(v, np.c_[f, f[:, :1]], view), "triangles"),
        "facing-nan-vertices": (lambda: optim.facing_away(np.full_like(v, np.nan), f, view), "NaN"),
        "drop-not-a-mesh": (lambda: optim.drop_back_faces((v, f), view), "mesh must be"),
        "drop-normals-shape": (lambda: optim.drop_back_faces((v, f, None, np.zeros((3, 3))), view), "normals must"),
        "lighting-direction-text": (lambda: optim.Lighting(direction="abc"), "direction must be"),
        "lighting-ambient-none": (lambda: optim.Lighting(ambient=None), "ambient must be"),
        "lighting-ambient-bool": (lambda: optim.Lighting(ambient=True), "ambient must be"),
        "lighting-two-sided-text": (lambda: optim.Lighting(two_sided="no"), "two_sided must be"),
        "lighting-two-lights": (lambda: optim.View(eye=(0, 0, 5), lighting=[L, L]), "one light only"),
        "view-gaze-error-text": (lambda: optim.View(eye=(0, 0, 5), gaze_error_deg="x"), "gaze_error_deg"),
        "view-background-text": (lambda: optim.View(eye=(0, 0, 5), background="x"), "background"),
        "view-image-size-fraction": (lambda: optim.View(eye=(0, 0, 5), image_size=(100.7, 100.0)), "image_size"),
        "view-image-size-bool": (lambda: optim.View(eye=(0, 0, 5), image_size=(True, True)), "image_size"),
        "points-progress": (lambda: optim.build_points(np.eye(3), np.eye(3), progress=5), "progress must be"),
        "traverse-other-terms": (lambda: optim.traverse(h, pview, terms=other_terms), "terms must be the PointTerms"),
        "traverse-terms-int": (lambda: optim.traverse(h, pview, terms=5), "terms must be the PointTerms"),
        "walk-flags-shape": (lambda: optim.walk(h, np.zeros(3, bool), np.zeros(3, bool)), "culled must be"),
        "splat-node-negative": (lambda: optim.splat_discs(h, [-1]), r"node indices must lie in"),
        "splat-node-fraction": (lambda: optim.splat_discs(h, [0.7]), "node indices"),
        "splat-tint-nan": (lambda: optim.splat_discs(h, [0], tint=[[np.nan, 0, 0]]), "tint must be"),
        "splat-segments-text": (lambda: optim.splat_discs(h, [0], segments="x"), "segments must be"),
        "cut-normals-unknown": (lambda: optim.cut_normals(tree, v, f, np.zeros(len(v), int), "bogus"), "normals must"),
        "cut-normals-nodes": (lambda: optim.cut_normals(tree, v, f, np.full(len(v), 10**9), "region"), "nodes must"),
    }


CASES = ["colors-text", "method-array", "agg-nan", "agg-negative", "agg-text", "faces-1e20", "metric-array",
         "exact-text", "threshold-text", "repair-length", "repair-nan", "budget-tree-none", "extract-tree-none",
         "visible-tree-none", "visible-margin-text", "visible-tolerance-text", "visible-evaluations-nan",
         "visible-evaluations-fraction", "visible-eye-text", "facing-eye-1e300", "facing-faces-range", "facing-quads",
         "facing-nan-vertices", "drop-not-a-mesh", "drop-normals-shape", "lighting-direction-text",
         "lighting-ambient-none", "lighting-ambient-bool", "lighting-two-sided-text", "lighting-two-lights",
         "view-gaze-error-text", "view-background-text", "view-image-size-fraction", "view-image-size-bool",
         "points-progress", "traverse-other-terms", "traverse-terms-int", "walk-flags-shape", "splat-node-negative",
         "splat-node-fraction", "splat-tint-nan", "splat-segments-text", "cut-normals-unknown", "cut-normals-nodes"]


@pytest.fixture(scope="module")
def bad_cases(case, points):
    return _bad_cases(*case, *points)


@pytest.mark.parametrize("name", CASES)
def test_bad_arguments_are_one_line_errors(bad_cases, name):
    call, msg = bad_cases[name]
    with pytest.raises(PlodError, match=msg) as exc:
        call()
    assert "\n" not in str(exc.value)


def test_every_case_is_listed(bad_cases):
    assert sorted(bad_cases) == sorted(CASES)

"""What a viewer sees: the imperceptible cut of a small mesh is invisible to the independent judge
(FovVideoVDP), relit and baked; and the accuracy sweep's summary numbers are computed from its rows.

The judge runs on small renders (480 x 270 with the display's angular content); skipped without torch
and pyfvvdp (the ``judge`` extra) or without an OpenGL context.
"""

from __future__ import annotations

import numpy as np
import pytest

import optim
from experiments import accuracy as A

SIZE = (480, 270)


@pytest.fixture(scope="module")
def judge():
    pytest.importorskip("torch")
    pytest.importorskip("pyfvvdp")
    from experiments.judge import judge as j

    return j


def _judged(judge, *a, **k):
    try:
        return judge(*a, **k)
    except RuntimeError as exc:  # no EGL here
        if "OpenGL" in str(exc):
            pytest.skip(str(exc))
        raise


@pytest.mark.parametrize("lighting", ["relit", "baked"])
def test_imperceptible_cut_is_invisible_to_the_judge(judge, lighting):
    v, f = optim.bumpy_sphere(4, seed=5, amplitude=0.1)
    mesh = A._Mesh("sphere", v, f, None)
    tree = mesh.tree[lighting]
    view = A._view(mesh, np.array([0.4, 0.3, 0.87]), 4.0, lighting,
                   {"object_deg": 30.0, "gaze_error_deg": 1.0}, model_lights=True)
    cut = optim.imperceptible_cut(tree, view)
    assert 0 < cut.triangles < tree.n_triangles  # something is folded
    res = _judged(judge, mesh.original(lighting), optim.extract(tree, cut), view, mode=lighting,
                  lighting=optim.Lighting() if lighting == "relit" else None, size=SIZE, heatmap=False)
    assert res.jod >= A.IMPERCEPTIBLE_TARGET
    # and the same number of triangles chosen by size keys is visible: the judge can tell
    keys = optim.score(tree, view, None, "size")
    worse = optim.extract(tree, optim.budget_cut(tree, keys, max(cut.triangles // 3, 1), monotone="trust"))
    res2 = _judged(judge, mesh.original(lighting), worse, view, mode=lighting,
                   lighting=optim.Lighting() if lighting == "relit" else None, size=SIZE, heatmap=False)
    assert res2.jod < res.jod - 0.1


def test_front_facing_budget_looks_better_at_equal_drawn_triangles(judge):
    """The judge's view of ``optim.visible_budget_cut``: at the same number of drawn triangles, spending
    them all on the side that faces the eye scores higher than a plain budget cut, and dropping the back
    faces of one cut (keeping its normals) does not change its score at all."""
    v, f = optim.bumpy_sphere(4, seed=5, amplitude=0.1)
    mesh = A._Mesh("sphere", v, f, None)
    tree = mesh.tree["relit"]
    view = A._view(mesh, np.array([0.4, 0.3, 0.87]), 4.0, "relit", {"object_deg": 30.0, "gaze_error_deg": 1.0},
                   model_lights=True)
    keys = optim.score(tree, view)
    budget = tree.n_triangles // 20
    plain = optim.extract(tree, optim.budget_cut(tree, keys, budget, monotone="trust"))
    front = optim.visible_budget_cut(tree, keys, len(plain[1]), view, monotone="trust")
    assert front.triangles <= len(plain[1]) and front.cut.triangles > 1.5 * len(plain[1])
    kw = dict(mode="relit", lighting=optim.Lighting(), size=SIZE, heatmap=False)
    j_plain = _judged(judge, mesh.original("relit"), plain, view, **kw).jod
    j_front = _judged(judge, mesh.original("relit"), front.mesh, view, **kw).jod
    j_whole = _judged(judge, mesh.original("relit"), optim.extract(tree, front.cut), view, **kw).jod
    assert j_front > j_plain + 0.1
    assert j_front == pytest.approx(j_whole, abs=1e-6)


def _row(cell, lighting, method, budget, jod, tri=100, inp=1000):
    return dict(cell=cell, lighting=lighting, method=method, budget=budget, jod=jod, triangles=tri,
                input_triangles=inp, update_ms=10.0 if method == "perceptual" else None)


def test_summary_counts_wins_and_gains():
    cfg = {**A.DEFAULTS, "lightings": ["relit"], "budgets": [0.1], "model_budget": 0.1}
    rows = [
        _row("a", "relit", "imperceptible", None, 9.9, 400), _row("b", "relit", "imperceptible", None, 9.7, 600),
        _row("a", "relit", "perceptual", 0.1, 9.5), _row("a", "relit", "size", 0.1, 9.3),
        _row("a", "relit", "geometric", 0.1, 9.4), _row("a", "relit", "meshoptimizer", 0.1, 9.45),
        _row("b", "relit", "perceptual", 0.1, 9.0), _row("b", "relit", "size", 0.1, 9.2),
        _row("b", "relit", "fast_simplification", 0.1, 8.0), _row("b", "relit", "model:x", 0.1, 9.1),
    ]
    s = A.summarise(rows, cfg)
    imp = s["imperceptible"]["relit"]
    assert imp["cells"] == 2 and imp["min_jod"] == 9.7 and imp["share_at_target"] == 0.5
    assert imp["median_kept"] == pytest.approx(0.5)
    b = s["budget"]["relit"]
    assert b["cells"] == 2 and b["share_best"] == 0.5
    assert b["median_gain"] == pytest.approx(np.median([9.5 - 9.45, 9.0 - 9.2]))
    assert s["models"]["relit"] == {"perceptual": pytest.approx(9.25), "model:x": 9.1}
    assert s["update_ms"]["relit"] == 10.0


def test_report_names_config_files_not_found(tmp_path):
    """Mesh and model files the config names but the checkout lacks are skipped (the procedural cells still
    run without ../shared), and the report says which: a sweep with fewer cells than its config is not
    silent about it."""
    rows = [_row("a", "relit", "perceptual", 0.1, 9.5), _row("a", "relit", "size", 0.1, 9.3)]
    cfg = {**A.DEFAULTS, "lightings": ["relit"], "budgets": [0.1], "model_budget": 0.1,
           "meshes": ["../shared/data/meshes/horse.ply", "nowhere/missing-mesh.ply"],
           "models": ["kellyabstract", "nowhere/missing-model.json"]}
    A.write_report(rows, cfg, "test", tmp_path)
    text = (tmp_path / "report.md").read_text()
    line = next(ln for ln in text.splitlines() if ln.startswith("**Not run**"))
    assert "`nowhere/missing-mesh.ply`" in line and "`nowhere/missing-model.json`" in line
    assert "kellyabstract" not in line and ("horse.ply" in line) != A.repo_path(cfg["meshes"][0]).is_file()
    A.write_report(rows, {**cfg, "meshes": [], "models": ["kellyabstract"]}, "test", tmp_path)
    assert "**Not run**" not in (tmp_path / "report.md").read_text()


def test_views_are_seeded_and_not_from_above():
    a = A.view_directions(5, 7, "horse")
    np.testing.assert_array_equal(a, A.view_directions(5, 7, "horse"))
    assert not np.array_equal(a, A.view_directions(5, 8, "horse"))
    assert np.allclose(np.linalg.norm(a, axis=1), 1.0) and (np.abs(a[:, 1]) < np.sin(np.radians(60))).all()


def test_bad_procedural_spec_is_one_error():
    with pytest.raises(ValueError, match="procedural"):
        A.load_meshes({"meshes": [], "procedural": ["cube:3"]})


@pytest.mark.parametrize("line, msg", [('normals = "smooth"', "normals must be one of region, faces"),
                                       ('method = "kdtree"', "method must be one of qem, octree, meshopt, hybrid")])
def test_bad_normals_or_method_in_config_is_one_line_error(tmp_path, capsys, line, msg):
    cfg = tmp_path / "c.toml"
    cfg.write_text(line + "\n")
    with pytest.raises(A.PlodError, match=msg) as e:
        A.main(["--config", str(cfg), "--quick", "--out", str(tmp_path / "out")])
    assert "\n" not in str(e.value) and not (tmp_path / "out").exists()


def test_plod_mesh_carries_the_configured_normals():
    """``normals = "region"``: plod's cuts carry optim.extract's region normals, with and without culling;
    ``"faces"`` without culling: no normals (the renderer makes the faces' own)."""
    v, f, c = optim.bumpy_sphere(3, seed=2, colors=True)
    tree = optim.build_tree(v, f, c)
    view = optim.View.framing(v, direction=(0.2, 0.3, 1.0), lighting=optim.Lighting())
    keys = optim.score(tree, view)
    cfg = dict(A.DEFAULTS, normals="region")
    m, _ = A.plod_mesh(tree, keys, view, cfg, 300)
    cut = optim.budget_cut(tree, keys, 300, monotone="trust")
    np.testing.assert_array_equal(m[3], optim.extract(tree, cut, "region")[3])
    assert len(A.plod_mesh(tree, keys, view, dict(A.DEFAULTS), 300)[0]) == 3
    mc, _ = A.plod_mesh(tree, keys, view, dict(cfg, face_cull=True), 300)
    assert len(mc) == 4 and np.allclose(np.linalg.norm(mc[3][np.unique(mc[1])], axis=1), 1.0, atol=1e-6)

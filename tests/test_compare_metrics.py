"""experiments/compare_metrics.py: the quick run's files, one row recomputed independently, config errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

import optim
from experiments import compare_metrics as CM
from experiments import render as R


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("compare_metrics")
    assert CM.main(["--quick", "--out", str(out)]) == 0
    return out, json.loads((out / "results.json").read_text())


def test_quick_run_writes_the_files(quick):
    out, res = quick
    for name in ("report.md", "results.json", "run_info.json", "distance_vs_triangles.png"):
        assert (out / name).stat().st_size > 0, name
    info = json.loads((out / "run_info.json").read_text())
    assert "--quick" in info["command"] and info["config"]["budgets"] == [0.05, 0.10]
    recs = res["records"]
    # one procedural mesh x two budgets x one view x five methods
    assert len(recs) == 2 * 5 and {r["method"] for r in recs} == set(CM.METHODS)
    report = (out / "report.md").read_text()
    assert "## Summary" in report and "| budget | method | triangles |" in report
    if res["gl"]["ok"]:
        for name in ("flip_vs_triangles.png", "wflip_vs_triangles.png", "time_vs_flip.png",
                     "comparison_bumpy_sphere_4.png"):
            assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
    else:
        assert "No FLIP columns" in report


def test_budgets_and_distances_follow_the_greedy_order(quick):
    _, res = quick
    recs = res["records"]
    T = res["meshes"][0]["triangles"]
    for frac in res["config"]["budgets"]:
        cell = {r["method"]: r for r in recs if r["budget_fraction"] == frac}
        budget = int(round(frac * T))
        for m in CM.METRICS:
            assert cell[m]["budget"] == budget
            assert 0 < cell[m]["triangles"] <= budget
            assert cell[m]["ms"] > 0
        # perceptual-keyed cut: its own distance is the recorded k; no other key order reaches a smaller k
        assert cell["perceptual"]["distance"] == pytest.approx(cell["perceptual"]["key_distance"], rel=1e-6)
        assert cell["perceptual"]["distance"] <= cell["size"]["distance"]
        assert cell["perceptual"]["distance"] <= cell["geometric"]["distance"]
        for m in CM.BASELINES:
            assert cell[m]["distance"] is None  # no vertex tree, no imperceptible distance
    # more triangles, smaller (or equal) distance
    ks = [r["distance"] for r in sorted((r for r in recs if r["method"] == "perceptual"), key=lambda r: r["budget"])]
    assert ks[0] >= ks[1] > 0


def test_one_row_recomputed_independently(quick):
    """Rebuild the quick mesh, cut it with perceptual keys and FLIP the renders ourselves."""
    _, res = quick
    cfg = res["config"]
    row = next(r for r in res["records"] if r["method"] == "perceptual" and r["budget_fraction"] == 0.10)
    v, f, c = optim.bumpy_sphere(cfg["procedural"], seed=cfg["seed"], colors=True)
    tree = optim.build_tree(v, f, colors=c, method=cfg["method"])
    view = optim.View.framing(tree.vertices, object_deg=30.0, gaze_error_deg=1.0)
    keys = optim.score(tree, view, optim.default_model(), "perceptual")
    cut = optim.budget_cut(tree, keys, int(round(0.10 * tree.n_triangles)))
    assert cut.triangles == row["triangles"]
    assert cut.distance == pytest.approx(row["distance"], rel=1e-6)
    if not res["gl"]["ok"]:
        pytest.skip(f"no OpenGL: {res['gl']['error']}")
    size = tuple(cfg["render_size"])
    try:
        a = R.render(tree.vertices, tree.faces, tree.colors, view, lighting=tree.lighting, size=size)
    except RuntimeError as exc:  # pragma: no cover - GL vanished between the run and the check
        pytest.skip(str(exc))
    b = R.render(*optim.extract(tree, cut), view, lighting=tree.lighting, size=size)
    ppd = float(view.display.pixels_per_degree()) * size[0] / view.width
    emap, mean = R.flip(a, b, ppd)
    assert mean == pytest.approx(row["flip"], rel=1e-4, abs=1e-6)
    assert 0 < row["wflip"] <= row["flip"]
    w = CM.eccentricity_weights(view, optim.default_model(), size, 0.0)
    assert float(np.mean(w * emap)) == pytest.approx(row["wflip"], rel=1e-4, abs=1e-7)
    # the table shows that row
    report = (quick[0] / "report.md").read_text()
    assert f"{row['flip']:.4f}" in report


def test_eccentricity_weights():
    v, _ = optim.icosphere(2)
    model = optim.default_model()
    view = CM.gaze_view(v, 15.0, {"object_deg": 30.0, "gaze_error_deg": 1.0})
    w = CM.eccentricity_weights(view, model, (96, 54), 4.0)
    assert w.shape == (54, 96) and np.all((w >= 0) & (w <= 1))
    # the gaze is 15 deg right of the centre: full weight there, far less at the screen centre and left edge
    gx = view.gaze_px[0, 0] * 96 / view.width
    assert w[27, int(gx)] == pytest.approx(1.0)
    # pixel column 48 of 96 is centred 10 display px (~0.25 deg) right of the screen centre: e' in (13.5, 14)
    rel = lambda e: float(model.sensitivity(4.0, e) / model.sensitivity(4.0, 0.0))  # noqa: E731
    assert rel(14.0) < w[27, 48] < rel(13.5)
    assert w[27, 0] < w[27, 48]
    # the gaze direction is 15 deg from the viewing axis
    assert view.visual_angle_px(view.gaze_px[0], [view.width / 2, view.height / 2]) == pytest.approx(15.0, abs=1e-6)


def test_unknown_config_key_is_rejected(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text('budgetz = [0.1]\n')
    with pytest.raises(ValueError, match="unknown config key 'budgetz'"):
        CM.main(["--config", str(p), "--out", str(tmp_path / "out")])
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("text, key", [
    ("budgets = [0.1, 1.5]", "budgets"),
    ("gaze_offsets_deg = []", "gaze_offsets_deg"),
    ("render_size = [480]", "render_size"),
    ('model = "nosuchcsf"', "model"),
    ('method = "random"', "method"),
    ("repeats = 0", "repeats"),
    ('budgets = "ten percent"', "budgets"),
])
def test_bad_config_values_name_the_key(tmp_path, text, key):
    p = tmp_path / "bad.toml"
    p.write_text(text + "\n")
    with pytest.raises(ValueError, match=key):
        CM.main(["--config", str(p), "--quick", "--out", str(tmp_path / "out")])

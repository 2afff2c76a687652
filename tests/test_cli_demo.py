"""`plod demo`: the built-in job gives consistent thresholds, cuts and judged images (values, not just
that it runs), on short settings (a 1,280-triangle mesh, 192x108 renderings)."""

from __future__ import annotations

import json
import re
import sys

import numpy as np
import pytest

from experiments.cli import main

PNG = b"\x89PNG\r\n\x1a\n"
SHORT = ["demo", "--subdivisions", "3", "--budget-fraction", "0.2", "--size", "192x108"]


def _run(capsys, args):
    rc = main(args)
    cap = capsys.readouterr()
    if rc != 0 and "OpenGL" in cap.err:
        pytest.skip(cap.err)
    assert rc == 0, cap.err
    return cap.out


def _summary_rows(md: str) -> dict:
    """{result: [cells]} of the summary's results table."""
    rows = {}
    for line in md.splitlines():
        m = re.match(r"\| (perceptual|size|imperceptible) \| (.*) \|$", line)
        if m:
            rows[m.group(1)] = [c.strip() for c in m.group(2).split("|")]
    return rows


def test_demo_writes_report_with_images(tmp_path, capsys):
    pytest.importorskip("torch")
    pytest.importorskip("pyfvvdp")
    import optim
    from experiments.judge import offset_gaze_view

    out = json.loads(_run(capsys, [*SHORT, "--out", str(tmp_path), "--json"]))
    # The default display spans 46 degrees (the study of [LH01 §6.2]) and xi = 1/(2 * degrees per pixel).
    d = out["display"]
    assert abs(d["field_of_view_deg"][0] - 46.0) < 1e-3
    centre_deg_per_px = np.degrees(2 * np.tan(np.radians(23.0)) / 1920)
    assert abs(d["xi_cycles_per_deg"] - 1 / (2 * centre_deg_per_px)) < 1e-3
    ms = out["thresholds"]["Manos-Sakrison"]
    assert abs(ms["peak_frequency"] - 7.89) < 0.02  # Manos-Sakrison's published peak
    for row in out["thresholds"].values():
        assert all(c > 0 for c in row["threshold_contrast"])
        assert row["imperceptible_distance"] is None or row["imperceptible_distance"] > 0

    s = out["simplification"]
    assert s["input_triangles"] == 20 * 4**3 and s["gaze_deg"] == 20.0
    budget = int(0.2 * s["input_triangles"])
    cuts = s["cuts"]
    perc, size, imp = cuts["perceptual"], cuts["size"], cuts["imperceptible"]
    assert perc["triangles"] <= budget and size["triangles"] == perc["triangles"]
    # Ordering folds by perceptibility is what makes the perceptual cut imperceptible from closest.
    assert perc["distance"] <= size["distance"] + 1e-6
    assert imp["stop_reason"] == "imperceptible" and imp["distance"] <= 1.0 + 1e-6

    # The counts are the library's for the same mesh and view (recomputed here).
    v, f, c = optim.bumpy_sphere(3, seed=0, colors=True)
    tree = optim.build_tree(v, f, colors=c)
    view = offset_gaze_view(v, 20.0, object_deg=30.0, lighting=optim.Lighting())
    pk = optim.score(tree, view)
    assert optim.budget_cut(tree, pk, budget).triangles == perc["triangles"]
    assert optim.imperceptible_cut(tree, view).triangles == imp["triangles"]

    j = out["judge"]
    assert j["metrics"] == ["fovvdp", "flip"] and j["note"] is None and j["size"] == [192, 108]
    for name in ("perceptual", "size", "imperceptible"):
        r = j["judged"][name]
        assert np.isfinite(r["jod"]) and r["jod"] <= 10.0 + 1e-6
        assert 0.0 <= r["flip"] <= 1.0
        assert (tmp_path / r["image"]).read_bytes()[:8] == PNG
    # the imperceptible cut keeps more triangles than the budget cuts and looks at least as good
    assert imp["triangles"] > perc["triangles"]
    assert j["judged"]["imperceptible"]["flip"] <= j["judged"]["perceptual"]["flip"] + 1e-6

    # summary.md carries the same numbers as results.json, which equals what was printed
    saved = json.loads((tmp_path / "results.json").read_text())
    assert saved["simplification"]["cuts"] == cuts and saved["judge"]["judged"] == j["judged"]
    md = (tmp_path / "summary.md").read_text()
    rows = _summary_rows(md)
    assert set(rows) == {"perceptual", "size", "imperceptible"}
    for name, cells in rows.items():
        c_, r = cuts[name], j["judged"][name]
        assert int(cells[0].replace(",", "")) == c_["triangles"]
        assert float(cells[2]) == pytest.approx(c_["distance"], abs=5e-4)
        assert float(cells[4]) == pytest.approx(r["jod"], abs=5e-4)
        assert float(cells[5]) == pytest.approx(r["flip"], abs=5e-5)
        assert f"]({r['image']})" in md
    assert "plod demo --subdivisions 3" in md
    info = json.loads((tmp_path / "run_info.json").read_text())
    assert info["config"]["subdivisions"] == 3 and info["command"].startswith("plod demo")


def test_demo_without_judge_extra_still_writes_images(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "pyfvvdp", None)  # `import pyfvvdp` now raises ImportError
    text = _run(capsys, [*SHORT, "--out", str(tmp_path)])
    assert "pip install -e .[judge]" in text and f"wrote {tmp_path / 'summary.md'}" in text
    res = json.loads((tmp_path / "results.json").read_text())
    assert res["judge"]["metrics"] == ["flip"] and "pip install -e .[judge]" in res["judge"]["note"]
    for name, r in res["judge"]["judged"].items():
        assert r["jod"] is None and 0.0 <= r["flip"] <= 1.0
        assert (tmp_path / r["image"]).read_bytes()[:8] == PNG
    md = (tmp_path / "summary.md").read_text()
    assert "pip install -e .[judge]" in md and "| n/a |" in md


def test_demo_rejects_bad_options(capsys, tmp_path):
    assert main(["demo", "--budget-fraction", "1.5"]) == 2
    assert "--budget-fraction must be in (0, 1]" in capsys.readouterr().err
    assert main(["demo", "--size", "big"]) == 2
    assert "--size must be WIDTHxHEIGHT" in capsys.readouterr().err
    f = tmp_path / "file"
    f.write_text("x")
    assert main(["demo", "--out", str(f)]) == 2
    assert "is a file" in capsys.readouterr().err
    assert main(["demo", "--out", str(f / "x")]) == 2  # below a file: before, NotADirectoryError's traceback
    err = capsys.readouterr().err
    assert "Not a directory" in err and err.count("\n") == 1
    # a budget below the smallest non-empty cut (before: 0-triangle cuts judged and reported)
    assert main(["demo", "--subdivisions", "1", "--budget-fraction", "0.001", "--no-judge"]) == 2
    err = capsys.readouterr().err
    assert "below the smallest non-empty cut" in err and err.count("\n") == 1

"""`plod demo`: the built-in job gives consistent thresholds and cuts (values, not just that it runs)."""

from __future__ import annotations

import json

import numpy as np

from experiments.cli import main


def test_demo_json(capsys):
    assert main(["demo", "--subdivisions", "3", "--budget-fraction", "0.2", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    # The default display spans 46 degrees (the study of [LH01 §6.2]) and xi = 1/(2 * degrees per pixel).
    d = out["display"]
    assert abs(d["field_of_view_deg"][0] - 46.0) < 1e-3
    # Centre pixel of a 1920-pixel screen spanning 46 deg: 2 tan(23 deg) / 1920 of the distance, in degrees.
    centre_deg_per_px = np.degrees(2 * np.tan(np.radians(23.0)) / 1920)
    assert abs(d["xi_cycles_per_deg"] - 1 / (2 * centre_deg_per_px)) < 1e-3
    ms = out["thresholds"]["Manos-Sakrison"]
    assert abs(ms["peak_frequency"] - 7.89) < 0.02  # Manos-Sakrison's published peak
    for row in out["thresholds"].values():
        assert all(c > 0 for c in row["threshold_contrast"]) and row["imperceptible_distance"] > 0
    s = out["simplification"]
    assert s["input_triangles"] == 20 * 4**3
    cuts = s["cuts"]
    budget = int(0.2 * s["input_triangles"])
    perc = cuts[f"budget {budget:,}, perceptual keys"]
    size = cuts[f"budget {budget:,}, size keys"]
    assert perc["triangles"] <= budget and size["triangles"] <= budget
    # Ordering folds by perceptibility is what makes the perceptual cut imperceptible from closest.
    assert perc["distance"] <= size["distance"] + 1e-6
    imp = cuts["imperceptible"]
    assert imp["stop_reason"] == "imperceptible" and imp["distance"] <= 1.0 + 1e-6
    assert np.isfinite([c["distance"] for c in cuts.values()]).all()


def test_demo_rejects_bad_options(capsys):
    assert main(["demo", "--budget-fraction", "1.5"]) == 2
    assert "--budget-fraction must be in (0, 1]" in capsys.readouterr().err

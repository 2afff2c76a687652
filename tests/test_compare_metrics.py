"""experiments/compare_metrics.py is a config of the experiment runner: the shipped config resolves to
the comparison it names, --quick shrinks it, and its quick run's rows are the runner's."""

from __future__ import annotations

import pytest

from experiments import compare_metrics as CM
from experiments import experiment as E
from experiments._runinfo import repo_path


def test_the_config_is_the_comparison():
    cfg = E.load_experiment_config(repo_path(CM.CONFIG))
    assert cfg["methods"] == ["perceptual", "size", "geometric", "meshoptimizer", "fast_simplification"]
    assert cfg["judges"] == ["flip", "distance"] and cfg["tree_method"] == "qem"
    assert cfg["budgets"] == [0.02, 0.05, 0.10, 0.20, 0.40] and cfg["gaze_offsets_deg"] == [0.0, 15.0, 29.0]
    assert cfg["procedural"] == ["sphere:6:0"] and cfg["missing_meshes"] == "skip"


def test_quick_run_is_the_runner(tmp_path, monkeypatch):
    """The quick comparison with distance only (no rendering): the wrapper's rows are the runner's."""
    monkeypatch.setitem(CM.QUICK, "judges", ["distance"])
    monkeypatch.setitem(CM.QUICK, "procedural", ["sphere:3:0"])
    assert CM.main(["--quick", "--workers", "0", "--out", str(tmp_path / "a")]) == 0
    rows = E.read_table(tmp_path / "a" / "results.csv")
    assert len(rows) == 2 * 5 and (tmp_path / "a" / "report.md").is_file()
    cfg = E.check_config({**E.load_experiment_config(repo_path(CM.CONFIG)), **CM.QUICK})
    ref = E.run_experiment(cfg, out=tmp_path / "b", workers=0)
    assert E.strip_volatile(rows) == E.strip_volatile(ref)


def test_unknown_config_key_is_rejected(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text('budgetz = [0.1]\n')
    with pytest.raises(ValueError, match=r"unknown config key 'budgetz' \(.*line 1\)"):
        CM.main(["--config", str(p), "--out", str(tmp_path / "out")])
    assert not (tmp_path / "out").exists()

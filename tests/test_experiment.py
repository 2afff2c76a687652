"""``plod experiment`` (experiments/experiment.py): config errors name the key and its line; a killed
sweep resumes without repeating cells; local, process-pool and Dask runs give the same rows; the
Pareto plot draws the rows' values; a failed cell is recorded and the sweep goes on.

Cheap: a 1,280-triangle procedural sphere judged by plod's own distance only (no rendering).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from experiments import experiment as E
from experiments import _experiment_report as R
from pmetric import PlodError

ROOT = Path(__file__).resolve().parent.parent

TINY = """\
procedural = ["sphere:3:11"]
views = 1
gaze_offsets_deg = [0.0, 12.0]
budgets = [0.1, 300]
methods = ["imperceptible", "perceptual", "size", "geometric", "meshoptimizer", "fast_simplification"]
judges = ["distance"]
examples = 0
"""
N_CELLS = 2 * (1 + 5 * 2)  # gaze offsets x (imperceptible + 5 methods x 2 budgets)


def _cfg(tmp_path, text=TINY, name="tiny.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """An uninterrupted in-process run of the tiny sweep: (config, rows, out folder)."""
    d = tmp_path_factory.mktemp("expt_ref")
    cfg = E.load_experiment_config(_cfg(d))
    rows = E.run_experiment(cfg, out=d / "out", workers=0)
    return cfg, rows, d / "out"


# ----------------------------------------------------------------------------------------------- config
def test_unknown_key_names_the_key_and_its_line(tmp_path):
    p = _cfg(tmp_path, 'views = 1\n# a comment\n\nbudgetz = [0.1]\n')
    with pytest.raises(ValueError, match=r"unknown config key 'budgetz' \(.*tiny\.toml line 4\)"):
        E.load_experiment_config(p)
    p = _cfg(tmp_path, 'views = 1\n[judging]\nsize = 3\n')
    with pytest.raises(ValueError, match=r"unknown config key 'judging' \(.*line 2\)"):
        E.load_experiment_config(p)


@pytest.mark.parametrize("text, key, line", [
    ("views = 1\nbudgets = [0.1, 1.5]\n", "budgets", 2),
    ('views = 1\n\nmethods = ["perceptual", "nosuch"]\n', "methods", 3),
    ('methods = ["model:nosuchcsf"]\n', "methods", 1),
    ('judges = ["fovvdp", "psnr"]\n', "judges", 1),
    ('seed = 1\nviews = "two"\n', "views", 2),
    ('views = 1\nseed = -1\n', "seed", 2),
    ('procedural = ["cube:3"]\n', "procedural", 1),
    ('meshes = ["no/such/mesh.ply"]\n', "meshes", None),
    # found by fuzzing (2026-12-06): a traceback (unhashable nested lists), runs that should not start
    ('lightings = [[1]]\n', "lightings", 1),
    ('methods = [[1]]\n', "methods", 1),
    ('judges = [{a = 1}]\n', "judges", 1),
    ('procedural = ["sphere:2:-1"]\n', "procedural", 1),
    ('procedural = ["torus:200000:200000:0"]\n', "procedural", 1),
    ('gaze_error_deg = 1e300\n', "gaze_error_deg", 1),
    ('views = true\n', "views", 1),
    ('judge_size = [40000, 16]\n', "judge_size", 1),
])
def test_bad_values_name_the_key_and_line(tmp_path, text, key, line):
    p = _cfg(tmp_path, text)
    pat = rf"config key '{key}'" + (rf" \(.*line {line}\)" if line else "")
    with pytest.raises(ValueError, match=pat):
        E.cells(E.load_experiment_config(p))


@pytest.mark.parametrize("line", ["gaze_offsets_deg = [1.0, 1.0000001]", "gaze_offsets_deg = [0.0, 0]",
                                  "budgets = [0.5, 0.5000001]"])
def test_cells_of_one_id_are_refused(tmp_path, line):
    """Rows are keyed by cell id: two cells of one id kept one row and dropped the other silently."""
    p = _cfg(tmp_path, TINY.replace("gaze_offsets_deg = [0.0, 12.0]", "").replace("budgets = [0.1, 300]", "")
             + line + "\n")
    with pytest.raises(ValueError, match="two cells would share the id"):
        E.cells(E.load_experiment_config(p))


def test_one_triangle_and_the_whole_mesh_are_distinct_budgets(tmp_path):
    cfg = E.load_experiment_config(_cfg(tmp_path, TINY.replace("budgets = [0.1, 300]", "budgets = [1, 1.0]")))
    assert {c["budget"] for c in E.cells(cfg) if c["budget"] is not None} == {1, 1.0} and len(E.cells(cfg)) == 22


def test_a_config_error_leaves_the_last_run_untouched(tmp_path, reference):
    """A config that cannot run (a mesh file not found) is refused before the output folder is touched: the
    last run's journal and sweep record stay as they were (before: the journal was emptied and the record
    replaced by the new sweep's, so a later --resume checked against the wrong sweep)."""
    import shutil

    _, _, ref_out = reference
    out = tmp_path / "keep"
    shutil.copytree(ref_out, out)
    before = {n: (out / n).read_bytes() for n in ("results.jsonl", "experiment.json")}
    cfg = E.load_experiment_config(_cfg(tmp_path, TINY + 'meshes = ["typo.ply"]\n'))
    with pytest.raises(ValueError, match="'meshes'.*not found"):
        E.run_experiment(cfg, out=out, workers=0)
    assert {n: (out / n).read_bytes() for n in before} == before


@pytest.mark.parametrize("damage", ["{}", "[1]", "not json"])
def test_resume_with_a_damaged_sweep_record_is_one_line(tmp_path, reference, damage):
    import shutil

    cfg, _, ref_out = reference
    out = tmp_path / "damaged"
    shutil.copytree(ref_out, out)
    (out / "experiment.json").write_text(damage)
    with pytest.raises(ValueError, match="is not a sweep record of plod experiment"):
        E.run_experiment(cfg, out=out, workers=0, resume=True)


def test_resume_skips_journal_lines_that_are_not_rows(tmp_path, reference):
    """A damaged journal line (not a row of ours) is dropped and its cell runs again (before: AttributeError)."""
    import shutil

    cfg, ref_rows, ref_out = reference
    out = tmp_path / "lines"
    shutil.copytree(ref_out, out)
    lines = (out / "results.jsonl").read_text().splitlines(keepends=True)
    (out / "results.jsonl").write_text("5\n" + "".join(lines[1:]) + '"text"\n')
    rows = E.run_experiment(cfg, out=out, workers=0, resume=True)
    assert E.strip_volatile(rows) == E.strip_volatile(ref_rows)


@pytest.mark.parametrize("out", ["", "."])
def test_the_repository_root_is_not_an_output_folder(tmp_path, out):
    cfg = E.load_experiment_config(_cfg(tmp_path))
    with pytest.raises(ValueError, match="empty|repository root"):
        E.run_experiment(cfg, out=out, workers=0)


def test_a_config_overrides_its_base(tmp_path):
    _cfg(tmp_path, TINY, "base.toml")
    p = _cfg(tmp_path, 'base = "base.toml"\nbudgets = [0.2]\n', "over.toml")
    cfg = E.load_experiment_config(p)
    assert cfg["budgets"] == [0.2] and cfg["judges"] == ["distance"] and cfg["procedural"] == ["sphere:3:11"]
    assert cfg["views"] == E.DEFAULTS["views"] and cfg["examples"] == 0
    # the shipped configs load and the small one is small
    small = E.load_experiment_config(ROOT / "configs" / "experiment_small.toml")
    assert len(E.cells(small)) <= 20
    E.load_experiment_config(ROOT / "configs" / "experiment_full.toml")
    E.load_experiment_config(ROOT / "configs" / "compare_metrics.toml")


# ----------------------------------------------------------------------------------------------- cells
def test_reference_rows(reference):
    cfg, rows, out = reference
    assert len(rows) == N_CELLS and [r["index"] for r in rows] == list(range(N_CELLS))
    assert len({r["cell"] for r in rows}) == N_CELLS and not any(r["error"] for r in rows)
    T = rows[0]["input_triangles"]
    assert T == 1280
    groups = {}
    for r in rows:
        groups.setdefault((r["gaze_deg"], r["budget"]), {})[r["method"]] = r
    assert len(groups) == 2 * 3
    for (g, b), group in groups.items():
        if b == "-":
            continue
        n = round(float(b) * T) if "." in b else int(b)
        p = group["perceptual"]
        assert p["triangles"] == p["target_triangles"] <= n
        for m in ("size", "geometric", "meshoptimizer", "fast_simplification"):
            assert group[m]["target_triangles"] == p["triangles"]  # the same triangle count
            assert group[m]["triangles"] <= p["triangles"] + 2
        # plod's distance: perceptual keys give the smallest at their count
        assert p["distance"] <= group["size"]["distance"] and p["distance"] <= group["geometric"]["distance"]
        assert group["meshoptimizer"]["distance"] is None
    imp = [r for r in rows if r["method"] == "imperceptible"]
    assert all(r["distance"] <= 1.0 and r["budget"] == "-" for r in imp)
    # the table on disk holds the same rows
    assert E.strip_volatile(E.read_table(out / "results.csv")) == E.strip_volatile(rows)
    assert all(r["versions"].startswith("jax ") and r["time_cell_s"] > 0 for r in rows)


def test_killed_sweep_resumes_without_repeating_cells(tmp_path, reference):
    _, ref_rows, _ = reference
    cfg_path = _cfg(tmp_path, TINY.replace("sphere:3:11", "sphere:3:11") + f'out = "{tmp_path / "out"}"\n')
    journal = tmp_path / "out" / "results.jsonl"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    log = tmp_path / "stderr.txt"
    with open(log, "wb") as err:
        proc = subprocess.Popen([sys.executable, "-m", "experiments.experiment", str(cfg_path), "--workers", "0"],
                                cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=err)
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and proc.poll() is None:
            if journal.is_file() and journal.read_text().count("\n") >= 1:
                proc.send_signal(signal.SIGKILL)
                break
            time.sleep(0.005)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == -signal.SIGKILL, log.read_text()[-2000:]
    before = journal.read_text().splitlines()
    assert 1 <= len(before) < N_CELLS  # killed part way
    with open(journal, "a") as fh:  # and as if the kill had cut a line short
        fh.write('{"cell": "sphere-3-11/v0/g0/relit/b0.1/size", "index": 3, "tri')
    seen = []
    cfg = E.load_experiment_config(cfg_path)
    rows = E.run_experiment(cfg, workers=0, resume=True, progress=lambda s, d, t: seen.append((s, d, t)))
    assert seen[0] == ("resumed", len(before), N_CELLS) and seen[-1][1:] == (N_CELLS, N_CELLS)
    lines = [json.loads(x) for x in journal.read_text().splitlines()]
    cells = [r["cell"] for r in lines]
    assert len(cells) == len(set(cells)) == N_CELLS  # no cell repeated, none missing
    assert [json.loads(x)["cell"] for x in before] == cells[:len(before)]  # the finished ones kept as they were
    assert E.strip_volatile(rows) == E.strip_volatile(ref_rows)
    # a resume with a different sweep is refused
    cfg2 = {**cfg, "budgets": [0.2]}
    with pytest.raises(ValueError, match="--resume"):
        E.run_experiment(cfg2, workers=0, resume=True)


def test_local_processes_and_dask_give_the_same_rows(tmp_path, reference):
    cfg, ref_rows, _ = reference
    rows = E.run_experiment(cfg, out=tmp_path / "pool", workers=1)
    assert E.strip_volatile(rows) == E.strip_volatile(ref_rows)
    assert len({r["worker"] for r in rows}) == 1 and rows[0]["worker"] != ref_rows[0]["worker"]
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as lc:
        rows = E.run_experiment(cfg, out=tmp_path / "dask", scheduler=lc.scheduler_address)
    assert E.strip_volatile(rows) == E.strip_volatile(ref_rows)
    # the tree was built once on the worker: one cell records a build, the others reuse it
    assert sum(r["time_tree_s"] > 0 for r in rows) <= 1


def test_failed_cell_is_recorded_and_the_sweep_goes_on(tmp_path, monkeypatch, reference):
    cfg, ref_rows, _ = reference
    real = E._peer

    def flaky(method, *a):
        if method == "fast_simplification":
            raise RuntimeError("simplifier crashed | on purpose")
        return real(method, *a)

    monkeypatch.setattr(E, "_peer", flaky)
    rows = E.run_experiment(cfg, out=tmp_path / "out", workers=0)
    bad = [r for r in rows if r["error"]]
    assert len(rows) == N_CELLS and len(bad) == 4
    assert all(r["method"] == "fast_simplification" and r["error"] == "RuntimeError: simplifier crashed | on purpose"
               and r["triangles"] is None for r in bad)
    good = [r for r in rows if not r["error"]]
    ref_good = [r for r in ref_rows if r["method"] != "fast_simplification"]
    assert E.strip_volatile(good) == E.strip_volatile(ref_good)
    R.write_report(rows, cfg, tmp_path / "out", "test", examples=False)
    text = (tmp_path / "out" / "report.md").read_text()
    assert "## Failed cells" in text and "simplifier crashed / on purpose" in text
    # resume runs the failed cells again (here: now fixed)
    monkeypatch.setattr(E, "_peer", real)
    rows = E.run_experiment(cfg, out=tmp_path / "out", workers=0, resume=True)
    assert E.strip_volatile(rows) == E.strip_volatile(ref_rows)


# ----------------------------------------------------------------------------------------------- report
def _front_brute(x, y):
    """Reference: points no other point dominates (<= in both, < in one); duplicates kept once."""
    keep = []
    for i in range(len(x)):
        dom = any((x[j] <= x[i] and y[j] <= y[i] and (x[j] < x[i] or y[j] < y[i])) for j in range(len(x)))
        dup = any(x[j] == x[i] and y[j] == y[i] for j in keep)
        if not dom and not dup:
            keep.append(i)
    return sorted(keep, key=lambda i: (x[i], y[i]))


def test_pareto_front_matches_brute_force():
    rng = np.random.default_rng(3)
    for _ in range(20):
        x = rng.integers(0, 8, 30).astype(float)
        y = rng.integers(0, 8, 30).astype(float)
        assert list(E.pareto_front(x, y)) == _front_brute(x, y)


def test_pareto_plot_points_are_the_rows_values(tmp_path, reference):
    _, rows, _ = reference
    data = R.plot_time_vs_error(rows, tmp_path / "t.png")
    assert (tmp_path / "t.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert data["column"] == "distance"  # the only judge of the tiny sweep
    use = [r for r in rows if r["distance"] is not None]
    assert sum(len(v) for v in data["points"].values()) == len(use)
    for m, pts in data["points"].items():
        mine = [r for r in use if r["method"] == m]
        want = np.array([[r["time_score_s"] + r["time_cut_s"] + r["time_extract_s"] + r["time_peer_s"],
                          r["distance"]] for r in mine])
        np.testing.assert_allclose(pts, np.maximum(want, [1e-6, -np.inf]), rtol=1e-12)
    x = np.array([max(R.method_seconds(r), 1e-6) for r in use])
    y = np.array([r["distance"] for r in use])
    idx = _front_brute(x, y)
    np.testing.assert_allclose(data["front"], np.stack([x[idx], y[idx]], 1))
    assert data["front_cells"] == [use[i]["cell"] for i in idx]
    for b, cells in data["budget_fronts"].items():  # each budget's front is the brute-force front of its rows
        sel = [i for i, r in enumerate(use) if str(r["budget"]) == b]
        assert sel and cells == [use[sel[k]]["cell"] for k in _front_brute(x[sel], y[sel])]
    assert sorted(data["budget_fronts"]) == sorted({str(r["budget"]) for r in use})
    # JOD rows: the error is 10 - JOD
    jrows = [{**r, "jod": 10.0 - r["distance"] / 100.0} for r in use]
    d2 = R.plot_time_vs_error(jrows, tmp_path / "t2.png")
    assert d2["column"] == "jod"
    got = np.concatenate([d2["points"][m] for m in d2["points"]])[:, 1]
    want = np.concatenate([[10.0 - r["jod"] for r in jrows if r["method"] == m] for m in d2["points"]])
    np.testing.assert_allclose(got, want)


def test_error_plot_and_wins_are_the_rows_values(tmp_path, reference):
    _, rows, _ = reference
    data = R.plot_error_vs_triangles(rows, tmp_path / "e.png")
    assert set(data) == {"distance"}
    for m, pts in data["distance"].items():
        want = [[r["triangles"], r["distance"]] for r in rows if r["method"] == m and r["distance"] is not None]
        np.testing.assert_allclose(pts, want)
    w = R.wins(rows, "distance")
    assert set(w) == {(0.0, "0.1"), (0.0, "300"), (12.0, "0.1"), (12.0, "300")}
    for (g, b), counts in w.items():
        group = [r for r in rows if r["gaze_deg"] == g and r["budget"] == b and r["distance"] is not None]
        best = min(r["distance"] for r in group)
        assert counts == {r["method"]: int(r["distance"] == best) for r in group}
        assert counts["perceptual"] == 1  # perceptual keys minimise the perceptual distance


def test_cli_writes_the_report(tmp_path, monkeypatch, capsys):
    from experiments import cli

    monkeypatch.setattr(cli, "COMMANDS", [*cli.COMMANDS, "experiment"] if "experiment" not in cli.COMMANDS
                        else cli.COMMANDS)
    p = _cfg(tmp_path, TINY.replace('budgets = [0.1, 300]', 'budgets = [0.1]').replace(
        'gaze_offsets_deg = [0.0, 12.0]', 'gaze_offsets_deg = [0.0]'))
    out = tmp_path / "out"
    assert cli.main(["experiment", str(p), "--workers", "0", "--out", str(out)]) == 0
    assert "6 cells" in capsys.readouterr().out
    for name in ("report.md", "results.csv", "run_info.json", "error_vs_triangles.png", "time_vs_error.png",
                 "wins.png"):
        assert (out / name).stat().st_size > 0, name
    info = json.loads((out / "run_info.json").read_text())
    assert info["seed"] == 2026 and info["config"]["budgets"] == [0.1] and info["command"].startswith("plod experiment")
    assert "## Run time against error" in (out / "report.md").read_text()
    bad = _cfg(tmp_path, "views = 1\nworkerz = 3\n", "bad.toml")
    assert cli.main(["experiment", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "unknown config key 'workerz'" in err and "line 2" in err
    # an --out below a file: one line (before: NotADirectoryError's traceback)
    assert cli.main(["experiment", str(p), "--workers", "0", "--out", str(p / "sub")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Not a directory" in err
    # flags a config of another kind does not take: refused, not ignored (--resume ran everything again)
    kind = _cfg(tmp_path, 'kind = "accuracy_motion"\n', "kind.toml")
    for flag in (["--resume"], ["--workers", "3"], ["--scheduler", "tcp://127.0.0.1:1"], ["--no-examples"]):
        assert cli.main(["experiment", str(kind), *flag]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and f"{flag[0]} does not apply to a config of kind 'accuracy_motion'" in err


def test_cli_exits_1_when_a_cell_failed(tmp_path, monkeypatch, capsys):
    """A failed cell is recorded and the sweep goes on, but the command's status says so (before: exit 0,
    the reason only in the table): a garbage mesh file, one line naming the cell and the reason."""
    from experiments import cli

    monkeypatch.setattr(cli, "COMMANDS", [*cli.COMMANDS, "experiment"] if "experiment" not in cli.COMMANDS
                        else cli.COMMANDS)
    garbage = tmp_path / "garbage.ply"
    garbage.write_bytes(b"\x00\x01 not a mesh")
    p = _cfg(tmp_path, f'meshes = ["{garbage}"]\nprocedural = []\nviews = 1\ngaze_offsets_deg = [0.0]\n'
                       'budgets = [0.5]\nmethods = ["perceptual"]\njudges = ["distance"]\nexamples = 0\n')
    assert cli.main(["experiment", str(p), "--workers", "0", "--out", str(tmp_path / "out")]) == 1
    cap = capsys.readouterr()
    assert "1 failed" in cap.out
    last = cap.err.strip().splitlines()[-1]  # (the lines above: one progress line per cell, not a terminal)
    assert "1 of 1 cells failed; first: garbage/v0/g0/" in last and "garbage.ply" in last


def test_small_config_end_to_end(tmp_path):
    """configs/experiment_small.toml with its judges (FovVideoVDP, FLIP): the report, its plots and the
    example renderings (slow tier: about a minute). Skipped without the judge extra or OpenGL."""
    pytest.importorskip("torch")
    pytest.importorskip("pyfvvdp")
    cfg = E.load_experiment_config(ROOT / "configs" / "experiment_small.toml")
    rows = E.run_experiment(cfg, out=tmp_path, workers=1)
    if any("OpenGL" in (r["error"] or "") for r in rows):
        pytest.skip(next(r["error"] for r in rows if r["error"]))
    assert not any(r["error"] for r in rows) and len(rows) == len(E.cells(cfg))
    assert all(0 < r["jod"] <= 10.0 and 0 <= r["flip"] <= 1 for r in rows)
    imp = [r for r in rows if r["method"] == "imperceptible"]
    assert all(r["jod"] >= 9.8 for r in imp)  # plod's imperceptible cut is invisible to the judge
    data = R.write_report(rows, cfg, tmp_path, "test")
    assert data["time_vs_error"]["column"] == "jod"
    assert [name for _, name in data["examples"]] == ["example_best_0.png", "example_worst_0.png"]
    for name in ("report.md", "error_vs_triangles.png", "time_vs_error.png", "wins.png", "example_best_0.png",
                 "example_worst_0.png", "run_info.json"):
        assert (tmp_path / name).stat().st_size > 0, name


@pytest.mark.parametrize("kind, name, judged", [
    ("terrain", "table1.md", False), ("terrain", "run_info.json", False),
    ("terrain_motion", "motion.md", True), ("accuracy_motion", "report.md", True)])
def test_a_run_does_not_write_over_its_own_config(tmp_path, kind, name, judged):
    """A config named like one of its run's outputs, in its own output folder, was replaced by that
    output (2026-12-07); the experiments whose ``run_config`` knows its config refuse before any work."""
    import importlib

    if judged:  # these check for the judge extra first
        pytest.importorskip("pyfvvdp")
    cfg = tmp_path / name
    text = f'kind = "{kind}"\n' + ("fractal_size = 33\n" if kind == "terrain" else "")
    cfg.write_text(text)
    with pytest.raises(PlodError, match=f"would write its {name} over the config"):
        importlib.import_module(f"experiments.{kind}").run_config(cfg, out=tmp_path)
    assert cfg.read_text() == text


@pytest.mark.parametrize("kind, name", [
    ("points", "report.md"), ("points", "figs/counts.png"), ("experiment", "report.md"),
    ("experiment", "wins.png"), ("experiment", "results.jsonl"), ("accuracy", "report.md"),
    ("accuracy", "worst_perceptual_0.png"), ("compare_metrics", "results.csv"), ("lods", "report.md")])
def test_the_other_runs_do_not_write_over_their_own_config(tmp_path, kind, name):
    """The same for the runs whose outputs were checked from the config dict alone (2026-12-08): the
    points experiment, ``plod experiment`` on a sweep, ``experiments.accuracy`` and ``compare_metrics``.
    Nothing is written: the refusal comes before any work."""
    import importlib

    from experiments import experiment as E

    cfg = tmp_path / name
    cfg.parent.mkdir(exist_ok=True)
    text = {"points": 'kind = "points"\n', "accuracy": "views = 1\n", "lods": "held_out = 1\n"}.get(kind, "seed = 3\n")
    cfg.write_text(text)
    with pytest.raises(PlodError, match=r"would write its \S+ over the config"):
        if kind == "points":
            importlib.import_module("experiments.points").run_config(cfg, out=tmp_path)
        elif kind == "experiment":
            E.run_experiment(E.load_experiment_config(cfg), out=tmp_path, workers=0, config=cfg)
        else:
            importlib.import_module(f"experiments.{kind}").main(["--config", str(cfg), "--out", str(tmp_path)])
    assert cfg.read_text() == text
    assert sorted(p.name for p in tmp_path.rglob("*")) == sorted({cfg.name, *cfg.relative_to(tmp_path).parts})

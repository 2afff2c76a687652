"""Atomic outputs, config overrides and run provenance."""

from __future__ import annotations

import json
import os

import pytest

from experiments._runinfo import load_config, save_run_info
from pmetric import atomic_path, atomic_write_text


def test_atomic_write_replaces_only_on_success(tmp_path):
    p = tmp_path / "out.txt"
    atomic_write_text(p, "first")
    with pytest.raises(RuntimeError):
        with atomic_path(p) as tmp:
            tmp.write_text("partial")
            raise RuntimeError("crash mid-write")
    assert p.read_text() == "first"
    assert sorted(os.listdir(tmp_path)) == ["out.txt"]  # no temporary left behind


def test_atomic_refuses_to_overwrite_input(tmp_path):
    src = tmp_path / "mesh.ply"
    src.write_text("precious")
    with pytest.raises(ValueError, match="refusing to overwrite the input"):
        atomic_write_text(src, "oops", protect=(src,))
    assert src.read_text() == "precious"


DEFAULTS = {"seed": 0, "scale": 1.0, "models": ["a"], "solver": {"name": "lm", "tol": 1e-8}}


def test_config_overrides_and_rejects_unknown(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text('scale = 2\n[solver]\nname = "bfgs"\n')
    out = load_config(cfg, DEFAULTS)
    assert out["scale"] == 2.0 and isinstance(out["scale"], float)
    assert out["solver"] == {"name": "bfgs", "tol": 1e-8} and out["seed"] == 0
    cfg.write_text("[solver]\ntoll = 1e-3\n")
    with pytest.raises(ValueError, match=r"unknown config key 'solver\.toll'"):
        load_config(cfg, DEFAULTS)
    cfg.write_text('seed = "zero"\n')
    with pytest.raises(ValueError, match="'seed' must be int"):
        load_config(cfg, DEFAULTS)
    cfg.write_text("seed = -1\n")  # numpy's "expected non-negative integer" reached the user before
    with pytest.raises(ValueError, match="'seed' must be an integer >= 0, got -1"):
        load_config(cfg, DEFAULTS)
    cfg.write_text("seed = = 3\n")
    with pytest.raises(ValueError, match="malformed TOML"):
        load_config(cfg, DEFAULTS)
    with pytest.raises(FileNotFoundError):
        load_config(tmp_path / "missing.toml", DEFAULTS)


def test_run_info_records_provenance(tmp_path):
    path = save_run_info(tmp_path, {"a": 1}, 7, "plod fit x.csv")
    info = json.loads(path.read_text())
    assert info["seed"] == 7 and info["config"] == {"a": 1} and info["command"] == "plod fit x.csv"
    assert "jax" in info["versions"] and info["git_sha"]


def test_run_main_turns_user_errors_into_one_line(capsys):
    from experiments._runinfo import run_main

    def bad():
        raise ValueError("unknown config key 'zz'")

    assert run_main(bad) == 2
    err = capsys.readouterr().err
    assert err.strip().endswith("error: unknown config key 'zz'") and "Traceback" not in err
    assert run_main(lambda: 0) == 0


def test_experiment_scripts_reject_unknown_config_keys(tmp_path):
    import subprocess
    import sys

    cfg = tmp_path / "bad.toml"
    cfg.write_text("not_a_key = 1\n")
    for module in ("experiments.compare_metrics", "experiments.fit_real"):
        proc = subprocess.run([sys.executable, "-m", module, "--config", str(cfg)], capture_output=True,
                              text=True, timeout=300)
        assert proc.returncode == 2, (module, proc.stderr)
        assert "unknown config key 'not_a_key'" in proc.stderr and "Traceback" not in proc.stderr


@pytest.mark.parametrize("text, key", [
    ("models = []", "models"),  # before: every fit and the MCMC ran, then StopIteration writing the report
    ('[mcmc]\ndata = "bogus"', "mcmc.data"),
    ("[mcmc]\nq = 2.0", "mcmc.q"),
    ("[mcmc]\nnwalkers = 0", "mcmc.nwalkers"),
    ("[mcmc]\nnsteps = 0", "mcmc.nsteps"),
    ("[cv]\nprior_grid = [-1.0]", "cv.prior_grid"),
])
def test_fit_real_checks_its_values_before_any_fit(text, key, tmp_path):
    from experiments._runinfo import load_config
    from experiments.fit_real import DEFAULTS, check_config

    p = tmp_path / "c.toml"
    p.write_text(text + "\n")
    with pytest.raises(ValueError, match=f"config key '{key}' must be"):
        check_config(load_config(p, DEFAULTS))
    check_config(load_config(None, DEFAULTS))  # the defaults pass


@pytest.mark.parametrize("override, msg", [
    ({"names": ["s (a)", "s (b)"]}, "'names' must differ"),  # both figures were s_10deg.png
    ({"gaze_deg": 1000.0}, "'gaze_deg' must be angles in"),
    ({"curve_gaze_deg": [0.0, -5.0]}, "'curve_gaze_deg' must be angles in"),
])
def test_points_config_values(override, msg):
    from experiments import points as P

    cfg = {**P.DEFAULTS, **P.QUICK, **override}
    if "names" in override:
        for k in ("paths", "point_cloud", "directions", "ups"):
            cfg[k] = cfg[k] * 2
    with pytest.raises(ValueError, match=msg):
        P._check_sets(cfg)

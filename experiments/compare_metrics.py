"""Compare perceptual, size and geometric keys with meshoptimizer and fast-simplification: now a config
of the experiment runner (``configs/compare_metrics.toml``, ``experiments/experiment.py``).

    .venv/bin/python -m experiments.compare_metrics [--config FILE] [--quick] [--out DIR] [--workers N] [--resume]

is ``plod experiment configs/compare_metrics.toml`` (``--config``: another runner config instead;
``--quick``: one small procedural mesh, two budgets, the centre gaze, into ``reports/compare_metrics/quick``).
Every cell is judged by plod's imperceptible distance and mean FLIP [And20]; the report plots both
against the triangles kept, and run time against error with its Pareto front.
"""

from __future__ import annotations

import argparse
import sys

CONFIG = "configs/compare_metrics.toml"
QUICK = {"meshes": [], "procedural": ["sphere:4:0"], "budgets": [0.05, 0.10], "gaze_offsets_deg": [0.0],
         "judge_size": [320, 180], "out": "reports/compare_metrics/quick"}


def main(argv=None) -> int:
    from experiments import experiment as E
    from experiments._cmd_experiment import _default_workers
    from experiments._experiment_report import write_report
    from experiments._runinfo import check_out_dir, repo_path

    ap = argparse.ArgumentParser(prog="python -m experiments.compare_metrics", description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default=None, help=f"runner config (default {CONFIG}; unknown keys are refused)")
    ap.add_argument("--quick", action="store_true", help="one small procedural mesh, two budgets, one gaze")
    ap.add_argument("--out", default=None, help="output folder (overrides the config's 'out')")
    ap.add_argument("--workers", type=int, default=None, help="local worker processes (0: this process)")
    ap.add_argument("--resume", action="store_true", help="finish an interrupted run in the same folder")
    args = ap.parse_args(argv)
    config = repo_path(args.config or CONFIG)
    cfg = E.load_experiment_config(config)
    if args.quick:
        cfg.update(QUICK)
    if args.out:
        cfg["out"] = args.out
    cfg = E.check_config(cfg)
    out = check_out_dir(repo_path(cfg["out"]), config=config, writes=E.WRITES)
    command = "python -m experiments.compare_metrics " + " ".join(sys.argv[1:] if argv is None else argv)
    rows = E.run_experiment(cfg, out=out, workers=_default_workers() if args.workers is None else args.workers,
                            resume=args.resume, config=config)
    write_report(rows, cfg, out, command)
    print(f"wrote {out / 'report.md'}", file=sys.stderr)
    return 0


if __name__ == "__main__":  # pragma: no cover
    from experiments._runinfo import run_script

    run_script(main)

"""``plod experiment CONFIG.toml``: run a judged sweep of meshes x views x gaze offsets x lightings x
budgets x methods from a short TOML config and write ``results.parquet`` (or ``results.csv``),
``report.md`` with PNG plots and ``run_info.json`` (see ``experiments/experiment.py``).

Cells run on ``--workers`` local processes (default: the CPUs, at most 4) or on a Dask cluster given
``--scheduler tcp://HOST:PORT``; ``--resume`` finishes an interrupted run in the same ``--out`` folder
without repeating its finished cells. A rich progress bar with an ETA is drawn on a terminal. A cell that
fails is recorded in the report and the sweep goes on; the command then exits 1, naming the first failure.
"""

from __future__ import annotations

import os
import sys


def _default_workers() -> int:
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(4, cpus))


def register(sub) -> None:
    p = sub.add_parser("experiment", help="run a judged sweep from a TOML config (resumable, local or Dask)",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("config", help="TOML config (overrides of experiments.experiment.DEFAULTS), "
                                  "e.g. configs/experiment_small.toml")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help=f"local worker processes (default {_default_workers()}; 0: run in this process)")
    p.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                   help="run the cells on this Dask scheduler instead (needs dask.distributed)")
    p.add_argument("--resume", action="store_true",
                   help="keep the finished cells of an interrupted run in --out and run only the rest")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="output folder (default: the config's 'out', relative to the repository root)")
    p.add_argument("--no-examples", action="store_true", help="skip the example renderings of the best and worst cells")
    p.set_defaults(func=run)


# config ``kind`` -> the module under experiments/ whose ``run_config(path, out, progress)`` runs it
KINDS = ("terrain", "terrain_motion", "accuracy_motion", "points")


def _config_kind(path) -> str | None:
    """The config's top-level ``kind`` (one of :data:`KINDS` runs ``experiments.<kind>.run_config``), or
    None; a file that does not parse is left to the loader, which names the problem."""
    import tomllib

    try:
        with open(path, "rb") as fh:
            kind = tomllib.load(fh).get("kind")
    except (OSError, tomllib.TOMLDecodeError):
        return None
    return kind if isinstance(kind, str) else None


def run(args) -> int:
    from experiments import experiment as E
    from experiments._experiment_report import write_report
    from experiments._progress import rich_progress
    from experiments._runinfo import repo_path

    from pathlib import Path

    kind = _config_kind(args.config)
    if kind in KINDS:  # an experiment of its own module (its run_config), not a sweep of the runner
        import importlib

        from pmetric import PlodError

        given = [f for f, on in (("--workers", args.workers is not None), ("--scheduler", bool(args.scheduler)),
                                 ("--resume", args.resume), ("--no-examples", args.no_examples)) if on]
        if given:  # before, ignored silently (a --resume ran everything again and emptied the journal)
            raise PlodError(f"{given[0]} does not apply to a config of kind {kind!r} (it runs in this process, "
                            "from the start); only --out does")

        run_config = importlib.import_module(f"experiments.{kind}").run_config
        with rich_progress(kind.replace("_", " ")) as cb:
            out = run_config(args.config, out=None if args.out is None else Path(args.out).resolve(), progress=cb)
        print(f"wrote {out}")
        return 0
    # --out is relative to the working directory; the config's own paths to the repository root
    cfg = E.load_experiment_config(args.config, out=None if args.out is None else str(Path(args.out).resolve()))
    out = repo_path(cfg["out"])
    workers = _default_workers() if args.workers is None else args.workers
    command = " ".join(["plod experiment", args.config, *([f"--workers {args.workers}"] if args.workers is not None else []),
                        *([f"--scheduler {args.scheduler}"] if args.scheduler else []),
                        *(["--resume"] if args.resume else []), *([f"--out {args.out}"] if args.out else []),
                        *(["--no-examples"] if args.no_examples else [])])
    with rich_progress("experiment") as cb:
        def progress(stage, done, total):
            if cb is not None:
                cb(stage, done, total)
            elif stage not in ("start", "resumed"):  # a log, not a terminal: one line per cell
                print(f"[{done}/{total}] {stage}", file=sys.stderr, flush=True)

        rows = E.run_experiment(cfg, out=out, workers=workers, scheduler=args.scheduler, resume=args.resume,
                                progress=progress, config=args.config)
    write_report(rows, cfg, out, command, examples=not args.no_examples)
    failed = [r for r in rows if r.get("error")]
    table = "results.parquet" if (out / "results.parquet").exists() else "results.csv"
    print(f"wrote {out / 'report.md'} and {out / table}: {len(rows)} cells"
          + (f", {len(failed)} failed (see the report; --resume runs them again)" if failed else ""))
    if failed:  # exit 1, so that a script sees it: the first failure in one line
        print(f"plod experiment: {len(failed)} of {len(rows)} cells failed; first: {failed[0]['cell']}: "
              f"{failed[0]['error']}", file=sys.stderr)
        return 1
    return 0

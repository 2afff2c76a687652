"""Configs of overrides and the provenance saved next to every report (nanoGPT style).

A config is a short TOML file of overrides on a script's defaults: unknown keys are rejected, so a
typo can never be silently ignored. Every report folder gets ``run_info.json`` with the resolved
config, the git SHA, the seed, the command line and the package versions that made it.
"""

from __future__ import annotations

import json
import math
import platform
import subprocess
import sys
import tomllib
from importlib import metadata
from pathlib import Path, PurePosixPath
from typing import Any, Mapping

from pmetric import PlodError, atomic_write_text

ROOT = Path(__file__).resolve().parent.parent  # the repository


def repo_path(p: str | Path) -> Path:
    """``p`` itself when absolute, else relative to the repository root (config paths). An empty path is a
    PlodError (it would name the repository root itself: an ``out = ""`` wrote reports there)."""
    if not str(p).strip():
        raise PlodError("a path in the config is empty; give a file or folder name")
    q = Path(p)
    return q if q.is_absolute() else ROOT / q


def check_out_dir(out: Path, config=None, writes=()) -> Path:
    """``out`` (an experiment's output folder), unless it is the repository root or a folder above it
    (PlodError: a run would scatter its tables and plots among the project's files), or the ``config`` file
    the run reads lies in ``out`` (or a folder below it) under a name the run writes: ``writes`` are glob
    patterns matched from the right against its path below ``out`` (``"report.md"``, ``"*.png"``;
    ``run_info.json`` always)."""
    r = Path(out).resolve()
    if r == ROOT.resolve() or r in ROOT.resolve().parents:
        raise PlodError(f"output folder {str(out)!r} is the repository root or above it; give a folder of its own "
                        "(e.g. reports/NAME)")
    if config is not None:
        c = Path(config).resolve()
        if c.is_relative_to(r):
            rel = PurePosixPath(c.relative_to(r).as_posix())
            for name in (*writes, "run_info.json"):
                if rel.match(name):
                    raise PlodError(f"output folder {str(out)!r}: the run would write its {name} over the config "
                                    f"{str(config)!r}; give another folder")
    return out

def config_numbers(x, n=None, lo=None, strict=False, ints=False, empty=False, below=None) -> bool:
    """``x`` is a list (of ``n`` items when given; non-empty unless ``empty``) of finite numbers (ints when
    ``ints``; never bools) at least ``lo`` (more than ``lo`` when ``strict``) and less than ``below``: the
    range checks of the experiments' config values (the loader checks only names and types)."""
    if not isinstance(x, (list, tuple)) or (n is not None and len(x) != n) or (not x and not empty):
        return False
    kinds = (int,) if ints else (int, float)
    return all(isinstance(v, kinds) and not isinstance(v, bool) and math.isfinite(v) and
               (lo is None or (v > lo if strict else v >= lo)) and (below is None or v < below) for v in x)


_PACKAGES = ("jax", "jaxlib", "equinox", "optimistix", "lineax", "jaxopt", "numpy", "scipy", "trimesh",
             "emcee", "matplotlib", "fast-simplification", "meshoptimizer", "rich")


def _merge(defaults: Mapping[str, Any], overrides: Mapping[str, Any], where: str) -> dict:
    out = dict(defaults)
    for key, value in overrides.items():
        if key not in defaults:
            known = ", ".join(sorted(defaults)) or "(none)"
            raise PlodError(f"unknown config key {where + key!r}; known keys: {known}")
        if isinstance(defaults[key], Mapping):
            if not isinstance(value, Mapping):
                raise PlodError(f"config key {where + key!r} must be a table, got {type(value).__name__}")
            out[key] = _merge(defaults[key], value, f"{where}{key}.")
        else:
            d = defaults[key]
            ok = (
                d is None
                or isinstance(value, type(d))
                or (isinstance(d, float) and isinstance(value, int) and not isinstance(value, bool))
                or (isinstance(d, (list, tuple)) and isinstance(value, (list, tuple)))
            )
            if not ok:
                raise PlodError(
                    f"config key {where + key!r} must be {type(d).__name__}, got {type(value).__name__} ({value!r})"
                )
            if key == "seed" and (isinstance(value, bool) or not isinstance(value, int) or value < 0):
                # numpy's generators take 0 .. 2^128 - 1; every experiment's "seed" seeds one of them
                raise PlodError(f"config key {where + key!r} must be an integer >= 0, got {value!r}")
            out[key] = float(value) if isinstance(d, float) else value
    return out


def load_config(path: str | Path | None, defaults: Mapping[str, Any]) -> dict:
    """Return ``defaults`` overridden by the TOML file at ``path`` (None: defaults unchanged).

    Raises ``PlodError`` naming the key for unknown keys or wrongly typed values, and for malformed
    TOML; ``FileNotFoundError`` when the file does not exist.
    """
    if path is None:
        return _merge(defaults, {}, "")
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"config file not found: {p}")
    try:
        overrides = tomllib.loads(p.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise PlodError(f"malformed TOML in {p}: {exc}") from None
    return _merge(defaults, overrides, "")


def git_sha(cwd: str | Path | None = None) -> str:
    """The current commit (with ``-dirty`` when the tree has changes), or ``"unknown"``."""
    cwd = cwd or ROOT
    try:
        sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=cwd, capture_output=True, text=True,
                             timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=cwd,
                               capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return (sha + ("-dirty" if dirty else "")) if sha else "unknown"


def versions() -> dict[str, str]:
    """Versions of Python, the platform and the packages behind a result."""
    out = {"python": sys.version.split()[0], "platform": platform.platform()}
    for name in _PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            pass
    try:
        import jax

        out["jax_backend"] = jax.default_backend()
        out["devices"] = ", ".join(str(d) for d in jax.devices())
    except Exception:  # pragma: no cover - provenance must never fail a report
        pass
    return out


def save_run_info(out_dir: str | Path, config: Mapping[str, Any], seed: int | None, command: str) -> Path:
    """Write ``run_info.json`` (resolved config, git SHA, seed, command, versions) into ``out_dir``."""
    info = {"command": command, "git_sha": git_sha(), "seed": seed, "config": dict(config),
            "versions": versions()}
    path = Path(out_dir) / "run_info.json"
    atomic_write_text(path, json.dumps(info, indent=2, default=str) + "\n")
    return path


# User errors: printed as one line, never a traceback (PlodError is a ValueError).
USER_ERRORS = (ValueError, FileNotFoundError, IsADirectoryError, NotADirectoryError, FileExistsError, PermissionError)


def report_errors(fn, prog: str) -> int:
    """``fn()``'s exit code; a user error is printed as ``PROG: error: MESSAGE`` (status 2), an
    interrupt as ``PROG: interrupted`` (status 130).

    Ctrl-C always stops the command (``experiments._interrupt``): an interrupt that was swallowed on the
    way (a gc callback, a ``__del__``) still blocks every later atomic write and ends with status 130.
    """
    from experiments import _interrupt

    with _interrupt.guard():
        try:
            _interrupt.check()  # a Ctrl-C during start-up (recorded only, see _interrupt.install)
            code = int(fn() or 0)
            _interrupt.check()
            return code
        except KeyboardInterrupt:
            return _interrupted(prog)
        except USER_ERRORS as exc:
            if _interrupt.seen():  # the error came from an interrupted step
                return _interrupted(prog)
            msg = " ".join(str(exc).split()) or type(exc).__name__  # one line, whatever the message holds
            print(f"{prog}: error: {msg}", file=sys.stderr)
            return 2
        except Exception:
            if _interrupt.seen():  # e.g. ImportError: a KeyboardInterrupt inside a C extension's import
                return _interrupted(prog)
            raise


def _interrupted(prog: str) -> int:
    from experiments import _interrupt

    _interrupt.stop_raising()
    print(f"{prog}: interrupted", file=sys.stderr)
    return 130


def run_main(main) -> int:
    """Run an experiment's ``main()`` as a script: user errors (bad config, missing file, bad value)
    are printed as one line naming the problem, with exit status 2, never as a traceback."""
    return report_errors(main, Path(sys.argv[0]).stem if sys.argv and sys.argv[0] else "experiment")


def run_script(main) -> None:  # pragma: no cover - ends the process
    """``python -m experiments.NAME``: :func:`run_main`, then end the process with its status (130 after
    a Ctrl-C, whatever the interpreter remembers: :func:`experiments._interrupt.exit_process`)."""
    from experiments._interrupt import exit_process

    exit_process(run_main(main))

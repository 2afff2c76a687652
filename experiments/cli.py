"""The ``plod`` command line.

Each subcommand lives in its own module ``experiments/_cmd_<name>.py`` that defines
``register(subparsers)``; the module adds its parser and sets ``func`` to a handler taking the parsed
namespace and returning an exit code. Errors meant for users are raised as ``pmetric.PlodError`` (a
``ValueError``; plain ``ValueError``/``FileNotFoundError`` are treated alike) and printed as one line
(``plod CMD: error: ...``, exit status 2), never a traceback. Every ``--model`` flag goes through
``pmetric.make_model``; ``plod models`` lists what it accepts.
"""

from __future__ import annotations

import re
import sys

# Nothing else is imported at module level (argparse and the rest inside the functions): the console
# script installs the Ctrl-C handler (``entry``) as early as it can, before JAX and the rest are
# imported, so an interrupt during start-up is not lost either.


def __getattr__(name):  # ``experiments.cli.PlodError``: the library's one error type, re-exported lazily
    if name == "PlodError":
        from pmetric import PlodError

        return PlodError
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

CACHE_HELP = ("environment: PLOD_CACHE=DIR keeps compiled XLA programs (DIR/xla) and plod simplify's vertex "
              "trees in DIR (default ~/.cache/plod); PLOD_CACHE set to an empty string means no cache at all; "
              "PLOD_NO_XLA_CACHE=1 turns off only the XLA cache.")

# Subcommand modules, in the order they appear in ``plod --help``.
COMMANDS = ["demo", "experiment", "fit", "calibrate", "simplify", "lods", "judge", "models"]


def build_parser() -> "argparse.ArgumentParser":  # noqa: F821
    import argparse
    import importlib

    parser = argparse.ArgumentParser(
        prog="plod",
        description="Perceptually driven level of detail: which simplifications can a viewer not see?",
        epilog=CACHE_HELP,
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"experiments._cmd_{name}").register(sub)
    return parser


def _enable_compile_cache() -> None:
    """Keep XLA's compiled programs between runs (``$PLOD_CACHE/xla``, default ``~/.cache/plod/xla``).

    A command-line run compiles the same scoring and model programs every time; the persistent cache
    reuses them from the second run on. ``PLOD_NO_XLA_CACHE=1`` or an empty ``PLOD_CACHE`` turns it off.
    """
    import os
    from pathlib import Path

    if os.environ.get("PLOD_NO_XLA_CACHE"):
        return
    import jax

    env = os.environ.get("PLOD_CACHE")
    if env is not None and env.strip() == "":
        return  # PLOD_CACHE set but empty: no cache at all (see CACHE_HELP)
    root = Path(env) if env is not None else Path.home() / ".cache" / "plod"
    try:
        (root / "xla").mkdir(parents=True, exist_ok=True)
    except OSError:
        return  # an unwritable cache never stops a command
    _repair_xla_cache(root / "xla")
    jax.config.update("jax_compilation_cache_dir", str(root / "xla"))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


XLA_RUN_MARK = ".plod-run-"
"""Name prefix of the marker a ``plod`` run keeps in the XLA cache folder while it runs."""


def _repair_xla_cache(xla: "Path") -> list:
    """Remove XLA cache entries that a killed ``plod`` run left half-written; returns them.

    JAX writes its cache entries in place (not atomically), and never replaces an existing one: an
    entry cut short by SIGKILL made every later run warn "Error reading persistent compilation cache
    entry" forever (issue 13, item 9). Each run keeps a marker ``.plod-run-HOST-PID`` in the folder
    and removes it when it ends. A marker whose process is gone (this host) or that is older than
    ``pmetric._atomic.STALE_AFTER_S`` belongs to a killed run: the entries written since it was made
    are decompressed with JAX's own reader and removed when that fails. Never raises.
    """
    import atexit
    import contextlib
    import os
    import time

    from pmetric._atomic import STALE_AFTER_S, _host_tag, _pid_alive

    removed = []
    with contextlib.suppress(OSError):
        host, now = _host_tag(), time.time()
        for mark in xla.glob(XLA_RUN_MARK + "*"):
            try:
                tag, pid = mark.name[len(XLA_RUN_MARK):].rsplit("-", 1)
                since = mark.stat().st_mtime
            except (ValueError, OSError):
                continue
            if not ((tag == host and not _pid_alive(int(pid))) or now - since > STALE_AFTER_S):
                continue  # a run still going
            try:
                from jax._src.compilation_cache import decompress_executable
            except ImportError:  # pragma: no cover - another JAX layout: only the marker goes
                decompress_executable = None
            for entry in xla.glob("*-cache"):
                with contextlib.suppress(OSError):
                    if decompress_executable is None or entry.stat().st_mtime < since - 1.0:
                        continue
                    try:
                        decompress_executable(entry.read_bytes())
                    except Exception:  # truncated or corrupt: JAX would warn on it at every run
                        entry.unlink()
                        removed.append(entry)
                        with contextlib.suppress(OSError):
                            (xla / (entry.name[:-len("-cache")] + "-atime")).unlink()
            with contextlib.suppress(OSError):
                mark.unlink()
        mine = xla / f"{XLA_RUN_MARK}{host}-{os.getpid()}"
        mine.touch()
        atexit.register(lambda: mine.unlink(missing_ok=True))
    return removed


def _join_negative_values(argv: list[str]) -> list[str]:
    """``--light -1,0,0`` as ``--light=-1,0,0``: argparse takes a value that starts with '-' for an option
    unless it is a single negative number (``--eye -2,1,1`` was "expected one argument"). No plod option
    or positional starts with '-' and a digit, so such a token after an option is that option's value."""
    out, i = [], 0
    while i < len(argv):
        tok = argv[i]
        if tok == "--":  # the rest are positionals
            return out + list(argv[i:])
        if (tok.startswith("--") and "=" not in tok and i + 1 < len(argv)
                and re.match(r"-(\d|\.\d)", argv[i + 1])):
            out.append(f"{tok}={argv[i + 1]}")
            i += 2
            continue
        out.append(tok)
        i += 1
    return out


def main(argv: list[str] | None = None) -> int:
    import warnings

    warnings.filterwarnings("ignore", message=".*JAXopt is no longer maintained.*", category=DeprecationWarning)
    parser = build_parser()
    args = parser.parse_args(_join_negative_values(sys.argv[1:] if argv is None else list(argv)))
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    from experiments._runinfo import report_errors

    return report_errors(lambda: args.func(args), f"plod {args.command}")  # PlodError: one line, status 2


def entry() -> None:  # pragma: no cover - the console script (tests run it as a subprocess)
    """The ``plod`` console script: ``main`` plus the persistent XLA cache (a process-wide setting,
    so it is switched on here and not in ``main``, which tests and other programs call) and the Ctrl-C
    handler, installed before anything heavy is imported (``experiments._interrupt``): Ctrl-C at any
    moment exits with status 130 and commits no output."""
    from experiments import _interrupt

    _interrupt.install(early=True)
    try:
        _interrupt.check()
        _enable_compile_cache()
        code = main()
        if code == 0:
            _interrupt.check()  # an interrupt after the command's own guard ended
    except (KeyboardInterrupt, Exception) as exc:
        if not isinstance(exc, KeyboardInterrupt) and not _interrupt.seen():
            raise  # a real error (an error after a Ctrl-C is its doing, e.g. a C extension's import)
        _interrupt.stop_raising()
        print("plod: interrupted", file=sys.stderr)
        code = 130
    _interrupt.stop_raising()  # shutting down: a late Ctrl-C can no longer change anything
    _interrupt.exit_process(code)


if __name__ == "__main__":  # pragma: no cover
    from experiments.cli import entry as _entry  # the installed module's entry, as the console script

    _entry()

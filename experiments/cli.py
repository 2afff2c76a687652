"""The ``plod`` command line.

Each subcommand lives in its own module ``experiments/_cmd_<name>.py`` that defines
``register(subparsers)``; the module adds its parser and sets ``func`` to a handler taking the parsed
namespace and returning an exit code. Errors meant for users are raised as ``pmetric.PlodError`` (a
``ValueError``; plain ``ValueError``/``FileNotFoundError`` are treated alike) and printed as one line
(``plod CMD: error: ...``, exit status 2), never a traceback. Every ``--model`` flag goes through
``pmetric.make_model``; ``plod models`` lists what it accepts.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings

from pmetric import PlodError  # noqa: F401  (the library's one error type, re-exported)

CACHE_HELP = ("environment: PLOD_CACHE=DIR keeps compiled XLA programs (DIR/xla) and plod simplify's vertex "
              "trees in DIR (default ~/.cache/plod); PLOD_CACHE set to an empty string means no cache at all; "
              "PLOD_NO_XLA_CACHE=1 turns off only the XLA cache.")

# Subcommand modules, in the order they appear in ``plod --help``.
COMMANDS = ["demo", "fit", "calibrate", "simplify", "judge", "models"]


def build_parser() -> argparse.ArgumentParser:
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
    jax.config.update("jax_compilation_cache_dir", str(root / "xla"))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


def main(argv: list[str] | None = None) -> int:
    warnings.filterwarnings("ignore", message=".*JAXopt is no longer maintained.*", category=DeprecationWarning)
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    from experiments._runinfo import report_errors

    return report_errors(lambda: args.func(args), f"plod {args.command}")  # PlodError: one line, status 2


def entry() -> None:  # pragma: no cover - the console script
    """The ``plod`` console script: ``main`` plus the persistent XLA cache (a process-wide setting,
    so it is switched on here and not in ``main``, which tests and other programs call)."""
    _enable_compile_cache()
    sys.exit(main())


if __name__ == "__main__":  # pragma: no cover
    from experiments.cli import entry as _entry  # the installed module's entry, as the console script

    _entry()

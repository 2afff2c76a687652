"""The ``plod`` command line.

Each subcommand lives in its own module ``experiments/_cmd_<name>.py`` that defines
``register(subparsers)``; the module adds its parser and sets ``func`` to a handler taking the parsed
namespace and returning an exit code. Errors meant for users are raised as ``PlodError`` (or
``ValueError``/``FileNotFoundError``) and printed as one line, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings

# Subcommand modules, in the order they appear in ``plod --help``.
COMMANDS = ["demo", "fit", "calibrate", "simplify"]


class PlodError(Exception):
    """An error caused by the user's input; printed without a traceback."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="plod",
        description="Perceptually driven level of detail: which simplifications can a viewer not see?",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"experiments._cmd_{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    warnings.filterwarnings("ignore", message=".*JAXopt is no longer maintained.*", category=DeprecationWarning)
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except (PlodError, ValueError, FileNotFoundError, IsADirectoryError, PermissionError) as exc:
        print(f"plod {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("plod: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

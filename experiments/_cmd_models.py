"""``plod models``: the models every ``--model`` flag and config accepts (``pmetric.make_model``).

Lists each registered class with its aliases (names are case-insensitive and ignore ``-``/``_``), the
inputs it depends on (``f`` cycles/deg, ``e`` deg, ``v`` deg/s, ``luminance`` cd/m2, ``area`` deg2) and
its constants with their default values. ``--json`` prints the same as a list of objects.
"""

from __future__ import annotations

import json


def register(sub) -> None:
    p = sub.add_parser("models", help="list the model names, aliases, inputs and default constants",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("--json", action="store_true", help="print the list as JSON")
    p.set_defaults(func=run)


def listing() -> list[dict]:
    """One dictionary per registered class: name, aliases, kind, default, inputs, constants, spec."""
    import pmetric

    default = type(pmetric.default_model()).__name__
    rows = []
    for entry in pmetric.model_entries().values():
        rows.append({
            "name": entry.name,
            "aliases": list(entry.aliases),
            "kind": "csf" if entry.is_csf else "component",
            "default": entry.name == default,
            "spec": f"{entry.name.lower()}(CSF)" if entry.wraps else entry.name.lower(),
            "wraps": entry.wraps,
            "inputs": None if entry.inputs() is None else list(entry.inputs()),
            "constants": entry.constants(),
        })
    return rows


def _short(value) -> str:
    if isinstance(value, list):
        return "[" + ", ".join(_short(v) for v in value) + "]"
    return f"{value:.6g}"


def run(args) -> int:
    rows = listing()
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title="pmetric models (plod ... --model NAME | eccentric(NAME) | FILE.json)")
    table.add_column("name", no_wrap=True)
    for col in ("aliases", "inputs", "constants (defaults)"):
        table.add_column(col, overflow="fold")
    for r in rows:
        name = r["spec"] + (" (default)" if r["default"] else "") + ("" if r["kind"] == "csf" else " (component)")
        consts = ("needs arguments: load a fitted .json" if r["constants"] is None else
                  ", ".join(f"{k}={_short(v)}" for k, v in r["constants"].items()))
        table.add_row(name, ", ".join(r["aliases"]), ", ".join(r["inputs"] or ()), consts)
    Console().print(table)
    return 0

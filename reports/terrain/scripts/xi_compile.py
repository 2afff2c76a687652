"""First calls of the terrain's H'(v, e) for four display caps (xi 3.2, 1.6, 0.8, 0.4 cycles/deg), each side
in a fresh process: a git revision (default 405e6b1, before one jitted function served every cap) against this
tree, printed with their ratio (the cost of a new display cap: a compilation per cap before, none after the
first):

    .venv/bin/python reports/terrain/scripts/xi_compile.py [REV]
"""
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]


def first_calls(rev):
    """Seconds of the four caps' first calls, in this process (``rev``: that revision's _terrain.py)."""
    sys.path.insert(0, str(ROOT))
    if rev:
        T = types.ModuleType("old_terrain")
        T.__package__ = "optim"  # its relative imports resolve in this tree
        sys.modules["old_terrain"] = T
        exec(subprocess.check_output(["git", "-C", str(ROOT), "show", f"{rev}:optim/_terrain.py"]).decode(),
             T.__dict__)
    else:
        import optim._terrain as T
    e, v = np.linspace(0, 60, 1000), np.linspace(0, 100, 1000)
    t = time.perf_counter()
    for xi in (3.2, 1.6, 0.8, 0.4):
        T._acuity(xi, e, v)
    return time.perf_counter() - t


if len(sys.argv) > 1 and sys.argv[1] == "--one":  # a child: one side, its seconds on stdout
    print(first_calls(sys.argv[2] if len(sys.argv) > 2 else ""))
else:
    rev = sys.argv[1] if len(sys.argv) > 1 else "405e6b1"
    side = lambda *a: float(subprocess.check_output([sys.executable, __file__, "--one", *a]).split()[-1])  # noqa: E731
    old, new = side(rev), side()
    print(f"four display caps' first calls: {rev} {old:.2f} s, this tree {new:.2f} s, ratio {old / new:.2f}x")

"""First calls of the terrain's H'(v, e) for four display caps (xi 3.2, 1.6, 0.8, 0.4 cycles/deg) in a fresh
process, at a git revision or in this tree: the cost of a new display cap (a compilation per cap before
02fc5fb, none after the first):

    .venv/bin/python reports/terrain/scripts/xi_compile.py [REV]
"""
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
if len(sys.argv) > 1:
    T = types.ModuleType("old_terrain")
    T.__package__ = "optim"  # its relative imports resolve in this tree
    sys.modules["old_terrain"] = T
    exec(subprocess.check_output(["git", "-C", str(ROOT), "show", f"{sys.argv[1]}:optim/_terrain.py"]).decode(),
         T.__dict__)
else:
    import optim._terrain as T
e, v = np.linspace(0, 60, 1000), np.linspace(0, 100, 1000)
t = time.perf_counter()
for xi in (3.2, 1.6, 0.8, 0.4):
    T._acuity(xi, e, v)
print(f"{sys.argv[1] if len(sys.argv) > 1 else 'this tree'}: four display caps' first calls {time.perf_counter() - t:.2f} s")

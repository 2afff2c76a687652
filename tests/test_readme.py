"""The README's Python example runs as written and gives what it says."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_readme_python_example(capsys):
    src = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", src, re.S)
    assert blocks, "README has no Python example"
    ns: dict = {}
    exec(compile(blocks[0], "README.md", "exec"), ns)
    cut, v, f = ns["cut"], ns["v"], ns["f"]
    assert cut.stop_reason == "budget" and cut.triangles <= 10_000 and len(f) == cut.triangles
    assert cut.distance > 1.0  # a 12% budget of this mesh is visible from the current distance
    assert f.max() < len(v)
    # The threshold at 8 c/deg is Manos-Sakrison's peak threshold: 1/250 with the default peak sensitivity.
    assert abs(float(ns["csf"].threshold_contrast(7.89)) - 1 / 250) < 1e-5

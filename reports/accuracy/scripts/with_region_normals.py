"""Run one of the held-out key experiments of this folder with plod's cuts carrying their region normals
(``experiments.accuracy``'s config key ``normals = "region"``, read by ``plod_mesh``): every plod cut of
that script (today's perceptual, size, geometric keys and its variants) is then judged with the normals
it carries; the peers keep their own faces' normals.

    OMP_NUM_THREADS=1 PYOPENGL_PLATFORM=egl .venv/bin/python reports/accuracy/scripts/with_region_normals.py SCRIPT.py ARGS...
"""
import runpy
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import experiments.accuracy as A  # noqa: E402

A.DEFAULTS["normals"] = "region"  # the scripts copy DEFAULTS when they run
script = Path(__file__).resolve().parent / sys.argv[1]
sys.argv = [str(script), *sys.argv[2:]]
runpy.run_path(str(script), run_name="__main__")

"""Issue 10 experiment: region normals except across creases. A node whose normal cone is wider than
``deg`` (its region straddles a crease) gives its vertex the faces' normal instead of the region's mean;
leaves always keep their input normal. Relit, no face culling, held-out cells (see carried_normals.py).

    OMP_NUM_THREADS=1 PYOPENGL_PLATFORM=egl .venv/bin/python reports/accuracy/scripts/crease_normals.py OUT.jsonl [meshes] [degs]
"""
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402

import optim  # noqa: E402
from optim._cut import _extract_parts  # noqa: E402
from optim._normals import cut_normals  # noqa: E402
from pooled_priority import HELD_OUT, SIZE, emit, held_out_cells  # noqa: E402
from experiments.accuracy import DEFAULTS  # noqa: E402


def crease_mesh(tree, cut, deg):
    v, f, c, _, nodes, _ = _extract_parts(tree, cut.unfolded)
    reg = cut_normals(tree, v, f, nodes, "region")
    fac = cut_normals(tree, v, f, nodes, "faces")
    _, half = optim.normal_cones(tree)
    wide = (np.asarray(tree.child_count)[nodes] > 0) & (half[nodes] > np.radians(deg))
    return v, f, c, np.where(wide[:, None], fac, reg)


def main():
    out = open(sys.argv[1], "a")
    names = sys.argv[2].split(",") if len(sys.argv) > 2 and sys.argv[2] else HELD_OUT
    degs = [float(x) for x in sys.argv[3].split(",")] if len(sys.argv) > 3 else [30.0, 60.0, 90.0]
    cfg = dict(DEFAULTS, size=list(SIZE))
    for name, mesh, view, g, J in held_out_cells(names, cfg):
        tree = mesh.tree["relit"]
        keys = optim.score(tree, view)
        for b in (0.03, 0.08, 0.2):
            t0 = time.perf_counter()
            cut = optim.budget_cut(tree, keys, max(int(b * tree.n_triangles), 1), monotone="trust")
            row = dict(mesh=name, gaze=g, budget=b, tris=cut.triangles,
                       faces=J(optim.extract(tree, cut)), region=J(optim.extract(tree, cut, "region")))
            for d in degs:
                row[f"crease{d:g}"] = J(crease_mesh(tree, cut, d))
            row["s"] = round(time.perf_counter() - t0, 1)
            emit(out, row)


if __name__ == "__main__":
    main()

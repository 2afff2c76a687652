"""Issue 10 item 4, second try (face culling on, the default stelaCSF): relit fold contrast bounded by a
tilt from the node's RMS surface deviation (``deviation_contrast.py``'s ``dev`` columns) instead of the
whole normal cone. Relit cells on meshes the tests and the sweep do not use; the imperceptible cut too
(it must stay >= 9.8 JOD).

    .venv/bin/python reports/accuracy/scripts/relit_deviation.py OUT.jsonl [meshes] [variants, default 0.5,1,2]

Variants: a number s (the ``dev{s}`` tilt), ``ring`` (``ring_cone.py``: the cone widened to the 2-ring) or
``cone_only`` (``neighbour_normals.py``: the relit columns before the neighbours' vertex normals were scored).
"""
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import optim  # noqa: E402
from deviation_contrast import dev_columns  # noqa: E402
from neighbour_normals import cone_only_columns  # noqa: E402
from ring_cone import ring_columns  # noqa: E402
from pooled_priority import HELD_OUT, SIZE, budget_rows, emit, held_out_cells  # noqa: E402
from optim._relight import light_key  # noqa: E402
from experiments.accuracy import DEFAULTS, plod_mesh  # noqa: E402

SCALES = (0.5, 1.0, 2.0)


def main():
    out = open(sys.argv[1], "a")
    names = sys.argv[2].split(",") if len(sys.argv) > 2 and sys.argv[2] else HELD_OUT
    scales = tuple(sys.argv[3].split(",")) if len(sys.argv) > 3 else SCALES
    cfg = dict(DEFAULTS, face_cull=True, size=list(SIZE))
    light = optim.Lighting()
    trees = {}
    for name, mesh, view, g, J in held_out_cells(names, cfg):
        if name not in trees:
            trees = {name: {"perceptual": mesh.tree["relit"]}}
            for s in scales:
                t = optim.build_tree(mesh.v, mesh.f, mesh.c)
                if s in ("ring", "cone_only"):
                    t._derived[f"relight.columns.{light_key(light)}"] = (ring_columns if s == "ring" else cone_only_columns)(t, light)
                    trees[name][s] = t
                else:
                    t._derived[f"relight.columns.{light_key(light)}"] = dev_columns(t, light, float(s))
                    trees[name][f"dev{float(s):g}"] = t
        row = dict(mesh=name, gaze=g, budget=None)
        for kn, tr in trees[name].items():
            k = optim.score(tr, view)
            m, _ = plod_mesh(tr, k, view, cfg, cut=optim.threshold_cut(tr, k, 1.0, monotone="trust"))
            row[kn] = J(m)
            row[kn + "_tris"] = len(m[1])
        emit(out, row)
        budget_rows(out, mesh.tree["relit"], view, cfg, J,
                    {kn: (lambda n, tr=tr: plod_mesh(tr, optim.score(tr, view), view, cfg, n)[0])
                     for kn, tr in trees[name].items() if kn != "perceptual"}, mesh=name, gaze=g)

if __name__ == "__main__":
    main()

"""Issue 10 item 4, second try (face culling on, the default stelaCSF): relit fold contrast bounded by a
tilt from the node's RMS surface deviation (``deviation_contrast.py``'s ``dev`` columns) instead of the
whole normal cone. Relit cells on meshes the tests and the sweep do not use; the imperceptible cut too
(it must stay >= 9.8 JOD).

    .venv/bin/python reports/accuracy/scripts/relit_deviation.py OUT.jsonl [meshes]
"""
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import optim  # noqa: E402
from deviation_contrast import dev_columns  # noqa: E402
from pooled_priority import HELD_OUT, SIZE, budget_row, emit, held_out_mesh, judge_fn  # noqa: E402
from optim._relight import light_key  # noqa: E402
from experiments.accuracy import DEFAULTS, _view, plod_mesh  # noqa: E402
from experiments.experiment import view_directions  # noqa: E402

SCALES = (0.5, 1.0, 2.0)


def main():
    out = open(sys.argv[1], "a")
    names = sys.argv[2].split(",") if len(sys.argv) > 2 else HELD_OUT
    cfg = dict(DEFAULTS, face_cull=True, size=list(SIZE))
    light = optim.Lighting()
    for name in names:
        mesh = held_out_mesh(name)
        trees = {"perceptual": mesh.tree["relit"]}
        for s in SCALES:
            t = optim.build_tree(mesh.v, mesh.f, mesh.c)
            t._derived[f"relight.columns.{light_key(light)}"] = dev_columns(t, light, s)
            trees[f"dev{s:g}"] = t
        for d in view_directions(1, 77, name):
            for g in (0.0, 8.0):
                view = _view(mesh, d, g, "relit", cfg, True)
                J = judge_fn(mesh, view, "relit")
                row = dict(mesh=name, gaze=g, budget=None)
                for kn, tr in trees.items():
                    k = optim.score(tr, view)
                    m, _ = plod_mesh(tr, k, view, cfg, cut=optim.threshold_cut(tr, k, 1.0, monotone="trust"))
                    row[kn] = J(m)
                    row[kn + "_tris"] = len(m[1])
                emit(out, row)
                tree = trees["perceptual"]
                for b in (0.03, 0.08, 0.2):
                    t0 = time.perf_counter()
                    row, target = budget_row(tree, view, cfg, b, J, mesh=name, gaze=g)
                    for kn, tr in trees.items():
                        if kn != "perceptual":
                            row[kn] = J(plod_mesh(tr, optim.score(tr, view), view, cfg, target)[0])
                    row["s"] = round(time.perf_counter() - t0, 1)
                    emit(out, row)


if __name__ == "__main__":
    main()

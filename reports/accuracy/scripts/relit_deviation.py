"""Issue 10 item 4, second try (face culling on, the default stelaCSF): relit fold contrast bounded by a
tilt from the node's RMS surface deviation (``deviation_contrast.py``'s ``dev`` columns) instead of the
whole normal cone. Relit cells on meshes the tests and the sweep do not use; the imperceptible cut too
(it must stay >= 9.8 JOD).

    .venv/bin/python reports/accuracy/scripts/relit_deviation.py OUT.jsonl [meshes]
"""
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import optim  # noqa: E402
from deviation_contrast import dev_columns  # noqa: E402
from optim._relight import light_key  # noqa: E402
from experiments.accuracy import DEFAULTS, _Mesh, _view, plod_mesh  # noqa: E402
from experiments.experiment import procedural_mesh, view_directions  # noqa: E402
from experiments.judge import judge  # noqa: E402

SCALES = (0.5, 1.0, 2.0)


def main():
    out = open(sys.argv[1], "a")
    names = sys.argv[2].split(",") if len(sys.argv) > 2 else ["cow.obj", "stanford-bunny.obj", "turbineblade.ply",
                                                               "sphere:5:7"]
    cfg = dict(DEFAULTS, face_cull=True, size=[960, 540])
    light = optim.Lighting()
    for name in names:
        v, f, c = procedural_mesh(name) if ":" in name else optim.load_mesh(ROOT.parent / "shared/data/meshes" / name)
        mesh = _Mesh(name, v, f, c)
        trees = {"perceptual": mesh.tree["relit"]}
        for s in SCALES:
            t = optim.build_tree(v, f, c)
            t._derived[f"relight.columns.{light_key(light)}"] = dev_columns(t, light, s)
            trees[f"dev{s:g}"] = t
        for d in view_directions(1, 77, name):
            for g in (0.0, 8.0):
                view = _view(mesh, d, g, "relit", cfg, True)
                ref = mesh.original("relit")

                def J(res):
                    return round(judge(ref, res, view, mode="relit", lighting=light, size=(960, 540),
                                       heatmap=False).jod, 4)

                row = dict(mesh=name, gaze=g, budget=None)
                for kn, tr in trees.items():
                    k = optim.score(tr, view)
                    m, whole = plod_mesh(tr, k, view, cfg, cut=optim.threshold_cut(tr, k, 1.0, monotone="trust"))
                    row[kn] = J(m)
                    row[kn + "_tris"] = len(m[1])
                print(json.dumps(row), flush=True)
                out.write(json.dumps(row) + "\n")
                tree = trees["perceptual"]
                T = tree.n_triangles
                for b in (0.03, 0.08, 0.2):
                    t0 = time.perf_counter()
                    pres, _ = plod_mesh(tree, optim.score(tree, view), view, cfg, max(int(b * T), 1))
                    target = len(pres[1])
                    row = dict(mesh=name, gaze=g, budget=b, tris=target, perceptual=J(pres))
                    for metric in ("size", "geometric"):
                        row[metric] = J(plod_mesh(tree, optim.score(tree, view, None, metric), view, cfg, target)[0])
                    for kn, tr in trees.items():
                        if kn != "perceptual":
                            row[kn] = J(plod_mesh(tr, optim.score(tr, view), view, cfg, target)[0])
                    row["s"] = round(time.perf_counter() - t0, 1)
                    print(json.dumps(row), flush=True)
                    out.write(json.dumps(row) + "\n")
                    out.flush()


if __name__ == "__main__":
    main()

"""Issue 10 experiment: the normal-detail and surface-deviation tilts of ``detail_contrast.py`` and
``relit_deviation.py`` (2026-12-04/05, on the qem tree without region normals), rerun on today's relit
default of ``plod simplify`` (the hybrid tree, region normals, face culling), for budget keys only.

With region normals a coarse cut's vertex normals are its regions' mean normals, so what a renderer
cannot show after a fold is the residual of the original normals about a smooth (affine) normal field
over the region: the ``detail`` tilt. Held-out cells (meshes neither the tests nor the sweep use), each
variant cut at today's perceptual cut's drawn count.

    OMP_NUM_THREADS=1 PYOPENGL_PLATFORM=egl .venv/bin/python reports/accuracy/scripts/detail_hybrid.py OUT.jsonl [meshes] [variants]

``variants``: comma-separated ``detail{s}`` / ``dev{s}`` (default ``detail1.5,detail2,dev2``).
"""
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import optim  # noqa: E402
import experiments.accuracy as A  # noqa: E402
import pooled_priority as PP  # noqa: E402
from blend_keys import hybrid_mesh  # noqa: E402
from deviation_contrast import dev_columns  # noqa: E402
from detail_contrast import detail_columns  # noqa: E402
from experiments.accuracy import DEFAULTS, plod_mesh  # noqa: E402
from optim._relight import light_key  # noqa: E402


def variant_tree(mesh, name, light):
    t = optim.build_tree(mesh.v, mesh.f, mesh.c, method="hybrid")
    kind, s = (name[:6], float(name[6:])) if name.startswith("detail") else (name[:3], float(name[3:]))
    cols = detail_columns(t, light, s) if kind == "detail" else dev_columns(t, light, s)
    t._derived[f"relight.columns.{light_key(light)}"] = cols
    return t


def main():
    PP.held_out_mesh = hybrid_mesh
    out = open(sys.argv[1], "a")
    names = sys.argv[2].split(",") if len(sys.argv) > 2 and sys.argv[2] else PP.HELD_OUT
    labels = sys.argv[3].split(",") if len(sys.argv) > 3 else ["detail1.5", "detail2", "dev2"]
    cfg = dict(DEFAULTS, face_cull=True, normals="region", method="hybrid", size=list(PP.SIZE))
    A.DEFAULTS["normals"] = "region"
    light = optim.Lighting()
    trees = {}
    for name, mesh, view, g, J in PP.held_out_cells(names, cfg):
        if name not in trees:
            trees = {name: {lab: variant_tree(mesh, lab, light) for lab in labels}}
        PP.budget_rows(out, mesh.tree["relit"], view, cfg, J,
                       {lab: (lambda n, tr=tr: plod_mesh(tr, optim.score(tr, view), view, cfg, n)[0])
                        for lab, tr in trees[name].items()}, mesh=name, gaze=g)


if __name__ == "__main__":
    main()

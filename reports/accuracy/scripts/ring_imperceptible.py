"""Issue 10: the imperceptible cut with the relit cone widened to the 2-ring (``ring_cone.py``) on the
accuracy sweep's relit cells (face culling on, as ``configs/accuracy_facecull.toml``): JOD and drawn
triangles against today's cut and against the cut before lights (``reports/accuracy/before/results.jsonl``,
the count the issue's "no more triangles than today's cut" refers to).

    OMP_NUM_THREADS=1 PYOPENGL_PLATFORM=egl .venv/bin/python reports/accuracy/scripts/ring_imperceptible.py OUT.jsonl [tight]

``tight``: ``ring_cone.ring_half_tight`` (two stacked angles per neighbour instead of three); ``nb``: no ring,
today's cut against the cut without the neighbours' normals (``neighbour_normals.cone_only_tree``, key
``cone_only``).
"""
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import optim  # noqa: E402
from neighbour_normals import cone_only_tree  # noqa: E402
from ring_cone import ring_tree  # noqa: E402
from experiments.accuracy import DEFAULTS, _Mesh, _cell_id, _cells, _view, load_meshes, plod_mesh  # noqa: E402
from experiments.judge import judge  # noqa: E402


def judge_row(out, row, trees, mesh, view, cfg, light):
    """``row[label]``: the judge's JOD of each ``trees[label]``'s imperceptible cut at ``view`` (relit),
    ``row[label_tris]`` its triangles; the row printed and appended to ``out``."""
    for label, tree in trees.items():
        k = optim.score(tree, view)
        m, _ = plod_mesh(tree, k, view, cfg, cut=optim.threshold_cut(tree, k, 1.0, monotone="trust"))
        res = judge(mesh.original("relit"), m, view, mode="relit", lighting=light, size=tuple(cfg["size"]),
                    heatmap=False)
        row[label] = round(res.jod, 4)
        row[label + "_tris"] = len(m[1])
    print(json.dumps(row), flush=True)
    out.write(json.dumps(row) + "\n")
    out.flush()


def main():
    cfg = dict(DEFAULTS, face_cull=True, lightings=["relit"])
    before = {}
    for line in open(ROOT / "reports/accuracy/before/results.jsonl"):
        r = json.loads(line)
        if r["method"] == "imperceptible":
            before[r["cell"]] = r["triangles"]
    out = open(sys.argv[1], "a")
    variant = sys.argv[2] if len(sys.argv) > 2 else "ring"
    tight = variant == "tight"
    light = optim.Lighting()
    meshes = load_meshes(cfg)
    trees = {}
    for name, vi, d, g, lighting in _cells(meshes, cfg):
        if name not in trees:
            spec = next(m for m in meshes if m[0] == name)
            mesh = _Mesh(*spec)
            alt = (cone_only_tree(mesh.v, mesh.f, mesh.c, light) if variant == "nb" else
                   ring_tree(mesh.v, mesh.f, mesh.c, light, tight))
            trees = {name: (mesh, alt)}
        mesh, rt = trees[name]
        view = _view(mesh, d, g, "relit", cfg, True)
        row = {"cell": _cell_id(name, vi, g, "relit"), "before_tris": before.get(_cell_id(name, vi, g, "relit"))}
        judge_row(out, row, {"today": mesh.tree["relit"], "cone_only" if variant == "nb" else "ring": rt}, mesh, view,
                  cfg, light)


if __name__ == "__main__":
    main()

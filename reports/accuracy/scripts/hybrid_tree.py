"""Issue 10 experiment: the hybrid tree (``build_tree(method="hybrid")``: qem collapses at the bottom while the
mesh keeps more than ``HYBRID_KEEP`` of its triangles, meshoptimizer's nested levels above) against the
meshopt and qem trees. Held-out meshes, two random views (the seed of tree_choice.py), gaze at the centre,
relit with region normals, no culling, 960x540; each tree's perceptual cut at the meshopt tree's count.

    OMP_NUM_THREADS=1 PYOPENGL_PLATFORM=egl .venv/bin/python reports/accuracy/scripts/hybrid_tree.py OUT.jsonl [meshes] [keeps]
"""
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import optim  # noqa: E402
import optim._build as B  # noqa: E402
from pooled_priority import HELD_OUT, SIZE, held_out_mesh  # noqa: E402
from tree_choice import tree_rows  # noqa: E402
from experiments.accuracy import DEFAULTS  # noqa: E402


def main():
    out = open(sys.argv[1], "a")
    names = sys.argv[2].split(",") if len(sys.argv) > 2 and sys.argv[2] else HELD_OUT
    keeps = [float(x) for x in sys.argv[3].split(",")] if len(sys.argv) > 3 else [0.1]
    cfg = dict(DEFAULTS, size=list(SIZE), normals="region")
    for name in names:
        mesh = held_out_mesh(name)
        trees = {"meshopt": mesh.tree["relit"], "qem": optim.build_tree(mesh.v, mesh.f, mesh.c, method="qem")}
        for kp in keeps:
            B.HYBRID_KEEP = kp
            trees[f"hybrid{kp:g}"] = optim.build_tree(mesh.v, mesh.f, mesh.c, method="hybrid")
        tree_rows(out, name, mesh, trees, cfg,
                  lambda tn, tree, cut, m, b: {tn + "_flips": int(optim.cut_flips(tree, cut).flipped)})

if __name__ == "__main__":
    main()

"""Issue 10 experiment: the hybrid tree (``build_tree(method="hybrid")``: qem collapses at the bottom while the
mesh keeps more than ``HYBRID_KEEP`` of its triangles, meshoptimizer's nested levels above) against the
meshopt and qem trees. Held-out meshes, two random views (the seed of tree_choice.py), gaze at the centre,
relit with region normals, no culling, 960x540; each tree's perceptual cut at the meshopt tree's count.

    OMP_NUM_THREADS=1 PYOPENGL_PLATFORM=egl .venv/bin/python reports/accuracy/scripts/hybrid_tree.py OUT.jsonl [meshes] [keeps]
"""
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import optim  # noqa: E402
import optim._build as B  # noqa: E402
from pooled_priority import HELD_OUT, SIZE, emit, held_out_mesh, judge_fn  # noqa: E402
from experiments.accuracy import DEFAULTS, _view  # noqa: E402
from experiments.experiment import view_directions  # noqa: E402


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
        for vi, d in enumerate(view_directions(2, 55, name)):
            view = _view(mesh, d, 0.0, "relit", cfg, True)
            J = judge_fn(mesh, view, "relit")
            for b in (0.03, 0.08, 0.2):
                t0 = time.perf_counter()
                row = dict(mesh=name, view=vi, budget=b)
                target = None
                for tn, tree in trees.items():
                    n = max(int(b * tree.n_triangles), 1) if target is None else target
                    cut = optim.budget_cut(tree, optim.score(tree, view), n, monotone="trust")
                    m = optim.extract(tree, cut, "region")
                    target = target or len(m[1])
                    row[tn] = J(m)
                    row[tn + "_flips"] = int(optim.cut_flips(tree, cut).flipped)
                for peer in ("meshoptimizer", "fast_simplification"):
                    row[peer] = J(mesh.peer(peer, "relit", target))
                row["s"] = round(time.perf_counter() - t0, 1)
                emit(out, row)


if __name__ == "__main__":
    main()

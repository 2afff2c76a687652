"""The folds that bind an LOD level: the horse's 5 % level (relit, hybrid tree, 64 directions), its eight folded nodes
with the largest keys, each from its worst direction: silhouette flag, extent theta (deg) and in pixels,
contrast, own contrast, thin band (deg). Run from the repository root:
.venv/bin/python reports/lods/scripts/binding_nodes.py (reports/lods/notes.md quotes it)."""
import numpy as np, optim
v, f, c = optim.load_mesh("../shared/data/meshes/horse.ply")
tree = optim.build_tree(v, f, c, method="hybrid")
T = tree.n_triangles; L = optim.Lighting()
(lv,) = optim.lod_chain(tree, budgets=[int(T*0.05)], directions=64, lighting=L)
s = lv.object_deg; print("size", s, lv.key)
I = tree.internal; fo = I[~lv.cut.unfolded[I]]
dirs = optim.sphere_directions(64)
K = np.stack([optim.score(tree, optim.View.framing(v, s, direction=u, gaze=None, lighting=L)) for u in dirs])
kf = K[:, fo].max(0); top = fo[np.argsort(-kf)[:8]]
for n in top:
    di = int(np.argmax(K[:, n])); view = optim.View.framing(v, s, direction=dirs[di], gaze=None, lighting=L)
    t = optim.node_terms(tree, view)
    print(n, "key", K[di, n], "sil", t.silhouette[n], "theta", t.theta[n], "px", t.size_px[n], "c", t.contrast[n], "own", t.own_contrast[n], "band", t.band_deg[n], "geom_err/r", tree.geom_error[n]/tree.radius[n])
# how many of the folded would be silhouettes vs interior binding (key > 0.5)

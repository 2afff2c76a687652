"""Issue 10 item 4 experiment: interior fold contrast from the surface deviation, and RMS geometric keys.
Relit cells on meshes the tests and the accuracy sweep do not use."""
import json, sys, time
import numpy as np
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[3]))
import optim
from optim._relight import relit_columns, light_key, _lambert_range, normal_cones, _albedo
from optim._qem import quadric_error, vertex_quadrics
from experiments.accuracy import _Mesh, _view, DEFAULTS
from experiments.experiment import view_directions
from experiments.judge import judge

def rms_dev(tree):
    V = np.asarray(tree.vertices, float); F = np.asarray(tree.faces)
    q = vertex_quadrics(V, F)
    qn = np.zeros((tree.n_nodes, 10)); qn[tree.vertex_node] = q
    tree.levels.reduce_up(qn, np.add)
    area = (qn[:, 0] + qn[:, 3] + qn[:, 5]) / 3.0
    err = quadric_error(qn, np.asarray(tree.position, float))
    k = np.sqrt(np.maximum(err, 0.0) / np.maximum(area, 1e-300))
    k[np.asarray(tree.child_count) == 0] = 0.0
    return k

def dev_columns(tree, light, scale):
    """relit columns whose fold_delta comes from a tilt of atan(scale * rms / radius) (capped by the cone)."""
    base = relit_columns(tree, light)
    axis, half = normal_cones(tree)
    rms = rms_dev(tree)
    r = np.maximum(np.asarray(tree.radius, float), 1e-30)
    return tilt_columns(tree, light, base, axis, np.minimum(np.arctan(scale * rms / r), half.astype(float)))


def tilt_columns(tree, light, base, axis, tilt):
    """``base`` (the relit columns) with fold_delta no more than the Lambert range over normals within
    ``tilt`` (N,) rad of ``axis`` (N, 3), times the node's albedo range."""
    lo, hi, mid = _lambert_range(axis, tilt, light)
    a_lo, a_hi, a_mid = _albedo(tree)
    delta = np.maximum(a_hi * hi - a_mid * mid, a_mid * mid - a_lo * lo)
    delta[np.asarray(tree.child_count) == 0] = 0
    d = np.minimum(np.asarray(base["fold_delta"], float), delta)
    return dict(base, fold_delta=np.ascontiguousarray(d, np.float32))

def main():
    meshes = sys.argv[1].split(",")
    budgets = [0.03, 0.08]
    gazes = [0.0, 8.0]
    cfg = dict(DEFAULTS); cfg["size"] = [960, 540]
    light = optim.Lighting()
    out = open(sys.argv[2], "a")
    for name in meshes:
        v, f, c = optim.load_mesh(f"../shared/data/meshes/{name}")
        t0 = time.time()
        trees = {}
        trees["perceptual"] = optim.build_tree(v, f, c)
        for s in (1.0, 2.0):
            t = optim.build_tree(v, f, c)
            cols = dev_columns(t, light, s)
            t._derived[f"relight.columns.{light_key(light)}"] = cols
            trees[f"dev{s:g}"] = t
        geo_rms = optim.build_tree(v, f, c)
        rms = rms_dev(geo_rms)
        object.__setattr__(geo_rms, "geom_error", np.ascontiguousarray(rms, np.float32))  # frozen dataclass
        print(name, "built", time.time() - t0, flush=True)
        m = _Mesh.__new__(_Mesh); m.name, m.v, m.f, m.c = name, v, f, c; m.baked_colors = c
        T = len(f)
        for d in view_directions(1, 77, name):
            for g in gazes:
                view = _view(m, d, g, "relit", cfg, True)
                ref = (v, f, c)
                def J(res):
                    return judge(ref, res, view, mode="relit", lighting=light, size=tuple(cfg["size"]), heatmap=False).jod
                # imperceptible
                row = dict(mesh=name, gaze=g)
                for kname in ("perceptual", "dev1", "dev2"):
                    tr = trees[kname]
                    k = optim.score(tr, view)
                    cut = optim.threshold_cut(tr, k, 1.0, monotone="trust")
                    res = optim.extract(tr, cut)
                    row[f"imp_{kname}"] = (len(res[1]), J(res))
                print(json.dumps(row), flush=True); out.write(json.dumps(row) + "\n"); out.flush()
                for b in budgets:
                    row = dict(mesh=name, gaze=g, budget=b)
                    tr = trees["perceptual"]
                    k = optim.score(tr, view)
                    pres = optim.extract(tr, optim.budget_cut(tr, k, int(b * T), monotone="trust"))
                    target = len(pres[1]); row["tris"] = target
                    row["perceptual"] = J(pres)
                    for kname in ("dev1", "dev2"):
                        tr = trees[kname]
                        row[kname] = J(optim.extract(tr, optim.budget_cut(tr, optim.score(tr, view), target, monotone="trust")))
                    tr = trees["perceptual"]
                    for metric in ("size", "geometric"):
                        row[metric] = J(optim.extract(tr, optim.budget_cut(tr, optim.score(tr, view, None, metric), target, monotone="trust")))
                    row["geometric_rms"] = J(optim.extract(geo_rms, optim.budget_cut(geo_rms, optim.score(geo_rms, view, None, "geometric"), target, monotone="trust")))
                    row["meshoptimizer"] = J(m.peer("meshoptimizer", "relit", target))
                    row["fast_simplification"] = J(m.peer("fast_simplification", "relit", target))
                    print(json.dumps(row), flush=True); out.write(json.dumps(row) + "\n"); out.flush()

if __name__ == '__main__':
    main()

"""Issue 10 experiment: the relit cone widened to the 2-ring. A fold changes the vertex normals of its
neighbours too (their area-weighted normals include the faces the fold replaces), so the shading of the
faces around them changes: on the cow a flat panel folded beside a ridge (a zero-width cone, contrast 0)
shifts the ridge's normals (9.78 JOD, seen by the motion judge). Here each node's relit cone covers the
normals of the faces within the 2-ring of its supported vertices (bounded through vertex-level cones:
angle(axis, n_u) plus the cone of u's neighbours' faces about n_u) and of the faces its fold leaves.
Used by relit_deviation.py (variant ``ring``)."""
import numpy as np
import optim
from optim._levels import level_runs
from optim._mesh import face_normals
from optim._normal_cube import _unit
from optim._relight import (_albedo, _lambert_range, _post_fold_masks, light_key, normal_cones, relit_columns)
from optim._tree import _vertex_normals


def _ang(a, b):
    return np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0))


def ring_half(tree):
    v = np.asarray(tree.vertices, np.float64)
    f = np.asarray(tree.faces, np.int64)
    V = len(v)
    fn = face_normals(v, f)
    ok = np.linalg.norm(fn, axis=1) > 0
    fu = _unit(fn)
    vn = _unit(_vertex_normals(v, f, fn))
    h1 = np.zeros(V)
    for k in range(3):
        np.maximum.at(h1, f[ok, k], _ang(vn[f[ok, k]], fu[ok]))
    hv = h1.copy()
    for a in range(3):
        for b in range(3):
            if a != b:
                u, w = f[:, a], f[:, b]
                np.maximum.at(hv, u, _ang(vn[u], vn[w]) + h1[w])
    axis, half = normal_cones(tree)
    ax = axis.astype(np.float64)
    lo, hi = np.asarray(tree.leaf_lo, np.int64), np.asarray(tree.leaf_hi, np.int64)
    lvtx = np.asarray(tree.leaf_vertex, np.int64)
    out = half.astype(np.float64).copy()
    for nodes, idx, off in level_runs(tree.levels.start, lo, hi - lo, np.asarray(tree.child_count) > 0):
        sz = hi[nodes] - lo[nodes]
        u = lvtx[idx]
        val = _ang(np.repeat(ax[nodes], sz, axis=0), vn[u]) + hv[u]
        out[nodes] = np.maximum(out[nodes], np.maximum.reduceat(val, off))
    _, cos_left = _post_fold_masks(tree, v, f)
    out = np.maximum(out, np.arccos(np.clip(cos_left, -1, 1)))
    return np.minimum(out * (1 + 1e-6) + 1e-6, np.pi)


def ring_columns(tree, light, tight=False):
    return cone_columns(tree, light, ring_half_tight(tree) if tight else ring_half(tree))


def cone_columns(tree, light, half):
    """Relit columns from the Lambert range over each node's cone of half-angle ``half`` (N,) alone."""
    base = relit_columns(tree, light)
    axis, _ = normal_cones(tree)
    i_lo, i_hi, i_mid = _lambert_range(axis, half, light)
    a_lo, a_hi, a_mid = _albedo(tree)
    lo, hi, proxy = a_lo * i_lo, a_hi * i_hi, a_mid * i_mid
    delta = np.maximum(hi - proxy, proxy - lo)
    delta[np.asarray(tree.child_count) == 0] = 0.0
    f32 = lambda x: np.ascontiguousarray(x, np.float32)  # noqa: E731
    return dict(base, lum=f32(proxy), lum_min=f32(lo), lum_max=f32(hi), fold_delta=f32(delta))


def ring_tree(v, f, c, light, tight=False):
    t = optim.build_tree(v, f, c)
    t._derived[f"relight.columns.{light_key(light)}"] = ring_columns(t, light, tight)
    return t


def ring_half_tight(tree):
    """The tighter form: about each node's axis, the normals of the faces incident to its supported
    vertices and their neighbours, bounded per neighbour w by angle(axis, n_w) + the cone of w's own faces
    about n_w (two angles, not three), and the faces its fold leaves."""
    from optim._levels import expand_ranges

    v = np.asarray(tree.vertices, np.float64)
    f = np.asarray(tree.faces, np.int64)
    V = len(v)
    fn = face_normals(v, f)
    ok = np.linalg.norm(fn, axis=1) > 0
    fu = _unit(fn)
    vn = _unit(_vertex_normals(v, f, fn))
    h1 = np.zeros(V)
    for k in range(3):
        np.maximum.at(h1, f[ok, k], _ang(vn[f[ok, k]], fu[ok]))
    # closed neighbourhoods as CSR (u -> w, self included)
    src = np.concatenate([f[:, a] for a in range(3) for b in range(3) if a != b] + [np.arange(V)])
    dst = np.concatenate([f[:, b] for a in range(3) for b in range(3) if a != b] + [np.arange(V)])
    key = np.unique(src * V + dst)
    src, dst = key // V, key % V
    start = np.searchsorted(src, np.arange(V + 1))
    axis, half = normal_cones(tree)
    ax = axis.astype(np.float64)
    lo, hi = np.asarray(tree.leaf_lo, np.int64), np.asarray(tree.leaf_hi, np.int64)
    lvtx = np.asarray(tree.leaf_vertex, np.int64)
    out = half.astype(np.float64).copy()
    for nodes, idx, off in level_runs(tree.levels.start, lo, hi - lo, np.asarray(tree.child_count) > 0):
        u = lvtx[idx]
        cnt = start[u + 1] - start[u]
        w = dst[expand_ranges(start[u], cnt)]
        per_node = np.add.reduceat(cnt, off)
        node_of = np.repeat(nodes, per_node)
        val = _ang(ax[node_of], vn[w]) + h1[w]
        o = np.cumsum(per_node) - per_node
        out[nodes] = np.maximum(out[nodes], np.maximum.reduceat(val, o))
    _, cos_left = _post_fold_masks(tree, v, f)
    out = np.maximum(out, np.arccos(np.clip(cos_left, -1, 1)))
    return np.minimum(out * (1 + 1e-6) + 1e-6, np.pi)

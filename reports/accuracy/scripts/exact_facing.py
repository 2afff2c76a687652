"""Issue 10 experiment (2026-12-03, not landed): per-view exact facing of the faces a fold touches instead of
the normal-cube masks, injected into optim._score's host table path; prints front-facing triangle counts."""
import sys; sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[3]))
import numpy as np, optim
import optim._score as S
from optim._relight import _tree_nodes, _depth_first_position, _border_vertices
from optim._mesh import face_normals

_CACHE = {}
def _prep(tree):
    d = _CACHE.get(id(tree))
    if d is not None: return d
    v = np.asarray(tree.vertices, np.float64); f = np.asarray(tree.faces, np.int64)
    N = tree.n_nodes
    # post-fold faces: (node, normal, point) pairs (the walk of _post_fold_masks)
    fd = _depth_first_position(tree)[f]
    lo, hi = np.asarray(tree.leaf_lo, np.int64), np.asarray(tree.leaf_hi, np.int64)
    parent = np.asarray(tree.parent, np.int64); proxy = np.asarray(tree.position, np.float64)
    face = np.repeat(np.arange(len(f)), 3)
    cur = parent[np.asarray(tree.vertex_node, np.int64)[f.ravel()]]
    P_node, P_n, P_p = [], [], []
    while face.size:
        keep = cur >= 0; face, cur = face[keep], cur[keep]
        d = fd[face]; inside = (d >= lo[cur, None]) & (d < hi[cur, None])
        part = ~inside.all(1); face, cur, inside = face[part], cur[part], inside[part]
        if not face.size: break
        p = np.where(inside[:, :, None], proxy[cur][:, None, :], v[f[face]])
        n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        P_node.append(cur); P_n.append(n); P_p.append(p.mean(1))
        cur = parent[cur]
    bface, bvert = _border_vertices(f, len(v))
    rim = tree.levels.reduce_up(_tree_nodes(tree, bvert.astype(np.uint8)), np.maximum).astype(bool)
    d = dict(v=v, f=f, fn=face_normals(v, f), fc=v[f].mean(1), pn=np.concatenate(P_node), pnn=np.concatenate(P_n),
             pp=np.concatenate(P_p), rim=rim)
    _CACHE[id(tree)] = d
    return d

def exact_flags(tree, eye, ring=2, postfold=True):
    d = _prep(tree); v, f = d["v"], d["f"]; V = len(v)
    out = []
    s = np.einsum("ij,ij->i", d["fn"], eye - d["fc"])
    ps = np.einsum("ij,ij->i", d["pnn"], eye - d["pp"])
    for want, pw in ((s > 0, ps > 0), (s < 0, ps < 0)):
        r1 = np.zeros(V, bool)
        for k in range(3): np.logical_or.at(r1, f[:, k], want)
        fa = r1[f[:, 0]] | r1[f[:, 1]] | r1[f[:, 2]]
        r2 = r1.copy()
        if ring == 2:
            for k in range(3): np.logical_or.at(r2, f[:, k], fa)
        node = tree.levels.reduce_up(_tree_nodes(tree, r2.astype(np.uint8)), np.maximum).astype(bool)
        if postfold: np.logical_or.at(node, d["pn"], pw)
        out.append(node)
    front, back = out
    front |= d["rim"]; back |= d["rim"]
    return front, back

_orig_fh = S.facing_host
_orig_cls = S.classify
_state = {}
def _patched_table_keys_host(ctx, vp, ktab, has_gaze):
    fr, bk = _state["flags"]
    fr_c, bk_c = fr[ctx.node], bk[ctx.node]
    sil_flags = _state.get("sil")
    if sil_flags is not None:
        f1, b1 = sil_flags[0][ctx.node], sil_flags[1][ctx.node]
    pos = [0]
    cur = {}
    def fh(widx, hm, n):
        a = pos[0]; pos[0] += n
        cur["a"], cur["n"] = a, n
        return fr_c[a:a + n], bk_c[a:a + n]
    def cls(nonempty, front, back, out_of_view, cone=None):
        culled, backfacing, sil = _orig_cls(nonempty, front, back, out_of_view, cone)
        if sil_flags is not None:
            a, n = cur["a"], cur["n"]
            sil = f1[a:a + n] & b1[a:a + n] & cone[0] & cone[1] & ~culled
        return culled, backfacing, sil
    S.facing_host = fh; S.classify = cls
    try:
        return _orig_tkh(ctx, vp, ktab, has_gaze)
    finally:
        S.facing_host = _orig_fh; S.classify = _orig_cls
_orig_tkh = S._table_keys_host

def score_exact(tree, view, *a, sil_ring=None, sil_postfold=True, **k):
    _state["flags"] = exact_flags(tree, np.asarray(view.eye, float))
    _state["sil"] = None if sil_ring is None else exact_flags(tree, np.asarray(view.eye, float), ring=sil_ring, postfold=sil_postfold)
    S._table_keys_host = _patched_table_keys_host
    try:
        return optim.score(tree, view, *a, **k)
    finally:
        S._table_keys_host = _orig_tkh


def main():
    """Front-facing triangles of the budget cuts of one sweep cell (no judge) with today's classification,
    exact facing over the 1-ring and the faces the fold leaves, and exact facing over the 1-ring only."""
    import json, sys
    from experiments.accuracy import _Mesh, _view, DEFAULTS
    cell = sys.argv[1] if len(sys.argv) > 1 else "horse/v0/g16/relit"
    name, _, g, _ = cell.split("/")
    rows = [json.loads(l) for l in open("reports/accuracy/results.jsonl")]
    r = next(x for x in rows if x["cell"] == cell)
    path = next(p for p in DEFAULTS["meshes"] if name in p)
    v, f, c = optim.load_mesh(path)
    m = _Mesh(name, v, f, c); tree = m.tree["relit"]; T = tree.n_triangles
    view = _view(m, r["direction"], float(g[1:]), "relit", dict(DEFAULTS), True); eye = np.asarray(view.eye, float)
    for nm, k in (("today", optim.score(tree, view)), ("exact 1-ring + left faces", score_exact(tree, view, sil_ring=1)),
                  ("exact 1-ring only", score_exact(tree, view, sil_ring=1, sil_postfold=False))):
        for b in (0.03, 0.08):
            vv, ff, _ = optim.extract(tree, optim.budget_cut(tree, k, int(b * T), monotone="trust"))
            vv = np.asarray(vv, float); ff = np.asarray(ff)
            n = np.cross(vv[ff[:, 1]] - vv[ff[:, 0]], vv[ff[:, 2]] - vv[ff[:, 0]])
            print(f"| {nm} | {b:.0%} | {len(ff)} | {int(((n * (eye - vv[ff].mean(1))).sum(1) > 0).sum())} |")


if __name__ == "__main__":
    main()

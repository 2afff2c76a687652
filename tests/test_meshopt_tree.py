"""The nested-meshoptimizer hierarchy (optim/_meshopt_tree.py, build_tree(method="meshopt"))."""

from __future__ import annotations

import numpy as np
import pytest

import optim
from optim._build import _list_rank
from optim._mesh import validated_mesh_and_normals
from optim._meshopt_tree import _collapse_map, meshopt_parents, meshopt_simplify

TET_V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
TET_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def _soup(seed=2, n_pts=40, n_tri=60):
    """Random triangles: many small components, odd topology."""
    rng = np.random.default_rng(seed)
    return rng.random((n_pts, 3)), np.stack([rng.choice(n_pts, 3, replace=False) for _ in range(n_tri)]), None


def _two_islands():
    """Two bumpy spheres far apart plus a lone triangle: three components."""
    v, f = optim.icosphere(2)
    tri_v = np.array([[9.0, 0, 0], [9.5, 0, 0], [9.0, 0.5, 0]])
    vv = np.concatenate([v, v + 4.0, tri_v])
    ff = np.concatenate([f, f + len(v), [[2 * len(v), 2 * len(v) + 1, 2 * len(v) + 2]]])
    return vv, ff, None


MESHES = {
    "bumpy": optim.bumpy_sphere(3, seed=1, colors=True),
    "ico": (*optim.icosphere(3), None),
    "grid": (*optim.grid_mesh(12, 9), None),
    "torus": (*optim.bumpy_torus(30, 14, seed=2), None),
    "tet": (TET_V, TET_F, None),
    "soup": _soup(),
    "islands": _two_islands(),
}


@pytest.fixture(scope="module")
def trees():
    return {(m, p): optim.build_tree(*MESHES[m], method="meshopt", proxy=p)
            for m in MESHES for p in ("optimal", "vertex")}


def _validated(name):
    v, f, c = MESHES[name]
    mesh, _ = validated_mesh_and_normals(v, f, c, count_nonmanifold=False)
    return mesh.vertices, mesh.faces, mesh.colors


def _old_keys(parent, V):
    """(smallest vertex, vertex count) of every node of an old-numbering parent array."""
    N = parent.size
    mn = np.full(N, np.iinfo(np.int64).max)
    mn[:V] = np.arange(V)
    cnt = np.zeros(N, np.int64)
    cnt[:V] = 1
    for i in np.argsort(-_list_rank(parent), kind="stable"):  # deepest first
        p = parent[i]
        if p >= 0:
            mn[p] = min(mn[p], mn[i])
            cnt[p] += cnt[i]
    return mn, cnt


def _node_levels(tree, h):
    """``h.node_level`` in the tree's numbering (a node is named by its smallest vertex and its size: no
    two nodes share both, as the tree has no single-child chains)."""
    V = tree.n_vertices
    mn, cnt = _old_keys(h.parent, V)
    old = mn * (V + 1) + cnt
    new = tree.min_vertex.astype(np.int64) * (V + 1) + (tree.leaf_hi - tree.leaf_lo)
    o = np.argsort(old)
    p = np.searchsorted(old[o], new)
    assert np.array_equal(old[o][p], new)
    return h.node_level[o][p]


@pytest.mark.parametrize("mesh", sorted(MESHES))
@pytest.mark.parametrize("proxy", ["optimal", "vertex"])
def test_structure(trees, mesh, proxy):
    t = trees[(mesh, proxy)]
    t.check()
    assert t.method == "meshopt"
    N, V = t.n_nodes, t.n_vertices
    assert t.parent[0] == -1 and np.all(t.parent[1:] >= 0) and np.all(t.parent[1:] < np.arange(1, N))
    leaves = np.flatnonzero(t.child_count == 0)
    np.testing.assert_array_equal(np.sort(t.vertex_node), leaves)  # every input vertex is a leaf, and only they
    assert np.all(t.child_count[t.child_count > 0] >= 2)  # no single-child chains
    assert N <= 2 * V - 1
    v, f, _ = _validated(mesh)
    np.testing.assert_array_equal(t.vertices, v)
    np.testing.assert_array_equal(t.position[t.vertex_node], v.astype(np.float32))


@pytest.mark.parametrize("mesh", sorted(MESHES))
def test_vertex_proxy_is_the_kept_input_vertex(trees, mesh):
    """proxy="vertex": every internal node sits at the supported vertex of highest survival rank, the
    vertex meshoptimizer kept (unique below the octree top)."""
    t = trees[(mesh, "vertex")]
    v, f, c = _validated(mesh)
    h = meshopt_parents(v, f, c)
    level = _node_levels(t, h)
    top = level == level.max()
    for n in t.internal:
        sup = t.leaf_vertex[t.leaf_lo[n]:t.leaf_hi[n]]
        hit = np.flatnonzero(np.all(v[sup].astype(np.float32) == t.position[n], axis=1))
        assert hit.size >= 1, f"node {n}: proxy is not one of its supported input vertices"
        best = sup[h.survival[sup] == h.survival[sup].max()].min()  # ties (the octree top): smallest index
        np.testing.assert_array_equal(t.position[n], v[best].astype(np.float32))
        if not top[n]:  # below the octree top one vertex outlives all others
            assert np.sum(h.survival[sup] == h.survival[best]) == 1


@pytest.mark.parametrize("mesh", ["bumpy", "ico", "grid", "torus", "islands"])
def test_uniform_cut_reproduces_each_level(trees, mesh):
    """Unfolding every node above level k gives meshoptimizer's level-k mesh: its triangle count (the
    recovered collapse map is exact up to a few diagonal swaps) and, with vertex proxies, its vertices."""
    t = trees[(mesh, "vertex")]
    v, f, c = _validated(mesh)
    h = meshopt_parents(v, f, c)
    level = _node_levels(t, h)
    assert len(h.level_triangles) > 3 and h.level_triangles[0] == len(f)
    # recompute the level meshes' vertex sets as meshoptimizer made them
    F, sets = f.astype(np.int64), [np.unique(f)]
    for k in range(1, len(h.level_triangles)):
        used, Fl = np.unique(F, return_inverse=True)
        cl = None if c is None else c[used]
        F = used[meshopt_simplify(v[used], Fl.reshape(-1, 3), max(int(0.8 * len(F)), 1), cl)]
        assert len(F) == h.level_triangles[k]
        sets.append(np.unique(F))
    for k, want in enumerate(h.level_triangles):
        unfolded = (level > k) & (t.child_count > 0)
        vv, ff, _ = optim.extract(t, unfolded)
        assert abs(len(ff) - want) <= max(2, 0.005 * want), (k, len(ff), want)
        if mesh != "islands":  # (a dropped island keeps a vertex of its own)
            got = np.unique(vv.astype(np.float32), axis=0)
            exp = np.unique(v[sets[k]].astype(np.float32), axis=0)
            assert len(got) == len(exp) and np.array_equal(got, exp), k


def test_collapse_map_is_exact_on_a_single_pass():
    """A call that removes few triangles collapses disjoint edges: the recovered map must explain every
    output triangle (each removed vertex goes to an adjacent kept vertex)."""
    v, f = optim.icosphere(3)
    v = v * (1 + 0.05 * np.sin(7 * v[:, :1]))  # break the symmetry (ties in meshoptimizer's order)
    F = f.astype(np.int64)
    G = meshopt_simplify(v, F, int(0.95 * len(F)))
    r = _collapse_map(F, G, v)
    assert np.all(r[np.unique(F)] >= 0)
    M = r[F]
    nd = (M[:, 0] != M[:, 1]) & (M[:, 1] != M[:, 2]) & (M[:, 0] != M[:, 2])
    canon = lambda T: np.sort([tuple(np.roll(t, -int(np.argmin(t)))) for t in T], axis=0)  # noqa: E731
    np.testing.assert_array_equal(canon(M[nd]), canon(G))


def test_deterministic():
    v, f, c = MESHES["bumpy"]
    a = optim.build_tree(v, f, c, method="meshopt")
    b = optim.build_tree(v.copy(), f.copy(), c.copy(), method="meshopt")
    for k in ("parent", "position", "color", "geom_error", "tri_node", "fold_delta", "normal_mask"):
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k))


def test_colors_enter_the_simplification():
    """With colours meshoptimizer's attribute metric decides too: a colour edge changes the hierarchy."""
    v, f, c = MESHES["bumpy"]
    stripe = np.where(v[:, :1] > 0.2, 1.0, 0.0) * np.ones((1, 3))
    a = meshopt_parents(*_validated("bumpy")[:2], None)
    b = meshopt_parents(*_validated("bumpy")[:2], stripe.astype(np.float32))
    assert not np.array_equal(a.parent, b.parent)
    t = optim.build_tree(v, f, stripe, method="meshopt")
    t.check()
    assert t.color is not None


@pytest.mark.parametrize("proxy", ["optimal", "vertex"])
def test_cuts_scores_and_flips(trees, proxy):
    """The perceptual key path (score + budget_cut + extract) and flip detection run on a meshopt tree;
    budget cuts respect the budget and shrink with it."""
    t = trees[("bumpy", proxy)]
    view = optim.View.framing(t.vertices, lighting=optim.Lighting())
    last = None
    for budget in (1000, 400, 100):
        for metric in ("perceptual", "size", "geometric"):
            keys = optim.score(t, view, None, metric)
            cut = optim.budget_cut(t, keys, budget)
            vv, ff, cc = optim.extract(t, cut)
            assert len(ff) == cut.triangles <= budget and len(ff) > 0.8 * budget
            assert cc is not None and len(cc) == len(vv)
            fl = optim.cut_flips(t, cut)
            assert fl.triangles == len(ff) and fl.flipped <= 0.1 * len(ff)
        assert last is None or cut.triangles < last
        last = cut.triangles


def test_small_and_odd_meshes(trees):
    """A tetrahedron, a triangle soup and separate islands still give one tree over every vertex."""
    for name in ("tet", "soup", "islands"):
        t = trees[(name, "optimal")]
        assert t.n_vertices == len(_validated(name)[0]) and int(np.sum(t.parent < 0)) == 1
        full = optim.extract(t, t.child_count > 0)
        assert len(full[1]) == t.n_triangles  # everything unfolded: the input
    one = optim.build_tree(TET_V[:3], TET_F[:1], method="meshopt")
    one.check()
    assert one.n_triangles == 1


# ------------------------------------------------------------------ the hybrid tree (qem below, meshopt above)
@pytest.mark.parametrize("mesh", sorted(MESHES))
def test_hybrid_structure(mesh):
    """One tree over every vertex, binary qem nodes below and meshoptimizer's levels above, for every odd
    mesh (islands whose collapses leave no triangle included)."""
    t = optim.build_tree(*MESHES[mesh], method="hybrid")
    t.check()
    N, V = t.n_nodes, t.n_vertices
    assert t.method == "hybrid" and int(np.sum(t.parent < 0)) == 1
    assert np.all(t.parent[1:] < np.arange(1, N)) and np.all(t.child_count[t.child_count > 0] >= 2)
    np.testing.assert_array_equal(np.sort(t.vertex_node), np.flatnonzero(t.child_count == 0))
    assert len(optim.extract(t, t.child_count > 0)[1]) == t.n_triangles


def test_hybrid_ends_are_meshopt_and_qem(monkeypatch):
    """Keeping every triangle for meshoptimizer gives the meshopt tree exactly; the qem prefix's nodes are
    fast-simplification's first collapses, and its faces the input's under them."""
    import optim._build as B
    from optim._qem import _binary_nodes, qem_collapses, qem_prefix

    v, f, c = _validated("bumpy")
    monkeypatch.setattr(B, "HYBRID_KEEP", 1.0)
    a = optim.build_tree(v, f, c, method="hybrid")
    b = optim.build_tree(v, f, c, method="meshopt")
    np.testing.assert_array_equal(a.parent, b.parent)
    np.testing.assert_array_equal(a.position, b.position)
    parent, cur, faces, removed = qem_prefix(v, f, 0.25, diagonal=100.0)
    col = qem_collapses(v, f, diagonal=100.0)
    C = parent.size - len(v)
    assert 0 < C < len(col) and removed.sum() == C
    np.testing.assert_array_equal(parent, _binary_nodes(col[:C], len(v))[0])
    # the slow way: apply the collapses one by one
    r = np.arange(len(v))
    for i0, i1 in col[:C]:
        r[r == i1] = i0
    g = r[f]
    g = g[(g[:, 0] != g[:, 1]) & (g[:, 1] != g[:, 2]) & (g[:, 0] != g[:, 2])]
    np.testing.assert_array_equal(faces, g)
    assert 0.25 * len(f) < len(faces) <= 0.25 * len(f) + 4  # the last collapse that keeps more than a quarter
    assert not removed[faces].any() and np.all(parent[cur[~removed]] == -1)

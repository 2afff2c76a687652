"""Cuts and extraction (optim/_cut.py) against the heap greedy and slow references."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import optim


def _soup(seed, n_pts=40, n_tri=60):
    rng = np.random.default_rng(seed)
    v = rng.random((n_pts, 3))
    f = np.stack([rng.choice(n_pts, 3, replace=False) for _ in range(n_tri)])
    return v, f


def _build():
    out = {}
    v, f = optim.icosphere(2)
    out["ico-octree"] = optim.build_tree(v, f, method="octree")
    out["ico-qem"] = optim.build_tree(v, f, method="qem")
    out["grid-qem"] = optim.build_tree(*optim.grid_mesh(9, 6), method="qem")
    out["soup-octree"] = optim.build_tree(*_soup(1), method="octree")
    out["soup-qem"] = optim.build_tree(*_soup(2), method="qem")
    vb, fb, cb = optim.bumpy_sphere(1, seed=0, colors=True)
    out["bumpy-qem"] = optim.build_tree(vb, fb, cb, method="qem")
    return out


TREES = _build()
NAMES = sorted(TREES)


def _random_keys(tree, rng, ties, dtype=np.float64, culled_depth=None):
    k = rng.integers(0, 4, tree.n_nodes).astype(float) if ties else rng.random(tree.n_nodes) * 10
    k = optim.repair_monotone(tree, k)
    if ties:  # signed zeros tie with zeros (as in the heap's float comparison)
        k[(k == 0) & (rng.random(tree.n_nodes) < 0.5)] = -0.0
    if culled_depth is not None:  # culled subtrees: -inf (monotone: depth grows downwards)
        k[tree.depth >= culled_depth] = -np.inf
    return k.astype(dtype)


def _slow_repair(tree, keys):
    out = np.array(keys, float)
    for n in range(tree.n_nodes - 1, 0, -1):  # children after parents
        p = tree.parent[n]
        out[p] = max(out[p], out[n])
    return out


def _slow_extract_triangles(tree, unfolded):
    """Reference: representative = highest folded ancestor; a triangle survives iff its 3 reps differ."""
    rep = []
    for vtx in range(tree.n_vertices):
        n = int(tree.vertex_node[vtx])
        chain = [n]
        while tree.parent[chain[-1]] >= 0:
            chain.append(int(tree.parent[chain[-1]]))
        folded = [a for a in chain if not unfolded[a]]
        rep.append(folded[-1])  # the highest folded (leaves count as folded)
    rep = np.array(rep)
    tris = rep[tree.faces]
    keep = (tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 0] != tris[:, 2])
    return rep, keep


def _is_closed(tree, unfolded):
    ch = np.arange(1, tree.n_nodes)
    return bool(np.all(~unfolded[ch] | unfolded[tree.parent[ch]]))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(name=st.sampled_from(NAMES), seed=st.integers(0, 10**6), frac=st.floats(0, 1.05), ties=st.booleans(),
       f32=st.booleans(), culled=st.sampled_from([None, 2, 4]))
def test_budget_cut_equals_heap(name, seed, frac, ties, f32, culled):
    t = TREES[name]
    rng = np.random.default_rng(seed)
    k = _random_keys(t, rng, ties, np.float32 if f32 else np.float64, culled)
    budget = int(frac * t.n_triangles)
    a = optim.budget_cut(t, k, budget)
    b = optim.budget_cut_heap(t, k, budget)
    np.testing.assert_array_equal(a.unfolded, b.unfolded)
    assert (a.triangles, a.distance, a.stop_reason) == (b.triangles, b.distance, b.stop_reason)
    assert a.triangles == t.num_subtris[a.unfolded].sum() <= budget
    assert _is_closed(t, a.unfolded) and not a.unfolded[t.child_count == 0].any()
    if a.stop_reason == "budget":
        # tight: the boundary node with the greatest key (lowest index among ties) does not fit
        pu = np.ones(t.n_nodes, bool)
        pu[1:] = a.unfolded[t.parent[1:]]
        bnd = np.flatnonzero(pu & ~a.unfolded & (t.child_count > 0))
        top = bnd[np.lexsort((bnd, -k[bnd]))[0]]
        assert k[top] == a.distance and a.triangles + t.num_subtris[top] > budget
    else:
        assert a.triangles == t.n_triangles and a.distance == 0.0


def test_budget_cut_many_ties_large_tree():
    """All keys equal: the order is pure node index (exercises the radix passes down to shift 0)."""
    v, f = optim.icosphere(4)
    t = optim.build_tree(v, f, method="qem")
    for k in (np.ones(t.n_nodes), np.ones(t.n_nodes, np.float32)):
        for budget in (0, 1, 777, 2560, 5119):
            a, b = optim.budget_cut(t, k, budget), optim.budget_cut_heap(t, k, budget)
            np.testing.assert_array_equal(a.unfolded, b.unfolded)
            assert a.triangles == b.triangles
    # float64 keys that differ only below float32 precision: one 32-bit bucket, exact order from float64
    fine = optim.repair_monotone(t, 1.0 + np.random.default_rng(4).integers(0, 50, t.n_nodes) * 1e-12)
    for budget in (10, 2000, 5000):
        a, b = optim.budget_cut(t, fine, budget), optim.budget_cut_heap(t, fine, budget)
        np.testing.assert_array_equal(a.unfolded, b.unfolded)
        assert a.distance == b.distance
    k = optim.repair_monotone(t, np.random.default_rng(5).random(t.n_nodes)).astype(np.float32)
    for budget in (100, 3000, 5000):
        a, b = optim.budget_cut(t, k, budget), optim.budget_cut_heap(t, k, budget)
        np.testing.assert_array_equal(a.unfolded, b.unfolded)


def test_budget_extremes():
    t = TREES["ico-qem"]
    k = _random_keys(t, np.random.default_rng(0), False)
    c0 = optim.budget_cut(t, k, 0)
    assert c0.triangles == 0 and c0.stop_reason == "budget" and c0.distance == k[0]
    assert not c0.unfolded[0] or t.num_subtris[0] == 0
    call = optim.budget_cut(t, k, 10**9)
    assert call.stop_reason == "all_unfolded" and call.triangles == t.n_triangles and call.distance == 0.0
    np.testing.assert_array_equal(call.unfolded, t.child_count > 0)


def test_key_policy():
    t = TREES["grid-qem"]
    rng = np.random.default_rng(1)
    raw = rng.random(t.n_nodes)
    with pytest.raises(ValueError, match="not monotone"):
        optim.budget_cut(t, raw, 50)
    with pytest.raises(ValueError, match="not monotone"):
        optim.threshold_cut(t, raw, 0.5)
    rep = optim.repair_monotone(t, raw)
    np.testing.assert_array_equal(rep, _slow_repair(t, raw))
    assert np.all(rep[t.parent[1:]] >= rep[1:])
    a = optim.budget_cut(t, raw, 50, monotone="repair")
    b = optim.budget_cut_heap(t, rep, 50)
    np.testing.assert_array_equal(a.unfolded, b.unfolded)
    bad = rep.copy()
    bad[3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        optim.budget_cut(t, bad, 10)
    with pytest.raises(ValueError, match="shape"):
        optim.budget_cut(t, rep[:-1], 10)
    for b_ in (-1, 2.5, "x"):
        with pytest.raises(ValueError, match="budget"):
            optim.budget_cut(t, rep, b_)
    with pytest.raises(ValueError, match="monotone must be"):
        optim.budget_cut(t, rep, 10, monotone="maybe")
    # -inf keys (culled) are allowed and come last
    k = rep.copy()
    k[t.depth >= 3] = -np.inf
    a, b = optim.budget_cut(t, k, 10**6), optim.budget_cut_heap(t, k, 10**6)
    np.testing.assert_array_equal(a.unfolded, b.unfolded)


@settings(max_examples=40, deadline=None)
@given(name=st.sampled_from(NAMES), seed=st.integers(0, 10**6), thr=st.floats(-1, 11))
def test_threshold_cut(name, seed, thr):
    t = TREES[name]
    k = _random_keys(t, np.random.default_rng(seed), False)
    c = optim.threshold_cut(t, k, thr)
    want = (k > thr) & (t.child_count > 0)
    np.testing.assert_array_equal(c.unfolded, want)
    assert c.triangles == t.num_subtris[want].sum()
    if c.stop_reason == "imperceptible":
        pu = np.ones(t.n_nodes, bool)
        pu[1:] = want[t.parent[1:]]
        bnd = pu & ~want & (t.child_count > 0)
        assert c.distance == k[bnd].max() <= thr
    else:
        assert want[t.child_count > 0].all()
    # trust mode closes non-monotone keys under ancestors, top-down
    raw = np.random.default_rng(seed).random(t.n_nodes) * 10
    ct = optim.threshold_cut(t, raw, thr, monotone="trust")
    slow = np.zeros(t.n_nodes, bool)
    for n in range(t.n_nodes):
        slow[n] = raw[n] > thr and t.child_count[n] > 0 and (n == 0 or slow[t.parent[n]])
    np.testing.assert_array_equal(ct.unfolded, slow)


@settings(max_examples=40, deadline=None)
@given(name=st.sampled_from(NAMES), seed=st.integers(0, 10**6), frac=st.floats(0, 1))
def test_extract_matches_slow_reference(name, seed, frac):
    t = TREES[name]
    k = _random_keys(t, np.random.default_rng(seed), False)
    cut = optim.budget_cut(t, k, int(frac * t.n_triangles))
    verts, faces, colors = optim.extract(t, cut)
    rep, keep = _slow_extract_triangles(t, cut.unfolded)
    # the owner rule: a triangle survives iff its owner node is unfolded
    np.testing.assert_array_equal(keep, cut.unfolded[t.tri_node])
    assert faces.shape == (cut.triangles, 3) and faces.dtype == np.int32
    want_nodes = rep[t.faces[keep]]
    pos = np.where((t.child_count[want_nodes] == 0)[..., None], t.vertices[t.min_vertex[want_nodes]],
                   t.position[want_nodes].astype(np.float64))
    np.testing.assert_array_equal(verts[faces], pos)
    assert np.unique(faces).size == verts.shape[0]  # no unreferenced output vertex
    if t.color is not None:
        np.testing.assert_array_equal(colors[faces], np.where((t.child_count[want_nodes] == 0)[..., None],
                                                              t.colors[t.min_vertex[want_nodes]], t.color[want_nodes]))
    else:
        assert colors is None


@pytest.mark.parametrize("name", NAMES)
def test_extract_root_folded_and_all_unfolded(name):
    t = TREES[name]
    none = np.zeros(t.n_nodes, bool)
    v, f, c = optim.extract(t, none)
    assert f.shape == (0, 3) and v.shape == (0, 3)
    v, f, c = optim.extract(t, t.child_count > 0)
    np.testing.assert_array_equal(v, t.vertices)
    np.testing.assert_array_equal(f, t.faces)
    if t.colors is not None:
        np.testing.assert_array_equal(c, t.colors)
    with pytest.raises(ValueError, match="bool array"):
        optim.extract(t, np.zeros(3, bool))


def test_tetrahedron_exact_counts():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    for method in ("octree", "qem"):
        t = optim.build_tree(v, f, method=method)
        k = optim.repair_monotone(t, np.arange(t.n_nodes, 0, -1).astype(float))
        assert optim.budget_cut(t, k, 0).triangles == 0
        assert optim.budget_cut(t, k, 4).triangles == 4
        counts = sorted({optim.budget_cut(t, k, b).triangles for b in range(5)})
        # every reachable count is a prefix sum of the greedy order
        order = np.lexsort((np.arange(t.n_nodes), -k))
        order = order[t.child_count[order] > 0]
        assert set(counts) <= set(np.concatenate([[0], np.cumsum(t.num_subtris[order])]).tolist())


@pytest.mark.parametrize("k", [0, 1, 3, 50, 900])
def test_extract_orderings_equal_sorting(k):
    """extract's O(n) orderings (mask / scatter over [0, n)) give what sorting gives, on both sides of
    their switch (k * 64 < n sorts); repeated values come back once each in the scatter."""
    from optim._cut import _ascending, _order_of_distinct

    n = 1000
    rng = np.random.default_rng(k)
    vals = rng.choice(n, size=k, replace=False)
    assert np.array_equal(_ascending(vals.copy(), n), np.sort(vals))
    assert np.array_equal(_order_of_distinct(vals, n), np.argsort(vals))
    if k >= 50:
        rep = np.concatenate([vals, vals[:5]])
        order = _order_of_distinct(rep, n)
        assert order.size == k and np.array_equal(rep[order], np.sort(vals))


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("cores", [1, 2])
def test_extract_equals_reference_implementation(name, seed, cores, monkeypatch):
    """The cut-proportional extract returns the identical arrays (values and dtypes) as the O(N + V + T)
    reference, for budget cuts of many sizes; a cut not closed under ancestors falls back to it. With one
    usable core extract runs in the caller's thread, with two its halves overlap on a side thread."""
    import optim._parallel
    from optim._cut import _extract_reference

    monkeypatch.setattr(optim._parallel, "usable_cores", lambda: cores)
    tree = TREES[name]
    rng = np.random.default_rng(seed)
    keys = _random_keys(tree, rng, ties=bool(seed % 2))
    for frac in (0.0, 0.005, 0.05, 0.3, 0.7, 1.0):  # 0.005: extract's sorting branches, above: its scatters
        cut = optim.budget_cut(tree, keys, int(frac * tree.n_triangles))
        for a, b in zip(optim.extract(tree, cut), _extract_reference(tree, cut)):
            assert (a is None and b is None) or (np.array_equal(a, b) and a.dtype == b.dtype)
    bad = np.zeros(tree.n_nodes, bool)
    bad[tree.internal[-1]] = True  # an unfolded node whose parent is folded
    for a, b in zip(optim.extract(tree, bad), _extract_reference(tree, bad)):
        assert (a is None and b is None) or np.array_equal(a, b)
    # masks not closed under ancestors: a closed cut with a few nodes flipped either way (nested
    # boundary nodes whose ranges overlap while their lengths still sum to V must not pass as a tiling)
    internal = tree.internal
    for frac in (0.05, 0.3):
        base = optim.budget_cut(tree, keys, int(frac * tree.n_triangles)).unfolded
        for _ in range(4):
            bad = base.copy()
            flip = rng.choice(internal, size=rng.integers(1, 6), replace=False)
            bad[flip] = ~bad[flip]
            for a, b in zip(optim.extract(tree, bad), _extract_reference(tree, bad)):
                assert (a is None and b is None) or np.array_equal(a, b)


@pytest.mark.parametrize("name", [n for n in NAMES if n != "soup-octree"])  # its 40 points: too shallow to nest
def test_extract_overlap_hidden_by_a_gap_is_not_a_tiling(name):
    """A mask not closed under ancestors whose boundary ranges overlap by exactly as many leaves as
    they leave uncovered (their lengths still sum to V, their starts are distinct) is not taken for a
    tiling: extract gives the reference's arrays (before this check, a silently different mesh)."""
    from optim._cut import _extract_reference

    tree = TREES[name]
    rng = np.random.default_rng(5)
    parent, size = tree.parent, tree.leaf_hi - tree.leaf_lo
    leaf = tree.child_count == 0
    bad = None
    for frac in (0.3, 0.1, 0.5, 0.7):
        unf = optim.budget_cut(tree, _random_keys(tree, rng, ties=False), int(frac * tree.n_triangles)).unfolded
        for c in np.flatnonzero(~unf & unf[parent] & ~leaf):  # C folded, internal, its parent unfolded
            kids = np.arange(tree.child_start[c], tree.child_start[c] + tree.child_count[c])
            kids = kids[(tree.child_count[kids] > 0) & (tree.leaf_lo[kids] != tree.leaf_lo[c])]
            if kids.size == 0:  # E: an internal child that does not start C's range
                continue
            e = kids[0]
            outside = (tree.leaf_lo >= tree.leaf_hi[c]) | (tree.leaf_hi <= tree.leaf_lo[c])
            gaps = np.flatnonzero(leaf & unf[parent] & outside)  # leaves drawn as themselves, outside C
            if gaps.size >= size[e]:
                bad = unf.copy()
                bad[e] = True  # E's folded children lie inside C: an overlap of size[e] leaves
                bad[gaps[: size[e]]] = True  # as many leaves "unfolded": no boundary node covers them
                break
        if bad is not None:
            break
    assert bad is not None
    for a, b in zip(optim.extract(tree, bad), _extract_reference(tree, bad)):
        assert (a is None and b is None) or np.array_equal(a, b)

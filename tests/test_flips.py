"""Triangle flips of extracted cuts (optim/_flips.py) against a slow per-triangle reference."""

from __future__ import annotations

import numpy as np
import pytest

import optim
from optim._build import _assemble
from optim._mesh import face_normals
from optim._tree import _vertex_normals
from pmetric import PlodError


def _reference(tree, unfolded, tol=1e-6):
    """Per input triangle, in input order: representatives by climbing the tree; a triangle survives iff
    its three representatives differ; flipped iff its (non-degenerate) normal opposes the input's."""
    rep = []
    for vtx in range(tree.n_vertices):
        n = int(tree.vertex_node[vtx])
        top = n
        while tree.parent[n] >= 0:
            n = int(tree.parent[n])
            if not unfolded[n]:
                top = n
        rep.append(top)

    def pos(node):
        if tree.child_count[node] == 0:
            return np.asarray(tree.vertices[tree.leaf_vertex[tree.leaf_lo[node]]], float)
        return np.asarray(tree.position[node], float)

    flipped, degenerate, area, flip_area, out = [], [], 0.0, 0.0, 0
    for t, (a, b, c) in enumerate(tree.faces):
        r = (rep[a], rep[b], rep[c])
        if len(set(r)) < 3:
            continue
        p = np.array([pos(x) for x in r])
        q = np.asarray(tree.vertices[[a, b, c]], float)
        no = np.cross(p[1] - p[0], p[2] - p[0])
        ni = np.cross(q[1] - q[0], q[2] - q[0])
        longest = max(float(np.dot(p[i] - p[i - 1], p[i] - p[i - 1])) for i in range(3))
        dbl = float(np.linalg.norm(no))
        area += dbl
        if dbl <= tol * longest:
            degenerate.append(out)
        elif np.dot(no, ni) < 0:
            flipped.append(out)
            flip_area += dbl
        out += 1
    return flipped, degenerate, (flip_area / area if area > 0 else 0.0), out


def _check_against_reference(tree, unf):
    got = optim.cut_flips(tree, unf)
    unf = unf.unfolded if isinstance(unf, optim.Cut) else unf
    fl, dg, frac, n = _reference(tree, unf)
    assert got.triangles == n == len(optim.extract(tree, unf)[1])
    assert got.indices.tolist() == fl and got.flipped == len(fl)
    assert np.array_equal(got.sources, np.flatnonzero(unf[tree.tri_node])[got.indices])
    assert got.degenerate_indices.tolist() == dg and got.degenerate == len(dg)
    assert got.area_fraction == pytest.approx(frac, rel=1e-9, abs=1e-15)
    return got


def _hand_tree():
    """A flat 4 x 4 grid (normals +z) whose one internal node below the root joins two opposite corners:
    folding it moves both corners to the grid's centre, across their fans (a centroid proxy)."""
    v, f = optim.grid_mesh(4, 4)
    V = v.shape[0]
    far = V - 1  # vertex 0 is (0, 0), V - 1 is (1, 1)
    parent = np.full(V + 2, V + 1, dtype=np.int64)
    parent[[0, far]] = V
    parent[V + 1] = -1
    fn = face_normals(v, f)
    tree = _assemble(v, f.astype(np.int32), None, _vertex_normals(v, f, fn), fn, parent, None, optim.Lighting(),
                     method="octree")
    tree.check()
    return tree


def test_hand_made_fold_across_a_fan_is_detected():
    tree = _hand_tree()
    node = int(np.flatnonzero((tree.child_count > 0) & (tree.parent == 0))[0])
    assert np.allclose(tree.position[node], [0.5, 0.5, 0.0])
    unf = np.zeros(tree.n_nodes, bool)
    unf[0] = True  # the root unfolded, the corner pair folded to its centroid
    got = _check_against_reference(tree, unf)
    v, f, _ = optim.extract(tree, unf)
    n_out = face_normals(v, f)
    # both corner fans (corner 0 has 2 triangles, corner V-1 has 2) turn over; nothing else does
    assert got.flipped == 4 and np.all(n_out[got.indices, 2] < 0)
    assert np.all(np.delete(n_out[:, 2], np.concatenate([got.indices, got.degenerate_indices])) > 0)
    assert 0.0 < got.area_fraction < 1.0
    assert got.fraction == got.flipped / got.triangles
    everything = np.zeros(tree.n_nodes, bool)
    everything[tree.internal] = True
    full = optim.cut_flips(tree, everything)
    assert (full.flipped, full.degenerate, full.triangles) == (0, 0, tree.n_triangles)


def _corrugated_tree():
    v, f = optim.grid_mesh(24, 6)
    v[:, 2] = 0.15 * np.sin(2 * np.pi * 3 * v[:, 0])  # deep folds along x
    return optim.build_tree(v, f, method="qem")


def _fold_one(tree, n):
    """Everything unfolded but node ``n`` and its subtree."""
    unf = np.zeros(tree.n_nodes, bool)
    unf[tree.internal] = True
    sub = (tree.leaf_lo >= tree.leaf_lo[n]) & (tree.leaf_hi <= tree.leaf_hi[n]) & (tree.depth >= tree.depth[n])
    unf[sub] = False
    return unf


def test_folding_one_node_of_a_corrugated_sheet_flips():
    """QEM tree of a deeply folded sheet: folding single nodes across a crease flips triangles; every such
    hand-made cut agrees with the reference and some do flip."""
    tree = _corrugated_tree()
    flipped = 0
    for n in tree.internal[1:][::3]:
        got = _check_against_reference(tree, _fold_one(tree, n))
        flipped += got.flipped > 0
    assert flipped >= 1


def _named_tree(name):
    if name == "corrugated":
        return _corrugated_tree()
    if name == "sphere":
        return optim.build_tree(*optim.bumpy_sphere(2, seed=3, colors=True), method="qem")
    return optim.build_tree(*optim.bumpy_torus(30, 12), method="octree")


@pytest.mark.parametrize("name", ["sphere", "torus", "corrugated"])
def test_full_mesh_has_no_flips(name):
    tree = _named_tree(name)
    everything = np.zeros(tree.n_nodes, bool)
    everything[tree.internal] = True
    cut = optim.budget_cut(tree, optim.repair_monotone(tree, np.ones(tree.n_nodes)), tree.n_triangles)
    for c in (everything, cut):
        got = optim.cut_flips(tree, c)
        assert (got.flipped, got.degenerate, got.triangles, got.area_fraction) == (0, 0, tree.n_triangles, 0.0)
        assert got.indices.dtype == np.int64 and got.indices.size == 0


@pytest.mark.parametrize("method", ["qem", "octree"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_equals_reference_on_random_cuts_of_a_bumpy_sphere(method, seed):
    tree = optim.build_tree(*optim.bumpy_sphere(2, seed=seed), method=method)
    rng = np.random.default_rng(seed)
    keys = optim.repair_monotone(tree, rng.random(tree.n_nodes))
    for frac in (0.0, 0.01, 0.05, 0.1, 0.3, 0.6, 1.0):
        _check_against_reference(tree, optim.budget_cut(tree, keys, int(frac * tree.n_triangles)).unfolded)
    # a mask not closed under ancestors takes extract's fallback path: the same faces are examined
    bad = np.zeros(tree.n_nodes, bool)
    bad[tree.internal[-1]] = True
    assert optim.cut_flips(tree, bad).triangles == len(optim.extract(tree, bad)[1])


def test_accepts_cut_or_mask_and_rejects_bad_input():
    tree = _hand_tree()
    keys = optim.repair_monotone(tree, np.arange(tree.n_nodes, 0, -1.0))
    cut = optim.budget_cut(tree, keys, 10)
    a, b = optim.cut_flips(tree, cut), optim.cut_flips(tree, cut.unfolded)
    assert a.flipped == b.flipped and np.array_equal(a.indices, b.indices)
    empty = optim.cut_flips(tree, np.zeros(tree.n_nodes, bool))
    assert (empty.flipped, empty.triangles, empty.area_fraction, empty.fraction) == (0, 0, 0.0, 0.0)
    with pytest.raises(PlodError, match="cut_flips: unfolded"):
        optim.cut_flips(tree, np.zeros(3, bool))
    with pytest.raises(PlodError, match="cut_flips: unfolded"):
        optim.cut_flips(tree, np.zeros(tree.n_nodes, int))
    for bad in (-1.0, float("nan"), True, "1e-6", None):
        with pytest.raises(PlodError, match="degenerate_tol"):
            optim.cut_flips(tree, cut, degenerate_tol=bad)
    with pytest.raises(AttributeError):
        a.flipped = 3  # frozen


def test_coincident_proxies_are_degenerate_not_flipped():
    """degenerate_tol=0 counts only exactly zero-area outputs; a fold that collapses a triangle onto a
    line is degenerate, not flipped."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0.5, 0.5, 0]], float)
    f = np.array([[0, 1, 4], [1, 3, 4], [3, 2, 4], [2, 0, 4]], np.int32)  # a fan around vertex 4, +z
    V = v.shape[0]
    parent = np.full(V + 2, V + 1, dtype=np.int64)
    parent[[0, 3]] = V  # opposite corners -> centroid (0.5, 0.5) = vertex 4
    parent[V + 1] = -1
    fn = face_normals(v, f)
    tree = _assemble(v, f, None, _vertex_normals(v, f, fn), fn, parent, None, optim.Lighting(), method="octree")
    unf = np.zeros(tree.n_nodes, bool)
    unf[0] = True
    got = _check_against_reference(tree, unf)
    assert got.triangles == 4 and got.degenerate == 4 and got.flipped == 0
    assert optim.cut_flips(tree, unf, degenerate_tol=0.0).degenerate == 4


def test_equals_reference_on_random_cuts_of_a_corrugated_sheet():
    tree = _corrugated_tree()
    flipped = 0
    for seed in range(4):
        keys = optim.repair_monotone(tree, np.random.default_rng(seed).random(tree.n_nodes))
        for frac in (0.05, 0.1, 0.2, 0.4, 0.7):
            cut = optim.budget_cut(tree, keys, int(frac * tree.n_triangles))
            flipped += _check_against_reference(tree, cut).flipped
    assert flipped > 0

"""Hierarchy options (optim/_qem.py, build_tree(proxy=...)): vertex proxies, quadric variants."""

from __future__ import annotations

import numpy as np
import pytest

import optim
from optim._mesh import face_normals
from optim._qem import _boundary_edges, quadric_error, quadric_vertex, vertex_quadrics
from pmetric import PlodError


def _meshes():
    g = optim.grid_mesh(7, 5)
    gv = g[0].copy()
    gv[:, 2] = 0.1 * np.sin(5 * gv[:, 0]) * np.cos(4 * gv[:, 1])  # a bumpy sheet with an open border
    return {"bumpy": optim.bumpy_sphere(2, seed=1, colors=True)[:2], "sheet": (gv, g[1]),
            "torus": optim.bumpy_torus(20, 9, seed=2)}


MESHES = _meshes()


def _supported(tree):
    out = [[] for _ in range(tree.n_nodes)]
    for vtx, leaf in enumerate(tree.vertex_node):
        n = int(leaf)
        while n >= 0:
            out[n].append(vtx)
            n = int(tree.parent[n])
    return [np.array(s) for s in out]


def _node_quadrics(tree):
    q = vertex_quadrics(np.asarray(tree.vertices, float), np.asarray(tree.faces))
    sup = _supported(tree)
    return np.stack([q[s].sum(0) for s in sup]), sup


def _Q(q, x):
    A = np.array([[q[0], q[1], q[2]], [q[1], q[3], q[4]], [q[2], q[4], q[5]]])
    return float(x @ A @ x + 2 * q[6:9] @ x + q[9])


@pytest.mark.parametrize("name", sorted(MESHES))
@pytest.mark.parametrize("method", ["qem", "octree"])
def test_vertex_proxy_is_the_supported_vertex_of_least_quadric_error(name, method):
    v, f = MESHES[name]
    tree = optim.build_tree(v, f, method=method, proxy="vertex")
    tree.check()
    qn, sup = _node_quadrics(tree)
    V = np.asarray(tree.vertices, float)
    for n in tree.internal:
        cand = V[sup[n]]
        hit = np.flatnonzero(np.all(cand.astype(np.float32) == tree.position[n], axis=1))
        assert hit.size >= 1, f"node {n}: position is not one of its supported vertices"
        errs = np.array([_Q(qn[n], x) for x in cand])
        scale = max(abs(float(qn[n][9])), float(np.abs(errs).max()), 1e-300)
        assert errs[hit].min() <= errs.min() + 1e-9 * scale
    # leaves are their vertices; the geometric error is measured from the chosen vertex
    assert np.array_equal(tree.position[tree.vertex_node], V.astype(np.float32))
    for n in tree.internal[:50]:
        d = np.sqrt(((V[sup[n]] - tree.position[n].astype(float)) ** 2).sum(1)).max()
        assert tree.geom_error[n] >= np.float32(d) * (1 - 1e-6)


@pytest.mark.parametrize("name", sorted(MESHES))
def test_proxy_option_changes_only_positions(name):
    v, f = MESHES[name]
    a = optim.build_tree(v, f)
    b = optim.build_tree(v, f, proxy="optimal")
    c = optim.build_tree(v, f, proxy="vertex")
    for k in ("parent", "subtris", "tri_node", "center", "radius", "lum", "normal_mask", "position", "geom_error"):
        assert np.array_equal(getattr(a, k), getattr(b, k)), k  # the default is "optimal", unchanged
    for k in ("parent", "subtris", "tri_node", "center", "radius", "lum", "fold_delta", "normal_mask"):
        assert np.array_equal(getattr(a, k), getattr(c, k)), k
    assert not np.array_equal(a.position, c.position)


def test_bad_proxy_is_a_plod_error():
    v, f = MESHES["sheet"]
    with pytest.raises(PlodError, match="proxy must be one of"):
        optim.build_tree(v, f, proxy="centroid")


def test_quadric_vertex_matches_brute_force():
    rng = np.random.default_rng(4)
    pts = rng.normal(size=(200, 3))
    size = np.array([1, 3, 7, 20, 50, 119])
    lo = np.concatenate([[0], np.cumsum(size)[:-1]])
    q = np.stack([vertex_quadrics(*optim.bumpy_sphere(1, seed=s)).sum(0) for s in range(len(size))])
    got = quadric_vertex(q, pts, lo, size)
    for k in range(len(size)):
        errs = quadric_error(np.repeat(q[k:k + 1], size[k], 0), pts[lo[k]:lo[k] + size[k]])
        assert lo[k] <= got[k] < lo[k] + size[k]
        assert errs[got[k] - lo[k]] <= errs.min() + 1e-9 * np.abs(errs).max()
        assert errs[got[k] - lo[k]] == pytest.approx(_Q(q[k], pts[got[k]]), rel=1e-9, abs=1e-12)
    # ties go to the first candidate
    flat = np.zeros((1, 10))
    assert quadric_vertex(flat, pts, np.array([5]), np.array([9]))[0] == 5


def test_vertex_quadric_options():
    v, f = MESHES["sheet"]
    fn = face_normals(v, f)
    area = vertex_quadrics(v, f, fn)
    assert np.array_equal(area, vertex_quadrics(v, f))
    uni = vertex_quadrics(v, f, fn, weights="uniform")
    # uniform weights: the trace of A is the number of incident triangles
    assert np.allclose(uni[:, 0] + uni[:, 3] + uni[:, 5], np.bincount(f.ravel(), minlength=len(v)))
    tri, a, b = _boundary_edges(f)
    assert tri.size == 2 * (7 + 5)  # the border of a 7 x 5 grid
    bw = vertex_quadrics(v, f, fn, boundary_weight=2.0)
    border = np.unique(np.concatenate([a, b]))
    inner = np.setdiff1d(np.arange(len(v)), border)
    assert np.array_equal(bw[inner], area[inner]) and not np.allclose(bw[border], area[border])
    # the added planes contain the border: every vertex still has zero error at its own position ...
    errs = quadric_error(bw, v)
    assert np.all(np.abs(errs) <= 1e-12 * (1 + np.abs(bw[:, 9])))
    # ... and moving a border vertex off the border (in the sheet, outwards) costs more than before
    corner = int(np.argmin(v[:, 0] + v[:, 1]))
    x = v[corner:corner + 1] + np.array([[-0.05, 0.0, 0.0]])
    assert quadric_error(bw[corner:corner + 1], x)[0] > quadric_error(area[corner:corner + 1], x)[0]
    with pytest.raises(ValueError):
        vertex_quadrics(v, f, fn, weights="angle")


@pytest.mark.parametrize("name", sorted(MESHES))
def test_qem_diagonal_makes_the_hierarchy_independent_of_units(name):
    v, f = MESHES[name]
    a = optim.build_tree(v, f, qem_diagonal=100.0)
    b = optim.build_tree(1000.0 * v + 5.0, f, qem_diagonal=100.0)
    for k in ("parent", "subtris", "tri_node", "num_subtris"):
        assert np.array_equal(getattr(a, k), getattr(b, k)), k
    assert np.allclose(1000.0 * a.position.astype(float) + 5.0, b.position, rtol=1e-5, atol=1e-2)
    assert np.allclose(1000.0 * a.geom_error, b.geom_error, rtol=1e-4)
    a.check()
    # the default (None) computes the order at the mesh's own scale, as before
    d = optim.build_tree(v, f)
    assert np.array_equal(d.parent, optim.build_tree(v, f, qem_diagonal=None).parent)
    diag = float(np.linalg.norm(v.max(0) - v.min(0)))
    assert np.array_equal(d.parent, optim.build_tree(v, f, qem_diagonal=diag).parent)


def test_qem_diagonal_rejects_bad_values():
    v, f = MESHES["sheet"]
    for bad in (0, -1.0, float("nan"), float("inf"), True, "100"):
        with pytest.raises(PlodError, match="qem_diagonal"):
            optim.build_tree(v, f, qem_diagonal=bad)

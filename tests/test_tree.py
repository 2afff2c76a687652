"""The vertex tree (optim/_tree.py, _build.py, _levels.py, _octree.py, _qem.py) against slow brute-force references."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import optim
import optim._build
import pmetric
from optim._octree import morton_codes, octree_parents

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "meshes"
TET_V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
TET_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def _meshes():
    v, f = optim.icosphere(2)
    g = optim.grid_mesh(7, 5)
    b = optim.bumpy_sphere(1, seed=1, colors=True)
    return {"tet": (TET_V, TET_F, None), "ico2": (v, f, None), "grid": (*g, None), "bumpy": b}


MESHES = _meshes()
CASES = [(m, k) for m in MESHES for k in ("octree", "qem")]


@pytest.fixture(scope="module")
def trees():
    return {(m, k): optim.build_tree(*MESHES[m], method=k) for m, k in CASES}


def _ancestors(tree, n):
    out = [n]
    while tree.parent[out[-1]] >= 0:
        out.append(int(tree.parent[out[-1]]))
    return out  # n, parent, ..., root


def _supported(tree):
    """Brute force: input vertices below every node."""
    sup = [[] for _ in range(tree.n_nodes)]
    for vtx, leaf in enumerate(tree.vertex_node):
        for a in _ancestors(tree, int(leaf)):
            sup[a].append(vtx)
    return [np.array(s, dtype=int) for s in sup]


@pytest.mark.parametrize("mesh, method", CASES)
def test_structure(trees, mesh, method):
    t = trees[(mesh, method)]
    v, f, c = MESHES[mesh]
    t.check()
    N = t.n_nodes
    assert t.parent[0] == -1 and np.all(t.parent[1:] < np.arange(1, N))
    assert np.all(t.depth[1:] == t.depth[t.parent[1:]] + 1) and t.depth[0] == 0
    for n in range(N):  # contiguous children
        kids = np.flatnonzero(t.parent == n)
        np.testing.assert_array_equal(kids, np.arange(t.child_start[n], t.child_start[n] + t.child_count[n]))
    leaves = np.flatnonzero(t.child_count == 0)
    np.testing.assert_array_equal(np.sort(t.vertex_node), leaves)  # the leaves are exactly the vertices
    assert np.all(t.child_count[t.child_count > 0] >= 2)  # no single-child chains
    np.testing.assert_array_equal(t.vertices, v)
    np.testing.assert_array_equal(t.faces, f)
    assert t.faces.dtype == np.int32 and t.parent.dtype == np.int32 and t.normal_mask.shape == (N, 48)
    assert t.nbytes / t.n_triangles < 200 * (1 if t.n_triangles > 1000 else 5)
    if method == "qem" and mesh != "tet":
        # edge collapses give binary nodes below the octree top
        assert np.mean(t.child_count[t.child_count > 0] == 2) > 0.9


@pytest.mark.parametrize("mesh, method", CASES)
def test_subtris_owner_is_the_fold_that_removes_the_triangle(trees, mesh, method):
    """tri_node is the deepest pairwise LCA; subtris partition the triangles."""
    t = trees[(mesh, method)]
    T = t.n_triangles
    np.testing.assert_array_equal(np.sort(t.subtris), np.arange(T))
    np.testing.assert_array_equal(np.diff(t.subtri_start), t.num_subtris)
    anc = {n: _ancestors(t, n) for n in range(t.n_nodes)}
    for ti, tri in enumerate(t.faces):
        leaves = [int(t.vertex_node[x]) for x in tri]
        lcas = []
        for a, b in ((0, 1), (1, 2), (0, 2)):
            sb = set(anc[leaves[b]])
            lcas.append(next(x for x in anc[leaves[a]] if x in sb))
        assert t.tri_node[ti] == max(lcas, key=lambda x: t.depth[x])
        s = t.subtri_start[t.tri_node[ti]]
        assert ti in t.subtris[s:s + t.num_subtris[t.tri_node[ti]]]


@pytest.mark.parametrize("mesh, method", CASES)
def test_node_attributes_brute_force(trees, mesh, method):
    t = trees[(mesh, method)]
    v, f, c = MESHES[mesh]
    sup = _supported(t)
    lum_v = optim.vertex_luminance(v, f, c)
    cells = optim.normal_cells(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]))
    bits = np.unpackbits(t.normal_mask, axis=1, bitorder="little")  # (N, 384)
    for n in range(t.n_nodes):
        s = sup[n]
        pts = v[s]
        assert np.all(np.linalg.norm(pts - t.center[n], axis=1) <= t.radius[n])  # sphere holds them
        np.testing.assert_allclose(t.radius[n], np.linalg.norm(pts - t.center[n], axis=1).max(), rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(t.center[n], 0.5 * (pts.min(0) + pts.max(0)), rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(t.geom_error[n], np.linalg.norm(pts - t.position[n], axis=1).max(), rtol=1e-5,
                                   atol=1e-6)
        lo = min(lum_v[s].min(), t.lum[n])
        hi = max(lum_v[s].max(), t.lum[n])
        assert t.lum_min[n] == pytest.approx(lo, abs=1e-6) and t.lum_max[n] == pytest.approx(hi, abs=1e-6)
        if t.child_count[n]:
            assert t.fold_delta[n] == pytest.approx(max(hi - t.lum[n], t.lum[n] - lo), abs=1e-6)
        else:
            assert t.fold_delta[n] == 0 and t.lum[n] == pytest.approx(lum_v[s[0]])
            np.testing.assert_array_equal(t.position[n], v[s[0]].astype(np.float32))
        # normal mask = cells of every triangle with a corner among the supported vertices
        touched = np.isin(f, s).any(axis=1)
        want = np.zeros(384, bool)
        want[cells[touched]] = True
        np.testing.assert_array_equal(bits[n].astype(bool), want)
        assert t.min_vertex[n] == s.min()
        np.testing.assert_array_equal(np.sort(t.leaf_vertex[t.leaf_lo[n]:t.leaf_hi[n]]), np.sort(s))
        if c is not None:
            np.testing.assert_allclose(t.color[n], c[s].mean(0), atol=1e-6)


def test_octree_cube_corners_closed_form():
    """8 cube corners split at the top octree level: one root with 8 leaf children."""
    pts = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    parent, level = octree_parents(pts)
    assert parent.shape == (9,) and np.all(parent[:8] == 8) and parent[8] == -1 and list(level) == [0]
    # two clusters of 2 far apart: root + 2 internal nodes (tight: chains collapsed)
    pts = np.array([[0, 0, 0], [1e-3, 0, 0], [1, 1, 1], [1, 1, 1 - 1e-3]])
    parent, level = octree_parents(pts)
    assert parent.shape == (7,)
    root = int(np.flatnonzero(parent == -1)[0])
    assert parent[0] == parent[1] != parent[2] == parent[3]
    assert parent[parent[0]] == root == parent[parent[2]]
    # duplicate points share a bottom cell (level 21)
    parent, level = octree_parents(np.array([[0.0, 0, 0], [0, 0, 0], [1, 1, 1]]))
    assert sorted(level.tolist()) == [0, 21]


def test_morton_codes_interleave():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    c = morton_codes(pts)
    top = np.uint64(60)
    assert [int(x >> top) for x in c] == [0, 4, 2, 1]  # x is the high bit of each 3-bit digit


def test_luminance_from_colours_and_prelighting():
    v, f = optim.grid_mesh(2, 2)
    c = np.zeros((9, 3), np.float32)
    c[1] = 1.0
    c[2] = 0.5
    c[3] = [1, 0, 0]
    lum = optim.vertex_luminance(v, f, c)
    srgb = ((0.5 + 0.055) / 1.055) ** 2.4
    np.testing.assert_allclose(lum[:4], [0.0, 1.0, srgb, 0.2126], rtol=1e-6)
    up = optim.Lighting(direction=(0, 0, 2), ambient=0.1, diffuse=0.9)
    np.testing.assert_allclose(optim.vertex_luminance(v, f, lighting=up), 1.0, rtol=1e-6)
    side = optim.Lighting(direction=(1, 0, 0), ambient=0.1, diffuse=0.9)
    np.testing.assert_allclose(optim.vertex_luminance(v, f, lighting=side), 0.1, rtol=1e-6)
    tilt = {"direction": (0, 1, 1), "ambient": 0.0, "diffuse": 1.0}
    np.testing.assert_allclose(optim.vertex_luminance(v, f, lighting=tilt), np.sqrt(0.5), rtol=1e-6)
    below = optim.Lighting((0, 0, -1), 0.2, 0.8)
    np.testing.assert_allclose(optim.vertex_luminance(v, f, lighting=below), 0.2, rtol=1e-6)
    with pytest.raises(ValueError, match="direction"):
        optim.Lighting(direction=(0, 0, 0))
    with pytest.raises(ValueError, match="unknown fields"):
        optim.Lighting.coerce({"colour": 1})


def test_luminance_matches_pmetric_display():
    pm = pytest.importorskip("pmetric")
    if not hasattr(pm, "srgb_to_linear") or not hasattr(pm, "relative_luminance"):
        pytest.skip("pmetric display helpers not exported yet")
    c = np.random.default_rng(0).random((50, 3)).astype(np.float32)
    ref = np.asarray(pm.relative_luminance(pm.srgb_to_linear(c.astype(np.float64))))
    np.testing.assert_allclose(optim.vertex_luminance(None, None, c), ref, rtol=1e-5, atol=1e-7)


def test_normal_cells():
    n = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, 0, -1], [1, 0.999, -0.5]])
    cells = optim.normal_cells(n)
    assert cells[0] == 0 * 64 + 4 * 8 + 4 and cells[1] == 64 + 36 and cells[2] == 128 + 36 and cells[3] == 5 * 64 + 36
    # [1, .999, -.5]: face +x, u = y = .999 -> 7, v = z = -.5 -> 2
    assert cells[4] == 0 * 64 + 2 * 8 + 7
    np.testing.assert_array_equal(optim.normal_cells(optim.normal_cell_directions()), np.arange(384))
    corners = optim.normal_cell_directions(corners=True)
    assert corners.shape == (384, 4, 3)
    np.testing.assert_allclose(np.linalg.norm(corners, axis=2), 1.0)


def test_save_load_roundtrip_and_errors(trees, tmp_path):
    t = trees[("bumpy", "qem")]
    p = t.save(tmp_path / "t.npz")
    t2 = optim.load_tree(p)
    for k in ("parent", "subtris", "normal_mask", "position", "color", "colors", "lum", "leaf_vertex", "min_vertex"):
        np.testing.assert_array_equal(getattr(t2, k), getattr(t, k))
    assert t2.method == "qem" and t2.lighting == t.lighting
    t3 = optim.load_tree(trees[("grid", "octree")].save(tmp_path / "g.npz"))
    assert t3.color is None and t3.colors is None
    with pytest.raises(ValueError, match="refusing to overwrite"):
        t.save(p, protect=(p,))
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(ValueError, match="not a plod vertex tree"):
        optim.load_tree(tmp_path / "other.npz")
    (tmp_path / "junk.npz").write_bytes(b"junk")
    with pytest.raises(ValueError, match="junk.npz"):
        optim.load_tree(tmp_path / "junk.npz")
    assert sorted(x.name for x in tmp_path.iterdir()) == ["g.npz", "junk.npz", "other.npz", "t.npz"]


def test_mesh_hash():
    v, f = optim.icosphere(1)
    h = optim.mesh_hash(v, f, None, "qem", None)
    assert h == optim.mesh_hash(v.copy(), f.astype(np.int64), None, "qem", optim.Lighting())
    assert h != optim.mesh_hash(v, f, None, "octree", None)
    assert h != optim.mesh_hash(v, f, None, "qem", {"ambient": 0.3})
    v2 = v.copy()
    v2[0, 0] += 1e-9
    assert h != optim.mesh_hash(v2, f, None, "qem", None)
    c = np.zeros_like(v, dtype=np.float32)
    hc = optim.mesh_hash(v, f, c, "qem", None)
    assert hc != h and hc == optim.mesh_hash(v, f, c, "qem", {"ambient": 0.3})  # lighting unused with colours


def test_build_tree_bad_input_and_report():
    with pytest.raises(ValueError, match="method"):
        optim.build_tree(TET_V, TET_F, method="kd")
    with pytest.raises(ValueError, match="NaN"):
        optim.build_tree(np.where(TET_V == 1, np.nan, TET_V), TET_F)
    with pytest.raises(ValueError, match="out of range"):
        optim.build_tree(TET_V, TET_F + 1)
    f = np.concatenate([TET_F, TET_F[:1, ::-1], [[2, 2, 3]]])
    t = optim.build_tree(TET_V, f, method="octree")
    assert t.n_triangles == 4 and t.mesh_report["dropped_duplicate"] == 1 and t.mesh_report["dropped_degenerate"] == 1


def test_nonmanifold_and_disconnected_qem():
    """A triangle soup: non-manifold fan + separate component; qem tops the forest with an octree."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [5, 5, 5], [6, 5, 5], [5, 6, 5]], float)
    f = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4], [5, 6, 7]])
    for method in ("qem", "octree"):
        t = optim.build_tree(v, f, method=method)
        t.check()
        assert t.n_vertices == 8 and t.num_subtris.sum() == 4


@pytest.mark.shared
@pytest.mark.skipif(not (SHARED / "cow.obj").exists(), reason="needs ../shared")
def test_shared_cow_both_methods():
    v, f, _ = optim.load_mesh(SHARED / "cow.obj")
    for method in ("octree", "qem"):
        t = optim.build_tree(v, f, method=method)
        t.check()
        assert t.n_triangles == 5804 - t.mesh_report["dropped_degenerate"] - t.mesh_report["dropped_duplicate"]
        assert t.nbytes / t.n_triangles <= 200
        # the root's sphere bounds the whole model
        assert np.all(np.linalg.norm(t.vertices - t.center[0], axis=1) <= t.radius[0])


def test_quadric_optimal_matches_linear_solve():
    from optim._qem import quadric_optimal

    rng = np.random.default_rng(3)
    B = rng.normal(size=(50, 3, 3))
    A = B @ B.transpose(0, 2, 1)
    b = rng.normal(size=(50, 3))
    m = rng.normal(size=(50, 3))
    q = np.concatenate([A[:, 0, :], A[:, 1, 1:2], A[:, 1, 2:3], A[:, 2, 2:3], b, np.zeros((50, 1))], 1)
    lam = 1e-3 * np.trace(A, axis1=1, axis2=2) / 3
    want = np.linalg.solve(A + lam[:, None, None] * np.eye(3), (lam[:, None] * m - b)[..., None])[..., 0]
    np.testing.assert_allclose(quadric_optimal(q, m), want, rtol=1e-8, atol=1e-10)
    np.testing.assert_array_equal(quadric_optimal(np.zeros((2, 10)), m[:2]), m[:2])  # no planes: centroid


def test_qem_proxies_on_a_flat_grid_are_centroids(trees):
    """All planes are z = 0: the quadric pins z to 0 and the regulariser picks the centroid in x, y."""
    t = trees[("grid", "qem")]
    v = MESHES["grid"][0]
    sup = _supported(t)
    for n in np.flatnonzero(t.child_count > 0):
        np.testing.assert_allclose(t.position[n], v[sup[n]].mean(0), atol=1e-6)


def test_progress_callback_builds_the_same_tree(capsys):
    v, f = optim.icosphere(1)
    calls = []
    a = optim.build_tree(v, f, method="octree", progress=lambda stage, done, total: calls.append((stage, done, total)))
    b = optim.build_tree(v, f, method="octree")
    np.testing.assert_array_equal(a.parent, b.parent)
    np.testing.assert_array_equal(a.tri_node, b.tri_node)
    done = [d for _, d, _ in calls]
    assert done == sorted(done) and done[0] == 0 and calls[-1] == ("done", 5, 5)
    assert {t for _, _, t in calls} == {5}
    assert [s for s, _, _ in calls[:-1]] == list(optim._build.BUILD_STAGES)
    assert capsys.readouterr() == ("", "")  # the library prints nothing
    with pytest.raises(pmetric.PlodError, match="progress must be"):
        optim.build_tree(v, f, method="octree", progress=True)


def test_rich_progress_renders_the_build_callback():
    import io

    from rich.console import Console

    from experiments._progress import call_with_progress, rich_progress

    v, f = optim.icosphere(1)
    buf = io.StringIO()
    with rich_progress("build", console=Console(file=buf, force_terminal=True), transient=False) as cb:
        assert callable(cb)
        t = optim.build_tree(v, f, method="octree", progress=cb)
    assert "build" in buf.getvalue() and t.n_vertices == len(v)
    with rich_progress(enabled=False) as cb:
        assert cb is None
    t2 = call_with_progress(optim.build_tree, v, f, method="octree", progress=False)
    np.testing.assert_array_equal(t2.parent, t.parent)


def test_tree_is_immutable():
    v, f = optim.icosphere(1)
    t = optim.build_tree(v, f, method="octree")
    assert t.method == "octree"
    with pytest.raises(dataclasses.FrozenInstanceError):
        t.method = "qem"
    with pytest.raises(dataclasses.FrozenInstanceError):
        t.radius = t.radius * 2
    for name in ("parent", "radius", "normal_mask", "vertices", "faces"):
        with pytest.raises(ValueError, match="read-only"):
            getattr(t, name)[0] = 0
    with pytest.raises(ValueError, match="read-only"):
        t.internal[0] = 1
    assert v.flags.writeable  # the caller's arrays are left writable


def test_derived_cache_returns_the_same_object():
    v, f = optim.icosphere(1)
    t = optim.build_tree(v, f, method="octree")
    calls = []
    first = t.derived("test.thing", lambda: calls.append(1) or object())
    assert t.derived("test.thing", lambda: calls.append(1) or object()) is first and calls == [1]
    assert t.internal is t.internal and t.levels is t.levels and t.level_start is t.level_start
    np.testing.assert_array_equal(t.level_start, np.searchsorted(t.depth, np.arange(int(t.depth[-1]) + 2)))
    cut = optim.budget_cut(t, optim.repair_monotone(t, t.radius), 10)
    optim.extract(t, cut)
    assert {"cut.internal_parent_pos", "cut.extract_index_fast"} <= set(t._derived)


def test_tree_build_errors_are_plod_errors():
    v, f = optim.icosphere(1)
    with pytest.raises(pmetric.PlodError, match="method must be one of"):
        optim.build_tree(v, f, method="kmeans")
    with pytest.raises(pmetric.PlodError, match="direction"):
        optim.Lighting(direction=(0, 0, 0))


@pytest.mark.parametrize("method", ["octree", "qem"])
def test_tiny_and_coincident_meshes(method):
    one = optim.build_tree(TET_V[:3], [[0, 1, 2]], method=method)  # a single triangle
    one.check()
    assert one.num_subtris.sum() == 1 and one.n_vertices == 3
    with pytest.raises(ValueError, match="all vertices coincide"):  # PlodError is a ValueError
        optim.build_tree(np.zeros((3, 3)), [[0, 1, 2]], method=method)  # no surface: refused, not "imperceptible"
    v, f = optim.icosphere(1)  # two coincident copies: separate vertices at identical positions
    t = optim.build_tree(np.concatenate([v, v]), np.concatenate([f, f + len(v)]), method=method)
    t.check()
    assert t.n_vertices == 2 * len(v) and t.num_subtris.sum() == 2 * len(f)


def test_load_tree_rejects_inconsistent_arrays(trees, tmp_path):
    t = trees[("ico2", "octree")]
    p = t.save(tmp_path / "t.npz")
    with np.load(p) as z:
        data = {k: z[k] for k in z.files}
    data["radius"] = data["radius"][:-1]
    np.savez(tmp_path / "bad.npz", **data)
    with pytest.raises(ValueError, match="radius.*corrupt"):
        optim.load_tree(tmp_path / "bad.npz")


@pytest.mark.parametrize("edit", ["parent", "vertex_node", "subtris", "faces"])
def test_load_tree_rejects_arrays_of_the_right_shape_that_are_no_tree(trees, tmp_path, edit):
    """A file whose arrays have the right shapes but do not form a tree (a damaged or edited cache entry)
    is a one-line PlodError naming the file (before: an IndexError traceback in the first score)."""
    t = trees[("ico2", "octree")]
    p = t.save(tmp_path / "t.npz")
    with np.load(p) as z:
        data = {k: z[k].copy() for k in z.files}
    data[edit].flat[min(5, data[edit].size - 1)] = 10**6
    np.savez(tmp_path / "bad.npz", **data)
    with pytest.raises(ValueError, match=r"bad\.npz.*not a valid vertex tree") as exc:
        optim.load_tree(tmp_path / "bad.npz")
    assert "\n" not in str(exc.value)
    optim.load_tree(p).check()  # the original file loads


def test_load_tree_detects_damaged_bytes(trees, tmp_path):
    """A byte changed anywhere in a tree file's arrays (disk damage in a cache entry) is caught by the .npz
    members' CRC-32 and refused naming the file, even where the structure would still pass check()
    (a coordinate or a colour): the tree cache needs no digest of its own."""
    t = trees[("ico2", "octree")]
    raw = bytearray(t.save(tmp_path / "t.npz").read_bytes())
    for at in (len(raw) // 4, len(raw) // 2, 3 * len(raw) // 4):
        bad = bytearray(raw)
        bad[at] ^= 0x10
        (tmp_path / "bad.npz").write_bytes(bytes(bad))
        with pytest.raises(ValueError, match=r"bad\.npz.*(CRC|corrupt|not a valid|cannot read)"):
            optim.load_tree(tmp_path / "bad.npz")

"""Scale invariance: the same mesh in other units (x1e-6 .. x1e6) gives the same vertex tree and,
framed the same way, the same perceptual keys and cuts (issue: QEM order depended on the units)."""

from __future__ import annotations

import numpy as np
import pytest

import optim
from pmetric import PlodError

#: powers of two scale float coordinates exactly: the trees must be identical
EXACT = (2.0 ** -20, 2.0 ** -10, 1.0, 2.0 ** 10, 2.0 ** 20)
#: decimal units round the float32 coordinates meshoptimizer reads (greedy collapse orders then differ
#: slightly): the cuts must agree
DECIMAL = (1e-6, 1e-3, 1e3, 1e6)


@pytest.fixture(scope="module")
def mesh():
    return optim.bumpy_sphere(3, seed=2, amplitude=0.12)


def _run(v, f, s, method):
    tree = optim.build_tree(v * s, f, method=method)
    view = optim.View.framing(tree.vertices, 30.0, direction=(0.3, 0.4, 0.8), lighting=optim.Lighting())
    keys = optim.score(tree, view)
    return tree, keys, optim.imperceptible_cut(tree, view), optim.budget_cut(tree, keys, 200)


@pytest.mark.parametrize("method", ["meshopt", "qem", "hybrid"])
def test_tree_and_keys_do_not_depend_on_units(mesh, method):
    v, f = mesh
    tree0, keys0, imp0, bud0 = _run(v, f, 1.0, method)
    for s in EXACT:
        tree, keys, imp, bud = _run(v, f, s, method)
        np.testing.assert_array_equal(tree.parent, tree0.parent, err_msg=f"tree at scale {s:g}")
        np.testing.assert_allclose(keys, keys0, rtol=2e-3, atol=1e-4, err_msg=f"keys at scale {s:g}")
        assert imp.triangles == imp0.triangles and np.array_equal(bud.unfolded, bud0.unfolded)
    for s in DECIMAL:
        tree, keys, imp, bud = _run(v, f, s, method)
        assert abs(imp.triangles - imp0.triangles) <= 0.03 * imp0.triangles, f"imperceptible cut at {s:g}"
        assert abs(np.median(keys[tree.internal]) / np.median(keys0[tree0.internal]) - 1) < 0.05
        assert bud.triangles <= 200 and abs(bud.triangles - bud0.triangles) <= 4


#: offsets far from the mesh's size (its diagonal is about 2.5): multiples of the origin grid (4)
FAR = ((1e7, -5e6, 0.0), (0.0, 0.0, -2.0 ** 31), (4096.0, 4096.0, 4096.0))


@pytest.mark.parametrize("method", ["meshopt", "qem", "octree", "hybrid"])
def test_a_far_mesh_gives_the_tree_keys_and_cuts_of_the_same_mesh_near_0(mesh, method):
    """Translation: the mesh moved far from 0 for its size (float32 coordinates kept about 1 unit of
    precision at 1e7: other tree, keys and cuts) builds the same tree relative to its origin, the same
    keys and cuts for the same view, and extracts the same mesh moved back exactly."""
    v, f = mesh
    v = np.round(v * 2.0 ** 20) / 2.0 ** 20  # on a grid: v + offset is exact
    near = optim.build_tree(v, f, method=method)
    assert not near.origin.any() and near.local_vertices is near.vertices
    for off in FAR:
        off = np.array(off)
        far = optim.build_tree(v + off, f, method=method)
        np.testing.assert_array_equal(far.origin, off)
        np.testing.assert_array_equal(far.vertices, v + off)
        np.testing.assert_array_equal(far.local_vertices, v)
        for k in ("parent", "position", "center", "radius", "geom_error", "normal_mask"):
            np.testing.assert_array_equal(getattr(far, k), getattr(near, k), err_msg=f"{k} at offset {off}")
        for moving in (False, True):
            views = []
            for o in (np.zeros(3), off):
                kw = dict(direction=(0.3, 0.4, 0.8), lighting=optim.Lighting(), gaze=np.array([[700.0, 400.0]]))
                prev = optim.View.framing(v + o, 30.0, **kw) if moving else None
                kw["direction"] = (0.32, 0.4, 0.79)
                views.append(optim.View.framing(v + o, 30.0, previous=prev, dt_s=1 / 60 if moving else None, **kw))
            k0, k1 = (optim.score(t, w) for t, w in ((near, views[0]), (far, views[1])))
            np.testing.assert_allclose(k1, k0, rtol=1e-5, atol=0.0, err_msg=f"keys at offset {off}")
            c0, c1 = (optim.imperceptible_cut(t, w) for t, w in ((near, views[0]), (far, views[1])))
            assert c0.triangles == c1.triangles
        b0, b1 = optim.budget_cut(near, k0, 300), optim.budget_cut(far, k0, 300)
        (v0, f0, _), (v1, f1, _) = optim.extract(near, b0), optim.extract(far, b1)
        np.testing.assert_array_equal(f1, f0)
        np.testing.assert_array_equal(v1, v0 + off)  # proxies and input vertices, moved back exactly


def test_origin_survives_save_and_load_and_old_files_read_with_origin_0(mesh, tmp_path):
    import json

    v, f = mesh
    v = np.round(v * 2.0 ** 20) / 2.0 ** 20
    far = optim.build_tree(v + np.array([0.0, 2.0 ** 30, 0.0]), f, method="octree")
    back = optim.load_tree(far.save(tmp_path / "far.npz"))
    np.testing.assert_array_equal(back.origin, far.origin)
    np.testing.assert_array_equal(back.vertices, far.vertices)
    near = optim.build_tree(v, f, method="octree")
    with np.load(near.save(tmp_path / "near.npz")) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(str(arrays.pop("__meta__")))
    meta["format"] = "plod-vertex-tree-1"  # written before trees had an origin
    del meta["origin"]
    np.savez(tmp_path / "old.npz", __meta__=np.array(json.dumps(meta)), **arrays)
    old = optim.load_tree(tmp_path / "old.npz")
    assert not old.origin.any()
    np.testing.assert_array_equal(old.position, near.position)
    meta["format"] = "plod-vertex-tree-2"
    for bad in ([1.0, 2.0], ["a", 0.0, 0.0], [float("nan"), 0.0, 0.0], "far"):  # a damaged origin: one line
        meta["origin"] = bad
        np.savez(tmp_path / "bad.npz", __meta__=np.array(json.dumps(meta)), **arrays)
        with pytest.raises(PlodError, match=r"bad\.npz': tree file \(corrupt\?\): origin must be 3 finite numbers"):
            optim.load_tree(tmp_path / "bad.npz")


@pytest.mark.parametrize("off", [(1000.0, -500.0, 250.0), (1e7, -5e6, 2.5e6), (-3e9, 0.0, 0.0)])
def test_a_far_mesh_off_the_grid_cuts_like_the_mesh_near_0(mesh, off):
    """Offsets that do not keep the coordinates exact round the relative float32 positions slightly
    differently (like the decimal units above): the cuts must agree (before the origin, at 1e7 the
    imperceptible cut kept 1.66x the triangles and the budget cut's distance was 7x)."""
    v, f = mesh
    t0, _, imp0, bud0 = _run(v, f, 1.0, "meshopt")
    tree = optim.build_tree(v + np.array(off), f)
    assert tree.origin.any()
    view = optim.View.framing(tree.vertices, 30.0, direction=(0.3, 0.4, 0.8), lighting=optim.Lighting())
    keys = optim.score(tree, view)
    imp, bud = optim.imperceptible_cut(tree, view), optim.budget_cut(tree, keys, 200)
    assert abs(imp.triangles - imp0.triangles) <= 0.03 * imp0.triangles
    assert bud.triangles <= 200 and abs(bud.distance / bud0.distance - 1) < 0.1

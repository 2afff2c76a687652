"""Mesh input/output, validation policy and procedural meshes (optim/_mesh.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import optim
import optim._mesh
import pmetric

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "meshes"


def _edges(f):
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    return np.unique(e, axis=0, return_counts=True)


def _signed_volume(v, f):
    return float(np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6.0)


@pytest.mark.parametrize("n", [0, 1, 2, 3])
def test_icosphere_counts_closed_outward(n):
    v, f = optim.icosphere(n)
    assert f.shape == (20 * 4**n, 3) and v.shape == (10 * 4**n + 2, 3)
    assert f.dtype == np.int32 and v.dtype == np.float64
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-12)
    e, counts = _edges(f)
    assert np.all(counts == 2)  # closed 2-manifold
    assert v.shape[0] - e.shape[0] + f.shape[0] == 2  # Euler characteristic of a sphere
    vol = _signed_volume(v, f)
    assert 0 < vol < 4 / 3 * np.pi  # outward, inscribed in the unit sphere
    if n == 3:
        assert vol == pytest.approx(4 / 3 * np.pi, rel=0.02)


def test_grid_counts_and_area():
    v, f = optim.grid_mesh(4, 3, size=(2.0, 1.5))
    assert v.shape == (20, 3) and f.shape == (24, 3)
    cr = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert np.all(cr[:, 2] > 0)  # every face faces +z
    assert 0.5 * cr[:, 2].sum() == pytest.approx(3.0)
    with pytest.raises(ValueError, match="nx and ny"):
        optim.grid_mesh(0, 3)


def test_bumpy_sphere_deterministic_colours_and_size_formula():
    v1, f1, c1 = optim.bumpy_sphere(2, seed=3, colors=True)
    v2, f2, c2 = optim.bumpy_sphere(2, seed=3, colors=True)
    v3, _ = optim.bumpy_sphere(2, seed=4)
    np.testing.assert_array_equal(v1, v2)
    np.testing.assert_array_equal(c1, c2)
    assert not np.allclose(v1, v3)
    assert c1.shape == v1.shape and c1.dtype == np.float32 and c1.min() >= 0 and c1.max() <= 1
    r = np.linalg.norm(v1, axis=1)
    assert r.min() >= 1 - 0.08 - 1e-12 and r.max() <= 1 + 0.08 + 1e-12
    assert 20 * 4**8 >= 1_000_000  # subdivisions=8 is the >= 1M-triangle setting (icosphere formula above)


# ---------------------------------------------------------------------------------------------- validation

TET_V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
TET_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def test_validate_clean_mesh_unchanged():
    v, f, c, rep = optim.validate_mesh(TET_V, TET_F)
    np.testing.assert_array_equal(v, TET_V)
    np.testing.assert_array_equal(f, TET_F)
    assert c is None and not rep.changed and rep.summary() == "clean"
    assert f.dtype == np.int32


@pytest.mark.parametrize(
    "vertices, faces, match",
    [
        (np.array([[0, 0, np.nan], [1, 0, 0], [0, 1, 0]]), [[0, 1, 2]], "NaN or infinite.*vertex 0"),
        (np.array([[0, 0, 0], [np.inf, 0, 0], [0, 1, 0]]), [[0, 1, 2]], "NaN or infinite.*vertex 1"),
        (TET_V, [[0, 1, 4]], "out of range"),
        (TET_V, [[0, -1, 2]], "out of range"),
        (TET_V, np.zeros((0, 3), int), "empty mesh"),
        (np.zeros((0, 3)), [[0, 1, 2]], "empty mesh"),
        (TET_V, [[0, 1, 2, 3]], "triangles"),
        (TET_V[:, :2], [[0, 1, 2]], r"vertices must have shape \(V, 3\)"),
        (TET_V, [[0.5, 1, 2]], "integers"),
        (TET_V, [[0, 0, 1], [1, 1, 2]], "no non-degenerate faces"),
    ],
)
def test_validate_errors(vertices, faces, match):
    with pytest.raises(ValueError, match=match):
        optim.validate_mesh(vertices, faces, name="m.ply")


def test_validate_error_names_mesh():
    with pytest.raises(ValueError, match="^bunny.obj: "):
        optim.validate_mesh(TET_V, [[0, 1, 9]], name="bunny.obj")


def test_validate_drops_degenerate_duplicate_unreferenced():
    v = np.concatenate([TET_V, [[5.0, 5, 5]]])  # vertex 4 unreferenced
    f = np.array([[0, 2, 1], [0, 1, 3], [1, 1, 2], [2, 1, 0], [0, 3, 2], [1, 2, 3], [3, 0, 1]])
    c = np.tile(np.array([[0.1, 0.2, 0.3]], np.float32), (5, 1))
    c[4] = 1.0
    v2, f2, c2, rep = optim.validate_mesh(v, f, c)
    assert rep.dropped_degenerate == 1  # [1, 1, 2]
    assert rep.dropped_duplicate == 2  # [2, 1, 0] reverses the first, [3, 0, 1] rotates the second
    assert rep.dropped_unreferenced_vertices == 1
    np.testing.assert_array_equal(f2, TET_F)
    np.testing.assert_array_equal(v2, TET_V)
    np.testing.assert_array_equal(c2, np.tile(np.array([[0.1, 0.2, 0.3]], np.float32), (4, 1)))
    assert rep.changed and "duplicate" in rep.summary()


def test_validate_nonmanifold_allowed_zero_area_kept():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [2, 0, 0]], float)
    f = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4], [0, 1, 5]])  # edge 0-1 in 4 triangles; [0,1,5] collinear
    v2, f2, _, rep = optim.validate_mesh(v, f)
    assert f2.shape == (4, 3)
    assert rep.nonmanifold_edges == 1 and rep.zero_area == 1 and not rep.changed


def test_validate_colours():
    c8 = np.full((4, 4), 255, np.uint8)
    _, _, c, _ = optim.validate_mesh(TET_V, TET_F, c8)
    assert c.shape == (4, 3) and c.dtype == np.float32 and np.all(c == 1.0)
    with pytest.raises(ValueError, match="colors must have shape"):
        optim.validate_mesh(TET_V, TET_F, np.zeros((3, 3)))
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        optim.validate_mesh(TET_V, TET_F, np.full((4, 3), 2.0))


def test_validate_returns_one_named_type():
    """validate_mesh always returns a ValidatedMesh (4 fields, unpacks as before); build_tree's face
    normals come from a separate function, not from a hidden flag."""
    from optim._mesh import validated_mesh_and_normals

    out = optim.validate_mesh(TET_V, TET_F, name="tet")
    assert isinstance(out, optim.ValidatedMesh) and len(out) == 4
    assert out.report.faces_in == 4 and out.colors is None and out.faces.dtype == np.int32
    with pytest.raises(TypeError):
        optim.validate_mesh(TET_V, TET_F, _normals=True)
    mesh, normals = validated_mesh_and_normals(TET_V, TET_F)
    np.testing.assert_array_equal(mesh.faces, out.faces)
    np.testing.assert_array_equal(normals, optim._mesh.face_normals(out.vertices, out.faces))
    with pytest.raises(pmetric.PlodError, match="out of range"):
        optim.validate_mesh(TET_V, [[0, 1, 9]])


def test_bumpy_torus_is_exported():
    assert "bumpy_torus" in optim._shapes.__all__


# ---------------------------------------------------------------------------------------------- files


@pytest.mark.parametrize("ext", ["ply", "obj", "off", "glb"])
def test_save_load_roundtrip(tmp_path, ext):
    v, f = optim.icosphere(1)
    colors = None
    if ext in ("ply", "glb"):
        colors = (np.arange(v.shape[0] * 3).reshape(-1, 3) % 256 / 255.0).astype(np.float32)
    p = optim.save_mesh(tmp_path / f"m.{ext}", v, f, colors)
    v2, f2, c2 = optim.load_mesh(p)
    assert f2.shape == f.shape and f2.dtype == np.int32 and v2.dtype == np.float64
    # same triangles as coordinate triples (loaders may renumber vertices)
    tri = np.sort(np.round(v[f], 5).reshape(len(f), -1), axis=0)
    tri2 = np.sort(np.round(v2[f2], 5).reshape(len(f2), -1), axis=0)
    np.testing.assert_allclose(tri, tri2, atol=1e-5)
    if colors is not None:
        assert c2 is not None
        order = np.lexsort(np.round(v2, 5).T)
        order0 = np.lexsort(np.round(v, 5).T)
        np.testing.assert_allclose(c2[order], colors[order0], atol=1 / 255)
    assert [q.name for q in tmp_path.iterdir()] == [f"m.{ext}"]  # no temporary left behind


def test_load_scene_concatenated(tmp_path):
    import trimesh

    a = trimesh.Trimesh(*optim.icosphere(0), process=False)
    b = trimesh.Trimesh(TET_V + 5, TET_F, process=False)
    p = tmp_path / "scene.glb"
    p.write_bytes(trimesh.Scene([a, b]).export(file_type="glb"))
    v, f, _ = optim.load_mesh(p)
    assert f.shape == (24, 3) and v.shape == (16, 3)


def test_load_errors_name_the_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.ply"):
        optim.load_mesh(tmp_path / "nope.ply")
    bad_files = {
        "garbage.ply": b"this is not a mesh\x00\x01\x02",
        "empty.obj": b"",
        "points.obj": b"v 0 0 0\nv 1 0 0\nv 0 1 0\n",
        "nan.obj": b"v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    }
    for name, content in bad_files.items():
        path = tmp_path / name
        path.write_bytes(content)
        with pytest.raises(ValueError, match=name.replace(".", r"\.")):
            optim.load_mesh(path)
    with pytest.raises(ValueError, match="directory"):
        optim.load_mesh(tmp_path)


def test_save_never_over_input(tmp_path):
    v, f = optim.icosphere(0)
    src = optim.save_mesh(tmp_path / "in.ply", v, f)
    before = src.read_bytes()
    with pytest.raises(ValueError, match="refusing to overwrite"):
        optim.save_mesh(src, v[:, ::-1], f, protect=(src,))
    assert src.read_bytes() == before
    with pytest.raises(ValueError, match="format"):
        optim.save_mesh(tmp_path / "x.xyz", v, f)
    with pytest.raises(ValueError, match="colors must have shape"):
        optim.save_mesh(tmp_path / "y.ply", v, f, colors=np.zeros((2, 3)))


@pytest.mark.shared
@pytest.mark.skipif(not (SHARED / "cow.obj").exists(), reason="needs ../shared")
def test_load_shared_cow():
    v, f, c = optim.load_mesh(SHARED / "cow.obj")
    assert f.shape == (5804, 3) and c is None
    v2, f2, _, rep = optim.validate_mesh(v, f, name="cow.obj")
    assert f2.shape[0] + rep.dropped_degenerate + rep.dropped_duplicate == 5804


def test_bumpy_torus_is_a_closed_outward_genus_one_surface():
    import trimesh

    v, f, c = optim.bumpy_torus(40, 20, seed=3, colors=True)
    assert f.shape == (2 * 40 * 20, 3) and v.shape == (40 * 20, 3) and c.shape == (800, 3)
    m = trimesh.Trimesh(v, f, process=False)
    assert m.is_watertight and m.is_winding_consistent and m.euler_number == 0  # V - E + F = 0: genus 1
    assert m.volume > 0  # faces wind outward
    # Bumps are bounded by the amplitude: every vertex lies within 8% of the tube radius of the clean torus.
    ring = np.hypot(v[:, 0], v[:, 1])
    tube = np.hypot(ring - 1.0, v[:, 2])
    assert np.all(np.abs(tube - 0.4) <= 0.08 * 0.4 + 1e-12)
    assert optim.bumpy_torus(1000, 500)[1].shape[0] == 1_000_000
    with pytest.raises(ValueError, match="nu and nv must be >= 3"):
        optim.bumpy_torus(2, 10)


@pytest.mark.parametrize("ext", ["ply", "obj", "glb", "off"])
def test_load_mesh_gives_the_normals_a_file_carries(tmp_path, ext):
    v, f = optim.icosphere(2)
    n = np.tile([0.0, 0.6, 0.8], (len(v), 1))
    with_n = optim.save_mesh(tmp_path / f"n.{ext}", v, f, normals=n)
    without = optim.save_mesh(tmp_path / f"p.{ext}", v, f)
    got = optim.load_mesh(with_n, normals=True)
    assert len(got) == 4 and len(optim.load_mesh(with_n)) == 3
    if ext == "off":  # OFF holds no normals
        assert got[3] is None
    else:
        np.testing.assert_allclose(got[3], n, atol=1e-6)
    assert optim.load_mesh(without, normals=True)[3] is None

"""``plod simplify``: JSON output, budgets, imperceptible mode, the tree cache, atomic output and
one-line errors for bad flags."""

from __future__ import annotations

import json

import numpy as np
import pytest

import optim
from experiments.cli import main


@pytest.fixture(scope="module")
def mesh_file(tmp_path_factory):
    d = tmp_path_factory.mktemp("mesh")
    v, f = optim.icosphere(3)
    return optim.save_mesh(d / "sphere.obj", v, f)


@pytest.fixture(autouse=True)
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("PLOD_CACHE", str(tmp_path / "cache"))
    return tmp_path / "cache"


def _run(capsys, *argv):
    code = main(["simplify", *map(str, argv)])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_budget_json_and_output_file(capsys, mesh_file, tmp_path, cache):
    out = tmp_path / "small.ply"
    code, stdout, _ = _run(capsys, mesh_file, "--budget", 300, "--json", "--out", out, "--method", "octree")
    assert code == 0
    res = json.loads(stdout)
    assert res["input_triangles"] == 1280
    assert 0 < res["output_triangles"] <= 300
    assert res["stop_reason"] == "budget"
    assert res["imperceptible_distance"] > 0
    assert set(res["timings_ms"]) >= {"build", "score", "cut", "extract"}
    assert res["tree_cache"] == "miss"
    v, f, _ = optim.load_mesh(out)
    assert f.shape[0] == res["output_triangles"] and v.shape[0] == res["output_vertices"]
    assert not list(tmp_path.glob(".small.ply.*"))  # no temporary file left behind
    trees = [p for p in cache.glob("*.npz") if not p.name.startswith("ctx-")]
    assert len(trees) == 1 and res["context_cache"] == "saved"
    assert (cache / f"ctx-{trees[0].name}").is_file()  # the first view's per-tree work, beside the tree
    # second run: the tree and its first-view work come from the cache and the result is identical
    code, stdout, _ = _run(capsys, mesh_file, "--budget", 300, "--json", "--method", "octree")
    res2 = json.loads(stdout)
    assert res2["tree_cache"] == "hit" and res2["output_triangles"] == res["output_triangles"]
    assert res2["context_cache"] == "hit" and res2["imperceptible_distance"] == res["imperceptible_distance"]
    # a relit view needs the neighbours' normals too: built, then kept (the file is replaced)
    code, stdout, _ = _run(capsys, mesh_file, "--budget", 300, "--json", "--method", "octree", "--light", "1,1,1")
    res3 = json.loads(stdout)
    assert res3["context_cache"] == "saved"
    code, stdout, _ = _run(capsys, mesh_file, "--budget", 300, "--json", "--method", "octree", "--light", "1,1,1")
    res4 = json.loads(stdout)
    assert res4["context_cache"] == "hit" and res4["imperceptible_distance"] == res3["imperceptible_distance"]


def test_imperceptible_mode_and_view_flags(capsys, mesh_file):
    code, stdout, _ = _run(capsys, mesh_file, "--imperceptible", "--json", "--method", "octree", "--no-cache",
                           "--eye", "0,0,40", "--gaze", "100,100", "--gaze-error", "15")
    assert code == 0
    res = json.loads(stdout)
    assert res["stop_reason"] in ("imperceptible", "all_unfolded")
    assert res["imperceptible_distance"] <= 1.0
    assert res["output_triangles"] <= res["input_triangles"]
    # size metric, the rich table instead of JSON
    code, stdout, _ = _run(capsys, mesh_file, "--budget", 100, "--metric", "size", "--method", "octree",
                           "--screen-deg", "60", "--distance-m", "0.5", "--model", "ManosSakrison")
    assert code == 0 and "triangles" in stdout and "1,280" in stdout


def test_budget_larger_than_mesh_keeps_everything(capsys, mesh_file):
    code, stdout, _ = _run(capsys, mesh_file, "--budget", 10**6, "--json", "--method", "octree", "--no-gaze",
                           "--eye", "0,0,3")
    res = json.loads(stdout)
    # back-facing nodes are folded even with an unlimited budget; the visible half stays
    assert res["stop_reason"] in ("all_unfolded", "budget")
    assert 600 <= res["output_triangles"] <= 1280


def test_cull_back_faces_counts_front_facing_triangles(capsys, mesh_file, tmp_path):
    """--cull-back-faces: the budget counts the triangles that face the eye, the output has no triangle
    facing away, carries the whole cut's normals, and is drawn from a larger cut than without it."""
    argv = (mesh_file, "--budget", 300, "--json", "--method", "octree", "--no-cache", "--eye", "0,0,4")
    out = tmp_path / "front.ply"
    code, stdout, _ = _run(capsys, *argv, "--cull-back-faces", "--out", out)
    assert code == 0
    res = json.loads(stdout)
    _, plain, _ = _run(capsys, *argv)
    plain = json.loads(plain)
    assert 290 <= res["output_triangles"] <= 300 < res["cut_triangles"]
    assert res["cut_triangles"] > 1.5 * plain["cut_triangles"] and res["cull_back_faces_margin_deg"] == 0.0
    v, f, _ = optim.load_mesh(out)
    assert f.shape[0] == res["output_triangles"] and not optim.facing_away(v, f, np.array([0.0, 0.0, 4.0])).any()
    assert b"property float nx" in out.read_bytes()[:400]
    # 2026-12-07: the .ply kept the dropped back faces' vertices (the .obj did not), so output_vertices
    # disagreed between formats; .off / .stl hold no normals, where the JSON said "region"
    assert res["output_vertices"] == len(v) == len(np.unique(f)) and res["normals"] == "region"
    code, stdout, _ = _run(capsys, *argv, "--cull-back-faces", "--out", tmp_path / "front.off")
    res_off = json.loads(stdout)
    assert code == 0 and res_off["normals"] == "none" and res_off["output_vertices"] == len(v)


def test_a_cache_that_is_a_file_does_not_stop_the_command(capsys, mesh_file, tmp_path, monkeypatch):
    """PLOD_CACHE naming a file: the tree could not be saved and the command stopped after building it
    (the cache is an optimisation; a read-only one never stopped the command)."""
    blocker = tmp_path / "afile"
    blocker.write_text("not a folder")
    monkeypatch.setenv("PLOD_CACHE", str(blocker))
    code, stdout, err = _run(capsys, mesh_file, "--budget", 100, "--json", "--light", "0,0,1")
    assert code == 0, err
    res = json.loads(stdout)
    assert res["tree_cache"] == "miss" and res["context_cache"] == "off" and 0 < res["output_triangles"] <= 100
    assert blocker.read_text() == "not a folder"


def test_hybrid_tree_from_the_command_line(capsys, mesh_file):
    code, stdout, _ = _run(capsys, mesh_file, "--budget", 300, "--json", "--method", "hybrid", "--no-cache")
    res = json.loads(stdout)
    assert code == 0 and res["tree_method"] == "hybrid" and 0 < res["output_triangles"] <= 300
    # the default (auto): the hybrid tree for a relit view, meshopt for a pre-lit one
    for extra, want in ((("--light", "1,1,1"), "hybrid"), ((), "meshopt")):
        code, stdout, _ = _run(capsys, mesh_file, "--budget", 300, "--json", "--no-cache", *extra)
        assert code == 0 and json.loads(stdout)["tree_method"] == want


def test_output_carries_the_chosen_normals(capsys, mesh_file, tmp_path):
    """--normals: region (the default) writes each vertex's region normal (optim.extract's), faces the
    normals of the written faces, none no normals; the JSON says which."""
    import trimesh

    argv = (mesh_file, "--budget", 300, "--json", "--method", "octree", "--no-cache", "--light", "1,1,1")
    got = {}
    for how in ("region", "faces", "none"):
        out = tmp_path / f"{how}.ply"
        extra = () if how == "region" else ("--normals", how)
        code, stdout, _ = _run(capsys, *argv, *extra, "--out", out)
        assert code == 0 and json.loads(stdout)["normals"] == how
        got[how] = out
    assert b"property float nx" not in got["none"].read_bytes()[:400]
    region = trimesh.load(got["region"], process=False)
    faces = trimesh.load(got["faces"], process=False)
    np.testing.assert_array_equal(region.faces, faces.faces)
    v, f = np.asarray(faces.vertices, np.float64), np.asarray(faces.faces)
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    want = np.zeros_like(v)
    for j in range(3):
        np.add.at(want, f[:, j], cross)
    want /= np.linalg.norm(want, axis=1, keepdims=True)
    np.testing.assert_allclose(faces.vertex_normals, want, atol=1e-5)
    tree = optim.build_tree(*optim.load_mesh(mesh_file)[:2], method="octree")
    rn = np.asarray(region.vertex_normals)
    assert np.allclose(np.linalg.norm(rn, axis=1), 1.0, atol=1e-5)
    # a sphere's region normals point outward like its faces', but are not them
    ang = np.degrees(np.arccos(np.clip((rn * want).sum(1), -1, 1)))
    assert ang.max() < 45 and np.median(ang) > 0.1 and tree.n_triangles == 1280


@pytest.mark.parametrize(
    "argv, msg",
    [
        (["--budget", "10", "--eye", "1,2"], "--eye needs three comma-separated numbers"),
        (["--budget", "10", "--eye", "0,0,5", "--target", "a,b,c"], "--target needs three comma-separated numbers"),
        (["--budget", "ten"], "--budget needs a whole number"),
        (["--budget", "-3"], "--budget must be >= 1"),
        (["--budget", "10", "--fov", "200"], "--fov must be"),
        (["--budget", "10", "--gaze", "5"], "--gaze needs two comma-separated numbers"),
        (["--budget", "10", "--gaze-error", "-1"], "--gaze-error must be"),
        (["--budget", "10", "--model", "Nobody"], "unknown model 'Nobody'"),
        (["--budget", "10", "--model", "missing.json"], "file not found"),
        (["--imperceptible", "--metric", "size"], "--imperceptible needs --metric perceptual"),
        (["--budget", "10", "--out", "x.xyz"], "cannot write"),
        (["--budget", "10", "--target", "0,0,0"], "--target needs --eye"),
        (["--budget", "10", "--cull-back-faces", "90"], "--cull-back-faces must be"),
        (["--budget", "10", "--cull-back-faces", "x"], "--cull-back-faces needs a number"),
        (["--budget", "10", "--normals", "smooth"], "--normals must be region, faces or none"),
        (["--budget", "10", "--up", "0,0,0"], "--up must be a nonzero vector"),
    ],
)
def test_bad_flags_give_one_line_errors(capsys, mesh_file, argv, msg):
    code, _, err = _run(capsys, mesh_file, *argv)
    assert code == 2
    assert msg in err
    assert err.count("\n") == 1 and "Traceback" not in err


def test_one_triangle_relit_with_the_cache(capsys, tmp_path, cache):
    """A mesh of one triangle (a tree without folds, empty context arrays) with --light: the first run
    saves the tree and its context, the second reads both back; both keep the triangle. The context's
    digest used to raise a TypeError here (a traceback, found by fuzzing the command line)."""
    src = tmp_path / "tri.obj"
    src.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    for want in ("saved", "hit"):
        code, stdout, err = _run(capsys, src, "--budget", 1, "--light", "0,0,1", "--json", "--out", tmp_path / "o.ply")
        assert code == 0, err
        res = json.loads(stdout)
        assert res["output_triangles"] == 1 and res["context_cache"] == want


def test_never_overwrites_the_input(capsys, mesh_file):
    before = mesh_file.read_bytes()
    code, _, err = _run(capsys, mesh_file, "--budget", 10, "--out", mesh_file)
    assert code == 2 and "input mesh" in err
    assert mesh_file.read_bytes() == before


def test_missing_mesh(capsys, tmp_path):
    code, _, err = _run(capsys, tmp_path / "nope.ply", "--budget", 10)
    assert code == 2 and "not found" in err


def test_mode_is_required(capsys, mesh_file):
    with pytest.raises(SystemExit):
        main(["simplify", str(mesh_file)])
    with pytest.raises(SystemExit):
        main(["simplify", str(mesh_file), "--budget", "5", "--imperceptible"])
    capsys.readouterr()


def test_default_view_frames_the_object_at_30_degrees(mesh_file):
    from experiments._cmd_simplify import build_view, register  # noqa: F401
    import argparse

    p = argparse.ArgumentParser()
    sub = p.add_subparsers()
    register(sub)
    args = p.parse_args(["simplify", str(mesh_file), "--budget", "5"])
    v, _, _ = optim.load_mesh(mesh_file)
    view = build_view(v, args)
    r = np.sqrt((v ** 2).sum(1).max())
    assert 2 * np.degrees(np.arcsin(r / np.linalg.norm(view.eye))) == pytest.approx(30.0, rel=1e-6)

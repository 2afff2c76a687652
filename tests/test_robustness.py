"""Issue 13 (no silent wrong answers, no touched inputs): output permissions and temporary files,
mesh text encodings, budget arguments, off-screen gaze points, and the `plod` command line (output paths
checked before any work, inputs never touched, bad sampler settings, dropped rows, an empty PLOD_CACHE)."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
import time

import numpy as np
import pytest

import optim
from optim._cut import min_nonempty_budget
from pmetric import PlodError, atomic_path, atomic_write_bytes, atomic_write_text
from pmetric._atomic import STALE_AFTER_S, TMP_TAG, _host_tag


@pytest.fixture
def umask():
    """Set the process umask for a test (restored afterwards)."""
    old = os.umask(0o022)
    os.umask(old)
    yield lambda m: os.umask(m)
    os.umask(old)


def _mode(p) -> int:
    return stat.S_IMODE(os.stat(p).st_mode)


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


# ---------------------------------------------------------------------------------------------- 1 modes


@pytest.mark.parametrize("mask", [0o022, 0o002, 0o077])
def test_new_output_mode_follows_umask(tmp_path, umask, mask):
    umask(mask)
    p = atomic_write_text(tmp_path / "a.txt", "x")
    assert _mode(p) == 0o666 & ~mask
    v, f = optim.icosphere(0)
    assert _mode(optim.save_mesh(tmp_path / "m.ply", v, f)) == 0o666 & ~mask


def test_overwrite_keeps_the_existing_mode(tmp_path, umask):
    umask(0o077)
    p = tmp_path / "a.txt"
    p.write_text("old")
    for mode in (0o644, 0o640, 0o664):
        os.chmod(p, mode)
        atomic_write_bytes(p, b"new")
        assert _mode(p) == mode and p.read_bytes() == b"new"


# ---------------------------------------------------------------------------------------------- 2 temporaries


def _temp_name(target: str, pid: int, host: str | None = None) -> str:
    return f".{target}{TMP_TAG}{host or _host_tag()}-{pid}-deadbeef.ply"


def test_stale_temp_of_a_dead_process_is_removed(tmp_path):
    dead = tmp_path / _temp_name("out.ply", _dead_pid())
    dead.write_bytes(b"half a mesh")
    alive = tmp_path / _temp_name("out.ply", os.getppid())  # a running process: kept
    alive.write_bytes(b"in progress")
    old = tmp_path / _temp_name("out.ply", os.getppid(), host="abcdef")  # another host, hours old
    old.write_bytes(b"forgotten")
    t = time.time() - 2 * STALE_AFTER_S
    os.utime(old, (t, t))
    other = tmp_path / _temp_name("other.ply", _dead_pid())  # another target's: not ours to judge now
    other.write_bytes(b"x")
    v, f = optim.icosphere(0)
    optim.save_mesh(tmp_path / "out.ply", v, f)
    assert not dead.exists() and not old.exists()
    assert alive.exists() and other.exists()
    assert optim.load_mesh(tmp_path / "out.ply")[1].shape == (20, 3)


def test_temp_names_are_recognisable(tmp_path):
    seen = []
    with atomic_path(tmp_path / "out.ply") as tmp:
        seen.append(tmp.name)
        tmp.write_bytes(b"x")
    assert seen[0].startswith(f".out.ply{TMP_TAG}{_host_tag()}-{os.getpid()}-") and seen[0].endswith(".ply")
    assert sorted(q.name for q in tmp_path.iterdir()) == ["out.ply"]


@pytest.mark.parametrize("exc", [RuntimeError, KeyboardInterrupt])
def test_exception_while_writing_leaves_the_original_and_no_temp(tmp_path, exc):
    p = tmp_path / "out.ply"
    p.write_bytes(b"original")
    with pytest.raises(exc):
        with atomic_path(p) as tmp:
            tmp.write_bytes(b"partial")
            raise exc("interrupted")
    assert p.read_bytes() == b"original"
    assert [q.name for q in tmp_path.iterdir()] == ["out.ply"]


def test_refusing_to_overwrite_an_input_is_a_plod_error(tmp_path):
    p = tmp_path / "in.txt"
    p.write_text("input")
    with pytest.raises(PlodError, match="refusing to overwrite"):
        atomic_write_text(p, "output", protect=(p,))
    assert p.read_text() == "input" and [q.name for q in tmp_path.iterdir()] == ["in.txt"]


# ---------------------------------------------------------------------------------------------- 3 encodings

_PLY_HEAD = ("ply\nformat {fmt} 1.0\ncomment caf\xe9\nelement vertex 3\nproperty float x\nproperty float y\n"
             "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n")

_LATIN1 = {
    "obj": "# caf\xe9\no caf\xe9\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n".encode("latin-1"),
    "off": "OFF\n# caf\xe9\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n".encode("latin-1"),
    "ply": (_PLY_HEAD.format(fmt="ascii") + "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n").encode("latin-1"),
    "stl": ("solid caf\xe9\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\n"
            "endloop\nendfacet\nendsolid caf\xe9\n").encode("latin-1"),
}


@pytest.mark.parametrize("ext", sorted(_LATIN1))
def test_latin1_text_mesh_loads(tmp_path, ext):
    p = tmp_path / f"cafe.{ext}"
    p.write_bytes(_LATIN1[ext])
    v, f, _ = optim.load_mesh(p)
    assert f.shape == (1, 3)
    np.testing.assert_allclose(np.sort(v[f[0]], axis=0), [[0, 0, 0], [0, 0, 0], [1, 1, 0]])


def test_binary_ply_with_latin1_header_comment_loads(tmp_path):
    body = np.array([0, 0, 0, 1, 0, 0, 0, 1, 0], "<f4").tobytes() + b"\x03" + np.array([0, 1, 2], "<i4").tobytes()
    p = tmp_path / "bin.ply"
    p.write_bytes(_PLY_HEAD.format(fmt="binary_little_endian").encode("latin-1") + body)
    v, f, _ = optim.load_mesh(p)
    assert f.tolist() == [[0, 1, 2]] and v[1].tolist() == [1.0, 0.0, 0.0]


@pytest.mark.parametrize("ext", ["obj", "off", "ply", "stl"])
def test_binary_garbage_is_not_a_readable_mesh(tmp_path, ext):
    p = tmp_path / f"garbage.{ext}"
    p.write_bytes(np.random.default_rng(0).integers(0, 256, 300, dtype=np.uint8).tobytes())
    with pytest.raises(PlodError, match=rf"garbage\.{ext}.*not a readable mesh"):
        optim.load_mesh(p)


# ---------------------------------------------------------------------------------------------- 4 budgets


@pytest.fixture(scope="module")
def tree_keys():
    t = optim.build_tree(*optim.icosphere(2))
    k = optim.repair_monotone(t, np.random.default_rng(0).random(t.n_nodes))
    return t, k


@pytest.mark.parametrize("bad", [True, False, np.bool_(True), float("nan"), float("inf"), 2.5, "10", None, -1, -1.0])
def test_bad_budgets_are_rejected(tree_keys, bad):
    t, k = tree_keys
    for cut in (optim.budget_cut, optim.budget_cut_heap):
        with pytest.raises(PlodError, match="budget"):
            cut(t, k, bad)


def test_integral_budgets_are_accepted(tree_keys):
    t, k = tree_keys
    ref = optim.budget_cut(t, k, 40)
    for b in (40.0, np.int64(40), np.float32(40)):
        np.testing.assert_array_equal(optim.budget_cut(t, k, b).unfolded, ref.unfolded)


@pytest.mark.parametrize("method", ["qem", "octree"])
def test_min_nonempty_budget_and_no_empty_mesh_written(tmp_path, method):
    t = optim.build_tree(*optim.icosphere(2), method=method)
    rng = np.random.default_rng(1)
    for keys in (np.zeros(t.n_nodes), optim.repair_monotone(t, rng.random(t.n_nodes))):
        b = min_nonempty_budget(t, keys)
        assert b >= 1
        for cut in (optim.budget_cut, optim.budget_cut_heap):
            assert cut(t, keys, b - 1).triangles == 0 and cut(t, keys, b).triangles > 0
    v, f, c = optim.extract(t, optim.budget_cut(t, keys, 0))
    assert f.shape[0] == 0
    with pytest.raises(PlodError, match="empty mesh"):
        optim.save_mesh(tmp_path / "empty.ply", v, f, c)
    assert not any(tmp_path.iterdir())
    v, f, c = optim.extract(t, optim.budget_cut(t, keys, b))
    p = optim.save_mesh(tmp_path / "coarsest.ply", v, f, c)
    assert optim.load_mesh(p)[1].shape[0] == f.shape[0]


# ---------------------------------------------------------------------------------------------- 5 gaze


@pytest.mark.parametrize("g", [[-1.0, 10.0], [1921.0, 10.0], [10.0, -0.5], [10.0, 1081.0]])
def test_off_screen_pixel_gaze_is_rejected(g):
    with pytest.raises(PlodError, match=rf"gaze point \({g[0]:g}, {g[1]:g}\) px .*1920x1080"):
        optim.View(eye=(0, 0, 5), gaze=[[960.0, 540.0], g])


def test_gaze_on_the_image_edges_and_directions_past_it_are_accepted():
    v = optim.View(eye=(0, 0, 5), gaze=[[0, 0], [1920, 1080], [1920, 0]])
    assert v.gaze_px.shape == (3, 2)
    d = optim.View(eye=(0, 0, 5), gaze=[3.0, 0.0, -1.0])  # 72 deg right: off the screen, but a real gaze
    assert d.gaze_px[0, 0] > d.width


# ---------------------------------------------------------------------------------------------- 6 CLI
# Output paths are checked before any work; inputs are never touched; bad numbers name the flag.


@pytest.fixture
def cli_files(tmp_path, monkeypatch):
    """A tiny mesh, a small CSV (5 zero-frequency rows + 30 gratings), a saved model, a 2-row CSV."""
    import pmetric
    from optim.fit import CalibrationData

    monkeypatch.setenv("PLOD_CACHE", str(tmp_path / "cache"))
    mesh = tmp_path / "in.ply"
    optim.save_mesh(mesh, *optim.icosphere(2))
    f = np.concatenate([np.zeros(5), np.geomspace(0.5, 20, 30)])
    csv = tmp_path / "cal.csv"
    CalibrationData.from_arrays(f, log_threshold=-2.0 + 0.1 * np.log10(np.maximum(f, 0.1)) ** 2).to_csv(csv)
    few = tmp_path / "few.csv"  # 2 rows for KellyAbstract's 2 constants: an exact fit, no uncertainty
    CalibrationData.from_arrays([2.0, 4.0], log_threshold=-2.0).to_csv(few)
    model = tmp_path / "start.json"
    pmetric.save_model(pmetric.KellyAbstract(), model)
    (tmp_path / "afile.ply").write_bytes(b"not a folder")
    return {"dir": tmp_path, "mesh": mesh, "csv": csv, "few": few, "model": model}


def _snapshot(d):
    return {p: p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


def _cli_fails(capsys, files, argv, *msgs):
    from experiments.cli import main

    before = _snapshot(files["dir"])
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    for m in msgs:
        assert m in err, err
    after = _snapshot(files["dir"])
    assert after == before, "an input was changed or an output written"  # byte-identical, nothing new
    return err


def test_cli_fit_refuses_its_own_model_and_non_json_outputs(capsys, cli_files):
    c, m, d = cli_files["csv"], cli_files["model"], cli_files["dir"]
    _cli_fails(capsys, cli_files, ["fit", c, "--model", m, "--out", m], "--out", "the input model", "overwrite")
    _cli_fails(capsys, cli_files, ["fit", c, "--model", "kellyabstract", "--out", c], "the input data")
    _cli_fails(capsys, cli_files, ["fit", c, "--model", "kellyabstract", "--out", d / "x.ply"], "--out", ".json")
    # a model file inside a composition, or space-padded, is an input too (before: overwritten)
    _cli_fails(capsys, cli_files, ["fit", c, "--model", f"eccentric( {m} )", "--out", m], "the input model")
    _cli_fails(capsys, cli_files, ["fit", c, "--model", f" {m}", "--out", m], "the input model")


@pytest.mark.parametrize("case", ["file-parent", "directory", "proc", "missing-folder", "suffix"])
def test_cli_simplify_output_paths_checked_before_work(capsys, cli_files, case):
    d, mesh = cli_files["dir"], cli_files["mesh"]
    bad = {"file-parent": ["--out", d / "afile.ply" / "x.ply"], "directory": ["--out", d / "sub.ply"],
           "proc": ["--out", d / "ok.ply", "--render", "/proc/x.png"],
           "missing-folder": ["--render", d / "nope" / "x.png"], "suffix": ["--render", d / "x.jpg"]}[case]
    if case == "directory":
        (d / "sub.ply").mkdir()
    t0 = time.perf_counter()
    err = _cli_fails(capsys, cli_files, ["simplify", mesh, "--budget", "50", *bad], bad[-2])
    assert time.perf_counter() - t0 < 5.0  # before the tree is built or anything rendered
    assert not (d / "ok.ply").exists() and "plod-tmp" not in err
    assert not (d / "cache").exists()


def test_cli_calibrate_output_checked_and_fade_rejects_staircase_flags(capsys, cli_files):
    d = cli_files["dir"]
    _cli_fails(capsys, cli_files, ["calibrate", "--simulate", "--out", d / "afile.ply" / "x.csv"], "not a folder")
    _cli_fails(capsys, cli_files, ["calibrate", "--simulate", "--out", d / "x.json"], "--out", ".csv")
    for flag, val in (("--rule", "2down1up"), ("--trials", "40")):
        _cli_fails(capsys, cli_files, ["calibrate", "--simulate", flag, val, "--out", d / "s.csv"],
                   flag, "--method staircase")
    _cli_fails(capsys, cli_files, ["calibrate", "--simulate", "--observer-seed", "-1", "--out", d / "s.csv"],
               "--observer-seed must be >= 0")


@pytest.mark.parametrize("argv, msg", [
    (["--method", "mcmc", "--nsteps", "1"], "--nsteps must be >= 3"),
    (["--method", "mcmc", "--nsteps", "2"], "--nsteps must be >= 3"),
    (["--method", "mcmc", "--seed", "-1"], "--seed must be >= 0"),
])
def test_cli_fit_bad_sampler_settings(capsys, cli_files, argv, msg):
    _cli_fails(capsys, cli_files, ["fit", cli_files["csv"], "--model", "kellyabstract", *argv], msg)


def test_cli_fit_reports_dropped_rows_and_refuses_too_few(capsys, cli_files):
    import json

    from experiments.cli import main

    assert main(["fit", str(cli_files["csv"]), "--model", "kellyabstract", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["n_input_rows"] == 35 and rep["n_rows"] == 30 and rep["n_dropped_rows"] == 5
    assert rep["n_dropped_zero_frequency"] == 5 and "s_frequency 0" in rep["dropped_rows"]
    assert main(["fit", str(cli_files["csv"]), "--model", "kellyabstract"]) == 0
    assert "used 30 of 35 rows: dropped 5" in capsys.readouterr().out
    _cli_fails(capsys, cli_files, ["fit", cli_files["few"], "--model", "kellyabstract"],
               "2 usable data rows", "2 free constants", "need at least 3 rows")


def test_cli_empty_plod_cache_means_no_cache(capsys, cli_files, monkeypatch):
    import json

    from experiments import cli
    from experiments._cmd_simplify import cache_dir

    monkeypatch.setenv("PLOD_CACHE", "")
    monkeypatch.setenv("HOME", str(cli_files["dir"] / "home"))
    assert cache_dir() is None
    assert cli.main(["simplify", str(cli_files["mesh"]), "--budget", "50", "--json", "--method", "octree"]) == 0
    assert json.loads(capsys.readouterr().out)["tree_cache"] == "off"
    assert not (cli_files["dir"] / "home").exists()
    assert "empty string means no cache" in " ".join(cli.build_parser().format_help().split())


def test_protect_takes_one_path_or_several(tmp_path):
    """``protect`` may be one path (str or Path) or a sequence of them (before: a str was iterated per
    character, so the input was overwritten; a Path raised TypeError); other values are PlodErrors, as are
    a target that is a directory or lies below a file (before: IsADirectoryError, FileExistsError)."""
    p = tmp_path / "in.txt"
    p.write_text("input")
    for protect in (str(p), p, [str(p)], (None, p)):
        with pytest.raises(PlodError, match="refusing to overwrite"):
            atomic_write_text(p, "output", protect=protect)
    for protect in (3, [3]):
        with pytest.raises(PlodError, match="protect must be a path or a sequence of paths"):
            atomic_write_text(tmp_path / "other.txt", "output", protect=protect)
    with pytest.raises(PlodError, match="it is a directory"):
        atomic_write_text(tmp_path, "output")
    with pytest.raises(PlodError, match="a file is in the way of its folder"):
        atomic_write_text(p / "below" / "x.txt", "output")
    assert p.read_text() == "input" and [q.name for q in tmp_path.iterdir()] == ["in.txt"]
    atomic_write_text(tmp_path / "out.txt", "ok", protect=str(p))  # a different target is written
    assert (tmp_path / "out.txt").read_text() == "ok"
    # save_mesh made a tuple of its protect itself (a str per character): the input mesh was overwritten
    import optim

    v, f = optim.bumpy_sphere(1)
    m = tmp_path / "m.ply"
    optim.save_mesh(m, v, f)
    before = m.read_bytes()
    for protect in (str(m), m):
        with pytest.raises(PlodError, match="refusing to overwrite"):
            optim.save_mesh(m, v[:], f[:4], protect=protect)
    assert m.read_bytes() == before

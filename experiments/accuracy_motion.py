"""Plod's cuts judged in motion: an orbiting camera, every cut recomputed per frame, the clip scored as video.

    python -m experiments.accuracy_motion [--config configs/accuracy_motion.toml] [--out DIR]

The accuracy sweep (``experiments/accuracy.py``) judges still images. A graphics program updates its
cut every frame while the camera moves, so a viewer also sees the cut change (popping) and, with an
eye held on a point of the screen, the surface flow past. Per cell (a mesh the tests do not use, a
seeded start direction, a gaze offset in deg to the right of the object's centre, relit with
``optim.Lighting()``) the camera orbits the object's centre about the vertical at ``orbit_deg_s`` for
``frames`` frames at ``fps``; each frame plod recomputes, for that frame's view:

* ``imperceptible``: the imperceptible cut (``optim.threshold_cut`` at 1) of the perceptual keys;
* ``imperceptible+velocity``: the same with the previous frame as the view's ``previous`` (the keys'
  retinal velocity term [LHNW00]: a fold moving across the retina is harder to see);
* ``perceptual``: the perceptual budget cut at ``budget`` of the input (face-culled per ``face_cull``);
* ``perceptual+velocity``, ``size``, ``geometric``: keys with velocity, size and geometric keys, each at
  that frame's perceptual drawn count;

and the view-independent peers (``meshoptimizer``, ``fast_simplification``) are simplified once, at the
perceptual cut's mean drawn count, and drawn in every frame. Each method's frames are judged against the
original's with FovVideoVDP [Man21] as a video at ``fps`` (:func:`experiments.judge.fovvdp_clip`, fixation
held at the gaze) and every ``still_every``-th frame as a still.

Writes ``DIR/results.jsonl`` (one line per judged clip), ``DIR/report.md`` (tables), ``DIR/video_vs_still.png``
and ``DIR/run_info.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
from pathlib import Path

import numpy as np

from experiments._runinfo import check_out_dir, load_config, repo_path, run_script, save_run_info
from pmetric import PlodError, atomic_write_text

DEFAULTS = {
    "kind": "accuracy_motion",
    "out": "reports/accuracy_motion",
    # meshes in no test and not in the accuracy sweep
    "meshes": ["../shared/data/meshes/cow.obj", "../shared/data/meshes/stanford-bunny.obj",
               "../shared/data/meshes/turbineblade.ply"],
    "procedural": ["sphere:5:7"],
    "seed": 77,
    "object_deg": 30.0,
    "gaze_offsets_deg": [0.0, 8.0],
    "gaze_error_deg": 1.0,
    "budget": 0.08,
    "orbit_deg_s": 30.0,
    "fps": 30.0,
    "frames": 30,
    "still_every": 3,
    "size": [960, 540],
    "face_cull": True,
}
PEERS = ("meshoptimizer", "fast_simplification")
RIVALS = ("size", "geometric") + PEERS  # the "best of" set for the perceptual budget cut


def orbit_views(v, start, gaze_deg: float, frames: int, fps: float, orbit_deg_s: float, cfg) -> tuple[list, list]:
    """``(views, moving)``: the ``frames`` views of a camera orbiting the centre of ``v`` about the vertical
    (y) at ``orbit_deg_s`` (deg/s) from direction ``start``, framed as the accuracy sweep frames them and
    relit with ``optim.Lighting()``; ``moving``: the same views, each with the previous frame's view as
    ``previous`` (``dt_s = 1 / fps``; the first frame's previous is one step back on the orbit)."""
    import optim
    from experiments.judge import offset_gaze_view

    def view(k, **kw):
        a = math.radians(orbit_deg_s * k / fps)
        c, s = math.cos(a), math.sin(a)
        d = np.array([c * start[0] + s * start[2], start[1], -s * start[0] + c * start[2]])
        return offset_gaze_view(v, gaze_deg, object_deg=cfg["object_deg"], direction=d,
                                gaze_error_deg=cfg["gaze_error_deg"], lighting=optim.Lighting(), **kw)

    views = [view(k) for k in range(-1, frames)]  # views[j] is frame j - 1
    moving = [view(k, previous=views[k], dt_s=1.0 / fps) for k in range(frames)]
    return views[1:], moving


def clip_results(mesh, start, gaze_deg: float, cfg, progress=None) -> list[dict]:
    """Judge every method on one orbit (see the module docstring); one row per method: {method,
    triangles (mean drawn per frame), triangles_min, triangles_max, video_jod, still_jod (list)}."""
    import optim
    from experiments import render as R
    from experiments.accuracy import plod_mesh
    from experiments.judge import fovvdp_clip

    n, fps = int(cfg["frames"]), float(cfg["fps"])
    if n < 2 or not fps > 0:  # (check_config says so first, naming the key)
        raise PlodError(f"accuracy_motion: frames must be >= 2 and fps > 0, got {n!r}, {fps!r}")
    views, moving = orbit_views(mesh.v, start, gaze_deg, n, fps, float(cfg["orbit_deg_s"]), cfg)
    tree, light, size = mesh.tree["relit"], optim.Lighting(), tuple(cfg["size"])
    T = tree.n_triangles

    def draw(m, k):
        v, f, c, normals = R.mesh_parts(m, "accuracy_motion")
        return R.render(v, f, c, views[k], lighting=light, mode="relit", size=size, normals=normals)

    frames = {m: [] for m in ("original", "imperceptible", "imperceptible+velocity", "perceptual",
                              "perceptual+velocity", "size", "geometric")}
    tris = {m: [] for m in frames}
    for k in range(n):
        still, moved = views[k], moving[k]
        keys, vkeys = optim.score(tree, still), optim.score(tree, moved)
        out = {"original": mesh.original("relit")}
        for name, kk, vw in (("imperceptible", keys, still), ("imperceptible+velocity", vkeys, moved)):
            out[name] = plod_mesh(tree, kk, vw, cfg, cut=optim.threshold_cut(tree, kk, 1.0, monotone="trust"))[0]
        out["perceptual"] = plod_mesh(tree, keys, still, cfg, max(int(cfg["budget"] * T), 1))[0]
        target = len(out["perceptual"][1])
        out["perceptual+velocity"] = plod_mesh(tree, vkeys, moved, cfg, target)[0]
        for metric in ("size", "geometric"):
            out[metric] = plod_mesh(tree, optim.score(tree, still, None, metric), still, cfg, target)[0]
        for name, m in out.items():
            frames[name].append(draw(m, k))
            tris[name].append(len(m[1]))
        if progress:
            progress("frames", k + 1, n)
    target = int(round(statistics.mean(tris["perceptual"])))
    for peer in PEERS:
        m = mesh.peer(peer, "relit", target)
        frames[peer] = [draw(m, k) for k in range(n)]
        tris[peer] = [len(m[1])] * n
    ref = np.stack(frames.pop("original"))
    rows = []
    for name, fr in frames.items():
        jod, still, _ = fovvdp_clip(ref, np.stack(fr), views[n // 2], fps, still_every=int(cfg["still_every"]))
        rows.append({"method": name, "triangles": float(np.mean(tris[name])), "triangles_min": int(min(tris[name])),
                     "triangles_max": int(max(tris[name])), "video_jod": jod, "still_jod": still})
    return rows


def run(cfg, out: Path, progress=None) -> list[dict]:
    """Every cell of ``cfg``; rows (one per method and cell) appended to ``out/results.jsonl`` as they come."""
    from experiments.accuracy import _Mesh, load_meshes
    from experiments.experiment import view_directions

    meshes = load_meshes(dict(cfg, views=1))
    out.mkdir(parents=True, exist_ok=True)
    path = out / "results.jsonl"
    path.write_text("")
    rows = []
    cells = [(m, g) for m in meshes for g in cfg["gaze_offsets_deg"]]
    for i, ((name, v, f, c), g) in enumerate(cells):
        mesh = _Mesh(name, v, f, c)
        start = view_directions(1, int(cfg["seed"]), name)[0]
        for r in clip_results(mesh, start, float(g), cfg):
            r.update(mesh=name, gaze_deg=float(g), input_triangles=int(len(f)), start=[round(float(x), 6) for x in start])
            rows.append(r)
            with open(path, "a") as fh:
                fh.write(json.dumps(r) + "\n")
        if progress:
            progress("clips", i + 1, len(cells))
    return rows


def summarise(rows) -> list[str]:
    """Markdown: the per-clip table and the headline numbers."""
    cells = list(dict.fromkeys((r["mesh"], r["gaze_deg"]) for r in rows))
    get = {(r["mesh"], r["gaze_deg"], r["method"]): r for r in rows}
    methods = list(dict.fromkeys(r["method"] for r in rows))
    L = ["| mesh | gaze deg | " + " | ".join(methods) + " |", "| --- | ---: | " + " | ".join("---:" for _ in methods) + " |"]
    for m, g in cells:
        L.append(f"| {m} | {g:g} | " + " | ".join(
            f"{get[(m, g, x)]['video_jod']:.3f} ({np.median(get[(m, g, x)]['still_jod']):.3f}; "
            f"{get[(m, g, x)]['triangles']:,.0f})" for x in methods) + " |")
    L += ["", "Each entry: video JOD (median still JOD; mean drawn triangles per frame).", ""]
    imp = [get[(m, g, "imperceptible")] for m, g in cells]
    impv = [get[(m, g, "imperceptible+velocity")] for m, g in cells]
    gain = [get[(m, g, "perceptual")]["video_jod"] - max(get[(m, g, x)]["video_jod"] for x in RIVALS) for m, g in cells]
    sgain = [np.median(get[(m, g, "perceptual")]["still_jod"]) - max(np.median(get[(m, g, x)]["still_jod"]) for x in RIVALS)
             for m, g in cells]
    vel = [get[(m, g, "perceptual+velocity")]["video_jod"] - get[(m, g, "perceptual")]["video_jod"] for m, g in cells]
    L += [f"- Imperceptible cuts in motion: video JOD {min(r['video_jod'] for r in imp):.3f} - "
          f"{max(r['video_jod'] for r in imp):.3f} ({sum(r['video_jod'] >= 9.8 for r in imp)} / {len(imp)} >= 9.8); "
          f"with velocity {min(r['video_jod'] for r in impv):.3f} - {max(r['video_jod'] for r in impv):.3f} "
          f"({sum(r['video_jod'] >= 9.8 for r in impv)} / {len(impv)} >= 9.8) at "
          f"{statistics.median(b['triangles'] / a['triangles'] for a, b in zip(imp, impv)):.2f}x the triangles (median).",
          f"- Perceptual budget cut against the best of {', '.join(RIVALS)} as video: best in "
          f"{sum(x > 0 for x in gain)} / {len(gain)}, median gain {statistics.median(gain):+.3f} JOD (min "
          f"{min(gain):+.3f}); as stills (median over the frames): best in {sum(x > 0 for x in sgain)} / "
          f"{len(sgain)}, median gain {statistics.median(sgain):+.3f}.",
          f"- Velocity in the budget keys (same drawn counts): video JOD {statistics.median(vel):+.3f} median "
          f"(better in {sum(x > 0 for x in vel)} / {len(vel)}).", ""]
    return L


def _plot(rows, path):
    from experiments import _figures

    plt = _figures.pyplot()
    fig, ax = plt.subplots(figsize=(6, 5))
    for i, m in enumerate(dict.fromkeys(r["method"] for r in rows)):
        x = [np.median(r["still_jod"]) for r in rows if r["method"] == m]
        y = [r["video_jod"] for r in rows if r["method"] == m]
        ax.scatter(x, y, s=18, color=f"C{i}", label=m)
    lo = min(min(r["video_jod"], min(r["still_jod"])) for r in rows) - 0.05
    ax.plot([lo, 10], [lo, 10], color="grey", linewidth=0.8)
    ax.set_xlabel("median still JOD over the clip's frames")
    ax.set_ylabel("video JOD (FovVideoVDP, fixation held)")
    ax.set_title("plod's cuts in motion: video against stills")
    ax.legend(fontsize=7)
    _figures.save_png(fig, path)


def check_config(cfg: dict) -> dict:
    """The values of a loaded config, checked before any work (PlodError naming the key): before, a
    bad ``frames`` or ``size`` was found only after the meshes' trees were built and the journal emptied,
    and a budget of -5 or a gaze of 1000 deg ran."""
    from experiments.experiment import _parse_procedural

    def num(x):
        return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)

    def whole(x, lo, hi=math.inf):
        return isinstance(x, int) and not isinstance(x, bool) and lo <= x <= hi

    def bad(key, want):
        raise PlodError(f"accuracy_motion: config key {key!r} must be {want}, got {cfg[key]!r}")

    if cfg["kind"] != "accuracy_motion":
        bad("kind", "'accuracy_motion'")
    if not all(isinstance(m, str) and m.strip() for m in cfg["meshes"]):
        bad("meshes", "a list of mesh file paths")
    if not all(isinstance(s, str) and _parse_procedural(s) is not None for s in cfg["procedural"]):
        bad("procedural", "a list of 'sphere:SUBDIV:SEED' or 'torus:NU:NV:SEED'")
    g = cfg["gaze_offsets_deg"]
    if not g or not all(num(x) and 0 <= x < 80 for x in g) or len({float(x) for x in g}) != len(g):
        bad("gaze_offsets_deg", "a non-empty list of distinct angles in [0, 80) deg")
    if not (num(cfg["gaze_error_deg"]) and 0 <= cfg["gaze_error_deg"] < 90):
        bad("gaze_error_deg", "an angle in [0, 90) deg")
    if not (num(cfg["object_deg"]) and 0 < cfg["object_deg"] < 180):
        bad("object_deg", "an angle in (0, 180) deg")
    if not (num(cfg["budget"]) and 0 < cfg["budget"] <= 1):
        bad("budget", "a fraction of the input's triangles in (0, 1]")
    if not (num(cfg["orbit_deg_s"]) and 0 <= cfg["orbit_deg_s"] <= 3600):
        bad("orbit_deg_s", "an angular speed in [0, 3600] deg/s")
    if not (num(cfg["fps"]) and 0 < cfg["fps"] <= 1000):
        bad("fps", "a frame rate in (0, 1000] Hz")
    if not whole(cfg["frames"], 2, 10_000):
        bad("frames", "an integer in 2..10000")
    if not whole(cfg["still_every"], 1):
        bad("still_every", "an integer >= 1")
    if len(cfg["size"]) != 2 or not all(whole(x, 16, 8192) for x in cfg["size"]):
        bad("size", "two integers in 16..8192 (width, height in pixels)")
    if not isinstance(cfg["face_cull"], bool):
        bad("face_cull", "true or false")
    return cfg


def run_config(path, out=None, progress=None) -> Path:
    from experiments.accuracy import absent_line

    cfg = check_config(load_config(path, DEFAULTS))
    command = "python -m experiments.accuracy_motion" + (f" --config {path}" if path else "")
    try:
        import pyfvvdp  # noqa: F401
    except ImportError:
        raise PlodError("accuracy_motion: the judge extra is missing (pip install -e '.[judge]')") from None
    out = check_out_dir(Path(out or repo_path(cfg["out"])), config=path,
                        writes=("report.md", "results.jsonl", "video_vs_still.png"))
    rows = run(cfg, out, progress)
    head = ["# Plod's cuts judged in motion (FovVideoVDP on rendered orbits)", "",
            f"Command: `{command}`. Relit, {cfg['frames']} frames at "
            f"{cfg['fps']:g} fps, the camera orbiting the object's centre at {cfg['orbit_deg_s']:g} deg/s about the "
            f"vertical, object {cfg['object_deg']:g} deg, rendered at {cfg['size'][0]} x {cfg['size'][1]}, budget "
            f"{cfg['budget']:.0%} of the input, face culling {'on' if cfg['face_cull'] else 'off'}; every cut "
            "recomputed per frame; the peers simplified once at the perceptual cut's mean drawn count. Video: the "
            "clip judged by FovVideoVDP with the fixation held at the gaze; stills: one frame in "
            f"{cfg['still_every']} judged alone. Meshes in no test and not in the accuracy sweep.", ""]
    absent = absent_line(cfg)
    if absent:
        head.append(absent)
    atomic_write_text(out / "report.md", "\n".join(head + summarise(rows)))
    _plot(rows, out / "video_vs_still.png")
    save_run_info(out, cfg, cfg["seed"], command)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="accuracy_motion", description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=None)
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    from experiments._progress import rich_progress

    with rich_progress("accuracy motion") as cb:
        out = run_config(a.config, a.out, cb)
    print(f"wrote {out / 'report.md'}")
    return 0


if __name__ == "__main__":
    run_script(main)

"""Reddy's terrain criteria judged in motion: short clips of the flight rendered and scored as video.

    python -m experiments.terrain_motion configs/terrain_motion.toml [--out reports/terrain/motion]
    (equivalently: plod experiment configs/terrain_motion.toml)

The velocity criterion [Red01] coarsens what moves fast across the retina of an eye that holds its gaze
on the screen while the terrain flows past. A still frame cannot show that (the stills in
``experiments/terrain.py`` judge it at its worst); FovVideoVDP [Man21] on the rendered clip can: its
temporal channels weigh each change by the spatio-temporal CSF at the speed it moves, with the fixation
held at the gaze (the view centre) as the criterion assumes. An eye that pursues the terrain instead
sees it nearly still, so the still-frame scores bound that case.

For each terrain and clip (``clip_frames`` consecutive frames of the flight from each of
``clip_starts``, at the flight's fps) every criteria set is refined frame by frame (velocity from the
three previous cameras), rendered relit in the judged window of ``experiments.terrain.terrain_view``,
and scored against the full terrain as a video and frame by frame as stills. Controls: size + cull with
up to ``controls_px`` pixels of screen-space error (xi / k [Red01 Eq 5]), a coarsening that ignores
motion, for triangle counts near the velocity criterion's. Writes ``motion.md`` (the table),
``clips_<terrain>.png`` (still JOD per frame with the video JOD), ``clip<start>_<terrain>_<set>.png``
(the middle frame: renderings, the video's difference map at that frame, FLIP) and ``run_info.json``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from experiments._runinfo import check_out_dir, load_config, repo_path, run_script, save_run_info
from experiments.terrain import DEFAULTS as TERRAIN_DEFAULTS
from experiments.terrain import (FLIGHT, check_config, check_flight, check_frames, config_main, flight_cameras,
                                 judge_ppd, load_terrains, mean_angular_velocity, named_criteria, terrain_view)
from optim._terrain import TerrainCriteria, refine_terrain
from pmetric import PlodError, atomic_write_text

DEFAULTS = {"kind": "terrain_motion", "out": "reports/terrain/motion", "seed": 0,
            **{k: TERRAIN_DEFAULTS[k] for k in ("fractal_size", "fractal_spacing_m", "fractal_relief_m", "flight",
                                                "resolution", "judge_px_per_deg")},
            "clip_starts": [60, 300], "clip_frames": 30, "controls_px": [8],
            "criteria": ["cull", "size + periphery + cull", "all"]}


def clip_criteria(xi: float, names, controls_px) -> dict:
    """{label: TerrainCriteria}: the named sets of :func:`experiments.terrain.named_criteria` at ``xi``
    (cycles/deg) and, per k in ``controls_px``, size + cull at xi / k ("size + cull, k px")."""
    named = named_criteria(xi)
    bad = [n for n in names if n not in named]
    if bad:
        raise PlodError(f"terrain_motion: unknown criteria {bad!r}; choose from {sorted(named)}")
    if not names and not controls_px:
        raise PlodError("terrain_motion: config keys 'criteria' and 'controls_px' are both empty: nothing to judge")
    out = {n: named[n] for n in names}
    for k in controls_px:
        if not float(k) >= 1:
            raise PlodError(f"terrain_motion: controls_px must be >= 1 pixel, got {k!r}")
        out[f"size + cull, {float(k):g} px"] = TerrainCriteria(periphery=False, velocity=False, xi=xi / float(k))
    return out


def judge_clip(hf, cams, criteria: dict, start: int, frames: int, fps: float, *, px_per_deg: float = 6.4,
               size=None, out_dir=None, tag: str = "", progress=None) -> list[dict]:
    """Judge each criteria set's terrain against the full terrain over ``frames`` frames of the flight from
    ``start`` (>= 3), as a video at ``fps`` (Hz) and frame by frame as stills.

    ``criteria``: {label: TerrainCriteria}; rendering relit from the meshes' own normals with
    ``optim.Lighting``'s default in :func:`experiments.terrain.terrain_view` (``px_per_deg`` px/deg;
    ``size`` (w, h) renders smaller with the same angular content). Returns one row per set: {start,
    frames, criteria, triangles (mean per frame), video_jod, still_jod (list, per frame)}. With
    ``out_dir``: ``clip{start}_{tag}_{label}.png``, the middle frame with the video's map at that frame.
    """
    import optim
    from experiments import render as R
    from experiments.judge import JudgeResult, fixation_px, fovvdp_clip, pixels_per_degree, save_judgement
    from optim._terrain import full_mesh, terrain_mesh

    start, frames = int(start), int(frames)
    if start < 3 or frames < 1 or start + frames > len(cams):
        raise PlodError(f"terrain_motion: clip of {frames} frames from {start} must lie in 3..{len(cams) - 1} "
                        "of the flight")
    light = optim.Lighting()
    views = [terrain_view(cams[k], px_per_deg=px_per_deg) for k in range(start, start + frames)]
    fv, ff = full_mesh(hf)
    ref = np.stack([R.render(fv, ff, None, v, lighting=light, mode="relit", size=size) for v in views])
    rows, mid = [], frames // 2
    for i, (label, crit) in enumerate(criteria.items()):
        tst, tris = [], []
        for j, k in enumerate(range(start, start + frames)):
            lod = refine_terrain(hf, cams[k], crit, (cams[k - 1], cams[k - 2], cams[k - 3]), dt_s=1.0 / fps)
            V, F, _ = terrain_mesh(hf, lod)
            tst.append(R.render(V, F, None, views[j], lighting=light, mode="relit", size=size))
            tris.append(lod.triangles)
        tst = np.stack(tst)
        jod, still, vmap = fovvdp_clip(ref, tst, views[mid], fps, heatmap=out_dir is not None)
        rows.append({"start": start, "frames": frames, "criteria": label, "triangles": float(np.mean(tris)),
                     "video_jod": jod, "still_jod": still})
        if out_dir is not None:
            h, w = ref.shape[1:3]
            fmap, fmean = R.flip(ref[mid], tst[mid], pixels_per_degree(views[mid], (w, h)))
            res = JudgeResult(jod, fmean, ref[mid], tst[mid], vmap[mid], fmap, pixels_per_degree(views[mid], (w, h)),
                              fixation_px(views[mid], (w, h)), 0.0, "relit")
            save_judgement(Path(out_dir) / f"clip{start}_{tag}_{_slug(label)}.png", res,
                           titles=(f"full terrain, frame {start + mid}",
                                   f"{label}: {tris[mid]:,} triangles (video JOD, map at this frame)"))
        if progress:
            progress(f"clips {tag}", i + 1, len(criteria))
    return rows


def _slug(label: str) -> str:
    return label.replace(" + ", "_").replace(", ", "_").replace(" ", "")


def run_config(path, out=None, progress=None) -> Path:
    """Run the motion clips of config ``path`` into ``out`` (default the config's); returns it."""
    cfg = load_config(path, DEFAULTS)
    if cfg["kind"] != "terrain_motion":
        raise PlodError(f"terrain_motion: config kind must be 'terrain_motion', got {cfg['kind']!r}")
    check_config(cfg, "terrain_motion")
    try:
        import pyfvvdp  # noqa: F401
    except ImportError:
        raise PlodError("terrain_motion: the judge extra is missing (pip install -e '.[judge]')") from None
    fl = check_flight(load_config(repo_path(cfg["flight"]), FLIGHT), cfg["flight"])
    check_frames(cfg, fl, "terrain_motion")
    out = check_out_dir(Path(out or repo_path(cfg["out"])), config=path, writes=("motion.md", "motion.json"))
    fov = tuple(fl["fov_deg"])
    xi = float(cfg["resolution"][0]) / (2.0 * fov[0])
    ppd = judge_ppd(cfg, xi, "terrain_motion")
    crits = clip_criteria(xi, cfg["criteria"], cfg["controls_px"])
    n = int(cfg["clip_frames"])
    lines = ["# Reddy's terrain criteria judged in motion (FovVideoVDP on rendered clips of the flight)", "",
             f"Command: `python -m experiments.terrain_motion {path}`. Flight: {cfg['flight']} at {fl['fps']:g} fps; "
             f"clips of {n} frames ({n / fl['fps']:.2f} s) from frames {', '.join(map(str, cfg['clip_starts']))}; "
             f"xi = {xi:.2f} cycles/deg; every frame refined with the velocity from the three previous cameras. "
             f"Rendered relit in a 90 x 60 deg pinhole window at {ppd:.1f} px/deg around the view direction, the "
             "gaze (fixation) held at the view centre. *Video*: FovVideoVDP [Man21] on the clip at the flight's "
             "frame rate (its temporal channels see the terrain move past the fixed gaze, the retinal motion the "
             "velocity criterion assumes); *stills*: each frame judged alone (an eye that pursues the terrain "
             "sees it about still). Controls: size + cull at xi / k (up to k pixels of error), a coarsening that "
             "ignores motion.", ""]
    rows_all = []
    for name, hf in load_terrains(cfg):
        cams = flight_cameras(hf, fl)
        tag = name.replace(" ", "_").lower()
        rows = []
        for s in cfg["clip_starts"]:
            w = mean_angular_velocity(cams[int(s):int(s) + n], fl["fps"]) if n > 1 else float("nan")
            for r in judge_clip(hf, cams, crits, s, n, fl["fps"], px_per_deg=ppd, out_dir=out, tag=tag,
                                progress=progress):
                r.update(terrain=name, full_triangles=hf.full_triangles, angular_velocity=w)
                rows.append(r)
        _save_plot(out / f"clips_{tag}.png", rows, name)
        rows_all += rows
    lines += motion_tables(rows_all)
    atomic_write_text(out / "motion.md", "\n".join(lines))
    atomic_write_text(out / "motion.json", json.dumps(rows_all, indent=1) + "\n")
    save_run_info(out, {"config": cfg, "flight": fl}, cfg["seed"], "python -m experiments.terrain_motion " + str(path))
    return out


def motion_tables(rows) -> list[str]:
    """Markdown lines: per terrain, one row per clip and criteria set of :func:`judge_clip`'s rows (with
    ``terrain``, ``full_triangles`` and ``angular_velocity`` added)."""
    lines = []
    for name in dict.fromkeys(r["terrain"] for r in rows):
        mine = [r for r in rows if r["terrain"] == name]
        full, tag = mine[0]["full_triangles"], name.replace(" ", "_").lower()
        lines += [f"## {name}: {full:,} triangles", "",
                  "| clip (frames) | view rotation deg/s | criteria | triangles / frame | % of full | video JOD | "
                  "stills: median JOD | min |", "| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: |"]
        for r in mine:
            st = np.asarray(r["still_jod"])
            lines.append(f"| {r['start']}-{r['start'] + r['frames'] - 1} | {r['angular_velocity']:.1f} | "
                         f"{r['criteria']} | {r['triangles']:,.0f} | {100 * r['triangles'] / full:.2f} | "
                         f"{r['video_jod']:.3f} | {np.median(st):.3f} | {st.min():.3f} |")
        lines += ["", f"Still JOD per frame and the video JOD: `clips_{tag}.png`; middle frames: "
                  f"`clip<start>_{tag}_<criteria>.png`.", ""]
    return lines


def _save_plot(path, rows, name):
    from experiments import _figures

    plt = _figures.pyplot()
    starts = sorted({r["start"] for r in rows})
    fig, axes = plt.subplots(1, len(starts), figsize=(5.5 * len(starts), 4), squeeze=False, sharey=True)
    for ax, s in zip(axes[0], starts):
        for i, r in enumerate(x for x in rows if x["start"] == s):
            c = f"C{i}"
            k = np.arange(s, s + len(r["still_jod"]))
            ax.plot(k, r["still_jod"], color=c, label=f"{r['criteria']} ({r['triangles']:,.0f})")
            ax.axhline(r["video_jod"], color=c, linestyle="--")
        ax.set_xlabel("frame")
        ax.set_title(f"{name}, frames {s}-{s + len(r['still_jod']) - 1}")
    axes[0][0].set_ylabel("JOD (solid: each still; dashed: the clip as video)")
    axes[0][-1].legend(fontsize=7, loc="lower right")
    _figures.save_png(fig, path)


def main(argv=None) -> int:
    return config_main(argv, "terrain_motion", __doc__.splitlines()[0], run_config, "motion.md")

if __name__ == "__main__":
    run_script(main)

"""Seed 000 Table 1 and Figure 4: Reddy's perceptual terrain LOD over a recorded (generated) flight [Red01].

    python -m experiments.terrain configs/terrain_table1.toml [--out reports/terrain]

Writes ``table1.md`` (mean triangles per frame and % of the full terrain per criteria combination, beside
the seed's), ``fig4.png`` (triangles per frame over imposed velocity x square field of view), the refinement
time per frame (ms, median and worst) and ``run_info.json``. ``run_config(path, out, progress)`` is the
entry point for ``plod experiment`` configs with ``kind = "terrain"``.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from experiments._runinfo import (check_out_dir, config_numbers, load_config, repo_path, run_script,
                                 save_run_info)
from optim._terrain import (Heightfield, TerrainCamera, TerrainCriteria, fractal_heightfield, refine_terrain)
from pmetric import PlodError, atomic_write_text

DEFAULTS = {"kind": "terrain", "out": "reports/terrain", "seed": 0, "fractal_size": 1025,
            "fractal_spacing_m": 10.0, "fractal_relief_m": 600.0, "flight": "configs/terrain_flight.toml",
            "frame_step": 10, "resolution": [1280, 864], "fig4_velocities": [0.0, 30.0, 60.0, 90.0, 120.0],
            "fig4_fovs": [30.0, 60.0, 90.0, 135.0, 180.0], "fig4_frame_step": 60,
            "pixel_errors": [1, 2, 4, 8], "scale_size": 0, "scale_frames": 3,
            "judge_frames": [], "judge_px_per_deg": 0.0}
FLIGHT = {"duration_s": 20.0, "fps": 30.0, "orbit_frac": 0.3, "orbit_turns": 0.5, "altitude_m": 150.0,
          "pitch_deg": -20.0, "yaw_amp_deg": 50.0, "yaw_period_s": 4.0, "fov_deg": [200.0, 135.0]}
# seed 000 Table 1: (size, periphery, velocity, cull) -> % of the full terrain
SEED_TABLE = [((0, 0, 0, 0), 100.0), ((0, 0, 0, 1), 40.3), ((1, 0, 0, 1), 5.4), ((1, 1, 0, 1), 3.6),
              ((1, 0, 1, 1), 5.4), ((1, 1, 1, 1), 0.8)]


MAX_FRAMES = 1_000_000  # frames of a flight
MAX_PX = 1e4  # pixels of screen-space error (xi / k)
PPD_RANGE = (1.0, 40.0)  # pixels per degree of a judged window (90 x 60 deg: 90 x 60 .. 3600 x 2400 pixels)


def _grid_size(n) -> bool:
    return isinstance(n, int) and not isinstance(n, bool) and n >= 3 and (n - 1) & (n - 2) == 0


def check_config(cfg: dict, who: str = "terrain") -> dict:
    """``cfg`` itself when every value the terrain experiments read is in range; PlodError naming the key
    otherwise (the loader checks only names and types)."""
    def bad(key, want):
        raise PlodError(f"{who}: config key {key!r} must be {want}, got {cfg[key]!r}")

    checks = {
        "fractal_size": (_grid_size, "2^n + 1 samples (3, 5, 9, ..., 1025)"),
        "fractal_spacing_m": (lambda x: config_numbers([x], lo=0, strict=True), "a finite number of metres > 0"),
        "fractal_relief_m": (lambda x: config_numbers([x], lo=0, strict=True), "a finite number of metres > 0"),
        "resolution": (lambda x: config_numbers(x, 2, lo=1, ints=True), "two pixel counts >= 1 (across, down)"),
        "judge_px_per_deg": (lambda x: x == 0 or config_numbers([x], lo=PPD_RANGE[0]) and x <= PPD_RANGE[1],
                             f"0 (twice xi) or {PPD_RANGE[0]:g} .. {PPD_RANGE[1]:g} pixels per degree"),
        "frame_step": (lambda x: config_numbers([x], lo=1, ints=True), "an integer >= 1"),
        "fig4_frame_step": (lambda x: config_numbers([x], lo=1, ints=True), "an integer >= 1"),
        "fig4_velocities": (lambda x: config_numbers(x, lo=0), "a non-empty list of velocities >= 0 deg/s"),
        "fig4_fovs": (lambda x: config_numbers(x, lo=0, strict=True) and max(x) <= 180,
                      "a non-empty list of square fields of view in (0, 180] deg"),
        "pixel_errors": (lambda x: config_numbers(x, lo=0, strict=True) and max(x) <= MAX_PX,
                         f"a non-empty list of pixel errors in (0, {MAX_PX:g}]"),
        "scale_size": (lambda x: x == 0 or _grid_size(x), "0 (no scale test) or 2^n + 1 samples"),
        "scale_frames": (lambda x: config_numbers([x], lo=1, ints=True), "an integer >= 1"),
        "judge_frames": (lambda x: config_numbers(x, lo=3, ints=True, empty=True), "a list of flight frames >= 3"),
        "clip_starts": (lambda x: config_numbers(x, lo=3, ints=True), "a non-empty list of flight frames >= 3"),
        "clip_frames": (lambda x: config_numbers([x], lo=1, ints=True), "an integer >= 1"),
        "controls_px": (lambda x: config_numbers(x, lo=1, empty=True) and max(x, default=1) <= MAX_PX,
                        f"a list of pixel errors in [1, {MAX_PX:g}]"),
    }
    for key, (ok, want) in checks.items():
        if key in cfg and not ok(cfg[key]):
            bad(key, want)
    return cfg


def check_flight(fl: dict, path) -> dict:
    """``fl`` itself when the flight's values are usable; PlodError naming the key and file otherwise."""
    def bad(key, want):
        raise PlodError(f"terrain flight {str(path)!r}: {key!r} must be {want}, got {fl[key]!r}")

    for key in ("duration_s", "fps", "yaw_period_s"):
        if not config_numbers([fl[key]], lo=0, strict=True):
            bad(key, "a finite number > 0")
    n = flight_frames(fl)
    if not 4 <= n <= MAX_FRAMES:  # each refined frame takes its velocity from the three before it
        bad("duration_s", f"such that duration_s x fps (= {fl['duration_s'] * fl['fps']:g}) gives 4 .. "
            f"{MAX_FRAMES:,} frames")
    for key in ("orbit_frac", "orbit_turns", "altitude_m", "yaw_amp_deg"):
        if not config_numbers([fl[key]]):
            bad(key, "a finite number")
    if not config_numbers([fl["pitch_deg"]]) or abs(fl["pitch_deg"]) >= 90:
        bad("pitch_deg", "an angle in (-90, 90) deg")
    f = fl["fov_deg"]
    if not config_numbers(f, 2, lo=0, strict=True) or f[0] > 360 or f[1] > 180:
        bad("fov_deg", "two angles in (0, 360] x (0, 180] deg")
    return fl


def flight_frames(fl: dict) -> int:
    """Frames of the flight ``fl``: round(duration_s x fps) + 1."""
    return int(min(round(fl["duration_s"] * fl["fps"]), 2 * MAX_FRAMES)) + 1


def check_frames(cfg: dict, fl: dict, who: str = "terrain"):
    """PlodError naming the key when a judged frame or clip of ``cfg`` lies outside flight ``fl``'s frames
    (a refined frame needs the three before it: frames 3 .. n - 1)."""
    n = flight_frames(fl)
    for k in cfg.get("judge_frames", []):
        if not 3 <= k < n:
            raise PlodError(f"{who}: config key 'judge_frames' has frame {k}, outside the flight's 3 .. {n - 1}")
    for s in cfg.get("clip_starts", []):
        if not (3 <= s and s + cfg["clip_frames"] <= n):
            raise PlodError(f"{who}: config key 'clip_starts' has a clip of {cfg['clip_frames']} frames from frame "
                            f"{s}, outside the flight's 3 .. {n - 1}")


def judge_ppd(cfg: dict, xi: float, who: str = "terrain") -> float:
    """Pixels per degree of the judged window: ``judge_px_per_deg``, or 2 xi when that is 0; PlodError
    when 2 xi (from ``resolution``) falls outside the range a judged rendering can have."""
    ppd = float(cfg["judge_px_per_deg"]) or 2.0 * xi
    if not PPD_RANGE[0] <= ppd <= PPD_RANGE[1]:
        raise PlodError(f"{who}: judge_px_per_deg = 0 takes twice xi, {ppd:g} pixels per degree from 'resolution' "
                        f"{cfg['resolution']}, outside {PPD_RANGE[0]:g} .. {PPD_RANGE[1]:g}; set judge_px_per_deg")
    return ppd


def flight_cameras(hf: Heightfield, fl: dict, fov=None) -> list[TerrainCamera]:
    """The cameras of the generated flight (one per frame, 1 / fps s apart)."""
    n = flight_frames(fl)
    if not 4 <= n <= MAX_FRAMES:
        raise PlodError(f"terrain flight: duration_s x fps must give 4 .. {MAX_FRAMES:,} frames, got {n}")
    side = (hf.n - 1) * hf.spacing
    t = np.arange(n) / fl["fps"]
    phi = 2 * math.pi * fl["orbit_turns"] * t / fl["duration_s"]
    rad = fl["orbit_frac"] * side
    y = float(hf.heights.max()) + fl["altitude_m"]
    heading = phi + math.pi / 2 + np.radians(fl["yaw_amp_deg"]) * np.sin(2 * math.pi * t / fl["yaw_period_s"])
    pitch = math.radians(fl["pitch_deg"])
    fov = tuple(fl["fov_deg"]) if fov is None else fov
    cams = []
    for k in range(n):
        eye = np.array([0.5 * side + rad * math.cos(phi[k]), y, 0.5 * side + rad * math.sin(phi[k])])
        fwd = np.array([math.cos(pitch) * math.cos(heading[k]), math.sin(pitch), math.cos(pitch) * math.sin(heading[k])])
        cams.append(TerrainCamera(eye=eye, forward=fwd, fov_deg=fov))
    return cams


def mean_angular_velocity(cams, fps) -> float:
    """Mean angle (deg) between successive view directions times fps (deg/s)."""
    f = np.array([c.forward / np.linalg.norm(c.forward) for c in cams])
    return float(np.degrees(np.arccos(np.clip((f[1:] * f[:-1]).sum(1), -1, 1))).mean() * fps)


def run_flight(hf, cams, crit, fps, step, progress=None, label=""):
    """(triangles per refined frame, seconds per refinement) over every ``step``-th frame."""
    tris, secs = [], []
    frames = list(range(3, len(cams), step))
    refine_terrain(hf, cams[3], crit, (cams[2], cams[1], cams[0]), dt_s=1.0 / fps)  # warm-up: compiles H'(v, e)
    for i, k in enumerate(frames):
        prev = (cams[k - 1], cams[k - 2], cams[k - 3])
        t0 = time.perf_counter()
        tris.append(refine_terrain(hf, cams[k], crit, prev, dt_s=1.0 / fps).triangles)
        secs.append(time.perf_counter() - t0)
        if progress:
            progress(label, i + 1, len(frames))
    return np.array(tris), np.array(secs)


def load_terrains(cfg):
    """[(name, Heightfield)]: the fractal, and Mt St Helens cropped to 257 x 257 when the data exists."""
    out = [(f"fractal {cfg['fractal_size']}", Heightfield(
        fractal_heightfield(cfg["fractal_size"], seed=cfg["seed"], relief=cfg["fractal_relief_m"]),
        cfg["fractal_spacing_m"]))]
    pgm = repo_path("../shared/data/terrain/SainteHelens_30m.pgm")
    if pgm.is_file():
        from optim._terrain import crop_heightfield

        z = read_pgm(pgm)
        out.append(("St Helens 257", Heightfield(crop_heightfield(z, 257), 30.0)))  # centre crop: no 0 = nodata
    return out


def read_pgm(path) -> np.ndarray:
    """The samples (rows, columns) float64 of the greyscale PGM (P2 or P5) ``path`` as stored in the file.

    Pillow reads it but rescales every sample to 0..255 or 0..65535 from the header's maxval (a DEM whose
    maxval is its highest elevation, 2543, came out 25.8x too tall): the maxval is read from the header
    here and the rescaling undone (exactly: Pillow rounds v / maxval * top, and round(p maxval / top)
    recovers v for maxval <= top). PlodError naming the file for anything that is not such a PGM."""
    from PIL import Image

    try:
        with open(path, "rb") as f:
            head = f.read(4096)
        tokens = []
        for line in head.split(b"\n"):  # magic, width, height, maxval, with '#' comments
            tokens += line.split(b"#", 1)[0].split()
            if len(tokens) >= 4:
                break
        if len(tokens) < 4 or tokens[0] not in (b"P2", b"P5") or not tokens[3].isdigit():
            raise PlodError(f"terrain: {str(path)!r} is not a greyscale PGM (P2 or P5 with a maxval)")
        maxval = int(tokens[3])
        with Image.open(path) as im:
            if im.mode not in ("L", "I", "I;16", "I;16B"):
                raise PlodError(f"terrain: {str(path)!r} is not a greyscale PGM (mode {im.mode})")
            p = np.asarray(im, dtype=np.float64)
    except PlodError:
        raise
    except (OSError, ValueError) as exc:  # UnidentifiedImageError is an OSError
        raise PlodError(f"terrain: cannot read the PGM {str(path)!r}: {exc}") from None
    top = 255 if maxval <= 255 else 65535
    return p if maxval == top else np.round(p * (maxval / top))


def run_config(path, out=None, progress=None) -> Path:
    """Run the terrain experiment of config ``path`` into ``out`` (default the config's); returns it."""
    cfg = load_config(path, DEFAULTS)
    if cfg["kind"] != "terrain":
        raise PlodError(f"terrain: config kind must be 'terrain', got {cfg['kind']!r}")
    check_config(cfg)
    fl = check_flight(load_config(repo_path(cfg["flight"]), FLIGHT), cfg["flight"])
    check_frames(cfg, fl)
    out = check_out_dir(Path(out or repo_path(cfg["out"])), config=path, writes=("table1.md", "fig4.png"))
    fov = tuple(fl["fov_deg"])
    xi = float(cfg["resolution"][0]) / (2.0 * fov[0])
    if cfg["judge_frames"]:
        judge_ppd(cfg, xi)
    lines = [f"# Seed 000 Table 1 and Figure 4 (Reddy's perceptual terrain LOD)", "",
             f"Command: `python -m experiments.terrain {path}`. Flight: {cfg['flight']} ({fl['duration_s']} s at "
             f"{fl['fps']} fps, every {cfg['frame_step']}th frame refined), FOV {fov[0]:g} x {fov[1]:g} deg, "
             f"xi = {cfg['resolution'][0]} px / (2 x {fov[0]:g} deg) = {xi:.2f} cycles/deg, gaze at the view centre.", ""]
    for name, hf in load_terrains(cfg):
        cams = flight_cameras(hf, fl)
        w = mean_angular_velocity(cams, fl["fps"])
        lines += [f"## {name}: {hf.full_triangles:,} triangles, mean angular velocity of the flight {w:.1f} deg/s", "",
                  "| size | periphery | velocity | cull | mean triangles / frame | % of full | seed % | ms / frame median | worst |",
                  "| --- | --- | --- | --- | ---: | ---: | ---: | ---: | ---: |"]
        for (s, p, v, c), seed_pct in SEED_TABLE:
            crit = TerrainCriteria(size=bool(s), periphery=bool(p), velocity=bool(v), cull=bool(c), xi=xi)
            tris, secs = run_flight(hf, cams, crit, fl["fps"], cfg["frame_step"], progress, name)
            yn = lambda b: "yes" if b else "no"
            lines.append(f"| {yn(s)} | {yn(p)} | {yn(v)} | {yn(c)} | {tris.mean():,.0f} | "
                         f"{100 * tris.mean() / hf.full_triangles:.2f} | {seed_pct} | {1e3 * np.median(secs):.1f} | "
                         f"{1e3 * secs.max():.1f} |")
        lines.append("")
        lines += _pixel_sweep(hf, cams, cfg, fl, xi, progress, name)
        lines += _judged_section(hf, cams, cfg, fl, xi, out, name, progress)
        if name.startswith("fractal"):
            fig = _figure4(hf, fl, cfg, xi, progress)
            _save_fig4(out / "fig4.png", fig, cfg)
            lines += ["Figure 4 (`fig4.png`): mean triangles per frame, all criteria, imposed uniform retinal velocity "
                      "x square field of view (the seed plotted frame time).", "",
                      "| velocity deg/s \\ FOV deg | " + " | ".join(f"{f:g}" for f in cfg["fig4_fovs"]) + " |",
                      "| --- | " + " | ".join("---:" for _ in cfg["fig4_fovs"]) + " |"]
            for i, v in enumerate(cfg["fig4_velocities"]):
                lines.append(f"| {v:g} | " + " | ".join(f"{x:,.0f}" for x in fig[i]) + " |")
            lines.append("")
    if cfg["scale_size"]:
        lines += _scale_test(cfg, fl, xi, progress)
    atomic_write_text(out / "table1.md", "\n".join(lines))
    save_run_info(out, {"config": cfg, "flight": fl}, cfg["seed"], "python -m experiments.terrain " + str(path))
    return out


def named_criteria(xi) -> dict:
    """{label: TerrainCriteria} of the judged and scale-test rows at display cap ``xi`` (cycles/deg)."""
    return {"cull": TerrainCriteria(size=False, periphery=False, velocity=False, xi=xi),
            "size + cull": TerrainCriteria(periphery=False, velocity=False, xi=xi),
            "size + periphery + cull": TerrainCriteria(velocity=False, xi=xi), "all": TerrainCriteria(xi=xi)}


def _pixel_sweep(hf, cams, cfg, fl, xi, progress, name):
    """Table rows: size + cull and all criteria with the display cap xi / k (screen-space errors up to k
    pixels [Red01 Eq 5]: "by halving xi, we allow screen-space errors of up to 2 pixels")."""
    if not cfg["pixel_errors"]:
        return []
    out = ["Screen-space error allowed (xi / k, up to k pixels [Red01 Eq 5]), same flight:", "",
           "| k pixels | xi cycles/deg | size + cull: triangles / frame | % | all criteria: triangles / frame | % "
           "| all: ms / frame median | worst |", "| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for k in cfg["pixel_errors"]:
        x = xi / float(k)
        crits = named_criteria(x)
        sc, _ = run_flight(hf, cams, crits["size + cull"], fl["fps"], cfg["frame_step"], progress, f"{name} xi/{k}")
        al, secs = run_flight(hf, cams, crits["all"], fl["fps"], cfg["frame_step"], progress, f"{name} xi/{k}")
        out.append(f"| {k} | {x:.2f} | {sc.mean():,.0f} | {100 * sc.mean() / hf.full_triangles:.2f} | {al.mean():,.0f} | "
                   f"{100 * al.mean() / hf.full_triangles:.2f} | {1e3 * np.median(secs):.1f} | {1e3 * secs.max():.1f} |")
    return out + [""]


def _judged_section(hf, cams, cfg, fl, xi, out, name, progress):
    """Table rows: rendered frames judged against the full terrain (:func:`judge_frames`), PNGs in ``out``."""
    if not cfg["judge_frames"]:
        return []
    try:
        import pyfvvdp  # noqa: F401
    except ImportError:
        return ["Rendered frames: not judged (the judge extra is missing: pip install -e '.[judge]').", ""]
    ppd = judge_ppd(cfg, xi)
    crits = named_criteria(xi)
    tag = name.replace(" ", "_").lower()
    try:
        rows = judge_frames(hf, cams, crits, cfg["judge_frames"], fl["fps"], out_dir=out / f"frames_{tag}",
                            px_per_deg=ppd, progress=progress)
    except RuntimeError as exc:  # no OpenGL context
        return [f"Rendered frames: not judged ({exc}).", ""]
    v = terrain_view(cams[cfg["judge_frames"][0]], px_per_deg=ppd)
    lines = [f"Rendered frames judged against the full terrain ({hf.full_triangles:,} triangles): FovVideoVDP "
             f"[Man21] foveated at the gaze (view centre) and FLIP [And20] on a {v.width} x {v.height} pinhole "
             f"window 90 x 60 deg around the view direction at {ppd:.1f} px/deg (the seed's 200 x 135 deg has no "
             f"pinhole rendering), relit from each mesh's own normals; a still frame, so the judge sees no retinal "
             f"motion (the velocity criterion is judged at its worst). PNGs in `frames_{tag}/`.", "",
             "| frame | criteria | triangles | JOD | FLIP mean |", "| ---: | --- | ---: | ---: | ---: |"]
    for r in rows:
        lines.append(f"| {r['frame']} | {r['criteria']} | {r['triangles']:,} | {r['jod']:.3f} | {r['flip']:.4f} |")
    return lines + [""]


def _scale_test(cfg, fl, xi, progress):
    """The scale test: build time and a few refined frames of a ``scale_size`` fractal."""
    n = int(cfg["scale_size"])
    t0 = time.perf_counter()
    z = fractal_heightfield(n, seed=cfg["seed"], relief=cfg["fractal_relief_m"] * (n - 1) / (cfg["fractal_size"] - 1))
    t1 = time.perf_counter()
    hf = Heightfield(z, cfg["fractal_spacing_m"])
    t2 = time.perf_counter()
    cams = flight_cameras(hf, fl)
    step = max(1, (len(cams) - 4) // max(1, int(cfg["scale_frames"])))
    out = [f"## Scale test: fractal {n} x {n} ({hf.full_triangles:,} triangles; same spacing, relief "
           f"scaled with the side, the orbit a fraction of the side)", "",
           f"Synthesis {t1 - t0:.1f} s, quadtree pyramid {t2 - t1:.1f} s; {int(cfg['scale_frames'])} frames "
           f"{step} frames apart.", "",
           "| criteria | mean triangles / frame | % of full | ms / frame median | worst |",
           "| --- | ---: | ---: | ---: | ---: |"]
    for label in ("cull", "size + cull", "all"):
        crit = named_criteria(xi)[label]
        tris, secs = run_flight(hf, cams, crit, fl["fps"], step, progress, f"scale {n}")
        out.append(f"| {label} | {tris.mean():,.0f} | {100 * tris.mean() / hf.full_triangles:.2f} | "
                   f"{1e3 * np.median(secs):.1f} | {1e3 * secs.max():.1f} |")
    return out + [""]


def terrain_view(camera: TerrainCamera, *, fov_deg=(90.0, 60.0), px_per_deg: float = 6.4, distance_m: float = 0.6):
    """An ``optim.View`` of a renderable window of ``camera``: a pinhole image ``fov_deg`` (horizontal,
    vertical; deg, each < 180) wide centred on the camera's forward direction, with ``px_per_deg`` pixels
    per degree at its centre (default 6.4 = 2 xi for the seed's 1280 px over 200 deg [Red01 Eq 5]), on a
    flat display ``distance_m`` (m) from the eye sized to match. The gaze is the camera's (the screen
    centre for ``gaze_deg = (0, 0)``); near plane 1 m, target 1 km along the view (world units m).

    The seed's 200 x 135 deg field of view has no pinhole rendering, so frames are judged in this
    window; every square in it was refined for the full field (the cull keeps what the window shows).
    """
    import optim
    import pmetric as pm

    fh, fv = (float(a) for a in fov_deg)
    if not (0 < fh < 180 and 0 < fv < 180) or not px_per_deg > 0:
        raise PlodError(f"terrain: judged window must be in (0, 180) deg and px_per_deg > 0, got {fov_deg!r}, "
                        f"{px_per_deg!r}")
    pitch = distance_m * math.tan(math.radians(1.0 / px_per_deg))  # m per pixel at the screen centre
    w, h = (max(2, int(round(2 * distance_m * math.tan(math.radians(a / 2)) / pitch))) for a in (fh, fv))
    display = pm.Display(width=w * pitch, height=h * pitch, resolution=(w, h), distance=distance_m)
    R = camera.rotation()  # rows: right, up, back (world)
    eye = np.asarray(camera.eye, float)
    gaze = "center" if tuple(camera.gaze_deg) == (0.0, 0.0) else (R.T @ camera.gaze())[None]
    return optim.View(eye=eye, target=eye - 1000.0 * R[2], up=R[1], display=display, image_size=(w, h),
                      gaze=gaze, near=1.0)


def judge_frames(hf, cams, criteria: dict, frames, fps, *, out_dir=None, size=None, px_per_deg=6.4,
                 progress=None) -> list[dict]:
    """Render frames of the flight and judge each criteria set's terrain against the full terrain.

    ``criteria``: {label: TerrainCriteria}; ``frames``: frame indices (>= 3: three previous cameras give
    the velocity); relit from the meshes' own normals with ``optim.Lighting``'s default; FovVideoVDP
    foveated at the camera's gaze [Man21] and FLIP [And20] (:func:`experiments.judge.judge`) on
    :func:`terrain_view`. Returns rows {frame, criteria, triangles, jod, flip}; with ``out_dir`` writes
    ``frame{k}_{label}.png`` (renderings and difference maps) there.
    """
    from experiments.judge import judge, save_judgement
    from optim._terrain import full_mesh, terrain_mesh

    full = full_mesh(hf) + (None,)
    rows, n = [], len(frames) * len(criteria)
    for k in frames:
        if not 3 <= int(k) < len(cams):
            raise PlodError(f"terrain: judged frame {k} outside 3..{len(cams) - 1} of the flight")
        view = terrain_view(cams[k], px_per_deg=px_per_deg)
        prev = (cams[k - 1], cams[k - 2], cams[k - 3])
        for label, crit in criteria.items():
            lod = refine_terrain(hf, cams[k], crit, prev, dt_s=1.0 / fps)
            V, F, _ = terrain_mesh(hf, lod)
            res = judge(full, (V, F, None), view, mode="relit", size=size)
            rows.append({"frame": int(k), "criteria": label, "triangles": lod.triangles, "jod": res.jod,
                         "flip": res.flip_mean})
            if out_dir is not None:
                save_judgement(Path(out_dir) / f"frame{k}_{label.replace(' + ', '_')}.png", res,
                               titles=("full terrain", f"{label}: {lod.triangles:,} triangles"))
            if progress:
                progress("judged frames", len(rows), n)
    return rows


def _figure4(hf, fl, cfg, xi, progress):
    grid = np.zeros((len(cfg["fig4_velocities"]), len(cfg["fig4_fovs"])))
    for j, f in enumerate(cfg["fig4_fovs"]):
        cams = flight_cameras(hf, fl, fov=(float(f), float(f)))
        for i, v in enumerate(cfg["fig4_velocities"]):
            crit = TerrainCriteria(xi=xi, velocity_deg_s=float(v))
            tris, _ = run_flight(hf, cams, crit, fl["fps"], cfg["fig4_frame_step"], progress, "figure 4")
            grid[i, j] = tris.mean()
    return grid


def _save_fig4(path, grid, cfg):
    from experiments import _figures

    plt = _figures.pyplot()
    fig, ax = plt.subplots(figsize=(6, 4.5))
    im = ax.imshow(grid, origin="lower", aspect="auto", cmap="viridis")
    ax.set_xticks(range(len(cfg["fig4_fovs"])), [f"{f:g}" for f in cfg["fig4_fovs"]])
    ax.set_yticks(range(len(cfg["fig4_velocities"])), [f"{v:g}" for v in cfg["fig4_velocities"]])
    ax.set_xlabel("square field of view (deg)")
    ax.set_ylabel("retinal velocity (deg/s)")
    ax.set_title("triangles per frame, all criteria [Red01 Fig 4]")
    fig.colorbar(im, ax=ax)
    _figures.save_png(fig, path)


def config_main(argv, prog: str, description: str, run, written: str) -> int:
    """``python -m experiments.<prog> CONFIG [--out DIR]``: ``run(config, out, progress)`` with a rich
    progress bar; prints the path of the report ``written`` in the output folder."""
    ap = argparse.ArgumentParser(prog=prog, description=description)
    ap.add_argument("config")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    from experiments._progress import rich_progress

    with rich_progress(prog.replace("_", " ")) as cb:
        out = run(a.config, a.out, cb)
    print(f"wrote {out / written}")
    return 0


def main(argv=None) -> int:
    return config_main(argv, "terrain", __doc__.splitlines()[0], run_config, "table1.md")

if __name__ == "__main__":
    run_script(main)

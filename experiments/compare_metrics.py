"""Compare perceptual, size and geometric keys (and two view-independent decimators) by FLIP and run time.

    .venv/bin/python -m experiments.compare_metrics [--config configs/compare_metrics.toml] [--quick] [--out DIR]

For each mesh (the shared bunny, horse, armadillo and lucy when ``../shared`` is present, and always a
procedural ``optim.bumpy_sphere(6, colors=True)``) the QEM vertex tree is built once. Views: the object
framed at 30 deg of the 46-deg screen (``optim.View.framing``), gaze at the object centre and at
``gaze_offsets_deg`` to the right of it ([LH01 Fig 8] puts the gaze 29 deg from the bunny's centre,
beyond the screen edge at 23 deg), 1 deg gaze error. For every budget (a fraction of the input
triangles) each metric's keys (``optim.score(tree, view, model, metric)``) are cut with
``optim.budget_cut``; meshoptimizer's ``simplify`` and fast-simplification's decimation go to the same
triangle count as view-independent baselines. Every result is judged by

* ``k``: the perceptual distance beyond which it is imperceptible (largest perceptual key among folded
  internal nodes; with monotone keys the boundary's maximum). It does not exist for the baselines
  (they have no vertex tree to score), reported as "n/a";
* ``FLIP``: mean FLIP [And20] between renderings of the original and the simplified
  mesh (``experiments/render.py``) at ``render_size``, with the display's pixels per degree scaled to
  that size;
* ``wFLIP``: FLIP weighted by the model's relative sensitivity at each pixel's eccentricity,
  ``w(e) = S(f_w, e') / S(f_w, 0)`` with ``e' = max(0, e - gaze_error)`` (the eccentricity the scoring
  uses, [LHNW00 §4.4]) and ``f_w`` = ``weight_frequency`` (0: the model's foveal peak
  frequency, 4 cycles/deg for the default KellyAbstract; the errors of a 480x270 rendering at ~10 px/deg
  lie at 1-5 cycles/deg). ``wFLIP = mean(w * FLIP map)`` <= FLIP: errors the viewer sees only in the
  periphery are discounted. FLIP itself is foveal everywhere. This is a simple per-pixel weighting, not
  a foveated FLIP (FLIP's own spatial filtering stays foveal);
* ``ms``: per-view update time, score + budget cut + extract (median of ``repeats``; the first view of
  each metric, with XLA compilation, is excluded and reported separately); for the baselines the time
  of the simplify call (view independent: run once per budget).

Writes ``report.md`` (a table per mesh and a summary computed from the numbers), ``results.json``,
PNG plots (``flip_vs_triangles.png``, ``wflip_vs_triangles.png``, ``distance_vs_triangles.png``,
``time_vs_flip.png``), ``comparison_<mesh>.png`` (original | perceptual | size at the budget closest to
``comparison_budget``, centre view) and ``run_info.json``. Without an OpenGL context (``render`` raises
``RuntimeError``) the FLIP columns are left out with a note.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:  # pragma: no cover - run as a script
    sys.path.insert(0, str(ROOT))

from experiments._runinfo import repo_path as _rel  # noqa: E402  (after the path set-up of a script run)
from experiments.peers import compact, fast_simplify, meshopt_simplify, nearest_colors  # noqa: E402,F401
from pmetric import DEFAULT_MODEL, PlodError, make_model  # noqa: E402

DEFAULTS = {
    "out": "reports/compare_metrics",
    "meshes": [
        "../shared/data/meshes/stanford-bunny.obj",
        "../shared/data/meshes/horse.ply",
        "../shared/data/meshes/armadillo-70k.ply",
        "../shared/data/meshes/lucy-100k.ply",
    ],
    # subdivisions of the procedural optim.bumpy_sphere(n, colors=True) mesh (always run); 0 = none
    "procedural": 6,
    "method": "meshopt",
    "model": DEFAULT_MODEL,  # any name of `plod models`, eccentric(NAME) or a fitted .json
    "budgets": [0.02, 0.05, 0.10, 0.20, 0.40],  # fractions of the input triangles
    "object_deg": 30.0,
    "gaze_offsets_deg": [0.0, 15.0, 29.0],  # gaze to the right of the object centre (deg of visual angle)
    "gaze_error_deg": 1.0,
    "render_size": [480, 270],
    "weight_frequency": 0.0,  # cycles/deg of the eccentricity weighting; 0 = the model's foveal peak
    "comparison_budget": 0.10,
    "repeats": 3,
    "seed": 0,
}

QUICK = {"meshes": [], "procedural": 4, "budgets": [0.05, 0.10], "gaze_offsets_deg": [0.0],
         "render_size": [320, 180], "repeats": 1, "out": "reports/compare_metrics/quick"}

from experiments._compare_report import (BASELINES, METHODS, METRICS, _safe,  # noqa: E402,F401  (BASELINES: tests)
                                         plot_comparison, plot_time_vs_flip, plot_vs_triangles, write_report)


# ----------------------------------------------------------------------------- config
def check_config(cfg: dict) -> dict:
    """Validate values beyond their types; raises PlodError naming the key."""
    b = cfg["budgets"]
    if not b or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and 0 < x <= 1 for x in b):
        raise PlodError(f"config key 'budgets' must be a non-empty list of fractions in (0, 1], got {b!r}")
    cfg["budgets"] = sorted(float(x) for x in b)
    g = cfg["gaze_offsets_deg"]
    if not g or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and 0 <= x < 80 for x in g):
        raise PlodError(f"config key 'gaze_offsets_deg' must be a non-empty list of angles in [0, 80) deg, got {g!r}")
    cfg["gaze_offsets_deg"] = [float(x) for x in g]
    rs = cfg["render_size"]
    if len(rs) != 2 or not all(isinstance(x, int) and not isinstance(x, bool) and x >= 16 for x in rs):
        raise PlodError(f"config key 'render_size' must be two integers >= 16 (width, height), got {rs!r}")
    if not all(isinstance(m, str) for m in cfg["meshes"]):
        raise PlodError(f"config key 'meshes' must be a list of file paths, got {cfg['meshes']!r}")
    if cfg["procedural"] < 0 or cfg["procedural"] > 8:
        raise PlodError(f"config key 'procedural' must be 0 (none) .. 8 subdivisions, got {cfg['procedural']!r}")
    if not cfg["meshes"] and cfg["procedural"] == 0:
        raise PlodError("config: no meshes ('meshes' is empty and 'procedural' is 0)")
    if cfg["method"] not in ("meshopt", "qem", "octree"):
        raise PlodError(f"config key 'method' must be 'meshopt', 'qem' or 'octree', got {cfg['method']!r}")
    if cfg["repeats"] < 1:
        raise PlodError(f"config key 'repeats' must be >= 1, got {cfg['repeats']!r}")
    for key in ("object_deg", "gaze_error_deg", "weight_frequency", "comparison_budget"):
        if not math.isfinite(cfg[key]) or cfg[key] < 0:
            raise PlodError(f"config key {key!r} must be a finite number >= 0, got {cfg[key]!r}")
    if not 0 < cfg["object_deg"] < 180:
        raise PlodError(f"config key 'object_deg' must be in (0, 180) deg, got {cfg['object_deg']!r}")
    return cfg


def load_model(name: str):
    """The config's ``model``: any spelling ``pmetric.make_model`` accepts (``plod models``); a .json path
    is relative to the repository root. PlodError naming the key."""
    spec = str(_rel(name)) if name.lower().endswith(".json") else name
    try:
        return make_model(spec)
    except PlodError as exc:
        raise PlodError(f"config key 'model': {exc}") from None


# ----------------------------------------------------------------------------- pieces
def gaze_view(vertices, offset_deg: float, cfg):
    """The framed view with the gaze ``offset_deg`` to the right of the object centre (screen centre)."""
    from experiments.judge import offset_gaze_view

    return offset_gaze_view(vertices, offset_deg, object_deg=cfg["object_deg"], gaze_error_deg=cfg["gaze_error_deg"])


def eccentricity_weights(view, model, size, weight_frequency: float) -> np.ndarray:
    """(H, W) relative sensitivity S(f_w, e') / S(f_w, 0) at each rendered pixel (see the module docstring)."""
    w, h = size
    s = view.width / w
    xs, ys = np.meshgrid((np.arange(w) + 0.5) * s, (np.arange(h) + 0.5) * (view.height / h))
    xy = np.stack([xs, ys], axis=-1)
    ecc = np.min([view.visual_angle_px(xy, g) for g in view.gaze_px], axis=0)
    e = np.maximum(ecc - view.gaze_error_deg, 0.0)
    f = float(model.peak_frequency(0.0)) if weight_frequency <= 0 else weight_frequency
    s0 = float(model.sensitivity(f, 0.0))
    return np.clip(np.asarray(model.sensitivity(f, e.astype(np.float32)), dtype=np.float64) / s0, 0.0, 1.0)


def perceptual_distance(tree, pkeys, unfolded) -> float:
    """Largest perceptual key among folded internal nodes (0.0 when all are unfolded)."""
    internal = tree.internal
    folded = ~unfolded[internal]
    return float(pkeys[internal][folded].max()) if folded.any() else 0.0


def _median_time(fn, repeats):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return out, 1e3 * statistics.median(times)


def _load(spec):
    import optim

    if spec[0] == "procedural":
        v, f, c = optim.bumpy_sphere(spec[1], seed=spec[2], colors=True)
        return f"bumpy_sphere({spec[1]})", v, f, c
    v, f, c = optim.load_mesh(spec[1])
    return Path(spec[1]).stem, v, f, c


# ----------------------------------------------------------------------------- one mesh
def _baselines(V, F, C, budgets, repeats, progress, task):
    """{(method, budget): ((vertices, faces, colors), ms)} of the view-independent decimators."""
    base = {}
    for b in budgets:
        faces_mo, ms = _median_time(lambda: meshopt_simplify(V, F, b, C), repeats)
        base[("meshoptimizer", b)] = (compact(V, faces_mo, C), ms)
        (pv, pf), ms = _median_time(lambda: fast_simplify(V, F, b), repeats)
        base[("fast_simplification", b)] = ((pv, pf.astype(np.int32), nearest_colors(V, C, pv)), ms)
        progress.advance(task, 2)
    return base


def _first_view_s(tree, view, model, budget) -> float:
    """Seconds of the first view of every metric (context, tables, XLA compilation), kept out of ``ms``."""
    import optim

    t0 = time.perf_counter()
    for m in METRICS:
        keys = optim.score(tree, view, model, m)
        optim.extract(tree, optim.budget_cut(tree, keys, budget))
    return time.perf_counter() - t0


def _method_record(tree, view, model, m, b, pkeys, base, repeats) -> tuple[dict, tuple]:
    """(record without FLIP, simplified mesh) of method ``m`` at budget ``b``."""
    import optim

    if m not in METRICS:
        mesh, ms = base[(m, b)]
        return dict(triangles=int(len(mesh[1])), stop_reason=None, distance=None, key_distance=None, ms=ms), mesh

    def update():
        c = optim.budget_cut(tree, optim.score(tree, view, model, m), b)
        return c, optim.extract(tree, c)

    (cut, mesh), ms = _median_time(update, repeats)
    return dict(triangles=int(cut.triangles), stop_reason=cut.stop_reason,
                distance=perceptual_distance(tree, pkeys, cut.unfolded), key_distance=float(cut.distance),
                ms=ms), mesh


def _view_renders(tree, view, model, cfg, gl):
    """(original rendering, eccentricity weights), or (None, None) without OpenGL (``gl`` records why)."""
    from experiments import render as R

    if not gl["ok"]:
        return None, None
    size = tuple(cfg["render_size"])
    try:
        orig = R.render(tree.vertices, tree.faces, tree.colors, view, lighting=tree.lighting, size=size)
    except RuntimeError as exc:
        gl["ok"], gl["error"] = False, str(exc)
        return None, None
    return orig, eccentricity_weights(view, model, size, cfg["weight_frequency"])


def run_mesh(spec, cfg, model, progress, task, gl):
    """All views, budgets and methods of one mesh; returns (records, mesh info, comparison renders)."""
    import optim
    from experiments import render as R

    name, v0, f0, c0 = _load(spec)
    t0 = time.perf_counter()
    tree = optim.build_tree(v0, f0, colors=c0, method=cfg["method"])
    build_s = time.perf_counter() - t0
    V, F, C = tree.vertices, tree.faces, tree.colors
    T = int(tree.n_triangles)
    size = tuple(cfg["render_size"])
    budgets = [max(1, int(round(b * T))) for b in cfg["budgets"]]
    comp_i = int(np.argmin([abs(b - cfg["comparison_budget"]) for b in cfg["budgets"]]))
    info = {"mesh": name, "triangles": T, "vertices": int(len(V)), "nodes": int(tree.n_nodes),
            "build_s": build_s, "colors": C is not None, "budgets": budgets}
    base = _baselines(V, F, C, budgets, cfg["repeats"], progress, task)
    info["first_view_s"] = _first_view_s(tree, gaze_view(V, cfg["gaze_offsets_deg"][0], cfg), model, budgets[0])

    records, comps = [], {}
    for off in cfg["gaze_offsets_deg"]:
        view = gaze_view(V, off, cfg)
        pkeys = optim.score(tree, view, model, "perceptual")
        imp = optim.imperceptible_cut(tree, view, model)
        info.setdefault("imperceptible_triangles", {})[f"{off:g}"] = int(imp.triangles)
        ppd = float(view.display.pixels_per_degree()) * size[0] / view.width
        info["ppd"] = ppd
        orig, weights = _view_renders(tree, view, model, cfg, gl)
        for bi, b in enumerate(budgets):
            for m in METHODS:
                rec = {"mesh": name, "gaze_deg": off, "budget_fraction": cfg["budgets"][bi], "budget": b,
                       "method": m}
                fields, mesh = _method_record(tree, view, model, m, b, pkeys, base, cfg["repeats"])
                rec.update(fields, flip=None, wflip=None)
                if gl["ok"]:
                    img = R.render(*mesh, view, lighting=tree.lighting, size=size)
                    emap, mean = R.flip(orig, img, ppd)
                    rec["flip"], rec["wflip"] = mean, float(np.mean(weights * emap))
                    if off == cfg["gaze_offsets_deg"][0] and bi == comp_i and m in ("perceptual", "size"):
                        comps[m] = (img, emap, rec)
                        comps["original"] = orig
                records.append(rec)
                progress.advance(task)
    info["comparison_budget"] = budgets[comp_i]
    return records, info, comps


# ----------------------------------------------------------------------------- outputs
# ----------------------------------------------------------------------------- main
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", help="TOML overrides of DEFAULTS (unknown keys are rejected)")
    ap.add_argument("--quick", action="store_true", help="small procedural mesh, two budgets, one view")
    ap.add_argument("--out", help="output folder (overrides the config's 'out')")
    args = ap.parse_args(argv)

    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from experiments._runinfo import load_config, save_run_info
    from pmetric import atomic_write_text

    defaults = dict(DEFAULTS)
    if args.quick:
        defaults.update(QUICK)
    cfg = check_config(load_config(args.config, defaults))
    if args.out:
        cfg["out"] = args.out
    model = load_model(cfg["model"])
    out = _rel(cfg["out"])
    console = Console(stderr=True)
    specs = []
    for m in cfg["meshes"]:
        p = _rel(m)
        if p.is_file():
            specs.append(("file", str(p)))
        else:
            console.print(f"[yellow]skipping {m}: not found[/]")
    if cfg["procedural"] > 0:
        specs.append(("procedural", int(cfg["procedural"]), int(cfg["seed"])))
    nb, nv = len(cfg["budgets"]), len(cfg["gaze_offsets_deg"])
    per_mesh = 2 * nb + nb * nv * len(METHODS)
    command = " ".join([".venv/bin/python -m experiments.compare_metrics", *(sys.argv[1:] if argv is None else argv)])
    gl = {"ok": True, "error": None}
    records, infos, t_start = [], [], time.perf_counter()
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    with Progress(*columns, console=console) as progress:
        task = progress.add_task("compare_metrics", total=per_mesh * len(specs))
        for spec in specs:
            progress.update(task, description=f"{Path(str(spec[1])).stem if spec[0] == 'file' else 'bumpy_sphere'}")
            recs, info, comps = run_mesh(spec, cfg, model, progress, task, gl)
            records += recs
            infos.append(info)
            if gl["ok"] and "original" in comps:
                plot_comparison(comps, info, info["ppd"], out / f"comparison_{_safe(info['mesh'])}.png")
    elapsed = time.perf_counter() - t_start
    if not gl["ok"]:
        console.print(f"[yellow]no FLIP columns: {gl['error']}[/]")
    offsets = cfg["gaze_offsets_deg"]
    if gl["ok"]:
        plot_vs_triangles(records, infos, offsets, "flip", "mean FLIP", out / "flip_vs_triangles.png", by_mesh=True)
        plot_vs_triangles(records, infos, offsets, "wflip", "eccentricity-weighted FLIP", out / "wflip_vs_triangles.png")
        plot_time_vs_flip(records, offsets[0], out / "time_vs_flip.png")
    plot_vs_triangles(records, infos, offsets, "distance", "perceptual distance k", out / "distance_vs_triangles.png",
                      methods=METRICS)
    for info in infos:
        info["mesh_file"] = _safe(info["mesh"])
    results = {"config": cfg, "gl": gl, "meshes": infos, "records": records, "elapsed_s": elapsed}
    atomic_write_text(out / "results.json", json.dumps(results, indent=1) + "\n")
    write_report(out, cfg, records, infos, gl, command, elapsed)
    save_run_info(out, cfg, int(cfg["seed"]), command)
    console.print(f"wrote {out / 'report.md'} ({elapsed:.0f} s)")
    return 0


if __name__ == "__main__":  # pragma: no cover
    from experiments._runinfo import run_main

    raise SystemExit(run_main(main))

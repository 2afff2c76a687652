"""Perceptually driven point rendering (seed 004 §4, Figure 7): splat counts, time and rendered error of
the perceptual QSplat traversal against QSplat's size-only traversal.

For each point set (``paths``: a mesh's vertices with their normals, read directly or, with
``point_cloud``, through a point-cloud PLY written from them and read back; ``sphere:SUBDIV``: the
coloured procedural bumpy sphere) and each object size (``object_deg``, deg of visual field on the
default display, 1920 x 1080 on a 46-deg screen), the hierarchy of :mod:`optim._points` is traversed

* size-only: QSplat's highest quality, splats under ``min_px`` pixels [LH01 Figure 1, left];
* perceptual: ``model``'s test of every node [LH01 §4], gaze at the centre and ``gaze_deg`` away
  (29 deg in the seed's Figure 7), with the display's pixel as a floor (``min_px``); the pure test
  (no pixel floor) is counted too;

and rendered as oriented disc splats (the baked renderer of :mod:`experiments.render`, back faces
culled), judged against the rendering of every point (all leaves) by FovVideoVDP [Man21] foveated
at the gaze and by FLIP [And20]. Traversal time is the median of ``repeats`` runs after a warm-up
(per-node terms in one XLA program + the level-by-level walk); render time one draw on this machine's
Mesa (llvmpipe, CPU). A curve of splat counts over the gaze offset (``curve_gaze_deg``) is plotted.

Writes ``DIR/report.md``, ``DIR/results.json``, ``DIR/counts.png`` (Figure 7's counts),
``DIR/curve.png``, one ``DIR/<set>_<deg>.png`` of renderings per set and size (blue: splats of
internal nodes, as in the seed's Figure 1) and ``DIR/run_info.json``.

    python -m experiments.points [--out reports/points] [--config FILE.toml] [--quick] [--no-judge]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from experiments._runinfo import check_out_dir, config_numbers, load_config, repo_path, save_run_info
from experiments.accuracy import IMPERCEPTIBLE_TARGET as IMPERCEPTIBLE_JOD
from pmetric import PlodError, atomic_write_text

WRITES = ("report.md", "results.json", "*.png")  # what a run writes into its folder (check_out_dir)

DEFAULTS = {
    "kind": "points",
    "out": "reports/points",
    "paths": ["../shared/data/meshes/lucy-100k.ply", "../shared/data/meshes/dragon-100k.obj", "sphere:6"],
    "names": ["lucy-100k", "dragon-100k (point-cloud PLY)", "bumpy sphere (coloured)"],
    "point_cloud": [False, True, False],
    "directions": [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]],
    "ups": [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0]],
    "object_deg": [30.0, 10.0],
    "gaze_deg": 29.0,
    "curve_gaze_deg": [0.0, 5.0, 10.0, 15.0, 20.0, 25.0, 29.0, 35.0, 40.0, 50.0],
    "gaze_error_deg": 1.0,
    "model": "kellyabstract",
    "min_px": 1.0,
    "leaf_k": 4,
    "repeats": 7,
    "judge": True,
    "seed": 0,
}
QUICK = {"paths": ["sphere:4"], "names": ["bumpy sphere (coloured)"], "point_cloud": [True],
         "directions": [[0.0, 0.0, 1.0]], "ups": [[0.0, 1.0, 0.0]], "object_deg": [10.0],
         "curve_gaze_deg": [0.0, 15.0, 29.0], "repeats": 2, "out": "reports/points/quick"}
SEED_FIG7 = {"size-only": 2.9e6, "perceptual, gaze 29 deg away": 0.8e6}  # Lucy, points [LH01 Figure 7]


# ----------------------------------------------------------------------------------------------- inputs
def _check_sets(cfg) -> list[dict]:
    """The point sets of ``cfg`` (one dict per set); PlodError naming the key when any value the
    experiment reads is out of range (the loader checks only names and types), before any work."""
    from optim._points import LEAF_K_MAX

    def bad(key, want):
        raise PlodError(f"config key {key!r} must be {want}, got {cfg[key]!r}")

    keys = ("paths", "names", "point_cloud", "directions", "ups")
    n = len(cfg["paths"])
    for k in keys:
        if len(cfg[k]) != n:
            raise PlodError(f"config: {k!r} has {len(cfg[k])} entries, 'paths' has {n}; give one per point set")
    if not all(isinstance(x, str) and x.strip() for x in cfg["paths"]):
        bad("paths", "a list of file names or 'sphere:SUBDIV'")
    for x in cfg["paths"]:
        if x.startswith("sphere:") and not x[7:].strip().isdigit():
            raise PlodError(f"config: procedural set {x!r} must be 'sphere:SUBDIV' with an integer")
        if not x.startswith("sphere:") and not repo_path(x).is_file():
            raise PlodError(f"config: point file {x!r} does not exist (paths are relative to the repository)")
    if not all(isinstance(x, str) for x in cfg["names"]):
        bad("names", "a list of strings (one name per point set)")
    if not all(isinstance(x, bool) for x in cfg["point_cloud"]):
        bad("point_cloud", "a list of true / false (one per point set)")
    for key in ("directions", "ups"):
        if not all(config_numbers(v, 3) and any(v) for v in cfg[key]):
            bad(key, "a list of nonzero 3-vectors of finite numbers (one per point set)")
    if not cfg["object_deg"]:
        raise PlodError("config: 'object_deg' must list at least one object size (deg)")
    if not config_numbers(cfg["object_deg"], lo=0, strict=True, below=180):
        bad("object_deg", "a list of object sizes in (0, 180) deg")
    if not config_numbers([cfg["gaze_error_deg"]], lo=0):
        bad("gaze_error_deg", "a finite angle >= 0 deg")
    if not config_numbers([cfg["min_px"]], lo=0):
        bad("min_px", "a finite number of pixels >= 0")
    if not config_numbers([cfg["leaf_k"]], lo=1, ints=True, below=LEAF_K_MAX + 1):
        bad("leaf_k", f"an integer in [1, {LEAF_K_MAX}]")
    if not config_numbers([cfg["repeats"]], lo=1, ints=True):
        bad("repeats", "an integer >= 1")
    if not isinstance(cfg["judge"], bool):
        bad("judge", "true or false")
    slugs = [_slug(str(x)) for x in cfg["names"]]
    if len(set(slugs)) != len(slugs):  # figures are named by slug: one would overwrite the other
        raise PlodError(f"config: 'names' must differ before their first ' (' and in their letters and digits "
                        f"(they name the figures), got {cfg['names']!r}")
    for key in ("gaze_deg", *(["curve_gaze_deg"] if "curve_gaze_deg" in cfg else [])):
        vals = cfg[key] if isinstance(cfg[key], list) else [cfg[key]]
        if not config_numbers(vals, lo=0, below=80, empty=True):
            raise PlodError(f"config key {key!r} must be angles in [0, 80) deg from the centre, got {cfg[key]!r}")
    for key in ("object_deg", "curve_gaze_deg"):  # object_deg names the figures, curve_gaze_deg the curve's points
        labels = [f"{float(x):g}" for x in cfg.get(key, [])]
        if len(set(labels)) != len(labels):
            bad(key, "a list of different values (as printed with 6 digits: they name the outputs)")
    return [dict(zip(keys, row)) for row in zip(*(cfg[k] for k in keys))]


def load_set(entry: dict, leaf_k: int):
    """(points, normals, colours, how it was read) of one configured point set."""
    import optim
    from optim._points import load_points, points_from_mesh, save_points

    path = str(entry["paths"])
    if path.startswith("sphere:"):
        try:
            sub = int(path.split(":", 1)[1])
        except ValueError:
            raise PlodError(f"config: procedural set {path!r} must be 'sphere:SUBDIV' with an integer") from None
        v, f, c = optim.bumpy_sphere(sub, colors=True)
        p, n, c = points_from_mesh(v, f, c)
        how = f"optim.bumpy_sphere({sub}, colors=True) vertices"
    else:
        p, n, c = load_points(repo_path(path))
        how = f"{path} vertices (area-weighted normals)"
    if entry["point_cloud"]:
        with tempfile.TemporaryDirectory(prefix="plod-points-") as tmp:
            cloud = Path(tmp) / "cloud.ply"
            save_points(cloud, p, n, c)
            p, n, c = load_points(cloud)
        how += ", written as a point-cloud PLY and read back with trimesh"
    return p, n, c, how


# ----------------------------------------------------------------------------------------------- one cell
def _timed(fn, repeats: int):
    fn()  # warm-up: compilation
    ts = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t0)
    return out, 1e3 * float(np.median(ts))


def _traverse_timed(h, view, model, repeats, **kw):
    """(traversal, median ms of terms + walk, median ms of the walk alone)."""
    from optim._points import traverse, walk

    tr, ms = _timed(lambda: traverse(h, view, model, **kw), repeats)
    t = tr.terms
    small = t.size_px <= kw.get("min_px", 1.0)
    stop = small if kw.get("criterion") == "size" else small | ~t.perceptible
    _, walk_ms = _timed(lambda: walk(h, t.culled, stop), repeats)
    return tr, ms, walk_ms


def _render(h, nodes, view, tint_internal: bool = False):
    from experiments import render as R
    from optim._points import splat_discs

    tint = None
    if tint_internal:
        tint = h.srgb(nodes)
        inner = h.child_count[nodes] > 0
        tint[inner] = 0.35 * tint[inner] + 0.65 * np.array([0.15, 0.35, 1.0], np.float32)
    v, f, c = splat_discs(h, nodes, tint=tint)
    t0 = time.perf_counter()
    img = R.render(v, f, c, view, mode="baked")
    return img, 1e3 * (time.perf_counter() - t0)


def _judge(ref, img, view):
    from experiments import render as R
    from experiments.judge import fovvdp, pixels_per_degree

    jod, _ = fovvdp(ref, img, view, heatmap=False)
    _, mean = R.flip(ref, img, pixels_per_degree(view))
    return float(jod), float(mean)


def run_cell(name, h, p, entry, deg, cfg, model, out: Path, progress=None):
    """All traversals, renderings and judgements of one point set at one object size."""
    from experiments.judge import offset_gaze_view
    from optim._points import traverse

    kw = dict(direction=entry["directions"], up=entry["ups"], gaze_error_deg=cfg["gaze_error_deg"])
    g29 = float(cfg["gaze_deg"])
    views = {0.0: offset_gaze_view(p, 0.0, object_deg=deg, **kw), g29: offset_gaze_view(p, g29, object_deg=deg, **kw)}
    rep, mpx = int(cfg["repeats"]), float(cfg["min_px"])
    size_tr, size_ms, size_walk = _traverse_timed(h, views[0.0], model, rep, criterion="size", min_px=mpx)
    row = dict(set=name, object_deg=deg, points=h.n_points, nodes=h.n_nodes,
               visible_leaves=int(np.sum(~size_tr.terms.culled[h.leaves])),
               size=dict(splats=size_tr.splats, visited=size_tr.visited, ms=size_ms, walk_ms=size_walk))
    perc = {}
    for g, view in views.items():
        tr, ms, wms = _traverse_timed(h, view, model, rep, min_px=mpx)
        pure = traverse(h, view, model, min_px=0.0, terms=tr.terms)
        perc[g] = tr
        t = tr.terms
        lp = np.unique(h.parent[h.leaves])
        lp = lp[~t.culled[lp]]  # the nodes just above the leaves, in view
        row[f"perceptual_{g:g}"] = dict(splats=tr.splats, visited=tr.visited, ms=ms, walk_ms=wms,
                                        pure_splats=pure.splats, silhouette_drawn=int(t.silhouette[tr.drawn].sum()),
                                        leaf_parents=dict(theta_deg=float(np.median(t.theta[lp])),
                                                          contrast=float(np.median(t.contrast[lp])),
                                                          ecc_deg=float(np.median(t.eccentricity[lp])),
                                                          perceptible=float(np.mean(t.perceptible[lp]))))
    row["curve"] = {f"{g:g}": traverse(h, offset_gaze_view(p, g, object_deg=deg, **kw), model, min_px=mpx).splats
                    for g in cfg["curve_gaze_deg"]}
    if progress:
        progress(f"{name} {deg:g} deg: render", 1, 3)
    ref, ref_ms = _render(h, h.leaves, views[0.0])
    size_img, size_rms = _render(h, size_tr.drawn, views[0.0])
    imgs = {g: _render(h, tr.drawn, views[g]) for g, tr in perc.items()}
    tinted, _ = _render(h, perc[g29].drawn, views[g29], tint_internal=True)
    row["render_ms"] = dict(full=ref_ms, size=size_rms, **{f"perceptual_{g:g}": v[1] for g, v in imgs.items()})
    if cfg["judge"]:
        if progress:
            progress(f"{name} {deg:g} deg: judge", 2, 3)
        for g, view in views.items():
            jod, fl = _judge(ref, size_img, view)
            row["size"][f"jod_gaze_{g:g}"], row["size"][f"flip_gaze_{g:g}"] = jod, fl
            jod, fl = _judge(ref, imgs[g][0], view)
            row[f"perceptual_{g:g}"]["jod"], row[f"perceptual_{g:g}"]["flip"] = jod, fl
    fig_name = f"{_slug(name)}_{deg:g}deg.png"
    _cell_figure(out / fig_name, row, ref, size_img, imgs, tinted, views, g29, mpx)
    row["figure"] = fig_name
    return row


def _slug(name: str) -> str:
    return "".join(ch if ch.isalnum() else "_" for ch in name.split(" (")[0]).strip("_")


# ----------------------------------------------------------------------------------------------- figures
def _crop(img):
    """Rows and columns around the object (the background is uniform)."""
    diff = np.abs(img - img[0, 0]).sum(-1) > 1e-3
    ys, xs = np.flatnonzero(diff.any(1)), np.flatnonzero(diff.any(0))
    if not len(ys):
        return slice(None), slice(None)
    pad = 20
    return (slice(max(ys[0] - pad, 0), ys[-1] + pad), slice(max(xs[0] - pad, 0), xs[-1] + pad))


def _cell_figure(path, row, ref, size_img, imgs, tinted, views, g29, min_px):
    from experiments._figures import pyplot, save_png

    plt = pyplot()
    sy, sx = _crop(ref)
    panels = [(ref, f"all points: {row['points']:,} ({row['visible_leaves']:,} facing)", None),
              (size_img, f"size-only (< {min_px:g} px): {row['size']['splats']:,}", None)]
    for g, (img, _) in imgs.items():
        r = row[f"perceptual_{g:g}"]
        j = f", {r['jod']:.2f} JOD" if "jod" in r else ""
        panels.append((img, f"perceptual, gaze {g:g} deg: {r['splats']:,}{j}", views[g]))
    panels.append((tinted, f"gaze {g29:g} deg, blue: simplified", views[g29]))
    fig, axes = plt.subplots(1, len(panels), figsize=(3.6 * len(panels), 5.2), constrained_layout=True)
    for ax, (img, title, view) in zip(axes, panels):
        ax.imshow(img[sy, sx])
        if view is not None:
            from experiments.judge import fixation_px

            fx, fy = fixation_px(view)
            x0, y0 = sx.start or 0, sy.start or 0
            if 0 <= fy - y0 < img[sy, sx].shape[0] and 0 <= fx - x0 < img[sy, sx].shape[1]:
                ax.plot([fx - x0], [fy - y0], marker="+", color="red", markersize=14, mew=2)
            else:
                ax.set_xlabel(f"gaze {'right of' if fx > x0 else 'left of'} the crop", color="red")
        ax.set_title(title, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(f"{row['set']}, object {row['object_deg']:g} deg", fontsize=11)
    save_png(fig, path)


def _summary_figures(rows, cfg, out: Path):
    from experiments._figures import pyplot, save_png

    plt = pyplot()
    g29 = float(cfg["gaze_deg"])
    fig, ax = plt.subplots(figsize=(max(6, 1.9 * len(rows)), 4.2), constrained_layout=True)
    x = np.arange(len(rows))
    w = 0.36
    for k, (key, label) in enumerate([("perceptual_0", "perceptual, gaze centre"),
                                      (f"perceptual_{g29:g}", f"perceptual, gaze {g29:g} deg away")]):
        vals = [100.0 * r[key]["splats"] / r["size"]["splats"] for r in rows]
        ax.bar(x + (k - 0.5) * w, vals, w, label=label)
    ax.axhline(100 * SEED_FIG7["perceptual, gaze 29 deg away"] / SEED_FIG7["size-only"], color="k", ls=":",
               label=f"seed Fig 7 (Lucy, gaze {g29:g} deg away): 0.8 M of 2.9 M")
    ax.set_xticks(x, [f"{r['set'].split(' (')[0]}\n{r['object_deg']:g} deg" for r in rows], fontsize=8)
    ax.set_ylabel("splats drawn, % of the size-only count")
    ax.set_ylim(0, 115)
    ax.legend(fontsize=8, loc="upper right", ncols=3)
    ax.set_title("Figure 7 shape: perceptual splat counts against QSplat's highest quality (size-only, < 1 px)")
    save_png(fig, out / "counts.png")
    fig, ax = plt.subplots(figsize=(6.5, 4.2), constrained_layout=True)
    for r in rows:
        gs = [float(g) for g in r["curve"]]
        line, = ax.plot(gs, [100.0 * v / r["points"] for v in r["curve"].values()], marker="o",
                        label=f"{r['set'].split(' (')[0]}, {r['object_deg']:g} deg")
        ax.axhline(100.0 * r["size"]["splats"] / r["points"], color=line.get_color(), ls="--", lw=0.8)
    ax.axvline(g29, color="k", ls=":", lw=0.8)
    ax.set_xlabel("gaze offset from the object's centre (deg)")
    ax.set_ylabel("splats drawn, % of points")
    ax.set_title("perceptual traversal over gaze offset (dashed: size-only)")
    ax.legend(fontsize=7)
    save_png(fig, out / "curve.png")


# ----------------------------------------------------------------------------------------------- report
def _fmt(x, spec=".2f"):
    return "-" if x is None else format(x, spec)


def write_report(rows, meta, cfg, command, out: Path):
    g = f"{float(cfg['gaze_deg']):g}"
    L = ["# Perceptually driven point rendering (seed 004 §4, Figure 7)", "",
         f"Command: `{command}` (run info: `run_info.json`; numbers: `results.json`).", "",
         "QSplat's bounding-sphere hierarchy (`optim._points`: binary median split, leaf radius = distance to the "
         f"{cfg['leaf_k']}-th nearest point, each node averaging its points' colour and normal, with an exact normal "
         "cone and the luminance range of the nodes of its level whose spheres meet it) traversed two ways: "
         f"**size-only** (QSplat's highest quality: splats under {cfg['min_px']:g} px) and **perceptual** "
         f"(`{cfg['model']}`'s `is_perceptible(contrast, 1 / (2 theta), eccentricity)` per node [LH01 §4], "
         f"silhouette nodes at the silhouette contrast, the pixel as a floor; *pure*: without the floor), gaze at the "
         f"centre and {g} deg to the right of it. Default display: 1920 x 1080, 46 x 26.9 deg; views framed so "
         "that the object spans `object_deg` of the visual field. Splats: oriented discs of the node's radius, "
         "back faces culled, baked colours (uncoloured points: grey Lambert intensity under the default light). "
         "Judged against the rendering of every point: FovVideoVDP (JOD, 10 = identical; foveated at the gaze) and "
         "mean FLIP.", "",
         "Seed (Lucy, 2.9 M points, 1600 x 1200 on a 23\" monitor): size-only 2.9 M points, perceptual with the "
         "gaze 29 deg away 0.8 M (28 %).", ""]
    L += ["## Point sets", "", "| set | read as | points | nodes | build (s) |", "| --- | --- | ---: | ---: | ---: |"]
    for name, m in meta.items():
        L.append(f"| {name} | {m['how']} | {m['points']:,} | {m['nodes']:,} | {m['build_s']:.1f} |")
    L += ["", "## Splat counts (Figure 7)", "",
          f"Size-only: % of the points in brackets; perceptual: % of the size-only count (the seed's ratio). "
          f"Perceptual @ {g}: gaze {g} deg from the object's centre.", "",
          f"| set | object deg | facing points | size-only | perceptual @ 0 | perceptual @ {g} | pure @ 0 | "
          f"pure @ {g} |", "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    pct = lambda n, r: f"{n:,} ({100.0 * n / r['points']:.0f} %)"  # noqa: E731
    for r in rows:
        a, b = r["perceptual_0"], r[f"perceptual_{g}"]
        rel = lambda n: f"{n:,} ({100.0 * n / r['size']['splats']:.0f} %)"  # noqa: E731
        L.append(f"| {r['set']} | {r['object_deg']:g} | {r['visible_leaves']:,} | {pct(r['size']['splats'], r)} | "
                 f"{rel(a['splats'])} | {rel(b['splats'])} | {a['pure_splats']:,} | {b['pure_splats']:,} |")
    L += ["", "![counts](counts.png)", "", "![curve](curve.png)", "",
          "## Rendered error and time", "",
          "JOD and FLIP against the rendering of every point, fixation at the gaze of the column. Traversal: median ms "
          "(per-node terms in one XLA program + the level-by-level walk; the walk alone in brackets). Render: one "
          "draw with Mesa on the CPU (ms).", "",
          f"| set | object deg | traversal | splats | traversal ms | render ms | JOD @ 0 | FLIP @ 0 | JOD @ {g} | "
          f"FLIP @ {g} |", "| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in rows:
        s = r["size"]
        L.append(f"| {r['set']} | {r['object_deg']:g} | size-only | {s['splats']:,} | "
                 f"{s['ms']:.1f} ({s['walk_ms']:.1f}) | "
                 f"{r['render_ms']['size']:.0f} | {_fmt(s.get('jod_gaze_0'))} | {_fmt(s.get('flip_gaze_0'), '.4f')} | "
                 f"{_fmt(s.get(f'jod_gaze_{g}'))} | {_fmt(s.get(f'flip_gaze_{g}'), '.4f')} |")
        for gg in ("0", g):
            q = r[f"perceptual_{gg}"]
            cells = [_fmt(q.get("jod")), _fmt(q.get("flip"), ".4f")]
            cols = (cells + ["", ""]) if gg == "0" else (["", ""] + cells)
            L.append(f"| | | perceptual @ {gg} | {q['splats']:,} | {q['ms']:.1f} ({q['walk_ms']:.1f}) | "
                     f"{r['render_ms'][f'perceptual_{gg}']:.0f} | " + " | ".join(cols) + " |")
        L.append(f"| | | all points | {r['points']:,} | | {r['render_ms']['full']:.0f} | | | | |")
    L += ["", "## Findings", ""] + _findings(rows, cfg) + ["", "## Renderings", ""]
    for r in rows:
        L += [f"{r['set']}, object {r['object_deg']:g} deg: `{r['figure']}`", "", f"![{r['set']}]({r['figure']})", ""]
    atomic_write_text(out / "report.md", "\n".join(L) + "\n")


def _findings(rows, cfg) -> list[str]:
    """Sentences computed from the rows (nothing here is typed in by hand)."""
    g = f"{float(cfg['gaze_deg']):g}"
    seed = 100 * SEED_FIG7["perceptual, gaze 29 deg away"] / SEED_FIG7["size-only"]
    out = []
    for r in rows:
        s, a, b = r["size"], r["perceptual_0"], r[f"perceptual_{g}"]
        jod = f", {b['jod']:.2f} JOD (size-only {s[f'jod_gaze_{g}']:.2f})" if "jod" in b else ""
        if "jod" in b and b["jod"] < IMPERCEPTIBLE_JOD:
            jod += f", below the {IMPERCEPTIBLE_JOD:g} JOD the accuracy report takes as imperceptible"
        lp = b["leaf_parents"]
        out.append(f"- {r['set']}, {r['object_deg']:g} deg: with the gaze {g} deg away the perceptual traversal "
                   f"draws {100 * b['splats'] / s['splats']:.0f} % of the size-only splats (seed: {seed:.0f} %){jod}; "
                   f"with the gaze at the centre {100 * a['splats'] / s['splats']:.0f} %. Size-only draws "
                   f"{100 * s['splats'] / max(r['visible_leaves'], 1):.0f} % of the facing points (its leaves are "
                   f"above a pixel: {SEED_FIG7['size-only'] / r['points']:.0f} times fewer points than the seed's "
                   "Lucy). The nodes just "
                   f"above the leaves (median, gaze {g} deg): {lp['theta_deg']:.2f} deg across, contrast "
                   f"{lp['contrast']:.2f}, eccentricity {lp['ecc_deg']:.1f} deg; {100 * lp['perceptible']:.0f} % "
                   "perceptible.")
    if len({r["object_deg"] for r in rows}) < 2:
        return out
    out += ["", "Where the nodes just above the leaves are small on the screen (the 10-deg views) the shape of "
            "Figure 7 appears: most of the model drawn with the gaze on it, a large cut 29 deg away. Where they "
            "subtend larger angles (30 deg), the model's threshold at their frequency stays below their contrast "
            "even 29 deg into the periphery (the perceptible fractions above), and the traversal keeps nearly every "
            "leaf. The size-only traversal differs from all points only where a leaf's normal faces away while its "
            "disc is still seen edge on, hence its JOD just under 10."]
    return out


# ----------------------------------------------------------------------------------------------- main
def run(cfg, out: Path, progress=None):
    import pmetric as pm
    from optim._points import build_points

    sets = _check_sets(cfg)
    model = pm.make_model(cfg["model"])
    rows, meta = [], {}
    for entry in sets:
        name = entry["names"]
        p, n, c, how = load_set(entry, cfg["leaf_k"])
        t0 = time.perf_counter()
        h = build_points(p, n, c, leaf_k=int(cfg["leaf_k"]))
        meta[name] = dict(how=how, points=h.n_points, nodes=h.n_nodes, build_s=time.perf_counter() - t0)
        for deg in cfg["object_deg"]:
            if progress:
                progress(f"{name} {deg:g} deg", 0, 3)
            rows.append(run_cell(name, h, p, entry, float(deg), cfg, model, out, progress))
    return rows, meta


def _write_all(cfg, command: str, progress=None, config=None) -> tuple[Path, list]:
    """Check ``cfg`` (read from the file ``config``, if any), run it and write every output into its ``out``
    folder (made here); returns the folder and the result rows."""
    _check_sets(cfg)  # before the folder is made (run checks again: it is also called without this)
    out = check_out_dir(repo_path(cfg["out"]), config=config, writes=WRITES)
    if out.exists() and not out.is_dir():
        raise PlodError(f"output folder {str(out)!r} is a file, not a folder")
    out.mkdir(parents=True, exist_ok=True)
    rows, meta = run(cfg, out, progress)
    _summary_figures(rows, cfg, out)
    write_report(rows, meta, cfg, command, out)
    atomic_write_text(out / "results.json", json.dumps(dict(sets=meta, rows=rows), indent=1, default=float) + "\n")
    save_run_info(out, cfg, cfg["seed"], command)
    return out, rows


def run_config(path, out=None, progress=None) -> Path:
    """``plod experiment CONFIG`` for a config of ``kind = "points"`` (e.g. ``configs/points_fig7.toml``):
    the experiment with the config's overrides into ``out`` (default the config's); returns the folder."""
    cfg = load_config(path, DEFAULTS)
    if cfg["kind"] != "points":
        raise PlodError(f"points: config kind must be 'points', got {cfg['kind']!r}")
    if out is not None:
        cfg["out"] = str(out)
    return _write_all(cfg, f"python -m experiments.points --config {path}", progress, config=path)[0]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m experiments.points", description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default=None, help="TOML overrides of the defaults (unknown keys are refused)")
    ap.add_argument("--quick", action="store_true", help="one small procedural point set")
    ap.add_argument("--out", default=None, help="report folder (default reports/points)")
    ap.add_argument("--no-judge", action="store_true", help="skip FovVideoVDP and FLIP")
    args = ap.parse_args(argv)
    cfg = load_config(args.config, {**DEFAULTS, **(QUICK if args.quick else {})})
    if args.out:
        cfg["out"] = args.out
    if args.no_judge:
        cfg["judge"] = False
    command = "python -m experiments.points " + " ".join(argv if argv is not None else sys.argv[1:])
    from experiments._progress import rich_progress

    with rich_progress("points") as cb:
        def progress(stage, done, total):
            if cb is not None:
                cb(stage, done, total)
            else:
                print(f"[points] {stage}", file=sys.stderr, flush=True)

        _, rows = _write_all(cfg, command, progress, config=args.config)
    print(json.dumps([{k: r[k] for k in ("set", "object_deg")} | {"size": r["size"]["splats"],
                      "perceptual_0": r["perceptual_0"]["splats"],
                      f"perceptual_{float(cfg['gaze_deg']):g}": r[f"perceptual_{float(cfg['gaze_deg']):g}"]["splats"]}
                      for r in rows], indent=1))
    return 0


if __name__ == "__main__":  # pragma: no cover
    from experiments._runinfo import run_script

    run_script(main)

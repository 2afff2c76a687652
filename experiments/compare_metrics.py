"""Compare perceptual, size and geometric keys (and two view-independent decimators) by FLIP and run time.

    .venv/bin/python -m experiments.compare_metrics [--config configs/compare_metrics.toml] [--quick] [--out DIR]

For each mesh (the shared bunny, horse, armadillo and lucy when ``../shared`` is present, and always a
procedural ``optim.bumpy_sphere(6, colors=True)``) the QEM vertex tree is built once. Views: the object
framed at 30 deg of the 46-deg screen (``optim.View.framing``), gaze at the object centre and at
``gaze_offsets_deg`` to the right of it (seed 004 figure 8 puts the gaze 29 deg from the bunny's centre,
beyond the screen edge at 23 deg), 1 deg gaze error. For every budget (a fraction of the input
triangles) each metric's keys (``optim.score(tree, view, model, metric)``) are cut with
``optim.budget_cut``; meshoptimizer's ``simplify`` and fast-simplification's decimation go to the same
triangle count as view-independent baselines. Every result is judged by

* ``k``: the perceptual distance beyond which it is imperceptible (largest perceptual key among folded
  internal nodes; with monotone keys the boundary's maximum). It does not exist for the baselines
  (they have no vertex tree to score), reported as "n/a";
* ``FLIP``: mean FLIP (Andersson et al. 2020) between renderings of the original and the simplified
  mesh (``experiments/render.py``) at ``render_size``, with the display's pixels per degree scaled to
  that size;
* ``wFLIP``: FLIP weighted by the model's relative sensitivity at each pixel's eccentricity,
  ``w(e) = S(f_w, e') / S(f_w, 0)`` with ``e' = max(0, e - gaze_error)`` (the eccentricity the scoring
  uses, seed 001 section 4.4) and ``f_w`` = ``weight_frequency`` (0: the model's foveal peak
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
    "method": "qem",
    "model": "default",  # "default" (optim's default model), a pmetric class name or a fitted .json
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

METRICS = ("perceptual", "size", "geometric")
BASELINES = ("meshoptimizer", "fast_simplification")
METHODS = METRICS + BASELINES
COLORS = {"perceptual": "C0", "size": "C1", "geometric": "C2", "meshoptimizer": "C3", "fast_simplification": "C4"}


# ----------------------------------------------------------------------------- config
def _rel(p: str) -> Path:
    q = Path(p)
    return q if q.is_absolute() else ROOT / q


def check_config(cfg: dict) -> dict:
    """Validate values beyond their types; raises ValueError naming the key."""
    b = cfg["budgets"]
    if not b or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and 0 < x <= 1 for x in b):
        raise ValueError(f"config key 'budgets' must be a non-empty list of fractions in (0, 1], got {b!r}")
    cfg["budgets"] = sorted(float(x) for x in b)
    g = cfg["gaze_offsets_deg"]
    if not g or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and 0 <= x < 80 for x in g):
        raise ValueError(f"config key 'gaze_offsets_deg' must be a non-empty list of angles in [0, 80) deg, got {g!r}")
    cfg["gaze_offsets_deg"] = [float(x) for x in g]
    rs = cfg["render_size"]
    if len(rs) != 2 or not all(isinstance(x, int) and not isinstance(x, bool) and x >= 16 for x in rs):
        raise ValueError(f"config key 'render_size' must be two integers >= 16 (width, height), got {rs!r}")
    if not all(isinstance(m, str) for m in cfg["meshes"]):
        raise ValueError(f"config key 'meshes' must be a list of file paths, got {cfg['meshes']!r}")
    if cfg["procedural"] < 0 or cfg["procedural"] > 8:
        raise ValueError(f"config key 'procedural' must be 0 (none) .. 8 subdivisions, got {cfg['procedural']!r}")
    if not cfg["meshes"] and cfg["procedural"] == 0:
        raise ValueError("config: no meshes ('meshes' is empty and 'procedural' is 0)")
    if cfg["method"] not in ("qem", "octree"):
        raise ValueError(f"config key 'method' must be 'qem' or 'octree', got {cfg['method']!r}")
    if cfg["repeats"] < 1:
        raise ValueError(f"config key 'repeats' must be >= 1, got {cfg['repeats']!r}")
    for key in ("object_deg", "gaze_error_deg", "weight_frequency", "comparison_budget"):
        if not math.isfinite(cfg[key]) or cfg[key] < 0:
            raise ValueError(f"config key {key!r} must be a finite number >= 0, got {cfg[key]!r}")
    if not 0 < cfg["object_deg"] < 180:
        raise ValueError(f"config key 'object_deg' must be in (0, 180) deg, got {cfg['object_deg']!r}")
    return cfg


def load_model(name: str):
    """``"default"``, a registered pmetric class name or a fitted model's .json file."""
    import optim
    import pmetric

    if name == "default":
        return optim.default_model()
    p = _rel(name)
    if name.lower().endswith(".json"):
        if not p.is_file():
            raise ValueError(f"config key 'model': file not found: {name!r}")
        return pmetric.load_model(p)
    registry = {k.lower(): v for k, v in pmetric.model_registry().items()
                if isinstance(v, type) and issubclass(v, pmetric.CSFModel)}
    cls = registry.get(name.lower())
    if cls is None:
        raise ValueError(f"config key 'model': unknown model {name!r}; choose 'default', one of "
                         f"{', '.join(sorted(registry))} or a .json file")
    return cls()


# ----------------------------------------------------------------------------- pieces
def gaze_view(vertices, offset_deg: float, cfg):
    """The framed view with the gaze ``offset_deg`` to the right of the object centre (screen centre)."""
    import optim

    base = optim.View.framing(vertices, object_deg=cfg["object_deg"], gaze_error_deg=cfg["gaze_error_deg"])
    if offset_deg == 0:
        return base
    x = 0.5 * base.width + math.tan(math.radians(offset_deg)) * base.distance_m / base.pixel_pitch_m[0]
    return optim.View.framing(vertices, object_deg=cfg["object_deg"], gaze_error_deg=cfg["gaze_error_deg"],
                              gaze=np.array([[x, 0.5 * base.height]]))


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


def _compact(vertices, faces, colors):
    used, inv = np.unique(faces.ravel(), return_inverse=True)
    return vertices[used], inv.reshape(-1, 3).astype(np.int32), None if colors is None else colors[used]


def meshopt_simplify(vertices, faces, target):
    """meshoptimizer's simplify to ``target`` triangles (error bound lifted so the count decides)."""
    import meshoptimizer

    idx = np.ascontiguousarray(faces, dtype=np.uint32).ravel()
    pos = np.ascontiguousarray(vertices, dtype=np.float32)
    dest = np.empty_like(idx)
    n = meshoptimizer.simplify(dest, idx, pos, target_index_count=3 * int(target), target_error=1.0)
    return dest[:n].reshape(-1, 3).astype(np.int64)


def fast_simplify(vertices, faces, target):
    import fast_simplification

    return fast_simplification.simplify(np.ascontiguousarray(vertices, dtype=np.float64),
                                        np.ascontiguousarray(faces, dtype=np.int64),
                                        target_count=max(int(target), 1))


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

    # view-independent baselines, once per budget
    base = {}
    for b in budgets:
        faces_mo, ms = _median_time(lambda: meshopt_simplify(V, F, b), cfg["repeats"])
        base[("meshoptimizer", b)] = (_compact(V, faces_mo, C), ms)
        (pv, pf), ms = _median_time(lambda: fast_simplify(V, F, b), cfg["repeats"])
        pc = None
        if C is not None:  # fast-simplification drops colours: take each new vertex's nearest input colour
            from scipy.spatial import cKDTree

            pc = C[cKDTree(V).query(pv)[1]]
        base[("fast_simplification", b)] = ((pv, pf.astype(np.int32), pc), ms)
        progress.advance(task, 2)

    # first view of each metric: context, tables, XLA compilation (excluded from the per-view times)
    view0 = gaze_view(V, cfg["gaze_offsets_deg"][0], cfg)
    t0 = time.perf_counter()
    for m in METRICS:
        keys = optim.score(tree, view0, model, m)
        optim.extract(tree, optim.budget_cut(tree, keys, budgets[0]))
    info["first_view_s"] = time.perf_counter() - t0

    records, comps = [], {}
    for off in cfg["gaze_offsets_deg"]:
        view = gaze_view(V, off, cfg)
        pkeys = optim.score(tree, view, model, "perceptual")
        imp = optim.imperceptible_cut(tree, view, model)
        info.setdefault("imperceptible_triangles", {})[f"{off:g}"] = int(imp.triangles)
        orig = weights = None
        ppd = float(view.display.pixels_per_degree()) * size[0] / view.width
        info["ppd"] = ppd
        if gl["ok"]:
            try:
                orig = R.render(V, F, C, view, lighting=tree.lighting, size=size)
            except RuntimeError as exc:
                gl["ok"], gl["error"] = False, str(exc)
        if gl["ok"]:
            weights = eccentricity_weights(view, model, size, cfg["weight_frequency"])
        for bi, b in enumerate(budgets):
            for m in METHODS:
                rec = {"mesh": name, "gaze_deg": off, "budget_fraction": cfg["budgets"][bi], "budget": b,
                       "method": m}
                if m in METRICS:
                    def update(m=m):
                        k = optim.score(tree, view, model, m)
                        c = optim.budget_cut(tree, k, b)
                        return c, optim.extract(tree, c)

                    (cut, mesh), ms = _median_time(update, cfg["repeats"])
                    rec.update(triangles=int(cut.triangles), stop_reason=cut.stop_reason,
                               distance=perceptual_distance(tree, pkeys, cut.unfolded),
                               key_distance=float(cut.distance), ms=ms)
                else:
                    mesh, ms = base[(m, b)]
                    rec.update(triangles=int(len(mesh[1])), stop_reason=None, distance=None, key_distance=None,
                               ms=ms)
                rec["flip"] = rec["wflip"] = None
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
def _save_fig(fig, path):
    import matplotlib.pyplot as plt

    from pmetric import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_vs_triangles(records, infos, offsets, field, ylabel, path, methods=METHODS, by_mesh=False):
    """One panel per mesh and view (``by_mesh``: one per mesh, first view only, in a row)."""
    from matplotlib.ticker import NullFormatter

    plt = _plt()
    nr, nc = (1, len(infos)) if by_mesh else (len(infos), len(offsets))
    fig, axes = plt.subplots(nr, nc, figsize=(4.2 * nc, 3.2 * nr), squeeze=False)
    for i, info in enumerate(infos):
        for j, off in enumerate(offsets[:1] if by_mesh else offsets):
            ax = axes[0, i] if by_mesh else axes[i, j]
            for m in methods:
                rs = sorted((r for r in records if r["mesh"] == info["mesh"] and r["gaze_deg"] == off
                             and r["method"] == m and r[field] is not None), key=lambda r: r["triangles"])
                if rs:
                    ax.plot([r["triangles"] for r in rs], [r[field] for r in rs], "o-", ms=3, color=COLORS[m],
                            label=m)
            ax.set_xscale("log")
            ax.xaxis.set_minor_formatter(NullFormatter())
            if field in ("distance", "wflip"):
                ax.set_yscale("log")
            ax.set_title(f"{info['mesh']}, gaze {off:g} deg", fontsize=9)
            ax.set_xlabel("triangles", fontsize=8)
            ax.set_ylabel(ylabel, fontsize=8)
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    _save_fig(fig, path)


def plot_time_vs_flip(records, offset, path):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 5))
    for m in METHODS:
        rs = [r for r in records if r["method"] == m and r["gaze_deg"] == offset and r["flip"] is not None]
        ax.scatter([r["ms"] for r in rs], [r["flip"] for r in rs], s=14, color=COLORS[m], label=m, alpha=0.8)
    ax.set_xscale("log")
    ax.set_xlabel("time per view, ms (keys: score + cut + extract; baselines: simplify)")
    ax.set_ylabel("mean FLIP")
    ax.set_title(f"run time vs error, every mesh and budget, gaze {offset:g} deg")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    _save_fig(fig, path)


def plot_comparison(comps, info, ppd, path):
    plt = _plt()
    fig, axes = plt.subplots(2, 3, figsize=(15, 6.2), constrained_layout=True)
    axes[0, 0].imshow(comps["original"])
    axes[0, 0].set_title(f"original ({info['triangles']:,} triangles)")
    for j, m in enumerate(("perceptual", "size"), start=1):
        img, emap, rec = comps[m]
        axes[0, j].imshow(img)
        axes[0, j].set_title(f"{m} keys: {rec['triangles']:,} triangles, k = {rec['distance']:.2f}")
        im = axes[1, j].imshow(emap, cmap="magma", vmin=0, vmax=1)
        axes[1, j].set_title(f"FLIP {m}: mean {rec['flip']:.4f}")
    fig.colorbar(im, ax=axes[1, 2], fraction=0.046)
    axes[1, 0].text(0.02, 0.5, f"{info['mesh']}\nbudget {info['comparison_budget']:,} triangles\n"
                    f"gaze at the centre, {ppd:.1f} px/deg\nk: imperceptible beyond k x the viewing distance",
                    fontsize=11, va="center")
    for ax in axes.ravel():
        ax.axis("off")
    _save_fig(fig, path)


def _f(x, nd=4):
    return "n/a" if x is None else f"{x:.{nd}f}"


def _table(header, rows):
    out = ["| " + " | ".join(header) + " |", "| --- | --- |" + " ---: |" * (len(header) - 2)]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out)


def mesh_table(records, info, offsets, gl_ok):
    """Rows: budget x method; columns: triangles, then k / FLIP / wFLIP per view, then ms (median over views).
    The lowest FLIP (and wFLIP) of a budget and view is bold."""
    header = ["budget", "method", "triangles"]
    for off in offsets:
        header += [f"k @{off:g}°"] + ([f"FLIP @{off:g}°", f"wFLIP @{off:g}°"] if gl_ok else [])
    header += ["ms"]
    mine = [r for r in records if r["mesh"] == info["mesh"]]
    best = {}
    for r in mine:
        for fld in ("flip", "wflip"):
            if r[fld] is not None:
                key = (r["budget"], r["gaze_deg"], fld)
                best[key] = min(best.get(key, math.inf), r[fld])
    rows = []
    for b, frac in zip(info["budgets"], sorted({r["budget_fraction"] for r in mine})):
        for m in METHODS:
            rs = {r["gaze_deg"]: r for r in mine if r["budget"] == b and r["method"] == m}
            r0 = rs[offsets[0]]
            row = [f"{frac:.0%} ({b:,})", m, f"{r0['triangles']:,}"]
            for off in offsets:
                r = rs[off]
                row.append(_f(r["distance"], 2))
                if gl_ok:
                    for fld in ("flip", "wflip"):
                        s = _f(r[fld]) if fld == "flip" else ("n/a" if r[fld] is None else f"{r[fld]:.3g}")
                        row.append(f"**{s}**" if r[fld] is not None and r[fld] == best[(b, off, fld)] else s)
            row.append(f"{statistics.median(r['ms'] for r in rs.values()):.1f}")
            rows.append(row)
    return _table(header, rows)


def _ratios(cells, m):
    return [c[m]["distance"] / max(c["perceptual"]["distance"], 1e-9) for c in cells.values()]


def summary(records, infos, offsets, gl_ok):
    """Sentences computed from the numbers: who wins where."""
    lines = []
    cells = {}  # (mesh, gaze, budget) -> {method: record}
    for r in records:
        cells.setdefault((r["mesh"], r["gaze_deg"], r["budget"]), {})[r["method"]] = r
    n = len(cells)
    # perceptual distance: perceptual keys minimise it by construction (greedy order)
    ok = sum(1 for c in cells.values() if all(c["perceptual"]["distance"] <= c[m]["distance"] + 1e-6
                                              for m in ("size", "geometric")))
    lines.append(f"- **Perceptual distance k**: the perceptual keys give the smallest k in {ok} of {n} "
                 "(mesh, view, budget) cells, as the greedy order guarantees; size / geometric keys need "
                 "a median of "
                 + ", ".join(f"{statistics.median(_ratios(cells, m)):.2f}x ({m})" for m in ("size", "geometric"))
                 + " the perceptual k at the same budget. The baselines have no k.")
    if gl_ok:
        for fld, what in (("flip", "FLIP"), ("wflip", "eccentricity-weighted FLIP")):
            for off in offsets:
                sub = [c for (mesh, g, b), c in cells.items() if g == off]
                wins = {m: 0 for m in METHODS}
                for c in sub:
                    wins[min(METHODS, key=lambda m: c[m][fld])] += 1
                keyed = {m: 0 for m in METRICS}
                for c in sub:
                    keyed[min(METRICS, key=lambda m: c[m][fld])] += 1
                lines.append(f"- **{what}, gaze {off:g} deg** (lowest of {len(sub)} mesh x budget cells): "
                             + ", ".join(f"{m} {k}" for m, k in wins.items())
                             + "; among the tree cuts alone: " + ", ".join(f"{m} {k}" for m, k in keyed.items()) + ".")
        # where do the view-dependent cuts beat the best baseline?
        for off in offsets[:1]:
            per_budget = {}
            for (mesh, g, b), c in cells.items():
                if g == off:
                    frac = c["perceptual"]["budget_fraction"]
                    best_base = min(c[m]["flip"] for m in BASELINES)
                    per_budget.setdefault(frac, []).append(c["perceptual"]["flip"] / best_base)
            lines.append(f"- **Perceptual cut vs the better baseline, gaze {off:g} deg**, FLIP ratio (median over "
                         "meshes, < 1 = perceptual better): "
                         + ", ".join(f"{f:.0%}: {statistics.median(v):.2f}" for f, v in sorted(per_budget.items())) + ".")
    if gl_ok and len(offsets) > 1:
        lines.append("- FLIP is foveal everywhere, so it cannot see the gaze: the baselines' FLIP is the same in every "
                     "view, and the gaze views differ only through the perceptual cut (the same camera). wFLIP "
                     "discounts peripheral errors; with the gaze off the object it becomes tiny for every method.")
    imp = [i for i in infos if "imperceptible_triangles" in i]
    if imp:
        lines.append("- **Imperceptible cut** (`optim.imperceptible_cut`, k <= 1: no fold visible from here), triangles "
                     "(share of the input) per gaze offset: "
                     + "; ".join(i["mesh"] + " " + ", ".join(f"{g} deg {t:,} ({t / i['triangles']:.0%})"
                                                             for g, t in i["imperceptible_triangles"].items())
                                 for i in imp) + ".")
    ms = {m: statistics.median(r["ms"] for r in records if r["method"] == m) for m in METHODS}
    lines.append("- **Time** (median over every mesh, view and budget): "
                 + ", ".join(f"{m} {v:.1f} ms" for m, v in ms.items())
                 + ". Tree cuts pay a one-off tree build ("
                 + ", ".join(f"{i['mesh']} {i['build_s']:.1f} s" for i in infos)
                 + ") and then update per view; the baselines are view independent and rerun per budget.")
    return lines


def write_report(out, cfg, records, infos, gl, command, elapsed):
    from pmetric import atomic_write_text

    offsets = cfg["gaze_offsets_deg"]
    gl_ok = gl["ok"]
    L = ["# compare_metrics: perceptual vs size vs geometric keys, and two view-independent decimators", "",
         f"Command: `{command}`  ",
         f"Total time {elapsed:.0f} s. Model: `{cfg['model']}`; tree `{cfg['method']}`; object framed at "
         f"{cfg['object_deg']:g} deg of a 46-deg screen; gaze {', '.join(f'{o:g}' for o in offsets)} deg to the "
         f"right of the object centre (the screen edge is at 23 deg), {cfg['gaze_error_deg']:g} deg gaze error; "
         f"renders {cfg['render_size'][0]}x{cfg['render_size'][1]}; times are medians of {cfg['repeats']} runs.", "",
         "Columns: **k** = perceptual distance beyond which the result is imperceptible (largest perceptual key "
         "among folded nodes, multiples of the viewing distance; n/a for the baselines, which have no vertex "
         "tree to score); **FLIP** = mean FLIP between renderings of the original and the result (foveal "
         "everywhere); **wFLIP** = FLIP weighted by the model's relative sensitivity at each pixel's "
         "eccentricity from the gaze (see the docstring of `experiments/compare_metrics.py`); **ms** = per-view "
         "score + cut + extract for the tree cuts, the simplify call for the baselines (median over views). "
         "Bold: lowest FLIP / wFLIP of a budget and view. Baselines get each budget as their target count "
         "(meshoptimizer can stop above it on meshes with locked borders).", ""]
    if not gl_ok:
        L += [f"**No FLIP columns**: rendering is unavailable here ({gl['error']}).", ""]
    L += ["## Summary", ""] + summary(records, infos, offsets, gl_ok) + [""]
    L += ["Caveats: the tree cuts are view dependent, so back-facing and out-of-frustum parts are folded "
          "away for free, while the baselines spend triangles on the hidden side; that is part of what view-"
          "dependent LOD buys, not a quirk. The tree cuts keep proxy positions on the QEM hierarchy, the "
          "baselines re-optimise vertex positions (fast-simplification) or keep a subset of the input "
          "vertices (meshoptimizer). fast-simplification drops vertex colours; they are taken from the nearest "
          "input vertex (outside the timing).", ""]
    L += ["## Meshes", "", "| mesh | triangles | vertices | nodes | colours | build s | first view s |",
          "| --- | ---: | ---: | ---: | --- | ---: | ---: |"]
    L += [f"| {i['mesh']} | {i['triangles']:,} | {i['vertices']:,} | {i['nodes']:,} | {'yes' if i['colors'] else 'no'} "
          f"| {i['build_s']:.2f} | {i['first_view_s']:.2f} |" for i in infos]
    L += [""]
    for info in infos:
        L += [f"## {info['mesh']} ({info['triangles']:,} triangles)", "", mesh_table(records, info, offsets, gl_ok), ""]
        if gl_ok:
            L += [f"![comparison](comparison_{_safe(info['mesh'])}.png)", ""]
    L += ["## Plots", ""]
    if gl_ok:
        L += ["![FLIP vs triangles](flip_vs_triangles.png)", "", "![wFLIP vs triangles](wflip_vs_triangles.png)", "",
              "![time vs FLIP](time_vs_flip.png)", ""]
    L += ["![k vs triangles](distance_vs_triangles.png)", ""]
    atomic_write_text(out / "report.md", "\n".join(L) + "\n")


def _safe(name):
    return "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in name).strip("_")


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

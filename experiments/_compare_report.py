"""Plots and the Markdown report of ``experiments.compare_metrics`` (tables per mesh, the summary
computed from the numbers, PNG figures). Columns and units are described in that module's docstring."""

from __future__ import annotations

import math
import statistics

from experiments._figures import pyplot, save_png

METRICS = ("perceptual", "size", "geometric")
BASELINES = ("meshoptimizer", "fast_simplification")
METHODS = METRICS + BASELINES
COLORS = {"perceptual": "C0", "size": "C1", "geometric": "C2", "meshoptimizer": "C3", "fast_simplification": "C4"}


def plot_vs_triangles(records, infos, offsets, field, ylabel, path, methods=METHODS, by_mesh=False):
    """One panel per mesh and view (``by_mesh``: one per mesh, first view only, in a row)."""
    from matplotlib.ticker import NullFormatter

    plt = pyplot()
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
    save_png(fig, path, dpi=100)


def plot_time_vs_flip(records, offset, path):
    plt = pyplot()
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
    save_png(fig, path, dpi=100)


def plot_comparison(comps, info, ppd, path):
    plt = pyplot()
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
    save_png(fig, path, dpi=100)


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

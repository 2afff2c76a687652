"""The report of ``plod experiment`` (``experiments/experiment.py``): ``report.md`` with Markdown tables and
PNG plots computed from the rows, example renderings of the best and worst cells, ``run_info.json``.

* ``error_vs_triangles.png``: every judge's score against the triangles kept, per method;
* ``time_vs_error.png``: run time of the method (score + cut + extract, or the peer's simplify; seconds,
  tree build and judge excluded) against its error (JOD loss = 10 - JOD [Man21], else mean FLIP [And20],
  else plod's distance), with the Pareto front over all cells (lower time and lower error);
* ``wins.png`` and a table: per gaze offset and budget, how often each method has the best score among
  the methods of the same (mesh, view, lighting) at that budget;
* ``example_best_K.png`` / ``example_worst_K.png``: the cell re-run with FovVideoVDP and FLIP maps
  (``experiments.judge.save_judgement``).

The plotting functions return the data they drew, read back from the matplotlib artists, so a test can
check that the plotted points are the rows' values.
"""

from __future__ import annotations

import statistics
from pathlib import Path

import numpy as np

from pmetric import atomic_write_text

SCORES = (("jod", "FovVideoVDP (JOD, 10 = invisible)", True), ("flip", "mean FLIP", False),
          ("distance", "plod imperceptible distance", False))  # (column, label, higher is better)
METHOD_TIME = ("time_score_s", "time_cut_s", "time_extract_s", "time_peer_s")


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> None:
    import pmetric as pm

    with pm.atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    _plt().close(fig)


def _ok(rows):
    return [r for r in rows if not r.get("error")]


def method_seconds(row) -> float:
    """Seconds the method itself took in a row: score + cut + extract + peer simplify."""
    return float(sum(row.get(k) or 0.0 for k in METHOD_TIME))


def error_of(row, column: str) -> float | None:
    """The row's error on ``column``: ``10 - JOD`` for ``jod``, else the score itself (lower is better)."""
    v = row.get(column)
    if v is None:
        return None
    return 10.0 - float(v) if column == "jod" else float(v)


def error_column(rows) -> str | None:
    """The score the time-error plot uses: jod, else flip, else distance (the first any row has)."""
    for col, _, _ in SCORES:
        if any(r.get(col) is not None for r in _ok(rows)):
            return col
    return None


def _methods(rows):
    seen = []
    for r in rows:
        if r["method"] not in seen:
            seen.append(r["method"])
    return seen


def plot_error_vs_triangles(rows, path: Path) -> dict:
    """One panel per score present: the score of every cell against its triangles, per method.
    Returns {column: {method: (N, 2) array of the plotted (triangles, score)}}."""
    plt = _plt()
    cols = [(c, lab) for c, lab, _ in SCORES if any(r.get(c) is not None for r in _ok(rows))]
    if not cols:
        return {}
    fig, axes = plt.subplots(1, len(cols), figsize=(5.5 * len(cols), 4.2), squeeze=False, constrained_layout=True)
    data = {}
    for ax, (col, label) in zip(axes[0], cols):
        data[col] = {}
        for m in _methods(rows):
            pts = [(r["triangles"], r[col]) for r in _ok(rows) if r["method"] == m and r.get(col) is not None]
            if not pts:
                continue
            x, y = np.array(pts, float).T
            sc = ax.scatter(x, y, label=m, s=18, alpha=0.8)
            data[col][m] = np.asarray(sc.get_offsets(), float)
        ax.set_xscale("log")
        ax.set_xlabel("triangles")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    _save(fig, path)
    return data


def plot_time_vs_error(rows, path: Path, column: str | None = None) -> dict:
    """Run time of each cell's method against its error on ``column`` (default :func:`error_column`),
    per method, with the Pareto front over all cells and one per budget (dashed). Returns {"column",
    "points": {method: (N, 2) plotted (seconds, error)}, "front": (K, 2) plotted front over all cells,
    "front_cells": [cell ids on it], "budget_fronts": {budget: [cell ids on that budget's front]}}."""
    from experiments.experiment import pareto_front

    column = column or error_column(rows)
    if column is None:
        return {}
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 4.5), constrained_layout=True)
    use = [r for r in _ok(rows) if r.get(column) is not None]
    points = {}
    for m in _methods(use):
        mine = [r for r in use if r["method"] == m]
        x = np.array([max(method_seconds(r), 1e-6) for r in mine])
        y = np.array([error_of(r, column) for r in mine])
        sc = ax.scatter(x, y, label=m, s=20, alpha=0.8)
        points[m] = np.asarray(sc.get_offsets(), float)
    x = np.array([max(method_seconds(r), 1e-6) for r in use])
    y = np.array([error_of(r, column) for r in use])
    idx = pareto_front(x, y) if len(use) else np.array([], int)
    (line,) = ax.step(x[idx], y[idx], where="post", color="k", lw=1.2, label="Pareto front, all cells")
    # one front per budget: the overall front mixes budgets (a cell keeping more triangles has less error)
    by_budget = {}
    for b in sorted({str(r["budget"]) for r in use}):
        sel = [i for i, r in enumerate(use) if str(r["budget"]) == b]
        j = np.asarray(sel)[pareto_front(x[sel], y[sel])]
        ax.step(x[j], y[j], where="post", lw=0.8, ls="--", alpha=0.7, label=f"front, budget {b}")
        by_budget[b] = [use[i]["cell"] for i in j]
    ax.set_xscale("log")
    ax.set_xlabel("method run time (s): score + cut + extract, or peer simplify")
    ax.set_ylabel({"jod": "JOD loss (10 - JOD)", "flip": "mean FLIP", "distance": "plod distance"}[column])
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    _save(fig, path)
    return {"column": column, "points": points, "front": np.asarray(line.get_xydata(), float),
            "front_cells": [use[i]["cell"] for i in idx], "budget_fronts": by_budget}


def wins(rows, column: str) -> dict:
    """{(gaze_deg, budget): {method: wins}}: per (mesh, view, lighting) at a gaze offset and budget, the
    method(s) with the best ``column`` score (ties count for each); budget-free cells (``-``) left out."""
    higher = dict((c, h) for c, _, h in SCORES)[column]
    groups: dict = {}
    for r in _ok(rows):
        if r["budget"] == "-" or r.get(column) is None:
            continue
        groups.setdefault((r["gaze_deg"], r["budget"]), {}).setdefault((r["mesh"], r["view"], r["lighting"]), []).append(r)
    out = {}
    for key, sits in groups.items():
        count = {}
        for cand in sits.values():
            vals = [c[column] for c in cand]
            best = max(vals) if higher else min(vals)
            for c in cand:
                count.setdefault(c["method"], 0)
                if c[column] == best:
                    count[c["method"]] += 1
        out[key] = count
    return out


def plot_wins(table: dict, column: str, path: Path) -> dict:
    """Grouped bars of :func:`wins`; returns {method: plotted heights in the order of the groups}."""
    if not table:
        return {}
    plt = _plt()
    keys = sorted(table, key=lambda k: (k[0], float(k[1])))
    methods = sorted({m for d in table.values() for m in d})
    fig, ax = plt.subplots(figsize=(max(6.0, 1.2 * len(keys) + 2), 4.0), constrained_layout=True)
    width = 0.8 / max(len(methods), 1)
    heights = {}
    for i, m in enumerate(methods):
        h = [table[k].get(m, 0) for k in keys]
        bars = ax.bar(np.arange(len(keys)) + i * width, h, width, label=m)
        heights[m] = [b.get_height() for b in bars]
    ax.set_xticks(np.arange(len(keys)) + 0.4 - width / 2, [f"gaze {g:g}°\nbudget {b}" for g, b in keys], fontsize=8)
    ax.set_ylabel(f"wins ({column})")
    ax.legend(fontsize=7)
    _save(fig, path)
    return heights


def _fmt(x, nd=3):
    return "n/a" if x is None else f"{x:.{nd}f}"


def _median(xs):
    xs = [x for x in xs if x is not None]
    return statistics.median(xs) if xs else None


def example_images(rows, cfg, out: Path, column: str, n: int) -> list[tuple[str, str]]:
    """Re-run the ``n`` best and ``n`` worst cells on ``column`` with FovVideoVDP/FLIP maps and save
    them; returns [(title, file name)]."""
    from experiments import experiment as E
    from experiments.judge import save_judgement

    if n <= 0 or column not in ("jod", "flip") or not any(j in cfg["judges"] for j in ("fovvdp", "flip")):
        return []
    use = sorted((r for r in _ok(rows) if r.get(column) is not None), key=lambda r: error_of(r, column))
    if not use:
        return []
    tasks = {t["cell"]: t for t in E.cells(cfg)}
    picks = [("best", k, r) for k, r in enumerate(use[:n])]
    picks += [("worst", k, r) for k, r in enumerate(use[::-1][:n]) if r["cell"] not in {p[2]["cell"] for p in picks}]
    images = []
    for kind, k, r in picks:
        row = E.run_cell(tasks[r["cell"]], keep=True)
        res = row.get("_judgement")
        if res is None:
            continue
        name = f"example_{kind}_{k}.png"
        title = (f"{kind} cell {r['cell']}: {row['triangles']:,} of {row['input_triangles']:,} triangles, "
                 f"JOD {_fmt(row['jod'])}, FLIP {_fmt(row['flip'], 4)}")
        save_judgement(out / name, res, titles=("original", f"{r['method']}: {row['triangles']:,} triangles"))
        images.append((title, name))
    return images


def write_report(rows, cfg, out, command: str, *, examples: bool = True) -> dict:
    """Write ``report.md``, the PNGs and ``run_info.json`` into ``out``; returns the plotted data
    ({"error_vs_triangles", "time_vs_error", "wins"})."""
    from experiments import experiment as E
    from experiments._runinfo import save_run_info

    out = Path(out)
    ok = _ok(rows)
    column = error_column(rows)
    plotted = {"error_vs_triangles": plot_error_vs_triangles(rows, out / "error_vs_triangles.png"),
               "time_vs_error": plot_time_vs_error(rows, out / "time_vs_error.png", column) if column else {}}
    wcol = column
    table = wins(rows, wcol) if wcol else {}
    plotted["wins"] = plot_wins(table, wcol, out / "wins.png") if table else {}
    T = "results.parquet" if (out / "results.parquet").exists() else "results.csv"
    L = ["# plod experiment\n", f"Command: `{command}`\n",
         f"{len(rows)} cells ({len(rows) - len(ok)} failed); rows in `{T}` (one per cell: ids, triangles, "
         "every judge's score, seconds of each stage, versions); resolved config, git SHA, seed and versions in "
         "`run_info.json`.\n",
         f"Meshes: {', '.join(sorted({r['mesh'] for r in rows}))}; {cfg['views']} view(s) per mesh (seed "
         f"{cfg['seed']}), object {cfg['object_deg']:g} deg; gaze offsets "
         f"{', '.join(f'{g:g}' for g in cfg['gaze_offsets_deg'])} deg, gaze error {cfg['gaze_error_deg']:g} deg; "
         f"lightings {', '.join(cfg['lightings'])}; budgets {', '.join(str(b) for b in cfg['budgets'])} "
         f"(fractions of the input triangles, or counts); tree {cfg['tree_method']}; judges "
         f"{', '.join(cfg['judges'])} at {cfg['judge_size'][0]}x{cfg['judge_size'][1]} px.\n"]
    skipped = E.skipped_meshes(cfg)
    if skipped:
        L.append(f"Skipped (not found here): {', '.join(skipped)}.\n")
    L += ["## Methods\n", "Medians over the cells of each method. *s*: the method's run time (score + cut + "
          "extract, or the peer's simplify), tree build and judge excluded.\n",
          "| method | cells | triangles | JOD | FLIP | distance | s | judge s |",
          "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for m in _methods(rows):
        mine = [r for r in ok if r["method"] == m]
        if not mine:
            L.append(f"| {m} | 0 | n/a | n/a | n/a | n/a | n/a | n/a |")
            continue
        L.append(f"| {m} | {len(mine)} | {_median([r['triangles'] for r in mine]):,.0f} | "
                 f"{_fmt(_median([r.get('jod') for r in mine]))} | {_fmt(_median([r.get('flip') for r in mine]), 4)} | "
                 f"{_fmt(_median([r.get('distance') for r in mine]))} | {_median([method_seconds(r) for r in mine]):.4f} | "
                 f"{_median([r.get('time_judge_s') for r in mine]) or 0:.2f} |")
    L.append("")
    if plotted["error_vs_triangles"]:
        L += ["## Error against triangles\n", "![error against triangles](error_vs_triangles.png)\n"]
    tv = plotted["time_vs_error"]
    if tv:
        L += ["## Run time against error\n",
              f"Error: {'JOD loss (10 - JOD)' if column == 'jod' else column}; the Pareto front (black) joins the "
              "cells no other cell beats in both run time and error.\n", "![run time against error](time_vs_error.png)\n",
              "| on the front | method | s | error |", "| --- | --- | ---: | ---: |"]
        by = {r["cell"]: r for r in ok}
        for cid in tv["front_cells"]:
            r = by[cid]
            L.append(f"| {cid} | {r['method']} | {method_seconds(r):.4f} | {_fmt(error_of(r, column), 4)} |")
        L += ["", "The front over all cells mixes budgets (a cell that keeps more triangles has less error); the "
              "front of each budget compares methods at equal budgets (dashed in the plot):", "",
              "| budget | on the front | method | s | error |", "| --- | --- | --- | ---: | ---: |"]
        for b, cells in tv.get("budget_fronts", {}).items():
            for cid in cells:
                r = by[cid]
                L.append(f"| {b} | {cid} | {r['method']} | {method_seconds(r):.4f} | "
                         f"{_fmt(error_of(r, column), 4)} |")
        L.append("")
    if table:
        methods = sorted({m for d in table.values() for m in d})
        L += [f"## Wins per gaze offset and budget ({wcol})\n",
              "Per (mesh, view, lighting): the method(s) with the best score at that gaze offset and budget "
              "(ties count for each).\n", "![wins](wins.png)\n",
              "| gaze deg | budget | situations | " + " | ".join(methods) + " |",
              "| ---: | ---: | ---: |" + " ---: |" * len(methods)]
        groups = {}
        for r in ok:
            if r["budget"] != "-" and r.get(wcol) is not None:
                groups.setdefault((r["gaze_deg"], r["budget"]), set()).add((r["mesh"], r["view"], r["lighting"]))
        for key in sorted(table, key=lambda k: (k[0], float(k[1]))):
            L.append(f"| {key[0]:g} | {key[1]} | {len(groups[key])} | "
                     + " | ".join(str(table[key].get(m, 0)) for m in methods) + " |")
        L.append("")
    failed = [r for r in rows if r.get("error")]
    if failed:
        L += ["## Failed cells\n", "| cell | error |", "| --- | --- |"]
        L += [f"| {r['cell']} | {r['error'].replace('|', '/')} |" for r in failed[:50]]
        L.append("")
    imgs = example_images(rows, cfg, out, column, cfg["examples"]) if examples and column else []
    if imgs:
        L.append("## Example renderings\n")
        L.append("Original | result | FovVideoVDP map | FLIP map, for the best and worst cells.\n")
        for title, name in imgs:
            L.append(f"**{title}**\n\n![{title}]({name})\n")
    L += ["## All cells\n", "| cell | triangles | JOD | FLIP | distance | s |", "| --- | ---: | ---: | ---: | ---: | ---: |"]
    for r in ok:
        L.append(f"| {r['cell']} | {r['triangles']:,} | {_fmt(r.get('jod'))} | {_fmt(r.get('flip'), 4)} | "
                 f"{_fmt(r.get('distance'))} | {method_seconds(r):.4f} |")
    atomic_write_text(out / "report.md", "\n".join(L) + "\n")
    save_run_info(out, cfg, cfg["seed"], command)
    plotted["examples"] = imgs
    return plotted

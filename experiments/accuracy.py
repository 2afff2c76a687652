"""What a viewer sees: plod's cuts judged by FovVideoVDP [Man21] and FLIP [And20] on meshes and views
the tests do not use (the accuracy targets of the issue "make the perceptual metric right").

    .venv/bin/python -m experiments.accuracy [--config configs/accuracy.toml] [--quick] [--out DIR] [--resume]

Cells: every mesh x ``views`` random view directions (seeded) x gaze offsets (deg of visual angle to
the right of the object's centre, gaze error ``gaze_error_deg``) x lighting:

* ``relit``: the renderer shades each mesh from its own normals with ``optim.Lighting()`` (the
  view carries the light, so plod's fold contrast covers what relighting shows);
* ``baked``: the seeds' pre-lit case: vertex colours (for an uncoloured mesh, the original's
  lighting baked into grey vertex colours) carried by the result; the view has no light.

Per cell: the imperceptible cut (``optim.imperceptible_cut``, default model) and, for every budget (a
fraction of the input triangles), plod's perceptual budget cut and, at its triangle count, size keys,
geometric keys, meshoptimizer's ``simplify`` (``simplifyWithAttributes`` on coloured meshes) and
fast-simplification; at ``model_budget`` also perceptual cuts with the other ``models`` (registry
names or fitted JSON files). Every result is rendered at ``size`` for the view (same angular content
as the full image) and judged against the original in the cell's lighting: FovVideoVDP JOD (10 =
indistinguishable), foveated at the gaze, and mean FLIP.

Writes ``DIR/results.jsonl`` (one line per judged mesh, appended as it goes; ``--resume`` skips what
is there), ``DIR/report.md`` (tables computed from those lines), ``DIR/worst_*.png`` (renderings and
difference maps of the worst cells) and ``DIR/run_info.json``. ``--no-model-lights`` scores relit
cells without putting the light in the view (what the code before lights in the model did).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from experiments._runinfo import check_out_dir, load_config, repo_path, save_run_info
from experiments.experiment import baked_grey, procedural_mesh, view_directions  # noqa: F401  (shared with the runner)
from pmetric import PlodError, atomic_write_text

WRITES = ("results.jsonl", "report.md", "worst_*.png")  # what a run writes into its folder (check_out_dir)

DEFAULTS = {
    "out": "reports/accuracy",
    "meshes": [
        "../shared/data/meshes/horse.ply",
        "../shared/data/meshes/armadillo-70k.ply",
        "../shared/data/meshes/lucy-100k.ply",
        "../shared/data/meshes/dragon-100k.obj",
    ],
    # procedural meshes, always run: "sphere:SUBDIV:SEED" (bumpy_sphere, coloured) or "torus:NU:NV:SEED"
    "procedural": ["sphere:6:11", "torus:240:120:5"],
    "views": 1,
    "seed": 2026,
    "object_deg": 30.0,
    "gaze_offsets_deg": [0.0, 8.0, 16.0],
    "gaze_error_deg": 1.0,
    "lightings": ["relit", "baked"],
    "budgets": [0.03, 0.08, 0.20],
    "model_budget": 0.08,
    # beside the default (stelaCSF): the seeds' model, plod's default before, and the refits
    "models": ["kellyabstract", "reports/fit_real/fitted_stelacsf.json", "reports/fit_real/fitted_barten.json"],
    "size": [960, 540],
    "worst": 3,
    # plod's cuts without the triangles that face away from the eye (optim.drop_back_faces, keeping the
    # full cut's normals), budgets counted in front-facing triangles (optim.visible_budget_cut); the peers
    # stay whole meshes at plod's (front-facing) triangle count
    "face_cull": False,
    "face_cull_margin_deg": 0.0,
    # the vertex normals plod's cuts carry for the relit renderer (optim.extract's ``normals``): "faces",
    # recomputed from the cut's faces (what a renderer does with a mesh that carries none; the whole cut's
    # with face culling), or "region", each vertex its region's mean input normal
    "normals": "faces",
    # plod's vertex tree (optim.build_tree's method)
    "method": "meshopt",
    # the imperceptible cuts of the code before lights in the model (default: OUT/before/results.jsonl)
    "before": "",
}
QUICK = {"meshes": [], "procedural": ["sphere:4:11"], "views": 1, "gaze_offsets_deg": [0.0],
         "budgets": [0.08], "models": [], "size": [480, 270], "worst": 1, "out": "reports/accuracy/quick"}

KEY_METHODS = ("perceptual", "size", "geometric")
PEERS = ("meshoptimizer", "fast_simplification")
IMPERCEPTIBLE_TARGET = 9.8


# ----------------------------------------------------------------------------------------------- inputs
def load_meshes(cfg):
    """[(name, vertices, faces, colors or None)] of the config's files (missing ones skipped) and
    procedural meshes."""
    import optim

    out = []
    for spec in cfg["meshes"]:
        p = repo_path(spec)
        if p.is_file():
            v, f, c = optim.load_mesh(p)
            out.append((p.stem, v, f, c))
    for spec in cfg["procedural"]:
        v, f, c = procedural_mesh(spec)
        out.append((spec.replace(":", "-"), v, f, c))
    if not out:
        raise PlodError("accuracy: no meshes (none of the config's files exist and 'procedural' is empty)")
    return out


def absent_inputs(cfg) -> list[str]:
    """The config's mesh files and JSON model files that are not found (``load_meshes`` and
    ``load_models`` skip them, so that a checkout without ``../shared`` still runs the procedural cells):
    the reports name them, so that a sweep with fewer cells than its config says so."""
    names = list(cfg.get("meshes", ())) + [m for m in cfg.get("models", ()) if str(m).lower().endswith(".json")]
    return [n for n in names if not repo_path(n).is_file()]


def absent_line(cfg) -> str:
    """One report line naming :func:`absent_inputs`, or "" when every file was found."""
    gone = absent_inputs(cfg)
    return f"**Not run** (in the config, files not found): {', '.join(f'`{n}`' for n in gone)}.\n" if gone else ""


def load_models(names):
    from pmetric import make_model

    out = {}
    for name in names:
        spec = str(repo_path(name)) if name.lower().endswith(".json") else name
        if name.lower().endswith(".json") and not Path(spec).is_file():
            continue
        out[Path(name).stem if name.endswith(".json") else name] = make_model(spec)
    return out


# ----------------------------------------------------------------------------------------------- one cell
class _Mesh:
    """A mesh of the sweep and its trees: ``relit`` (its own colours or none) and ``baked`` (for an
    uncoloured mesh, built from the original's lighting baked into grey vertex colours)."""

    def __init__(self, name, v, f, c, method: str = "meshopt"):
        import optim

        self.name, self.v, self.f, self.c = name, v, f, c
        t0 = time.perf_counter()
        self.tree = {"relit": optim.build_tree(v, f, c, method=method)}
        if c is None:
            self.baked_colors = baked_grey(v, f)
            self.tree["baked"] = optim.build_tree(v, f, self.baked_colors, method=method)
        else:
            self.baked_colors = c
            self.tree["baked"] = self.tree["relit"]
        self.build_s = time.perf_counter() - t0

    def original(self, lighting: str):
        return (self.v, self.f, self.c if lighting == "relit" else self.baked_colors)

    def peer(self, method: str, lighting: str, target: int):
        """A view-independent peer's result at ``target`` triangles with the cell's colours
        (``experiments.experiment``'s, with meshoptimizer keeping the mesh's own colour edges)."""
        from experiments.experiment import _peer

        colors = self.c if lighting == "relit" else self.baked_colors
        if method == "meshoptimizer":
            from experiments.peers import compact, meshopt_simplify

            return compact(self.v, meshopt_simplify(self.v, self.f, target, self.c), colors)
        return _peer(method, self.v, self.f, colors, target)


def _view(mesh: _Mesh, direction, gaze_deg, lighting, cfg, model_lights: bool):
    import optim
    from experiments.judge import offset_gaze_view

    kw = {"lighting": optim.Lighting()} if lighting == "relit" and model_lights else {}
    return offset_gaze_view(mesh.v, gaze_deg, object_deg=cfg["object_deg"], direction=direction,
                            gaze_error_deg=cfg["gaze_error_deg"], **kw)


def plod_mesh(tree, keys, view, cfg, target: int | None = None, *, cut=None):
    """(mesh, triangles of the whole cut) of plod's cut for ``view``: ``cut`` as given, else the budget cut
    of ``keys`` to ``target`` triangles; with ``cfg["face_cull"]`` drawn without its back faces, a budget
    counting front-facing triangles (``optim.visible_budget_cut``)."""
    import optim

    cull, margin = bool(cfg.get("face_cull")), float(cfg.get("face_cull_margin_deg", 0.0))
    normals = cfg.get("normals", "faces")
    if cut is None and cull:
        vc = optim.visible_budget_cut(tree, keys, target, view, margin_deg=margin, monotone="trust", normals=normals)
        return vc.mesh, vc.cut.triangles
    if cut is None:
        cut = optim.budget_cut(tree, keys, target, monotone="trust")
    # "faces" without culling: the mesh as a file without normals gives it (the renderer makes the same ones)
    mesh = optim.extract(tree, cut, None if normals == "faces" and not cull else normals)
    return (optim.drop_back_faces(mesh, view, margin) if cull else mesh), cut.triangles


def cell_results(mesh: _Mesh, direction, gaze_deg, lighting, cfg, models, model_lights=True, keep=None):
    """Judge every method of one cell; returns a list of result dicts (and, with ``keep`` a set of
    ``(method, budget)``, the judged meshes of those in ``keep_out``)."""
    import optim
    from experiments.judge import judge

    tree = mesh.tree[lighting]
    view = _view(mesh, direction, gaze_deg, lighting, cfg, model_lights)
    light = optim.Lighting() if lighting == "relit" else None
    size = tuple(cfg["size"])
    ref = mesh.original(lighting)
    rows, kept = [], {}

    def judged(method, budget, result, ms=None, **extra):
        res = judge(ref, result, view, mode=lighting, lighting=light, size=size, heatmap=False)
        rows.append(dict(method=method, budget=budget, triangles=int(len(result[1])), jod=res.jod,
                         flip=res.flip_mean, update_ms=ms, judge_s=round(res.seconds, 2), **extra))
        if keep is not None and (method, budget) in keep:
            kept[(method, budget)] = result

    t0 = time.perf_counter()
    keys = optim.score(tree, view)
    cut = optim.threshold_cut(tree, keys, 1.0, monotone="trust")
    result, _ = plod_mesh(tree, keys, view, cfg, cut=cut)
    judged("imperceptible", None, result, 1e3 * (time.perf_counter() - t0), distance=float(cut.distance),
           cut_triangles=int(cut.triangles))
    T = tree.n_triangles
    for b in cfg["budgets"]:
        t0 = time.perf_counter()
        pk = optim.score(tree, view)
        presult, pcut_t = plod_mesh(tree, pk, view, cfg, max(int(b * T), 1))
        ms = 1e3 * (time.perf_counter() - t0)
        judged("perceptual", b, presult, ms, cut_triangles=pcut_t)
        target = len(presult[1])
        for metric in ("size", "geometric"):
            k = optim.score(tree, view, None, metric)
            m, ct = plod_mesh(tree, k, view, cfg, target)
            judged(metric, b, m, cut_triangles=ct)
        for peer in PEERS:
            judged(peer, b, mesh.peer(peer, lighting, target))
        if b == cfg["model_budget"]:
            for name, model in models.items():
                k = optim.score(tree, view, model)
                m, ct = plod_mesh(tree, k, view, cfg, target)
                judged(f"model:{name}", b, m, cut_triangles=ct)
    return (rows, kept) if keep is not None else rows


# ----------------------------------------------------------------------------------------------- sweep
def _cells(meshes, cfg):
    for name, v, f, c in meshes:
        for vi, d in enumerate(view_directions(cfg["views"], cfg["seed"], name)):
            for g in cfg["gaze_offsets_deg"]:
                for lighting in cfg["lightings"]:
                    yield name, vi, d, float(g), lighting


def _cell_id(name, vi, g, lighting):
    return f"{name}/v{vi}/g{g:g}/{lighting}"


def run_sweep(cfg, *, resume=False, model_lights=True, progress=None):
    """Run (or resume) the sweep; returns all result rows (dicts with the cell's ids)."""
    out = check_out_dir(repo_path(cfg["out"]))
    out.mkdir(parents=True, exist_ok=True)
    path = out / "results.jsonl"
    done = {}
    if resume and path.is_file():
        for line in path.read_text().splitlines():
            if line.strip():
                row = json.loads(line)
                done.setdefault(row["cell"], []).append(row)
    elif path.exists():
        path.unlink()
    meshes = load_meshes(cfg)
    models = load_models(cfg["models"])
    cells = list(_cells(meshes, cfg))
    built = {}
    rows = []
    for i, (name, vi, d, g, lighting) in enumerate(cells):
        cid = _cell_id(name, vi, g, lighting)
        if cid in done:
            rows += done[cid]
            continue
        if name not in built:
            built.clear()
            mesh = next(m for m in meshes if m[0] == name)
            built[name] = _Mesh(*mesh, method=cfg["method"])
        mesh = built[name]
        t0 = time.perf_counter()
        try:
            cell_rows = cell_results(mesh, d, g, lighting, cfg, models, model_lights)
        except Exception as exc:  # a failed cell records its error; the sweep goes on
            cell_rows = [dict(method="error", budget=None, error=f"{type(exc).__name__}: {exc}")]
        base = dict(cell=cid, mesh=name, view=vi, direction=[round(x, 6) for x in d], gaze_deg=g, lighting=lighting,
                    input_triangles=int(mesh.tree[lighting].n_triangles), colored=mesh.c is not None)
        cell_rows = [{**base, **r} for r in cell_rows]
        with open(path, "a") as fh:
            for r in cell_rows:
                fh.write(json.dumps(r) + "\n")
        rows += cell_rows
        if progress is not None:
            progress(i + 1, len(cells), cid, time.perf_counter() - t0)
    return rows


# ----------------------------------------------------------------------------------------------- report
def _fmt(x, nd=2):
    return "n/a" if x is None else f"{x:.{nd}f}"


def summarise(rows, cfg):
    """The numbers of the report, computed from the rows: dict of summaries."""
    by_cell = {}
    for r in rows:
        by_cell.setdefault(r["cell"], []).append(r)
    summ = {"imperceptible": {}, "budget": {}, "models": {}, "update_ms": {}}
    for lighting in cfg["lightings"]:
        imp = [r for r in rows if r["lighting"] == lighting and r["method"] == "imperceptible" and r.get("jod") is not None]
        if imp:
            jods = [r["jod"] for r in imp]
            summ["imperceptible"][lighting] = dict(
                cells=len(imp), min_jod=min(jods), median_jod=statistics.median(jods),
                share_at_target=sum(j >= IMPERCEPTIBLE_TARGET for j in jods) / len(jods),
                median_kept=statistics.median(r["triangles"] / r["input_triangles"] for r in imp))
        wins, gains, total = 0, [], 0
        for cid, cr in by_cell.items():
            if cr[0]["lighting"] != lighting:
                continue
            for b in cfg["budgets"]:
                got = {r["method"]: r["jod"] for r in cr if r.get("budget") == b and r.get("jod") is not None}
                if "perceptual" not in got:
                    continue
                others = [got[m] for m in ("size", "geometric") + PEERS if m in got]
                if not others:
                    continue
                total += 1
                best = max(others)
                wins += got["perceptual"] > best
                gains.append(got["perceptual"] - best)
        if total:
            summ["budget"][lighting] = dict(cells=total, share_best=wins / total, median_gain=statistics.median(gains))
        per = {}
        for r in rows:
            if r["lighting"] == lighting and r.get("budget") == cfg["model_budget"] and r.get("jod") is not None:
                if r["method"] == "perceptual" or r["method"].startswith("model:"):
                    per.setdefault(r["method"], []).append(r["jod"])
        if per:
            summ["models"][lighting] = {m: statistics.median(j) for m, j in per.items()}
        ms = [r["update_ms"] for r in rows if r["lighting"] == lighting and r["method"] == "perceptual"
              and r.get("update_ms") is not None]
        if ms:
            summ["update_ms"][lighting] = statistics.median(ms)
    return summ


def write_report(rows, cfg, command, out, images=()):
    summ = summarise(rows, cfg)
    L = [f"# Accuracy under an independent judge\n", f"Command: `{command}`\n",
         "Judge: FovVideoVDP (pyfvvdp, foveated at the gaze; JOD, 10 = indistinguishable) and mean FLIP "
         f"on pyrender renderings at {cfg['size'][0]}x{cfg['size'][1]} pixels with the display's angular "
         "content (plod's default display: 46 deg wide at 0.63 m, 200 cd/m2). Relit: each mesh shaded "
         "from its own normals with `optim.Lighting()`; baked: vertex colours (the original's lighting "
         "baked into grey for uncoloured meshes) carried by the result. Views: random directions per "
         f"mesh (seed {cfg['seed']}), object {cfg['object_deg']:g} deg, gaze offsets "
         f"{', '.join(f'{g:g}' for g in cfg['gaze_offsets_deg'])} deg from its centre, gaze error "
         f"{cfg['gaze_error_deg']:g} deg. None of these meshes or views is used by the tests.\n"]
    absent = absent_line(cfg)
    if absent:
        L.append(absent)
    if cfg.get("face_cull"):
        L.append(f"**Face culling on**: plod's cuts (imperceptible, perceptual, size, geometric, models) are drawn "
                 f"without the triangles that face away from the eye by more than {cfg['face_cull_margin_deg']:g} deg "
                 "(`optim.drop_back_faces`, shading from the whole cut's normals unless they carry their own, so the view's image is the whole "
                 "cut's), and budgets count front-facing triangles (`optim.visible_budget_cut`). The peers are whole "
                 "meshes at plod's front-facing triangle count. *triangles* columns count drawn triangles; "
                 "`results.jsonl` has each cut's whole count as `cut_triangles`.\n")
    if cfg.get("method", "meshopt") != "meshopt":
        L.append(f"**Tree**: plod's cuts come from `optim.build_tree(method=\"{cfg['method']}\")`.\n")
    if cfg.get("normals", "faces") == "region":
        L.append("**Carried normals**: plod's cuts carry each vertex's region normal (`optim.extract(..., "
                 "normals=\"region\")`: the mean input normal of the surface its node stands for), and the "
                 "relit renderer shades from them; the peers are shaded from normals of their own faces.\n")
    errors = [r for r in rows if r["method"] == "error"]
    if errors:
        L.append(f"**{len(errors)} cells failed**: " + "; ".join(f"{r['cell']}: {r['error']}" for r in errors[:5]) + "\n")
    L.append("## Summary\n")
    L.append("| lighting | imperceptible cuts | min JOD | median JOD | share >= 9.8 | median kept | "
             "budget cells | perceptual best | median gain (JOD) | update ms |")
    L.append("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for lighting in cfg["lightings"]:
        i = summ["imperceptible"].get(lighting, {})
        b = summ["budget"].get(lighting, {})
        L.append(f"| {lighting} | {i.get('cells', 0)} | {_fmt(i.get('min_jod'))} | {_fmt(i.get('median_jod'))} | "
                 f"{_fmt(100 * i['share_at_target'], 0) + ' %' if i else 'n/a'} | "
                 f"{_fmt(100 * i['median_kept'], 1) + ' %' if i else 'n/a'} | {b.get('cells', 0)} | "
                 f"{_fmt(100 * b['share_best'], 0) + ' %' if b else 'n/a'} | {_fmt(b.get('median_gain'), 3)} | "
                 f"{_fmt(summ['update_ms'].get(lighting), 1)} |")
    L.append("\n*perceptual best*: share of (cell, budget) pairs where plod's perceptual budget cut has a higher "
             "JOD than each of size keys, geometric keys, meshoptimizer and fast-simplification at its triangle "
             "count; *median gain*: perceptual JOD minus the best of those. *update ms*: score + budget cut + "
             "extract per view (median; on this machine, with the judge idle).\n")
    if any(summ["models"].values()):
        names = sorted({m for d in summ["models"].values() for m in d})
        L.append(f"## CSF models at the {100 * cfg['model_budget']:g} % budget (median JOD)\n")
        L.append("| lighting | " + " | ".join(names) + " |")
        L.append("| --- |" + " ---: |" * len(names))
        for lighting, d in summ["models"].items():
            L.append(f"| {lighting} | " + " | ".join(_fmt(d.get(m), 3) for m in names) + " |")
        import pmetric

        L.append(f"\n`perceptual` is the default model (`{pmetric.DEFAULT_MODEL}`, "
                 f"{type(pmetric.default_model()).__name__}); `model:NAME` the same cut with that model.\n")
    before = _before_rows(out, cfg.get("before", ""))
    if before:
        L += _before_table(rows, before)
    L.append("## Imperceptible cuts\n")
    L.append("| cell | triangles kept | distance | JOD | FLIP |")
    L.append("| --- | ---: | ---: | ---: | ---: |")
    for r in sorted((r for r in rows if r["method"] == "imperceptible"), key=lambda r: r.get("jod") or 0):
        L.append(f"| {r['cell']} | {r['triangles']:,} of {r['input_triangles']:,} | {_fmt(r.get('distance'), 3)} | "
                 f"{_fmt(r.get('jod'), 3)} | {_fmt(r.get('flip'), 4)} |")
    L.append("\n## Budget cuts (JOD; triangles of the perceptual cut)\n")
    methods = ["perceptual", "size", "geometric", *PEERS]
    L.append("| cell | budget | triangles | " + " | ".join(methods) + " |")
    L.append("| --- | ---: | ---: |" + " ---: |" * len(methods))
    by = {}
    for r in rows:
        if r.get("budget") is not None:
            by.setdefault((r["cell"], r["budget"]), {})[r["method"]] = r
    for (cid, b), d in sorted(by.items()):
        if "perceptual" not in d:
            continue
        best = max((d[m]["jod"] for m in methods if m in d and d[m].get("jod") is not None), default=None)
        cells = []
        for m in methods:
            j = d.get(m, {}).get("jod")
            s = _fmt(j, 3)
            cells.append(f"**{s}**" if j is not None and j == best else s)
        L.append(f"| {cid} | {100 * b:g} % | {d['perceptual']['triangles']:,} | " + " | ".join(cells) + " |")
    if images:
        L.append("\n## Worst cells\n")
        for title, rel in images:
            L.append(f"**{title}**\n\n![{title}]({rel})\n")
    atomic_write_text(out / "report.md", "\n".join(L) + "\n")
    return summ


def _before_rows(out: Path, before: str = "") -> dict:
    """{cell: imperceptible row} of ``out/before/results.jsonl`` (or ``before/results.jsonl``: the same
    cells judged with the code before lights in the model), or {} when absent."""
    path = out / "before" / "results.jsonl" if not before else repo_path(before) / "results.jsonl"
    if not path.is_file():
        return {}
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return {r["cell"]: r for r in rows if r["method"] == "imperceptible" and r.get("jod") is not None}


def _before_table(rows, before) -> list:
    """Markdown lines comparing each imperceptible cut with the one before (same cell)."""
    now = {r["cell"]: r for r in rows if r["method"] == "imperceptible" and r.get("jod") is not None}
    cells = sorted(set(now) & set(before))
    if not cells:
        return []
    ratio = [now[c]["triangles"] / max(before[c]["triangles"], 1) for c in cells]
    L = ["## Imperceptible cuts before and after\n",
         f"{len(cells)} cells; triangles kept now / before: median {statistics.median(ratio):.2f}, "
         f"range {min(ratio):.2f} .. {max(ratio):.2f}; cells at >= {IMPERCEPTIBLE_TARGET} JOD: before "
         f"{sum(before[c]['jod'] >= IMPERCEPTIBLE_TARGET for c in cells)}, now "
         f"{sum(now[c]['jod'] >= IMPERCEPTIBLE_TARGET for c in cells)}; cells keeping no more triangles "
         f"than before: {sum(r <= 1.0 for r in ratio)}.\n",
         "| cell | triangles before | JOD before | triangles now | JOD now |", "| --- | ---: | ---: | ---: | ---: |"]
    for c in cells:
        b, n = before[c], now[c]
        L.append(f"| {c} | {b['triangles']:,} | {b['jod']:.3f} | {n['triangles']:,} | {n['jod']:.3f} |")
    L.append("")
    return L


def worst_images(rows, cfg, out, model_lights=True):
    """Re-judge the worst imperceptible cells and the cells where perceptual keys lose most, with maps;
    returns [(title, file name)]."""
    from experiments.judge import judge, save_judgement
    import optim

    imp = sorted((r for r in rows if r["method"] == "imperceptible" and r.get("jod") is not None), key=lambda r: r["jod"])
    loss = []
    by = {}
    for r in rows:
        if r.get("budget") is not None and r.get("jod") is not None:
            by.setdefault((r["cell"], r["budget"]), {})[r["method"]] = r
    for (cid, b), d in by.items():
        if "perceptual" in d:
            others = [(d[m]["jod"], m) for m in ("size", "geometric") + PEERS if m in d]
            if others:
                best = max(others)
                loss.append((d["perceptual"]["jod"] - best[0], cid, b, best[1], d["perceptual"]))
    loss.sort()
    picks = [("imperceptible", r, None, None) for r in imp[:cfg["worst"]]]
    picks += [("perceptual", r, b, peer) for _, cid, b, peer, r in loss[:cfg["worst"]]]
    meshes = {m[0]: m for m in load_meshes(cfg)}
    images, built = [], {}
    for k, (method, r, b, peer) in enumerate(picks):
        if r["mesh"] not in built:
            built.clear()
            built[r["mesh"]] = _Mesh(*meshes[r["mesh"]], method=cfg["method"])
        mesh = built[r["mesh"]]
        d = np.asarray(r["direction"])
        lighting = r["lighting"]
        view = _view(mesh, d, r["gaze_deg"], lighting, cfg, model_lights)
        tree = mesh.tree[lighting]
        keys = optim.score(tree, view)
        if method == "imperceptible":
            result, _ = plod_mesh(tree, keys, view, cfg, cut=optim.threshold_cut(tree, keys, 1.0, monotone="trust"))
        else:
            result, _ = plod_mesh(tree, keys, view, cfg, max(int(b * tree.n_triangles), 1))
        res = judge(mesh.original(lighting), result, view, mode=lighting,
                    lighting=optim.Lighting() if lighting == "relit" else None, size=tuple(cfg["size"]))
        name = f"worst_{method}_{k}.png"
        nt = len(result[1])
        title = (f"{method} cut, {r['cell']}" + (f", budget {100 * b:g} % (best peer: {peer})" if b else "")
                 + f": {nt:,} triangles, JOD {res.jod:.3f}")
        save_judgement(out / name, res, titles=("original", f"{method}: {nt:,} triangles"))
        images.append((title, name))
    return images


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m experiments.accuracy", description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default=None, help="TOML overrides of the defaults (unknown keys are refused)")
    ap.add_argument("--quick", action="store_true", help="a small sweep (one procedural mesh, one view)")
    ap.add_argument("--out", default=None, help="report folder (default reports/accuracy)")
    ap.add_argument("--resume", action="store_true", help="keep the cells already in results.jsonl")
    ap.add_argument("--no-model-lights", action="store_true",
                    help="score relit cells without the light in the view (the behaviour before lights in the model)")
    ap.add_argument("--no-images", action="store_true", help="skip the worst-cell images")
    args = ap.parse_args(argv)
    defaults = {**DEFAULTS, **(QUICK if args.quick else {})}
    cfg = load_config(args.config, defaults)
    from optim import NORMALS
    from optim._tree import METHODS

    if cfg["method"] not in METHODS:
        raise PlodError(f"accuracy config: method must be one of {', '.join(METHODS)}, got {cfg['method']!r}")
    if cfg["normals"] not in NORMALS:
        raise PlodError(f"accuracy config: normals must be one of {', '.join(NORMALS)}, got {cfg['normals']!r}")
    if args.out:
        cfg["out"] = args.out
    out = check_out_dir(repo_path(cfg["out"]), config=args.config, writes=WRITES)
    command = "python -m experiments.accuracy " + " ".join(argv if argv is not None else sys.argv[1:])
    from experiments._progress import rich_progress

    with rich_progress("accuracy") as cb:
        def progress(i, n, cid, s):
            if cb is not None:
                cb(f"{cid} ({s:.0f} s)", i, n)
            else:  # a log, not a terminal: one line per cell
                print(f"[{i}/{n}] {cid}: {s:.0f} s", file=sys.stderr, flush=True)

        rows = run_sweep(cfg, resume=args.resume, model_lights=not args.no_model_lights, progress=progress)
    images = () if args.no_images else worst_images(rows, cfg, out, not args.no_model_lights)
    summ = write_report(rows, cfg, command, out, images)
    save_run_info(out, cfg, cfg["seed"], command)
    print(json.dumps(summ, indent=1))
    return 0


if __name__ == "__main__":  # pragma: no cover
    from experiments._runinfo import run_script

    run_script(main)

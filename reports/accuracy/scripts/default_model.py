"""Issue 14: should plod's default CSF model be ``stela`` (published stelaCSF constants) instead of
``kellyabstract``? The accuracy sweep's cells (experiments/accuracy.py: same meshes, views, gazes,
lightings and config DEFAULTS) judged again with the imperceptible cut and the perceptual budget cuts
scored by ``pmetric.make_model(MODEL)``; compared with the rows of reports/accuracy/results.jsonl as of git c0cfd96, the sweep made when
``kellyabstract`` was the default (read with ``git show``; the default is ``stela`` since).

    OMP_NUM_THREADS=1 taskset -c 0 .venv/bin/python reports/accuracy/scripts/default_model.py [--resume]
        [--model stela] [--lightings relit,baked] [--report-only]

Writes reports/accuracy/default_model.jsonl (one line per judged cut, appended as it goes; ``--resume``
skips the (cell, method, budget) already there) and reports/accuracy/default_model.md (tables from
both files). Relit cells are run first (all meshes), then baked. Every row also carries
``default_triangles``: the triangles of the same cut with ``kellyabstract`` under today's code (a check
that the cells are the ones of that results.jsonl).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from experiments.accuracy import (DEFAULTS, IMPERCEPTIBLE_TARGET, PEERS, _cell_id, _cells, _Mesh,  # noqa: E402
                                  _view, load_meshes)

OUT = ROOT / "reports" / "accuracy"
BASE = OUT / "results.jsonl"
BASE_REV = "c0cfd96"  # results.jsonl of the sweep with kellyabstract as the default
ROWS = OUT / "default_model.jsonl"
REPORT = OUT / "default_model.md"
BEST_PEERS = ("size", "geometric") + PEERS  # the harness's "perceptual best" comparison set


def _done(path):
    done = set()
    if path.is_file():
        for line in path.read_text().splitlines():
            if line.strip():
                r = json.loads(line)
                done.add((r["cell"], r["method"], r["budget"]))
    return done


def judge_cell(mesh, d, g, lighting, cfg, model, todo, write):
    """Judge the imperceptible cut and the perceptual budget cuts of one cell scored with ``model``
    (the judge call of ``experiments.accuracy.cell_results``); ``todo`` the (method, budget) to run;
    ``write(row)`` is called per judged cut."""
    import optim
    from experiments.judge import judge

    tree = mesh.tree[lighting]
    view = _view(mesh, d, g, lighting, cfg, True)
    light = optim.Lighting() if lighting == "relit" else None
    size = tuple(cfg["size"])
    ref = mesh.original(lighting)
    T = tree.n_triangles
    import pmetric

    dkeys = optim.score(tree, view, pmetric.KellyAbstract())  # the old default: the check against results.jsonl

    def judged(method, budget, result, ms, default_tri, **extra):
        res = judge(ref, result, view, mode=lighting, lighting=light, size=size, heatmap=False)
        write(dict(method=method, budget=budget, triangles=int(len(result[1])), jod=res.jod, flip=res.flip_mean,
                   update_ms=ms, judge_s=round(res.seconds, 2), default_triangles=int(default_tri), **extra))

    if ("imperceptible", None) in todo:
        t0 = time.perf_counter()
        keys = optim.score(tree, view, model)
        cut = optim.threshold_cut(tree, keys, 1.0, monotone="trust")
        result = optim.extract(tree, cut)
        ms = 1e3 * (time.perf_counter() - t0)
        k = np.asarray(keys, np.float64)
        stats = dict(keys_nan=int(np.isnan(k).sum()), keys_nonzero=round(float(np.mean(k > 0)), 4),
                     keys_max=float(np.nanmax(k)), keys_median_nonzero=float(np.median(k[k > 0])) if (k > 0).any() else 0.0)
        dcut = optim.threshold_cut(tree, dkeys, 1.0, monotone="trust")
        judged("imperceptible", None, result, ms, dcut.triangles, distance=float(cut.distance), **stats)
    for b in cfg["budgets"]:
        if ("perceptual", b) not in todo:
            continue
        t0 = time.perf_counter()
        pk = optim.score(tree, view, model)
        pcut = optim.budget_cut(tree, pk, max(int(b * T), 1), monotone="trust")
        presult = optim.extract(tree, pcut)
        ms = 1e3 * (time.perf_counter() - t0)
        dcut = optim.budget_cut(tree, dkeys, max(int(b * T), 1), monotone="trust")
        judged("perceptual", b, presult, ms, dcut.triangles)


def run(cfg, model_name, lightings, resume, progress=print):
    import pmetric

    model = pmetric.make_model(model_name)
    if not resume and ROWS.exists():
        ROWS.unlink()
    done = _done(ROWS) if resume else set()
    meshes = load_meshes(cfg)
    cells = list(_cells(meshes, cfg))
    want = [("imperceptible", None)] + [("perceptual", b) for b in cfg["budgets"]]
    n_cells = sum(1 for c in cells if c[4] in lightings)
    i = 0
    t_start = time.perf_counter()
    for lighting in lightings:  # relit first (all meshes), then baked
        for name, v, f, c in meshes:
            mine = [c_ for c_ in cells if c_[0] == name and c_[4] == lighting]
            mesh = None
            for name_, vi, d, g, lt in mine:
                i += 1
                cid = _cell_id(name_, vi, g, lt)
                todo = {w for w in want if (cid, w[0], w[1]) not in done}
                if not todo:
                    continue
                if mesh is None:
                    mesh = _Mesh(name, v, f, c)
                base = dict(cell=cid, mesh=name, view=vi, direction=[round(x, 6) for x in d], gaze_deg=g,
                            lighting=lt, input_triangles=int(mesh.tree[lt].n_triangles), colored=mesh.c is not None,
                            model=model_name)
                t0 = time.perf_counter()

                def write(r):
                    with open(ROWS, "a") as fh:
                        fh.write(json.dumps({**base, **r}) + "\n")

                try:
                    judge_cell(mesh, d, g, lt, cfg, model, todo, write)
                except Exception as exc:  # a failed cell records its error; the run goes on
                    write(dict(method="error", budget=None, error=f"{type(exc).__name__}: {exc}"))
                progress(f"[{i}/{n_cells}] {cid}: {time.perf_counter() - t0:.0f} s "
                         f"(total {time.perf_counter() - t_start:.0f} s)")
    return time.perf_counter() - t_start


# ----------------------------------------------------------------------------------------------- report
def _load(path):
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.is_file() else []


def _med(xs):
    return statistics.median(xs) if xs else None


def _f(x, nd=3):
    return "n/a" if x is None else f"{x:.{nd}f}"


def _pct(num, den):
    return "n/a" if not den else f"{100 * num / den:.0f} % ({num}/{den})"


def report(cfg, model_name, command, seconds=None):
    import subprocess

    text = subprocess.run(["git", "-C", str(ROOT), "show", f"{BASE_REV}:reports/accuracy/results.jsonl"],
                          capture_output=True, text=True, check=True).stdout
    base = [json.loads(x) for x in text.splitlines() if x.strip()]
    base = [r for r in base if r.get("jod") is not None]
    new = [r for r in _load(ROWS) if r.get("jod") is not None and r.get("model", model_name) == model_name]
    errors = [r for r in _load(ROWS) if r["method"] == "error"]
    B = {(r["cell"], r["method"], r["budget"]): r for r in base}
    N = {(r["cell"], r["method"], r["budget"]): r for r in new}
    L = [f"# Default CSF model: `kellyabstract` (the default before issue 14) vs `{model_name}` (published stelaCSF constants, the default since)\n",
         f"Command: `{command}`\n",
         "Cells: those of the accuracy sweep (`experiments/accuracy.py` DEFAULTS: 4 scanned meshes + 2 procedural, "
         f"1 view each (seed {cfg['seed']}), gaze offsets {', '.join(f'{g:g}' for g in cfg['gaze_offsets_deg'])} deg, "
         f"gaze error {cfg['gaze_error_deg']:g} deg, relit and baked, {cfg['size'][0]}x{cfg['size'][1]} px), rebuilt with "
         "the harness's own `load_meshes`, `_Mesh`, `_cells`, `_view` and judged with the same `judge` call. "
         f"`kellyabstract` rows: reports/accuracy/results.jsonl at git {BASE_REV}; `{model_name}` rows: reports/accuracy/default_model.jsonl "
         f"(`optim.score(tree, view, pmetric.make_model('{model_name}'))`). Only cells present in both files are compared.\n"]
    # the check that the cells are the same: default-model triangles now vs results.jsonl
    chk = [(r, B.get((r["cell"], r["method"], r["budget"]))) for r in new]
    chk = [(r, b) for r, b in chk if b is not None]
    same = sum(r["default_triangles"] == b["triangles"] for r, b in chk)
    L.append(f"Same-cells check: the default model's cut recomputed today has the triangle count of results.jsonl "
             f"in {same} of {len(chk)} cuts.\n")
    if seconds is not None:
        L.append(f"Run time: {seconds / 60:.1f} min (one core).\n")
    if errors:
        L.append(f"**{len(errors)} failed cells**: " + "; ".join(f"{r['cell']}: {r['error']}" for r in errors[:5]) + "\n")
    bad = [r for r in new if r["method"] == "imperceptible" and (r.get("keys_nan") or not r.get("keys_nonzero"))]
    imp_new = [r for r in new if r["method"] == "imperceptible"]
    if imp_new:
        L.append(f"`{model_name}` keys: NaN in {sum(bool(r.get('keys_nan')) for r in imp_new)} cells, all-zero in "
                 f"{sum(not r.get('keys_nonzero') for r in imp_new)}; nonzero share median "
                 f"{_med([r['keys_nonzero'] for r in imp_new]):.3f}; cut distance median "
                 f"{_med([r['distance'] for r in imp_new]):.4f} (<= 1 by construction).\n")
    if bad:
        L.append("**Cells with NaN or all-zero keys**: " + ", ".join(r["cell"] for r in bad) + "\n")
    summary = {}
    for lighting in cfg["lightings"]:
        cells = sorted({k[0] for k in N if N[k]["lighting"] == lighting and (k[0], "imperceptible", None) in B})
        if not cells:
            continue
        L.append(f"## {lighting}\n")
        # imperceptible cuts
        pairs = [(B[(c, "imperceptible", None)], N[(c, "imperceptible", None)]) for c in cells
                 if (c, "imperceptible", None) in N]
        L.append(f"### Imperceptible cut (`threshold_cut(..., 1.0)`), {len(pairs)} cells\n")
        L.append("| model | median JOD | min JOD | share >= 9.8 | median kept (% of input) |")
        L.append("| --- | ---: | ---: | ---: | ---: |")
        s = {}
        for label, idx in (("kellyabstract", 0), (model_name, 1)):
            rs = [p[idx] for p in pairs]
            j = [r["jod"] for r in rs]
            kept = _med([100 * r["triangles"] / r["input_triangles"] for r in rs])
            s[label] = dict(median=_med(j), min=min(j), share=sum(x >= IMPERCEPTIBLE_TARGET for x in j), n=len(j), kept=kept)
            L.append(f"| {label} | {_f(_med(j))} | {_f(min(j))} | {_pct(s[label]['share'], len(j))} | {_f(kept, 1)} % |")
        ratio = [n["triangles"] / max(k["triangles"], 1) for k, n in pairs]
        dj = [n["jod"] - k["jod"] for k, n in pairs]
        L.append(f"\nPer cell, {model_name} / kellyabstract triangles: median {_f(_med(ratio), 2)}, range "
                 f"{_f(min(ratio), 2)} .. {_f(max(ratio), 2)}; {model_name} keeps fewer in {sum(x < 1 for x in ratio)} "
                 f"of {len(ratio)} cells. JOD {model_name} - kellyabstract: median {_f(_med(dj))}, range "
                 f"{_f(min(dj))} .. {_f(max(dj))}.\n")
        below = [n["cell"] + f" ({n['jod']:.3f})" for k, n in pairs if n["jod"] < IMPERCEPTIBLE_TARGET]
        if below:
            L.append(f"{model_name} imperceptible cuts below 9.8 JOD: " + ", ".join(below) + "\n")
        summary[(lighting, "imperceptible")] = s
        # budget cuts
        L.append("### Perceptual budget cuts\n")
        L.append("| budget | cells | median tri kelly / " + model_name + " | median JOD kelly | median JOD " + model_name
                 + f" | {model_name} beats kelly | median diff | median best peer | perceptual best: kelly | perceptual best: "
                 + model_name + " |")
        L.append("| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
        for b in cfg["budgets"]:
            rows = []
            for c in cells:
                k, n = B.get((c, "perceptual", b)), N.get((c, "perceptual", b))
                peers = [B[(c, m, b)]["jod"] for m in BEST_PEERS if (c, m, b) in B]
                if k is None or n is None or not peers:
                    continue
                rows.append((k, n, max(peers)))
            if not rows:
                continue
            kj, nj, pj = [r[0]["jod"] for r in rows], [r[1]["jod"] for r in rows], [r[2] for r in rows]
            wins = sum(n > k for k, n in zip(kj, nj))
            ties = sum(n == k for k, n in zip(kj, nj))
            bk = sum(k > p for k, p in zip(kj, pj))
            bn = sum(n > p for n, p in zip(nj, pj))
            tk = _med([r[0]["triangles"] for r in rows])
            tn = _med([r[1]["triangles"] for r in rows])
            L.append(f"| {100 * b:g} % | {len(rows)} | {tk:,.0f} / {tn:,.0f} | {_f(_med(kj))} | {_f(_med(nj))} | "
                     f"{_pct(wins, len(rows))}{f', {ties} ties' if ties else ''} | {_f(_med([n - k for k, n in zip(kj, nj)]))} | "
                     f"{_f(_med(pj))} | {_pct(bk, len(rows))} | {_pct(bn, len(rows))} |")
            summary[(lighting, b)] = dict(kelly=_med(kj), new=_med(nj), wins=wins, n=len(rows), best_k=bk, best_n=bn,
                                          peer=_med(pj))
        ref = [(B[(c, "model:fitted_stelacsf", cfg["model_budget"])]["jod"]) for c in cells
               if (c, "model:fitted_stelacsf", cfg["model_budget"]) in B]
        if ref:
            L.append(f"\nFor reference, results.jsonl's `model:fitted_stelacsf` (the refitted stelaCSF, at kelly's "
                     f"perceptual triangle count) at {100 * cfg['model_budget']:g} %: median JOD {_f(_med(ref))}.\n")
        L.append("")
    L.append("*best peer*: the highest JOD of size keys, geometric keys, meshoptimizer and fast-simplification at the "
             "cell and budget (results.jsonl; those were cut at kelly's perceptual triangle count, which the "
             f"{model_name} cut matches within the budget: both are `budget_cut` at max(int(b*T), 1)). *perceptual "
             "best*: share of cells where that model's perceptual cut has a higher JOD than every peer. "
             f"*{model_name} beats kelly*: share of cells where {model_name}'s perceptual JOD is strictly higher.\n")
    L += _verdict(summary, model_name, cfg)
    # per-cell table
    L.append("## Per cell (JOD; triangles)\n")
    L.append("| cell | imperceptible kelly | imperceptible " + model_name + " | "
             + " | ".join(f"{100 * b:g} % kelly | {100 * b:g} % {model_name}" for b in cfg["budgets"]) + " |")
    L.append("| --- | ---: | ---: |" + " ---: | ---: |" * len(cfg["budgets"]))
    for c in sorted({k[0] for k in N}):
        parts = []
        for m, b in [("imperceptible", None)] + [("perceptual", b) for b in cfg["budgets"]]:
            for src in (B, N):
                r = src.get((c, m, b))
                parts.append("n/a" if r is None else f"{r['jod']:.3f}; {r['triangles']:,}")
        L.append(f"| {c} | " + " | ".join(parts) + " |")
    REPORT.write_text("\n".join(L) + "\n")
    return summary


def _verdict(summary, model_name, cfg):
    L = ["## Verdict\n"]
    for lighting in cfg["lightings"]:
        s = summary.get((lighting, "imperceptible"))
        if not s:
            continue
        k, n = s["kellyabstract"], s[model_name]
        parts = [f"**{lighting}**: imperceptible cuts keep a median {_f(n['kept'], 1)} % of the input with {model_name} "
                 f"vs {_f(k['kept'], 1)} % with kellyabstract, at median JOD {_f(n['median'])} vs {_f(k['median'])} "
                 f"(min {_f(n['min'])} vs {_f(k['min'])}; >= 9.8 in {n['share']}/{n['n']} vs {k['share']}/{k['n']} cells)."]
        for b in cfg["budgets"]:
            t = summary.get((lighting, b))
            if t:
                parts.append(f"{100 * b:g} %: median JOD {_f(t['new'])} vs {_f(t['kelly'])} ({model_name} higher in "
                             f"{t['wins']}/{t['n']} cells; perceptual best {t['best_n']}/{t['n']} vs {t['best_k']}/{t['n']}).")
        ts = [summary[(lighting, b)] for b in cfg["budgets"] if (lighting, b) in summary]
        if ts:
            n_all = sum(t["n"] for t in ts)
            parts.append(f"Over all budgets: {model_name} higher in {sum(t['wins'] for t in ts)}/{n_all} (cell, budget) "
                         f"pairs; perceptual best {_pct(sum(t['best_n'] for t in ts), n_all)} vs "
                         f"{_pct(sum(t['best_k'] for t in ts), n_all)} (the latter is report.md's 'perceptual best').")
        L.append(" ".join(parts) + "\n")
    gains = [summary[k]["new"] - summary[k]["kelly"] for k in summary if k[1] != "imperceptible"]
    imp = [summary[k] for k in summary if k[1] == "imperceptible"]
    if gains and imp:
        better = "better" if min(gains) > 0 else ("worse" if max(gains) < 0 else "mixed")
        L.append(f"**In short**: on these {sum(s[model_name]['n'] for s in imp)} cells {model_name}'s perceptual budget cuts are "
                 f"{better} than kellyabstract's at every budget and lighting (median JOD {min(gains):+.3f} .. "
                 f"{max(gains):+.3f}, same triangle counts); its imperceptible cuts reach >= 9.8 JOD in as many cells "
                 f"({sum(s[model_name]['share'] for s in imp)} vs {sum(s['kellyabstract']['share'] for s in imp)}) and keep "
                 + " / ".join(f"{s[model_name]['kept'] - s['kellyabstract']['kept']:+.1f}" for s in imp)
                 + " percentage points of the input (median, " + " / ".join(l for l in cfg["lightings"]) + "): "
                 "more on the scanned meshes, fewer on the procedural ones (per-cell ratios above).\n")
    return L


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", default="stela")
    ap.add_argument("--lightings", default="relit,baked", help="order of the passes")
    ap.add_argument("--resume", action="store_true")
    ap.add_argument("--report-only", action="store_true")
    ap.add_argument("--run-seconds", type=float, default=None, help="with --report-only: the run's time, for the report")
    args = ap.parse_args(argv)
    cfg = dict(DEFAULTS)
    command = ("OMP_NUM_THREADS=1 taskset -c 0 .venv/bin/python reports/accuracy/scripts/default_model.py "
               + " ".join(argv if argv is not None else sys.argv[1:])).strip()
    seconds = args.run_seconds
    if not args.report_only:
        seconds = run(cfg, args.model, [x for x in args.lightings.split(",") if x], args.resume,
                      progress=lambda s: print(s, file=sys.stderr, flush=True))
    report(cfg, args.model, command, seconds)
    print(REPORT.read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())

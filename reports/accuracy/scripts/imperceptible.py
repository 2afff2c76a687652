"""Judge only the imperceptible cuts of the accuracy sweep (or of other meshes), with this tree's code.

    .venv/bin/python reports/accuracy/scripts/imperceptible.py OUT.jsonl [--meshes a.ply,b.obj] [--no-procedural]
        [--lightings relit,baked] [--gazes 0,8,16] [--md OUT.md]

Cells are built exactly as ``experiments.accuracy`` builds them (``_Mesh``, ``_view``, its views: seed
2026, one random direction per mesh, gaze offsets 0 / 8 / 16 deg, 960x540) and judged with
``experiments.judge.judge``; each row is compared with the row of the same cell and method
``"imperceptible"`` in ``reports/accuracy/results.jsonl`` (today's cut), when there is one. Rows are
appended as they are judged; cells already in OUT.jsonl are skipped (resume). The Markdown table
(``--md``, default OUT with ``.md``) is written from all rows of OUT.jsonl.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

TARGET = 9.8


def _before():
    out = {}
    path = ROOT / "reports" / "accuracy" / "results.jsonl"
    for line in path.read_text().splitlines():
        if line.strip():
            r = json.loads(line)
            if r.get("method") == "imperceptible":
                out[r["cell"]] = r
    return out


def run(out_path: Path, meshes, procedural, lightings, gazes):
    import optim
    from experiments.accuracy import DEFAULTS, _cell_id, _Mesh, _view, load_meshes
    from experiments.experiment import view_directions
    from experiments.judge import judge

    cfg = dict(DEFAULTS, meshes=meshes, procedural=procedural, gaze_offsets_deg=gazes)
    done = set()
    if out_path.is_file():
        done = {json.loads(x)["cell"] for x in out_path.read_text().splitlines() if x.strip()}
    before = _before()
    for name, v, f, c in load_meshes(cfg):
        cells = [(vi, d, float(g), lt) for vi, d in enumerate(view_directions(cfg["views"], cfg["seed"], name))
                 for g in gazes for lt in lightings]
        if all(_cell_id(name, vi, g, lt) in done for vi, _, g, lt in cells):
            continue
        mesh = _Mesh(name, v, f, c)
        print(f"{name}: trees built in {mesh.build_s:.1f} s", flush=True)
        for vi, d, g, lt in cells:
            cid = _cell_id(name, vi, g, lt)
            if cid in done:
                continue
            tree = mesh.tree[lt]
            view = _view(mesh, d, g, lt, cfg, True)
            t0 = time.perf_counter()
            cut = optim.threshold_cut(tree, optim.score(tree, view), 1.0, monotone="trust")
            result = optim.extract(tree, cut)
            ms = 1e3 * (time.perf_counter() - t0)
            res = judge(mesh.original(lt), result, view, mode=lt, lighting=optim.Lighting() if lt == "relit" else None,
                        size=tuple(cfg["size"]), heatmap=False)
            b = before.get(cid, {})
            row = dict(cell=cid, mesh=name, direction=[round(float(x), 6) for x in d], gaze_deg=g, lighting=lt,
                       input_triangles=int(tree.n_triangles), triangles=int(cut.triangles), jod=res.jod,
                       flip=res.flip_mean, distance=float(cut.distance), update_ms=round(ms, 1),
                       triangles_before=b.get("triangles"), jod_before=b.get("jod"))
            with open(out_path, "a") as fh:
                fh.write(json.dumps(row) + "\n")
            print(f"{cid}: {cut.triangles} tris, {res.jod:.3f} JOD (today {b.get('triangles')}, "
                  f"{b.get('jod') or float('nan'):.3f})", flush=True)


def table(rows) -> str:
    lines = ["| cell | input | triangles today | JOD today | triangles now | now / today | JOD now |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in sorted(rows, key=lambda r: r["cell"]):
        tb, jb = r.get("triangles_before"), r.get("jod_before")
        ratio = f"{r['triangles'] / tb:.3f}" if tb else ""
        lines.append(f"| {r['cell']} | {r['input_triangles']:,} | {f'{tb:,}' if tb else ''} | "
                     f"{f'{jb:.3f}' if jb is not None else ''} | {r['triangles']:,} | {ratio} | {r['jod']:.3f} |")
    lines.append("")
    lines.append("| lighting | cells | min JOD today | min JOD now | >= 9.8 today | >= 9.8 now | triangles now / today "
                 "(sum) | median ratio |")
    lines.append("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for lt in sorted({r["lighting"] for r in rows}):
        rs = [r for r in rows if r["lighting"] == lt]
        both = [r for r in rs if r.get("triangles_before")]
        jb = [r["jod_before"] for r in both]
        ratio = (sum(r["triangles"] for r in both) / sum(r["triangles_before"] for r in both)) if both else float("nan")
        med = float(np.median([r["triangles"] / r["triangles_before"] for r in both])) if both else float("nan")
        lines.append(f"| {lt} | {len(rs)} | {min(jb) if jb else float('nan'):.3f} | {min(r['jod'] for r in rs):.3f} | "
                     f"{sum(j >= TARGET for j in jb)} | {sum(r['jod'] >= TARGET for r in rs)} | {ratio:.3f} | {med:.3f} |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--meshes", default=None, help="comma-separated mesh files (default: the sweep's)")
    ap.add_argument("--no-procedural", action="store_true")
    ap.add_argument("--lightings", default="relit,baked")
    ap.add_argument("--gazes", default="0,8,16")
    ap.add_argument("--md", default=None)
    ap.add_argument("--table-only", action="store_true")
    a = ap.parse_args(argv)
    from experiments.accuracy import DEFAULTS

    out = Path(a.out)
    meshes = DEFAULTS["meshes"] if a.meshes is None else a.meshes.split(",")
    procedural = [] if a.no_procedural else DEFAULTS["procedural"]
    if not a.table_only:
        run(out, meshes, procedural, a.lightings.split(","), [float(x) for x in a.gazes.split(",")])
    rows = [json.loads(x) for x in out.read_text().splitlines() if x.strip()]
    md = Path(a.md) if a.md else out.with_suffix(".md")
    md.write_text(table(rows))
    print(table(rows))


if __name__ == "__main__":
    main()

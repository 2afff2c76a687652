"""Benchmark: per-view update (score + budget cut + extract) against meshoptimizer's simplify.

    .venv/bin/python -m experiments.bench_optim                  # 796k-triangle mesh + 1.0M and 1.3M procedural
    .venv/bin/python -m experiments.bench_optim --quick          # small procedural mesh, seconds
    .venv/bin/python -m experiments.bench_optim --with-tree      # also engineer C's bench_tree sections

For each mesh (the shared 796k-triangle turbine blade when ``../shared`` exists, skipped cleanly
otherwise, a procedural bumpy torus of 1,000,000 and a bumpy sphere of 1,310,720 triangles): build the vertex tree once, then
for 8 views around the object (framed at 30 deg of a 46 deg screen, gaze at the centre, the study of
[LH01 §6.2]) time ``optim.score`` (perceptual keys, the default model), ``optim.budget_cut`` to 10 % of the
input triangles and ``optim.extract``. meshoptimizer's ``simplify`` then produces the same triangle
count from the full mesh, and the ratio of the two is measured in the same run.

Targets: per-view update <= 50 ms, and >= 10x faster than meshoptimizer at the same triangle count.
Times: wall clock and process CPU time (the latter is robust on a shared machine); medians over views.
Writes the Markdown report itself (atomically).
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from experiments.peers import meshopt_simplify

ROOT = Path(__file__).resolve().parents[1]
BIG = ROOT.parent / "shared" / "data" / "meshes" / "turbineblade-subdiv-796k.ply"
TARGET_MS = 50.0
TARGET_RATIO = 10.0


def _timed(fn):
    """(result, wall s, process CPU s) of one call."""
    c0, t0 = time.process_time(), time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0, time.process_time() - c0


#: the moving views: an orbit at ORBIT_DEG_S (deg/s) around the object seen at 60 Hz, each view carrying
#: the one a frame earlier (the retinal velocity of every node)
ORBIT_DEG_S, FRAME_S = 60.0, 1 / 60


def _views(vertices, n: int, lighting=None, moving: bool = False):
    import optim

    def at(az, **kw):
        d = (np.sin(az), 0.25, np.cos(az))
        return optim.View.framing(vertices, 30.0, direction=d, lighting=lighting, **kw)

    out = []
    for i in range(n):
        az = 2 * np.pi * i / n
        if moving:
            prev = at(az - np.radians(ORBIT_DEG_S * FRAME_S))
            out.append(at(az, previous=prev, dt_s=FRAME_S))
        else:
            out.append(at(az))
    return out


def _time_views(tree, views, budget, metric, repeat, progress, label):
    """Best of ``repeat`` (score, cut, extract) per view, wall and CPU seconds, triangles, distance."""
    import optim

    rows = []
    task = progress.add_task(label, total=len(views))
    for view in views:
        best = None
        for _ in range(repeat):  # best of `repeat` per view (the machine is shared), median over views
            keys, ts, cs = _timed(lambda: optim.score(tree, view, metric=metric))
            cut, tc, cc = _timed(lambda: optim.budget_cut(tree, keys, budget, monotone="trust"))
            mesh, te, ce = _timed(lambda: optim.extract(tree, cut))
            row = (ts, tc, te, cs, cc, ce, mesh[1].shape[0], cut.distance)
            best = row if best is None or sum(row[:3]) < sum(best[:3]) else best
        rows.append(best)
        progress.advance(task)
    return rows


def bench_mesh(name, vertices, faces, *, method, n_views, budget_fraction, metric, progress, con, repeat=3,
               lighting=None):
    import optim

    rec = {"mesh": name, "triangles": int(faces.shape[0]), "metric": metric}
    tree, rec["build_s"], _ = _timed(lambda: optim.build_tree(vertices, faces, method=method))
    rec["nodes"] = tree.n_nodes
    budget = int(budget_fraction * tree.n_triangles)
    rec["budget"] = budget
    views = _views(tree.vertices, n_views, lighting)
    moving = _views(tree.vertices, n_views, lighting, moving=True)
    # first view: per-tree context (cull columns, normal cones, relit columns), model table and XLA
    # compilation (reported, not in the medians); the same for the first moving view
    _, rec["first_view_s"], _ = _timed(lambda: optim.score(tree, views[0], metric=metric))
    _, rec["first_moving_s"], _ = _timed(lambda: optim.score(tree, moving[0], metric=metric))
    rows = _time_views(tree, views, budget, metric, repeat, progress, f"{name}: views")
    mrows = _time_views(tree, moving, budget, metric, repeat, progress, f"{name}: moving views")
    rec["moving_score_ms"] = statistics.median(r[0] for r in mrows) * 1e3
    rec["moving_update_ms"] = statistics.median((r[0] + r[1] + r[2]) for r in mrows) * 1e3
    rec["moving_out_triangles"] = int(statistics.median(r[6] for r in mrows))
    med = lambda k: statistics.median(r[k] for r in rows) * 1e3  # noqa: E731
    rec.update(score_ms=med(0), cut_ms=med(1), extract_ms=med(2), score_cpu_ms=med(3), cut_cpu_ms=med(4),
               extract_cpu_ms=med(5))
    rec["update_ms"] = statistics.median((r[0] + r[1] + r[2]) for r in rows) * 1e3
    rec["update_cpu_ms"] = statistics.median((r[3] + r[4] + r[5]) for r in rows) * 1e3
    rec["update_min_ms"] = min((r[0] + r[1] + r[2]) for r in rows) * 1e3
    rec["out_triangles"] = int(statistics.median(r[6] for r in rows))
    rec["distance"] = float(statistics.median(r[7] for r in rows))
    # meshoptimizer to the same triangle count (best of 2 runs)
    runs = [_timed(lambda: len(meshopt_simplify(tree.vertices, tree.faces, rec["out_triangles"]))) for _ in range(2)]
    best = min(runs, key=lambda r: r[1])
    rec["meshopt_triangles"], rec["meshopt_ms"], rec["meshopt_cpu_ms"] = best[0], best[1] * 1e3, best[2] * 1e3
    rec["ratio"] = rec["meshopt_ms"] / rec["update_ms"]
    rec["ratio_cpu"] = rec["meshopt_cpu_ms"] / max(rec["update_cpu_ms"], 1e-9)
    con.print(f"  {name}: update {rec['update_ms']:.1f} ms (score {rec['score_ms']:.1f}, cut {rec['cut_ms']:.1f}, "
              f"extract {rec['extract_ms']:.1f}), moving {rec['moving_update_ms']:.1f} ms; CPU {rec['update_cpu_ms']:.1f} ms; meshoptimizer "
              f"{rec['meshopt_ms']:.0f} ms -> x{rec['ratio']:.1f} (CPU x{rec['ratio_cpu']:.1f})")
    return rec


def report(recs, args) -> str:
    cmd = ("`.venv/bin/python -m experiments.bench_optim" + (" --quick" if args.quick else "")
           + (f" --lighting {args.lighting}" if args.lighting != "relit" else "") + "`")
    lines = [
        "# bench_optim: per-view update (score + budget cut + extract) vs meshoptimizer",
        "",
        f"Command: {cmd}  ",
        f"Machine: {platform.machine()} {platform.processor() or ''}, Python {platform.python_version()}, "
        f"numpy {np.__version__}, {os.cpu_count()} cores, load average {args.load} at the start (shared "
        f"machine). {args.views} views around each object (framed at 30 deg of a 46 deg screen, "
        "gaze at the screen centre, 1 deg gaze error), perceptual keys with the default model "
        f"(`optim._score.default_model`), budget {args.budget_fraction:.0%} of the input triangles, "
        f"tree method `{args.method}`, lighting `{args.lighting}` (relit: the views carry `optim.Lighting()`, "
        f"fold contrast from the normal cones and the neighbours' normals). Best of {args.repeat} runs per view, medians over the views; the "
        "first view (tree context: cull columns, normal cones, neighbours' normals, relit columns; model table; XLA compilation) "
        f"is listed separately. Moving views: the same {args.views} views, each carrying the view a 60 Hz "
        f"frame earlier on a {ORBIT_DEG_S:.0f} deg/s orbit (`previous`, `dt_s`; the retinal velocity of every "
        "node; keys from the model's motion table), timed the same way (their first view, with its "
        "compilation, apart). meshoptimizer: "
        "`meshoptimizer.simplify` of the full mesh to the same triangle count, best of 2. Wall time and "
        "process CPU time (CPU time is the robust figure on a shared machine).",
        "",
        "| mesh | triangles | nodes | build s | first view s | score ms | cut ms | extract ms | update ms "
        "(min) | update CPU ms | out triangles | distance k | meshopt ms | ratio (CPU ratio) | moving: first s | "
        "score ms | update ms | out triangles |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: "
        "| ---: | ---: | ---: | ---: |",
    ]
    for r in recs:
        lines.append(
            f"| {r['mesh']} | {r['triangles']:,} | {r['nodes']:,} | {r['build_s']:.1f} | {r['first_view_s']:.1f} | "
            f"{r['score_ms']:.1f} | {r['cut_ms']:.1f} | {r['extract_ms']:.1f} | {r['update_ms']:.1f} "
            f"({r['update_min_ms']:.1f}) | {r['update_cpu_ms']:.1f} | {r['out_triangles']:,} | {r['distance']:.3g} | "
            f"{r['meshopt_ms']:.0f} | {r['ratio']:.1f}x ({r['ratio_cpu']:.1f}x) | {r['first_moving_s']:.1f} | "
            f"{r['moving_score_ms']:.1f} | {r['moving_update_ms']:.1f} | {r['moving_out_triangles']:,} |")
    lines += ["", f"Targets: update <= {TARGET_MS:.0f} ms and >= {TARGET_RATIO:.0f}x faster than meshoptimizer."]
    for r in recs:
        ok_t = r["update_ms"] <= TARGET_MS
        ok_r = r["ratio"] >= TARGET_RATIO
        lines.append(f"- {r['mesh']}: update {r['update_ms']:.1f} ms {'meets' if ok_t else 'MISSES'} the "
                     f"{TARGET_MS:.0f} ms target; ratio {r['ratio']:.1f}x {'meets' if ok_r else 'MISSES'} "
                     f"the {TARGET_RATIO:.0f}x target (meshoptimizer rate "
                     f"{r['triangles'] / r['meshopt_ms'] / 1e3:.2f} M input triangles/s); moving views "
                     f"{r['moving_update_ms']:.1f} ms ({'meets' if r['moving_update_ms'] <= TARGET_MS else 'MISSES'}).")
    if args.skipped:
        lines += ["", f"Skipped: {args.skipped}"]
    lines.append("")
    return "\n".join(lines)


def main(argv=None) -> int:
    from rich.console import Console
    from rich.progress import Progress

    import optim
    from pmetric import atomic_write_text

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="one small procedural mesh (bumpy sphere, 82k triangles)")
    ap.add_argument("--views", type=int, default=8, help="views per mesh (default 8)")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs per view; the best counts (default 3)")
    ap.add_argument("--budget-fraction", type=float, default=0.1, help="budget as a fraction of the input")
    ap.add_argument("--method", choices=("meshopt", "hybrid", "qem", "octree"), default="meshopt",
                    help="tree builder (default meshopt)")
    ap.add_argument("--metric", choices=("perceptual", "size", "geometric"), default="perceptual")
    ap.add_argument("--lighting", choices=("relit", "baked"), default="relit",
                    help="relit (default): the views carry optim.Lighting(), fold contrast from the normal "
                         "cones; baked: the tree's pre-lit intensities")
    ap.add_argument("--with-tree", action="store_true", help="also run experiments.bench_tree (its own report)")
    ap.add_argument("--out", default=str(ROOT / "reports" / "bench_optim.md"))
    args = ap.parse_args(argv)
    if args.views < 1 or args.repeat < 1 or not (0 < args.budget_fraction <= 1):
        raise SystemExit("bench_optim: --views and --repeat must be >= 1 and --budget-fraction in (0, 1]")
    con = Console()
    args.load = " / ".join(f"{x:.1f}" for x in os.getloadavg())
    meshes = []
    args.skipped = ""
    if args.quick:
        meshes.append(("bumpy_sphere(6)", lambda: optim.bumpy_sphere(6, seed=0)[:2]))
    else:
        if BIG.exists():
            meshes.append((BIG.name, lambda: optim.load_mesh(BIG)[:2]))
        else:
            args.skipped = f"{BIG} (../shared is absent)"
            con.print(f"[yellow]skipping {BIG}: ../shared is absent[/yellow]")
        meshes.append(("bumpy_torus(1000, 500)", lambda: optim.bumpy_torus(1000, 500, seed=0)))
        meshes.append(("bumpy_sphere(8)", lambda: optim.bumpy_sphere(8, seed=0)[:2]))
    recs = []
    with Progress(console=con, transient=True) as progress:
        for name, load in meshes:
            v, f = load()
            con.print(f"mesh {name}: {f.shape[0]:,} triangles")
            recs.append(bench_mesh(name, v, f, method=args.method, n_views=args.views,
                                   budget_fraction=args.budget_fraction, metric=args.metric,
                                   progress=progress, con=con, repeat=args.repeat,
                                   lighting=optim.Lighting() if args.lighting == "relit" else None))
    out = atomic_write_text(args.out, report(recs, args))
    con.print(f"wrote {out}")
    if args.with_tree:
        try:
            from experiments import bench_tree
        except ImportError:
            con.print("[yellow]experiments.bench_tree is not present; skipped[/yellow]")
        else:
            bench_tree.main(["--quick"] if args.quick else [])
    return 0


if __name__ == "__main__":
    from experiments._runinfo import run_script

    run_script(main)

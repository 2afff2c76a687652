"""Benchmark: vertex-tree build, budget cut and extraction (engineer C's speed targets).

    .venv/bin/python -m experiments.bench_tree                 # 796k-triangle mesh from ../shared
    .venv/bin/python -m experiments.bench_tree --quick         # small procedural mesh, seconds
    .venv/bin/python -m experiments.bench_tree --mesh M.ply --out reports/bench_tree.md

Measures, in one run (so ratios are comparable on a noisy machine):

* build throughput (input triangles/s) of ``build_tree(method="octree" | "qem")`` beside
  fast-simplification decimating the same mesh (to 10 % and to its full collapse sequence);
  tree memory in bytes per input triangle (target <= 200; octree target >= 0.3 M triangles/s);
* ``budget_cut`` vs ``budget_cut_heap`` on a tree of >= 10^6 nodes: identical cuts, speed ratio
  (target >= 30x);
* per-view ``budget_cut`` + ``extract`` (ms) on the big mesh (target about 25 ms of the 50 ms update).

Writes the Markdown report itself (atomically).
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BIG = ROOT.parent / "shared" / "data" / "meshes" / "turbineblade-subdiv-796k.ply"


def _best(fn, repeat):
    """Best of ``repeat`` runs: process CPU seconds (robust on a shared machine; the numpy and
    fast-simplification work here is single-threaded) and the result. Wall seconds go to WALL."""
    cpu, wall, out = [], [], None
    for _ in range(repeat):
        c0, t0 = time.process_time(), time.perf_counter()
        out = fn()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - t0)
    WALL.append(min(wall))
    return min(cpu), out


WALL: list[float] = []


def _view_keys(tree, rng):
    """Plausible per-view keys: angular size of each node's sphere from a random viewpoint, made monotone."""
    import optim

    eye = tree.center[0] + rng.normal(size=3) * 3 * tree.radius[0]
    dist = np.linalg.norm(tree.center - eye, axis=1)
    k = tree.radius / np.maximum(dist, 1e-9) * (1 + tree.fold_delta)
    return optim.repair_monotone(tree, k).astype(np.float32)


def _cache_bytes(tree) -> int:
    """Bytes of the per-view caches budget_cut / extract keep on the tree (the arrays among the tree's
    derived data, ``tree.derived``, that are not its fields)."""
    import dataclasses

    fields = {f.name for f in dataclasses.fields(tree)}
    total = 0
    for val in tree._derived.values():
        for a in (val if isinstance(val, tuple) else (val,)):
            if isinstance(a, np.ndarray) and not any(a is getattr(tree, f) for f in fields):
                total += a.nbytes
    return total


def _parse(argv):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--mesh", default=None, help="mesh file (default: the 796k-triangle turbine blade)")
    ap.add_argument("--quick", action="store_true", help="small procedural mesh (bumpy sphere, 20k triangles)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT / "reports" / "bench_tree.md"))
    return ap.parse_args(argv)


def _input_mesh(args):
    """(vertices, faces, name) of the benchmark mesh."""
    import optim

    if args.quick:
        v, f = optim.bumpy_sphere(5, seed=0)
        return v, f, "bumpy_sphere(5)"
    if args.mesh or BIG.exists():
        path = Path(args.mesh) if args.mesh else BIG
        v, f, _ = optim.load_mesh(path)
        return v, f, path.name
    v, f = optim.bumpy_sphere(7, seed=0)
    return v, f, "bumpy_sphere(7)"


def _bench_builds(v, f, args, con):
    """Build both trees and time fast-simplification on the same mesh: (rows, trees, full-sequence s)."""
    import fast_simplification

    import optim

    T = f.shape[0]
    reps = 1 if T > 200_000 else args.repeat
    rows, trees = [], {}
    for method in ("octree", "qem"):
        dt, tree = _best(lambda: optim.build_tree(v, f, method=method), reps)
        trees[method] = tree
        rows.append((f"build_tree({method})", dt, T / dt, tree.nbytes / T, tree.n_nodes, WALL[-1]))
        con.print(f"  build {method}: {dt:.2f} s CPU ({WALL[-1]:.2f} s wall), {T / dt / 1e6:.3f} M tri/s, {tree.nbytes / T:.0f} B/tri, "
                  f"{tree.n_nodes:,} nodes, depth {int(tree.depth.max())}")
    f32 = np.ascontiguousarray(f, dtype=np.int32)
    dt, _ = _best(lambda: fast_simplification.simplify(v, f32, target_reduction=0.9), reps)
    rows.append(("fast_simplification 10 %", dt, T / dt, float("nan"), 0, WALL[-1]))
    dt0, _ = _best(lambda: fast_simplification.simplify(v, f32, target_count=0, return_collapses=True), reps)
    rows.append(("fast_simplification to 0 (collapse sequence)", dt0, T / dt0, float("nan"), 0, WALL[-1]))
    con.print(f"  fast_simplification (CPU): 10 % {dt:.2f} s, full sequence {dt0:.2f} s")
    return rows, trees, dt0


def _bench_cuts(trees, args, rng, con):
    """budget_cut vs budget_cut_heap on a tree of >= 10^6 nodes: (tree, rows)."""
    import optim

    big = trees["qem"]
    if big.n_nodes < 1_000_000 and not args.quick:
        vb, fb = optim.bumpy_sphere(8, seed=1)
        big = optim.build_tree(vb, fb, method="octree")
        if big.n_nodes < 1_000_000:
            big = optim.build_tree(vb, fb, method="qem")
    rand = optim.repair_monotone(big, rng.random(big.n_nodes))
    keys_sets = {"random monotone, float32": rand.astype(np.float32),
                 "random monotone, float64": rand,
                 "view-like, float32": _view_keys(big, rng)}
    cut_rows = []
    for kname, keys in keys_sets.items():
        for frac in (0.1, 0.5):
            budget = int(frac * big.n_triangles)
            tf, cf = _best(lambda: optim.budget_cut(big, keys, budget), args.repeat)
            th, ch = _best(lambda: optim.budget_cut_heap(big, keys, budget), 1)
            same = bool(np.array_equal(cf.unfolded, ch.unfolded) and cf.triangles == ch.triangles)
            cut_rows.append((kname, budget, tf, th, th / tf, same))
            con.print(f"  cut {kname} budget {budget:,}: fast {tf * 1e3:.1f} ms, heap {th * 1e3:.0f} ms, "
                      f"x{th / tf:.0f}, identical={same}")
    return big, cut_rows


def _bench_views(trees, T, args, rng, con):
    """Per-view budget_cut + extract on the build mesh: rows."""
    import optim

    view_rows = []
    for method, tree in trees.items():
        keys = _view_keys(tree, rng)
        for frac in (0.1, 0.5):
            budget = int(frac * T)
            tc, cut = _best(lambda: optim.budget_cut(tree, keys, budget), args.repeat)
            tt, _ = _best(lambda: optim.budget_cut(tree, keys, budget, monotone="trust"), args.repeat)
            te, mesh = _best(lambda: optim.extract(tree, cut), args.repeat)
            view_rows.append((method, budget, tc, tt, te, mesh[1].shape[0]))
            con.print(f"  view {method} budget {budget:,}: cut {tc * 1e3:.1f} ms (trust {tt * 1e3:.1f}), "
                      f"extract {te * 1e3:.1f} ms")
    return view_rows


def _bench_quality(trees, T, con):
    """Surface deviation of budget cuts greedy on geometric error: rows."""
    import igl

    import optim

    quality = []
    for method, tree in trees.items():
        gk = optim.repair_monotone(tree, tree.geom_error)
        for frac in (0.01, 0.1):
            vs, fs, _ = optim.extract(tree, optim.budget_cut(tree, gk, int(frac * T)))
            d2 = igl.point_mesh_squared_distance(tree.vertices, vs, fs.astype(np.int64))[0]
            rad = float(tree.radius[0])
            quality.append((method, fs.shape[0], np.sqrt(d2.mean()) / rad, np.sqrt(d2.max()) / rad))
            con.print(f"  quality {method} {fs.shape[0]:,} triangles: input vertices to simplified surface "
                      f"rms {quality[-1][2]:.3g}, max {quality[-1][3]:.3g} x bounding radius")
    return quality


def _report(args, name, v, T, rows, dt0, big, cut_rows, view_rows, cache_rows, quality) -> str:
    octree_rate = rows[0][2]
    lines = [
        "# bench_tree: vertex-tree build, budget cut, extraction",
        "",
        f"Command: `.venv/bin/python -m experiments.bench_tree{' --quick' if args.quick else ''}`  ",
        f"Machine: {platform.machine()} {platform.processor() or ''}, Python {platform.python_version()}, "
        f"numpy {np.__version__}; best of {args.repeat} (builds of > 200k triangles: 1 run). Times are process "
        "CPU time (single-threaded work, robust on a shared machine); build wall time is listed beside it.",
        "",
        f"## Build ({name}: {T:,} triangles, {v.shape[0]:,} vertices)",
        "",
        "| what | CPU s | wall s | input M tri/s (CPU) | bytes / input triangle | nodes |",
        "| --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for what, dt, rate, bpt, nn, wall in rows:
        lines.append(f"| {what} | {dt:.3f} | {wall:.3f} | {rate / 1e6:.3f} | {'' if np.isnan(bpt) else f'{bpt:.0f}'} | "
                     f"{f'{nn:,}' if nn else ''} |")
    lines += [
        "",
        f"Targets: octree >= 0.3 M tri/s (measured {octree_rate / 1e6:.2f}); memory <= 200 B per input triangle. "
        f"Ratio octree build / fast-simplification full collapse sequence: {rows[0][1] / dt0:.2f}; "
        f"qem build / same: {rows[1][1] / dt0:.2f}.",
        "",
        f"## budget_cut vs budget_cut_heap ({big.n_nodes:,} nodes, {big.n_triangles:,} triangles, {big.method})",
        "",
        "| keys | budget | budget_cut ms | heap ms | speed-up | identical cut |",
        "| --- | ---: | ---: | ---: | ---: | --- |",
    ]
    for kname, budget, tf, th, ratio, same in cut_rows:
        lines.append(f"| {kname} | {budget:,} | {tf * 1e3:.1f} | {th * 1e3:.0f} | {ratio:.0f}x | {same} |")
    lines += [
        "",
        "Target: identical cuts, >= 30x faster. Keys of `optim.score` are float32; float64 keys are "
        "rounded to float32 for the radix passes and ordered exactly among the final candidates. The 10 % "
        "budget with random keys is the hardest case for the ratio (the heap stops early).",
        "",
        f"## Per-view budget_cut + extract ({name})",
        "",
        "| tree | budget | budget_cut ms (checked) | budget_cut ms (monotone='trust') | extract ms | cut+extract ms |",
        "| --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for method, budget, tc, tt, te, nt in view_rows:
        lines.append(f"| {method} | {budget:,} | {tc * 1e3:.1f} | {tt * 1e3:.1f} | {te * 1e3:.1f} | "
                     f"{(tc + te) * 1e3:.1f} |")
    lines += ["", "Target: about 25 ms for budget cut + extract on the 796k-triangle mesh.", "",
              "Memory after the views above (bytes per input triangle): "
              + "; ".join(f"{m}: tree {a:.0f} + per-view caches {b:.0f} = {a + b:.0f}" for m, a, b in cache_rows)
              + " (target <= 200).", "",
              "## Hierarchy quality ([LHNW00 §6.3] asks for a better clustering than the octree)", "",
              "Budget cuts greedy on each fold's geometric error (largest distance from a supported vertex "
              "to the proxy, made monotone); distance from every input vertex to the simplified surface "
              "(libigl point-mesh distance), in units of the model's bounding radius (smaller is better).", "",
              "| tree | triangles | rms distance / radius | max distance / radius |", "| --- | ---: | ---: | ---: |"]
    lines += [f"| {m} | {n:,} | {r:.3g} | {x:.3g} |" for m, n, r, x in quality]
    lines += [""]
    return "\n".join(lines)


def main(argv=None) -> int:
    from rich.console import Console

    from pmetric import atomic_write_text

    args = _parse(argv)
    con = Console()
    rng = np.random.default_rng(0)
    v, f, name = _input_mesh(args)
    T = f.shape[0]
    con.print(f"mesh {name}: {T:,} triangles, {v.shape[0]:,} vertices")
    rows, trees, dt0 = _bench_builds(v, f, args, con)
    big, cut_rows = _bench_cuts(trees, args, rng, con)
    view_rows = _bench_views(trees, T, args, rng, con)
    cache_rows = [(m, tr.nbytes / T, _cache_bytes(tr) / T) for m, tr in trees.items()]
    for m, a, b in cache_rows:
        con.print(f"  memory {m}: {a:.0f} B/tri tree + {b:.0f} B/tri per-view caches")
    quality = _bench_quality(trees, T, con)
    out = atomic_write_text(args.out, _report(args, name, v, T, rows, dt0, big, cut_rows, view_rows, cache_rows, quality))
    con.print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    from experiments._runinfo import run_script

    run_script(main)

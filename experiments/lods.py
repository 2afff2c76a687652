"""LOD chains judged: is each level invisible at its switch size from directions the chain did not sample?

``python -m experiments.lods [--config FILE] [--quick] [--out DIR]`` builds, per mesh and lighting, the
chain of ``optim.lod_chain`` at triangle budgets (fractions of the input), and judges every level with
FovVideoVDP (foveated at the object's centre) at its switch size and at ``factors`` times it (how much
margin the perceptual switch leaves), from ``held_out`` random directions. Beside it, the conventional
rule: meshoptimizer's simplification to the same count, switched where its geometric error (the largest
distance from an input vertex to the simplified surface, libigl) projects to one pixel; it is judged at
its own switch size and at plod's. With ``eccentricities`` above 0 (``configs/lods_eccentric.toml``), each
level's switch size with the gaze at least that far off the object (``optim.lod_sizes``) is judged too, with
FovVideoVDP fixating that far beyond the object's outline. Writes ``DIR/results.jsonl`` (one row per judged
rendering), ``DIR/report.md`` and ``DIR/run_info.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from experiments._runinfo import check_out_dir, load_config, repo_path, save_run_info
from pmetric import PlodError, atomic_write_text

WRITES = ("results.jsonl", "report.md")
DEFAULTS = {
    "out": "reports/lods",
    "meshes": ["../shared/data/meshes/horse.ply", "../shared/data/meshes/armadillo-70k.ply",
               "../shared/data/meshes/cow.obj", "../shared/data/meshes/stanford-bunny.obj"],
    "procedural": [],
    "fractions": [0.5, 0.25, 0.1, 0.05, 0.02],
    "lightings": ["relit", "baked"],
    "held_out": 2,
    "factors": [1.0, 4.0, 16.0],
    "eccentricities": [0.0],
    "directions": 512,
    "search_directions": 64,
    "size": [960, 540],
    "seed": 11,
}
QUICK = {"meshes": [], "procedural": ["sphere:4:11"], "fractions": [0.25], "lightings": ["relit"], "held_out": 1,
         "factors": [1.0], "directions": 64, "size": [480, 270], "out": "reports/lods/quick"}
JOD_INVISIBLE = 9.8


def _check(cfg):
    from experiments._runinfo import config_numbers

    if not config_numbers(cfg["fractions"], lo=0.0, strict=True, below=1.0):
        raise PlodError(f"lods config: fractions must be numbers in (0, 1), got {cfg['fractions']!r}")
    if not config_numbers(cfg["factors"], lo=0.0, strict=True):
        raise PlodError(f"lods config: factors must be positive numbers, got {cfg['factors']!r}")
    e = cfg["eccentricities"]
    if not config_numbers(e, lo=0.0, below=90.0001) or not e or list(e) != sorted(set(e)):
        raise PlodError(f"lods config: eccentricities must be increasing angles in [0, 90] deg, got {e!r}")
    bad = [x for x in cfg["lightings"] if x not in ("relit", "baked")]
    if bad or not cfg["lightings"]:
        raise PlodError(f"lods config: lightings must be relit and/or baked, got {cfg['lightings']!r}")
    for key, lo in (("held_out", 1), ("directions", 1), ("search_directions", 1)):
        if not config_numbers([cfg[key]], lo=lo, ints=True):
            raise PlodError(f"lods config: {key} must be an integer >= {lo}, got {cfg[key]!r}")
    if not config_numbers(cfg["size"], n=2, lo=16, ints=True, below=8193):
        raise PlodError(f"lods config: size must be two integers in 16..8192, got {cfg['size']!r}")


def _meshes(cfg):
    import optim
    from experiments.experiment import procedural_mesh

    for spec in cfg["procedural"]:
        v, f, c = procedural_mesh(spec)
        yield spec, v, f, c
    for name in cfg["meshes"]:
        p = repo_path(name)
        if p.is_file():
            v, f, c = optim.load_mesh(p)
            yield p.stem, v, f, c


def geometric_error(v, f, v2, f2) -> float:
    """The largest distance (object units) from an input vertex to the simplified surface (libigl)."""
    import igl

    d2 = igl.point_mesh_squared_distance(np.asarray(v, np.float64), np.asarray(v2, np.float64),
                                         np.asarray(f2, np.int64))[0]
    return float(np.sqrt(d2.max()))


def one_pixel_deg(error: float, radius: float, display) -> float:
    """The object size (deg, bounding-sphere diameter) at which ``error`` (object units) spans one pixel of
    ``display`` at the object's distance: 2 asin(px_rad radius / error), the screen's height when larger."""
    from optim import max_object_deg

    px = math.radians(float(display.degrees_per_pixel()))
    top = max_object_deg(display)
    if error <= 0:
        return top
    return min(top, math.degrees(2 * math.asin(min(1.0, px * radius / error))))


def run(cfg, out: Path, progress=None) -> list[dict]:
    import optim
    import pmetric
    from experiments.experiment import baked_grey
    from experiments.judge import judge, offset_gaze_view
    from experiments.peers import compact, meshopt_simplify
    from experiments.render import mesh_parts

    display = pmetric.Display.default()
    top = optim.max_object_deg(display)
    rng = np.random.default_rng(cfg["seed"])
    rows = []
    path = out / "results.jsonl"
    path.write_text("")
    for name, v, f, c in _meshes(cfg):
        held = rng.normal(size=(cfg["held_out"], 3))
        held /= np.linalg.norm(held, axis=1)[:, None]
        radius = optim.framing_sphere(v)[1]
        for lighting in cfg["lightings"]:
            relit = lighting == "relit"
            colors = c if relit or c is not None else baked_grey(v, f)
            light = optim.Lighting() if relit else None
            t0 = time.perf_counter()
            tree = optim.build_tree(v, f, colors, method="hybrid" if relit else "meshopt")
            T = int(tree.n_triangles)
            budgets = [max(1, int(round(x * T))) for x in cfg["fractions"]]
            chain = optim.lod_chain(tree, budgets=budgets, directions=cfg["directions"],
                                    search_directions=cfg["search_directions"], display=display, lighting=light)
            off = {e: chain if e == 0 else optim.lod_sizes(
                tree, chain, eccentricity_deg=e, directions=cfg["directions"],
                search_directions=cfg["search_directions"], display=display, lighting=light)
                for e in cfg["eccentricities"]}
            chain_s = time.perf_counter() - t0
            ref = (v, f, colors)
            for j, lv in enumerate(chain):
                mesh = optim.extract(tree, lv.cut, "region" if relit else None)
                pv, pf, pc, pn = mesh_parts(mesh)
                ours = (pv, pf, pc, pn) if relit else (pv, pf, pc)
                err_plod = geometric_error(v, f, pv, pf)
                base = dict(mesh=name, lighting=lighting, level=j + 1, budget=budgets[j], triangles=lv.triangles,
                            plod_deg=lv.object_deg, key=lv.key, capped=lv.capped,
                            plod_1px_deg=one_pixel_deg(err_plod, radius, display), plod_error=err_plod,
                            chain_s=round(chain_s, 1))
                # (who, mesh, eccentricity, size judged, at, switch size)
                jobs = [("plod", ours, e, min(top, k * o[j].object_deg), k, o[j].object_deg)
                        for e, o in off.items() for k in cfg["factors"]]
                if 0 in off:  # the conventional rule beside the chain's own sizes
                    mo = compact(v, meshopt_simplify(v, f, lv.triangles, colors), colors)
                    err_mo = geometric_error(v, f, mo[0], mo[1])
                    s_mo = one_pixel_deg(err_mo, radius, display)
                    base.update(meshopt_triangles=int(len(mo[1])), meshopt_1px_deg=s_mo, meshopt_error=err_mo)
                    jobs += [("meshopt", mo, 0.0, s_mo, "1px", None), ("meshopt", mo, 0.0, lv.object_deg, "plod", None)]
                for u_i, u in enumerate(held):
                    for who, m, e, s, at, switch in jobs:
                        # the gaze e beyond the object's outline (to the right of its centre); 0: at its centre
                        view = offset_gaze_view(v, e + 0.5 * s if e > 0 else 0.0, object_deg=s, direction=u,
                                                display=display)
                        res = judge(ref, m, view, mode=lighting, lighting=light, size=tuple(cfg["size"]),
                                    metrics=("fovvdp",), heatmap=False)
                        row = dict(base, who=who, at=at, eccentricity=e, switch_deg=switch,
                                   object_deg=s, direction=u_i, jod=float(res.jod))
                        rows.append(row)
                        with open(path, "a") as fh:
                            fh.write(json.dumps(row) + "\n")
                        if progress:
                            progress(f"{name} {lighting} level {j + 1} {who} at {at} ({e:g} deg off)", len(rows))
    return rows


def _fmt(x, nd=2):
    return "" if x is None else f"{x:.{nd}f}"


def write_report(rows, cfg, command, out: Path) -> None:
    from experiments._runinfo import git_sha

    L = ["# LOD chains judged at their switch sizes", ""]
    centre = [r for r in rows if r.get("eccentricity", 0.0) == 0]
    off = [r for r in rows if r.get("eccentricity", 0.0) > 0]
    if centre:
        L += _centre_section(centre, cfg, command, git_sha())
    if off:
        L += _eccentric_section(off, cfg, command, git_sha())
    atomic_write_text(out / "report.md", "\n".join(L) + "\n")


def _by_level(rows) -> dict:
    keyed = {}
    for r in rows:
        keyed.setdefault((r["mesh"], r["lighting"], r["level"]), []).append(r)
    return keyed


def _lowest(rs, who, at, e=None):
    js = [r["jod"] for r in rs if r["who"] == who and r["at"] == at and (e is None or r["eccentricity"] == e)]
    return min(js) if js else None


def _centre_section(rows, cfg, command, sha) -> list[str]:
    from optim import screen_fraction

    L = [f"`{command}` (git {sha}). Each level of `optim.lod_chain` (budgets "
         f"{', '.join(f'{x:g}' for x in cfg['fractions'])} of the input; {cfg['directions']} directions, the size "
         f"searched over {cfg['search_directions']}) is judged by FovVideoVDP, foveated at the object's centre, at "
         f"{cfg['size'][0]}x{cfg['size'][1]} with the default display's angular content, from {cfg['held_out']} random "
         "directions the chain did not sample; JOD is the lowest over those directions. *plod deg*: the level's "
         "switch size (the object's bounding-sphere diameter, deg, at or below which the level is used); "
         "*1 px deg*: the size at which the level's geometric error (largest distance from an input vertex to "
         "its surface) spans one pixel, the conventional switch; meshoptimizer is its simplification to the same "
         "count, judged at its own 1-pixel size and at plod's switch size.", ""]
    keyed = _by_level(rows)
    factors = [k for k in cfg["factors"]]
    head = ["mesh", "lighting", "level", "triangles", "plod deg", "screen height"]
    head += [f"plod JOD at {k:g}x" for k in factors]
    head += ["plod 1 px deg", "meshopt 1 px deg", "meshopt JOD at its 1 px", "meshopt JOD at plod deg"]
    L += ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    lows = {k: [] for k in factors}
    mo1 = []
    for (mesh, lighting, level), rs in keyed.items():
        r0 = rs[0]
        cells = [mesh, lighting, str(level), f"{r0['triangles']:,}", f"{r0['plod_deg']:.3g}",
                 f"{screen_fraction(r0['plod_deg']):.3f}"]
        for k in factors:
            x = _lowest(rs, "plod", k)
            lows[k].append(x)
            cells.append(_fmt(x, 3))
        a, b = _lowest(rs, "meshopt", "1px"), _lowest(rs, "meshopt", "plod")
        mo1.append(a)
        cells += [f"{r0['plod_1px_deg']:.3g}", f"{r0['meshopt_1px_deg']:.3g}", _fmt(a, 3), _fmt(b, 3)]
        L.append("| " + " | ".join(cells) + " |")
    n = len(keyed)
    L += ["", "## Summary", ""]
    for k in factors:
        xs = [x for x in lows[k] if x is not None]
        if xs:
            L.append(f"- plod's levels at {k:g}x their switch size: {sum(x >= JOD_INVISIBLE for x in xs)} of {len(xs)} "
                     f"score >= {JOD_INVISIBLE} JOD (lowest {min(xs):.3f}, median {float(np.median(xs)):.3f}).")
    xs = [x for x in mo1 if x is not None]
    if xs:
        L.append(f"- meshoptimizer's levels at their 1-pixel size: {sum(x >= JOD_INVISIBLE for x in xs)} of {len(xs)} "
                 f">= {JOD_INVISIBLE} JOD (lowest {min(xs):.3f}, median {float(np.median(xs)):.3f}).")
    ratio = [r["plod_deg"] / r["meshopt_1px_deg"] for r in (v[0] for v in keyed.values())]
    if ratio:
        L.append(f"- plod's switch size over meshoptimizer's 1-pixel size, same count: median "
                 f"{float(np.median(ratio)):.2f} (from {min(ratio):.2f} to {max(ratio):.2f}; above 1 plod switches "
                 f"to the level sooner) over {n} levels.")
    return L


def _eccentric_section(rows, cfg, command, sha) -> list[str]:
    eccs = sorted({r["eccentricity"] for r in rows})
    factors = [k for k in cfg["factors"]]
    L = ["## Switch sizes with the gaze off the object", "",
         f"`{command}` (git {sha}). Per level of `optim.lod_chain` (budgets "
         f"{', '.join(f'{x:g}' for x in cfg['fractions'])} of the input; {cfg['directions']} directions, searched "
         f"over {cfg['search_directions']}), `optim.lod_sizes` gives its switch size when the gaze lies at least "
         "E deg beyond the object's bounding sphere (gaze error 1 deg). Each is judged by FovVideoVDP at "
         f"{cfg['size'][0]}x{cfg['size'][1]} fixating E deg beyond the object's outline, to the right of its centre, "
         f"from {cfg['held_out']} random directions the chain did not sample (JOD: the lowest over them), at the "
         "switch size and at multiples of it (the fixation kept E deg off the larger outline). *deg at 0*: the "
         "chain's own switch size (no gaze information); *x*: the size off the gaze over it.", ""]
    head = ["mesh", "lighting", "level", "triangles", "deg at 0"]
    for e in eccs:
        head += [f"deg at {e:g}", "x"] + [f"JOD at {e:g}, {k:g}x" for k in factors]
    L += ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    lows = {(e, k): [] for e in eccs for k in factors}
    gain = {e: [] for e in eccs}
    keyed = _by_level(rows)
    for (mesh, lighting, level), rs in keyed.items():
        r0 = rs[0]
        cells = [mesh, lighting, str(level), f"{r0['triangles']:,}", f"{r0['plod_deg']:.3g}"]
        for e in eccs:
            sw = [r["switch_deg"] for r in rs if r["eccentricity"] == e]
            if not sw:
                cells += [""] * (2 + len(factors))
                continue
            gain[e].append(sw[0] / r0["plod_deg"])
            cells += [f"{sw[0]:.3g}", f"{sw[0] / r0['plod_deg']:.2f}"]
            for k in factors:
                x = _lowest(rs, "plod", k, e)
                lows[(e, k)].append(x)
                cells.append(_fmt(x, 3))
        L.append("| " + " | ".join(cells) + " |")
    L += ["", "### Summary", ""]
    for e in eccs:
        g = gain[e]
        if g:
            L.append(f"- {e:g} deg off: switch sizes a median {float(np.median(g)):.2f}x the chain's own (from "
                     f"{min(g):.2f}x to {max(g):.2f}x) over {len(g)} levels.")
        for k in factors:
            xs = [x for x in lows[(e, k)] if x is not None]
            if xs:
                L.append(f"  - at {k:g}x that size: {sum(x >= JOD_INVISIBLE for x in xs)} of {len(xs)} score >= "
                         f"{JOD_INVISIBLE} JOD (lowest {min(xs):.3f}, median {float(np.median(xs)):.3f}).")
    return L


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m experiments.lods", description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default=None, help="TOML overrides of the defaults (unknown keys are refused)")
    ap.add_argument("--quick", action="store_true", help="one small procedural mesh, one level")
    ap.add_argument("--out", default=None, help="report folder (default reports/lods)")
    args = ap.parse_args(argv)
    cfg = load_config(args.config, {**DEFAULTS, **(QUICK if args.quick else {})})
    _check(cfg)
    if args.out:
        cfg["out"] = args.out
    out = check_out_dir(repo_path(cfg["out"]), config=args.config, writes=WRITES)
    out.mkdir(parents=True, exist_ok=True)
    command = "python -m experiments.lods " + " ".join(argv if argv is not None else sys.argv[1:])
    from experiments._progress import rich_progress

    with rich_progress("lods") as cb:
        def progress(stage, done):
            if cb is not None:
                cb(stage, done, None)
            else:
                print(f"[lods {done}] {stage}", file=sys.stderr, flush=True)

        rows = run(cfg, out, progress)
    write_report(rows, cfg, command, out)
    save_run_info(out, cfg, cfg["seed"], command)
    print(f"wrote {out / 'report.md'}", file=sys.stderr)
    return 0


if __name__ == "__main__":  # pragma: no cover
    from experiments._runinfo import run_script

    run_script(main)

"""``plod lods``: a chain of levels of detail for any view direction, each with its switch size.

Stages: read the mesh and its vertex tree (as ``plod simplify``: cached under ``$PLOD_CACHE``) ->
``optim.lod_chain`` (the levels at ``--budgets`` or ``--object-deg``, each imperceptible from every one of
``--directions`` view directions up to its size, no gaze information) -> ``optim.extract`` per level ->
``--out NAME.ply`` writes ``NAME_lod1.ply``, ``NAME_lod2.ply``, ... atomically (never over the input).

A level's switch size is the angular diameter (deg) of the object's bounding sphere at or below which
the level may be drawn, for the display of ``--screen-deg`` / ``--distance-m``; also given as the object's
height over the screen's (an engine's screen-size switch, for the display's physical camera) and as a
distance in the mesh's units. ``reports/lods/report.md`` judges such chains: every level was invisible to
FovVideoVDP at its switch size, and the sizes lie an order of magnitude below the one-pixel geometric rule.

``--eccentricity E,E,...`` adds, per level, its switch size when the viewer's gaze lies at least E degrees
off the object's bounding sphere (``optim.lod_sizes``: an eye-tracked or foveated renderer, with a gaze
error of ``--gaze-error`` deg): the same level files, larger sizes off the gaze.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from pmetric import DEFAULT_MODEL, PlodError, make_model


def register(sub) -> None:
    p = sub.add_parser("lods", help="levels of detail for any view direction, with the size at which each "
                                    "becomes imperceptible", description=__doc__.split("\n\n")[0])
    p.add_argument("mesh", help="input mesh (PLY, OBJ, OFF, STL, GLB)")
    mode = p.add_mutually_exclusive_group(required=True)
    mode.add_argument("--budgets", metavar="N,N,...", help="decreasing triangle counts, or percentages of the "
                      "input (50%%,25%%,10%%): each level's switch size is found")
    mode.add_argument("--object-deg", metavar="DEG,DEG,...", help="decreasing object sizes (deg, the bounding "
                      "sphere's angular diameter): each level is the imperceptible cut at its size")
    p.add_argument("--directions", metavar="N", default="512",
                   help="view directions each level is checked from (default 512; 64..4096 recommended)")
    p.add_argument("--light", metavar="DX,DY,DZ[,AMBIENT]", default=None,
                   help="the renderer relights the mesh from its normals with this light (object space); default "
                        "pre-lit (baked)")
    p.add_argument("--model", default=DEFAULT_MODEL, metavar="NAME|FILE.json",
                   help="model name (see plod models) or a fitted model .json (default stela)")
    p.add_argument("--method", choices=("auto", "meshopt", "hybrid", "qem", "octree"), default="auto",
                   help="vertex tree builder (default auto: hybrid with --light, meshopt without)")
    p.add_argument("--screen-deg", metavar="DEG", default=None,
                   help="horizontal angle the screen subtends at the viewer, 0.5..180 deg (default 46)")
    p.add_argument("--distance-m", metavar="M", default=None, help="viewing distance, 0.01..1000 m (default 0.63)")
    p.add_argument("--normals", metavar="region|faces|none", default="region",
                   help="vertex normals written with each level (as plod simplify)")
    p.add_argument("--eccentricity", metavar="DEG,DEG,...", default=None,
                   help="also give each level's switch size with the gaze at least this far off the object "
                        "(increasing angles in (0, 90] deg, e.g. 5,10,20: for an eye-tracked renderer)")
    p.add_argument("--gaze-error", metavar="DEG", default=None,
                   help="the eye tracker's error with --eccentricity, deg, 0 up to 90 (default 1)")
    p.add_argument("--no-cache", action="store_true", help="do not read or write the tree cache")
    p.add_argument("--out", metavar="NAME.ply", default=None,
                   help="write the levels as NAME_lod1.ply, NAME_lod2.ply, ... (suffix: .ply .obj .off .stl .glb)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=run)


def _list(flag: str, text: str) -> list[str]:
    parts = [s.strip() for s in str(text).split(",")]
    if not parts or any(not s for s in parts):
        raise PlodError(f"{flag} needs comma-separated values, got {text!r}")
    return parts


def _budgets(text: str, total: int) -> list[int]:
    if total < 2:
        raise PlodError(f"--budgets: the input has {total} triangle; there is nothing to simplify")
    out = []
    for s in _list("--budgets", text):
        try:
            x = float(s[:-1]) / 100 * total if s.endswith("%") else float(s.replace("_", ""))
            n = round(x)
            if not s.endswith("%") and n != x:  # 1e3 is a whole number, 10.5 is not
                raise ValueError
        except (ValueError, OverflowError):
            raise PlodError(f"--budgets: {s!r} is neither a whole number of triangles nor a percentage") from None
        if not 1 <= n < total:
            raise PlodError(f"--budgets: {s!r} gives {n:,} triangles; each level needs 1..{total - 1:,} (the input "
                            f"has {total:,})")
        out.append(n)
    if any(b >= a for a, b in zip(out, out[1:])):
        raise PlodError(f"--budgets must decrease (finest level first), got {text!r}")
    return out


def _numbers(flag: str, text: str) -> list[tuple[str, float]]:
    """(item, value) per comma-separated item of ``text``; an item that is not a number is refused."""
    out = []
    for s in _list(flag, text):
        try:
            out.append((s, float(s)))
        except ValueError:
            raise PlodError(f"{flag}: {s!r} is not a number") from None
    return out


def _sizes(text: str) -> list[float]:
    return [x for _, x in _numbers("--object-deg", text)]


def _eccentricities(text: str | None) -> list[float]:
    if text is None:
        return []
    out = []
    for s, x in _numbers("--eccentricity", text):
        if not 0 < x <= 90:
            raise PlodError(f"--eccentricity: {s!r} is not an angle in (0, 90] deg (how far the gaze lies off the object)")
        out.append(x)
    if any(b <= a for a, b in zip(out, out[1:])):
        raise PlodError(f"--eccentricity must increase, got {text!r}")
    return out


def _outputs(args, mesh_path: Path, n: int) -> list[Path] | None:
    if args.out is None:
        return None
    from experiments._paths import MESH_SUFFIXES, check_output

    base = Path(args.out)
    inputs = (("the input mesh", mesh_path), ("the input model", args.model))
    check_output("--out", base, suffixes=MESH_SUFFIXES, inputs=())  # its folder and suffix
    return [check_output("--out", base.with_name(f"{base.stem}_lod{j + 1}{base.suffix}"), suffixes=MESH_SUFFIXES,
                         inputs=inputs) for j in range(n)]


def lods(args) -> dict:
    """Run the command; returns the result dictionary printed by ``--json``."""
    import optim
    from experiments._cmd_simplify import _display, _number, tree_for_file
    from experiments._paths import check_mesh_input
    from experiments.render import mesh_parts

    mesh_path = Path(args.mesh)
    model = make_model(args.model)
    check_mesh_input(mesh_path)
    screen = _number("--screen-deg", args.screen_deg, lo=0.5, hi=180.0, strict=False)
    dist = _number("--distance-m", args.distance_m, lo=0.01, hi=1000.0, strict=False)
    display = _display(screen, dist)
    light = optim.Lighting.from_text(args.light) if args.light is not None else None
    nd = _number("--directions", args.directions, lo=1, hi=100_001, strict=False)
    if nd != int(nd):
        raise PlodError(f"--directions needs a whole number, got {args.directions!r}")
    if args.normals not in (*optim.NORMALS, "none"):
        raise PlodError(f"--normals must be region, faces or none, got {args.normals!r}")
    eccs = _eccentricities(args.eccentricity)
    if args.gaze_error is not None and not eccs:
        raise PlodError("--gaze-error needs --eccentricity (it is the eye tracker's error off the gaze)")
    gaze_error = _number("--gaze-error", "1" if args.gaze_error is None else args.gaze_error, lo=0.0, hi=90.0,
                         strict=False)
    sizes = _sizes(args.object_deg) if args.object_deg is not None else None
    if sizes is not None:  # checked before the tree is built
        for s in sizes:
            optim._lods._check_size("--object-deg", s, display)
    n_levels = len(sizes) if sizes is not None else len(_list("--budgets", args.budgets))
    outs = _outputs(args, mesh_path, n_levels)
    t0 = time.perf_counter()
    method = args.method if args.method != "auto" else ("hybrid" if light is not None else "meshopt")
    tree, cache, _, unit_exp, _ = tree_for_file(mesh_path, method, use_cache=not args.no_cache, progress=not args.json)
    build_s = time.perf_counter() - t0
    v = np.ldexp(tree.vertices, -unit_exp) if unit_exp else tree.vertices  # the file's units
    if outs is not None:  # the format must hold the mesh's coordinates (float32 PLY: |x| < 3.4e38)
        from optim._mesh import check_writable

        check_writable(outs[0], v)
    budgets = _budgets(args.budgets, int(tree.n_triangles)) if sizes is None else None
    from experiments._progress import rich_progress

    t0 = time.perf_counter()
    with rich_progress("lods", enabled=not args.json) as cb:
        levels = optim.lod_chain(tree, object_deg=sizes, budgets=budgets, directions=int(nd), model=model,
                                 display=display, lighting=light, progress=cb)
        off = {e: optim.lod_sizes(tree, levels, eccentricity_deg=e, directions=int(nd), model=model, display=display,
                                  lighting=light, gaze_error_deg=gaze_error, progress=cb) for e in eccs}
    chain_s = time.perf_counter() - t0
    empty = [j + 1 for j, lv in enumerate(levels) if lv.triangles == 0]
    if empty and outs is not None:  # refused before any level is written
        raise PlodError(f"level {empty[0]} has no triangles (its {'budget' if sizes is None else 'size'} is below "
                        f"the smallest cut this tree makes); drop it or give a larger one")
    radius = optim.framing_sphere(v)[1]
    normals = None if args.normals == "none" else args.normals
    rows = []
    for j, lv in enumerate(levels):
        row = {"level": j + 1, "triangles": lv.triangles, "object_deg": lv.object_deg,
               "screen_fraction": optim.screen_fraction(lv.object_deg, display),
               "distance": optim.object_distance(lv.object_deg, radius), "key": lv.key,
               "capped": bool(lv.capped), "out": None,
               "off_gaze": [{"eccentricity_deg": e, "object_deg": o[j].object_deg,
                             "screen_fraction": optim.screen_fraction(o[j].object_deg, display),
                             "distance": optim.object_distance(o[j].object_deg, radius), "key": o[j].key,
                             "capped": bool(o[j].capped)} for e, o in off.items()]}
        if outs is not None:
            v2, f2, c2, n2 = mesh_parts(optim.extract(tree, lv.cut, normals))
            if unit_exp:
                v2 = np.ldexp(np.asarray(v2, np.float64), -unit_exp)
            optim.save_mesh(outs[j], v2, f2, c2, protect=(mesh_path,), normals=n2)
            row["out"] = str(outs[j])
        rows.append(row)
    return {"mesh": str(mesh_path), "input_triangles": int(tree.n_triangles), "bounding_radius": radius,
            "directions": int(nd), "model": type(model).__name__, "eccentricity_deg": eccs,
            "gaze_error_deg": gaze_error if eccs else None,
            "lighting": light.to_dict() if light is not None else "baked", "tree_method": method,
            "tree_cache": cache, "display": {"screen_deg": float(display.field_of_view[0]),
                                             "distance_m": float(display.distance)},
            "levels": rows, "timings_s": {"tree": round(build_s, 3), "chain": round(chain_s, 3)}}


def run(args) -> int:
    from experiments._interrupt import check

    res = lods(args)
    check()
    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"plod lods {res['mesh']} ({res['input_triangles']:,} triangles, "
                        f"{res['directions']} directions)")
    names = ["level", "triangles", "imperceptible at or below (deg)", "screen height", "distance"]
    names += [f"gaze {e:g} deg off (deg)" for e in res["eccentricity_deg"]] + ["written"]
    for name in names:
        table.add_column(name, justify="left" if name == "written" else "right")
    cap = lambda x, capped: f"{x:.3g}" + (" (cap)" if capped else "")  # noqa: E731
    for r in res["levels"]:
        table.add_row(str(r["level"]), f"{r['triangles']:,}", cap(r["object_deg"], r["capped"]),
                      f"{r['screen_fraction']:.3g}", f"{r['distance']:.4g}",
                      *(cap(o["object_deg"], o["capped"]) for o in r["off_gaze"]), r["out"] or "")
    Console().print(table)
    return 0

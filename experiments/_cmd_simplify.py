"""``plod simplify``: simplify one mesh for one view, to a triangle budget or imperceptibly.

Stages: read the mesh (PLY, OBJ, OFF, GLB ... through trimesh) -> vertex tree (built once and cached
by mesh hash under ``$PLOD_CACHE`` or ``~/.cache/plod``, with its first view's per-tree work beside it
(``optim.save_context``); an empty ``PLOD_CACHE``: no cache) -> view
(default: the object subtends about 30 deg of a 46 deg screen, the study of [LH01 §6.2]) -> per-node
keys (``optim.score``) -> cut (``optim.budget_cut`` or ``optim.imperceptible_cut``; with
``--cull-back-faces`` ``optim.visible_budget_cut``) -> ``optim.extract`` (and ``optim.drop_back_faces``)
-> write ``--out`` atomically (never over the input; every output path is checked by
``experiments._paths.check_output`` before any work).

A mesh of extreme size (bounding-box diagonal outside 1e-6 .. 1e6 object units) is scaled by an exact
power of two for the tree, view and keys, and the output scaled back (``unit_exponent``): plod's
float32 scoring needs it (issue 13).

Units: ``--fov`` and ``--screen-deg`` deg, ``--distance-m`` m, ``--gaze`` pixels of the image (x right,
y down, origin top-left), ``--gaze-error`` deg. Perceptual keys are viewing-distance multiples
[LH01 §5.3]; size and geometric keys are pixels. ``--model`` takes any spelling ``pmetric.make_model``
accepts (``plod models`` lists them).
"""

from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path

import numpy as np

from pmetric import DEFAULT_MODEL, PlodError, make_model

DEFAULT_OBJECT_DEG = 30.0


def register(sub) -> None:
    p = sub.add_parser(
        "simplify",
        help="simplify a mesh for one view: to a triangle budget or imperceptibly",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument("mesh", help="input mesh (PLY, OBJ, OFF, STL, GLB)")
    mode = p.add_mutually_exclusive_group(required=True)
    mode.add_argument("--budget", type=str, default=None, metavar="N", help="keep at most N triangles")
    mode.add_argument("--imperceptible", action="store_true",
                      help="fold every node whose fold is imperceptible from this view")
    p.add_argument("--metric", choices=("perceptual", "size", "geometric"), default="perceptual",
                   help="fold priority for --budget (default perceptual: imperceptible distance)")
    p.add_argument("--eye", metavar="X,Y,Z", help="camera position (object units); default: framed at 30 deg")
    p.add_argument("--target", metavar="X,Y,Z", help="point looked at (default: the mesh's bounding-box centre)")
    p.add_argument("--up", metavar="X,Y,Z", default=None, help="camera up vector (default 0,1,0)")
    p.add_argument("--fov", metavar="DEG", default=None,
                   help="vertical field of view of the camera, deg (default: what the screen subtends)")
    p.add_argument("--screen-deg", metavar="DEG", default=None,
                   help="horizontal angle the screen subtends at the viewer, 0.5..180 deg (default 46)")
    p.add_argument("--distance-m", metavar="M", default=None, help="viewing distance, 0.01..1000 m (default 0.63)")
    p.add_argument("--gaze", metavar="U,V", action="append", default=None,
                   help="gaze point in image pixels; repeat for several viewers (default: screen centre)")
    p.add_argument("--no-gaze", action="store_true", help="no gaze information: treat every node as foveal")
    p.add_argument("--gaze-error", metavar="DEG", default="1.0",
                   help="gaze uncertainty, 0..180 deg (1 for an eye tracker, 15 for head tracking; default 1)")
    p.add_argument("--light", metavar="DX,DY,DZ[,AMBIENT]", default=None,
                   help="the renderer relights the mesh from its own normals with this directional light "
                        "(direction toward the light, object space; ambient default 0.15): fold contrast "
                        "covers what relighting shows. Default: the mesh is displayed pre-lit (baked)")
    p.add_argument("--model", default=DEFAULT_MODEL, metavar="NAME|FILE.json",
                   help=f"model name (see plod models), eccentric(NAME) or a fitted model .json "
                        f"(default {DEFAULT_MODEL})")
    p.add_argument("--method", choices=("auto", "meshopt", "hybrid", "qem", "octree"), default="auto",
                   help="vertex tree builder: meshopt (nested meshoptimizer simplifications), hybrid (quadric "
                        "collapses below a fifth of the triangles, meshoptimizer's levels above), qem, octree; "
                        "default auto: hybrid with --light, meshopt without (the trees the judge rated best "
                        "for relit and pre-lit meshes, reports/accuracy/what_we_tried.md)")
    p.add_argument("--no-cache", action="store_true",
                   help="do not read or write the tree cache (kept in $PLOD_CACHE, default ~/.cache/plod; "
                        "PLOD_CACHE set to an empty string also means no cache)")
    p.add_argument("--cull-back-faces", metavar="MARGIN_DEG", nargs="?", const="0", default=None,
                   help="drop the triangles facing away from the eye by more than MARGIN_DEG (default 0: "
                        "exactly those a back-face-culling renderer skips; a margin keeps them for a moving "
                        "eye) and count --budget in front-facing triangles; the output carries the whole "
                        "cut's vertex normals (PLY, OBJ, GLB), which the renderer should shade from")
    p.add_argument("--normals", metavar="region|faces|none", default="region",
                   help="vertex normals written with the mesh for a renderer that relights it: region (default: "
                        "each vertex the mean input normal of the surface it stands for, which shades closest "
                        "to the input), faces (recomputed from the simplified faces) or none (the renderer "
                        "makes its own, as faces; with --cull-back-faces the whole cut's are written). Written "
                        "in .ply, .obj and .glb; .off and .stl hold no normals")
    p.add_argument("--out", metavar="OUT.ply", default=None, help="write the simplified mesh here")
    p.add_argument("--render", metavar="OUT.png", default=None,
                   help="render original and simplified for this view, with their FLIP difference, to a PNG")
    p.add_argument("--render-size", metavar="W,H", default="960,540",
                   help="rendering size in pixels for --render (default 960,540; FLIP's px/deg is scaled to it)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=run)


# ----------------------------------------------------------------------------------------------- parsing
def _vector(flag: str, text: str | None, n: int):
    if text is None:
        return None
    parts = [s.strip() for s in str(text).split(",")]
    words = {2: "two", 3: "three"}[n]
    try:
        vals = [float(s) for s in parts]
    except ValueError:
        vals = []
    if len(vals) != n:
        raise PlodError(f"{flag} needs {words} comma-separated numbers, got {text!r}")
    if not all(math.isfinite(x) for x in vals):
        raise PlodError(f"{flag} needs finite numbers, got {text!r}")
    return np.asarray(vals, dtype=np.float64)


def _number(flag: str, text, *, lo: float = 0.0, hi: float | None = None, strict: bool = True) -> float | None:
    if text is None:
        return None
    try:
        x = float(text)
    except (TypeError, ValueError):
        raise PlodError(f"{flag} needs a number, got {text!r}") from None
    bad = not math.isfinite(x) or (x <= lo if strict else x < lo) or (hi is not None and x >= hi)
    if bad:
        rng = f"{'>' if strict else '>='} {lo:g}" + (f" and < {hi:g}" if hi is not None else "")
        raise PlodError(f"{flag} must be a finite number {rng}, got {text!r}")
    return x


def _budget(text) -> int:
    try:
        n = int(str(text).replace("_", ""))
    except ValueError:
        raise PlodError(f"--budget needs a whole number of triangles, got {text!r}") from None
    if n < 1:
        raise PlodError(f"--budget must be >= 1 (0 triangles is an empty mesh), got {text!r}")
    return n


def _display(screen_deg, distance_m):
    import pmetric

    d = pmetric.Display.default()
    if screen_deg is None and distance_m is None:
        return d
    dist = float(d.distance) if distance_m is None else distance_m
    if screen_deg is None:
        return d.with_distance(dist)
    width = 2 * dist * math.tan(math.radians(screen_deg) / 2)
    rx, ry = d.resolution
    return pmetric.Display(width, width * ry / rx, (rx, ry), dist, peak_luminance=float(d.peak_luminance),
                           black_level=float(d.black_level))


def cache_dir() -> Path | None:
    """``$PLOD_CACHE``, or ``~/.cache/plod`` when it is unset; None (no cache) when it is set but empty."""
    env = os.environ.get("PLOD_CACHE")
    if env is None:
        return Path.home() / ".cache" / "plod"
    return Path(env) if env.strip() else None


def _file_key(path: Path, method: str) -> str:
    """SHA-256 of the mesh file's bytes, the tree method (the hybrid's with its ``HYBRID_KEEP``) and the tree
    format: the cache key."""
    import hashlib

    from optim._tree import TREE_FORMAT

    from optim._build import HYBRID_KEEP

    tag = f"{method}{HYBRID_KEEP!r}" if method == "hybrid" else method  # the hybrid's split is part of its tree
    h = hashlib.sha256(f"{TREE_FORMAT}|{tag}|{path.suffix.lower()}|".encode())
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 22), b""):
            h.update(block)
    return h.hexdigest()


#: bounding-box diagonals (object units) that ``plod simplify`` uses as they are; a mesh outside this
#: range is scaled by an exact power of two (``unit_exponent``) to a diagonal of about 1 for the tree,
#: the view and the keys (float32 inside: x1e18 gave all keys 0, x1e-20 no view), and the output is
#: scaled back exactly. Within it nothing changes (tests/test_scale.py: x1e-6 .. x1e6 agree with x1).
UNSCALED_DIAGONAL = (1e-6, 1e6)


def unit_exponent(vertices) -> int:
    """``k`` with ``vertices * 2**k`` of bounding-box diagonal in about [0.7, 1.4]; 0 when the diagonal
    is within :data:`UNSCALED_DIAGONAL` (or zero: ``validate_mesh`` judges such a mesh)."""
    v = np.asarray(vertices, dtype=np.float64)
    lo, hi = v.min(0), v.max(0)
    diag = float(np.hypot.reduce(hi - lo)) if np.isfinite(hi - lo).all() else math.inf
    if diag == 0.0 or UNSCALED_DIAGONAL[0] <= diag <= UNSCALED_DIAGONAL[1]:
        return 0
    if not math.isfinite(diag):  # the extent overflows float64 (coordinates near 1e308)
        return -int(round(math.log2(float(np.hypot.reduce(np.ldexp(hi, -64) - np.ldexp(lo, -64)))) + 64))
    return -int(round(math.log2(diag)))


def _cache_entry(root: Path, key: str) -> tuple[Path, int] | None:
    """The cached tree of ``key`` and its unit exponent (``KEY.npz``: 0; ``KEY.s{k}.npz``: k)."""
    plain = root / f"{key}.npz"
    if plain.is_file():
        return plain, 0
    for p in sorted(root.glob(f"{key}.s*.npz")):
        try:
            return p, int(p.name[len(key) + 2:-4])
        except ValueError:
            continue
    return None


def context_path(entry: Path) -> Path:
    """The file beside a cached tree ``KEY[.sK].npz`` that keeps its first view's per-tree work
    (``optim.save_context``): ``ctx-KEY[.sK].npz``."""
    return entry.with_name("ctx-" + entry.name)


def tree_for_file(path: Path, method: str, *, use_cache: bool = True, progress: bool = False):
    """(tree, "hit" | "miss" | "off", load seconds, k, context file or None): the vertex tree of a mesh
    file, built on the mesh scaled by ``2**k`` (:func:`unit_exponent`; 0 for every mesh of ordinary size).

    The cache is keyed by the file's bytes (plus method and tree format), so a hit skips parsing the
    mesh as well as building the tree; the tree holds the validated mesh (``tree.vertices``,
    ``tree.faces``, ``tree.colors``, scaled by ``2**k``), which is all the later stages need. On a hit
    the per-tree work of an earlier run's first view is put back too when its file is valid
    (``optim.load_context``: same code, numpy and tree); the caller saves it after its first view
    (:func:`save_context_quietly`) to the returned path.
    """
    import optim

    entry = None
    root = cache_dir() if use_cache else None
    if root is not None:
        from pmetric._atomic import remove_stale_temps_in

        remove_stale_temps_in(root)  # temp files of cache writes killed earlier (SIGKILL), any mesh's
        key = _file_key(path, method)
        found = _cache_entry(root, key)
        if found is not None:
            try:
                tree = optim.load_tree(found[0])
            except (ValueError, OSError, KeyError):
                tree = None  # unreadable or stale cache entry: rebuild and overwrite it
            if tree is not None:
                ctx = context_path(found[0])
                optim.load_context(tree, ctx)
                return tree, "hit", 0.0, found[1], ctx
    t0 = time.perf_counter()
    vertices, faces, colors = optim.load_mesh(path)
    k = unit_exponent(vertices)
    if k:
        vertices = np.ldexp(vertices, k)  # exact: a power of two
        if not np.isfinite(vertices).all():
            raise PlodError(f"mesh file {str(path)!r}: its coordinates lie too far from the origin for its size "
                            f"(scaled by 2**{k} to a unit diagonal they overflow); move it nearer the origin")
    load_s = time.perf_counter() - t0
    from experiments._progress import call_with_progress

    tree = call_with_progress(optim.build_tree, vertices, faces, colors, method=method, progress=progress)
    if root is None:
        return tree, "off", load_s, k, None
    entry = root / (f"{key}.npz" if k == 0 else f"{key}.s{k}.npz")
    try:
        tree.save(entry)
    except (OSError, PlodError):  # PlodError: PLOD_CACHE is a file, or lies below one
        pass  # a read-only cache never stops the command
    return tree, "miss", load_s, k, context_path(entry)


def save_context_quietly(tree, ctx: Path | None) -> str:
    """Keep the first view's per-tree work beside the cached tree (``optim.save_context``, replacing a
    file that did not hold all of it or was made by other code): "saved", or "off" (no cache, a
    read-only one, or nothing to keep)."""
    import optim

    if ctx is None:
        return "off"
    try:
        return "saved" if optim.save_context(tree, ctx) else "off"
    except (OSError, PlodError):
        return "off"  # a read-only cache (or one that is a file) never stops the command


def build_view(vertices, args, unit_exp: int = 0):
    """The ``optim.View`` described by the flags (see the module docstring); ``vertices`` are the
    mesh's scaled by ``2**unit_exp`` (see :func:`tree_for_file`), ``--eye`` and ``--target`` are
    scaled alike."""
    import optim

    eye = _vector("--eye", args.eye, 3)
    target = _vector("--target", args.target, 3)
    if unit_exp:
        eye = None if eye is None else np.ldexp(eye, unit_exp)
        target = None if target is None else np.ldexp(target, unit_exp)
    up = _vector("--up", args.up, 3)
    fov = _number("--fov", args.fov, hi=180.0)
    screen = _number("--screen-deg", args.screen_deg, lo=0.5, hi=180.0, strict=False)
    dist = _number("--distance-m", args.distance_m, lo=0.01, hi=1000.0, strict=False)  # m: 1 cm .. 1 km
    gaze_err = _number("--gaze-error", args.gaze_error, hi=180.0, strict=False)  # deg
    if args.no_gaze and args.gaze:
        raise PlodError("--gaze and --no-gaze cannot be combined")
    gaze = None if args.no_gaze else "center"
    if args.gaze:
        gaze = np.stack([_vector("--gaze", g, 2) for g in args.gaze])
    if target is not None and eye is None:
        raise PlodError("--target needs --eye")
    light = optim.Lighting.from_text(args.light) if getattr(args, "light", None) is not None else None
    kw = dict(display=_display(screen, dist), gaze=gaze, gaze_error_deg=gaze_err, fov_deg=fov, lighting=light)
    if up is not None:
        kw["up"] = up
    if eye is None:
        return optim.View.framing(vertices, DEFAULT_OBJECT_DEG, **kw)
    if target is None:
        target = 0.5 * (vertices.min(0) + vertices.max(0))
    return optim.View(eye=eye, target=target, **kw)


def _check_view_flags(args) -> None:
    """Check the view flags before any work (issue 13: an off-screen ``--gaze`` was found only after
    the tree was built): the numbers of ``--eye/--target/--up``, and every other flag through a
    throwaway ``View`` of a unit cube (the same checks ``build_view`` makes later)."""
    import argparse

    for flag, text in (("--eye", args.eye), ("--target", args.target), ("--up", args.up)):
        v = _vector(flag, text, 3)
        if flag == "--up" and v is not None and not np.any(v):
            raise PlodError(f"--up must be a nonzero vector, got {text!r}")
        if v is not None and np.abs(v).max() > 1e150:  # the view's bound (its lengths would overflow)
            raise PlodError(f"{flag} must lie within 1e150 of 0, got {text!r}")
    rest = argparse.Namespace(**{**vars(args), "eye": None, "target": None, "up": None})
    build_view(np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]), rest)


# ----------------------------------------------------------------------------------------------- run
def _outputs(args, mesh_path: Path):
    """Checked ``(--budget, --out, --render, --render-size)`` (None where not given)."""
    budget = _budget(args.budget) if args.budget is not None else None
    if args.imperceptible and args.metric != "perceptual":
        raise PlodError("--imperceptible needs --metric perceptual (keys in viewing-distance multiples)")
    from experiments._paths import MESH_SUFFIXES, check_output

    inputs = (("the input mesh", mesh_path), ("the input model", args.model))
    out = check_output("--out", args.out, suffixes=MESH_SUFFIXES, inputs=inputs) if args.out else None
    render_path = check_output("--render", args.render, suffixes=(".png",), inputs=inputs) if args.render else None
    render_size = None
    if render_path is not None:
        if render_path.suffix.lower() != ".png":
            raise PlodError(f"--render: the picture is written as PNG; use a .png path, got {str(render_path)!r}")
        wh = _vector("--render-size", args.render_size, 2)
        render_size = tuple(int(x) for x in wh)
        if (wh != np.round(wh)).any() or min(render_size) <= 0 or max(render_size) > 8192:  # 3.7 was taken as 3
            raise PlodError(f"--render-size must be two integers in 1..8192, got {args.render_size!r}")
    return budget, out, render_path, render_size


def _timed(t: dict, name: str, fn, *a, **kw):
    """``fn(*a, **kw)``, its seconds stored as ``t[name]``."""
    t0 = time.perf_counter()
    res = fn(*a, **kw)
    t[name] = time.perf_counter() - t0
    return res


def _cut(tree, keys, args, budget):
    import optim

    if args.imperceptible:
        from optim._cut import threshold_cut

        return threshold_cut(tree, keys, 1.0, monotone="trust")
    return optim.budget_cut(tree, keys, budget, monotone="trust")


def _render(path, size, tree, mesh, view, args, distance, mesh_path) -> dict:
    """Render original and simplified with their FLIP difference to ``path``; the ``render`` result."""
    from experiments import render as R

    comp = R.compare(tree, mesh, view, size=size, mode="baked" if view.lighting is None else "relit",
                     lighting=view.lighting)
    R.save_comparison(path, comp, protect=(mesh_path,), titles=(
        f"original: {tree.n_triangles:,} triangles",
        f"{args.metric} keys: {mesh[1].shape[0]:,} triangles (invisible beyond {distance:.3g}x)"))
    return {"path": str(path), "mean_flip": comp.mean_flip, "pixels_per_degree": comp.pixels_per_degree}


def simplify(args) -> dict:
    """Run the command; returns the result dictionary printed by ``--json``."""
    import optim

    mesh_path = Path(args.mesh)
    budget, out, render_path, render_size = _outputs(args, mesh_path)
    model = make_model(args.model)
    from experiments._paths import check_mesh_input

    check_mesh_input(mesh_path)
    _check_view_flags(args)
    margin = _number("--cull-back-faces", args.cull_back_faces, hi=90.0, strict=False)  # deg, or None
    if args.normals not in (*optim.NORMALS, "none"):
        raise PlodError(f"--normals must be region, faces or none, got {args.normals!r}")
    normals = None if args.normals == "none" else args.normals  # optim.extract's choice
    t = {}
    t0 = time.perf_counter()
    method = args.method if args.method != "auto" else ("hybrid" if args.light is not None else "meshopt")
    tree, cache, t["load"], unit_exp, ctx = tree_for_file(mesh_path, method, use_cache=not args.no_cache,
                                                          progress=not args.json)
    t["build"] = time.perf_counter() - t0 - t["load"]
    if out is not None:  # the format must hold the mesh's coordinates (float32 PLY: |x| < 3.4e38)
        from optim._mesh import check_writable

        check_writable(out, np.ldexp(tree.vertices, -unit_exp) if unit_exp else tree.vertices)
    view = build_view(tree.vertices, args, unit_exp)
    held = {n for n in optim.CONTEXT_NAMES if tree.has_derived(n)}  # read from the cache
    keys = _timed(t, "score", optim.score, tree, view, model, args.metric)
    built = {n for n in optim.CONTEXT_NAMES if tree.has_derived(n)} - held
    context = save_context_quietly(tree, ctx) if built else ("hit" if held else "off")
    mesh = None  # with --cull-back-faces and --budget, the search extracts the cut's mesh itself
    if margin is not None and budget is not None:
        vc = _timed(t, "cut", optim.visible_budget_cut, tree, keys, budget, view, margin_deg=margin, monotone="trust",
                    normals=normals or "faces")
        cut, mesh = vc.cut, vc.mesh
    else:
        cut = _timed(t, "cut", _cut, tree, keys, args, budget)
    if budget is not None and cut.triangles == 0:
        raise PlodError(f"--budget {budget} is below the smallest non-empty cut for this view "
                        f"({optim.min_nonempty_budget(tree, keys, monotone='trust')} triangles)")
    if mesh is None:
        mesh = _timed(t, "extract", optim.extract, tree, cut, normals)
        if margin is not None:
            mesh = _timed(t, "cull", optim.drop_back_faces, mesh, view, margin)
    from experiments.render import mesh_parts  # light: numpy only at import

    v2, f2, c2, n2 = mesh_parts(mesh)  # no normals with --normals none (unless --cull-back-faces)
    if margin is not None and len(f2) == 0:
        raise PlodError("every triangle of the cut faces away from the eye: nothing to write (check --eye)")
    if margin is not None:  # the dropped back faces' own vertices are not written (.ply kept them, .obj not)
        from optim._mesh import compact

        v2, f2, c2, n2 = compact(v2, f2, c2, n2)
    if unit_exp:
        v2 = np.ldexp(np.asarray(v2, np.float64), -unit_exp)  # back to the file's units, exactly
    flips = optim.cut_flips(tree, cut)
    if out is not None:
        _timed(t, "save", optim.save_mesh, out, v2, f2, c2, protect=(mesh_path,), normals=n2)
    perceptual = args.metric == "perceptual"
    # Whatever keys chose the cut, report the perceptual distance beyond which it is imperceptible
    # [LH01 §5.3]: the largest perceptual key among folded nodes (keys are monotone).
    pkeys = keys if perceptual else optim.score(tree, view, model, "perceptual")
    folded = ~cut.unfolded
    distance = float(pkeys[folded].max()) if folded.any() else 0.0
    rendered = None
    if render_path is not None:
        rendered = _timed(t, "render", _render, render_path, render_size, tree, (v2, f2, c2, n2), view, args,
                          distance, mesh_path)
    return {
        "mesh": str(mesh_path),
        "input_triangles": int(tree.n_triangles),
        "output_triangles": int(f2.shape[0]),
        "cut_triangles": int(cut.triangles),  # with --cull-back-faces: before the back faces were dropped
        "cull_back_faces_margin_deg": margin,
        # the vertex normals written with the mesh (.off and .stl hold none)
        "normals": "none" if n2 is None or (out is not None and out.suffix.lower() in (".off", ".stl"))
        else (normals or "faces"),
        "output_vertices": int(v2.shape[0]),
        "metric": args.metric,
        "model": type(model).__name__,
        "budget": budget,
        "imperceptible_distance": distance,
        "boundary_key": float(cut.distance),
        "boundary_key_units": "viewing-distance multiple" if perceptual else "pixels",
        "stop_reason": cut.stop_reason,
        "flipped_triangles": int(flips.flipped),
        "degenerate_triangles": int(flips.degenerate),
        "lighting": view.lighting.to_dict() if view.lighting is not None else "baked",
        "tree_method": method,  # --method auto resolved
        "tree_cache": cache,
        "context_cache": context,  # the first view's per-tree work: "hit" (read), "saved" or "off"
        "unit_exponent": unit_exp,  # the tree, view and keys used the mesh scaled by 2**unit_exponent
        "out": str(out) if out is not None else None,
        "render": rendered,
        "timings_ms": {k: round(v * 1e3, 3) for k, v in t.items()},
    }


def run(args) -> int:
    from experiments._interrupt import check

    res = simplify(args)
    check()  # a Ctrl-C that something swallowed: no result is reported (report_errors: status 130)
    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"plod simplify {res['mesh']}", show_header=False)
    table.add_column("quantity")
    table.add_column("value", justify="right")
    table.add_row("triangles", f"{res['input_triangles']:,} -> {res['output_triangles']:,}")
    table.add_row("metric / stop", f"{res['metric']} / {res['stop_reason']}")
    if res["flipped_triangles"] or res["degenerate_triangles"]:
        table.add_row("turned over / degenerate", f"{res['flipped_triangles']:,} / {res['degenerate_triangles']:,} triangles")
    table.add_row("imperceptible beyond", f"{res['imperceptible_distance']:.3g} x the viewing distance")
    if res["metric"] != "perceptual":
        table.add_row("boundary key", f"{res['boundary_key']:.3g} px")
    table.add_row("tree", f"{res['tree_method']} (cache {res['tree_cache']}, first-view context {res['context_cache']})")
    table.add_row("time (ms)", ", ".join(f"{k} {v:.1f}" for k, v in res["timings_ms"].items()))
    if res["out"]:
        table.add_row("written", res["out"])
    if res["render"]:
        table.add_row("rendered", f"{res['render']['path']} (mean FLIP {res['render']['mean_flip']:.4f})")
    Console().print(table)
    return 0

"""``plod judge``: how visible is the difference between an original mesh and a simplified one?

Both meshes are rendered for one view (the original framed at ``--object-deg`` of the viewer's visual
field, seen from ``--direction``) and the result is scored against the original by FovVideoVDP
[Man21] (JOD, 10 = indistinguishable; foveated at the gaze, ``--gaze-deg`` deg to the right of the
object's centre) and FLIP [And20] (mean error, 0 = identical); see ``experiments/judge.py``.
``--mode relit`` shades each mesh from its own normals per pixel (those its file carries, as ``plod
simplify`` writes them, else its faces'), ``baked`` draws the vertex colours or pre-lit intensities
plod's model assumes, ``both`` does both. ``--light DX,DY,DZ[,AMBIENT]``: the
direction towards the light in object space and the ambient term (diffuse = 1 - ambient; default the
``optim.Lighting`` default). Needs the ``judge`` extra (torch, pyfvvdp; FovVideoVDP is CC BY-NC 4.0).

Units: ``--object-deg`` and ``--gaze-deg`` deg of visual angle, ``--size`` pixels (default the view's
1920x1080 image; a smaller size keeps the angular content: pixels per degree scale with it).
"""

from __future__ import annotations

import json
import math

from pmetric import PlodError

MODES = ("relit", "baked")


def register(sub) -> None:
    p = sub.add_parser("judge", help="score a simplified mesh against the original: FovVideoVDP JOD and FLIP",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("original", help="reference mesh (PLY, OBJ, OFF, STL, GLB)")
    p.add_argument("result", help="mesh to judge against it, e.g. plod simplify's --out")
    p.add_argument("--mode", choices=(*MODES, "both"), default="relit",
                   help="relit: per-pixel shading from each mesh's own normals (default); baked: vertex "
                        "colours or pre-lit intensities; both")
    p.add_argument("--light", metavar="DX,DY,DZ[,AMBIENT]", default=None,
                   help="direction towards the light (object space) and ambient in [0, 1]; diffuse = 1 - ambient")
    p.add_argument("--object-deg", metavar="DEG", default="30",
                   help="angle the original's bounding sphere subtends, deg (default 30)")
    p.add_argument("--direction", metavar="X,Y,Z", default="0,0,1",
                   help="direction from the object's centre to the eye (default 0,0,1)")
    p.add_argument("--gaze-deg", metavar="E", default="0",
                   help="gaze E deg of visual angle to the right of the object's centre (default 0)")
    p.add_argument("--size", metavar="W,H", default=None,
                   help="rendering size in pixels (default the view's 1920,1080; px/deg scaled to it)")
    p.add_argument("--out", metavar="OUT.png", default=None,
                   help="write reference | result | FovVideoVDP map | FLIP map here (--mode both: "
                        "OUT-relit.png and OUT-baked.png)")
    p.add_argument("--json", metavar="OUT.json", default=None, help="write the results as JSON here")
    p.set_defaults(func=run)


def _floats(flag: str, text: str, counts: tuple[int, ...]) -> list[float]:
    """Comma-separated finite numbers, as many as one of ``counts``; else PlodError naming ``flag``."""
    try:
        vals = [float(s) for s in str(text).split(",")]
    except ValueError:
        vals = []
    if len(vals) not in counts or not all(math.isfinite(x) for x in vals):
        want = " or ".join(str(c) for c in counts)
        raise PlodError(f"{flag} needs {want} comma-separated finite numbers, got {text!r}")
    return vals


def _lighting(text):
    import optim

    return optim.Lighting() if text is None else optim.Lighting.from_text(text, "--light")


def _outputs(args) -> dict:
    """The PNG path per mode and the JSON path, checked before any work."""
    from experiments._paths import check_output

    inputs = (("the original mesh", args.original), ("the result mesh", args.result))
    modes = list(MODES) if args.mode == "both" else [args.mode]
    pngs = {}
    if args.out is not None:
        out = check_output("--out", args.out, suffixes=(".png",), inputs=inputs)
        for m in modes:
            path = out if len(modes) == 1 else out.with_name(f"{out.stem}-{m}{out.suffix}")
            pngs[m] = check_output("--out", path, suffixes=(".png",), inputs=inputs)
    js = check_output("--json", args.json, suffixes=(".json",), inputs=inputs) if args.json else None
    return {"modes": modes, "png": pngs, "json": js}


def judge_files(args) -> dict:
    """Run the command; returns the result dictionary written by ``--json``."""
    import optim
    from experiments import judge as J

    outs = _outputs(args)
    light = _lighting(args.light)
    object_deg = _floats("--object-deg", args.object_deg, (1,))[0]
    if not 0.01 <= object_deg < 180:
        raise PlodError(f"--object-deg must be in [0.01, 180) deg, got {args.object_deg!r}")
    direction = _floats("--direction", args.direction, (3,))
    if not any(direction):
        raise PlodError(f"--direction must be nonzero, got {args.direction!r}")
    gaze = _floats("--gaze-deg", args.gaze_deg, (1,))[0]
    if not -80 < gaze < 80:
        raise PlodError(f"--gaze-deg must be in (-80, 80) deg, got {args.gaze_deg!r}")
    size = None
    if args.size is not None:
        vals = _floats("--size", args.size, (2,))
        size = tuple(int(x) for x in vals)
        if any(x != int(x) or not 16 <= x <= 8192 for x in vals):  # FovVideoVDP fails below 4 pixels
            raise PlodError(f"--size must be two integers in 16..8192, got {args.size!r}")
    from experiments._paths import check_mesh_input

    meshes = {}
    for key in ("original", "result"):
        path = check_mesh_input(getattr(args, key))
        meshes[key] = optim.load_mesh(path, normals=True)  # relit: shaded from the file's normals if it has them
    # the view is framed on the original: one without extent (all vertices at one point) frames nothing
    optim.validate_mesh(*meshes["original"][:2], name=f"the original mesh {str(args.original)!r}",
                        count_nonmanifold=False)
    view = J.offset_gaze_view(meshes["original"][0], gaze, object_deg=object_deg, direction=direction)
    try:
        import pyfvvdp  # noqa: F401
        import torch  # noqa: F401
    except ImportError as exc:
        raise PlodError(f"plod judge needs torch and pyfvvdp: pip install '.[judge]' ({exc})") from None
    rows = []
    for mode in outs["modes"]:
        png = outs["png"].get(mode)
        try:  # FovVideoVDP's map only for the picture (it doubles the metric's time)
            res = J.judge(meshes["original"], meshes["result"], view, mode=mode, lighting=light, size=size,
                          heatmap=png is not None)
        except RuntimeError as exc:  # no OpenGL context: an environment problem, said in one line
            raise PlodError(str(exc)) from None
        if png is not None:
            J.save_judgement(png, res, protect=(args.original, args.result), titles=(
                f"original: {len(meshes['original'][1]):,} triangles",
                f"result: {len(meshes['result'][1]):,} triangles"))
        # a result wholly outside the original's frame (or behind the eye) renders as the empty image: its
        # score is that image's, which the table says rather than leaves to be guessed
        rows.append({"mode": mode, "jod": res.jod, "flip_mean": res.flip_mean, "seconds": round(res.seconds, 3),
                     "png": None if png is None else str(png), "result_drawn": bool(res.test.max() > res.test.min()),
                     "original_drawn": bool(res.reference.max() > res.reference.min())})
    h, w = res.reference.shape[:2]
    return {
        "original": str(args.original), "result": str(args.result),
        "triangles": {"original": int(len(meshes["original"][1])), "result": int(len(meshes["result"][1]))},
        # relit shading: the vertex normals the file carries ("file", e.g. plod simplify's), else its faces'
        "normals": {k: "faces" if m[3] is None else "file" for k, m in meshes.items()},
        "view": {"object_deg": object_deg, "direction": direction, "gaze_deg": gaze, "size": [w, h],
                 "fixation_px": list(res.fixation_px), "pixels_per_degree": res.pixels_per_degree},
        "lighting": light.to_dict(),
        "results": rows,
        "json": None if outs["json"] is None else str(outs["json"]),
    }


def run(args) -> int:
    res = judge_files(args)
    if res["json"] is not None:
        from pmetric import atomic_write_text

        atomic_write_text(res["json"], json.dumps(res, indent=2) + "\n", protect=(args.original, args.result))
    from rich.console import Console
    from rich.table import Table

    t = res["triangles"]
    table = Table(title=f"plod judge: {t['result']:,} vs {t['original']:,} triangles, "
                        f"gaze {res['view']['gaze_deg']:g} deg, {res['view']['pixels_per_degree']:.1f} px/deg")
    for col in ("mode", "JOD (10 = same)", "FLIP (0 = same)", "s", "picture"):
        table.add_column(col, justify="left" if col in ("mode", "picture") else "right")
    for r in res["results"]:
        table.add_row(r["mode"], f"{r['jod']:.3f}", f"{r['flip_mean']:.4f}", f"{r['seconds']:.1f}", r["png"] or "")
    console = Console()
    console.print(table)
    blank = [r["mode"] for r in res["results"] if not r["original_drawn"]]
    empty = [r["mode"] for r in res["results"] if not r["result_drawn"] and r["original_drawn"]]
    if blank:  # e.g. --object-deg below a pixel: the note below would blame the result
        console.print(f"note: the original draws nothing in this view ({', '.join(blank)}): it is under a pixel "
                      "or outside the frame (check --object-deg and --size), so two empty images are compared")
    if empty:
        console.print(f"note: the result draws nothing in this view ({', '.join(empty)}): it lies wholly outside "
                      "the original's frame or behind the eye, so it is scored as the empty image")
    return 0

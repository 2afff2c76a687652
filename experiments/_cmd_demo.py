"""``plod demo``: the main job on built-in defaults, with no input files.

1. Thresholds: the threshold contrast of every CSF model at a few spatial frequencies for the default
   display and viewer, the display's highest frequency xi, and the viewing-distance multiple beyond
   which a 0.5-degree, 10%-contrast change stops being visible.
2. Simplification: a procedural mesh (no ``../shared`` needed) viewed as in the study of [LH01 §6.2] (the
   object spans about 30 degrees of a 46-degree screen), simplified imperceptibly and to a triangle
   budget with perceptual and size keys.
"""

from __future__ import annotations

import json
import time

from pmetric import PlodError

FREQS = (1.0, 4.0, 16.0, 32.0)  # cycles/deg


def register(sub) -> None:
    p = sub.add_parser("demo", help="run the main job on built-in defaults (no input files needed)",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("--subdivisions", type=int, default=6,
                   help="icosphere subdivisions of the procedural demo mesh (6: 81,920 triangles)")
    p.add_argument("--budget-fraction", type=float, default=0.1,
                   help="triangle budget as a fraction of the input (default 0.1)")
    p.add_argument("--json", action="store_true", help="print the results as JSON instead of tables")
    p.set_defaults(func=run)


def _models():
    import pmetric as pm

    return {
        "Manos-Sakrison": pm.ManosSakrison(),
        "Kelly abstract": pm.KellyAbstract(),
        "Kelly-Reddy, 0.1 deg/s": pm.KellySpatioTemporal(constants="reddy"),
        "M-S + Rovamo-Virsu, 10 deg": pm.Eccentric(pm.ManosSakrison(), pm.RovamoVirsu()),
        "Barten, 100 cd/m2": pm.Barten(),
        "stelaCSF, 100 cd/m2": pm.StelaCSF(),
    }


def thresholds_table() -> dict:
    """Thresholds for the default display: ``{model: {"c_T": [...], "peak": f, "k": k}}``."""
    import jax.numpy as jnp

    f = jnp.asarray(FREQS)
    out = {}
    for name, m in _models().items():
        e = 10.0 if name.endswith("10 deg") else 0.0
        out[name] = {
            "threshold_contrast": [float(x) for x in m.threshold_contrast(f, e)],
            "peak_frequency": float(m.peak_frequency(e)),
            "imperceptible_distance": float(m.imperceptible_distance(0.1, 0.5, e)),
        }
    return out


def simplification(subdivisions: int, budget_fraction: float) -> dict:
    """Imperceptible and budget cuts of a procedural bumpy sphere for the default view of [LH01 §6.2].

    Every cut is also judged by the perceptual keys: its ``distance`` is the viewing-distance multiple
    beyond which it is imperceptible [LH01 §5.3], whatever keys chose it, so the size-keyed
    cut (VDSlib's default) and the perceptual one can be compared at the same triangle count.
    """
    import optim
    import pmetric

    vertices, faces, colors = optim.bumpy_sphere(subdivisions, seed=0, colors=True)
    t0 = time.perf_counter()
    tree = optim.build_tree(vertices, faces, colors=colors)
    build_ms = 1e3 * (time.perf_counter() - t0)
    view = optim.View.framing(vertices)
    model = pmetric.default_model()
    perceptual = optim.score(tree, view, model, metric="perceptual")
    budget = int(budget_fraction * len(faces))
    cuts = {
        f"budget {budget:,}, perceptual keys": optim.budget_cut(tree, perceptual, budget),
        f"budget {budget:,}, size keys": optim.budget_cut(tree, optim.score(tree, view, metric="size"), budget),
        "imperceptible": optim.imperceptible_cut(tree, view, model),
    }
    rows = {}
    for name, cut in cuts.items():
        folded = ~cut.unfolded
        distance = float(perceptual[folded].max()) if folded.any() else 0.0
        rows[name] = {"triangles": int(cut.triangles), "distance": distance, "stop_reason": cut.stop_reason}
    return {"input_triangles": int(len(faces)), "build_ms": build_ms, "model": type(model).__name__,
            "cuts": rows}


def run(args) -> int:
    if args.subdivisions < 1 or args.subdivisions > 9:
        raise PlodError("--subdivisions must be between 1 and 9")
    if not 0.0 < args.budget_fraction <= 1.0:
        raise PlodError("--budget-fraction must be in (0, 1]")
    import pmetric as pm

    display = pm.Display.default()
    result = {
        "display": {"field_of_view_deg": [float(x) for x in display.field_of_view],
                    "xi_cycles_per_deg": float(display.xi), "distance_m": float(display.distance)},
        "thresholds": thresholds_table(),
    }
    try:
        import optim

        have_optim = all(hasattr(optim, n) for n in ("View", "score", "imperceptible_cut", "bumpy_sphere"))
    except ImportError:  # pragma: no cover
        have_optim = False
    if have_optim:
        result["simplification"] = simplification(args.subdivisions, args.budget_fraction)
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    _print_tables(result)
    return 0


def _print_tables(result: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    con = Console()
    d = result["display"]
    con.print(f"[bold]Default display[/]: {d['field_of_view_deg'][0]:.0f} x {d['field_of_view_deg'][1]:.1f} deg "
              f"at {d['distance_m']:.2f} m; highest displayable frequency xi = {d['xi_cycles_per_deg']:.1f} cycles/deg")
    t = Table(title="Threshold contrast (Michelson) by spatial frequency; fovea, static, unless stated")
    t.add_column("model")
    for f in FREQS:
        t.add_column(f"{f:g} c/deg", justify="right")
    t.add_column("peak", justify="right")
    t.add_column("k", justify="right")
    for name, row in result["thresholds"].items():
        t.add_row(name, *[f"{x:.4f}" if x < 1 else "invisible" for x in row["threshold_contrast"]],
                  f"{row['peak_frequency']:.1f}",
                  f"{row['imperceptible_distance']:.1f}")
    con.print(t)
    con.print("peak: frequency of peak sensitivity (cycles/deg). k: the viewing-distance multiple beyond which "
              "a 0.5-degree change of contrast 0.1 is invisible.")
    s = result.get("simplification")
    if s:
        t = Table(title=f"Simplifying a procedural mesh of {s['input_triangles']:,} triangles "
                        f"(hierarchy built in {s['build_ms']:.0f} ms; model {s['model']})")
        for col in ("cut", "triangles", "invisible beyond (x distance)", "stop"):
            t.add_column(col, justify="left" if col in ("cut", "stop") else "right")
        for name, c in s["cuts"].items():
            t.add_row(name, f"{c['triangles']:,}", f"{c['distance']:.2f}", c["stop_reason"])
        con.print(t)

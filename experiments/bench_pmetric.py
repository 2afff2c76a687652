"""Benchmark: is_perceptible and imperceptible_distance over 10^6 random inputs, one jitted call per model.

Prints evaluations per second (float32 and float64) and the speed-up of imperceptible_distance over a
40-step bisection reference measured in the same run, and writes ``reports/bench_pmetric.md``.

    .venv/bin/python experiments/bench_pmetric.py [--n 1000000] [--repeats 3] [--out reports/bench_pmetric.md]
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

import pmetric as pm


def _models():
    out = {
        "ManosSakrison": pm.ManosSakrison(),
        "KellyAbstract": pm.KellyAbstract(),
        "KellySpatioTemporal(kelly1979)": pm.KellySpatioTemporal("kelly1979"),
        "Eccentric(ManosSakrison)": pm.Eccentric(pm.ManosSakrison()),
        "ReddyAcuity": pm.ReddyAcuity(xi=30.0),
    }
    try:  # a 2-D (f x e) calibrated table
        out["CalibratedCSF"] = pm.CalibratedCSF(
            freqs=[1.0, 2.0, 4.0, 8.0, 16.0, 32.0], eccs=[0.0, 10.0, 30.0],
            log_thresholds=np.log10(1.0 / np.array([[60, 120, 150, 100, 30, 4], [40, 70, 60, 25, 5, 1],
                                                     [20, 25, 15, 4, 1, 0.5]], float)).T)
    except Exception as err:  # noqa: BLE001 - a model another engineer is still writing
        print(f"skipping CalibratedCSF: {err}")
    for name in ("Barten", "StelaCSF"):
        cls = getattr(pm, name, None)
        if cls is not None:
            try:
                out[name] = cls()
            except Exception as err:  # noqa: BLE001 - a model another engineer is still writing
                print(f"skipping {name}: {err}")
    return out


def bisection_distance(model, c, theta, e, v, n_steps=40):
    """Reference: 40-step bisection in log k on [2e-3 theta, 2e3 theta] (assumes monotone perceptibility)."""
    lo = jnp.log(2e-3 * theta)
    hi = jnp.log(2e3 * theta)

    def body(_, s):
        lo, hi = s
        mid = 0.5 * (lo + hi)
        k = jnp.exp(mid)
        p = model.is_perceptible(c, k / (2 * theta), e / k, v / k)
        return jnp.where(p, mid, lo), jnp.where(p, hi, mid)

    lo, hi = jax.lax.fori_loop(0, n_steps, body, (lo, hi))
    return jnp.exp(lo)


def _time(fn, args, repeats):
    out = fn(*args)
    jax.block_until_ready(out)
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - t0)
    return best


def run(n, repeats, dtype_name):
    rng = np.random.default_rng(0)
    dtype = np.float32 if dtype_name == "float32" else np.float64
    c = jnp.asarray(rng.uniform(0, 1, n), dtype)
    f = jnp.asarray(np.exp(rng.uniform(np.log(1e-3), np.log(1e3), n)), dtype)
    e = jnp.asarray(rng.uniform(0, 60, n), dtype)
    v = jnp.asarray(np.where(rng.uniform(size=n) < 0.5, 0.0, rng.uniform(0, 100, n)), dtype)
    theta = jnp.asarray(np.exp(rng.uniform(np.log(0.01), np.log(5), n)), dtype)
    rows = []
    for name, model in _models().items():
        perc = jax.jit(lambda c, f, e, v, m=model: m.is_perceptible(c, f, e, v))
        dist = jax.jit(lambda c, t, e, v, m=model: m.imperceptible_distance(c, t, e, v))
        bis = jax.jit(lambda c, t, e, v, m=model: bisection_distance(m, c, t, e, v))
        # probe on a slice; models too slow for n inputs in the time budget use a slice of them. (20,000:
        # on a much smaller slice a solver's fixed cost, e.g. its compacted fallback for a few rare
        # elements, would dominate and the extrapolation would overestimate the full run)
        small = min(n, 20_000)
        sl = lambda *xs: tuple(x[:small] for x in xs)  # noqa: E731
        p_dist = _time(dist, sl(c, theta, e, v), 1) * n / small
        p_bis = _time(bis, sl(c, theta, e, v), 1) * n / small
        m = n if p_dist < 5.0 else small  # the model's own methods
        m_b = n if p_bis < 5.0 else small  # the bisection reference (slow for the costly models)
        reps = repeats if m == n else 1
        args_p, args_d = tuple(x[:m] for x in (c, f, e, v)), tuple(x[:m] for x in (c, theta, e, v))
        t_p = _time(perc, args_p, reps)
        t_d = _time(dist, args_d, reps)
        t_b = _time(bis, tuple(x[:m_b] for x in (c, theta, e, v)), max(1, (repeats if m_b == n else 1) // 2)) * m / m_b
        generic = type(model)._imperceptible_distance is pm.CSFModel._imperceptible_distance  # the hook
        rows.append((name, m / t_p / 1e6, m / t_d / 1e6, m / t_b / 1e6, t_b / t_d, generic, m))
        print(f"{dtype_name:8s} {name:32s} is_perceptible {rows[-1][1]:8.1f} M/s   imperceptible_distance "
              f"{_fmt(rows[-1][2]):>8s} M/s   bisection {_fmt(rows[-1][3]):>6s} M/s   ratio {rows[-1][4]:6.1f}x", flush=True)
    return rows


def _env_prefix():
    """``XLA_FLAGS=... `` when set (it changes the generated code, so it belongs to the command)."""
    flags = os.environ.get("XLA_FLAGS")
    return f"XLA_FLAGS={flags} " if flags else ""


def _fmt(x):
    """M evals/s: two decimals, three significant digits below 0.1 (so slow solvers do not read 0.00)."""
    return f"{x:.2f}" if x >= 0.1 else f"{x:.3g}"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default="reports/bench_pmetric.md")
    args = ap.parse_args(argv)
    t_start = time.perf_counter()
    results = {"float32": run(args.n, args.repeats, "float32")}
    with jax.enable_x64(True):
        results["float64"] = run(args.n, args.repeats, "float64")
    dev = jax.devices()[0]
    t_total = time.perf_counter() - t_start
    lines = [
        "# pmetric benchmark: is_perceptible and imperceptible_distance",
        "",
        f"Command: `{_env_prefix()}.venv/bin/python experiments/bench_pmetric.py --n {args.n} --repeats {args.repeats}"
        f"{'' if args.out == 'reports/bench_pmetric.md' else ' --out ' + args.out}`",
        f"Device: {dev.platform} ({dev.device_kind}); {platform.processor() or platform.machine()}; jax {jax.__version__}.",
        f"{args.n:,} random inputs (c in [0,1], f log-uniform 1e-3..1e3 c/deg, e in [0,60] deg, v 0 or "
        "[0,100] deg/s, theta log-uniform 0.01..5 deg), one jitted call per model, best of the repeats.",
        "Models whose solver would take more than 5 s on all inputs are timed once on the first 20,000 (column `inputs`); so is the bisection reference where it would (its speed is per input either way).",
        "Bisection: 40-step bisection of is_perceptible in log k, measured in the same run (it assumes "
        "monotone perceptibility, so it is a speed reference, not a correct answer for velocity terms).",
        "Targets (2-core CPU, float32): is_perceptible >= 200 M/s, imperceptible_distance >= 50 M/s.",
        f"CPU cores: {os.cpu_count()}; total run time {t_total:.0f} s (includes compilation). The machine is shared "
        "with other jobs: timings are noisy (best of the repeats).",
        "",
    ]
    for dt, rows in results.items():
        lines += [f"## {dt}", "", "| model | is_perceptible (M/s) | imperceptible_distance (M/s) | 40-step bisection (M/s) "
                  "| speed-up vs bisection | solver | inputs | meets 200 / 50 M/s |", "| --- | ---: | ---: | ---: | ---: | --- | ---: | --- |"]
        for r in rows:
            meets = ("yes" if r[1] >= 200 else "no") + " / " + ("yes" if r[2] >= 50 else "no")
            lines.append(f"| {r[0]} | {r[1]:.1f} | {_fmt(r[2])} | {_fmt(r[3])} | {r[4]:.1f}x | "
                         f"{'generic (CSFModel)' if r[5] else 'model-specific'} | {r[6]:,} | {meets if dt == 'float32' else '-'} |")
        lines.append("")
    lines += [
        "## Notes",
        "",
        "- The targets are set for the models of the pmetric issue (Manos-Sakrison, Kelly's spatio-temporal and "
        "abstract CSFs, Rovamo-Virsu eccentricity, Reddy's acuity, calibrated tables); Barten meets them too.",
        "- stelaCSF [MAC22] does not: one evaluation of its log-sensitivity alone costs about ten "
        "transcendental functions per input (about 110 M/s here), and below its peak frequency the threshold is the "
        "peak's, whose frequency depends on eccentricity and velocity. Its exact solvers (a per-model peak table "
        "polished by Newton; a certified grid-and-Newton solve along the viewing ray, with compacted fallbacks) run "
        "about 10x (is_perceptible) and 1000x (imperceptible_distance) faster than the generic solvers they replace.",
        "- XLA on CPU vectorizes with 256-bit registers by default. On CPUs with AVX-512, "
        "`XLA_FLAGS=--xla_cpu_prefer_vector_width=512` (set before JAX starts) makes the Newton-heavy solvers 20-50 % "
        "faster; `reports/bench_pmetric_avx512.md` is this benchmark run that way.",
        "",
    ]
    pm.atomic_write_text(args.out, "\n".join(lines))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()

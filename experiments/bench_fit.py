"""Benchmark: least-squares fits (optimistix vs jaxopt) and emcee sampling of CSF constants.

    .venv/bin/python experiments/bench_fit.py [--repeats 7] [--nsteps 2000] [--out reports/bench_fit.md]

The report checks the issue's targets ``TARGET_LM_MS`` (Levenberg-Marquardt on 800 rows and 5-10
constants, per fit after compilation) and ``TARGET_MCMC_S`` (emcee, 32 walkers x 2000 steps). Data: 800
thresholds simulated from
``pmetric.Barten`` (luminance 0.1-1000 cd/m2, area 0.1-100 deg2, 0.5-30 cycles/deg, 0.05 log10 noise);
8 of its constants are fitted from a start 20-40 % away. MCMC: ``KellyAbstract`` (2 constants + noise)
and ``Barten`` (8 constants + noise) on the same kind of data. Prints the jaxopt / optimistix time
ratio measured in this run and writes the Markdown report itself (with the git SHA and versions).
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:  # pragma: no cover
    sys.path.insert(0, str(ROOT))

from optim.fit import SOLVERS  # noqa: E402

TARGET_LM_MS = 20.0  # ms per least-squares fit after compilation
TARGET_MCMC_S = 10.0  # s per emcee run of 32 walkers x 2000 steps
BARTEN_FIT = ["sigma_0", "k", "t", "x_max", "n_max", "eta", "phi_0", "u_0"]


def simulate_barten(n=800, seed=0, noise=0.05):
    import jax

    import pmetric
    from optim.fit import CalibrationData

    rng = np.random.default_rng(seed)
    f = 10 ** rng.uniform(np.log10(0.5), np.log10(30), n)
    lum = 10 ** rng.uniform(-1, 3, n)
    area = 10 ** rng.uniform(-1, 2, n)
    true = pmetric.Barten()
    with jax.enable_x64(True):
        ls = np.log10(np.asarray(true.stimulus_sensitivity(f, 0.0, 0.0, luminance=lum, area=area), np.float64))
    ls += noise * rng.standard_normal(n)
    data = CalibrationData.from_arrays(f, log_threshold=-ls, luminance=lum, area=area, dataset="sim")
    start = pmetric.Barten(sigma_0=true.sigma_0 * 1.3, k=true.k * 0.8, t=true.t * 1.2, x_max=true.x_max * 1.4,
                           n_max=true.n_max * 0.7, eta=true.eta * 1.25, phi_0=true.phi_0 * 0.75, u_0=true.u_0 * 1.3)
    return data, start, true


def simulate_kelly(n=800, seed=0, noise=0.05):
    import jax

    import pmetric
    from optim.fit import CalibrationData

    rng = np.random.default_rng(seed)
    f = 10 ** rng.uniform(np.log10(0.5), np.log10(16), n)
    e = rng.uniform(0, 5, n)
    true = pmetric.KellyAbstract()
    with jax.enable_x64(True):
        ls = np.log10(np.asarray(true.stimulus_sensitivity(f, e), np.float64)) + noise * rng.standard_normal(n)
    data = CalibrationData.from_arrays(f, log_threshold=-ls, e=e, luminance=50.0, area=4.0, dataset="sim")
    return data, pmetric.KellyAbstract(delta=float(true.delta) * 0.5, f0=float(true.f0) * 1.5)


def time_fit(model, data, repeats, **kw):
    import optim

    t0 = time.perf_counter()
    res = optim.fit_least_squares(model, data, **kw)
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = optim.fit_least_squares(model, data, **kw)
        times.append(time.perf_counter() - t0)
    return res, first, float(np.median(times)), float(np.min(times))


def bench_least_squares(data, start, true, repeats, con):
    """Time every solver x backend on the Barten problem: (table rows, {(solver, backend): (res, median s)})."""
    rows = []
    results = {}
    for solver in SOLVERS:
        for backend in ("optimistix", "jaxopt"):
            con.print(f"LSQ {solver} / {backend} ...")
            res, first, med, best = time_fit(start, data, repeats, solver=solver, backend=backend, fit=BARTEN_FIT)
            results[(solver, backend)] = (res, med)
            err = max(abs(float(getattr(res.model, k)) / float(getattr(true, k)) - 1) for k in BARTEN_FIT)
            rows.append([solver, backend, f"{first:.2f}", f"{1e3 * med:.1f}", f"{1e3 * best:.1f}", res.steps,
                         res.result, f"{res.rmse_db:.3f}", f"{100 * err:.1f}"])
            con.print(f"  compile+first {first:.2f} s, median {1e3 * med:.1f} ms, {res.steps} steps, {res.result}, "
                      f"RMSE {res.rmse_db:.3f} dB, worst constant error {100 * err:.1f} %")
    return rows, results


def bench_mcmc(args, data, start, con):
    """Time emcee on KellyAbstract and Barten (after a short warm-up run each): table rows."""
    import optim

    mrows = []
    for label, (d, m) in {"KellyAbstract (2 + sigma)": simulate_kelly(seed=args.seed),
                          "Barten (8 + sigma)": (data, start)}.items():
        fit = BARTEN_FIT if label.startswith("Barten") else None
        con.print(f"MCMC {label} {args.nwalkers} x {args.nsteps} (warm-up run for compilation) ...")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", optim.ChainTooShortWarning)
            optim.fit_mcmc(m, d, nwalkers=args.nwalkers, nsteps=20, fit=fit, seed=args.seed)
            t0 = time.perf_counter()
            post = optim.fit_mcmc(m, d, nwalkers=args.nwalkers, nsteps=args.nsteps, fit=fit, seed=args.seed)
            dt = time.perf_counter() - t0
        mrows.append([label, args.nwalkers, args.nsteps, f"{dt:.2f}", f"{post.acceptance_fraction:.2f}",
                      f"{np.max(post.tau):.1f}", "yes" if post.converged else "no"])
        con.print(f"  {dt:.2f} s, acceptance {post.acceptance_fraction:.2f}, max tau {np.max(post.tau):.1f}")
    return mrows


def _met(ok: bool) -> str:
    return "met" if ok else "NOT met"


def report(args, rows, results, mrows) -> list[str]:
    """The Markdown report (lines)."""
    from experiments._runinfo import git_sha, versions

    ratios = {s: results[(s, "jaxopt")][1] / results[(s, "optimistix")][1] for s in SOLVERS}
    both = [s for s in SOLVERS if results[(s, "jaxopt")][0].success and results[(s, "optimistix")][0].success]
    agree = max((float(np.max(np.abs(results[(s, "jaxopt")][0].values / results[(s, "optimistix")][0].values - 1)))
                 for s in both), default=float("nan"))
    lm_ms = 1e3 * results[("lm", "optimistix")][1]
    lm_jx = 1e3 * results[("lm", "jaxopt")][1]
    mc_s = float(mrows[0][3])
    v = versions()
    return [
        "# bench_fit: fitting CSF constants", "",
        f"Command: `.venv/bin/python experiments/bench_fit.py --repeats {args.repeats} --nsteps {args.nsteps}` "
        f"(seed {args.seed}); git {git_sha()}; jax {v.get('jax')}, optimistix {v.get('optimistix')}, "
        f"jaxopt {v.get('jaxopt')}, emcee {v.get('emcee')}, numpy {v.get('numpy')}; {v.get('devices', '')}; "
        f"{v.get('platform')}.", "",
        "## Least squares: Barten, 800 simulated rows, 8 constants (float64)", "",
        "| solver | backend | compile + first fit (s) | median fit (ms) | best fit (ms) | steps | result | RMSE (dB) | worst constant error (%) |",
        "| --- | --- | ---: | ---: | ---: | ---: | --- | ---: | ---: |",
        *["| " + " | ".join(str(c) for c in r) + " |" for r in rows], "",
        "Time ratio jaxopt / optimistix measured in this run: "
        + ", ".join(f"{s} {r:.2f}" for s, r in ratios.items())
        + f". Largest relative difference between the backends' constants where both succeeded ({', '.join(both)}): "
        f"{agree:.1e}. The worst constant error is large because Barten's constants trade off against each other "
        "(the fit's RMSE equals the simulated noise, 0.05 log10 = 1.0 dB); undamped Gauss-Newton (optimistix) "
        "overshoots from this start and reports it.", "",
        f"Target LM <= {TARGET_LM_MS:g} ms per fit after compilation: optimistix {lm_ms:.1f} ms "
        f"({_met(lm_ms <= TARGET_LM_MS)}), jaxopt {lm_jx:.1f} ms ({_met(lm_jx <= TARGET_LM_MS)}). "
        "(A fit includes the covariance: Jacobian and pseudo-inverse at the optimum.)", "",
        "## emcee (vectorised, jitted log-probability)", "",
        "| model (constants) | walkers | steps | time (s) | acceptance | max tau (steps) | nsteps >= 50 tau |",
        "| --- | ---: | ---: | ---: | ---: | ---: | --- |",
        *["| " + " | ".join(str(c) for c in r) + " |" for r in mrows], "",
        f"Target emcee 32 x 2000 <= {TARGET_MCMC_S:g} s: {mc_s:.2f} s for KellyAbstract "
        f"({_met(mc_s <= TARGET_MCMC_S)}); Barten {mrows[1][3]} s. Times include the least-squares start and the "
        "autocorrelation estimate.", "",
    ]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--nsteps", type=int, default=2000)
    ap.add_argument("--nwalkers", type=int, default=32)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(ROOT / "reports" / "bench_fit.md"))
    args = ap.parse_args(argv)
    warnings.filterwarnings("ignore", message=".*JAXopt is no longer maintained.*", category=DeprecationWarning)
    from rich.console import Console

    from pmetric import atomic_write_text

    con = Console(stderr=True)
    data, start, true = simulate_barten(seed=args.seed)
    rows, results = bench_least_squares(data, start, true, args.repeats, con)
    for s in SOLVERS:
        con.print(f"jaxopt / optimistix time ratio ({s}): "
                  f"{results[(s, 'jaxopt')][1] / results[(s, 'optimistix')][1]:.2f}")
    mrows = bench_mcmc(args, data, start, con)
    atomic_write_text(args.out, "\n".join(report(args, rows, results, mrows)))
    con.print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    from experiments._runinfo import run_script

    run_script(main)

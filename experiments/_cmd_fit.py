"""``plod fit DATA.csv --model NAME``: fit a CSF model's constants to measured thresholds.

Least squares (Levenberg-Marquardt by default; ``--solver`` / ``--backend`` choose others) or emcee
(``--method mcmc``). ``--out fitted.json`` stores the fitted model (``pmetric.save_model``), which
``pmetric.load_model`` and ``plod simplify --model fitted.json`` read back. With ``--method mcmc`` the
stored model is the posterior median, or with ``--conservative Q`` the model whose thresholds sit at
the lower Q quantile of the posterior predictive (what imperceptible simplification should use).

Cross-validation (``optim.fit.cross_validate``): ``--cv dataset`` leaves one dataset out at a time,
``--cv K`` uses K folds from ``--seed``; it prints the training and held-out RMSE (dB) per dataset and
overall (a rich table, or ``--json``). Regularisation: ``--prior none`` (the default: the plain
least-squares fit, as before), ``--prior STRENGTH`` / ``--prior-strength STRENGTH`` (lambda >= 0 of the
Gaussian prior toward the starting model's constants, the published values for a model given by name)
or ``--prior cv`` (lambda chosen from ``optim.fit.PRIOR_GRID`` by held-out RMSE; the folds are those of
``--cv``, or leave-one-dataset-out when the data has several datasets and 5-fold otherwise). The same
prior is the MCMC prior with ``--method mcmc``. ``--out`` with ``--cv`` stores the fit of every row
at the (chosen) strength.
"""

from __future__ import annotations

import json
import math
import sys
import warnings
from pathlib import Path

from experiments._paths import check_output, model_files
from pmetric import PlodError, make_model

# emcee's autocorrelation estimate needs >= 3 kept steps per walker (nsteps 1, 2: NaN, cryptic error)
MIN_MCMC_STEPS = 3


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "fit",
        help="fit a CSF model to contrast thresholds (CSV)",
        description="Fit the constants of a pmetric CSF model to contrast-threshold data (CSV as in "
                    "../shared/data/csf: s_frequency, log_cone_contrast or sensitivity, optional "
                    "t_frequency, eccentricity, luminance, area, dataset).",
    )
    p.add_argument("data", help="CSV of thresholds")
    p.add_argument("--model", required=True, metavar="NAME|FILE.json",
                   help="model to fit: a name (case-insensitive, see plod models: stela, barten, kellyabstract, "
                        "eccentric(manossakrison), ...) or a saved model .json to start from")
    p.add_argument("--method", choices=["lm", "mcmc"], default="lm", help="least squares (lm) or emcee (mcmc)")
    p.add_argument("--solver", choices=["lm", "gauss-newton", "bfgs"], default="lm",
                   help="least-squares solver (--method lm)")
    p.add_argument("--backend", choices=["optimistix", "jaxopt"], default="optimistix")
    p.add_argument("--multipliers", action="store_true", help="one free sensitivity multiplier per dataset")
    p.add_argument("--fit", default=None, help="comma-separated fields to fit (default: all)")
    p.add_argument("--all-rows", action="store_true",
                   help="fit every row, not only those the model can express (see optim.expressible_rows)")
    p.add_argument("--nwalkers", type=int, default=32, help="MCMC walkers")
    p.add_argument("--nsteps", type=int, default=2000, help="MCMC steps per walker")
    p.add_argument("--seed", type=int, default=0, help="MCMC seed; the folds of --cv K")
    p.add_argument("--cv", default=None, metavar="dataset|K",
                   help="cross-validate: leave one dataset out (dataset) or K folds (from --seed); prints "
                        "training and held-out RMSE per dataset")
    p.add_argument("--prior", default=None, metavar="none|cv|STRENGTH",
                   help="Gaussian prior toward the starting (published) constants: none (default), a strength "
                        "lambda >= 0, or cv (lambda chosen by held-out error)")
    p.add_argument("--prior-strength", default=None, metavar="LAMBDA", help="the same as --prior LAMBDA")
    p.add_argument("--conservative", type=float, default=None, metavar="Q",
                   help="with --method mcmc: save the model at the lower Q quantile of thresholds (e.g. 0.95)")
    p.add_argument("--out", default=None, help="write the fitted model here (JSON)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    import optim
    import pmetric

    if args.conservative is not None and not 0 < args.conservative < 1:
        raise PlodError(f"--conservative must be in (0, 1), got {args.conservative}")
    if args.conservative is not None and args.method != "mcmc":
        raise PlodError("--conservative needs --method mcmc")
    data_path = Path(args.data)
    if args.out is not None:
        check_output("--out", args.out, suffixes=(".json",),
                     inputs=(("the input data", data_path), *(("the input model", m) for m in model_files(args.model))))
    if args.method == "mcmc":
        if args.nsteps < MIN_MCMC_STEPS:
            raise PlodError(f"--nsteps must be >= {MIN_MCMC_STEPS} for --method mcmc (the sampler needs "
                            f"{MIN_MCMC_STEPS} steps per walker to estimate the autocorrelation time), got {args.nsteps}")
        if args.nwalkers < 1:
            raise PlodError(f"--nwalkers must be >= 1, got {args.nwalkers}")
    if args.seed < 0:
        raise PlodError(f"--seed must be >= 0, got {args.seed}")
    prior_kind, lam = _parse_prior(args.prior, args.prior_strength)
    if args.cv is not None:
        if args.method != "lm":
            raise PlodError("--cv cross-validates least-squares fits; it cannot be combined with --method mcmc")
        optim.fit._cv.parse_cv(args.cv, arg="--cv")  # a bad --cv is refused before any work
    data = optim.fit.CalibrationData.from_csv(data_path)
    model = make_model(args.model)
    fit = [s.strip() for s in args.fit.split(",") if s.strip()] if args.fit else None
    rows = None if args.all_rows else "auto"
    from optim.fit._problem import Problem

    optim.fitted_fields(model, fit, arg="--fit")  # unknown or empty --fit names, by the flag's name
    # host-side layout only; the row count is checked below, naming the flags
    prob = Problem(model, data, fit=fit, multipliers=args.multipliers, rows=rows, min_rows=False)
    n_in, n_used, n_free = len(data), int(prob.mask.sum()), int(prob.static.n_free)
    n_f0 = int(((np.asarray(data.f) == 0) & ~prob.mask).sum())
    dropped = (f"used {n_used} of {n_in} rows: dropped {n_in - n_used} the model cannot express"
               + (f" ({n_f0} with s_frequency 0)" if n_f0 else "")
               + f"; rules: {'; '.join(prob.reasons)} (--all-rows keeps them)") if n_used < n_in else None
    if n_used < n_free + 1:
        raise PlodError(f"{n_used} usable data rows (of {n_in}) cannot fit {n_free} free constants with any "
                        f"uncertainty: need at least {n_free + 1} rows; give more data or fewer --fit fields")
    report: dict = {"model": type(model).__name__, "data": str(data_path), "method": args.method,
                    "n_input_rows": n_in, "n_dropped_rows": n_in - n_used, "n_dropped_zero_frequency": n_f0,
                    "dropped_rows": dropped}
    from experiments._progress import call_with_progress

    kw = dict(multipliers=args.multipliers, fit=fit, rows=rows)
    cv_res = None
    if prior_kind == "cv":
        n_sets = len(data.subset(prob.mask).datasets)
        cv_spec = args.cv if args.cv is not None else ("dataset" if n_sets >= 2 else 5)
        lam, grid = call_with_progress(optim.fit.select_prior_strength, model, data, cv=cv_spec, seed=args.seed,
                                       solver=args.solver, backend=args.backend, progress=not args.json,
                                       description="prior strength by cross-validation", **kw)
        report["prior_cv"] = {"cv": str(cv_spec), "held_out_rmse_db": {f"{g:g}": r.test_rmse_db for g, r in grid.items()},
                              "chosen": lam}
        cv_res = grid[lam] if args.cv is not None else None
    elif args.cv is not None:
        cv_res = call_with_progress(optim.fit.cross_validate, model, data, cv=args.cv, seed=args.seed,
                                    prior_strength=lam, solver=args.solver, backend=args.backend,
                                    progress=not args.json, description="cross-validation", **kw)
    report["prior"] = prior_kind
    report["prior_strength"] = lam
    if cv_res is not None:
        report["cv"] = cv_res.to_dict()
        fitted = None
        if args.out is not None:  # the fit of every row at the (chosen) strength
            fitted = optim.fit_least_squares(model, data, solver=args.solver, backend=args.backend,
                                             prior_strength=lam, **kw).model
        text = None
    elif args.method == "lm":
        res = optim.fit_least_squares(model, data, solver=args.solver, backend=args.backend,
                                      multipliers=args.multipliers, fit=fit, rows=rows, prior_strength=lam)
        fitted = res.model
        report.update(
            solver=res.solver, backend=res.backend, result=res.result, steps=res.steps, n_rows=res.n_rows,
            row_rules=res.row_rules, rmse_db=res.rmse_db, rmse_log10=res.rmse_log10,
            rmse_per_dataset_db=res.rmse_per_dataset, multipliers=res.multipliers,
            identifiable=res.identifiable,
            params={n: {"value": float(v), "stderr": float(s) if np.isfinite(s) else None}  # null: not determined
                    for n, v, s in zip(res.param_names, res.values, res.stderr)},
        )
        text = res.summary()
    else:
        from optim.fit import ChainTooShortWarning, conservative, fit_mcmc

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ChainTooShortWarning)
            post = call_with_progress(fit_mcmc, model, data, nwalkers=args.nwalkers, nsteps=args.nsteps,
                                      seed=args.seed, multipliers=args.multipliers, fit=fit, rows=rows,
                                      prior_strength=lam, progress=not args.json, description=f"emcee {args.nwalkers}x{args.nsteps}")
        fitted = post.model() if args.conservative is None else conservative(post, args.conservative)
        lo, hi = post.interval(0.95)
        report.update(
            nwalkers=post.nwalkers, nsteps=post.nsteps, burn=post.burn,
            acceptance_fraction=post.acceptance_fraction, tau_max=float(np.max(post.tau)),
            converged=post.converged, warning=post.warning, sigma_log10=float(np.median(post.sigma)),
            rmse_db=post.lsq.rmse_db, n_rows=post.lsq.n_rows, row_rules=post.lsq.row_rules,
            conservative_q=args.conservative,
            params={n: {"median": float(m), "lo95": float(a), "hi95": float(b)}
                    for n, m, a, b in zip(post.param_names, post.median(), lo, hi)},
        )
        text = post.summary() + ("" if post.warning is None else f"\nwarning: {post.warning}")
    if prior_kind == "cv" and text is not None:
        text = f"prior strength {lam:g} chosen by {report['prior_cv']['cv']} cross-validation\n{text}"
    if args.out is not None:
        pmetric.save_model(fitted, args.out)
        report["out"] = str(args.out)
    if args.json:
        print(json.dumps(report, indent=1, default=_jsonable))
        return 0
    if dropped is not None:
        print(dropped)
    if cv_res is not None:
        _print_cv(cv_res, report.get("prior_cv"))
    else:
        print(text)
    if args.out is not None:
        print(f"wrote {args.out}")
    return 0


def _parse_prior(prior, strength) -> tuple[str, float]:
    """``("none", 0)``, ``("cv", 0)`` (chosen later) or ``("fixed", lambda)`` from --prior / --prior-strength."""
    def number(flag, x):
        try:
            v = float(x)
        except ValueError:
            raise PlodError(f"{flag} must be none, cv or a number >= 0, got {x!r}") from None
        if not (math.isfinite(v) and v >= 0):
            raise PlodError(f"{flag} must be a finite number >= 0, got {x!r}")
        return v

    if strength is not None:
        lam = number("--prior-strength", strength)
        if prior is not None and (prior.strip().lower() in ("none", "cv") or number("--prior", prior) != lam):
            raise PlodError(f"--prior {prior} and --prior-strength {strength} disagree; give one of them")
        return ("none", 0.0) if lam == 0 else ("fixed", lam)
    if prior is None or prior.strip().lower() == "none":
        return "none", 0.0
    if prior.strip().lower() == "cv":
        return "cv", 0.0
    lam = number("--prior", prior)
    return ("none", 0.0) if lam == 0 else ("fixed", lam)


def _print_cv(cv, prior_cv) -> None:
    """The train / held-out table of a ``CVResult`` (rich)."""
    from rich.console import Console
    from rich.table import Table

    how = "leave-one-dataset-out" if cv.cv == "dataset" else f"{cv.k}-fold (seed {cv.seed})"
    table = Table(title=f"plod fit {cv.model}: {how} cross-validation, {cv.n_rows} rows, prior strength "
                        f"{cv.prior_strength:g}{', multipliers' if cv.multipliers else ''} (RMSE, dB)")
    table.add_column("dataset")
    for name in ("rows", "train dB", "held-out dB"):
        table.add_column(name, justify="right", no_wrap=True)
    if cv.cv == "dataset":
        table.add_column("held-out multiplier", justify="right", no_wrap=True)
    folds = {f.name: f for f in cv.folds}
    for d in cv.datasets:
        row = [d, str(cv.rows_per_dataset[d]), f"{cv.train_rmse_per_dataset.get(d, math.nan):.2f}",
               f"{cv.test_rmse_per_dataset[d]:.2f}"]
        if cv.cv == "dataset":
            row.append(f"{folds[d].test_multipliers[d]:.3f}")
        table.add_row(*row)
    last = ["overall", str(cv.n_rows), f"{cv.train_rmse_db:.2f}", f"{cv.test_rmse_db:.2f}"]
    table.add_row(*(last + ([""] if cv.cv == "dataset" else [])), style="bold")
    con = Console()
    con.print(table)
    if prior_cv is not None:
        con.print("prior strength by held-out RMSE: " + ", ".join(
            f"{g}: {v:.2f} dB" for g, v in prior_cv["held_out_rmse_db"].items())
            + f"; chosen {prior_cv['chosen']:g} (the held-out RMSE at the chosen strength is slightly optimistic)")


def _jsonable(x):
    try:
        v = float(x)
    except (TypeError, ValueError):
        return str(x)
    return v if math.isfinite(v) else None


if __name__ == "__main__":  # pragma: no cover
    from experiments.cli import main

    sys.exit(main(["fit", *sys.argv[1:]]))

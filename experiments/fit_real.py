"""Fit every CSF model to published contrast thresholds and write ``reports/fit_real/``.

    .venv/bin/python experiments/fit_real.py [--config configs/fit_real.toml]

Data (../shared/data/csf, Mantiuk group, MIT licence; [Ash24], [MAC22]): ``achromatic_thresholds.csv`` (787 rows, 12 datasets) and
``modelfest_individual.csv`` (16 ModelFest observers x 14 stimuli x 4 repeats).

For each model: least-squares refit (log10 sensitivity, Levenberg-Marquardt) on the rows it can express
(``optim.fit.expressible_rows``), without and with one free sensitivity multiplier per dataset. ModelFest:
(a) one model for all observers (observer = dataset) without / with a multiplier per observer,
(b) an individual refit per observer. One MCMC run (emcee) gives the corner plot and the conservative
(q-quantile) model. Leave-one-dataset-out cross-validation of every model at each prior strength of
``cv.prior_grid`` and at the published constants, and the held-out thresholds of ``cv.heldout``
(anderson1991 periphery, laird2006 velocity; extracted from gfxdisp/stelaCSF@052b15e
``data/data_aggregated.csv``, MIT) predicted by each all-rows fit. Writes ``report.md`` (Markdown tables), ``results.json``, PNG plots, the fitted
models (``fitted_<model>.json``, with multipliers) and ``run_info.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:  # pragma: no cover - run as a script
    sys.path.insert(0, str(ROOT))

from experiments._figures import pyplot, save_png  # noqa: E402

DEFAULTS = {
    "data": "../shared/data/csf/achromatic_thresholds.csv",
    "modelfest": "../shared/data/csf/modelfest_individual.csv",
    "out": "reports/fit_real",
    "models": ["stelacsf", "barten", "kellyabstract", "manossakrison", "kellyspatiotemporal", "eccentric"],
    "solver": "lm",
    "backend": "optimistix",
    "max_steps": 1000,
    "seed": 0,
    "observers": True,
    # also refit StelaCSF (with multipliers) with the other backend, to show where each one lands
    "compare_backend": True,
    # fields refitted per ModelFest observer (14 stimuli at one luminance): the big models keep their
    # luminance / temporal / eccentricity constants from the pooled fit
    "observer_fields": {
        "stelacsf": ["sust_s_max", "sust_f_max", "sust_bw", "sust_a", "f0", "a0"],
        "barten": ["sigma_0", "k", "eta", "n_max", "x_max", "u_0"],
    },
    # MCMC: a model and data set ("modelfest": all observers pooled, or "achromatic")
    "mcmc": {"model": "kellyabstract", "data": "modelfest", "nwalkers": 32, "nsteps": 3000, "q": 0.95},
    # cross-validation (optim.fit.cross_validate): leave one achromatic dataset out, for each prior
    # strength of the grid and the published constants (lambda -> infinity: only multipliers fitted);
    # "heldout": thresholds no fit sees (anderson1991 periphery, laird2006 velocity), predicted by the
    # fit of every achromatic row at each strength with one free multiplier per dataset
    "cv": {"enabled": True, "prior_grid": [0.0, 1.0, 10.0, 100.0],
           "heldout": "reports/fit_real/heldout_periphery.csv"},
}

#: train / test RMSE (dB) of the published castleCSF comparison, as quoted in issue 14 ([Ash24])
PUBLISHED_TRAIN_TEST = {"castleCSF": (3.14, 3.33), "StelaCSF": (4.19, 4.37), "Barten": (4.42, 4.50)}

PUBLISHED = "castleCSF 3.48 dB, Barten refit 3.87 dB, stelaCSF 4.37 dB (achromatic test set, with multipliers)"


def _rel(p: str) -> Path:
    q = Path(p)
    return q if q.is_absolute() else ROOT / q


def _fmt(x, nd=2):
    return "–" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{nd}f}"


def _numeric(x) -> bool:
    try:
        float(str(x).split(" ")[0])
        return True
    except ValueError:
        return str(x) == "–"


def _table(header, rows):
    def align(i):
        return " --- " if i == 0 or not all(_numeric(r[i]) for r in rows) else " ---: "

    out = ["| " + " | ".join(header) + " |", "|" + "|".join(align(i) for i in range(len(header))) + "|"]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out)


# ----------------------------------------------------------------------------- plots
def _conditions(data):
    """Groups of rows sharing every condition but spatial frequency: {key: index array}."""
    keys = {}
    for i in range(len(data)):
        k = (data.dataset[i], float(data.luminance[i]), float(data.t_frequency[i]), float(data.e[i]),
             round(float(data.area[i]), 6) if np.isfinite(data.area[i]) else -1.0,
             float(data.vis_field[i]) if np.isfinite(data.vis_field[i]) else -1.0)
        keys.setdefault(k, []).append(i)
    return {k: np.array(v) for k, v in keys.items()}


def plot_data_vs_fit(res, data, path, title):
    import jax
    plt = pyplot()
    sub = data.subset(res.rows)
    groups = _conditions(sub)
    datasets = sub.datasets
    ncol = 4
    nrow = math.ceil(len(datasets) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4 * ncol, 3.2 * nrow), squeeze=False)
    model = res.model
    for ax, ds in zip(axes.ravel(), datasets):
        gks = [k for k in groups if k[0] == ds and len(groups[k]) >= 2]
        gks = sorted(gks, key=lambda k: -len(groups[k]))[:8]
        colors = plt.cm.viridis(np.linspace(0, 0.9, max(len(gks), 1)))
        for c, k in zip(colors, gks):
            idx = groups[k]
            _, lum, tf, e, area, vis = k
            f = sub.f[idx]
            ax.loglog(f, sub.sensitivity[idx], "o", ms=3, color=c)
            fg = np.geomspace(f.min() * 0.8, f.max() * 1.25, 60)
            kw = {}
            if "vis_field" in getattr(model, "inputs", ()) and vis >= 0:
                kw["vis_field"] = vis
            with jax.enable_x64(True):
                s = np.asarray(model.stimulus_sensitivity(
                    fg, e, tf / fg, luminance=lum if np.isfinite(lum) else None,
                    area=area if area > 0 else None, **kw), np.float64)
            ax.loglog(fg, s * res.multipliers.get(ds, 1.0), "-", color=c, lw=1,
                      label=f"L={lum:g} tf={tf:g} e={e:g} A={area:.2g}")
        ax.set_title(f"{ds} ({res.rmse_per_dataset[ds]:.2f} dB)", fontsize=9)
        ax.set_xlabel("spatial frequency (cycles/deg)", fontsize=8)
        ax.set_ylabel("sensitivity", fontsize=8)
        ax.tick_params(labelsize=7)
        if len(gks) <= 4:
            ax.legend(fontsize=5)
    for ax in axes.ravel()[len(datasets):]:
        ax.axis("off")
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    save_png(fig, path)


def plot_residuals(results, data, path):
    plt = pyplot()
    n = len(results)
    ncol = min(3, n)
    nrow = math.ceil(n / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.6 * ncol, 3.4 * nrow), squeeze=False, sharey=True)
    all_ds = data.datasets
    cmap = plt.cm.tab20(np.linspace(0, 1, len(all_ds)))
    for ax, (name, res) in zip(axes.ravel(), results.items()):
        sub = data.subset(res.rows)
        for j, ds in enumerate(all_ds):
            m = sub.dataset == ds
            if m.any():
                ax.semilogx(sub.f[m], 20 * res.residuals[m], ".", ms=3, color=cmap[j], label=ds)
        ax.axhline(0, color="k", lw=0.5)
        ax.set_title(f"{name}: {res.rmse_db:.2f} dB, {res.n_rows} rows", fontsize=9)
        ax.set_xlabel("spatial frequency (cycles/deg)", fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in axes[:, 0]:
        ax.set_ylabel("residual, model - data (dB)", fontsize=8)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    axes[0, 0].legend(fontsize=5, ncol=2)  # the first model (StelaCSF) covers every dataset
    fig.tight_layout()
    save_png(fig, path)


def plot_corner(samples, names, path, truths=None):
    """A small pair plot (no ``corner`` package): histograms on the diagonal, scatter below."""
    plt = pyplot()
    p = samples.shape[1]
    fig, axes = plt.subplots(p, p, figsize=(2.4 * p, 2.4 * p), squeeze=False)
    rng = np.random.default_rng(0)
    pick = samples[rng.choice(len(samples), size=min(4000, len(samples)), replace=False)]
    for i in range(p):
        for j in range(p):
            ax = axes[i, j]
            if j > i:
                ax.axis("off")
                continue
            if i == j:
                ax.hist(samples[:, i], bins=40, color="0.4", histtype="step")
                lo, hi = np.quantile(samples[:, i], [0.025, 0.975])
                for x in (lo, hi):
                    ax.axvline(x, color="C1", lw=0.8, ls="--")
                ax.set_yticks([])
            else:
                ax.plot(pick[:, j], pick[:, i], ".", ms=1, alpha=0.3, color="C0")
            if i == p - 1:
                ax.set_xlabel(names[j], fontsize=8)
            if j == 0 and i > 0:
                ax.set_ylabel(names[i], fontsize=8)
            ax.tick_params(labelsize=6)
    fig.tight_layout()
    save_png(fig, path)


def plot_modelfest(indiv, mf, path):
    import jax
    plt = pyplot()
    obs = list(indiv)
    ncol = 4
    nrow = math.ceil(len(obs) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.4 * ncol, 2.6 * nrow), squeeze=False, sharex=True, sharey=True)
    for ax, o in zip(axes.ravel(), obs):
        d = mf.subset(mf.observer == o)
        big = np.isclose(d.area, np.max(d.area))
        ax.loglog(d.f[big], d.sensitivity[big], "o", ms=2, color="0.3")
        ax.loglog(d.f[~big], d.sensitivity[~big], "s", ms=2, color="C3")
        fg = np.geomspace(1.0, 32.0, 60)
        for name, res in indiv[o].items():
            with jax.enable_x64(True):
                s = np.asarray(res.model.stimulus_sensitivity(fg, 0.0, 0.0, luminance=30.0, area=float(np.max(d.area))))
            ax.loglog(fg, s, lw=1, label=f"{name} {res.rmse_db:.1f} dB")
        ax.set_title(o, fontsize=8)
        ax.legend(fontsize=5)
        ax.tick_params(labelsize=6)
    for ax in axes.ravel()[len(obs):]:
        ax.axis("off")
    fig.suptitle("ModelFest individual fits (grey: Gabors of 0.5 deg s.d.; red: smaller Gabors)", fontsize=10)
    fig.tight_layout()
    save_png(fig, path)


# ----------------------------------------------------------------------------- stages
def load_data(cfg):
    """(achromatic thresholds, ModelFest with one dataset per observer)."""
    from optim.fit import CalibrationData

    data = CalibrationData.from_csv(_rel(cfg["data"]))
    mf = CalibrationData.from_csv(_rel(cfg["modelfest"]))
    mf = CalibrationData.from_arrays(
        mf.f, log_threshold=mf.log_threshold, e=mf.e, t_frequency=mf.t_frequency, luminance=mf.luminance,
        area=mf.area, vis_field=mf.vis_field, dataset=mf.observer, observer=mf.observer)
    return data, mf


def fit_all(cfg, models, data, mf, step):
    """Least-squares fits: {"ach", "mfp", "indiv"} by model label (and observer), and the backend check.

    ``step(description)`` is called before each fit (the caller advances its progress display).
    """
    import optim

    kw = dict(solver=cfg["solver"], backend=cfg["backend"], max_steps=int(cfg["max_steps"]))
    ach: dict[str, dict] = {}
    mfp: dict[str, dict] = {}
    indiv: dict[str, dict] = {}
    for name, model in models.items():
        label = type(model).__name__
        for mult in (False, True):
            step(f"{label} achromatic{' +mult' if mult else ''}")
            ach.setdefault(label, {})[mult] = optim.fit_least_squares(model, data, multipliers=mult, **kw)
        for mult in (False, True):
            step(f"{label} ModelFest pooled{' +mult' if mult else ''}")
            # start from the achromatic fit (with multipliers): the population model
            mfp.setdefault(label, {})[mult] = optim.fit_least_squares(
                ach[label][True].model, mf, multipliers=mult, **kw)
        if cfg["observers"]:
            fields = cfg["observer_fields"].get(name.lower()) or None
            for o in mf.datasets:
                step(f"{label} observer {o}")
                d = mf.subset(mf.dataset == o)
                indiv.setdefault(o, {})[label] = optim.fit_least_squares(mfp[label][False].model, d, fit=fields, **kw)
    alt = None
    if cfg["compare_backend"] and "StelaCSF" in ach:
        other = "jaxopt" if cfg["backend"] == "optimistix" else "optimistix"
        step(f"StelaCSF achromatic +mult ({other})")
        import pmetric

        alt = optim.fit_least_squares(models["stelacsf"] if "stelacsf" in models else pmetric.StelaCSF(), data,
                                      multipliers=True, **{**kw, "backend": other})
    return ach, mfp, indiv, alt


def run_mcmc(cfg, data, mf, progress):
    """(posterior, conservative model, seconds) of the configured MCMC run."""
    from optim.fit import ChainTooShortWarning, conservative, fit_mcmc
    from pmetric import PlodError, make_model

    mc = cfg["mcmc"]
    if mc["data"] not in ("modelfest", "achromatic"):
        raise PlodError(f"mcmc.data must be 'modelfest' or 'achromatic', got {mc['data']!r}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ChainTooShortWarning)
        t0 = time.perf_counter()
        post = fit_mcmc(make_model(mc["model"]), mf if mc["data"] == "modelfest" else data,
                        nwalkers=int(mc["nwalkers"]), nsteps=int(mc["nsteps"]), seed=int(cfg["seed"]),
                        progress=progress)
        t_mcmc = time.perf_counter() - t0
    return post, conservative(post, float(mc["q"]), seed=int(cfg["seed"])), t_mcmc


def run_cv(cfg, models, data, heldout, step):
    """{label: {lambda: (CVResult, all-rows FitResult, {dataset: held_out_rmse entry})}} and seconds.

    ``lambda = inf``: the published constants (the model as made by name), only multipliers fitted.
    """
    import optim
    from optim.fit import cross_validate, held_out_rmse
    from pmetric import PlodError

    kw = dict(solver=cfg["solver"], backend=cfg["backend"], max_steps=int(cfg["max_steps"]))
    grid = [float(g) for g in cfg["cv"]["prior_grid"]]
    out, t0 = {}, time.perf_counter()
    for model in models.values():
        label = type(model).__name__
        out[label] = {}
        for lam in grid + [math.inf]:
            step(f"{label} leave-one-dataset-out, prior strength {lam:g}")
            fit_lam = 1e8 if lam == math.inf else lam  # the constants stay at the published values
            cvr = cross_validate(model, data, cv="dataset", prior_strength=fit_lam, multipliers=True, **kw)
            full = optim.fit_least_squares(model, data, multipliers=True, prior_strength=fit_lam, **kw)
            try:
                ext = held_out_rmse(model if lam == math.inf else full.model, heldout)
            except PlodError:  # the model can express none of the held-out rows
                ext = {}
            out[label][lam] = (cvr, full, ext)
    return out, time.perf_counter() - t0


def best_strength(per: dict) -> float:
    """The grid strength (published excluded) of least leave-one-dataset-out held-out RMSE."""
    return min((lam for lam in per if math.isfinite(lam)), key=lambda lam: (per[lam][0].test_rmse_db, -lam))


def write_outputs(out, ach, data, post, cons, indiv, mf, q):
    """Plots and the fitted / conservative models."""
    import pmetric

    best = ach.get("StelaCSF", next(iter(ach.values())))
    plot_data_vs_fit(best[True], data, out / "data_vs_fit_stelacsf.png",
                     f"{type(best[True].model).__name__} refit with multipliers: {best[True].rmse_db:.2f} dB")
    for label, r in ach.items():
        if label != "StelaCSF":
            plot_data_vs_fit(r[True], data, out / f"data_vs_fit_{label.lower()}.png",
                             f"{label} refit with multipliers: {r[True].rmse_db:.2f} dB")
    plot_residuals({k: v[True] for k, v in ach.items()}, data, out / "residuals.png")
    plot_corner(np.column_stack([post.samples, post.sigma]), post.param_names + ["sigma"], out / "mcmc_corner.png")
    if indiv:
        plot_modelfest(indiv, mf, out / "modelfest_individual.png")
    for label, r in ach.items():
        pmetric.save_model(r[True].model, out / f"fitted_{label.lower()}.json")
    pmetric.save_model(cons, out / f"conservative_{type(cons).__name__.lower()}_q{q:g}.json")


# ----------------------------------------------------------------------------- report sections
def achromatic_section(ach, data) -> list[str]:
    lines = ["## Achromatic thresholds (`achromatic_thresholds.csv`, 787 rows)", ""]
    rows = []
    for label, r in ach.items():
        a, b = r[False], r[True]
        n_const = len([n for n in b.param_names if not n.startswith("log10_multiplier")])
        rows.append([label, b.n_rows, n_const, _fmt(a.rmse_db), _fmt(b.rmse_db),
                     f"{a.result} / {b.result}", "; ".join(b.row_rules[1:]) or "all gratings/Gabors"])
    lines.append(_table(["model", "rows", "constants", "RMSE dB", "RMSE dB (+mult)", "solver result",
                         "rows it can express (besides f > 0)"], rows))
    lines += ["", "Disk stimuli (f = 0: hdr_csf_disc, hansen2009, 20 rows) are not CSF stimuli and are left out "
              "for every model. Models without a luminance term are fitted on photopic rows "
              "(10-1000 cd/m2); without an area term on stimuli >= 0.5 deg2; without a velocity term on "
              "static stimuli; without an eccentricity term on foveal stimuli.", "",
              "### RMSE (dB) per dataset, with multipliers (multiplier in brackets)", ""]
    dsets = data.datasets
    rows = []
    for label, r in ach.items():
        b = r[True]
        rows.append([label] + [f"{b.rmse_per_dataset[d]:.2f} ({b.multipliers[d]:.2f})" if d in b.rmse_per_dataset
                               else "–" for d in dsets])
    lines.append(_table(["model"] + dsets, rows))
    lines += ["", "### RMSE (dB) per dataset, without multipliers", ""]
    rows = [[label] + [_fmt(r[False].rmse_per_dataset.get(d)) for d in dsets] for label, r in ach.items()]
    lines.append(_table(["model"] + dsets, rows))
    return lines


def modelfest_section(ach, mfp, indiv, mf) -> list[str]:
    lines = ["", "## ModelFest observers (`modelfest_individual.csv`: 16 observers x 14 Gabors x 4 repeats)", "",
             "Pooled: one model for all observers, started from the achromatic fit; +mult: one sensitivity "
             "factor per observer. Individual: each observer refitted alone (StelaCSF and Barten refit only "
             "the fields in `observer_fields`; the others every constant). Rows: models without an area "
             "term see only the 10 large Gabors.", ""]
    rows = []
    for label in ach:
        a, b = mfp[label][False], mfp[label][True]
        ind = [indiv[o][label] for o in indiv]
        ind_rmse = math.sqrt(sum(x.rmse_log10 ** 2 * x.n_rows for x in ind) / sum(x.n_rows for x in ind)) * 20 if ind else None
        rows.append([label, a.n_rows, _fmt(a.rmse_db), _fmt(b.rmse_db), _fmt(ind_rmse)])
    lines.append(_table(["model", "rows", "pooled RMSE dB", "pooled +mult RMSE dB", "individual RMSE dB"], rows))
    if indiv:
        lines += ["", "### Individual refits: RMSE (dB) per observer", ""]
        labels = list(ach)
        rows = [[o] + [_fmt(indiv[o][lb].rmse_db) for lb in labels] for o in indiv]
        lines.append(_table(["observer"] + labels, rows))
    # repeat noise floor: the RMSE of the four repeats about their mean
    key = np.char.add(np.char.add(mf.dataset, "|"), np.char.add(mf.f.astype(str), mf.area.astype(str)))
    _, inv = np.unique(key, return_inverse=True)
    means = np.bincount(inv, weights=mf.log_threshold) / np.bincount(inv)
    floor = 20 * math.sqrt(np.mean((mf.log_threshold - means[inv]) ** 2) * 4 / 3)
    lines += ["", f"Repeat-to-repeat scatter of one observer (noise floor of any model): {floor:.2f} dB.", ""]
    return lines


def mcmc_section(post, cons, mc, t_mcmc) -> list[str]:
    import jax

    lo, hi = post.interval(0.95)
    lines = [f"## MCMC ({type(post.lsq.model).__name__}, {mc['data']} rows it can express, no multipliers)", "",
             f"emcee, {post.nwalkers} walkers x {post.nsteps} steps (burn {post.burn}), "
             f"{t_mcmc:.1f} s; acceptance {post.acceptance_fraction:.2f}; largest integrated autocorrelation "
             f"time {np.max(post.tau):.1f} steps ({'converged' if post.converged else 'NOT converged: ' + str(post.warning)}).",
             ""]
    rows = [[n, f"{m:.5g}", f"[{a:.5g}, {b:.5g}]", f"{v:.5g}", f"{s:.3g}"]
            for n, m, a, b, v, s in zip(post.param_names, post.median(), lo, hi, post.lsq.values, post.lsq.stderr)]
    rows.append(["sigma (log10)", f"{np.median(post.sigma):.4g}", f"[{np.quantile(post.sigma, 0.025):.4g}, "
                 f"{np.quantile(post.sigma, 0.975):.4g}]", "", ""])
    lines.append(_table(["constant", "posterior median", "95 % interval", "least squares", "LS std. err."], rows))
    fg = np.geomspace(0.5, 30, 7)
    with jax.enable_x64(True):
        ratio = np.asarray(cons.sensitivity(fg)) / np.asarray(post.model().sensitivity(fg))
    lines += ["", f"Conservative model (`optim.conservative`, q = {mc['q']}): thresholds at the lower {mc['q']} "
              "quantile of the posterior predictive; sensitivity relative to the posterior median at "
              + ", ".join(f"{f:.2g}" for f in fg) + " cycles/deg: " + ", ".join(f"{x:.2f}" for x in ratio) + ".", "",
              "## Plots", "",
              "- `data_vs_fit_<model>.png`: data (points) and fitted curves per dataset and condition (with multipliers)",
              "- `residuals.png`: residuals (dB) against frequency for every model",
              "- `modelfest_individual.png`: per-observer data and individual fits",
              "- `mcmc_corner.png`: posterior pair plot (dashed: 95 % intervals)", ""]
    return lines


def _lam(lam) -> str:
    return "published (inf)" if lam == math.inf else f"{lam:g}"


def cv_section(cvres, heldout, heldout_path, t_cv) -> list[str]:
    ext_sets = heldout.datasets
    lines = ["## Generalisation: leave-one-dataset-out and held-out periphery", "",
             "Each achromatic dataset in turn is left out; the model is refitted (least squares, one "
             "multiplier per training dataset) on the rest and predicts the left-out dataset, whose own "
             "multiplier alone is refitted on its rows (`optim.fit.cross_validate`, `cv=\"dataset\"`). "
             "`prior strength` is the lambda of the Gaussian prior toward the published constants "
             "(`fit_least_squares(prior_strength=)`, in the log / logit coordinates of the fit; the same prior "
             "is `fit_mcmc`'s); `published (inf)` keeps the published constants and fits only the multipliers. "
             "Train: RMSE of the training fits (pooled over folds); held-out: RMSE on the left-out datasets. "
             f"The last columns are thresholds no fit saw (`{heldout_path}`, from the stelaCSF "
             "repository, gfxdisp/stelaCSF@052b15e `data/data_aggregated.csv`, MIT; anderson1991: 8-55 deg "
             "eccentricity, 8 Hz drifting Gabors; laird2006: foveal, 9-31 Hz), predicted by the fit of every "
             "achromatic row at that strength with one free multiplier per held-out dataset "
             "(`optim.fit.held_out_rmse`); `–`: the model cannot express those rows. "
             f"Bold: the strength of least held-out RMSE (`--prior cv`). {t_cv:.0f} s.", ""]
    rows = []
    for label, per in cvres.items():
        best = best_strength(per)
        for lam, (cvr, full, ext) in per.items():
            mark = (lambda x: f"**{x}**") if lam == best else (lambda x: x)
            pub = PUBLISHED_TRAIN_TEST.get(label)
            rows.append([label if lam == next(iter(per)) else "", mark(_lam(lam)), cvr.n_rows,
                         _fmt(full.rmse_db), _fmt(cvr.train_rmse_db), mark(_fmt(cvr.test_rmse_db))]
                        + [_fmt(ext[d]["rmse_db"]) if d in ext else "–" for d in ext_sets]
                        + [f"{pub[0]:.2f} / {pub[1]:.2f}" if pub and lam == next(iter(per)) else ""])
    lines.append(_table(["model", "prior strength", "rows", "all-rows fit dB", "LODO train dB", "LODO held-out dB"]
                        + [f"{d} ({int(np.sum(heldout.dataset == d))} rows) dB" for d in ext_sets]
                        + ["published train / test [Ash24]"], rows))
    lines += ["", "Published train / test figures (castleCSF 3.14 / 3.33 dB, stelaCSF 4.19 / 4.37, Barten "
              "4.42 / 4.50; as quoted in issue 14 from the castleCSF comparison [Ash24]) come from a fixed "
              "train / test split of the full castleCSF data (chromatic too), not from leaving whole datasets "
              "out: they are the nearest published figures, not the same measurement. castleCSF itself is not "
              "in plod's registry.", "",
              "### Held-out RMSE (dB) per left-out dataset", ""]
    dsets = list(next(iter(cvres.values()))[0.0][0].test_rmse_per_dataset) if cvres else []
    rows = []
    for label, per in cvres.items():
        best = best_strength(per)
        for lam in (0.0, best, math.inf):
            if lam == best and lam == 0.0:
                continue
            cvr = per[lam][0]
            rows.append([f"{label}, {_lam(lam)}"] + [_fmt(cvr.test_rmse_per_dataset.get(d)) for d in dsets])
    lines.append(_table(["model, prior strength"] + dsets, rows))
    lines += [""] + recommendation(cvres, heldout)
    return lines


def recommendation(cvres, heldout) -> list[str]:
    """Which model and prior strength plod should use for LOD: least held-out periphery error."""
    periphery = "anderson1991"
    cands = []
    for label, per in cvres.items():
        for lam, (cvr, full, ext) in per.items():
            if periphery in ext:
                cands.append((ext[periphery]["rmse_db"], cvr.test_rmse_db, label, lam))
    lines = ["### Recommendation for LOD", ""]
    if not cands:
        return lines + [f"No model here can express the {periphery} rows.", ""]
    cands.sort()
    err, lodo, label, lam = cands[0]
    per = cvres[label]
    p0 = per[0.0][2][periphery]["rmse_db"]
    pinf = per[math.inf][2][periphery]["rmse_db"]
    best = best_strength(per)
    lines += [f"Gaze-directed LOD relies on the model where no calibration was done: the periphery. Of the models "
              f"that can express the {periphery} rows ({', '.join(sorted({c[2] for c in cands}))}), the least "
              f"held-out periphery error is {label} at prior strength {_lam(lam)}: {err:.2f} dB on {periphery} "
              f"(the unregularised refit: {p0:.2f} dB; the published constants: {pinf:.2f} dB), with "
              f"{lodo:.2f} dB leave-one-dataset-out. The strength of least leave-one-dataset-out error "
              f"(`--prior cv`) is {_lam(best)}: {per[best][0].test_rmse_db:.2f} dB held-out, "
              f"{per[best][2][periphery]['rmse_db']:.2f} dB on {periphery}.", "",
              DEFAULTS_NOTE, ""]
    return lines


DEFAULTS_NOTE = (
    "What plod uses by default: `pmetric.DEFAULT_MODEL` = `stela`, stelaCSF with its published constants "
    "[MAC22] (no refit: prior strength infinite), for `plod simplify`, the experiments and the library; the "
    "least held-out periphery error above decides it, and the image judge agrees: with it plod's budget cuts "
    "score higher than with the seeds' KellyAbstract, plod's default before, in 95 of 108 cells of the "
    "accuracy sweep (reports/accuracy/default_model.md). The seeds' reproductions keep KellyAbstract. "
    "`plod fit` defaults to `--prior none` (plain least squares: the constants of the data given); use "
    "`--prior cv` for a fit that will be used where the data has no rows (the periphery), as this table "
    "supports.")


def standing_section(ach, alt, backend) -> list[str]:
    stela = ach.get("StelaCSF")
    if not stela:
        return []
    s = stela[True].rmse_db
    lines = ["## Where the models stand", "",
             f"- StelaCSF refit with multipliers: {s:.2f} dB overall on {stela[True].n_rows} rows "
             f"(goal <= 4.5 dB; published 4.2-4.4 dB): {'met' if s <= 4.5 else 'NOT met'}. "
             f"Without multipliers {stela[False].rmse_db:.2f} dB."]
    if alt is not None:
        vals = dict(zip(alt.param_names, alt.values))
        ours = dict(zip(stela[True].param_names, stela[True].values))
        lines.append(f"- The same StelaCSF fit with the {alt.backend} backend: {alt.rmse_db:.2f} dB ({alt.result}, "
                     f"{alt.steps} steps), a different local minimum (sigma_trans = {vals['sigma_trans']:.3g}, "
                     f"beta_trans = {vals['beta_trans']:.3g}; {backend}: "
                     f"{ours['sigma_trans']:.3g}, {ours['beta_trans']:.3g}).")
    for label, r in ach.items():
        if label != "StelaCSF":
            lines.append(f"- {label}: {r[True].rmse_db:.2f} dB with multipliers on the {r[True].n_rows} rows "
                         f"it can express ({r[False].rmse_db:.2f} dB without).")
    lines += ["- The seeds' models (ManosSakrison, KellyAbstract, KellySpatioTemporal, Eccentric) have no "
              "luminance or size term, so they are compared on smaller, easier subsets: their RMSE is not "
              "comparable with StelaCSF's row for row.", ""]
    return lines


def cv_json(cvres) -> dict:
    return {label: {_lam(lam): {"cv": cvr.to_dict(), "all_rows_rmse_db": full.rmse_db, "held_out": ext}
                    for lam, (cvr, full, ext) in per.items()} for label, per in cvres.items()}


def results_json(ach, mfp, indiv, post, t_mcmc) -> dict:
    lo, hi = post.interval(0.95)

    def by_mult(v):
        return {("with_multipliers" if m else "without_multipliers"): _res_json(r) for m, r in v.items()}

    return {
        "achromatic": {lb: by_mult(v) for lb, v in ach.items()},
        "modelfest_pooled": {lb: by_mult(v) for lb, v in mfp.items()},
        "modelfest_individual": {o: {lb: {"rmse_db": r.rmse_db, "n_rows": r.n_rows, "result": r.result}
                                     for lb, r in v.items()} for o, v in indiv.items()},
        "mcmc": {"model": type(post.lsq.model).__name__, "param_names": post.param_names,
                 "median": post.median().tolist(), "lo95": lo.tolist(), "hi95": hi.tolist(),
                 "acceptance_fraction": post.acceptance_fraction, "tau": post.tau.tolist(),
                 "converged": post.converged, "seconds": t_mcmc},
    }


def _finite(x):
    v = float(x)
    return v if math.isfinite(v) else None


def pmetric_save(model, path):
    import pmetric

    pmetric.save_model(model, path)


def _res_json(r):
    return {"rmse_db": r.rmse_db, "rmse_log10": r.rmse_log10, "n_rows": r.n_rows, "result": r.result,
            "steps": r.steps, "rmse_per_dataset_db": r.rmse_per_dataset, "multipliers": r.multipliers,
            "row_rules": r.row_rules,
            "params": {n: [float(v), float(s)] for n, v, s in zip(r.param_names, r.values, r.stderr)}}


# ----------------------------------------------------------------------------- main
def _progress_bar(console):
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    columns = [TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
               TimeElapsedColumn()]
    return Progress(*columns, console=console)


def check_config(cfg: dict) -> dict:
    """The values the run reads, checked before any fit (PlodError naming the key): before, ``models = []``
    ran every fit and the MCMC, then crashed writing the report (StopIteration), and a bad ``mcmc`` value
    was found only after every least-squares fit."""
    from pmetric import PlodError, make_model

    def bad(key, want, got):
        raise PlodError(f"fit_real: config key {key!r} must be {want}, got {got!r}")

    def whole(x, lo):
        return isinstance(x, int) and not isinstance(x, bool) and x >= lo

    m = cfg["models"]
    if not m or not all(isinstance(x, str) for x in m) or len(set(m)) != len(m):
        bad("models", "a non-empty list of distinct model names (plod models lists them)", m)
    for name in m:
        make_model(name)  # an unknown name: PlodError naming it
    mc = cfg["mcmc"]
    if mc.get("data") not in ("modelfest", "achromatic"):
        bad("mcmc.data", "'modelfest' or 'achromatic'", mc.get("data"))
    if not isinstance(mc.get("model"), str):
        bad("mcmc.model", "a model name", mc.get("model"))
    make_model(mc["model"])
    if not whole(mc.get("nwalkers"), 2):
        bad("mcmc.nwalkers", "an integer >= 2", mc.get("nwalkers"))
    if not whole(mc.get("nsteps"), 3):
        bad("mcmc.nsteps", "an integer >= 3", mc.get("nsteps"))
    q = mc.get("q")
    if not (isinstance(q, (int, float)) and not isinstance(q, bool) and 0 < q < 1):
        bad("mcmc.q", "a probability in (0, 1)", q)
    grid = cfg["cv"].get("prior_grid", [])
    if not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and x >= 0 for x in grid):
        bad("cv.prior_grid", "a list of prior strengths >= 0", grid)
    return cfg


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default=None, help="TOML of overrides (e.g. configs/fit_real.toml)")
    args = ap.parse_args(argv)
    warnings.filterwarnings("ignore", message=".*JAXopt is no longer maintained.*", category=DeprecationWarning)
    from rich.console import Console

    from experiments._runinfo import load_config, save_run_info
    from pmetric import PlodError, atomic_write_text, make_model

    cfg = check_config(load_config(args.config, DEFAULTS))
    unknown = [k for k in cfg["observer_fields"] if k not in DEFAULTS["observer_fields"]]
    if unknown:  # pragma: no cover - load_config rejects them already
        raise PlodError(f"unknown observer_fields keys {unknown}")
    out = _rel(cfg["out"])
    out.mkdir(parents=True, exist_ok=True)
    console = Console(stderr=True)
    t_start = time.perf_counter()
    data, mf = load_data(cfg)
    models = {name: make_model(name) for name in cfg["models"]}
    mc = cfg["mcmc"]
    n_fits = 4 * len(models) + len(models) * (len(mf.datasets) if cfg["observers"] else 0)
    n_fits += int(bool(cfg["compare_backend"]) and any(type(m).__name__ == "StelaCSF" for m in models.values()))
    cv_on = bool(cfg["cv"]["enabled"])
    n_fits += len(models) * (len(cfg["cv"]["prior_grid"]) + 1) if cv_on else 0
    heldout = None
    if cv_on:
        from optim.fit import CalibrationData

        heldout = CalibrationData.from_csv(_rel(cfg["cv"]["heldout"]))
    with _progress_bar(console) as bar:
        task = bar.add_task("fitting", total=n_fits + 1)

        def step(description):
            if bar.tasks[task].description != "fitting":
                bar.advance(task)
            bar.update(task, description=description)

        ach, mfp, indiv, alt = fit_all(cfg, models, data, mf, step)
        cvres, t_cv = run_cv(cfg, models, data, heldout, step) if cv_on else ({}, 0.0)
        mcmc_label = f"MCMC {mc['model']} {mc['nwalkers']}x{mc['nsteps']}"
        step(mcmc_label)
        post, cons, t_mcmc = run_mcmc(
            cfg, data, mf, lambda stage, done, total: bar.update(task, description=f"{mcmc_label}: {stage} {done}/{total}"))
        bar.update(task, completed=n_fits + 1)
    console.print("writing plots and report")
    write_outputs(out, ach, data, post, cons, indiv, mf, mc["q"])
    cmd = " ".join([".venv/bin/python experiments/fit_real.py", *(argv if argv is not None else sys.argv[1:])])
    lines = ["# Refitting the CSF models to published thresholds", "",
             f"Command: `{cmd}` ({time.perf_counter() - t_start:.0f} s on this machine). Least squares in log10 sensitivity, "
             f"{cfg['solver']} / {cfg['backend']}; RMSE in dB of sensitivity (20 log10). "
             "Multipliers: one free sensitivity factor per dataset, geometric mean 1.", "",
             f"Published ([Ash24]): {PUBLISHED}.", ""]
    lines += achromatic_section(ach, data) + modelfest_section(ach, mfp, indiv, mf)
    lines += cv_section(cvres, heldout, cfg["cv"]["heldout"], t_cv) if cvres else []
    lines += mcmc_section(post, cons, mc, t_mcmc) + standing_section(ach, alt, cfg["backend"])
    atomic_write_text(out / "report.md", "\n".join(lines) + "\n")
    res_json = results_json(ach, mfp, indiv, post, t_mcmc)
    if cvres:
        res_json["cross_validation"] = cv_json(cvres)
        for label, per in cvres.items():  # the all-rows fit at the strength --prior cv would choose
            best = best_strength(per)
            if best > 0:
                pmetric_save(per[best][1].model, out / f"fitted_{label.lower()}_prior{best:g}.json")
    atomic_write_text(out / "results.json", json.dumps(res_json, indent=1, default=_finite) + "\n")
    save_run_info(out, cfg, int(cfg["seed"]), " ".join(["experiments/fit_real.py", *(argv or sys.argv[1:])]))
    console.print(f"wrote {out}/report.md in {time.perf_counter() - t_start:.0f} s")
    if "StelaCSF" in ach:
        console.print(f"StelaCSF with multipliers: {ach['StelaCSF'][True].rmse_db:.3f} dB")
    return 0


if __name__ == "__main__":
    from experiments._runinfo import run_script

    run_script(main)

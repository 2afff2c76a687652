"""Cross-validated least-squares fits: leave-one-dataset-out and k-fold, train and held-out RMSE.

A fold's training fit is ``solve_problem`` on a ``Problem`` built from ``data.subset(train_rows)``
alone, ``train_rows`` an integer index array into ``data`` that ``CVFold`` keeps: the held-out rows
never reach the training fit (``test_rows`` and ``train_rows`` are disjoint; a test inspects them).
The held-out rows are then predicted by the trained constants. With ``multipliers=True`` a held-out
dataset absent from the training rows (always so when leaving a dataset out) gets its own sensitivity
multiplier refitted on its held-out rows alone, every other constant fixed at the training fit, as the
published castleCSF / stelaCSF comparisons allow ([Ash24], [MAC22]); for one free log multiplier the
least-squares value is closed-form, the (weighted) mean of ``log10 S_data - log10 S_model`` over those
rows. A held-out dataset that is also in the training rows (k-fold) keeps its training multiplier.

Folds: ``cv="dataset"`` (one fold per dataset among the rows the model can express) or an int
``k >= 2`` (the expressible rows permuted by ``numpy.random.default_rng(seed)`` and cut into ``k``
near-equal parts: deterministic for a seed).

RMSE in dB of sensitivity (20 log10): ``train_rmse_db`` pools the training residuals of every fold,
``test_rmse_db`` the held-out residuals (each expressible row is held out exactly once). To share one
compiled solver, every training problem is padded to the largest training size with weight-0 copies
of its own first row (``pad_arrays``), which changes nothing in the fit.

``select_prior_strength`` runs the cross-validation for each ``lambda`` of a grid (the prior of
``fit_least_squares(prior_strength=lambda)``) and picks the one of least held-out RMSE; the held-out
RMSE reported at the chosen lambda is then slightly optimistic (the choice saw the same folds).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from pmetric import PlodError

from ._least_squares import _check_prior_strength, _check_solver_args, solve_problem
from ._problem import Problem, predict_log10, row_arrays

__all__ = ["CVFold", "CVResult", "PRIOR_GRID", "cross_validate", "held_out_rmse", "make_folds", "parse_cv",
           "select_prior_strength"]

#: default grid of prior strengths (lambda, dimensionless; see ``fit_least_squares``) for ``--prior cv``
PRIOR_GRID = (0.0, 0.1, 1.0, 10.0, 100.0)

Progress = Callable[[str, int, int], None]


# ----------------------------------------------------------------------------- results
@dataclasses.dataclass(frozen=True)
class CVFold:
    """One fold: what the training fit saw, its constants, and the held-out errors.

    Attributes:
        name: the held-out dataset (``cv="dataset"``) or ``"fold i"``.
        train_rows, test_rows: sorted int indices into the input data (disjoint); the training fit
            is built from ``data.subset(train_rows)`` only.
        train_rmse_db, test_rmse_db: RMSE (dB) over this fold's training / held-out rows.
        train_rmse_per_dataset, test_rmse_per_dataset: {dataset: RMSE dB}.
        test_multipliers: {held-out dataset: the sensitivity multiplier applied to it}.
        refitted: the held-out datasets whose multiplier was refitted on the held-out rows alone.
        constants: {parameter name: natural value} of the training fit (``log10_multiplier[d]`` too).
        result: the training solver's outcome (``FitResult.result``); steps: its iterations.
        test_residuals: (len(test_rows),) log10 residuals (model x multiplier - data) of the held-out rows.
    """

    name: str
    train_rows: np.ndarray
    test_rows: np.ndarray
    train_rmse_db: float
    test_rmse_db: float
    train_rmse_per_dataset: dict
    test_rmse_per_dataset: dict
    test_multipliers: dict
    refitted: tuple
    constants: dict
    result: str
    steps: int
    test_residuals: np.ndarray = dataclasses.field(repr=False)


@dataclasses.dataclass(frozen=True)
class CVResult:
    """Outcome of ``cross_validate`` (all RMSE in dB of sensitivity).

    Attributes:
        model: class name of the model; cv: ``"dataset"`` or ``"k-fold"`` with ``k`` folds; seed.
        prior_strength: lambda of the prior in every training fit; multipliers: per-dataset multipliers.
        n_rows: expressible rows cross-validated; rows: (n_data,) bool mask of them; row_rules.
        train_rmse_db, test_rmse_db: pooled over folds (see the module docstring).
        train_rmse_per_dataset, test_rmse_per_dataset: {dataset: RMSE dB}, pooled over folds.
        rows_per_dataset: {dataset: expressible rows}.
        folds: the ``CVFold`` of every fold.
    """

    model: str
    cv: str
    k: int
    seed: int
    prior_strength: float
    multipliers: bool
    n_rows: int
    rows: np.ndarray = dataclasses.field(repr=False)
    row_rules: tuple = ()
    train_rmse_db: float = math.nan
    test_rmse_db: float = math.nan
    train_rmse_per_dataset: dict = dataclasses.field(default_factory=dict)
    test_rmse_per_dataset: dict = dataclasses.field(default_factory=dict)
    rows_per_dataset: dict = dataclasses.field(default_factory=dict)
    folds: tuple = ()

    @property
    def datasets(self) -> list[str]:
        return list(self.test_rmse_per_dataset)

    def to_dict(self) -> dict:
        """Plain JSON-able dict (numbers and strings; row indices as lists)."""
        return {
            "model": self.model, "cv": self.cv, "k": self.k, "seed": self.seed,
            "prior_strength": self.prior_strength, "multipliers": self.multipliers, "n_rows": self.n_rows,
            "row_rules": list(self.row_rules), "train_rmse_db": self.train_rmse_db,
            "test_rmse_db": self.test_rmse_db, "train_rmse_per_dataset_db": dict(self.train_rmse_per_dataset),
            "test_rmse_per_dataset_db": dict(self.test_rmse_per_dataset),
            "rows_per_dataset": dict(self.rows_per_dataset),
            "folds": [{"name": f.name, "n_train": int(len(f.train_rows)), "n_test": int(len(f.test_rows)),
                       "train_rmse_db": f.train_rmse_db, "test_rmse_db": f.test_rmse_db,
                       "train_rmse_per_dataset_db": dict(f.train_rmse_per_dataset),
                       "test_rmse_per_dataset_db": dict(f.test_rmse_per_dataset),
                       "test_multipliers": dict(f.test_multipliers), "refitted": list(f.refitted),
                       "result": f.result, "steps": f.steps, "constants": dict(f.constants),
                       "test_rows": f.test_rows.tolist()} for f in self.folds],
        }

    def summary(self) -> str:
        how = "leave-one-dataset-out" if self.cv == "dataset" else f"{self.k}-fold (seed {self.seed})"
        lines = [f"{self.model}: {how} cross-validation on {self.n_rows} rows, prior strength "
                 f"{self.prior_strength:g}{', multipliers' if self.multipliers else ''}: train "
                 f"{self.train_rmse_db:.2f} dB, held-out {self.test_rmse_db:.2f} dB"]
        for d in self.datasets:
            tr = self.train_rmse_per_dataset.get(d, math.nan)
            lines.append(f"  {d:<24} train {tr:6.2f} dB  held-out {self.test_rmse_per_dataset[d]:6.2f} dB")
        return "\n".join(lines)


# ----------------------------------------------------------------------------- folds
def parse_cv(cv, *, arg: str = "cv") -> tuple[str, int]:
    """``("dataset", 0)`` or ``("k-fold", k)`` from ``cv`` = "dataset" or an int (or digit string) k >= 2;
    ``arg``: how an error names ``cv`` (a command line passes its flag)."""
    if isinstance(cv, str) and cv.strip().lower() in ("dataset", "datasets", "lodo"):
        return "dataset", 0
    k = None
    if isinstance(cv, (int, np.integer)) and not isinstance(cv, bool):
        k = int(cv)
    elif isinstance(cv, str) and cv.strip().lstrip("+").isdigit():
        k = int(cv.strip())
    if k is None or k < 2:
        raise PlodError(f"{arg} must be 'dataset' (leave one dataset out) or a number of folds k >= 2, got {cv!r}")
    return "k-fold", k


def make_folds(dataset: Sequence[str], cv="dataset", seed: int = 0) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """``[(name, train_idx, test_idx)]`` over rows labelled ``dataset`` (indices into it, sorted).

    ``cv="dataset"``: one fold per distinct label (order of first appearance); an int ``k``: the rows
    permuted by ``numpy.random.default_rng(seed)`` and split into ``k`` near-equal parts.
    """
    kind, k = parse_cv(cv)
    dataset = np.asarray(dataset)
    n = len(dataset)
    idx = np.arange(n)
    if kind == "dataset":
        names = list(dict.fromkeys(dataset.tolist()))
        if len(names) < 2:
            raise PlodError(f"leave-one-dataset-out needs at least 2 datasets, got {len(names)} ({names}); "
                            "use a number of folds instead")
        return [(d, idx[dataset != d], idx[dataset == d]) for d in names]
    if not (isinstance(seed, (int, np.integer)) and not isinstance(seed, bool) and seed >= 0):
        raise PlodError(f"seed must be an int >= 0, got {seed!r}")
    if k > n:
        raise PlodError(f"{k} folds need at least {k} rows, got {n}")
    perm = np.random.default_rng(int(seed)).permutation(n)
    parts = np.array_split(perm, k)
    return [(f"fold {i + 1}", np.sort(np.setdiff1d(idx, p)), np.sort(p)) for i, p in enumerate(parts)]


# ----------------------------------------------------------------------------- cross-validation
@eqx.filter_jit
def _predict(theta, fixed, arrays, st):
    return predict_log10(theta, fixed, arrays, st)


def _pad_rows(arrays: dict, n_pad: int) -> dict:
    n = len(arrays["f"])
    return {k: np.concatenate([a, np.repeat(a[:1], n_pad - n)]) for k, a in arrays.items()}


def _rmse_db(r) -> float:
    r = np.asarray(r, np.float64)
    return float(20.0 * np.sqrt(np.mean(r * r))) if r.size else math.nan


def _pooled(pairs) -> float:
    """RMSE (dB) pooled from [(n, rmse_db)]."""
    n = sum(p[0] for p in pairs)
    return float(math.sqrt(sum(p[0] * p[1] ** 2 for p in pairs) / n)) if n else math.nan


def cross_validate(
    model,
    data,
    *,
    cv="dataset",
    seed: int = 0,
    prior_strength: float = 0.0,
    multipliers: bool = True,
    fit: Sequence[str] | None = None,
    weighted: bool = False,
    rows="auto",
    solver: str = "lm",
    backend: str = "optimistix",
    max_steps: int = 400,
    rtol: float = 1e-8,
    atol: float = 1e-8,
    progress: Progress | None = None,
) -> CVResult:
    """Cross-validate the least-squares fit of ``model`` to ``data`` (see the module docstring).

    Args:
        model: a ``pmetric.CSFModel``: every training fit starts from it (and its prior is centred on it).
        data: ``optim.fit.CalibrationData``.
        cv: ``"dataset"`` (leave one dataset out) or an int ``k >= 2`` (k-fold, folds from ``seed``).
        prior_strength: lambda of the Gaussian prior of every training fit (0: none).
        multipliers: one sensitivity multiplier per training dataset (and, for a held-out dataset not in
            training, one refitted on its held-out rows alone).
        fit, weighted, rows, solver, backend, max_steps, rtol, atol: as in ``fit_least_squares``.
        progress: None or ``progress(stage, done, total)``, stage ``"folds"``.

    Returns:
        ``CVResult``.
    """
    kind, k = parse_cv(cv)
    _check_solver_args(solver, backend, max_steps, rtol, atol)
    lam = _check_prior_strength(prior_strength)
    with jax.enable_x64(True):
        full = Problem(model, data, fit=fit, multipliers=multipliers, weighted=weighted, rows=rows)
        where = np.flatnonzero(full.mask)  # expressible rows, indices into data
        folds = make_folds(np.asarray(data.dataset)[where], cv, seed)
        n_pad = max(len(tr) for _, tr, _ in folds)
        n_pad_test = max(len(te) for _, _, te in folds)
        out_folds, test_r, test_ds = [], [], []
        train_pairs: dict[str, list] = {}
        if progress is not None:
            progress("folds", 0, len(folds))
        for i, (name, tr, te) in enumerate(folds):
            train_rows, test_rows = where[tr], where[te]
            prob = Problem(model, data.subset(train_rows), fit=fit, multipliers=multipliers, weighted=weighted,
                           rows="all")
            res = solve_problem(prob, solver=solver, backend=backend, max_steps=max_steps, rtol=rtol, atol=atol,
                                prior_strength=lam, pad_to=n_pad)
            # held-out rows: predicted by the trained constants (the test data never enters the fit above)
            test = data.subset(test_rows)
            arrays = row_arrays(model, test, weighted, np.zeros(len(test), np.int32))
            fixed = [np.asarray(x, np.float64) for x in prob.leaves]
            pred = np.asarray(_predict(jnp.asarray(res.theta), fixed, _pad_rows(arrays, n_pad_test),
                                       prob.static))[: len(test)]
            diff = pred - arrays["y"]  # log10, model - data, before the multiplier
            w = arrays["sw"] ** 2
            r = np.empty_like(diff)
            mults, refitted = {}, []
            for d in test.datasets:
                m = test.dataset == d
                if multipliers and d in res.multipliers:
                    lm = math.log10(res.multipliers[d])
                elif multipliers:
                    lm = -float(np.sum(w[m] * diff[m]) / np.sum(w[m]))  # closed-form LS multiplier
                    refitted.append(d)
                else:
                    lm = 0.0
                mults[d] = 10.0 ** lm
                r[m] = diff[m] + lm
            per_test = {d: _rmse_db(r[test.dataset == d]) for d in test.datasets}
            train_ds = np.asarray(prob.data.dataset)
            for d, v in res.rmse_per_dataset.items():
                train_pairs.setdefault(d, []).append((int(np.sum(train_ds == d)), v))
            out_folds.append(CVFold(
                name=name, train_rows=train_rows, test_rows=test_rows, train_rmse_db=res.rmse_db,
                test_rmse_db=_rmse_db(r), train_rmse_per_dataset=dict(res.rmse_per_dataset),
                test_rmse_per_dataset=per_test, test_multipliers=mults, refitted=tuple(refitted),
                constants={n: float(v) for n, v in zip(res.param_names, res.values)}, result=res.result,
                steps=res.steps, test_residuals=r))
            test_r.append(r)
            test_ds.append(np.asarray(test.dataset))
            if progress is not None:
                progress("folds", i + 1, len(folds))
    all_r, all_ds = np.concatenate(test_r), np.concatenate(test_ds)
    names = list(dict.fromkeys(np.asarray(data.dataset)[where].tolist()))
    return CVResult(
        model=type(model).__name__, cv=kind, k=len(folds), seed=int(seed), prior_strength=lam,
        multipliers=bool(multipliers), n_rows=len(where), rows=full.mask, row_rules=tuple(full.reasons),
        train_rmse_db=_pooled([(len(f.train_rows), f.train_rmse_db) for f in out_folds]),
        test_rmse_db=_rmse_db(all_r),
        train_rmse_per_dataset={d: _pooled(train_pairs[d]) for d in names if d in train_pairs},
        test_rmse_per_dataset={d: _rmse_db(all_r[all_ds == d]) for d in names},
        rows_per_dataset={d: int(np.sum(all_ds == d)) for d in names},
        folds=tuple(out_folds),
    )


def select_prior_strength(model, data, *, grid: Sequence[float] = PRIOR_GRID, progress: Progress | None = None,
                          **kwargs) -> tuple[float, dict]:
    """The prior strength of least held-out RMSE over ``grid``, and ``{lambda: CVResult}``.

    ``kwargs`` go to ``cross_validate`` (``cv``, ``seed``, ``multipliers``, ...); progress stage
    ``"prior strength"`` (grid points done). Ties go to the stronger prior.
    """
    grid = [_check_prior_strength(g) for g in grid]
    if not grid:
        raise PlodError("the prior-strength grid is empty")
    results = {}
    for i, lam in enumerate(grid):
        if progress is not None:
            progress("prior strength", i, len(grid))
        results[lam] = cross_validate(model, data, prior_strength=lam, **kwargs)
    if progress is not None:
        progress("prior strength", len(grid), len(grid))
    best = min(results, key=lambda lam: (results[lam].test_rmse_db, -lam))
    return best, results


def held_out_rmse(model, data, *, multipliers: bool = True, rows="auto", weighted: bool = False) -> dict:
    """RMSE (dB) of ``model``'s constants, as they are, on data no fit saw (an external test set).

    With ``multipliers`` each dataset gets one sensitivity multiplier refitted on its own rows alone
    (closed form, as in ``cross_validate``); nothing else is fitted. Returns ``{dataset: {"rmse_db",
    "multiplier", "n_rows"}}`` plus ``"overall"`` (pooled ``rmse_db`` and ``n_rows``).
    """
    with jax.enable_x64(True):
        prob = Problem(model, data, multipliers=False, weighted=weighted, rows=rows, min_rows=False)
        fixed, arrays = [np.asarray(x, np.float64) for x in prob.leaves], prob.arrays
        pred = np.asarray(_predict(jnp.asarray(prob.theta0), fixed, arrays, prob.static))
    diff, w = pred - arrays["y"], arrays["sw"] ** 2
    out, all_r = {}, []
    for i, d in enumerate(prob.group_names):
        m = prob.group == i
        lm = -float(np.sum(w[m] * diff[m]) / np.sum(w[m])) if multipliers else 0.0
        r = diff[m] + lm
        all_r.append(r)
        out[d] = {"rmse_db": _rmse_db(r), "multiplier": 10.0 ** lm, "n_rows": int(m.sum())}
    r = np.concatenate(all_r)
    out["overall"] = {"rmse_db": _rmse_db(r), "n_rows": int(r.size)}
    return out

"""optim.fit: fitting the constants of CSF models to contrast thresholds.

One home for everything fitting touches (data flows pmetric <- optim.fit <- experiments):

* ``_data``: ``CalibrationData``, contrast thresholds read from CSV or built from arrays;
* ``_simulate``: simulated observers and calibration sessions (``SimulatedObserver``, ``fade_in_session``,
  ``staircase_2afc``) that produce ``CalibrationData``;
* ``_problem``: the parametrisation shared by every fit (parameter layout, bounds reparametrisation,
  rows a model can express, residuals);
* ``_least_squares``: ``fit_least_squares`` and its ``FitResult`` (outcomes: ``optx.RESULTS`` members);
* ``_priors`` and ``_mcmc``: ``fit_mcmc`` (emcee), its ``Posterior`` and the ``conservative`` model;
  ``ridge_log_prior``, the Gaussian prior toward the published constants that both fitters use
  (``prior_strength=``);
* ``_cv``: ``cross_validate`` (leave-one-dataset-out, k-fold) and its ``CVResult``,
  ``select_prior_strength`` (the prior's strength chosen by held-out error).
"""

# Each private module adds its public names below (one import line per module).
from ._data import CalibrationData
from ._simulate import RULES, SimulatedObserver, Stimuli, fade_in_session, staircase_2afc, stimulus_grid
from ._problem import DATA_ATTRIBUTES, expressible_rows, fitted_fields
from ._least_squares import BACKENDS, OUTCOMES, SOLVERS, FitResult, fit_least_squares, outcome_name
from ._priors import LogUniform, Normal, Uniform, ridge_log_prior
from ._mcmc import ChainTooShortWarning, Posterior, conservative, fit_mcmc
from ._cv import PRIOR_GRID, CVFold, CVResult, cross_validate, held_out_rmse, make_folds, select_prior_strength

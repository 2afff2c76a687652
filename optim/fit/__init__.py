"""optim.fit: fitting the constants of CSF models to contrast thresholds.

One home for everything fitting touches (data flows pmetric <- optim.fit <- experiments):

* ``_data``: ``CalibrationData``, contrast thresholds read from CSV or built from arrays;
* ``_simulate``: simulated observers and calibration sessions (``SimulatedObserver``, ``fade_in_session``,
  ``staircase_2afc``) that produce ``CalibrationData``;
* ``_problem``: the parametrisation shared by every fit (parameter layout, bounds reparametrisation,
  rows a model can express, residuals);
* ``_least_squares``: ``fit_least_squares`` and its ``FitResult`` (outcomes: ``optx.RESULTS`` members);
* ``_priors`` and ``_mcmc``: ``fit_mcmc`` (emcee), its ``Posterior`` and the ``conservative`` model.
"""

# Each private module adds its public names below (one import line per module).
from ._data import CalibrationData
from ._simulate import RULES, SimulatedObserver, Stimuli, fade_in_session, staircase_2afc, stimulus_grid
from ._problem import DATA_ATTRIBUTES, expressible_rows, fitted_fields
from ._least_squares import BACKENDS, OUTCOMES, SOLVERS, FitResult, fit_least_squares, outcome_name
from ._priors import LogUniform, Normal, Uniform
from ._mcmc import ChainTooShortWarning, Posterior, conservative, fit_mcmc

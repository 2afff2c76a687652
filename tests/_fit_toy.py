"""A small CSF model and simulated thresholds shared by tests/test_fit.py and tests/test_mcmc.py."""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

try:  # the project's abstract base (pmetric/_base.py) when present
    from pmetric._base import CSFModel as _Base
except ImportError:  # pragma: no cover - only while the base class is being written
    _Base = eqx.Module

from pmetric import CalibrationData


def _arr(x):
    return jnp.asarray(x, dtype=jnp.result_type(float))


class ToyCSF(_Base):
    """log-parabola CSF with an eccentricity drop: 4 constants, bounds of every kind.

    log10 S = log10 gain - (log10 f - log10 f_peak)^2 / width - drop * e * f
    """

    gain: jax.Array = eqx.field(converter=_arr, default=200.0)
    f_peak: jax.Array = eqx.field(converter=_arr, default=4.0)
    width: jax.Array = eqx.field(converter=_arr, default=1.2)
    drop: jax.Array = eqx.field(converter=_arr, default=0.01)

    inputs: ClassVar[tuple[str, ...]] = ("f", "e")
    param_bounds: ClassVar[dict] = {
        "gain": (0.0, None), "f_peak": (0.1, 60.0), "width": (0.05, 20.0), "drop": (0.0, 1.0),
    }

    def sensitivity(self, f, e=0.0, v=0.0):
        f = jnp.asarray(f)
        ok = f > 0
        lf = jnp.log10(jnp.where(ok, f, 1.0))
        ls = jnp.log10(self.gain) - (lf - jnp.log10(self.f_peak)) ** 2 / self.width - self.drop * e * f
        return jnp.where(ok, 10.0 ** ls, 0.0)

    def stimulus_sensitivity(self, f, e=0.0, v=0.0, luminance=None, area=None):
        return self.sensitivity(f, e, v)


TRUE = dict(gain=150.0, f_peak=3.0, width=0.9, drop=0.02)


def simulate(seed=0, n=800, noise=0.01, n_datasets=2, mult=None, model=None):
    """Thresholds of ``model`` (default ToyCSF(**TRUE)) with log10 Gaussian noise of s.d. ``noise``."""
    rng = np.random.default_rng(seed)
    model = model or ToyCSF(**TRUE)
    f = 10 ** rng.uniform(-0.5, 1.2, n)
    e = np.where(rng.uniform(size=n) < 0.5, 0.0, rng.uniform(0, 10, n))
    ds = np.array([f"d{i % n_datasets}" for i in range(n)])
    with jax.enable_x64(True):
        ls = np.log10(np.asarray(model.stimulus_sensitivity(f, e), np.float64))
    if mult is not None:
        ls = ls + np.log10(np.asarray(mult))[np.arange(n) % n_datasets]
    ls = ls + noise * rng.standard_normal(n)
    return CalibrationData.from_arrays(f, log_threshold=-ls, e=e, dataset=ds, luminance=50.0, area=2.0)

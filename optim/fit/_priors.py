"""Priors for ``fit_mcmc``: densities of the natural values of fitted constants, and the ridge prior.

``ridge_log_prior`` is the Gaussian prior of the regularised fits: independent ``N(u0_j, sigma^2 /
lambda)`` on the unconstrained coordinates ``u_j`` (log / logit of the constant, ``optim.fit._problem``)
of every fitted constant, centred on the starting (published) constants ``u0``, with ``sigma`` the
data noise s.d. (log10 units). ``-2 sigma^2`` times the log posterior is then ``SSR + lambda sum_j
(u_j - u0_j)^2`` up to a constant, so the maximum a posteriori point at any ``sigma`` is the
regularised least-squares fit (``fit_least_squares(prior_strength=lambda)``): one prior, two fitters.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp

from pmetric import PlodError

__all__ = ["LogUniform", "Normal", "Uniform", "ridge_log_prior"]


def ridge_log_prior(du, lam: float, ln_sigma):
    """Log density of ``du = u - u0`` (shape (k,)) under ``N(0, sigma^2 / lam)`` each, ``lam > 0``.

    ``ln_sigma``: natural log of the data noise s.d. (log10 units), a scalar (traced or not).
    """
    k = du.shape[0]
    return (-0.5 * lam * jnp.sum(du * du) * jnp.exp(-2.0 * ln_sigma)
            + 0.5 * k * math.log(lam / (2.0 * math.pi)) - k * ln_sigma)


class Uniform(eqx.Module):
    """Flat density on [lo, hi] (natural units of the constant)."""

    lo: float
    hi: float

    def __check_init__(self):
        if not (math.isfinite(self.lo) and math.isfinite(self.hi) and self.hi > self.lo):
            raise PlodError(f"Uniform prior needs finite lo < hi, got ({self.lo}, {self.hi})")

    def log_prob(self, x):
        inside = (x >= self.lo) & (x <= self.hi)
        return jnp.where(inside, -math.log(self.hi - self.lo), -jnp.inf)


class LogUniform(eqx.Module):
    """Density proportional to 1/x on [lo, hi], 0 < lo < hi (flat in log x)."""

    lo: float
    hi: float

    def __check_init__(self):
        if not (math.isfinite(self.hi) and 0 < self.lo < self.hi):
            raise PlodError(f"LogUniform prior needs 0 < lo < hi, got ({self.lo}, {self.hi})")

    def log_prob(self, x):
        inside = (x >= self.lo) & (x <= self.hi)
        xs = jnp.where(inside, x, 1.0)
        return jnp.where(inside, -jnp.log(xs) - math.log(math.log(self.hi / self.lo)), -jnp.inf)


class Normal(eqx.Module):
    """Gaussian density N(mean, sd^2) (natural units)."""

    mean: float
    sd: float

    def __check_init__(self):
        if not (math.isfinite(self.mean) and math.isfinite(self.sd) and self.sd > 0):
            raise PlodError(f"Normal prior needs a finite mean and sd > 0, got ({self.mean}, {self.sd})")

    def log_prob(self, x):
        z = (x - self.mean) / self.sd
        return -0.5 * z * z - math.log(self.sd * math.sqrt(2 * math.pi))


def as_prior(name, p):
    """A prior object from a prior or a ``(lo, hi)`` pair (-> ``Uniform``)."""
    if isinstance(p, (Uniform, LogUniform, Normal)):
        return p
    if isinstance(p, (tuple, list)) and len(p) == 2:
        return Uniform(float(p[0]), float(p[1]))
    raise PlodError(f"prior for {name!r} must be Uniform, LogUniform, Normal or a (lo, hi) tuple, got {p!r}")

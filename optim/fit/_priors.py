"""Priors on the natural values of fitted constants, for ``fit_mcmc``."""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp

from pmetric import PlodError

__all__ = ["LogUniform", "Normal", "Uniform"]


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

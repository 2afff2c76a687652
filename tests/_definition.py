"""Brute-force check of the imperceptible-distance definition (``pmetric.CSFModel.imperceptible_distance``),
shared by the model test files."""

import jax
import numpy as np

perceptible = jax.jit(lambda m, c, f, e, v: m.is_perceptible(c, f, e, v))
distance = jax.jit(lambda m, c, t, e, v: m.imperceptible_distance(c, t, e, v))


def check_distance_definition(m, c, theta, e, v, grid, rel, n_fine):
    """In float64: nothing on ``grid`` (k values) nor on ``n_fine`` points just above the answer k is
    perceptible beyond ``k (1 + rel)``, and the change is perceptible at ``k (1 - rel)`` when k > 0.
    Returns ``(k, kk, p)``: the answer, the k values checked and their perceptibility."""
    with jax.enable_x64(True):
        k = float(distance(m, c, theta, e, v))
        kk = np.concatenate([grid, k * (1 + np.geomspace(rel, 1.0, n_fine))]) if k > 0 else grid
        p = np.asarray(perceptible(m, c, kk / (2 * theta), e / kk, v / kk))
        assert not p[kk > k * (1 + rel)].any(), (k, kk[p].max())  # nothing beyond k is perceptible
        if k > 0:
            ks = k * (1 - rel)
            assert bool(perceptible(m, c, ks / (2 * theta), e / ks, v / ks)), k  # perceptible at k
    return k, kk, p


def _generic(hook, m, method, **arrays):
    """The base class's generic hook ``CSFModel.<hook>`` (not the model's closed form) on inputs checked
    and cast as the public methods do."""
    import jax.numpy as jnp

    from pmetric._base import CSFModel

    mm, *xs, shape = m._checked(method, **arrays)
    return jnp.broadcast_to(getattr(CSFModel, hook)(mm, *xs), shape)


def generic_distance(m, c, theta, e=0.0, v=0.0):
    """``imperceptible_distance`` by the generic scan of :class:`pmetric.CSFModel`."""
    return _generic("_imperceptible_distance", m, "imperceptible_distance", c=c, theta=theta, e=e, v=v)


def generic_threshold_frequency(m, c, e=0.0, v=0.0):
    """``threshold_frequency`` by the generic root finder of :class:`pmetric.CSFModel`."""
    return _generic("_threshold_frequency", m, "threshold_frequency", c=c, e=e, v=v)

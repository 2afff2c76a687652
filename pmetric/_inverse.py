"""Exact, vectorized, differentiable inversions used by the CSF models.

* :func:`lambertw_m1` -- the lower branch ``W_{-1}(x)`` of the Lambert W function on ``[-1/e, 0)``
  (``jax.scipy.special`` only has the principal branch). Halley iteration from the branch-point
  series / the asymptotic expansion [Cor96], three unrolled steps: elementwise and fusable. Exact derivative by ``custom_jvp``.
* :func:`bracketed_root` -- the root of a function that changes sign from ``>= 0`` to ``< 0`` inside a
  bracket: Newton with bisection safeguard (``rtsafe``, Numerical Recipes section 9.4), a fixed
  number of iterations so it is jit/vmap clean.
* :func:`largest_crossing` -- the LARGEST ``x`` in a log-spaced search range at which ``g(x) >= 0``:
  scans a grid from the bottom, keeps the last grid point where ``g >= 0`` and refines the crossing
  above it with :func:`bracketed_root`. This is how the generic ``CSFModel.imperceptible_distance``
  finds the largest perceptible viewing-distance multiple even when perceptibility is not monotone
  in distance (Kelly's velocity term).
* :func:`implicit_root` -- attaches the implicit-function-theorem derivative ``dx*/dp = -g_p / g_x``
  to a root computed under ``stop_gradient``: the value is returned unchanged and the gradient with
  respect to everything ``g`` closes over (inputs and model constants) is exact.
"""

from __future__ import annotations

from functools import partial
from typing import Callable

import jax
import jax.numpy as jnp
from jax import lax

from ._numerics import as_float, safe_div

__all__ = ["lambertw_m1", "bracketed_root", "largest_crossing", "implicit_root", "implicit_solution", "safe_div"]

_INV_E = 0.36787944117144233


def _lambertw_m1_impl(x):
    dtype = x.dtype
    # x in [-1/e, 0); clip so that the result is finite at the ends (x -> 0- gives W -> -inf).
    tiny = jnp.finfo(dtype).tiny
    xc = jnp.clip(x, -_INV_E, -tiny)
    # Start 1: branch-point series in p = -sqrt(2 (1 + e x)) [Cor96 Eq 4.22].
    p = -jnp.sqrt(jnp.maximum(2.0 * (1.0 + jnp.e * xc), 0.0))
    w_bp = -1.0 + p - p * p / 3.0 + (11.0 / 72.0) * p * p * p - (43.0 / 540.0) * p**4
    # Start 2: asymptotic series near 0- [Cor96 Eq 4.19] with L1 = ln(-x), L2 = ln(-L1).
    l1 = jnp.log(-xc)
    l2 = jnp.log(jnp.maximum(-l1, 1e-30))
    w_as = l1 - l2 + l2 / l1 + l2 * (l2 - 2.0) / (2.0 * l1 * l1)
    w = jnp.where(xc < -0.25, w_bp, w_as)
    w = jnp.minimum(w, -1.0)
    for _ in range(3):  # Halley on f(w) = w e^w - x; cubic convergence
        ew = jnp.exp(w)
        f = w * ew - xc
        wp1 = w + 1.0
        near_bp = jnp.abs(wp1) < 1e-4
        wp1s = jnp.where(near_bp, -1e-4, wp1)
        den = ew * wp1s - (w + 2.0) * f / (2.0 * wp1s)
        step = safe_div(f, den)
        w = jnp.where(near_bp, w, jnp.minimum(w - step, -1.0))
    return w


@jax.custom_jvp
def lambertw_m1(x):
    """Lower branch ``W_{-1}(x)`` of the Lambert W function, elementwise, for ``x`` in ``[-1/e, 0)``.

    ``W_{-1}`` solves ``w e^w = x`` with ``w <= -1``. ``x`` is clipped into ``[-1/e, -tiny]``, so
    ``lambertw_m1(-1/e) = -1`` and values close to 0 give large negative (finite) ``w``.
    Derivative ``W / (x (1 + W))`` (infinite at the branch point; there it is clamped to a large finite
    number). Relative error about 1 ulp in float64 and float32.
    """
    return _lambertw_m1_impl(as_float(x))


@lambertw_m1.defjvp
def _lambertw_m1_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    w = lambertw_m1(x)
    xs = jnp.asarray(x, w.dtype)
    dwdx = safe_div(w, xs * jnp.minimum(1.0 + w, -jnp.sqrt(jnp.finfo(w.dtype).eps)))
    return w, dwdx * dx


def bracketed_root(g: Callable, lo, hi, n_iter: int = 40):
    """Root of an elementwise function ``g`` in ``[lo, hi]`` with ``g(lo) >= 0 > g(hi)``.

    Safeguarded Newton (``rtsafe``): a Newton step is taken when it stays inside the current bracket
    and at least halves it, otherwise a bisection step; every step shrinks the bracket, so after
    ``n_iter`` (fixed, for jit) iterations the bracket is at most ``2^-n_iter`` of the initial one and
    typically at machine precision. Returns the lower end ``lo`` (where ``g >= 0`` still holds),
    under ``stop_gradient``; use :func:`implicit_root` for derivatives.
    """
    lo = lax.stop_gradient(lo)
    hi = lax.stop_gradient(hi)

    def body(_, state):
        lo, hi, x = state
        gx, dg = jax.jvp(g, (x,), (jnp.ones_like(x),))
        gx, dg = lax.stop_gradient(gx), lax.stop_gradient(dg)
        pos = gx >= 0
        lo = jnp.where(pos, x, lo)
        hi = jnp.where(pos, hi, x)
        newton = x - safe_div(gx, dg)
        ok = (newton > lo) & (newton < hi) & jnp.isfinite(newton) & (jnp.abs(newton - x) < 0.5 * (hi - lo))
        x = jnp.where(ok, newton, 0.5 * (lo + hi))
        return lo, hi, x

    lo, hi, _ = lax.fori_loop(0, n_iter, body, (lo, hi, 0.5 * (lo + hi)))
    return lo


def largest_crossing(g: Callable, lo, hi, n_grid: int = 65, n_iter: int = 40):
    """Largest ``x`` in ``[lo, hi]`` with ``g(x) >= 0`` (``g`` elementwise, ``lo``, ``hi`` arrays).

    Scans ``n_grid`` equally spaced points from ``lo`` to ``hi`` (pass log-values for a log grid),
    remembers the last point where ``g >= 0`` and refines the crossing between it and the next grid
    point with :func:`bracketed_root`. Returns ``(x, found, saturated)``: ``found`` is False where
    ``g < 0`` at every grid point (``x`` is then ``lo``); ``saturated`` is True where ``g(hi) >= 0``
    (``x`` is then ``hi``). Memory is O(size of the inputs), not O(n_grid x size).
    Exact (to the root finder's precision) under the assumption that ``g`` has no positive excursion
    narrower than one grid step above the last positive grid point.
    """
    lo = lax.stop_gradient(jnp.asarray(lo))
    hi = lax.stop_gradient(jnp.asarray(hi))
    step = (hi - lo) / (n_grid - 1)

    def scan(j, state):
        last = state
        x = lo + j * step
        return jnp.where(g(x) >= 0, x, last)

    neg = jnp.full(jnp.broadcast_shapes(lo.shape, hi.shape), -jnp.inf, dtype=lo.dtype)
    last = lax.fori_loop(0, n_grid, scan, neg)
    found = jnp.isfinite(last)
    saturated = found & (last >= hi - 0.5 * step)
    a = jnp.where(found & ~saturated, last, lo)
    b = jnp.where(found & ~saturated, last + step, lo + step)
    root = bracketed_root(g, a, b, n_iter)
    x = jnp.where(saturated, hi, jnp.where(found, root, lo))
    return x, found, saturated


def implicit_root(g: Callable, x_star, mask=None):
    """Give a root ``x*`` of ``g`` (computed without gradients) the implicit-function derivative.

    Returns ``x*`` exactly; its derivative with respect to anything ``g`` closes over is
    ``-(dg/dp) / (dg/dx)`` evaluated at ``x*`` (finite: ``dg/dx`` is kept away from 0). Where ``mask``
    is False the root is returned with zero derivative.
    """
    x_star = lax.stop_gradient(x_star)
    gx, dg = jax.jvp(g, (x_star,), (jnp.ones_like(x_star),))
    dg = lax.stop_gradient(dg)
    floor = jnp.sqrt(jnp.finfo(dg.dtype).tiny)  # 1/floor^2 stays finite: no 0 * inf in any rule
    dg = jnp.where(jnp.abs(dg) > floor, dg, jnp.where(dg < 0, -floor, floor))
    num = gx - lax.stop_gradient(gx)
    if mask is not None:  # masked out: 0 / 1, so no NaN leaks into the gradient (double where)
        num = jnp.where(mask, num, 0.0)
        dg = jnp.where(mask, dg, 1.0)
    return x_star - num / dg


def implicit_solution(margin: Callable, x_star, mask, *args):
    """:func:`implicit_root` without forward cost: ``x*`` whose derivative ``-(dg/dp . dp) / (dg/dx)``
    (``g = margin(x, *args)``) is computed only when the result is differentiated (``jax.custom_jvp``).

    ``margin`` must be a function of its arguments only (no closed-over arrays that need
    derivatives): everything to differentiate through, model included, goes in ``args``. Where
    ``mask`` is False the derivative is 0. ``x*`` is taken under ``stop_gradient``. As in
    :func:`implicit_root`, ``dg/dx`` is held constant under further differentiation.
    """
    return _implicit_solution(margin, lax.stop_gradient(x_star), mask, *args)


@partial(jax.custom_jvp, nondiff_argnums=(0,))
def _implicit_solution(margin, x_star, mask, *args):
    return x_star


@_implicit_solution.defjvp
def _implicit_solution_jvp(margin, primals, tangents):
    x_star, mask, *args = primals
    dargs = tangents[2:]
    _, dg = jax.jvp(lambda x: margin(x, *args), (x_star,), (jnp.ones_like(x_star),))
    dg = lax.stop_gradient(dg)
    _, dgp = jax.jvp(lambda *a: margin(x_star, *a), tuple(args), tuple(dargs))
    floor = jnp.sqrt(jnp.finfo(dg.dtype).tiny)
    dg = jnp.where(jnp.abs(dg) > floor, dg, jnp.where(dg < 0, -floor, floor))
    num = jnp.where(mask, dgp, 0.0)  # double where: no NaN leaks from masked-out elements
    den = jnp.where(mask, dg, 1.0)
    return x_star, jnp.broadcast_to(-num / den, jnp.shape(x_star)).astype(x_star.dtype)

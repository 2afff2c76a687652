"""Guarded numerical primitives and rare-element compaction shared by every pmetric model.

Hand-written because no library offers them in this form: JAX / XLA have no "double-where" guarded
log / power / division (the value is finite where the argument is at an edge, and so is every
derivative, because the unsafe branch never sees the edge value), and no compaction of a rare mask
that stays fast with XLA on CPU (:func:`rare_update`). Every function works in float32 and float64
and is jit / vmap / grad clean.

Numerics standard of ``pmetric``: a log, power, division or exp whose argument can reach an edge
(0, a negative value, +inf) goes through one of these helpers (or the same double-where written out):
``jnp.where(ok, f(jnp.where(ok, x, safe)), fill)``, so that values and gradients stay finite.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jax import lax

__all__ = [
    "SENSITIVITY_FLOOR", "LN_FLOOR", "as_float", "is_tracer", "log_guard", "safe_log", "where_pos",
    "pow_pos", "safe_div", "div_or_zero", "clenshaw", "rare_update",
]

#: Smallest sensitivity the physical models (Barten, stelaCSF) return (threshold contrast <= 1e30).
SENSITIVITY_FLOOR = 1e-30
LN_FLOOR = math.log(SENSITIVITY_FLOOR)


def as_float(x):
    """``x`` as a floating JAX array (integers and bools become the default float dtype)."""
    x = jnp.asarray(x)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    return x


def is_tracer(x) -> bool:
    """True when ``x`` is a JAX tracer (inside jit / grad / vmap), i.e. its value is not known."""
    return isinstance(x, jax.core.Tracer)


def log_guard(x):
    """log(x) for x >= 0 with finite value and gradient at 0: ``log(max(x, 1e-30))``.

    For inputs (contrasts, sensitivities). The floor's log (-69) lies beyond ``LOG_CT_MAX``, and
    1 / floor stays finite in float32 gradients."""
    x = jnp.asarray(x)
    return jnp.log(jnp.maximum(x, 1e-30))


def safe_log(x):
    """log(x) for x > 1e-30; ``LN_FLOOR`` with gradient exactly 0 at and below it (double-where).

    For fitted constants, which a fit may push to or through 0."""
    ok = x > SENSITIVITY_FLOOR
    return jnp.where(ok, jnp.log(jnp.where(ok, x, 1.0)), LN_FLOOR)


def where_pos(x, fn, fill):
    """``fn(x)`` where x > 0 else ``fill``: the double-where pattern (finite gradients at x <= 0)."""
    ok = x > 0
    safe = jnp.where(ok, x, jnp.ones_like(x))
    return jnp.where(ok, fn(safe), fill)


def pow_pos(x, p):
    """x**p for x >= 0: 0 at x <= 0 with a finite (zero) gradient, ``exp(p log x)`` elsewhere."""
    return where_pos(x, lambda s: jnp.exp(p * jnp.log(s)), jnp.zeros_like(x))


def safe_div(num, den, tiny=None):
    """``num / den`` with ``den`` pushed away from 0, keeping its sign: ``|den| < tiny`` becomes
    ``+-tiny`` (``den == 0`` counts as positive), so value and gradient stay finite; the result is
    large (``num / tiny``) where ``den`` is ~0. Default ``tiny``: 1e4 times the smallest normal float.
    Use it where a near-zero denominator means a large step or slope (Newton, Halley)."""
    den = jnp.asarray(den)
    if tiny is None:
        tiny = jnp.finfo(den.dtype if jnp.issubdtype(den.dtype, jnp.floating) else jnp.float32).tiny * 1e4
    small = jnp.abs(den) < tiny
    den_ok = jnp.where(small, jnp.where(den < 0, -tiny, tiny), den)
    return num / den_ok


def div_or_zero(num, den):
    """``num / den`` where ``den != 0``, exactly 0 where ``den == 0`` (double-where: zero gradient
    there). Use it where 0 / 0 means "no quantity" (a ratio of a length to a zero length)."""
    ok = den != 0
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), 0.0)


def clenshaw(t, coeffs):
    """Chebyshev series ``sum_k coeffs[k] T_k(t)``, elementwise (Clenshaw recurrence, unrolled)."""
    b1 = jnp.zeros_like(t)
    b2 = jnp.zeros_like(t)
    for ck in coeffs[:0:-1]:
        b1, b2 = 2.0 * t * b1 - b2 + ck, b1
    return t * b1 - b2 + coeffs[0]


def rare_update(fn, base, mask, args, block: int = 16, max_blocks: int | None = None,
                cap: int | None = None):
    """``base`` with ``fn(*args)`` written where ``mask`` (``fn`` elementwise, returning one array).

    For a rare mask: flat compaction of a large array is slow with XLA on CPU, so it is two-level.
    The blocks of ``block`` elements holding a masked element are gathered (at most ``max_blocks``,
    static), then the masked elements among them (at most ``cap``); ``fn`` runs on those and the
    results are scattered into ``base``. With more masked elements than ``cap`` ``fn`` runs on the
    gathered blocks, with more blocks than ``max_blocks`` on everything, with none not at all
    (``lax.switch`` / ``lax.cond``). Defaults: ``max_blocks`` ``n / 256`` (at least 64), ``cap``
    ``n / 256`` (at least 64), about three times the rate at which the Kelly direct solve leaves
    elements unsettled on random inputs."""
    shape = mask.shape
    m = mask.reshape(-1)
    n = m.size
    b0 = jnp.broadcast_to(base, shape).reshape(-1)
    nblk = -(-n // block)
    pad = nblk * block - n
    flat = [jnp.broadcast_to(a, shape).reshape(-1) for a in args]
    if pad:
        flat = [jnp.pad(a, (0, pad)) for a in flat]
        m = jnp.pad(m, (0, pad))
    mb = m.reshape(nblk, block)
    hit = mb.any(axis=1)
    nb = min(max(64, -(-n // 256)) if max_blocks is None else max_blocks, nblk)
    cap = min(nb * block, max(64, -(-n // 256)) if cap is None else cap)
    drop = n + pad  # out-of-range index: the write is dropped

    def none(b):
        return b

    def full(b):
        return jnp.where(m[:n], fn(*(a[:n] for a in flat)), b)

    def blocks(b):
        (bi,) = jnp.nonzero(hit, size=nb, fill_value=nblk)
        bi_c = jnp.minimum(bi, nblk - 1)
        sub = [a.reshape(nblk, block)[bi_c].reshape(-1) for a in flat]
        msub = (mb[bi_c] & (bi < nblk)[:, None]).reshape(-1)
        idx = (bi_c[:, None] * block + jnp.arange(block)[None, :]).reshape(-1)

        def gathered(b):
            return b.at[jnp.where(msub, idx, drop)].set(fn(*sub), mode="drop")

        def elements(b):
            (ei,) = jnp.nonzero(msub, size=cap, fill_value=msub.size)
            ei_c = jnp.minimum(ei, msub.size - 1)
            w = fn(*(a[ei_c] for a in sub))
            return b.at[jnp.where(ei < msub.size, idx[ei_c], drop)].set(w, mode="drop")

        if cap >= msub.size:
            return gathered(b)
        return lax.cond(msub.sum() <= cap, elements, gathered, b)

    nhit = hit.sum()
    branch = jnp.where(nhit == 0, 0, jnp.where(nhit <= nb, 1, 2))
    return lax.switch(branch, [none, blocks, full], b0).reshape(shape)

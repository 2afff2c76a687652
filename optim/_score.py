"""Per-view scoring of every fold of a vertex tree: :func:`score` and :func:`node_terms`.

``score(tree, view, model, metric)`` returns one key per node, larger = more important to keep the node
unfolded, made monotone (a parent's key is at least its children's [LH01 fn 2]). Units of the keys:

* ``"perceptual"``: the imperceptible distance of the fold [LH01 §5.3], a multiple of the current
  viewing distance: ``k <= 1`` means the fold cannot be seen from here.
* ``"size"``: projected bounding-sphere diameter, pixels (VDSlib's default criterion).
* ``"geometric"``: projected object-space fold error (``tree.geom_error``, largest distance from a
  supported vertex to the proxy), pixels, at the nearest point of the node's bounding sphere.

Named stages, per chunk of internal nodes of the per-tree context (:mod:`optim._context`; leaves
have nothing to fold and get 0): ``classify`` -> ``terms`` -> ``key`` -> ``propagate``.

* ``classify`` and ``terms`` (:mod:`optim._terms`, the one definition of every per-node term):
  facing flags against the silhouette table, cull flags, extent, eccentricity, velocity, contrast,
  geometric error.
* ``key``: ``model.imperceptible_distance(c, theta, e, v)`` (``exact=True`` or with motion), else a
  per-model table ``theta * K(c, e / theta)`` read on the conservative side; or the pixel keys.
* ``propagate`` (:class:`optim._levels.Levels`): culling spread down to whole subtrees, then the
  maximum propagated from the deepest level up (two O(M) numpy passes over the breadth-first levels;
  XLA:CPU runs such level-by-level scatters and prefix scans several times slower than numpy).

The stages run as several XLA programs rather than one: fused together, XLA:CPU recomputes shared
per-node arithmetic inside scalar gather loops. Table mode (perceptual keys without motion, the
default) on a CPU backend with few cores (:func:`_host_gathers`) runs one XLA program per chunk without
gathers (:func:`_table_inputs`: table-word positions, the key-table index of the own contrast, the
silhouette contrast, theta, the band, frustum cull) and does the gathers in numpy
(:func:`_table_keys_host`): XLA:CPU fuses index arithmetic into gather loops as scalar code; on a GPU
or four or more cores the XLA programs with their gathers are faster and run instead (same keys). The
silhouette nodes' table indices come from one more XLA program over those nodes alone
(:func:`_silhouette_indices`, about a fifth of the nodes). All chunks are dispatched before any
result is read, with ``jax.jit`` (asynchronous; ``eqx.filter_jit`` blocks on each call's result), so
numpy's work on one chunk overlaps XLA's on the next. Speed: see ``reports/bench_optim.md``.
"""

from __future__ import annotations

import functools
import hashlib
from pathlib import Path
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from pmetric import PlodError
from pmetric._numerics import div_or_zero

from ._context import scoring_context
from ._normal_cube import table_device
from ._parallel import usable_cores as _usable_cores
from ._terms import (band_width, contrast_pair, classify, extent, eccentricity, facing_flags, facing_host,
                     facing_rows, frustum_culled, cone_facing, terms, terms_jit, view_params, Terms, _geometry)

__all__ = ["score", "node_terms", "NodeTerms", "default_model", "prepare_motion_table", "METRICS"]

METRICS = ("perceptual", "size", "geometric")


# ----------------------------------------------------------------------------------------------
# key: the perceptual key through a contrast table
#: contrast grid: log10 c from -4 to 0; eccentricity-to-size ratio grid: 0, then log10 from -2 to 4.
#: 256 x 96 float32 = 96 KiB, small enough to stay in cache during the per-node gather
_TAB_C = (-4.0, 0.0, 256)
_TAB_R = (-2.0, 4.0, 96)


def _perceptual_table(model) -> np.ndarray:
    """K[j, i] = model.imperceptible_distance(c_j, 1 deg, r_i deg, 0), made conservative: non-decreasing
    in c and, over each r cell, the larger of its two ends. Flat (Nc * Nr,) float32."""
    lc0, lc1, nc = _TAB_C
    lr0, lr1, nr = _TAB_R
    c = np.logspace(lc0, lc1, nc)
    rr = np.concatenate([[0.0], np.logspace(lr0, lr1, nr - 1)])
    cg, rg = np.meshgrid(c, rr, indexing="ij")
    k = np.asarray(jax.jit(lambda m, a, b: m.imperceptible_distance(a, jnp.ones_like(a), b, 0.0))(
        model, jnp.asarray(cg, jnp.float32), jnp.asarray(rg, jnp.float32)), np.float64)
    k = np.where(np.isfinite(k), k, 1e30)
    k = np.maximum.accumulate(k, axis=0)  # non-decreasing in contrast
    k[:, :-1] = np.maximum(k[:, :-1], k[:, 1:])  # cell [r_i, r_i+1): upper end of a monotone pair
    return k.astype(np.float32).ravel()


#: velocity-to-size ratio grid (v / theta, deg/s per deg): 0, then log10 from -2 to 5; sub-samples per
#: cell of the motion table (its entries are the largest key over each cell's ends and sub-samples)
_TAB_W = (-2.0, 5.0, 48)
_W_SUB = 3
_BUILD_BATCH = 1 << 16


def _motion_table(model) -> np.ndarray:
    """K[j, i, l] = model.imperceptible_distance(c_j, 1 deg, r_i deg, w deg/s) over the velocity cell
    ``w`` in [w_l, w_l+1] (the key of a moving fold: ``k(c, theta, e, v) = theta K(c, e / theta,
    v / theta)``, since seen k times farther away a change has e / k and v / k [LH01 §5.3]), made
    conservative: the largest value over the cell's two ends and ``_W_SUB`` log-spaced points between
    them (the key is not monotone in velocity: a band-pass temporal response), then non-decreasing
    in c and, over each r cell, the larger of its two ends, as in :func:`_perceptual_table`. The last
    cell is its lower end (ratios above 10^5 deg/s per deg use 10^5: nothing moves that fast and
    stays visible). Flat (Nc * Nr * Nw,) float32.

    The model is closed over (its constants are compile-time constants), so models with a fast
    direct solve for concrete constants use it (stelaCSF: about 1 us per entry instead of 180 us;
    its compilation is about 30 s on one core, once per process)."""
    lc0, lc1, nc = _TAB_C
    lr0, lr1, nr = _TAB_R
    lw0, lw1, nw = _TAB_W
    c = np.logspace(lc0, lc1, nc)
    rr = np.concatenate([[0.0], np.logspace(lr0, lr1, nr - 1)])
    ends = np.concatenate([[0.0], np.logspace(lw0, lw1, nw - 1)])
    sub = [ends[:1]]
    for l in range(nw - 1):
        a, b = ends[l], ends[l + 1]
        inner = np.linspace(a, b, _W_SUB + 2)[1:] if a == 0 else np.geomspace(a, b, _W_SUB + 2)[1:]
        sub.append(inner)
    ws = np.concatenate(sub)  # ends[l] = ws[l * (_W_SUB + 1)]
    cg, rg, wg = (x.astype(np.float32).ravel() for x in np.meshgrid(c, rr, ws, indexing="ij"))
    fn = jax.jit(lambda a, r, w: model.imperceptible_distance(a, jnp.ones_like(a), r, w))
    n = len(cg)
    k = np.empty(n, np.float64)
    for s in range(0, n, _BUILD_BATCH):
        m = min(_BUILD_BATCH, n - s)
        pad = lambda x: np.pad(x[s:s + m], (0, _BUILD_BATCH - m), constant_values=1.0)  # noqa: E731
        k[s:s + m] = np.asarray(fn(pad(cg), pad(rg), pad(wg)), np.float64)[:m]
    k = np.where(np.isfinite(k), k, 1e30).reshape(nc, nr, len(ws))
    step = _W_SUB + 1
    cells = np.empty((nc, nr, nw))
    for l in range(nw - 1):
        cells[:, :, l] = k[:, :, l * step:(l + 1) * step + 1].max(-1)
    cells[:, :, nw - 1] = k[:, :, -1]
    cells = np.maximum.accumulate(cells, axis=0)  # non-decreasing in contrast
    cells[:, :-1] = np.maximum(cells[:, :-1], cells[:, 1:])  # r cell: the larger of its ends
    return cells.astype(np.float32).ravel()


class _KeyTable(NamedTuple):
    device: jax.Array
    host: np.ndarray
    band: "BandBound"  # band_bound: the thin-band key's constants, with their bounds off the gaze


#: Retinal velocities (deg/s) over which :func:`band_constant` bounds a moving band: 0 and a log grid
#: to 10^4 deg/s (beyond it nothing stays visible: the motion table's last cell is 10^5 deg/s per deg).
_BAND_VELOCITIES = np.concatenate([[0.0], np.logspace(-2.0, 4.0, 49)])


def band_constant(model, motion: bool = False) -> tuple:
    """``(M, f*)``: ``M = max_f f S(f, 0)`` and its frequency ``f*`` (cycles/deg) for ``model``, on a log
    grid of 2049 frequencies over [1e-2, 10^2.5] cycles/deg; M rounded up by 1 % (the grid step is
    0.5 %), f* by one grid step. A band of width ``w`` deg and contrast ``c`` is imperceptible beyond
    ``2 c w M`` times the viewing distance whatever channel sees it, and the channel that attains it
    is at ``f*`` (see :func:`thin_band_key`). With ``motion``: ``M`` the largest over the retinal
    velocities ``_BAND_VELOCITIES`` too (a moving band seen k times farther moves at v / k, any of them)
    and ``f*`` the highest of the per-velocity peaks, so the thin-band key stays a bound for moving
    folds (a band-pass temporal response can raise S above its static value)."""
    f = np.logspace(-2.0, 2.5, 2049)
    vs = _BAND_VELOCITIES if motion else np.zeros(1)
    sens_fn = jax.jit(lambda m, x, v: m.sensitivity(x, jnp.zeros_like(x), v))
    best, f_star = 0.0, 0.0
    for v in vs:
        sens = np.asarray(sens_fn(model, jnp.asarray(f, jnp.float32), jnp.float32(v)), np.float64)
        fs = np.where(np.isfinite(sens), f * sens, 0.0)
        j = int(np.argmax(fs))
        best, f_star = max(best, float(fs[j])), max(f_star, float(f[min(j + 1, len(f) - 1)]))
    return best * 1.01, f_star


#: Eccentricity grid (deg) of :func:`band_constants`: 0, then 0.1 to 100 deg at 16 points per decade.
BAND_ECCENTRICITIES = np.concatenate([[0.0], np.logspace(-1.0, 2.0, 49)])
#: Scales a (deg) of the envelopes ``b / (1 + e / a)`` of :func:`band_bound` (with the foveal bound b = 1,
#: a = inf): the band key's closed forms.
BAND_SCALES = (0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0)


class BandBound(NamedTuple):
    """What the thin-band key needs of a model (float32 arrays): ``m0`` the band constant ``M = max_f
    f S(f, 0)`` (:func:`band_constant`), ``f_star`` where it is, and the envelopes of :func:`band_bound`:
    ``M(e) <= m0 b_i / (1 + e inv_a_i)`` for e in [0, 100] deg, ``M(e) <= m0 tail`` beyond."""
    m0: np.ndarray
    f_star: np.ndarray
    b: np.ndarray  # (P,)
    inv_a: np.ndarray  # (P,) 1 / deg
    tail: np.ndarray


@eqx.filter_jit
def _grid_sensitivity(model, f, e, v):
    """S(f, e, v) on the grid (E, F) of eccentricities ``e`` (E,) and frequencies ``f`` (F,): one program
    per model type (the model's constants traced), not one per model."""
    return model.sensitivity(f[None, :], e[:, None], v)


def band_constants(model, motion: bool = False) -> tuple:
    """``(M_e, f*)``: ``M_e`` (E,) float64 the band constant of :func:`band_constant` per eccentricity
    cell of :data:`BAND_ECCENTRICITIES`: ``M_e[0]`` is ``band_constant``'s ``M`` (eccentricity 0), and
    ``M_e[i]`` the largest of ``max_f f S(f, e_j)`` over the grid points ``e_j >= e_i`` (rounded up by
    1 %, at most ``M_e[0]``), so ``M_e`` never increases and bounds every eccentricity from ``e_i`` on,
    given a sensitivity that falls with eccentricity between grid points and beyond the last (every model
    here: ``tests/test_score.py`` checks it at random eccentricities); ``f*`` as ``band_constant``'s. With
    ``motion``, also the largest over the retinal velocities."""
    m0, f_star = band_constant(model, motion)
    f = jnp.asarray(np.logspace(-2.0, 2.5, 2049), jnp.float32)
    e = jnp.asarray(BAND_ECCENTRICITIES[1:], jnp.float32)
    vs = _BAND_VELOCITIES if motion else np.zeros(1)
    per = np.zeros(len(BAND_ECCENTRICITIES) - 1)
    for v in vs:
        sens = np.asarray(_grid_sensitivity(model, f, e, jnp.float32(v)), np.float64)
        fs = np.where(np.isfinite(sens), np.asarray(f, np.float64)[None, :] * sens, 0.0)
        per = np.maximum(per, fs.max(axis=1))
    suffix = np.maximum.accumulate(per[::-1])[::-1] * 1.01
    return np.concatenate([[m0], np.minimum(suffix, m0)]), f_star


def band_bound(model, motion: bool = False) -> BandBound:
    """The :class:`BandBound` of ``model``: for each scale a of :data:`BAND_SCALES` the least ``b >= 1``
    with ``M(e) <= M0 b / (1 + e / a)`` on every cell ``[e_j, e_j+1)`` of :func:`band_constants`' grid (M
    there at most ``M_e[j]``, ``1 + e / a`` at most its value at ``e_j+1``), b rounded up and 1 / a down to
    float32; ``tail = M_e[-1] / M0`` bounds ``M(e) / M0`` from 100 deg on. A model whose M is 0 gets the
    foveal bound alone."""
    m_e, f_star = band_constants(model, motion)
    m0 = float(m_e[0])
    r = m_e / m0 if m0 > 0 else np.ones_like(m_e)
    g = BAND_ECCENTRICITIES
    bs = [max(1.0, float(np.max(r[:-1] * (1.0 + g[1:] / a)))) for a in BAND_SCALES]
    f32 = np.float32
    up = lambda x: np.nextafter(f32(x), f32(np.inf)) if float(f32(x)) < x else f32(x)  # noqa: E731
    down = lambda x: np.nextafter(f32(x), f32(0)) if float(f32(x)) > x else f32(x)  # noqa: E731
    return BandBound(f32(m0), f32(f_star), np.array([f32(1.0)] + [up(x) for x in bs], f32),
                     np.array([f32(0.0)] + [down(1.0 / a) for a in BAND_SCALES], f32), up(float(r[-1])))


#: the band bound of the pixel metrics (unused by them)
_NO_BAND = BandBound(np.float32(0), np.float32(0), np.zeros(len(BAND_SCALES) + 1, np.float32),
                     np.zeros(len(BAND_SCALES) + 1, np.float32), np.float32(0))


_DEVICE_BANDS: dict = {}


def _device_band(bb: BandBound) -> BandBound:
    """``bb`` on the device, once per bound (the bounds live in the per-model caches; five transfers cost
    about a millisecond, per view otherwise)."""
    hit = _DEVICE_BANDS.get(id(bb))
    if hit is None or hit[0] is not bb:
        if len(_DEVICE_BANDS) > 64:
            _DEVICE_BANDS.clear()
        hit = _DEVICE_BANDS[id(bb)] = (bb, BandBound(*jax.device_put(tuple(np.asarray(x, np.float32) for x in bb))))
    return hit[1]


def band_key(kc, ecc, bb: BandBound, xp=jnp):
    """The largest distance multiple ``k`` at which a thin band with ``kc = 2 c w`` (:func:`thin_band_key`)
    is perceptible to some channel, bounded with the band's eccentricity ``ecc`` (deg, at the current
    distance; None: no gaze). At ``k`` times the distance the band lies at ``ecc / k``, so ``k <= kc
    M(ecc / k)`` with ``M(e) = max_f f S(f, e)``. Where ``ecc / k <= 100`` deg each envelope ``M(x) <= M0 b
    / (1 + x / a)`` of :func:`band_bound` gives ``k (1 + ecc / (a k)) <= b kc M0``, i.e. ``k <= b K0 - ecc /
    a`` with ``K0 = kc M0`` (the bound at eccentricity 0); beyond, ``k <= K0 tail``. So ``k <= max(min_i (b_i
    K0 - ecc / a_i), K0 tail)``, at most K0 (the foveal envelope b = 1, 1 / a = 0) and exactly K0 without
    gaze or at eccentricity 0. Eight products and differences per node, no iteration and no gather."""
    k0 = kc * bb.m0
    if ecc is None:
        return k0
    k = k0
    for i in range(1, len(BAND_SCALES) + 1):
        k = xp.minimum(k, bb.b[i] * k0 - ecc * bb.inv_a[i])
    return xp.maximum(k, k0 * bb.tail)


def thin_band_key(k_own, k_cap, k_a, k_b, kc, k_edge, silhouette, xp=jnp):
    """The key of a silhouette fold whose outline moves within a band of width ``w`` <= ``theta`` (deg).

    A visual channel of half-period ``s`` (frequency ``1 / (2 s)``) averages the band over ``s``: it
    sees contrast ``c w / s`` at size ``s``, for ``s`` in ``[w, theta]`` (a narrower channel sees at
    most the band's own contrast ``c``, a wider one no longer fits the node). The fold is
    imperceptible beyond the largest of those channels' distances, ``max_s k(c w / s, s, e)``. At
    distance ``k`` the channel of half-period ``s`` has frequency ``f = k / (2 s)`` and sees
    ``c (2 w f / k) S(f)``, so an interior maximum is at ``f* = argmax f S(f)`` with value
    ``kc = 2 c w M`` (:func:`band_constant`, at eccentricity 0, where S is largest; off the gaze the
    tighter :func:`band_key`, which callers pass as ``kc``), and it lies in the interval only if
    ``kc <= k_edge = 2 theta f*`` (with eccentricity the
    peak moves to lower frequencies, so ``k_edge`` still bounds it); otherwise the maximum is at an
    end, ``k_a = k(c w / theta, theta, e)`` or ``k_b = k(c, w, e)``. Every channel's key is at most
    the whole-node key ``k_cap = k(c, theta, e)`` (smaller and fainter). So the silhouette key is
    ``min(k_cap, max(k_a, k_b, min(kc, k_edge)))``, and a silhouette node's key is the larger of it
    and its own fold's ``k_own``; other nodes keep ``k_own``. ``xp``: jax.numpy or numpy."""
    inner = xp.minimum(kc, k_edge)
    thin = xp.minimum(k_cap, xp.maximum(xp.maximum(k_a, k_b), inner))
    return xp.where(silhouette, xp.maximum(k_own, thin), k_own)


_TABLES: dict = {}
_BANDS: dict = {}
_BANDS_MOTION: dict = {}


def _model_key(model) -> tuple:
    """The model's type, structure and constants (bytes): what the per-model caches are keyed by."""
    leaves = jax.tree_util.tree_leaves(model)
    return (type(model).__qualname__, str(jax.tree_util.tree_structure(model)),
            tuple(np.asarray(x).tobytes() for x in leaves))


def _per_model(cache: dict, model, build):
    """``build(model)``, cached in ``cache`` by :func:`_model_key` (at most 17 entries: the cache is
    emptied beyond that)."""
    key = _model_key(model)
    if key not in cache:
        if len(cache) > 16:
            cache.clear()
        cache[key] = build(model)
    return cache[key]


#: The key table of :func:`default_model` shipped with plod: stelaCSF's takes about 10 s to build (an
#: iterative distance solve per entry, 5 s of it XLA compilation), once per process. Used only when the
#: model and the grid are those it was built for (:func:`_table_digest`); ``tests/test_score.py`` checks
#: it against a fresh build. Rewrite it after a change to the default model, its constants or the
#: grid: ``.venv/bin/python -c "from optim._score import write_shipped_table; write_shipped_table()"``.
SHIPPED_TABLE = Path(__file__).resolve().parent / "data" / "key_table_default.npz"


#: The motion key table of :func:`default_model` (:func:`_motion_table`), shipped because stelaCSF's
#: takes about 5 minutes to build on one core (entries far outside its fast solver's table fall back
#: to the generic scan); float16 rounded up (conservative: 0.1 % coarser than the float32 table).
SHIPPED_MOTION_TABLE = Path(__file__).resolve().parent / "data" / "motion_table_default.npz"


def _table_digest(model, motion: bool = False) -> str:
    """sha256 of the model's :func:`_model_key` and the table grid (with ``motion``, the motion grid)."""
    name, structure, constants = _model_key(model)
    grid = (_TAB_C, _TAB_R) + ((_TAB_W, _W_SUB, "float16-up") if motion else ())
    h = hashlib.sha256(repr(grid + ((name, structure),)).encode())
    for b in constants:
        h.update(b)
    return h.hexdigest()


def _shipped_table(model, motion: bool = False):
    """The shipped (static or motion) table if it was built for ``model`` and this grid, else None
    (also for a missing or unreadable file, or one of the wrong size: the table is then built afresh,
    or for motion the exact per-node key is used)."""
    import io
    import zipfile

    path = SHIPPED_MOTION_TABLE if motion else SHIPPED_TABLE
    try:  # read the bytes first: np.load leaves a damaged file open
        with np.load(io.BytesIO(path.read_bytes())) as z:
            if str(z["digest"]) != _table_digest(model, motion):
                return None
            table = np.ascontiguousarray(z["table"], np.float32)
            if motion:
                table[np.isposinf(table)] = 1e30
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        return None
    n = _TAB_C[2] * _TAB_R[2] * (_TAB_W[2] if motion else 1)
    return table if table.shape == (n,) and np.isfinite(table).all() else None


def _round_up_f16(x: np.ndarray) -> np.ndarray:
    """float16 copy of ``x`` (float32 >= 0) rounded up, never below ``x``; values beyond float16's
    range (the 1e30 "no finite key" entries) become inf, read back as 1e30."""
    h = x.astype(np.float16)
    low = h.astype(np.float32) < x
    h[low] = np.nextafter(h[low], np.float16(np.inf))
    return h


def write_shipped_table(path=None, motion: bool = False):
    """Build the static (or, with ``motion``, the motion) key table of :func:`default_model` and write
    it (atomically) to ``path`` (default: the shipped file of that kind)."""
    import io

    from pmetric import atomic_write_bytes

    model = default_model()
    if path is None:
        path = SHIPPED_MOTION_TABLE if motion else SHIPPED_TABLE
    if motion:
        table = _round_up_f16(_motion_table(model))
    else:
        table = _perceptual_table(model)
    buf = io.BytesIO()
    np.savez_compressed(buf, table=table, digest=np.asarray(_table_digest(model, motion)))
    return atomic_write_bytes(path, buf.getvalue())


def _build_table(model) -> _KeyTable:
    host = _shipped_table(model)
    if host is None:
        host = _perceptual_table(model)
    host.flags.writeable = False
    return _KeyTable(jnp.asarray(host), host, _model_band(model))


def _model_table(model) -> _KeyTable:
    """The key table of ``model`` (device and numpy copies), cached by the model's type and values."""
    return _per_model(_TABLES, model, _build_table)


_MOTION_TABLES: dict = {}
_NO_MOTION_TABLE: set = set()  # model keys without a shipped motion table (not re-read per view)


def _motion_key_table(host: np.ndarray, model) -> _KeyTable:
    host.flags.writeable = False
    return _KeyTable(jnp.asarray(host), host, _model_band(model, motion=True))


def _build_motion(model) -> _KeyTable:
    host = _shipped_table(model, motion=True)
    return _motion_key_table(_motion_table(model) if host is None else host, model)


def prepare_motion_table(model) -> None:
    """Build (once per process) the motion key table of ``model``, so that :func:`score` reads the keys
    of moving views from it instead of calling the model per node. The default model's is shipped;
    for others the build costs a second (direct-solve models such as KellyAbstract) to about 5
    minutes (stelaCSF fits) on one core, against about 180 us per node and view on the per-node path
    for stelaCSF."""
    import pmetric

    if not isinstance(model, pmetric.CSFModel):
        raise PlodError(f"prepare_motion_table: model must be a pmetric.CSFModel, got {type(model).__name__}")
    _NO_MOTION_TABLE.discard(_model_key(model))
    _per_model(_MOTION_TABLES, model, _build_motion)


def _motion_table_for(model):
    """The motion key table of ``model`` if it is shipped or was prepared (:func:`prepare_motion_table`),
    else None (the per-node key is used)."""
    key = _model_key(model)
    if key in _MOTION_TABLES:
        return _MOTION_TABLES[key]
    if key in _NO_MOTION_TABLE:
        return None
    host = _shipped_table(model, motion=True)
    if host is None:
        if len(_NO_MOTION_TABLE) > 16:
            _NO_MOTION_TABLE.clear()
        _NO_MOTION_TABLE.add(key)
        return None
    return _per_model(_MOTION_TABLES, model, lambda m: _motion_key_table(host, m))


def _model_band(model, motion: bool = False) -> tuple:
    """:func:`band_bound` of ``model`` (with ``motion``, over retinal velocities too), cached like the
    key tables."""
    return _per_model(_BANDS_MOTION if motion else _BANDS, model, lambda m: band_bound(m, motion))


def _ratio_cell(x, theta, grid):
    """Cell (rounded down) of the ratio ``x / theta`` on a grid ``(log10 lo, log10 hi, n)`` of 0 then
    n - 1 log-spaced points: 0 below 10^lo, n - 1 at and above 10^hi."""
    lo, hi, n = grid
    ratio = div_or_zero(x, theta)
    small = ratio < 10.0 ** lo
    lr = jnp.log10(jnp.where(small, 1.0, ratio))
    return jnp.where(small, 0, 1 + jnp.clip(jnp.floor((lr - lo) * ((n - 2) / (hi - lo))), 0, n - 2)).astype(jnp.int32)


def table_index(c, theta, ecc, vel=None):
    """Flat index into the key table of (c rounded up, ecc / theta rounded down), -1 where the key is
    0 (no contrast or no extent); with ``vel`` (deg/s) into the motion table, with the cell of
    vel / theta. Computed apart from the gather: fused into it, XLA:CPU computes the indices with
    scalar code (log10 per element)."""
    lc0, lc1, nc = _TAB_C
    nr = _TAB_R[2]
    pos_c = c > 0
    lc = jnp.log10(jnp.where(pos_c, jnp.maximum(c, 10.0 ** lc0), 1.0))
    j = jnp.clip(jnp.ceil((lc - lc0) * ((nc - 1) / (lc1 - lc0)) - 1e-4), 0, nc - 1).astype(jnp.int32)
    flat = j * nr + _ratio_cell(ecc, theta, _TAB_R)
    if vel is not None:
        flat = flat * _TAB_W[2] + _ratio_cell(vel, theta, _TAB_W)
    return jnp.where(pos_c & (theta > 0), flat, -1)


def table_gather(ktab, idx, theta, xp=jnp):
    """theta * K(c rounded up, ecc / theta rounded down): an upper bound of the exact key within the
    table's resolution (3.7 % in contrast, 15.7 % in the eccentricity-to-size ratio; ratios below 0.01
    use 0, above 1e4 use 1e4). ``idx`` from :func:`table_index`; 0 where it is -1. jax or numpy."""
    return xp.where(idx >= 0, theta * xp.take(ktab, idx, mode="clip"), xp.float32(0.0))  # float32 in, float32 out


# ----------------------------------------------------------------------------------------------
# key: the programs
def _thin_parts(c_sil, theta, band):
    """(contrast c w / theta of the widest channel, 2 c w) of the thin-band silhouette key."""
    return c_sil * div_or_zero(band, theta), 2.0 * c_sil * band


@functools.partial(jax.jit, static_argnames=("metric", "has_gaze", "has_motion", "table_mode"))
def _key_inputs(ch, vp, facing, metric, has_gaze, has_motion, table_mode=False):
    """``terms`` of a chunk -> (cull flag, what the key needs). Only that leaves the program (per-node
    arrays of 10^6 nodes no longer fit in cache): with ``table_mode`` the key-table indices of the
    own, silhouette and thin-band keys, theta, the band width, 2 c w and the silhouette flag; else
    the contrasts, theta, band, silhouette flag, ecc and vel for the model; or the pixel key."""
    t = terms(ch, vp, facing, has_gaze, has_motion, metric)
    if metric == "perceptual":
        c_a, kc = _thin_parts(t.contrast, t.theta, t.band)
        if table_mode:  # with motion, the motion table at velocity / size (the band's key: vel / band)
            vel = t.vel if has_motion else None
            idx = lambda c, th: table_index(c, th, t.ecc, vel)  # noqa: E731
            return t.culled, (idx(t.c_own, t.theta), idx(t.contrast, t.theta), idx(c_a, t.theta),
                              idx(t.contrast, t.band), t.theta, t.band, kc, t.silhouette,
                              t.ecc if has_gaze else None)
        return t.culled, (t.c_own, t.contrast, t.theta, t.band, t.silhouette, t.ecc if has_gaze else None,
                          t.vel if has_motion else None)
    return t.culled, (t.size_px if metric == "size" else t.err_px,)


@eqx.filter_jit
def _exact_key(model, inputs, metric, has_gaze, has_motion, band_m):
    """``key`` without the key table (``exact=True``, motion, pixel metrics): raw key (C,) float32 >= 0.
    A separate XLA program: fused with ``terms``, XLA:CPU recomputes shared intermediates. ``band_m``:
    :func:`band_bound` (with motion, its bound over velocities too)."""
    if metric == "perceptual":
        c_own, c_sil, theta, band, sil, ecc, vel = inputs
        e = ecc if has_gaze else 0.0
        v = vel if has_motion else 0.0
        clean = lambda k: jnp.where(jnp.isnan(k), 1e30, jnp.minimum(k, 1e30))  # noqa: E731
        dist = lambda c, th: clean(model.imperceptible_distance(c, th, e, v))  # noqa: E731
        k_own, k_cap = dist(c_own, theta), dist(c_sil, theta)
        c_a, kc = _thin_parts(c_sil, theta, band)
        key = thin_band_key(k_own, k_cap, dist(c_a, theta), dist(c_sil, band), band_key(kc, ecc, band_m),
                            2.0 * theta * band_m.f_star, sil)
    else:
        key = inputs[0]
    return jnp.maximum(key, 0.0).astype(jnp.float32)


@jax.jit
def _table_keys_device(ktab, band_m, i_own, i_sil, i_a, i_b, theta, band, kc, sil, ecc):
    """Table mode in XLA: the same keys as :func:`_table_keys_host` (``ecc`` None without gaze)."""
    g = lambda i, th: table_gather(ktab, i, th)  # noqa: E731
    return thin_band_key(g(i_own, theta), g(i_sil, theta), g(i_a, theta), g(i_b, band), band_key(kc, ecc, band_m),
                         2.0 * theta * band_m.f_star, sil)


@functools.partial(jax.jit, static_argnames=("has_gaze",))
def _table_inputs(ch, vp, has_gaze):
    """Table mode, ``terms`` in one XLA program without gathers: the silhouette-table word positions
    (C, 2) int32 of each node, the key-table index of its own contrast, its silhouette contrast,
    eccentricity (deg), theta (deg), band width (deg), the frustum cull flag and whether its cone may
    face both ways; the same term functions as :func:`optim._terms.terms`. The silhouette keys'
    table indices are computed for the silhouette nodes alone (:func:`_silhouette_indices`: only
    they need them, and the facing flags that pick them are known only after the numpy gathers)."""
    g = _geometry(ch, vp)
    _, theta = extent(vp, g)
    ecc = eccentricity(vp, g, theta) if has_gaze else jnp.zeros_like(theta)
    c_own, c_sil = contrast_pair(ch, vp)
    band = band_width(ch, vp, g, theta)
    widx = facing_rows(ch, vp)[:, None] * 12 + ch.word_idx
    cone_front, cone_back = cone_facing(ch, vp, g)
    return (widx, table_index(c_own, theta, ecc), c_sil, ecc, theta, band, frustum_culled(ch, vp, g),
            cone_front & cone_back)


@jax.jit
def _silhouette_indices_xla(c_sil, ecc, theta, band, bb):
    c_a, kc = _thin_parts(c_sil, theta, band)
    return (table_index(c_sil, theta, ecc), table_index(c_a, theta, ecc), table_index(c_sil, band, ecc),
            band_key(kc, ecc, bb))


def _silhouette_indices(c_sil, ecc, theta, band, bb):
    """Key-table indices of the silhouette, widest-channel and band contrasts and the band key
    (:func:`band_key` of ``2 c w`` with the :class:`BandBound` ``bb``; the thin-band parts,
    :func:`thin_band_key`) of some nodes, numpy (S,) in and out; the XLA arithmetic of
    :func:`table_index` and :func:`band_key` (bit-identical to the XLA path), padded to a power of two
    >= 1024 nodes so that few lengths compile. Without a gaze ``ecc`` is 0, where :func:`band_key` is
    exactly the foveal bound."""
    n = c_sil.shape[0]
    cols = np.zeros((4, max(1024, 1 << (n - 1).bit_length())), np.float32)  # padding: contrast 0 -> index -1
    for row, x in zip(cols, (c_sil, ecc, theta, band)):
        row[:n] = x
    return tuple(np.asarray(x)[:n] for x in _silhouette_indices_xla(*cols, _device_band(bb)))


def _table_keys_host(ctx, vp, ktab: _KeyTable, has_gaze):
    """Raw key (M,) float32 and cull flag (M,) bool, table mode: ``classify`` and the table gathers
    in numpy (the same values as the XLA path of :func:`_raw_keys` with ``fast=False``); the
    thin-band keys only for silhouette nodes, whose table indices come from one XLA call over the
    silhouettes of every chunk. The chunks' programs run asynchronously (``jax.jit``;
    ``eqx.filter_jit`` would wait for each result), so a chunk's numpy work overlaps the next
    chunk's program."""
    outs = [_table_inputs(ch, vp, has_gaze) for ch in ctx.chunks]  # dispatch all chunks first
    key = np.empty(ctx.m, np.float32)
    culled = np.empty(ctx.m, bool)
    tab = ktab.host
    sil_pos, sil_cols = [], []
    a = 0
    for hm, n, out in zip(ctx.host_masks, ctx.sizes, outs):
        widx, i_own, c_sil, ecc, theta, band, out_of_view, cone_both = (np.asarray(x)[:n] for x in out)
        front, back = facing_host(widx, hm, n)
        b = a + n
        culled[a:b], _, sil = classify(hm.nonempty[:n], front, back, out_of_view, (cone_both, cone_both))
        key[a:b] = table_gather(tab, i_own, theta, np)
        s = np.flatnonzero(sil)
        sil_pos.append(s + a)
        sil_cols.append((c_sil[s], ecc[s], theta[s], band[s]))
        a = b
    s = np.concatenate(sil_pos)
    if s.size:
        c_sil, ecc, th, bd = (np.concatenate(c) for c in zip(*sil_cols))
        i_sil, i_a, i_b, kb = _silhouette_indices(c_sil, ecc, th, bd, ktab.band)
        f_star = np.float32(ktab.band.f_star)
        key[s] = thin_band_key(key[s], table_gather(tab, i_sil, th, np), table_gather(tab, i_a, th, np),
                               table_gather(tab, i_b, bd, np), kb, np.float32(2.0) * th * f_star, True, np)
    return key, culled


#: fewer usable cores than this: table mode gathers in numpy on the CPU backend (:func:`_host_gathers`)
HOST_GATHER_MAX_CORES = 3


def _host_gathers() -> bool:
    """Whether table mode does its gathers in numpy (:func:`_table_keys_host`) rather than in its XLA
    programs: only on the CPU backend with at most :data:`HOST_GATHER_MAX_CORES` usable cores, where
    XLA:CPU's scalar gather loops lose to numpy. Measured with ``reports/scripts/ab_score_gathers.py``
    (1M-triangle torus, static views, same keys either way): numpy gathers 0.86x the XLA programs' time on
    2 cores; XLA 1.36x / 1.69x / 1.81x faster on 4 / 8 / 16 cores of a 16-core machine and 2.88x on its
    H200 GPU (reports/bench_optim_device.md). The 2-core choice depends on the machine: on the 2-core
    AVX-512 machine of 2026-12-05 numpy gathers took 1.12x (torus) and 1.07x (sphere) the XLA programs'
    time for static views, and for moving views (the motion table, tried and not kept) 1.03x / 0.95x."""
    return jax.default_backend() == "cpu" and _usable_cores() <= HOST_GATHER_MAX_CORES


def _raw_keys(ctx, vp, model, ktab, metric, has_gaze, has_motion, fast=None):
    """``classify``, ``terms`` and ``key`` of every internal node: raw key (M,) float32 and cull flag
    (M,), chunk by chunk (all chunks dispatched before any result is read). ``ktab``: the model's
    :class:`_KeyTable` for table mode, else None; ``fast``: table mode through
    :func:`_table_keys_host` (same values as the XLA programs); None: :func:`_host_gathers`."""
    table_mode = metric == "perceptual" and ktab is not None
    if fast is None:
        fast = _host_gathers()
    if table_mode and fast and not has_motion:
        return _table_keys_host(ctx, vp, ktab, has_gaze)
    table = table_device()
    band_m = _NO_BAND
    if metric == "perceptual":
        band_m = ktab.band if ktab is not None else _model_band(model, motion=has_motion)
    band_m = _device_band(band_m)
    outs = []
    for ch in ctx.chunks:
        culled, inputs = _key_inputs(ch, vp, facing_flags(ch, vp, table), metric, has_gaze, has_motion, table_mode)
        if table_mode:
            key = _table_keys_device(ktab.device, band_m, *inputs)
        else:
            key = _exact_key(model, inputs, metric, has_gaze, has_motion, band_m)
        outs.append((key, culled))
    sz = ctx.sizes
    return (np.concatenate([np.asarray(k)[:n] for (k, _), n in zip(outs, sz)]),
            np.concatenate([np.asarray(c)[:n] for (_, c), n in zip(outs, sz)]))


# ----------------------------------------------------------------------------------------------
# propagate
def _spread_culled(ctx, culled) -> np.ndarray:
    """A culled node culls its whole subtree (top down, one gather per level)."""
    return ctx.levels.spread_down(np.array(culled, dtype=bool), np.logical_or)


def _propagate(ctx, raw, culled) -> np.ndarray:
    """Keys in tree order: culled subtrees 0, then the maximum up the levels [LH01 fn 2]."""
    key = np.array(raw)
    key[_spread_culled(ctx, culled)] = 0.0
    return ctx.to_tree(ctx.levels.max_up(key), 0.0)


# ----------------------------------------------------------------------------------------------
# public API
class NodeTerms(NamedTuple):
    """Per-node terms of one view, tree order, numpy (N,) (leaves: all False / 0): ``culled`` (outside
    the frustum, wholly back facing, or below such a node), ``backfacing``, ``silhouette`` (bool);
    ``size_px`` projected bounding-sphere diameter (pixels); ``theta`` its visual angle (deg);
    ``eccentricity`` (deg); ``velocity`` retinal velocity (deg/s); ``contrast`` Michelson contrast of
    the fold (a silhouette node's: its silhouette contrast); ``own_contrast`` the contrast of the
    fold's own luminance change; ``band_deg`` the width (deg) of the band a silhouette fold can
    change (its slab projected, at most ``theta``)."""

    culled: np.ndarray
    backfacing: np.ndarray
    silhouette: np.ndarray
    size_px: np.ndarray
    theta: np.ndarray
    eccentricity: np.ndarray
    velocity: np.ndarray
    contrast: np.ndarray
    own_contrast: np.ndarray
    band_deg: np.ndarray


def default_model():
    """The perceptual model used when none is given: :func:`pmetric.default_model` (stelaCSF with its
    published constants [MAC22]; see :data:`pmetric.DEFAULT_MODEL` for why)."""
    import pmetric

    return pmetric.default_model()


def node_terms(tree, view) -> NodeTerms:
    """Cull flags, silhouette flags, angular size, eccentricity, velocity and contrast of every node
    for ``view`` (the inputs of the perceptual key; see :mod:`optim._terms` for units)."""
    ctx = scoring_context(tree, getattr(view, "lighting", None))
    vp = view_params(view, ctx.scene_lum, ctx.origin)
    has_gaze, has_motion = view.gaze_px is not None, view.previous is not None
    table = table_device()
    parts = [terms_jit(ch, vp, facing_flags(ch, vp, table), has_gaze, has_motion) for ch in ctx.chunks]
    t = Terms(*(np.concatenate([np.asarray(getattr(p, f))[:n] for p, n in zip(parts, ctx.sizes)])
                for f in Terms._fields))
    culled = _spread_culled(ctx, t.culled)
    return NodeTerms(*(ctx.to_tree(a, False if a.dtype == bool else 0.0)
                       for a in (culled, t.backfacing, t.silhouette, t.size_px, t.theta, t.ecc, t.vel, t.contrast,
                                 t.c_own, t.band)))


def score(tree, view, model=None, metric: str = "perceptual", *, exact: bool = False) -> np.ndarray:
    """Keys (N,) float32, one per node of ``tree`` for ``view``: larger = more important to keep unfolded.

    ``metric="perceptual"``: ``model.imperceptible_distance`` of the fold (multiples of the current
    viewing distance; <= 1 = imperceptible now [LH01 §5.3]); ``model`` is a :class:`pmetric.CSFModel`
    (default: :func:`default_model`). Without motion the key is read from a per-model table
    (``k(c, theta, e) = theta K(c, e / theta)`` holds for every model by the definition of the distance
    key) rounded to the conservative side; a view with motion (``view.previous``) reads the motion
    table ``theta K(c, e / theta, v / theta)`` (:func:`_motion_table`) when the model has one (shipped
    for the default model; :func:`prepare_motion_table` for others), else calls the model per node, as
    ``exact=True`` always does. Cost of that per-node call: KellyAbstract's distance is a direct
    solve (milliseconds per 10^5 nodes); the default stelaCSF's is iterative, about 180 us per node on
    one core (11 s for 77,000 nodes, plus about 5 s of compilation per padded chunk shape): for moving
    views of large meshes pass a model with a direct solve (``pmetric.KellyAbstract()``).
    ``"size"``: projected bounding-sphere diameter (pixels). ``"geometric"``: projected fold error
    (pixels). Leaves, culled nodes (outside the frustum, wholly back facing) and their subtrees get 0.
    Keys are monotone: ``key[parent] >= key[child]`` [LH01 fn 2].
    """
    if not isinstance(metric, str) or metric not in METRICS:
        raise PlodError(f"score: metric must be one of {METRICS}, got {metric!r}")
    if not isinstance(exact, (bool, np.bool_)):
        raise PlodError(f"score: exact must be True or False, got {exact!r}")
    ctx = scoring_context(tree, getattr(view, "lighting", None))
    vp = view_params(view, ctx.scene_lum, ctx.origin)
    ktab = None
    if metric == "perceptual":
        import pmetric

        model = default_model() if model is None else model
        if not isinstance(model, pmetric.CSFModel):
            raise PlodError(f"score: model must be a pmetric.CSFModel, got {type(model).__name__}")
        if not exact:
            ktab = _model_table(model) if view.previous is None else _motion_table_for(model)
    else:
        model = None
    raw, culled = _raw_keys(ctx, vp, model, ktab, metric, view.gaze_px is not None, view.previous is not None)
    return _propagate(ctx, raw, culled)

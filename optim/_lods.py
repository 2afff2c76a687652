"""A chain of discrete levels of detail for a mesh seen from any direction, each with the largest
projected size at which it is imperceptible: the switch sizes an engine's LOD group needs.

Written here because no library computes perceptual switch sizes: meshoptimizer's LOD examples switch by
a geometric error in pixels, and engines (Unity's LODGroup, Unreal's static-mesh LODs) take the screen
sizes from the user. plod's keys already say from what viewing distance a fold stops being visible
[LH01 §5.3]; a level that must hold for every view direction takes, per fold, the largest key over a
set of directions.

Stages, each a function below:

1. :func:`sphere_directions`: D view directions spread evenly over the sphere (a Fibonacci lattice).
2. :func:`direction_keys`: the perceptual keys (viewing-distance multiples, <= 1 imperceptible) of
   every node from each direction with the object framed at a given angular size (its bounding sphere's
   diameter, deg), no gaze information (every node foveal: the viewer may look at any part of the
   object), the largest over the directions.
3. :func:`lod_chain`: the levels, nested (each coarser level folds everything the finer one folds),
   either at given sizes (the imperceptible cut of stage 2's keys at each size) or at given triangle
   budgets (the budget cut, and the largest size at which that cut stays imperceptible from every
   direction, found by a fixed-point iteration: a key is a multiple of the viewing distance, so at a
   smaller angular size it shrinks nearly in proportion).

4. :func:`lod_sizes`: the switch sizes of given levels (the cuts kept) when the viewer's gaze is known to
   lie at least some degrees off the object (an eye-tracked or foveated renderer): every view of stages 2
   and 3 then puts the gaze anywhere on the circle ``eccentricity_deg`` beyond the bounding sphere's
   outline (``View.gaze_ring_deg``), so each node's eccentricity is its smallest over that circle, less
   the gaze error [LHNW00 §4.4]. Sensitivity falls with eccentricity, so the circle is the worst case of
   every gaze at least that far off. ``eccentricity_deg = 0`` (the default everywhere) is the case
   without gaze information: the viewer may look at any part of the object.

Units: sizes are the angular diameter of the object's bounding sphere (about its bounding-box centre)
in degrees of the viewer's visual field; the camera is the display's physical one (the image spans
what the screen subtends), so a size is also a screen-height fraction for that display
(:func:`screen_fraction`) and a distance in object units (:func:`object_distance`).
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple

import numpy as np

from pmetric import PlodError

from ._cut import Cut, budget_cut, threshold_cut
from ._mesh import real_or_nan

__all__ = ["LevelOfDetail", "sphere_directions", "direction_keys", "lod_chain", "lod_sizes", "screen_fraction",
           "object_distance", "max_object_deg"]

DIRECTIONS = 512  # view directions a level is checked over (the certificate)
SEARCH_DIRECTIONS = 64  # and the ones its budget level's size is searched over
MIN_OBJECT_DEG = 1e-6  # the smallest size a level is made for (deg: 3.6 milliarcseconds)
MAX_ECCENTRICITY_DEG = 90.0  # the gaze at most this far off the object (deg): the gaze circle stays in front
_TIGHT = 0.97  # a budget level's size is accepted once its largest folded key lies in [_TIGHT, 1]
_ITERATIONS = 8


class LevelOfDetail(NamedTuple):
    """One level of a chain.

    ``cut``: the :class:`optim.Cut` (its ``triangles`` the level's count); ``object_deg``: the largest
    angular diameter of the object's bounding sphere (deg) at which every fold of the level is
    imperceptible from every direction of the chain (use the level at or below it); ``key``: the
    largest perceptual key over the directions among the level's folded nodes at ``object_deg`` (<= 1;
    0 when nothing it folds is visible from any direction at that size); ``capped``: True when
    ``object_deg`` is :func:`max_object_deg` (the object fills the screen's height): a budget level
    imperceptible even there, or a size level made there.
    """

    cut: Cut
    object_deg: float
    key: float
    capped: bool = False

    @property
    def triangles(self) -> int:
        return int(self.cut.triangles)


def sphere_directions(n: int) -> np.ndarray:
    """(n, 3) float64 unit vectors spread evenly over the sphere (the Fibonacci lattice: point k at
    height 1 - (2k + 1) / n, turned by the golden angle from the one before); ``n`` >= 1."""
    if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or not 1 <= n <= 100_000:
        raise PlodError(f"sphere_directions: n must be an integer in 1..100000, got {n!r}")
    k = np.arange(int(n), dtype=np.float64)
    y = 1.0 - (2.0 * k + 1.0) / n
    r = np.sqrt(np.maximum(0.0, 1.0 - y * y))
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    return np.stack([r * np.cos(phi), y, r * np.sin(phi)], -1)


def max_object_deg(display=None) -> float:
    """The largest size (deg) a level is made for: the vertical angle ``display``'s screen subtends
    (default display: 26.9 deg). A bigger object does not fit the image: the views would cull what lies
    off the screen, and a turn of the camera brings it back."""
    d = _display(display)  # in float64, as View's own field of view (Display.field_of_view is float32)
    return math.degrees(2.0 * math.atan(0.5 * float(d.height) / float(d.distance)))


def _display(display):
    import pmetric

    if display is None:
        return pmetric.Display.default()
    if not isinstance(display, pmetric.Display):
        raise PlodError(f"display must be a pmetric.Display, got {type(display).__name__}")
    return display


def _angle(name: str, s, lo: float, hi: float, closed: bool, why: str = "") -> float:
    """``s`` as a float angle (deg) in [lo, hi] (``closed``) or [lo, hi); PlodError naming ``name``."""
    x = real_or_nan(s)
    if not (lo <= x <= hi if closed else lo <= x < hi):
        raise PlodError(f"{name} must be an angle in [{lo:g}, {hi:.6g}{']' if closed else ')'} deg{why}, got {s!r}")
    return x


def _check_size(name: str, s, display=None) -> float:
    return _angle(name, s, MIN_OBJECT_DEG, max_object_deg(display), True,
                  " (at most the screen's height: a bigger object does not fit the image)")


def _directions(directions, name: str = "directions") -> np.ndarray:
    if isinstance(directions, (int, np.integer)) and not isinstance(directions, (bool, np.bool_)):
        if not 1 <= directions <= 100_000:
            raise PlodError(f"{name} must be a count in 1..100000 or a (D, 3) array, got {directions!r}")
        return sphere_directions(int(directions))
    d = np.zeros(0)
    if not isinstance(directions, (bool, np.bool_, str, bytes)) and not np.iscomplexobj(directions):
        try:
            d = np.asarray(directions, dtype=np.float64)
        except (TypeError, ValueError):
            pass
    if d.ndim != 2 or d.shape[1] != 3 or len(d) == 0:
        raise PlodError(f"{name} must be a count or a non-empty (D, 3) array of real numbers, got "
                        f"{type(directions).__name__} of shape {np.shape(d)}")
    n = np.linalg.norm(d, axis=1)
    if not (np.isfinite(d).all() and (n > 0).all()):
        raise PlodError(f"{name} must be finite nonzero vectors")
    return d / n[:, None]


def direction_keys(tree, object_deg: float, directions=64, *, model=None, display=None, lighting=None,
                   eccentricity_deg: float = 0.0, gaze_error_deg: float = 1.0,
                   progress: Callable[[int, int], None] | None = None) -> np.ndarray:
    """(N,) float32: per node of ``tree``, the largest perceptual key of :func:`optim.score` over the
    views framing the object at ``object_deg`` (deg, its bounding sphere's angular diameter) from each
    of ``directions`` (a count for :func:`sphere_directions`, or a (D, 3) array of directions from the
    object's centre to the eye). ``display`` (:class:`pmetric.Display`, default the default display),
    ``lighting`` (:class:`optim.Lighting`, default pre-lit) and ``model`` (default
    :func:`optim.default_model`) as for a :class:`optim.View` and :func:`optim.score`. Keys are multiples
    of the viewing distance: <= 1 is imperceptible from every one of the directions at this size
    [LH01 §5.3]. ``progress(done, total)`` per direction.

    ``eccentricity_deg`` (deg, 0 .. 90): 0 (default) is no gaze information, every node foveal; above 0
    the gaze lies that far beyond the bounding sphere's outline, anywhere around it (a gaze ring of
    radius ``eccentricity_deg + object_deg / 2`` about the object's centre), less ``gaze_error_deg``
    (deg, default 1: an eye tracker [LHNW00 §4.4])."""
    from ._score import score
    from ._view import View, framing_sphere

    s = _check_size("object_deg", object_deg, display)
    e = _eccentricity(eccentricity_deg)
    dirs = _directions(directions)
    gaze = dict(gaze=None) if e == 0 else dict(gaze="center", gaze_ring_deg=e + 0.5 * s)
    gaze["gaze_error_deg"] = gaze_error_deg  # (checked by View either way)
    sphere, display = framing_sphere(tree.vertices, who="direction_keys"), _display(display)  # once, not per view
    out = None
    for i, u in enumerate(dirs):
        view = View.framing(None, s, direction=u, sphere=sphere, display=display, lighting=lighting, **gaze)
        k = score(tree, view, model, "perceptual")
        out = k if out is None else np.maximum(out, k)
        if progress is not None:
            progress(i + 1, len(dirs))
    return out


def _eccentricity(e) -> float:
    return _angle("eccentricity_deg", e, 0.0, MAX_ECCENTRICITY_DEG, True,
                  " (how far the gaze lies off the object's bounding sphere)")


def _nested(tree, unfolded: np.ndarray, keys: np.ndarray, reason: str) -> Cut:
    """The cut of the mask ``unfolded`` (closed under ancestors); its ``distance`` is :func:`_folded_key`."""
    kept = unfolded[tree.internal]
    tri = int(tree.num_subtris[tree.internal[kept]].sum())
    return Cut(unfolded, tri, _folded_key(tree, unfolded, keys), reason if not kept.all() else "all_unfolded")


def _folded_key(tree, unfolded: np.ndarray, keys: np.ndarray) -> float:
    """The largest of ``keys`` over the internal nodes the mask ``unfolded`` folds (0 when none)."""
    folded = tree.internal[~unfolded[tree.internal]]
    return max(float(keys[folded].max()), 0.0) if folded.size else 0.0


def lod_chain(tree, *, object_deg=None, budgets=None, directions=DIRECTIONS, search_directions=SEARCH_DIRECTIONS,
              model=None, display=None, lighting=None, eccentricity_deg: float = 0.0, gaze_error_deg: float = 1.0,
              progress: Callable[[str, int, int], None] | None = None) -> tuple[LevelOfDetail, ...]:
    """The levels of detail of ``tree``, finest first, nested (each level folds every node the level
    before it folds), each imperceptible from every one of ``directions`` up to its ``object_deg``.

    Give exactly one of:

    - ``object_deg``: decreasing angular sizes (deg, from 1e-6 up to :func:`max_object_deg`); level j
      unfolds what the imperceptible cut [LH01 §5.1] of :func:`direction_keys` unfolds at its own size or
      any coarser level's (keys need not shrink with the size), so the levels nest;
    - ``budgets``: decreasing triangle counts (integers >= 1, below the input's); each level is the
      budget cut [LH01 §5.3] of the keys at a size found by iteration over ``search_directions``: start
      at the finer level's size (half the screen's height for the first), take the cut, and scale the
      size by 1 / (its largest folded key) until that key lies in [0.97, 1], bisecting between the
      largest size found imperceptible and the smallest found visible when the scaling overshoots (at
      most 8 rounds). The cut found is then certified over all ``directions``: while its largest folded
      key there exceeds 1, its size is divided by that key (the cut kept). A level folds at least what
      the level before it folds, so it is imperceptible wherever a coarser one is: a level's size is at
      least every coarser level's.

    ``directions`` (default 512), ``model``, ``display``, ``lighting``, ``eccentricity_deg`` (default 0:
    no gaze information) and ``gaze_error_deg`` as for :func:`direction_keys`. The directions sample the
    views; a fold visible only between them is missed: on the horse at 10 deg, 32 directions left 421
    folded nodes visible from one of 64 random other directions (keys up to 10.9), 128 left 8 (up to 1.5),
    512 none. Cost: one :func:`optim.score` per direction per size tried. ``progress(stage, done, total)``
    per direction. :func:`lod_sizes` gives the same levels' sizes at other eccentricities.
    """
    if (object_deg is None) == (budgets is None):
        raise PlodError("lod_chain: give exactly one of object_deg (sizes) and budgets (triangle counts)")
    keys_at, dirs, search, top = _key_source(tree, directions, search_directions, model, display, lighting,
                                             eccentricity_deg, gaze_error_deg, progress, "lod_chain")
    off_gaze = _eccentricity(eccentricity_deg) > 0  # keys far from proportional to the size: tighten the sizes
    prev = np.ones(tree.n_nodes, dtype=bool)  # the finer level's unfolded mask (the input: all)

    levels = []
    if object_deg is not None:
        sizes = [_check_size("object_deg", s, display) for s in _sequence("object_deg", object_deg)]
        if any(b >= a for a, b in zip(sizes, sizes[1:])):
            raise PlodError(f"lod_chain: object_deg must decrease (finest level first), got {sizes}")
        keys = [keys_at(s, f"level {j + 1} at {s:g} deg") for j, s in enumerate(sizes)]
        # a level may fold only what every coarser level's size allows too (keys need not shrink with the
        # size: a band-pass CSF, a silhouette seen at another angle), so that the chain nests: level j
        # unfolds what the imperceptible cut at any size s_j, s_j+1, ... unfolds
        unf = [threshold_cut(tree, k, 1.0, monotone="trust").unfolded for k in keys]
        for j in range(len(sizes) - 2, -1, -1):
            unf[j] = unf[j] | unf[j + 1]
        for s, k, u in zip(sizes, keys, unf):
            cut = _nested(tree, u, k, "imperceptible")
            levels.append(LevelOfDetail(cut, s, cut.distance, capped=s >= top))
        return tuple(levels)

    counts = _budgets(budgets, int(tree.n_triangles))
    s0 = 0.5 * top
    for j, T in enumerate(counts):
        label = f"level {j + 1} ({T:,} triangles)"

        def at(s):  # the level's cut with the keys at size s, and its largest folded key there
            k = keys_at(s, f"{label}: search at {s:.3g} deg", search)
            masked = np.where(prev, k, -np.inf).astype(k.dtype)  # folded at the finer level: folded here
            c = budget_cut(tree, masked, T, monotone="trust")
            c = _nested(tree, c.unfolded & prev, k, "budget")
            return c, c.distance

        s, cut, m = _largest_size(tree, at, keys_at, s0, top, label, "lod_chain", tighten=off_gaze)
        levels.append(LevelOfDetail(cut, s, m, capped=s >= top))
        prev = cut.unfolded
        s0 = s
    return _monotone_sizes(tree, levels, keys_at)


def lod_sizes(tree, levels, *, eccentricity_deg: float, directions=DIRECTIONS, search_directions=SEARCH_DIRECTIONS,
              model=None, display=None, lighting=None, gaze_error_deg: float = 1.0,
              progress: Callable[[str, int, int], None] | None = None) -> tuple[LevelOfDetail, ...]:
    """The levels of :func:`lod_chain` (the same cuts, finest first) with the switch sizes they have when
    the gaze lies at least ``eccentricity_deg`` (deg, 0 .. 90) off the object's bounding sphere: each
    level's largest size (deg) at which every fold it makes is imperceptible from every one of
    ``directions`` with the gaze anywhere on the circle that far beyond the sphere's outline (see
    :func:`direction_keys`), found as :func:`lod_chain` finds a budget level's size (searched over
    ``search_directions`` from the level's own size, certified over all ``directions``, then tightened
    over all of them: never below the level's own size where that is certified too), then made
    monotone (a finer level is imperceptible wherever a coarser one is). ``levels`` must be nested, finest
    first (a chain, or part of one). ``model``, ``display``,
    ``lighting`` should be the chain's. An engine that knows the angle between the gaze and the object's
    bounding sphere uses a level up to the size given for the largest eccentricity at or below that
    angle. ``eccentricity_deg = 0`` recomputes the chain's own sizes (without gaze information).
    """
    keys_at, dirs, search, top = _key_source(tree, directions, search_directions, model, display, lighting,
                                             eccentricity_deg, gaze_error_deg, progress, "lod_sizes")
    if isinstance(levels, LevelOfDetail) or not isinstance(levels, (list, tuple)) or not levels \
            or not all(isinstance(lv, LevelOfDetail) for lv in levels):
        raise PlodError("lod_sizes: levels must be a non-empty sequence of LevelOfDetail (lod_chain's result)")
    for j, lv in enumerate(levels):
        if not isinstance(lv.cut, Cut):
            raise PlodError(f"lod_sizes: a level's cut must be an optim.Cut (lod_chain's), got {type(lv.cut).__name__}")
        if np.shape(lv.cut.unfolded) != (tree.n_nodes,):
            raise PlodError(f"lod_sizes: a level's cut has {np.size(lv.cut.unfolded)} nodes, the tree "
                            f"{tree.n_nodes:,}: levels must come from this tree's chain")
        if not 0 < real_or_nan(lv.object_deg) < math.inf:
            raise PlodError(f"lod_sizes: a level's object_deg must be a size > 0 deg (lod_chain's), got "
                            f"{lv.object_deg!r}")
        # the monotone step below lifts a finer level to a coarser one's size: right only for nested levels
        if j and (lv.cut.unfolded[tree.internal] & ~levels[j - 1].cut.unfolded[tree.internal]).any():
            raise PlodError(f"lod_sizes: levels must be nested, finest first (lod_chain's order): level {j + 1} "
                            f"unfolds a node level {j} folds")
    out = []
    for j, lv in enumerate(levels):
        label = f"level {j + 1} ({lv.triangles:,} triangles) at {eccentricity_deg:g} deg off"

        def at(s, lv=lv, label=label):
            k = keys_at(s, f"{label}: search at {s:.3g} deg", search)
            return lv.cut, _folded_key(tree, lv.cut.unfolded, k)

        s0 = min(max(float(lv.object_deg), MIN_OBJECT_DEG), top)
        s, cut, m = _largest_size(tree, at, keys_at, s0, top, label, "lod_sizes", tighten=True, floor=s0)
        out.append(LevelOfDetail(lv.cut, s, m, capped=s >= top))
    return _monotone_sizes(tree, out, keys_at)


def _key_source(tree, directions, search_directions, model, display, lighting, eccentricity_deg, gaze_error_deg,
                progress, who):
    """(keys_at(size, stage, over=all directions), the directions, the search directions, the top size),
    the arguments checked."""
    dirs = _directions(directions)
    if isinstance(search_directions, (bool, np.bool_)) or not isinstance(search_directions, (int, np.integer)):
        raise PlodError(f"{who}: search_directions must be a count in 1..100000, got {search_directions!r}")
    search = dirs if len(dirs) <= search_directions else _directions(search_directions, "search_directions")
    if progress is not None and not callable(progress):
        raise PlodError(f"{who}: progress must be a callable (stage, done, total) or None, got "
                        f"{type(progress).__name__}")
    top = max_object_deg(display)  # (checks the display)
    e = _eccentricity(eccentricity_deg)
    ge = _angle(f"{who}: gaze_error_deg", gaze_error_deg, 0.0, 180.0, True)

    def keys_at(s, stage, over=dirs):
        cb = None if progress is None else (lambda d, n: progress(stage, d, n))
        return direction_keys(tree, s, over, model=model, display=display, lighting=lighting, eccentricity_deg=e,
                              gaze_error_deg=ge, progress=cb)

    return keys_at, dirs, search, top


def _largest_size(tree, at, keys_at, s0: float, top: float, label: str, who: str, tighten: bool = False,
                  floor: float | None = None) -> tuple[float, Cut, float]:
    """(size, cut, its largest folded key <= 1): the search of :func:`lod_chain`'s budget levels, ``at(s)``
    giving (cut, largest folded key over the search directions) at size s, then the certificate over
    every direction (``keys_at``) with the cut kept; with ``tighten``, then :func:`_tighten` (``floor``
    its first try)."""
    best, fail = None, math.inf  # (size, cut, key) with key <= 1, the largest; the smallest size with key > 1
    s = min(s0, top)
    for _ in range(_ITERATIONS):
        cut, m = at(s)
        if m <= 1.0:
            if best is None or s > best[0]:
                best = (s, cut, m)
            if m >= _TIGHT or s >= top:
                break
        else:
            fail = min(fail, s)
        nxt = top if m <= 0.0 else min(s / m, top)  # keys scale about as the size
        if best is not None and not best[0] < nxt < fail:  # the scaling overshot: bisect (in log size)
            if fail / best[0] < 1.01:
                break
            nxt = math.sqrt(best[0] * min(fail, top))
        s = nxt
    while best is None:  # no size tried was imperceptible: shrink the smallest until one is
        s = s / max(m, 1.0) * 0.97
        if s < MIN_OBJECT_DEG:
            raise PlodError(f"{who}: no size at which the {label} is imperceptible")
        cut, m = at(s)
        if m <= 1.0:
            best = (s, cut, m)
    s, cut, m = best
    bad = math.inf  # the smallest size found to fail over every direction
    while True:  # certify over every direction, the cut kept
        k = keys_at(s, f"{label}: check at {s:.3g} deg")
        m = _folded_key(tree, cut.unfolded, k)
        if m <= 1.0:
            break
        bad = s
        s = s / m * 0.999
    if tighten:
        s, m = _tighten(tree, cut, keys_at, s, m, bad, top, label, floor)
    return float(s), cut, m


def _tighten(tree, cut, keys_at, s: float, m: float, bad: float, top: float, label: str,
             floor: float | None) -> tuple[float, float]:
    """(size, key): from ``s``, certified over every direction with key ``m``, up towards ``bad`` (the
    smallest size seen to fail over every direction, or inf), over every direction, as the search: until
    the key is within ``_TIGHT`` of 1, the size is ``top`` or the bracket is within 1 %. Off the gaze keys
    do not scale with the size (a fold's key jumps from 0 to ~9 as it comes into view; the search
    directions are not the certificate's), so the certificate's step ``s / m`` could stop 20x below the
    largest certified size, below the size without gaze. ``floor`` (the level's own size: without gaze
    certified over the same directions, so with any gaze too) is tried first."""

    def check(x):
        return _folded_key(tree, cut.unfolded, keys_at(x, f"{label}: tighten at {x:.3g} deg"))

    if floor is not None and s < floor < bad:
        mf = check(floor)
        if mf <= 1.0:
            s, m = floor, mf
        else:
            bad = floor
    for _ in range(2 * _ITERATIONS):  # (from MIN_OBJECT_DEG to the top, 1 % takes 12 bisections)
        if m >= _TIGHT or s >= top or bad / s < 1.01:
            break
        nxt = top if m <= 0.0 else min(s / m * 0.999, top)
        if not s < nxt < bad:  # the scaling overshot: bisect (in log size)
            nxt = math.sqrt(s * min(bad, top))
        mk = check(nxt)
        if mk <= 1.0:
            s, m = nxt, mk
        else:
            bad = nxt
    return s, m


def _monotone_sizes(tree, levels: list, keys_at) -> tuple[LevelOfDetail, ...]:
    """A level imperceptible at some size makes every finer one so there too (it folds a subset): a finer
    level whose search ended below a coarser level's size takes that size (its key recomputed)."""
    for j in range(len(levels) - 2, -1, -1):
        lv, up = levels[j], levels[j + 1].object_deg
        if up > lv.object_deg:
            k = keys_at(up, f"level {j + 1}: check at {up:.3g} deg")
            levels[j] = LevelOfDetail(lv.cut, up, _folded_key(tree, lv.cut.unfolded, k), capped=levels[j + 1].capped)
    return tuple(levels)


def _sequence(name: str, x) -> list:
    if isinstance(x, (str, bytes)) or np.ndim(x) != 1 or len(x) == 0:
        raise PlodError(f"lod_chain: {name} must be a non-empty sequence, got {x!r}")
    return list(x)


def _budgets(budgets, total: int) -> list[int]:
    out = []
    for b in _sequence("budgets", budgets):
        if isinstance(b, (bool, np.bool_)) or not isinstance(b, (int, np.integer)) or not 1 <= b < total:
            raise PlodError(f"lod_chain: budgets must be whole triangle counts in 1..{total - 1} (the input has "
                            f"{total:,}), got {b!r}")
        out.append(int(b))
    if any(b >= a for a, b in zip(out, out[1:])):
        raise PlodError(f"lod_chain: budgets must decrease (finest level first), got {out}")
    return out


def screen_fraction(object_deg: float, display=None) -> float:
    """The height of the object's bounding sphere on the image as a fraction of the image height, at
    angular diameter ``object_deg`` (deg) on ``display``'s physical camera (vertical field of view what
    the screen subtends): tan(object_deg / 2) / tan(fov / 2)."""
    d = _display(display)
    s = _check_size("object_deg", object_deg, d)
    return math.tan(math.radians(s) / 2) / math.tan(math.radians(max_object_deg(d)) / 2)


def object_distance(object_deg: float, radius: float) -> float:
    """The distance (object units) from the bounding sphere's centre at which a sphere of ``radius``
    subtends ``object_deg`` (deg): radius / sin(object_deg / 2)."""
    a = _angle("object_distance: object_deg", object_deg, MIN_OBJECT_DEG, 180.0, False)
    r = real_or_nan(radius)
    if not 0.0 < r < math.inf:
        raise PlodError(f"object_distance: radius must be a finite positive length, got {radius!r}")
    return r / math.sin(math.radians(a) / 2)

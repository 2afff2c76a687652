"""Per-node terms of one view: the one definition of each input of a fold's key, used by every key
path of :mod:`optim._score` (table, exact and pixel keys) and by :func:`optim.node_terms`.

Scoring runs in named stages, per chunk of internal nodes (flat jax columns, :class:`_Chunk`):

* ``classify`` (:func:`facing_flags` in XLA, :func:`facing_host` with numpy gathers): the node's normal
  mask against the silhouette-table row of its view direction and angular-radius margin [LHNW00 §4.3]
  -> possibly front facing, possibly back facing; wholly back-facing nodes are culled, nodes that may
  face both ways are silhouettes.
* ``terms`` (:func:`terms`, from the term functions below):

  - :func:`frustum_culled`: sphere wholly outside a side plane of the frustum or before the near plane
    (the sphere holding every triangle the fold touches, :func:`optim._relight.cull_columns`);
  - :func:`extent`: projected bounding-sphere diameter (pixels) and its visual angle ``theta`` (deg;
    the fold's lowest frequency is ``1 / (2 theta)`` cycles/deg [LH01 §3.1]);
  - :func:`eccentricity`: angle (deg) between the node's image and the nearest gaze point minus half of
    ``theta`` minus the gaze uncertainty, clamped at 0 [LHNW00 §4.4]; 0 without gaze;
  - :func:`velocity`: retinal velocity (deg/s) of the node's image from the previous view; 0 without one;
  - :func:`contrast_pair` and :func:`select_contrast`: Michelson contrast of display luminances
    (cd/m2): the fold's own luminance change ``fold_delta`` above the node's darkest value, and for
    silhouette nodes the node's luminance range against the scene's brightest and darkest values,
    background included [LHNW00 §4.2; LH01 §5.2];
  - :func:`geometric_error`: projected object-space fold error (pixels) at the nearest point of the
    bounding sphere; :func:`band_width`: the width (deg) of the band a silhouette fold can change
    (its slab, projected; the thin-band silhouette key of :mod:`optim._score`).

* ``key`` and ``propagate``: :mod:`optim._score`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from pmetric import PlodError
from pmetric._numerics import div_or_zero

from ._normal_cube import _MARGINS_DEG, _ROWS_PER_MARGIN, dir_bins, table_host

#: projected sizes are capped at this many image heights (a node around the eye covers everything)
_SIZE_CAP_IMAGES = 16.0


# ----------------------------------------------------------------------------------------------
# view parameters
class ViewParams(NamedTuple):
    eye: jax.Array  # (3,)
    rot: jax.Array  # (3, 3) world -> camera
    scal: jax.Array  # (11,) focal_px, tan_x, tan_y, near, size_cap, deg_per_px, kx, ky, gaze_err, 1/dt, gaze_ring
    gaze: jax.Array  # (G, 2) pixel offsets from the image centre (y down)
    lum: jax.Array  # (4,) black cd/m2, peak - black cd/m2, scene min, scene max (relative)
    prev_eye: jax.Array
    prev_rot: jax.Array
    prev_focal: jax.Array


def view_params(view, scene_lum, origin=None) -> ViewParams:
    """The per-view scalars of ``view`` (an :class:`optim.View`) as device arrays; ``scene_lum`` the
    darkest and brightest relative luminance of the model; ``origin`` (3,) the origin of the node
    coordinates (``tree.origin``; None: 0): the eyes are made relative to it in float64."""
    from ._view import View

    if not isinstance(view, View):
        raise PlodError(f"score: view must be an optim.View, got {type(view).__name__}")
    w, h = view.width, view.height
    tan_y = math.tan(math.radians(view.fov_deg) / 2)
    px, py = view.pixel_pitch_m
    d = view.distance_m
    gaze = view.gaze_px if view.gaze_px is not None else np.array([[w / 2, h / 2]])
    gaze = gaze - np.array([w / 2, h / 2])
    prev = view.previous
    scal = [view.focal_px, tan_y * w / h, tan_y, view.near, _SIZE_CAP_IMAGES * max(w, h), view.degrees_per_pixel,
            px / d, py / d, view.gaze_error_deg, 1.0 / view.dt_s if prev is not None else 0.0, view.gaze_ring_deg]
    black = float(view.display.black_level)
    peak = float(view.display.peak_luminance)
    lo = min(scene_lum[0], view.background)
    hi = max(scene_lum[1], view.background)
    f = np.float32
    o = np.zeros(3) if origin is None else np.asarray(origin, np.float64)
    rot = view.rotation
    host = ViewParams(
        eye=np.asarray(np.asarray(view.eye, np.float64) - o, f), rot=np.asarray(rot, f), scal=np.asarray(scal, f),
        gaze=np.asarray(gaze, f), lum=np.asarray([black, peak - black, lo, hi], f),
        prev_eye=np.asarray(np.asarray((prev or view).eye, np.float64) - o, f), prev_rot=np.asarray(rot if prev is None else prev.rotation, f),
        prev_focal=np.asarray((prev or view).focal_px, f),
    )
    return ViewParams(*jax.device_put(tuple(host)))  # one transfer (a jnp.asarray each costs ~0.2 ms)


# ----------------------------------------------------------------------------------------------
# arithmetic helpers
def _atan2_pos(y, x):
    """atan2(y, x) in rad for y >= 0, with mul/add only (max error about 2e-6 rad; XLA's CPU atan2
    is scalar code and much slower). Finite value and gradient at (0, 0)."""
    ax = jnp.abs(x)
    mx = jnp.maximum(ax, y)
    mn = jnp.minimum(ax, y)
    a = div_or_zero(mn, mx)
    s = a * a
    r = a * (0.99997726 + s * (-0.33262347 + s * (0.19354346 + s * (-0.11643287 + s * (0.05265332 - 0.0117212 * s)))))
    r = jnp.where(y > ax, 0.5 * np.pi - r, r)
    return jnp.where(x < 0, np.pi - r, r)


def _angle_deg(a, b):
    """Angle (deg) between 3-vectors given as column tuples a = (ax, ay, az), b = (bx, by, bz)."""
    cx = a[1] * b[2] - a[2] * b[1]
    cy = a[2] * b[0] - a[0] * b[2]
    cz = a[0] * b[1] - a[1] * b[0]
    n2 = cx * cx + cy * cy + cz * cz
    pos = n2 > 0
    n = jnp.where(pos, jnp.sqrt(jnp.where(pos, n2, 1.0)), 0.0)
    return jnp.degrees(_atan2_pos(n, a[0] * b[0] + a[1] * b[1] + a[2] * b[2]))


def _project(cx, cy, cz, eye, rot):
    dx, dy, dz = cx - eye[0], cy - eye[1], cz - eye[2]
    x = rot[0, 0] * dx + rot[0, 1] * dy + rot[0, 2] * dz
    y = rot[1, 0] * dx + rot[1, 1] * dy + rot[1, 2] * dz
    depth = -(rot[2, 0] * dx + rot[2, 1] * dy + rot[2, 2] * dz)
    return (dx, dy, dz), x, y, depth


class _Geometry(NamedTuple):
    """Camera-space quantities shared by the classify and term functions (columns)."""

    d: tuple  # (dx, dy, dz) eye to the sphere centre, world axes
    x: jax.Array
    y: jax.Array
    depth: jax.Array
    dist: jax.Array  # eye to the sphere centre
    s: jax.Array  # sin of the angular radius, in [0, 1]
    inside: jax.Array  # the eye is inside the bounding sphere


def _geometry(ch, vp: ViewParams) -> _Geometry:
    (dx, dy, dz), x, y, depth = _project(ch.cx, ch.cy, ch.cz, vp.eye, vp.rot)
    dist = jnp.sqrt(dx * dx + dy * dy + dz * dz)
    s = jnp.clip(div_or_zero(ch.radius, dist), 0.0, 1.0)
    return _Geometry((dx, dy, dz), x, y, depth, dist, s, dist <= ch.radius)


# ----------------------------------------------------------------------------------------------
# classify: normal masks against the silhouette table
def facing_rows(ch, vp: ViewParams):
    """Row of the silhouette table (margin level, view-direction bin) of every node (C,) int32: the
    margin covers the view directions to every face the fold touches (the sphere of ``cull_radius``)."""
    g = _geometry(ch, vp)
    s = jnp.clip(div_or_zero(ch.cull_radius, g.dist), 0.0, 1.0)  # every face the fold touches
    margins = np.sin(np.radians(_MARGINS_DEG[:-1])).astype(np.float32)
    level = sum((s > float(mk)).astype(jnp.int32) for mk in margins)
    level = jnp.where(g.dist <= ch.cull_radius, len(_MARGINS_DEG) - 1, level)
    dx, dy, dz = g.d
    return level * _ROWS_PER_MARGIN + dir_bins(-dx, -dy, -dz)


@jax.jit
def facing_flags(ch, vp: ViewParams, table):
    """(possibly front facing, possibly back facing) (C,) bool, in XLA. Its own program: fused into
    the per-node terms, XLA:CPU duplicates the direction-bin arithmetic into several gather loops.

    The device table holds each row's front and back words side by side, so one gather fetches both.
    Most masks use at most 2 of their 12 words (``word_idx``); the few wider ones gather whole rows.
    'clip' mode avoids XLA's slow checked gather. ``table``: :func:`optim._normal_cube.table_device`."""
    row = facing_rows(ch, vp)
    got = jnp.take(table, row[:, None] * 12 + ch.word_idx, axis=0, mode="clip")  # (C, 2 words, front/back)
    hit = jnp.any((got & ch.word_val[:, :, None]) != 0, axis=1)  # (C, 2)
    if ch.wide.shape[0]:
        rows = table.reshape(-1, 12, 2)
        tab = jnp.take(rows, jnp.take(row, ch.wide, mode="clip"), axis=0, mode="clip")  # (W, 12, 2)
        wide_hit = jnp.any((tab & ch.wide_mask[:, :, None]) != 0, axis=1)
        hit = hit.at[ch.wide].set(wide_hit, indices_are_sorted=True, unique_indices=True)
    return hit[:, 0], hit[:, 1]


def facing_host(widx: np.ndarray, hm, n: int):
    """:func:`facing_flags` with numpy gathers, from the table-word positions ``widx`` (C, 2)
    (``facing_rows * 12 + word_idx``) and the chunk's host masks ``hm``; first ``n`` nodes. numpy's
    take on precomputed indices is much faster than XLA:CPU's gather, into which XLA fuses the index
    arithmetic as scalar code."""
    table = table_host()
    m = table.take(widx)
    m &= hm.val[:n]
    m = m[:, 0] | m[:, 1]
    if hm.wide.size:  # (wide masks are never padding): whole rows, OR-ed column by column
        mw = table.reshape(-1, 12).take(widx[hm.wide, 0] // 12, axis=0)
        mw &= hm.wide_val
        acc = mw[:, 0].copy()
        for j in range(1, 12):
            acc |= mw[:, j]
        m[hm.wide] = acc
    half = m.view(np.uint32).reshape(-1, 2)  # (low word: front, high word: back) of each node
    if np.little_endian:
        return half[:, 0] != 0, half[:, 1] != 0
    return half[:, 1] != 0, half[:, 0] != 0


def cone_facing(ch, vp: ViewParams, g: _Geometry):
    """(possibly front facing, possibly back facing) (C,) bool from the normal cone of the faces the
    fold touches (axis ``ax, ay, az``, half-angle ``b``: ``cone_cos``, ``cone_sin``) and the view
    directions to the sphere of ``cull_radius`` (angular radius ``r``): with ``a`` the angle from the
    axis to the direction to the eye, a face can face the eye iff ``a - b - r < 90 deg`` and away iff
    ``a + b + r > 90 deg``; both when ``b + r >= 90 deg`` or the eye is in the sphere."""
    s = jnp.clip(div_or_zero(ch.cull_radius, g.dist), 0.0, 1.0)
    c = jnp.sqrt(jnp.maximum(1.0 - s * s, 0.0))
    sin_g = ch.cone_sin * c + ch.cone_cos * s  # sin(b + r)
    wide = (ch.cone_cos * c - ch.cone_sin * s <= 0.0) | (g.dist <= ch.cull_radius)  # b + r >= 90 deg
    dx, dy, dz = g.d
    cos_a = -div_or_zero(ch.ax * dx + ch.ay * dy + ch.az * dz, g.dist)
    return wide | (cos_a > -sin_g), wide | (cos_a < sin_g)


def classify(nonempty, front, back, out_of_view, cone=None):
    """(culled, backfacing, silhouette) (jax or numpy) from the facing flags of the normal masks,
    :func:`frustum_culled` and those of the cone (:func:`cone_facing`, or None): a wholly back-facing
    node [LHNW00 §4.3] by its mask or one out of view is culled; a node whose mask and cone may both
    face both ways is a silhouette node [LHNW00 §4.2]."""
    backfacing = nonempty & ~front
    sil = front & back
    if cone is not None:
        sil = sil & cone[0] & cone[1]
    return out_of_view | backfacing, backfacing, sil


# ----------------------------------------------------------------------------------------------
# terms
def frustum_culled(ch, vp: ViewParams, g: _Geometry):
    """The sphere of radius ``cull_radius`` (holding every triangle the fold touches) wholly outside a
    side plane of the frustum or before the near plane, and the eye not inside the node's sphere (C,)
    bool."""
    tan_x, tan_y, near = vp.scal[1], vp.scal[2], vp.scal[3]
    r = ch.cull_radius
    x, y, depth = g.x, g.y, g.depth
    ix, iy = jax.lax.rsqrt(1 + tan_x * tan_x), jax.lax.rsqrt(1 + tan_y * tan_y)
    outside = ((depth + r < near)
               | ((x - tan_x * depth) * ix > r) | ((-x - tan_x * depth) * ix > r)
               | ((y - tan_y * depth) * iy > r) | ((-y - tan_y * depth) * iy > r))
    return outside & ~g.inside


def extent(vp: ViewParams, g: _Geometry):
    """(size_px, theta): projected diameter 2 f tan(asin s) = 2 f s / sqrt(1 - s^2) (pixels, guarded at
    s -> 1, capped) and its visual angle (deg of the viewer's visual field)."""
    focal, size_cap, dpp = vp.scal[0], vp.scal[4], vp.scal[5]
    s = g.s
    one_m = jnp.maximum(1.0 - s * s, 1e-12)
    size_px = jnp.where(g.inside, size_cap, jnp.minimum(2.0 * focal * s * jax.lax.rsqrt(one_m), size_cap))
    return size_px, size_px * dpp


def _image(vp: ViewParams, g: _Geometry):
    """(in front of the near plane, direction from the viewer's eye to the node's image point)."""
    focal, near, kx, ky = vp.scal[0], vp.scal[3], vp.scal[6], vp.scal[7]
    front_pt = g.depth > near
    inv_depth = jnp.where(front_pt, 1.0 / jnp.where(front_pt, g.depth, 1.0), 0.0)
    u = focal * g.x * inv_depth  # px from the image centre, x right
    v = -focal * g.y * inv_depth  # y down
    return front_pt, (u * kx, v * ky, jnp.ones_like(u))


#: gaze points up to this many are unrolled in :func:`eccentricity`; more run in a loop (1,000 unrolled took
#: 53 s to compile for a 1,240-node tree)
_UNROLL_GAZE = 8


def eccentricity(vp: ViewParams, g: _Geometry, theta):
    """Eccentricity (deg), minimum over the gaze points, less half of ``theta`` and the gaze error. With a
    gaze ring (``View.gaze_ring_deg`` = r > 0) the angle to a gaze point is to the circle of radius r
    around it: ``|angle - r|`` (on the sphere the nearest point of a circle lies on the great circle
    through its centre)."""
    kx, ky, gaze_err, ring = vp.scal[6], vp.scal[7], vp.scal[8], vp.scal[10]
    front_pt, eye_vec = _image(vp, g)
    gz = vp.gaze

    def to(k):  # the angle to gaze point k (to its ring; |a - 0| is a itself, so no ring changes nothing)
        return jnp.abs(_angle_deg(eye_vec, (gz[k, 0] * kx, gz[k, 1] * ky, 1.0)) - ring)

    ang = to(0)
    if gz.shape[0] <= _UNROLL_GAZE:  # a few gaze points: unrolled (the usual one: straight-line code)
        for k in range(1, gz.shape[0]):
            ang = jnp.minimum(ang, to(k))
    else:  # many: one loop body, so the program (and its compile time) does not grow with G
        ang = jax.lax.fori_loop(1, gz.shape[0], lambda k, a: jnp.minimum(a, to(k)), ang)
    ecc = jnp.maximum(ang - 0.5 * theta - gaze_err, 0.0)
    return jnp.where(front_pt & ~g.inside, ecc, 0.0)


def velocity(ch, vp: ViewParams, g: _Geometry):
    """Retinal velocity (deg/s) of the node's image between the previous view and this one."""
    near, kx, ky, inv_dt = vp.scal[3], vp.scal[6], vp.scal[7], vp.scal[9]
    front_pt, eye_vec = _image(vp, g)
    _, px_, py_, pdepth = _project(ch.cx, ch.cy, ch.cz, vp.prev_eye, vp.prev_rot)
    pfront = pdepth > near
    pinv = jnp.where(pfront, 1.0 / jnp.where(pfront, pdepth, 1.0), 0.0)
    prev_vec = (vp.prev_focal * px_ * pinv * kx, -vp.prev_focal * py_ * pinv * ky, jnp.ones_like(px_))
    return jnp.where(front_pt & pfront, _angle_deg(eye_vec, prev_vec) * inv_dt, 0.0)


def contrast_pair(ch, vp: ViewParams):
    """(own, silhouette) Michelson contrast of display luminances (cd/m2) of every node: ``own`` the
    fold's luminance change ``fold_delta`` above the node's darkest value; ``silhouette`` the larger
    of ``own`` and the node's luminance range against the scene's extremes [LHNW00 §4.2]."""
    black, span, scene_lo, scene_hi = vp.lum[0], vp.lum[1], vp.lum[2], vp.lum[3]
    cd = lambda rel: black + span * jnp.clip(rel, 0.0, 1.0)  # noqa: E731
    mich = lambda a, b: div_or_zero(jnp.abs(a - b), a + b)  # noqa: E731
    lo = cd(ch.lum_min)
    c_own = mich(cd(ch.lum_min + ch.fold_delta), lo)
    c_sil = jnp.maximum(mich(cd(ch.lum_max), cd(scene_lo)), mich(cd(scene_hi), lo))
    return c_own, jnp.maximum(c_sil, c_own)


def select_contrast(silhouette, own, sil, xp=jnp):
    """The one silhouette-vs-own choice [LHNW00 §4.2; LH01 §5.2]: a silhouette node's value is that of
    its silhouette contrast, any other node's that of its own. ``own``/``sil`` may be the contrasts
    or any elementwise function of them (the key-table indices); ``xp`` is jax.numpy or numpy."""
    return xp.where(silhouette, sil, own)


def geometric_error(ch, vp: ViewParams, g: _Geometry):
    """Projected fold error (pixels) at the nearest point of the bounding sphere, capped."""
    focal, near, size_cap = vp.scal[0], vp.scal[3], vp.scal[4]
    near_d = jnp.maximum(g.dist - ch.radius, near)
    return jnp.where(g.inside, size_cap, jnp.minimum(focal * ch.geom_error / near_d, size_cap))


def band_width(ch, vp: ViewParams, g: _Geometry, theta):
    """Angular width (deg) of the band of the image a silhouette fold can change: the slab that holds
    the region and the fan replacing it (``2 slab``, :func:`optim._relight.slab_half_width`) projected
    at the nearest point of the bounding sphere, at most ``theta``."""
    focal, near, dpp = vp.scal[0], vp.scal[3], vp.scal[5]
    near_d = jnp.maximum(g.dist - ch.radius, near)
    return jnp.where(g.inside, theta, jnp.minimum(2.0 * focal * ch.slab / near_d * dpp, theta))


class Terms(NamedTuple):
    culled: jax.Array
    backfacing: jax.Array
    silhouette: jax.Array
    size_px: jax.Array
    theta: jax.Array
    ecc: jax.Array
    vel: jax.Array
    contrast: jax.Array
    err_px: jax.Array
    c_own: jax.Array
    band: jax.Array


def terms(ch, vp: ViewParams, facing, has_gaze: bool, has_motion: bool, need: str) -> Terms:
    """All terms of every node of a chunk, given the ``classify`` flags ``facing`` = (front, back).
    ``need`` (``"perceptual"``, ``"size"``, ``"geometric"``) skips what the metric does not use (0)."""
    g = _geometry(ch, vp)
    culled, backfacing, silhouette = classify(ch.nonempty, facing[0], facing[1], frustum_culled(ch, vp, g),
                                              cone_facing(ch, vp, g))
    size_px, theta = extent(vp, g)
    zero = jnp.zeros_like(ch.radius)
    perceptual = need == "perceptual"
    ecc = eccentricity(vp, g, theta) if has_gaze and perceptual else zero
    vel = velocity(ch, vp, g) if has_motion and perceptual else zero
    c_own, c_sil = contrast_pair(ch, vp) if perceptual else (zero, zero)
    contrast = select_contrast(silhouette, c_own, c_sil) if perceptual else zero
    err_px = geometric_error(ch, vp, g) if need == "geometric" else zero
    band = band_width(ch, vp, g, theta) if perceptual else zero
    return Terms(culled, backfacing, silhouette, size_px, theta, ecc, vel, contrast, err_px, c_own, band)


@eqx.filter_jit
def terms_jit(ch, vp: ViewParams, facing, has_gaze: bool, has_motion: bool):
    """:func:`terms` of the perceptual metric as one XLA program."""
    return terms(ch, vp, facing, has_gaze, has_motion, "perceptual")

"""One viewpoint: camera, physical display geometry, gaze and motion (the ``view`` step of optim).

A :class:`View` says everything the per-view scoring (``optim.score``) needs to turn a node's bounding
sphere (object units) into the quantities a contrast-sensitivity model takes:

* camera: ``eye``, ``target``, ``up`` (object units) and the vertical field of view ``fov_deg`` (deg)
  of a pinhole camera rendering an image of ``width x height`` pixels;
* physical geometry and photometry: a :class:`pmetric.Display` (pixel pitch in m, viewing distance
  in m, black level and peak luminance in cd/m2). Image pixels are display pixels, the image centred on
  the screen, so a size in pixels becomes a visual angle in degrees for *this* viewer;
* gaze: one or more gaze points (pixels, or directions from the eye in object space), default the
  screen centre; with several viewers a node's eccentricity is the smallest over the gaze points
  [LH01 §8.4]. ``gaze=None`` means no gaze information: every node is
  treated as foveal (eccentricity 0) and the eccentricity term costs nothing;
* ``gaze_error_deg``: gaze uncertainty (deg) subtracted from every eccentricity [LHNW00 §4.4]:
  about 1 deg for an eye tracker, about 15 deg when head tracking stands in for it [CAVE]);
* ``gaze_ring_deg``: each gaze point stands for the circle of gaze directions this many degrees around
  it, the gaze somewhere on it (0, the default: the point itself). A node's eccentricity is then its
  smallest angle to the circle, ``|angle to the point - gaze_ring_deg|``, the worst case over the
  circle. With a sensitivity that falls with eccentricity it is also the worst case over every gaze at
  least that far from the point: :func:`optim.lod_sizes` uses it for a gaze known to lie some degrees
  off the object;
* ``lighting``: the scene's light (:class:`optim.Lighting`, directional plus ambient, object space)
  when the renderer relights the mesh from its own normals: fold contrast then covers what
  relighting can show (:mod:`optim._relight`). None (default) is the seeds' pre-lit case: the tree's
  baked vertex intensities or colours are what is displayed;
* ``previous`` and ``dt_s``: the view one time step (s) earlier, for the retinal velocity (deg/s) of
  each node's image. Without a previous view the velocity term costs nothing.

Pixel coordinates: ``(0, 0)`` is the top-left corner, x to the right, y down; the image centre is
``(width / 2, height / 2)``. The camera looks along ``target - eye``; camera space has x right, y up
and the viewing direction along -z.
"""

from __future__ import annotations

import math

import equinox as eqx
import numpy as np

from pmetric import PlodError

from ._mesh import real_or_nan
from ._normal_cube import unit_any_length

__all__ = ["View"]


def _frozen(a: np.ndarray) -> np.ndarray:
    """``a`` as a read-only array of the View's own (a caller's array is copied, so changing it later
    cannot change the view or leave its cached geometry stale)."""
    a = np.array(a, dtype=np.float64)
    a.flags.writeable = False
    return a


_VEC_MAX = 1e150  # eye, target and up components: their squares stay finite in float64


def _vec3(name: str, x, bounded: bool = True) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise PlodError(f"View: {name} must be three numbers, got {x!r}") from None
    if a.shape != (3,):
        raise PlodError(f"View: {name} must be three numbers (shape (3,)), got shape {a.shape}")
    if not np.isfinite(a).all():
        raise PlodError(f"View: {name} must be finite, got {a.tolist()}")
    if bounded and np.abs(a).max() > _VEC_MAX:  # beyond, lengths and dot products overflow ("eye and target coincide")
        raise PlodError(f"View: {name} must lie within {_VEC_MAX:g} of 0 (a mesh is refused beyond 1e15), got "
                        f"{a.tolist()}")
    return _frozen(a)


def _positive(name: str, x, *, upper: float | None = None) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise PlodError(f"View: {name} must be a number, got {x!r}") from None
    if not math.isfinite(v) or v <= 0 or (upper is not None and v >= upper):
        rng = f"in (0, {upper})" if upper is not None else "> 0"
        raise PlodError(f"View: {name} must be finite and {rng}, got {x!r}")
    return v


def framing_sphere(vertices, *, who: str = "framing_sphere") -> tuple[np.ndarray, float]:
    """``(centre (3,), radius)`` of the sphere :meth:`View.framing` frames: about the bounding-box centre
    of ``vertices`` (V, 3), through the farthest vertex (object units; 0 for coincident vertices).
    ``who`` names the caller in the PlodError for another shape."""
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise PlodError(f"{who}: vertices must be a non-empty (V, 3) array, got shape {v.shape}")
    centre = 0.5 * (v.min(0) + v.max(0))
    return centre, float(np.sqrt(((v - centre) ** 2).sum(1).max()))


def _sphere(sphere) -> tuple[np.ndarray, float]:
    """``sphere`` checked as :func:`framing_sphere`'s ``(centre (3,), radius >= 0)``."""
    try:
        centre, radius = sphere
        c, r = np.asarray(centre, dtype=np.float64), float(radius)
    except (TypeError, ValueError):
        raise PlodError(f"View.framing: sphere must be framing_sphere's (centre (3,), radius), got {sphere!r}") from None
    if c.shape != (3,) or not (np.isfinite(c).all() and math.isfinite(r) and r >= 0):
        raise PlodError(f"View.framing: sphere must be a finite centre (3,) and a finite radius >= 0, got {sphere!r}")
    return c, r


class View(eqx.Module):
    """A camera, the display it is shown on, the viewer's gaze and (optionally) the previous view.

    Fields (numpy, float64): ``eye``, ``target``, ``up`` (3,) object units; ``fov_deg`` vertical field
    of view (deg; default: the angle the image subtends at the viewer, so rendering is geometrically
    correct for this display); ``width``, ``height`` image size (pixels); ``display`` (:class:`pmetric.Display`);
    ``gaze_px`` (G, 2) gaze points in pixels or None (no gaze: eccentricity 0 everywhere);
    ``gaze_error_deg`` (deg); ``gaze_ring_deg`` (deg, 0 .. 180; see the module's notes: the gaze
    somewhere on a circle of this radius around each gaze point); ``background`` relative luminance (0..1) of the background, used for
    silhouette contrast; ``near`` near-plane distance (object units); ``previous`` (View or None) and
    ``dt_s`` (s); ``lighting`` (:class:`optim.Lighting` or None: relit or pre-lit display).

    ``gaze`` may be ``"center"`` (default: the screen centre), None, an array (G, 2) of pixel
    coordinates (each on the image: in ``[0, width] x [0, height]``), or an array (G, 3) of gaze
    directions from the eye in object space (each must point in front of the camera; it may look
    past the screen edge).
    """

    eye: np.ndarray
    target: np.ndarray
    up: np.ndarray
    fov_deg: float = eqx.field(static=True)
    width: int = eqx.field(static=True)
    height: int = eqx.field(static=True)
    display: object
    gaze_px: np.ndarray | None
    gaze_error_deg: float = eqx.field(static=True)
    gaze_ring_deg: float = eqx.field(static=True)
    background: float = eqx.field(static=True)
    near: float = eqx.field(static=True)
    previous: "View | None"
    dt_s: float = eqx.field(static=True)
    lighting: object = eqx.field(static=True)
    _geom: tuple = eqx.field(static=True)  # (pitch x m, pitch y m, distance m, deg per px), cached

    def __init__(
        self,
        eye,
        target=(0.0, 0.0, 0.0),
        up=(0.0, 1.0, 0.0),
        fov_deg: float | None = None,
        image_size: tuple[int, int] | None = None,
        display=None,
        gaze="center",
        gaze_error_deg: float = 1.0,
        gaze_ring_deg: float = 0.0,
        previous: "View | None" = None,
        dt_s: float | None = None,
        background: float = 0.0,
        near: float | None = None,
        lighting=None,
    ):
        import pmetric

        self.eye = _vec3("eye", eye)
        self.target = _vec3("target", target)
        self.up = _vec3("up", up)
        if not np.any(self.up):
            raise PlodError("View: up must be a nonzero vector, got (0, 0, 0)")
        fwd = self.target - self.eye
        # relative to the positions' own magnitude, so a view of a tiny (1e-20 units) object is fine
        if np.linalg.norm(fwd) <= 1e-12 * max(np.linalg.norm(self.eye), np.linalg.norm(self.target)):
            raise PlodError("View: eye and target coincide; the viewing direction is undefined")
        if np.linalg.norm(np.cross(fwd, self.up)) <= 1e-9 * np.linalg.norm(fwd) * max(np.linalg.norm(self.up), 1e-300):
            raise PlodError("View: up must not be parallel to the viewing direction (target - eye)")
        if display is None:
            display = pmetric.Display.default()
        if not isinstance(display, pmetric.Display):
            raise PlodError(f"View: display must be a pmetric.Display, got {type(display).__name__}")
        self.display = display
        pitch = display.pixel_pitch
        self._geom = (float(pitch[0]), float(pitch[1]), float(display.distance), float(display.degrees_per_pixel()))
        if image_size is None:
            image_size = display.resolution
        try:
            wh = [s for s in image_size]
            w, h = (int(s) for s in wh)
            whole = len(wh) == 2 and all(not isinstance(s, (bool, np.bool_)) and s == int(s) for s in wh)
        except (TypeError, ValueError, OverflowError):
            whole = False
        if not whole or w <= 0 or h <= 0:
            raise PlodError(f"View: image_size must be two positive integers (width, height), got {image_size!r}")
        self.width, self.height = w, h
        if fov_deg is None:  # the physically correct camera: the image spans what the viewer sees of it
            py = float(display.height) / display.resolution[1]
            fov_deg = math.degrees(2 * math.atan(0.5 * h * py / float(display.distance)))
        self.fov_deg = _positive("fov_deg (vertical field of view, deg)", fov_deg, upper=180.0)
        ge = real_or_nan(gaze_error_deg)
        if not 0 <= ge <= 180:  # an angle (1e300 overflowed the float32 terms)
            raise PlodError(f"View: gaze_error_deg must be an angle in [0, 180] deg, got {gaze_error_deg!r}")
        self.gaze_error_deg = ge
        gr = real_or_nan(gaze_ring_deg)
        if not 0 <= gr <= 180:
            raise PlodError(f"View: gaze_ring_deg must be an angle in [0, 180] deg, got {gaze_ring_deg!r}")
        self.gaze_ring_deg = gr
        bg = real_or_nan(background)
        if not (0.0 <= bg <= 1.0):
            raise PlodError(f"View: background must be a relative luminance in [0, 1], got {background!r}")
        self.background = bg
        dist = float(np.linalg.norm(fwd))
        self.near = _positive("near (object units)", near) if near is not None else 1e-4 * dist
        if previous is not None:
            if not isinstance(previous, View):
                raise PlodError(f"View: previous must be a View, got {type(previous).__name__}")
            if dt_s is None:
                raise PlodError("View: a previous view needs dt_s, the time step in seconds")
            self.dt_s = _positive("dt_s (s)", dt_s)
        else:
            if dt_s is not None:
                raise PlodError("View: dt_s given without a previous view")
            self.dt_s = 0.0
        self.previous = previous
        if lighting is not None:
            from ._tree import Lighting

            lighting = Lighting.coerce(lighting)
        self.lighting = lighting
        g = self._gaze_pixels(gaze)
        if g is None and gr > 0:
            raise PlodError("View: gaze_ring_deg needs a gaze (a circle around each gaze point); gaze is None")
        self.gaze_px = None if g is None else _frozen(g)

    @classmethod
    def framing(cls, vertices, object_deg: float = 30.0, direction=(0.0, 0.0, 1.0), up=(0.0, 1.0, 0.0),
                *, sphere=None, **kw) -> "View":
        """A view looking at the centre of ``vertices`` (V, 3) from ``direction`` such that their bounding
        sphere (about the bounding-box centre) subtends ``object_deg`` degrees of the viewer's visual
        field (default 30 deg: the study of [LH01 §6.2], an object on a 46 deg screen). ``kw`` go to ``View``
        (``display``, ``gaze``, ``gaze_error_deg`` ...); the camera's field of view is the display's.
        ``sphere``: :func:`framing_sphere` of ``vertices``, given to frame one object from many directions
        without a pass over its vertices per view (``vertices`` is then not read)."""
        centre, radius = framing_sphere(vertices, who="View.framing") if sphere is None else _sphere(sphere)
        deg = _positive("object_deg (deg)", object_deg, upper=180.0)
        d = _vec3("direction", direction, bounded=False)
        if not np.any(d):
            raise PlodError("View.framing: direction must be nonzero")
        du = unit_any_length(d)  # any length: a 1e-320 direction's norm underflowed ("must be nonzero")
        radius = radius if radius > 0 else 1.0
        dist = radius / math.sin(math.radians(deg) / 2)
        eye = centre + du * dist  # (a 1e308-long direction: its norm would overflow)
        up = _vec3("up", up)
        if not np.any(up):  # only an up parallel to the direction is replaced below, not a missing one
            raise PlodError("View.framing: up must be a nonzero vector, got (0, 0, 0)")
        if np.linalg.norm(np.cross(du, up)) < 1e-6 * max(np.linalg.norm(up), 1e-300):
            up = np.array([1.0, 0.0, 0.0]) if abs(du[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
        return cls(eye=eye, target=centre, up=up, **kw)

    # ------------------------------------------------------------------ camera
    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) world -> camera rotation; rows are the camera's right, up and back (-forward) axes."""
        fwd = self.target - self.eye
        fwd = fwd / np.linalg.norm(fwd)
        right = np.cross(fwd, self.up)
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd)
        return np.stack([right, up, -fwd])

    @property
    def focal_px(self) -> float:
        """Focal length in pixels: (height / 2) / tan(fov_deg / 2)."""
        return 0.5 * self.height / math.tan(math.radians(self.fov_deg) / 2)

    @property
    def pixel_pitch_m(self) -> tuple[float, float]:
        """(horizontal, vertical) size of one pixel on the display, m."""
        return self._geom[0], self._geom[1]

    @property
    def distance_m(self) -> float:
        """Viewing distance from the eye to the screen centre, m."""
        return self._geom[2]

    @property
    def degrees_per_pixel(self) -> float:
        """Visual angle of one pixel at the screen centre (deg)."""
        return self._geom[3]

    def project(self, points) -> tuple[np.ndarray, np.ndarray]:
        """World points (..., 3) -> (pixel coordinates (..., 2), depth along the view axis (...)).

        Depth is in object units; points with depth <= 0 are behind the camera (their pixels are inf).
        """
        return self._project_camera((np.asarray(points, dtype=np.float64) - self.eye) @ self.rotation.T)

    def _project_camera(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`project` of camera-space vectors ``p`` (..., 3) from the eye (rotated, not moved: a
        direction from the eye projects as the point ``eye + p`` without the rounding of adding the eye)."""
        depth = -p[..., 2]
        front = depth > 0
        s = self.focal_px / np.where(front, depth, 1.0)
        xy = np.stack([0.5 * self.width + p[..., 0] * s, 0.5 * self.height - p[..., 1] * s], axis=-1)
        xy = np.where(front[..., None], xy, np.inf)
        return xy, depth

    def visual_angle_px(self, a, b) -> np.ndarray:
        """Visual angle (deg) between two pixel positions (..., 2) as seen by the viewer of the display."""
        pa, pb = self._eye_vectors(np.asarray(a, float)), self._eye_vectors(np.asarray(b, float))
        cr = np.linalg.norm(np.cross(pa, pb), axis=-1)
        return np.degrees(np.arctan2(cr, np.sum(pa * pb, axis=-1)))

    def _eye_vectors(self, xy):
        px, py = self.pixel_pitch_m
        x = (xy[..., 0] - 0.5 * self.width) * px
        y = (xy[..., 1] - 0.5 * self.height) * py
        return np.stack([x, y, np.full_like(x, self.distance_m)], axis=-1)

    # ------------------------------------------------------------------ gaze
    def _gaze_pixels(self, gaze):
        if gaze is None:
            return None
        if isinstance(gaze, str):
            if gaze != "center":
                raise PlodError(f"View: gaze must be 'center', None, (G, 2) pixels or (G, 3) directions; got {gaze!r}")
            return np.array([[0.5 * self.width, 0.5 * self.height]])
        try:
            g = np.asarray(gaze, dtype=np.float64)
        except (TypeError, ValueError):
            raise PlodError(
                f"View: gaze must be (G, 2) pixel coordinates or (G, 3) directions, got {gaze!r}") from None
        if g.ndim == 1:
            g = g[None]
        if g.ndim != 2 or g.shape[0] == 0 or g.shape[1] not in (2, 3):
            raise PlodError(f"View: gaze must be (G, 2) pixel coordinates or (G, 3) directions, got shape {g.shape}")
        if not np.isfinite(g).all():
            raise PlodError("View: gaze contains a non-finite value")
        if g.shape[1] == 3:
            if not np.abs(g).max(axis=1).all():
                raise PlodError("View: a gaze direction is zero")
            # the direction rotated into the camera frame, not eye + g projected: far from 0 the sum
            # rounds g away (at |eye| ~ 1e15 a gaze moved by degrees, or turned behind the camera)
            xy, depth = self._project_camera(g @ self.rotation.T)
            if (depth <= 0).any():
                raise PlodError("View: a gaze direction points behind the camera")
            return xy  # may lie off the screen: a viewer can look past its edge
        off = (g[:, 0] < 0) | (g[:, 0] > self.width) | (g[:, 1] < 0) | (g[:, 1] > self.height)
        if off.any():
            x, y = g[int(np.flatnonzero(off)[0])]
            raise PlodError(f"View: gaze point ({x:g}, {y:g}) px is off the {self.width}x{self.height} image "
                            f"(pixel gazes must lie in [0, {self.width}] x [0, {self.height}]; pass a (G, 3) "
                            "direction to look past the screen edge)")
        return g

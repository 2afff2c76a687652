"""An independent image judge: render the original and the simplified mesh, score them with
FovVideoVDP [Man21] (foveated, in JOD) and FLIP [And20].

Hand-written around two third-party metrics because neither knows plod's viewing conditions: the
renderings come from :func:`experiments.render.render` (``"relit"``: per-pixel Lambert shading from each
mesh's own normals, the pass a renderer would run; ``"baked"``: the vertex colours or pre-lit
intensities plod's model assumes), the display model passed to FovVideoVDP is built from the view's
:class:`pmetric.Display` (geometry: image size, physical size, viewing distance; photometry: plod's
own transfer function, peak luminance and black level, in cd/m2) and the fixation point is the view's
first gaze point. FovVideoVDP is foveated: sensitivity falls with eccentricity from that point
[Man21], which plod's eccentricity terms model too, so the judge checks them independently.

Rendering at ``size`` smaller than the view's image keeps the angular content: the display geometry
keeps the image's physical size and viewing distance, so the pixels per degree scale with the size
(FLIP gets the same pixels per degree).

Units: pixels per degree (px/deg) at the screen centre, luminance cd/m2, angles deg, JOD (just
objectionable differences; 10 = no visible difference, one JOD less = 75% of observers prefer the
reference). Licences: pyfvvdp (FovVideoVDP) is CC BY-NC 4.0, non-commercial use only; FLIP is BSD-3;
plod is MIT. torch and pyfvvdp are the optional ``judge`` extra and are imported inside the functions.
"""

from __future__ import annotations

import functools
import logging
import math
import os
import time
import warnings
from dataclasses import dataclass

import numpy as np

from pmetric import PlodError

METRICS = ("fovvdp", "flip")
# pyfvvdp 1.2.2's .mat reader uses a scipy namespace deprecated since SciPy 1.8 (works until SciPy 2.0).
_PYFVVDP_WARNINGS = (r"Please import `mat_struct` from the `scipy\.io\.matlab` namespace",)


@dataclass(frozen=True)
class JudgeResult:
    """One judgement of a test rendering against a reference rendering, same view.

    ``jod``: FovVideoVDP quality in JOD (10 = indistinguishable; None when not computed).
    ``flip_mean``: mean FLIP error in [0, 1] (None when not computed). ``reference``, ``test``:
    (H, W, 3) float32 sRGB renderings. ``vdp_map``: (H, W) float32 FovVideoVDP raw difference map
    (0 = none; pyfvvdp's visualisation clips it to [0, 1]) or None. ``flip_map``: (H, W) float32 in [0, 1]
    or None. ``pixels_per_degree``: px/deg at the screen centre of the rendering. ``fixation_px``: (x, y)
    fixation point in rendering pixels (continuous, origin top-left; may lie off the image).
    ``seconds``: wall time of the judgement (rendering and metrics). ``mode``: ``"relit"`` or ``"baked"``.
    """

    jod: float | None
    flip_mean: float | None
    reference: np.ndarray
    test: np.ndarray
    vdp_map: np.ndarray | None
    flip_map: np.ndarray | None
    pixels_per_degree: float
    fixation_px: tuple[float, float]
    seconds: float
    mode: str


# ----------------------------------------------------------------------------------------------- views
def offset_gaze_view(vertices, offset_deg: float = 0.0, *, object_deg: float = 30.0, direction=(0.0, 0.0, 1.0),
                     gaze_error_deg: float = 1.0, **kw):
    """``optim.View.framing(vertices, object_deg, direction, ...)`` with the gaze ``offset_deg`` degrees of
    visual angle to the right of the object's centre (the screen centre); 0: at the centre.

    The gaze is a direction from the eye (``View`` accepts (G, 3) directions), so it may lie beyond
    the screen edge (29 deg in [LH01 Fig 8] is past the 23-deg edge of a 46-deg screen). ``kw`` go to
    ``View`` (``display``, ``background`` ...).
    """
    import optim

    base = optim.View.framing(vertices, object_deg, direction, gaze_error_deg=gaze_error_deg, **kw)
    if offset_deg == 0:
        return base
    d = base.rotation.T @ np.array([math.tan(math.radians(offset_deg)), 0.0, -1.0])  # camera right of forward
    return optim.View.framing(vertices, object_deg, direction, gaze_error_deg=gaze_error_deg, gaze=d[None], **kw)


def rendering_size(view, size) -> tuple[int, int]:
    """(width, height) of the rendering: ``size`` or the view's image size; PlodError when not positive."""
    w, h = (view.width, view.height) if size is None else size
    try:
        w, h = int(w), int(h)
    except (TypeError, ValueError):
        raise PlodError(f"judge: size must be two positive integers (width, height), got {size!r}") from None
    if w <= 0 or h <= 0:
        raise PlodError(f"judge: size must be two positive integers (width, height), got {size!r}")
    return w, h


def image_geometry(view, size=None) -> tuple[float, float, float]:
    """(image width m, image height m, viewing distance m) of the view's image on its display.

    The image is ``view.width`` x ``view.height`` display pixels centred on the screen; a rendering of
    ``size`` spans the same physical height (the camera's vertical field of view) with square pixels.
    """
    w, h = rendering_size(view, size)
    height_m = view.height * view.pixel_pitch_m[1]
    return height_m * w / h, height_m, view.distance_m


def pixels_per_degree(view, size=None) -> float:
    """Pixels per degree (px/deg) at the centre of a rendering of ``size`` (default the view's image):
    the display geometry handed to FovVideoVDP and FLIP."""
    w, _ = rendering_size(view, size)
    width_m, _, dist = image_geometry(view, size)
    return 1.0 / (2.0 * math.degrees(math.atan(0.5 * width_m / w / dist)))


def fixation_px(view, size=None) -> tuple[float, float]:
    """The fixation point (x, y) in pixels of a rendering of ``size``: the view's first gaze point
    scaled to the rendering, or the image centre when the view has no gaze."""
    w, h = rendering_size(view, size)
    if view.gaze_px is None:
        return 0.5 * w, 0.5 * h
    gx, gy = (float(x) for x in view.gaze_px[0])
    return gx * w / view.width, gy * h / view.height


# ----------------------------------------------------------------------------------------------- FovVideoVDP
def _torch():
    """torch, with its CPU threads capped at this process's CPUs (containers report the host's cores)."""
    import torch

    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    if torch.get_num_threads() > cpus:
        torch.set_num_threads(cpus)
    return torch


def _device():
    torch = _torch()
    return torch.device("cuda:0" if torch.cuda.is_available() else "cpu")


class _QuietRootLogger:
    """pyfvvdp logs through the root logger (``logging.debug``), which installs a stderr handler when
    none exists; a NullHandler while it runs keeps library calls silent."""

    def __enter__(self):
        root = logging.getLogger()
        self._handler = logging.NullHandler() if not root.handlers else None
        if self._handler is not None:
            root.addHandler(self._handler)

    def __exit__(self, *exc):
        if self._handler is not None:
            logging.getLogger().removeHandler(self._handler)


@functools.lru_cache(maxsize=4)
def _metric(width_px: int, height_px: int, height_m: float, distance_m: float, peak: float, black: float,
            heatmap: bool, device: str):
    """A foveated pyfvvdp.fvvdp for absolute luminance (cd/m2) on the given image geometry (cached:
    its CSF tables and pyramid are reused between calls)."""
    torch = _torch()
    import pyfvvdp
    from pyfvvdp.fvvdp_display_model import fvvdp_display_geometry, fvvdp_display_photo_absolute

    class _Absolute(fvvdp_display_photo_absolute):
        """Absolute photometry: plod has already mapped the sRGB pixels to cd/m2 with its own display
        model; only clamp to [black, peak] (pyfvvdp's version also logs about dark images)."""

        def forward(self, V):
            return V.clamp(self.L_min, self.L_max)

    fov_v = 2.0 * math.degrees(math.atan(0.5 * height_m / distance_m))
    geometry = fvvdp_display_geometry((width_px, height_px), distance_m=distance_m, fov_vertical=fov_v)
    with warnings.catch_warnings(), _QuietRootLogger():
        for msg in _PYFVVDP_WARNINGS:
            warnings.filterwarnings("ignore", message=msg, category=DeprecationWarning)
        return pyfvvdp.fvvdp(display_photometry=_Absolute(L_max=peak, L_min=black), display_geometry=geometry,
                             color_space="sRGB", foveated=True, heatmap="raw" if heatmap else None, quiet=True,
                             device=torch.device(device))


def luminance_image(img: np.ndarray, display) -> np.ndarray:
    """(...) float32 luminance (cd/m2) a ``pmetric.Display`` emits for sRGB pixels (..., 3) in [0, 1]: an image
    (H, W, 3) or frames (F, H, W, 3)."""
    return np.array(display.luminance(np.clip(np.asarray(img, dtype=np.float32), 0.0, 1.0)), dtype=np.float32)


def fovvdp(reference: np.ndarray, test: np.ndarray, view, *, heatmap: bool = True,
           fps: float | None = None) -> tuple[float, np.ndarray | None]:
    """FovVideoVDP [Man21] of two renderings of ``view``: (JOD, raw map or None).

    Images: (H, W, 3) sRGB in [0, 1], judged as still images (map (H, W)). Videos: (F, H, W, 3) frames
    shown at ``fps`` (Hz, required for a video and only for one), judged with FovVideoVDP's temporal
    channels, so a change that moves across the screen is weighed by the spatio-temporal CSF (map
    (F, H, W)). Foveated at :func:`fixation_px` (a fixed fixation for every frame); the images are turned
    into luminance (cd/m2) by the view's ``pmetric.Display`` (its transfer function, peak luminance and
    black level) and shown on that display's geometry scaled to the image size
    (:func:`pixels_per_degree`). Runs on CUDA when torch sees a GPU, else on the CPU.
    """
    ref = np.asarray(reference, dtype=np.float32)
    tst = np.asarray(test, dtype=np.float32)
    video = ref.ndim == 4
    if ref.shape != tst.shape or ref.ndim not in (3, 4) or ref.shape[-1] != 3:
        raise PlodError(f"fovvdp: images must both be (H, W, 3) or videos (F, H, W, 3), got {ref.shape} and "
                        f"{tst.shape}")
    if video != (fps is not None) or (video and not (math.isfinite(fps) and fps > 0)):
        raise PlodError(f"fovvdp: a video needs fps > 0 and a still image none, got shape {ref.shape} and "
                        f"fps={fps!r}")
    h, w = ref.shape[-3:-1]
    _, height_m, dist = image_geometry(view, (w, h))
    disp = view.display
    dev = _device()
    metric = _metric(w, h, float(height_m), float(dist), float(disp.peak_luminance), float(disp.black_level),
                     bool(heatmap), str(dev))
    torch = _torch()
    fx, fy = fixation_px(view, (w, h))
    fix = torch.tensor([fx - 0.5, fy - 0.5], dtype=torch.float32)  # pyfvvdp: pixel index, centre at +0.5
    with torch.no_grad(), _QuietRootLogger():
        q, stats = metric.predict(torch.from_numpy(luminance_image(tst, disp)),
                                  torch.from_numpy(luminance_image(ref, disp)), dim_order="FHW" if video else "HW",
                                  frames_per_second=float(fps) if video else 0, fixation_point=fix)
    vmap = None
    if heatmap:
        vmap = stats["heatmap"][0, 0].float().cpu().numpy()
        vmap = vmap if video else vmap[0]
    return float(q), vmap


def fovvdp_clip(reference_frames, test_frames, view, fps: float, *, still_every: int = 1,
                heatmap: bool = False) -> tuple[float, list[float], np.ndarray | None]:
    """A clip judged two ways: ``(video JOD, still JODs, map)``. ``reference_frames``, ``test_frames``:
    (F, H, W, 3) sRGB renderings of the same camera path; ``view``: any frame's view (its display,
    geometry and gaze fix the fixation, held for the whole clip); ``fps`` (Hz).

    The video is :func:`fovvdp` with FovVideoVDP's temporal channels (a change that moves or pops is
    weighed by the spatio-temporal CSF, with the eye fixed on the gaze point); the stills judge every
    ``still_every``-th frame alone (what an eye that pursues the motion sees, about). ``map``: the
    video's (F, H, W) map with ``heatmap``, else None.
    """
    ref = np.asarray(reference_frames, dtype=np.float32)
    tst = np.asarray(test_frames, dtype=np.float32)
    if int(still_every) < 1:
        raise PlodError(f"fovvdp_clip: still_every must be >= 1, got {still_every!r}")
    jod, vmap = fovvdp(ref, tst, view, fps=fps, heatmap=heatmap)
    still = [fovvdp(a, b, view, heatmap=False)[0] for a, b in zip(ref[::int(still_every)], tst[::int(still_every)])]
    return jod, still, vmap


# ----------------------------------------------------------------------------------------------- judge
def judge(reference_mesh, test_mesh, view, *, mode: str = "relit", lighting=None, size=None,
          metrics=METRICS, heatmap: bool = True) -> JudgeResult:
    """Render ``reference_mesh`` and ``test_mesh`` (each ``(vertices, faces, colors or None)``, or with
    vertex normals (V, 3) as a fourth element for the relit pass) for ``view`` and judge the test
    rendering against the reference.

    ``mode``: ``"relit"`` or ``"baked"`` (:func:`experiments.render.render`); ``lighting``: an
    ``optim.Lighting`` (None: its default). ``size`` (width, height) in pixels, default the view's image;
    smaller renders keep the angular content (pixels per degree scaled). ``metrics``: any of ``"fovvdp"``
    (FovVideoVDP [Man21], foveated at the view's first gaze point, needs torch and pyfvvdp) and ``"flip"``
    (FLIP [And20]). ``heatmap``: also return FovVideoVDP's difference map (about 1 s more at 1920x1080
    on a 2-core CPU). Raises ``RuntimeError`` when no OpenGL context exists.
    """
    from experiments import render as R

    t0 = time.perf_counter()
    bad = [m for m in metrics if m not in METRICS]
    if bad or not metrics:
        raise PlodError(f"judge: metrics must be a non-empty subset of {METRICS}, got {tuple(metrics)!r}")
    w, h = rendering_size(view, size)
    rv, rf, rc, rn = R.mesh_parts(reference_mesh, "judge: reference_mesh")
    tv, tf, tc, tn = R.mesh_parts(test_mesh, "judge: test_mesh")
    ref = R.render(rv, rf, rc, view, lighting=lighting, mode=mode, size=(w, h), normals=rn)
    tst = R.render(tv, tf, tc, view, lighting=lighting, mode=mode, size=(w, h), normals=tn)
    ppd = pixels_per_degree(view, (w, h))
    jod = vmap = mean = fmap = None
    if "fovvdp" in metrics:
        jod, vmap = fovvdp(ref, tst, view, heatmap=heatmap)
    if "flip" in metrics:
        fmap, mean = R.flip(ref, tst, ppd)
    return JudgeResult(jod, mean, ref, tst, vmap, fmap, ppd, fixation_px(view, (w, h)),
                       time.perf_counter() - t0, mode)


def save_judgement(path, res: JudgeResult, *, titles: tuple[str, str] = ("reference", "test"), protect=()) -> None:
    """Write a PNG (atomically): reference | test renderings | FovVideoVDP map | FLIP map, titled with the
    JOD and mean FLIP; the fixation point is marked on the maps."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import pmetric as pm

    h, w = res.reference.shape[:2]
    panels = [(res.reference, f"{titles[0]} ({res.mode})"), (res.test, titles[1])]
    if res.vdp_map is not None:
        panels.append((res.vdp_map, f"FovVideoVDP: {res.jod:.3f} JOD"))
    if res.flip_map is not None:
        panels.append((res.flip_map, f"FLIP: mean {res.flip_mean:.4f} ({res.pixels_per_degree:.1f} px/deg)"))
    fig, axes = plt.subplots(1, len(panels), figsize=(5 * len(panels), 5 * h / w + 0.6), constrained_layout=True,
                             squeeze=False)
    fx, fy = res.fixation_px
    for ax, (img, title) in zip(axes[0], panels):
        if img.ndim == 3:
            ax.imshow(img)
        else:
            im = ax.imshow(img, cmap="magma", vmin=0.0, vmax=1.0)
            fig.colorbar(im, ax=ax, fraction=0.046)
            if 0 <= fx <= w and 0 <= fy <= h:
                ax.plot([fx], [fy], marker="+", color="cyan", markersize=12)
        ax.set_title(title)
        ax.axis("off")
    with pm.atomic_path(path, protect=protect) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)

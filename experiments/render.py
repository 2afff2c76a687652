"""Headless rendering of a mesh for a view, and the FLIP difference between two renderings.

What a simplification looks like is what matters, so ``plod simplify --render OUT.png`` draws the
original and the simplified mesh for the same :class:`optim.View` with pyrender (offscreen, EGL when
``PYOPENGL_PLATFORM=egl``), Gouraud-shaded from pre-lit vertex intensities exactly as the perceptual
model assumes ([LHNW00 §4], [LH01 §5.2]: extremes of intensity occur at vertices), and measures the
difference with NVIDIA's FLIP [And20], whose pixels-per-degree comes from the view's display.

Heavy imports (pyrender, flip_evaluator, matplotlib) happen inside the functions.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from pmetric import PlodError


def _vertex_rgb(vertices, faces, colors, lighting) -> np.ndarray:
    """(V, 3) float32 sRGB in [0, 1]: the colours when given, else grey pre-lit intensities."""
    if colors is not None:
        return np.clip(np.asarray(colors, dtype=np.float32), 0.0, 1.0)
    import optim
    import pmetric as pm

    lum = optim.vertex_luminance(vertices, faces, None, lighting)  # relative linear luminance
    grey = np.asarray(pm.linear_to_srgb(np.asarray(lum, dtype=np.float32)))
    return np.repeat(grey[:, None], 3, axis=1).astype(np.float32)


def render(vertices, faces, colors, view, *, lighting=None, size: tuple[int, int] | None = None,
           background: float | None = None) -> np.ndarray:
    """Render a mesh for ``view``: returns (H, W, 3) float32 sRGB in [0, 1].

    ``vertices`` (V, 3), ``faces`` (T, 3), ``colors`` (V, 3) sRGB in [0, 1] or None (then pre-lit
    with ``lighting``, an ``optim.Lighting``, as the vertex tree does). ``size`` = (width, height) in
    pixels (default the view's image size). The camera is the view's: eye, target, up and vertical
    field of view; the background is the view's background relative luminance unless given.
    Raises ``RuntimeError`` with a hint when no OpenGL context can be created.
    """
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    import pyrender
    import trimesh

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise PlodError(f"render: vertices must be (V, 3) and faces (T, 3), got {v.shape} and {f.shape}")
    w, h = size if size is not None else (view.width, view.height)
    if int(w) <= 0 or int(h) <= 0:
        raise PlodError(f"render: size must be two positive integers, got {size!r}")
    rgb = _vertex_rgb(v, f, colors, lighting)
    bg_lum = view.background if background is None else float(background)
    import pmetric as pm

    bg = float(pm.linear_to_srgb(np.float32(bg_lum)))
    scene = pyrender.Scene(bg_color=[bg, bg, bg, 1.0], ambient_light=[1.0, 1.0, 1.0])
    if len(f):
        mesh = trimesh.Trimesh(v, f, vertex_colors=(rgb * 255).round().astype(np.uint8), process=False)
        scene.add(pyrender.Mesh.from_trimesh(mesh, smooth=True))
    # Camera pose: columns are the camera's x (right), y (up) and z (backwards) axes in world space.
    fwd = view.target - view.eye
    fwd = fwd / np.linalg.norm(fwd)
    right = np.cross(fwd, view.up)
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, up, -fwd, view.eye
    dist = float(np.linalg.norm(view.target - view.eye))
    extent = float(np.linalg.norm(v.max(0) - v.min(0))) if len(v) else 1.0
    cam = pyrender.PerspectiveCamera(yfov=np.radians(view.fov_deg), aspectRatio=w / h,
                                     znear=max(view.near, 1e-3 * dist), zfar=dist + 4 * extent + 1.0)
    scene.add(cam, pose=pose)
    try:
        renderer = pyrender.OffscreenRenderer(int(w), int(h))
    except Exception as exc:  # pyrender raises several kinds when no GL context exists
        raise RuntimeError(
            f"render: cannot create an offscreen OpenGL context ({exc}); install Mesa's EGL "
            "(Debian: libegl1 libegl-mesa0 libgl1-mesa-dri libopengl0) and set PYOPENGL_PLATFORM=egl") from exc
    try:
        color, _ = renderer.render(scene, flags=pyrender.RenderFlags.FLAT)
    finally:
        renderer.delete()
    return color[..., :3].astype(np.float32) / 255.0


def flip(reference: np.ndarray, test: np.ndarray, pixels_per_degree: float) -> tuple[np.ndarray, float]:
    """FLIP error map (H, W) in [0, 1] and its mean between two sRGB images (H, W, 3) in [0, 1].

    ``pixels_per_degree`` is the viewing condition (the display's pixels per degree at its centre).
    """
    import flip_evaluator

    ref = np.ascontiguousarray(reference, dtype=np.float32)
    tst = np.ascontiguousarray(test, dtype=np.float32)
    if ref.shape != tst.shape or ref.ndim != 3 or ref.shape[2] != 3:
        raise PlodError(f"flip: images must both be (H, W, 3), got {ref.shape} and {tst.shape}")
    emap, mean, _ = flip_evaluator.evaluate(ref, tst, "LDR", inputsRGB=True, applyMagma=False,
                                            parameters={"ppd": float(pixels_per_degree)})
    emap = np.asarray(emap, dtype=np.float32)
    if emap.ndim == 3:
        emap = emap[..., 0]
    return emap, float(mean)


@dataclass(frozen=True)
class Comparison:
    """Original and simplified renderings of one view and their FLIP difference."""

    original: np.ndarray  # (H, W, 3) sRGB in [0, 1]
    simplified: np.ndarray  # (H, W, 3)
    flip_map: np.ndarray  # (H, W) in [0, 1]
    mean_flip: float
    pixels_per_degree: float


def compare(tree, simplified, view, *, size: tuple[int, int] | None = None) -> Comparison:
    """Render ``tree``'s full mesh and ``simplified`` = (vertices, faces, colors) for ``view``; FLIP them.

    ``size`` (width, height) renders smaller than the view's image; the pixels per degree passed to FLIP
    is scaled so the comparison is of the same angular content.
    """
    w, h = size if size is not None else (view.width, view.height)
    ppd = float(view.display.pixels_per_degree()) * (w / view.width)
    lighting = getattr(tree, "lighting", None)
    original = render(tree.vertices, tree.faces, tree.colors, view, lighting=lighting, size=(w, h))
    v2, f2, c2 = simplified
    simple = render(v2, f2, c2, view, lighting=lighting, size=(w, h))
    emap, mean = flip(original, simple, ppd)
    return Comparison(original, simple, emap, mean, ppd)


def save_comparison(path, comp: Comparison, *, titles: tuple[str, str] = ("original", "simplified"),
                    protect=()) -> None:
    """Write a PNG (atomically) with the two renderings side by side and the FLIP error map."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import pmetric as pm

    fig, axes = plt.subplots(1, 3, figsize=(15, 5.4), constrained_layout=True)
    for ax, img, title in zip(axes, (comp.original, comp.simplified), titles):
        ax.imshow(img)
        ax.set_title(title)
        ax.axis("off")
    im = axes[2].imshow(comp.flip_map, cmap="magma", vmin=0.0, vmax=1.0)
    axes[2].set_title(f"FLIP error (mean {comp.mean_flip:.4f}, {comp.pixels_per_degree:.1f} px/deg)")
    axes[2].axis("off")
    fig.colorbar(im, ax=axes[2], fraction=0.046)
    with pm.atomic_path(path, protect=protect) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)

"""Headless rendering of a mesh for a view, and the FLIP difference between two renderings.

Hand-written here (not a pyrender scene with its PBR lights) because the judge must shade exactly as
plod's model does: pyrender (offscreen, EGL when ``PYOPENGL_PLATFORM=egl``) only rasterises, with
``RenderFlags.FLAT`` (unlit interpolation of vertex colours, 4x MSAA, back faces culled), and the
lighting is computed here in numpy. Two modes:

* ``"baked"``: Gouraud interpolation of per-vertex sRGB colours, or, for an uncoloured mesh, of its
  grey pre-lit intensities ([LHNW00 §4], [LH01 §5.2]: extremes of intensity occur at vertices), as the
  perceptual model assumes.
* ``"relit"``: what a renderer shows. Each mesh is shaded from its *own* area-weighted vertex normals
  (so a simplification is judged with the normals it really has), per pixel: the interpolated normal is
  renormalised and lit by an :class:`optim.Lighting` (``direction`` towards the light in object space),
  linear intensity ``I = clip(ambient + diffuse * max(0, n . l), 0, 1)`` (``|n . l|`` when
  ``two_sided``), exactly ``Lighting.intensity``; linear RGB = albedo * I with albedo =
  ``srgb_to_linear`` of the interpolated vertex colours (1 for an uncoloured mesh); then sRGB. The
  normals reach numpy through one FLAT pass whose vertex colours are the encoded normals
  ``(n + 1) / 2``, read back as 8 bits (pyrender reads only 8-bit colour): each component is within
  1/255 of the interpolated normal, so ``n . l`` is within 0.007 and a lit pixel within about 1/255 of
  sRGB (2/255 in the darkest lit tones). The pass's alpha is each pixel's MSAA coverage; edge pixels
  are un-premultiplied by it and composited over the background in linear light.

The background is the view's background relative luminance (grey). FLIP [And20] takes the display's
pixels per degree, scaled to the rendering size.

Heavy imports (pyrender, flip_evaluator, matplotlib) happen inside the functions.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from pmetric import PlodError

MODES = ("baked", "relit")


def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """sRGB EOTF (IEC 61966-2-1) in numpy float32: the formula of ``pmetric.srgb_to_linear``."""
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def _linear_to_srgb(u: np.ndarray) -> np.ndarray:
    """Inverse sRGB EOTF in numpy float32: the formula of ``pmetric.linear_to_srgb``."""
    u = np.clip(u, 0.0, 1.0)
    return np.where(u <= 0.0031308, 12.92 * u, 1.055 * np.power(u, 1 / 2.4) - 0.055).astype(np.float32)


def vertex_normals(vertices, faces) -> np.ndarray:
    """(V, 3) float64 unit area-weighted vertex normals of a mesh, from its own faces (zero for a
    vertex on no face, or whose faces cancel)."""
    from optim._normal_cube import _unit
    from optim._tree import _vertex_normals

    return _unit(_vertex_normals(np.asarray(vertices, dtype=np.float64), np.asarray(faces)))


def _vertex_rgb(vertices, faces, colors, lighting) -> np.ndarray:
    """(V, 3) float32 sRGB in [0, 1]: the colours when given, else grey pre-lit intensities."""
    if colors is not None:
        return np.clip(np.asarray(colors, dtype=np.float32), 0.0, 1.0)
    import optim

    lum = optim.vertex_luminance(vertices, faces, None, lighting)  # relative linear luminance
    grey = _linear_to_srgb(np.asarray(lum, dtype=np.float32))
    return np.repeat(grey[:, None], 3, axis=1)


def _rasterise(v, f, passes, view, w, h) -> list[np.ndarray]:
    """Draw ``v``, ``f`` once per entry of ``passes`` ((V, 4) uint8 vertex RGBA) for ``view`` at
    ``w`` x ``h`` pixels, unlit (FLAT), back faces culled, on a transparent black background; returns
    (H, W, 4) uint8 images (alpha: coverage of the 4x MSAA samples)."""
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    import pyrender

    fwd = view.target - view.eye
    dist = float(np.linalg.norm(fwd))
    # Camera pose: columns are the camera's x (right), y (up) and z (backwards) axes in world space.
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = view.rotation.T, view.eye
    extent = float(np.linalg.norm(v.max(0) - v.min(0))) if len(v) else 1.0
    cam = pyrender.PerspectiveCamera(yfov=np.radians(view.fov_deg), aspectRatio=w / h,
                                     znear=max(view.near, 1e-3 * dist), zfar=dist + 4 * extent + 1.0)
    # Opaque, single-sided: GL_CULL_FACE with GL_BACK (counter-clockwise faces are front faces).
    material = pyrender.MetallicRoughnessMaterial(baseColorFactor=[1.0, 1.0, 1.0, 1.0], alphaMode="OPAQUE",
                                                  doubleSided=False)
    try:
        renderer = pyrender.OffscreenRenderer(int(w), int(h))
    except Exception as exc:  # pyrender raises several kinds when no GL context exists
        raise RuntimeError(
            f"render: cannot create an offscreen OpenGL context ({exc}); install Mesa's EGL "
            "(Debian: libegl1 libegl-mesa0 libgl1-mesa-dri libopengl0) and set PYOPENGL_PLATFORM=egl") from exc
    out = []
    try:
        for rgba in passes:
            scene = pyrender.Scene(bg_color=[0.0, 0.0, 0.0, 0.0], ambient_light=[1.0, 1.0, 1.0])
            if len(f):
                prim = pyrender.Primitive(positions=v.astype(np.float32), color_0=rgba, indices=f,
                                          material=material, mode=pyrender.constants.GLTF.TRIANGLES)
                scene.add(pyrender.Mesh([prim]))
            scene.add(cam, pose=pose)
            color, _ = renderer.render(scene, flags=pyrender.RenderFlags.FLAT | pyrender.RenderFlags.RGBA)
            out.append(np.asarray(color))
    finally:
        renderer.delete()
    return out


def _u8(x: np.ndarray) -> np.ndarray:
    """Values in [0, 1] (V, 3) -> (V, 4) uint8 RGBA, opaque."""
    rgb = np.clip(np.round(np.asarray(x, dtype=np.float64) * 255.0), 0, 255).astype(np.uint8)
    return np.concatenate([rgb, np.full((len(rgb), 1), 255, np.uint8)], axis=1)


def render(vertices, faces, colors, view, *, lighting=None, mode: str = "baked",
           size: tuple[int, int] | None = None, background: float | None = None, normals=None) -> np.ndarray:
    """Render a mesh for ``view``: returns (H, W, 3) float32 sRGB in [0, 1].

    ``vertices`` (V, 3), ``faces`` (T, 3), ``colors`` (V, 3) sRGB in [0, 1] or None. ``lighting``: an
    ``optim.Lighting`` (or what ``Lighting.coerce`` takes; None: its default). ``mode``: ``"baked"``
    (colours, or intensities pre-lit with ``lighting`` as the vertex tree does, Gouraud-interpolated)
    or ``"relit"`` (per-pixel Lambert shading from the mesh's own vertex normals; see the module
    docstring). ``size`` = (width, height) in pixels (default the view's image size). The camera is
    the view's: eye, target, up and vertical field of view; the background is the view's background
    relative luminance unless given. ``normals`` (V, 3): the vertex normals the relit pass shades from
    (None: the mesh's own, :func:`vertex_normals`), as a mesh file carrying normals gives them (e.g. a cut
    without its back faces, :func:`optim.drop_back_faces`, keeps the full cut's normals). Raises
    ``RuntimeError`` with a hint when no OpenGL context can be created.
    """
    import optim

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise PlodError(f"render: vertices must be (V, 3) and faces (T, 3), got {v.shape} and {f.shape}")
    if mode not in MODES:
        raise PlodError(f"render: mode must be one of {MODES}, got {mode!r}")
    if colors is not None and np.shape(colors) != v.shape:
        raise PlodError(f"render: colors must be (V, 3) like the vertices, got {np.shape(colors)}")
    w, h = size if size is not None else (view.width, view.height)
    if int(w) <= 0 or int(h) <= 0:
        raise PlodError(f"render: size must be two positive integers, got {size!r}")
    w, h = int(w), int(h)
    bg_lin = np.float32(view.background if background is None else float(background))
    light = optim.Lighting.coerce(lighting)
    if mode == "baked":
        (img,) = _rasterise(v, f, [_u8(_vertex_rgb(v, f, colors, light))], view, w, h)
        alpha = img[..., 3:4].astype(np.float32) / 255.0
        # GL's resolve averaged the sRGB-encoded samples: composite the same way (background sRGB).
        return img[..., :3].astype(np.float32) / 255.0 + (1.0 - alpha) * _linear_to_srgb(bg_lin)
    if normals is None:
        nrm = vertex_normals(v, f)
    else:
        nrm = np.asarray(normals, dtype=np.float64)
        if nrm.shape != v.shape or not np.isfinite(nrm).all():
            raise PlodError(f"render: normals must be (V, 3) finite like the vertices, got {nrm.shape}")
    passes = [_u8(0.5 * (nrm + 1.0))]
    if colors is not None:
        passes.append(_u8(np.clip(np.asarray(colors, dtype=np.float32), 0.0, 1.0)))
    imgs = _rasterise(v, f, passes, view, w, h)
    alpha = imgs[0][..., 3].astype(np.float32) / 255.0
    cov = alpha > 0
    a = alpha[cov][:, None]
    n = (imgs[0][..., :3][cov].astype(np.float64) / 255.0) / a * 2.0 - 1.0  # un-premultiply, decode
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    shade = light.intensity(n)[:, None]  # (K, 1) linear, Lighting's own formula
    if colors is not None:
        shade = shade * _srgb_to_linear(np.clip(imgs[1][..., :3][cov].astype(np.float32) / 255.0 / a, 0.0, 1.0))
    lin = np.full((h, w, 3), bg_lin, dtype=np.float32)
    lin[cov] = a * shade + (1.0 - a) * bg_lin  # coverage blends shade and background in linear light
    return _linear_to_srgb(lin)


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


def mesh_parts(mesh, who: str = "mesh") -> tuple:
    """``(vertices, faces, colors, normals or None)`` of a mesh given as ``(vertices, faces, colors or
    None)`` or with vertex normals (V, 3) as a fourth element; PlodError naming ``who`` otherwise."""
    try:
        v, f, c, nrm = (*mesh, None) if len(mesh) == 3 else mesh
    except (TypeError, ValueError):
        raise PlodError(f"{who} must be (vertices, faces, colors or None[, normals])") from None
    return v, f, c, nrm


def compare(tree, simplified, view, *, size: tuple[int, int] | None = None, mode: str = "baked",
            lighting=None) -> Comparison:
    """Render ``tree``'s full mesh and ``simplified`` = (vertices, faces, colors[, normals]) for ``view``;
    FLIP them.

    ``size`` (width, height) renders smaller than the view's image; the pixels per degree passed to FLIP
    is scaled so the comparison is of the same angular content. ``mode``: see :func:`render`;
    ``lighting``: an ``optim.Lighting`` (default: the tree's pre-lighting).
    """
    w, h = size if size is not None else (view.width, view.height)
    ppd = float(view.display.pixels_per_degree()) * (w / view.width)
    if lighting is None:
        lighting = getattr(tree, "lighting", None)
    original = render(tree.vertices, tree.faces, tree.colors, view, lighting=lighting, mode=mode, size=(w, h))
    v2, f2, c2, n2 = mesh_parts(simplified, "compare: simplified")
    simple = render(v2, f2, c2, view, lighting=lighting, mode=mode, size=(w, h), normals=n2)
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

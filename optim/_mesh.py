"""Mesh input and output: load, validate, save, and procedural test meshes.

Stages: ``load_mesh`` (any format trimesh reads) -> ``validate_mesh`` (the bad-input policy) ->
hierarchy (``optim._tree``). ``save_mesh`` writes atomically and never over an input file.

Units: vertex positions are in object units (whatever the file uses); colours are sRGB in [0, 1].

Bad-input policy of :func:`validate_mesh` (the single place it is decided):

* errors (``ValueError`` naming the problem): faces not of shape (T, 3) (non-triangles), non-integer
  faces, vertices not (V, 3), NaN or infinite coordinates, negative or out-of-range indices, an empty
  mesh (no vertices or no faces, or no face left after cleaning), colours of the wrong shape / NaN.
* documented handling, counted in the returned :class:`MeshReport`:
  - *degenerate* triangles (a corner index repeated) are dropped: they cover no area and no vertex
    hierarchy can give them an owner;
  - *duplicate* triangles (the same three vertex indices in any order or orientation) are dropped,
    keeping the first;
  - *unreferenced* vertices are dropped and the faces renumbered (order of the rest kept);
  - *zero-area* triangles with three distinct indices are kept (they render as nothing) and counted;
  - *non-manifold* meshes are allowed: edges shared by more than two triangles are only counted.
    The vertex hierarchy works on any triangle soup.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np

__all__ = [
    "MeshReport",
    "face_normals",
    "load_mesh",
    "validate_mesh",
    "save_mesh",
    "icosphere",
    "grid_mesh",
    "bumpy_sphere",
]


@dataclasses.dataclass(frozen=True)
class MeshReport:
    """What :func:`validate_mesh` changed or noticed (counts)."""

    vertices_in: int
    faces_in: int
    dropped_degenerate: int = 0
    dropped_duplicate: int = 0
    dropped_unreferenced_vertices: int = 0
    zero_area: int = 0
    nonmanifold_edges: int = 0  # -1: not counted

    @property
    def changed(self) -> bool:
        return bool(self.dropped_degenerate or self.dropped_duplicate or self.dropped_unreferenced_vertices)

    def summary(self) -> str:
        parts = []
        if self.dropped_degenerate:
            parts.append(f"dropped {self.dropped_degenerate} degenerate triangles (repeated corner)")
        if self.dropped_duplicate:
            parts.append(f"dropped {self.dropped_duplicate} duplicate triangles")
        if self.dropped_unreferenced_vertices:
            parts.append(f"dropped {self.dropped_unreferenced_vertices} unreferenced vertices")
        if self.zero_area:
            parts.append(f"kept {self.zero_area} zero-area triangles")
        if self.nonmanifold_edges > 0:
            parts.append(f"{self.nonmanifold_edges} non-manifold edges (allowed)")
        return "; ".join(parts) if parts else "clean"


# ----------------------------------------------------------------------------------------------
# validation


def face_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Unnormalised face normals (T, 3) float64: cross(v1 - v0, v2 - v0), length = 2 x area (object units^2)."""
    p = np.asarray(v, dtype=np.float64).take(np.asarray(f), axis=0)  # (T, 3, 3)
    a = p[:, 1] - p[:, 0]
    b = p[:, 2] - p[:, 0]
    out = np.empty_like(a)
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def validate_mesh(vertices, faces, colors=None, *, name: str = "mesh", count_nonmanifold: bool = True,
                  _normals: bool = False):
    """Check and clean a triangle mesh (the project's bad-input policy, see the module docstring).

    Args:
        vertices: (V, 3) real array, object units.
        faces: (T, 3) integer array of vertex indices.
        colors: optional (V, 3) or (V, 4) sRGB colours, floats in [0, 1] or uint8 (alpha dropped).
        name: how errors name the mesh (e.g. the file name).
        count_nonmanifold: count edges shared by more than two triangles (a sort of all edges;
            ``build_tree`` skips it and reports -1).

    Returns:
        ``(vertices (V', 3) float64, faces (T', 3) int32, colors (V', 3) float32 or None, report)``.

    Raises:
        ValueError: naming the problem, for shapes, NaN/inf, out-of-range indices and empty meshes.
    """
    v = np.asarray(vertices)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"{name}: vertices must have shape (V, 3), got {v.shape}")
    if not (np.issubdtype(v.dtype, np.floating) or np.issubdtype(v.dtype, np.integer)):
        raise ValueError(f"{name}: vertices must be real numbers, got dtype {v.dtype}")
    if f.ndim != 2 or f.shape[1] != 3:
        if f.ndim == 2 and f.shape[0] > 0:
            raise ValueError(f"{name}: faces must be triangles, shape (T, 3); got {f.shape[1]} corners per face")
        if f.size == 0:
            raise ValueError(f"{name}: empty mesh (no faces)")
        raise ValueError(f"{name}: faces must have shape (T, 3), got {f.shape}")
    if v.shape[0] == 0:
        raise ValueError(f"{name}: empty mesh (no vertices)")
    if f.shape[0] == 0:
        raise ValueError(f"{name}: empty mesh (no faces)")
    if not np.issubdtype(f.dtype, np.integer):
        if np.issubdtype(f.dtype, np.floating) and np.all(np.isfinite(f)) and np.all(f == np.round(f)):
            f = f.astype(np.int64)
        else:
            raise ValueError(f"{name}: face indices must be integers, got dtype {f.dtype}")
    v = v.astype(np.float64, copy=False)
    bad = ~np.isfinite(v)
    if bad.any():
        rows = np.flatnonzero(bad.any(axis=1))
        raise ValueError(
            f"{name}: {rows.size} vertices have NaN or infinite coordinates (first: vertex {int(rows[0])})"
        )
    nv = v.shape[0]
    lo, hi = int(f.min()), int(f.max())
    if lo < 0 or hi >= nv:
        bad_f = np.flatnonzero(((f < 0) | (f >= nv)).any(axis=1))
        raise ValueError(
            f"{name}: face indices out of range [0, {nv}) (min {lo}, max {hi}; {bad_f.size} faces, "
            f"first: face {int(bad_f[0])})"
        )
    f = f.astype(np.int64, copy=False)

    c = None
    if colors is not None:
        c = np.asarray(colors)
        if c.ndim != 2 or c.shape[0] != nv or c.shape[1] not in (3, 4):
            raise ValueError(f"{name}: colors must have shape (V, 3) or (V, 4) with V = {nv}, got {c.shape}")
        c = c[:, :3]
        if np.issubdtype(c.dtype, np.integer):
            c = c.astype(np.float32) / 255.0
        c = c.astype(np.float32)
        if not np.all(np.isfinite(c)):
            raise ValueError(f"{name}: colors contain NaN or infinite values")
        if c.min() < 0.0 or c.max() > 1.0:
            raise ValueError(f"{name}: float colors must lie in [0, 1] (got {c.min():g}..{c.max():g})")

    n_in = f.shape[0]
    # degenerate: a repeated corner index
    degen = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    f = f[~degen]
    # duplicate: same vertex set (any order / orientation); keep the first occurrence
    n_dup = 0
    if f.shape[0] > 1:
        lo_, hi_ = f.min(axis=1), f.max(axis=1)
        mid = f.sum(axis=1) - lo_ - hi_
        if nv < (1 << 21):
            _, first = np.unique((lo_ << 42) | (mid << 21) | hi_, return_index=True)
        else:
            _, first = np.unique(np.stack([lo_, mid, hi_], 1), axis=0, return_index=True)
        if first.size < f.shape[0]:
            n_dup = f.shape[0] - first.size
            f = f[np.sort(first)]
    if f.shape[0] == 0:
        raise ValueError(f"{name}: empty mesh (no non-degenerate faces)")
    # unreferenced vertices
    used = np.zeros(nv, dtype=bool)
    used[f.ravel()] = True
    n_unref = int(nv - used.sum())
    if n_unref:
        remap = np.cumsum(used) - 1
        f = remap[f]
        v = v[used]
        if c is not None:
            c = c[used]
    # zero-area (kept) and non-manifold edges (counted)
    cr = face_normals(v, f)
    zero_area = int(np.count_nonzero(np.einsum("ij,ij->i", cr, cr) == 0.0))
    nonmanifold = -1
    if count_nonmanifold:
        a_, b_ = np.concatenate([f[:, 0], f[:, 1], f[:, 2]]), np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
        ek = np.minimum(a_, b_) * v.shape[0] + np.maximum(a_, b_)
        _, counts = np.unique(ek, return_counts=True)
        nonmanifold = int(np.count_nonzero(counts > 2))

    report = MeshReport(
        vertices_in=nv,
        faces_in=n_in,
        dropped_degenerate=int(degen.sum()),
        dropped_duplicate=int(n_dup),
        dropped_unreferenced_vertices=n_unref,
        zero_area=zero_area,
        nonmanifold_edges=nonmanifold,
    )
    out = np.ascontiguousarray(v), np.ascontiguousarray(f.astype(np.int32)), c, report
    return (*out, cr) if _normals else out


# ----------------------------------------------------------------------------------------------
# files


def load_mesh(path: str | os.PathLike):
    """Read a triangle mesh (PLY, OBJ, OFF, STL, GLB/GLTF, ... via trimesh).

    A scene (several meshes) is concatenated into one mesh. Polygons are triangulated by trimesh.
    Vertex colours are kept when the file has them (face colours are ignored). The mesh is *not*
    cleaned here; pass it through :func:`validate_mesh` (``build_tree`` does).

    Returns:
        ``(vertices (V, 3) float64, faces (T, 3) int32, colors (V, 3) float32 in [0, 1] or None)``.

    Raises:
        FileNotFoundError: the file does not exist.
        ValueError: naming the file, when it cannot be read, is empty, has no triangles or has NaN.
    """
    import trimesh

    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"mesh file not found: {str(p)!r}")
    if p.is_dir():
        raise ValueError(f"{str(p)!r} is a directory, not a mesh file")
    try:
        obj = trimesh.load(str(p), process=False)
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise ValueError(f"cannot read mesh file {str(p)!r}: {type(exc).__name__}: {exc}") from None
    if isinstance(obj, trimesh.Scene):
        geoms = [g for g in obj.dump() if isinstance(g, trimesh.Trimesh)] if obj.geometry else []
        if not geoms:
            raise ValueError(f"mesh file {str(p)!r} contains no triangle mesh")
        if len(geoms) == 1:
            obj = geoms[0]
        else:
            obj = trimesh.util.concatenate(geoms)
    if not isinstance(obj, trimesh.Trimesh):
        raise ValueError(f"mesh file {str(p)!r} contains no triangles (got a {type(obj).__name__})")
    vertices = np.asarray(obj.vertices, dtype=np.float64)
    faces = np.asarray(obj.faces)
    if vertices.shape[0] == 0 or faces.size == 0:
        raise ValueError(f"mesh file {str(p)!r} is empty (no vertices or no triangles)")
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"mesh file {str(p)!r} has non-triangle faces of shape {faces.shape}")
    if not np.all(np.isfinite(vertices)):
        raise ValueError(f"mesh file {str(p)!r} has NaN or infinite vertex coordinates")
    colors = None
    try:
        if obj.visual.kind == "vertex":
            vc = np.asarray(obj.visual.vertex_colors)
            if vc.shape[0] == vertices.shape[0]:
                colors = (vc[:, :3].astype(np.float32) / 255.0).astype(np.float32)
    except Exception:  # visuals that cannot give vertex colours: treat as uncoloured
        colors = None
    return vertices, faces.astype(np.int32), colors


def save_mesh(path, vertices, faces, colors=None, *, protect=()):
    """Write a triangle mesh atomically (format from the suffix: .ply, .obj, .off, .stl, .glb).

    ``protect`` lists input files that must never be overwritten (``ValueError`` before writing).
    Colours (V, 3) in [0, 1] are written as 8-bit vertex colours where the format supports them.
    Returns the final path.
    """
    import trimesh

    from pmetric import atomic_path

    p = Path(path)
    fmt = p.suffix.lower().lstrip(".")
    if fmt not in ("ply", "obj", "off", "stl", "glb"):
        raise ValueError(f"cannot write mesh format {p.suffix!r} for {str(p)!r}; use .ply, .obj, .off, .stl or .glb")
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or (f.size and f.shape[1] != 3):
        raise ValueError(f"save_mesh: need vertices (V, 3) and faces (T, 3); got {v.shape} and {f.shape}")
    kw = {}
    if colors is not None:
        c = np.asarray(colors, dtype=np.float64)
        if c.shape != v.shape:
            raise ValueError(f"save_mesh: colors must have shape {v.shape}, got {c.shape}")
        kw["vertex_colors"] = np.clip(np.round(c * 255.0), 0, 255).astype(np.uint8)
    mesh = trimesh.Trimesh(vertices=v, faces=f.reshape(-1, 3), process=False, **kw)
    data = mesh.export(file_type=fmt)
    if isinstance(data, str):
        data = data.encode("utf-8")
    with atomic_path(p, protect=tuple(protect)) as tmp:
        tmp.write_bytes(data)
    return p


# ----------------------------------------------------------------------------------------------
# procedural meshes (no ../shared needed)


def icosphere(subdivisions: int = 3, radius: float = 1.0):
    """Unit icosphere: 20 * 4**subdivisions triangles, 10 * 4**subdivisions + 2 vertices.

    Returns ``(vertices (V, 3) float64, faces (T, 3) int32)``, outward (counter-clockwise) faces.
    """
    n = int(subdivisions)
    if n < 0 or n > 10:
        raise ValueError(f"icosphere: subdivisions must be in 0..10, got {subdivisions}")
    t = (1.0 + 5.0**0.5) / 2.0
    v = np.array(
        [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
         [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]],
        dtype=np.float64,
    )
    f = np.array(
        [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
         [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
         [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]],
        dtype=np.int64,
    )
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    for _ in range(n):
        edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        uniq, inv = np.unique(edges[:, 0] * v.shape[0] + edges[:, 1], return_inverse=True)
        a, b = uniq // v.shape[0], uniq % v.shape[0]
        mid = v[a] + v[b]
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        m = inv.reshape(3, -1).T + v.shape[0]  # midpoints of edges 01, 12, 20
        v = np.concatenate([v, mid])
        f = np.concatenate(
            [np.stack([f[:, 0], m[:, 0], m[:, 2]], 1), np.stack([f[:, 1], m[:, 1], m[:, 0]], 1),
             np.stack([f[:, 2], m[:, 2], m[:, 1]], 1), m]
        )
    return v * float(radius), f.astype(np.int32)


def grid_mesh(nx: int, ny: int, size: tuple[float, float] = (1.0, 1.0)):
    """A flat (nx x ny)-cell grid in the z = 0 plane: (nx+1)(ny+1) vertices, 2 nx ny triangles.

    Returns ``(vertices (V, 3) float64, faces (T, 3) int32)``; faces face +z.
    """
    nx, ny = int(nx), int(ny)
    if nx < 1 or ny < 1:
        raise ValueError(f"grid_mesh: nx and ny must be >= 1, got {nx}, {ny}")
    xs = np.linspace(0.0, size[0], nx + 1)
    ys = np.linspace(0.0, size[1], ny + 1)
    X, Y = np.meshgrid(xs, ys, indexing="xy")  # (ny+1, nx+1)
    v = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], axis=1)
    i = np.arange(ny)[:, None] * (nx + 1) + np.arange(nx)[None, :]
    i = i.ravel()
    a, b, c, d = i, i + 1, i + nx + 1, i + nx + 2
    f = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    return v, f.astype(np.int32)


def bumpy_sphere(subdivisions: int = 5, seed: int = 0, *, colors: bool = False, amplitude: float = 0.08):
    """An icosphere displaced by a random smooth bump field (deterministic for a seed).

    ``subdivisions`` = 8 gives 1,310,720 triangles (>= 1 M); 5 gives 20,480. With ``colors=True``
    vertex colours (sRGB, [0, 1]) vary with the bump height and position.

    Returns ``(vertices, faces)`` or ``(vertices, faces, colors)`` with colours (V, 3) float32.
    """
    v, f = icosphere(subdivisions)
    rng = np.random.default_rng(seed)
    k = 24
    dirs = rng.normal(size=(k, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    freq = rng.uniform(2.0, 9.0, size=k)
    phase = rng.uniform(0.0, 2 * np.pi, size=k)
    h = np.zeros(v.shape[0])
    for d, fr, ph in zip(dirs, freq, phase):
        h += np.sin(fr * (v @ d) + ph) / fr
    h /= np.abs(h).max()
    v = v * (1.0 + amplitude * h)[:, None]
    if not colors:
        return v, f
    t = 0.5 + 0.5 * h
    c = np.stack([0.25 + 0.7 * t, 0.35 + 0.4 * np.abs(v[:, 1]) / np.abs(v[:, 1]).max(), 0.9 - 0.6 * t], axis=1)
    return v, f, np.clip(c, 0.0, 1.0).astype(np.float32)


def bumpy_torus(nu: int = 1000, nv: int = 500, seed: int = 0, *, radii: tuple[float, float] = (1.0, 0.4),
                amplitude: float = 0.08, colors: bool = False):
    """A closed torus of ``2 nu nv`` triangles displaced along its normals by a random smooth bump field.

    ``nu`` segments around the main ring, ``nv`` around the tube; the default 1000 x 500 gives exactly
    1,000,000 triangles (a >= 1 M procedural mesh between the icosphere's 327,680 and 1,310,720).
    The surface is a closed 2-manifold of genus 1 (V - E + F = 0). ``radii`` = (ring radius, tube
    radius) in object units; ``amplitude`` scales the bumps relative to the tube radius.

    Returns ``(vertices (nu nv, 3) float64, faces (2 nu nv, 3) int32)``, plus colours (V, 3) float32
    sRGB in [0, 1] with ``colors=True``.
    """
    nu, nv = int(nu), int(nv)
    if nu < 3 or nv < 3:
        raise ValueError(f"bumpy_torus: nu and nv must be >= 3, got {nu}, {nv}")
    R, r = (float(x) for x in radii)
    if not (R > r > 0):
        raise ValueError(f"bumpy_torus: radii must satisfy ring > tube > 0, got {radii!r}")
    u = np.linspace(0.0, 2 * np.pi, nu, endpoint=False)
    w = np.linspace(0.0, 2 * np.pi, nv, endpoint=False)
    U, W = np.meshgrid(u, w, indexing="ij")  # (nu, nv)
    rng = np.random.default_rng(seed)
    h = np.zeros_like(U)
    for _ in range(16):
        a, b = rng.integers(1, 12), rng.integers(1, 8)
        h += np.sin(a * U + b * W + rng.uniform(0, 2 * np.pi)) / (a + b)
    h /= np.abs(h).max()
    rt = r * (1.0 + amplitude * h)
    v = np.stack([(R + rt * np.cos(W)) * np.cos(U), (R + rt * np.cos(W)) * np.sin(U), rt * np.sin(W)],
                 axis=-1).reshape(-1, 3)
    i = np.arange(nu)[:, None]
    j = np.arange(nv)[None, :]
    a = i * nv + j
    b = ((i + 1) % nu) * nv + j
    c = ((i + 1) % nu) * nv + (j + 1) % nv
    d = i * nv + (j + 1) % nv
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    faces = faces.astype(np.int32)
    if not colors:
        return v, faces
    t = (0.5 + 0.5 * h).ravel()
    col = np.stack([0.3 + 0.6 * t, 0.5 + 0.3 * np.cos(U).ravel(), 0.85 - 0.6 * t], axis=1)
    return v, faces, np.clip(col, 0.0, 1.0).astype(np.float32)

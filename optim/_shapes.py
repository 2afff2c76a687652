"""Procedural test meshes (no ``../shared`` needed): icosphere, grid, bumpy sphere and torus.

Each returns ``(vertices (V, 3) float64, faces (T, 3) int32[, colors (V, 3) float32 sRGB in [0, 1]])``
in object units, outward (counter-clockwise) faces.
"""

from __future__ import annotations

import numpy as np

from pmetric import PlodError

__all__ = ["icosphere", "grid_mesh", "bumpy_sphere", "bumpy_torus"]



def icosphere(subdivisions: int = 3, radius: float = 1.0):
    """Unit icosphere: 20 * 4**subdivisions triangles, 10 * 4**subdivisions + 2 vertices.

    Returns ``(vertices (V, 3) float64, faces (T, 3) int32)``, outward (counter-clockwise) faces.
    """
    n = int(subdivisions)
    if n < 0 or n > 10:
        raise PlodError(f"icosphere: subdivisions must be in 0..10, got {subdivisions}")
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
        raise PlodError(f"grid_mesh: nx and ny must be >= 1, got {nx}, {ny}")
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
        raise PlodError(f"bumpy_torus: nu and nv must be >= 3, got {nu}, {nv}")
    R, r = (float(x) for x in radii)
    if not (R > r > 0):
        raise PlodError(f"bumpy_torus: radii must satisfy ring > tube > 0, got {radii!r}")
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

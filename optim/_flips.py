"""Triangle flips of an extracted cut: output triangles facing against the input triangle they come from.

:func:`optim.extract` keeps the triangles of a cut in input order, each an input triangle whose corners
are replaced by their representatives (the highest folded node above each corner, at its proxy
position). Folding can move a representative across the opposite edge of a triangle, or fold a
cluster across a crease, and the triangle then faces the other way: a visible defect (its shading and
back-face culling invert) that no key measures. :func:`cut_flips` finds them for a cut:

* ``flipped``: non-degenerate output triangles with ``dot(n_out, n_in) < 0``, ``n_in`` the normal of
  the input triangle and ``n_out`` that of the output triangle (both unnormalised cross products);
* ``degenerate``: output triangles of (numerically) zero area, whose normal is undefined, counted
  separately: twice their area is at most ``degenerate_tol`` times their longest edge squared (an
  angle below about ``degenerate_tol`` radians; proxies are float32, resolving about 1e-7).

Work is one :func:`optim.extract` (the same index machinery, :func:`optim._cut._extract_parts`) plus
two cross products per output triangle.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from pmetric import PlodError

from ._cut import _extract_parts, _unfolded_mask

__all__ = ["Flips", "cut_flips"]


@dataclasses.dataclass(frozen=True)
class Flips:
    """Flipped and degenerate triangles of an extracted cut (see :func:`cut_flips`).

    Attributes:
        flipped: number of output triangles whose normal points against their input triangle's.
        indices: (flipped,) int64 indices of those triangles into the faces :func:`optim.extract`
            returns for the same cut (ascending).
        sources: (flipped,) int64 the input triangles (rows of ``tree.faces``) they come from.
        area_fraction: area of the flipped output triangles over the area of all output triangles
            (0.0 for an empty or zero-area output).
        degenerate: number of zero-area output triangles (not counted in ``flipped``).
        degenerate_indices: (degenerate,) int64 indices of those into extract's faces.
        triangles: number of output triangles (``len(faces)`` of :func:`optim.extract`).
    """

    flipped: int
    indices: np.ndarray
    sources: np.ndarray
    area_fraction: float
    degenerate: int
    degenerate_indices: np.ndarray
    triangles: int

    @property
    def fraction(self) -> float:
        """``flipped / triangles`` (0.0 for an empty output)."""
        return self.flipped / self.triangles if self.triangles else 0.0


def _normals(v: np.ndarray, f: np.ndarray):
    """Unnormalised normals (K, 3) of the triangles ``f`` (K, 3) over ``v`` (float64), and their edges'
    squared lengths (3, K)."""
    a, b, c = (v.take(f[:, k], axis=0) for k in range(3))
    e1, e2, e3 = b - a, c - a, c - b
    n = np.cross(e1, e2)
    return n, np.stack([np.einsum("ij,ij->i", e, e) for e in (e1, e2, e3)])


def cut_flips(tree, cut, *, degenerate_tol: float = 1e-6) -> Flips:
    """Output triangles of ``extract(tree, cut)`` that face against the input triangle they come from.

    Args:
        tree: :class:`optim.VertexTree`.
        cut: a :class:`optim.Cut` or an (N,) bool ``unfolded`` array, as :func:`optim.extract` takes.
        degenerate_tol: an output triangle is degenerate (zero area, not tested for a flip) when
            ``|n_out| <= degenerate_tol * (longest edge)^2``; a finite number >= 0 (0: exactly zero area).

    Returns:
        :class:`Flips`; its indices refer to the faces of ``extract(tree, cut)``.
    """
    ok = isinstance(degenerate_tol, (int, float, np.integer, np.floating)) and not isinstance(degenerate_tol, bool)
    tol = float(degenerate_tol) if ok else float("nan")
    if not np.isfinite(tol) or tol < 0:
        raise PlodError(f"cut_flips: degenerate_tol must be a finite number >= 0, got {degenerate_tol!r}")
    unf = _unfolded_mask(tree, cut, "cut_flips")
    verts, faces, _, keep = _extract_parts(tree, unf)[:4]
    T = int(faces.shape[0])
    if T == 0:
        empty = np.zeros(0, dtype=np.int64)
        return Flips(0, empty, empty, 0.0, 0, empty, 0)
    n_out, edges = _normals(np.asarray(verts, dtype=np.float64), faces)
    n_in, _ = _normals(np.asarray(tree.vertices, dtype=np.float64), tree.faces.take(keep, axis=0))
    dbl = np.sqrt(np.einsum("ij,ij->i", n_out, n_out))  # twice the output area
    degen = dbl <= tol * edges.max(axis=0)
    flip = ~degen & (np.einsum("ij,ij->i", n_out, n_in) < 0)
    total = float(dbl.sum())
    frac = float(dbl[flip].sum()) / total if total > 0 else 0.0
    idx = np.flatnonzero(flip).astype(np.int64)
    didx = np.flatnonzero(degen).astype(np.int64)
    return Flips(int(idx.size), idx, keep.take(idx).astype(np.int64), frac, int(didx.size), didx, T)

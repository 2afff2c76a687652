"""The peers plod is compared with: view-independent simplifiers run to a triangle count.

* :func:`meshopt_simplify`: meshoptimizer's ``simplify`` (its error bound lifted so the count decides),
  ``simplify_with_attributes`` on the vertex colours when the mesh has them;
* :func:`fast_simplify`: fast-simplification's quadric decimation;
* :func:`compact`: drop the vertices a simplified face list no longer uses.

Both simplifiers take ``vertices`` (V, 3) in object units and ``faces`` (T, 3) and return the new faces
(meshoptimizer keeps the input vertices; fast-simplification returns ``(vertices, faces)``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["compact", "fast_simplify", "meshopt_simplify", "nearest_colors"]


def compact(vertices, faces, colors=None):
    """``(vertices, faces int32, colors)`` with only the vertices ``faces`` uses, renumbered in order."""
    from optim._mesh import compact as compact_mesh

    v, f, c = compact_mesh(vertices, faces, colors)
    return v, np.asarray(f).reshape(-1, 3).astype(np.int32), c


def meshopt_simplify(vertices, faces, target, colors=None):
    """meshoptimizer's simplify to ``target`` triangles: faces (T', 3) int64 into ``vertices``. With
    ``colors`` (V, 3) its ``simplify_with_attributes`` keeps colour edges too (weight
    ``optim._meshopt_tree.COLOR_WEIGHT``; the call with its ctypes argument types declared lives there,
    beside the hierarchy built from it)."""
    from optim._meshopt_tree import meshopt_simplify as simplify

    return simplify(vertices, faces, target, colors)


def fast_simplify(vertices, faces, target):
    """fast-simplification's decimation to ``target`` triangles: ``(vertices, faces)``."""
    import fast_simplification

    # writable C-ordered copies: the binding rejects read-only arrays (a tree's vertices are read-only)
    return fast_simplification.simplify(np.array(vertices, dtype=np.float64, order="C"),
                                        np.array(faces, dtype=np.int64, order="C"),
                                        target_count=max(int(target), 1))


def nearest_colors(vertices, colors, points):
    """The colour (K, 3) of the input vertex nearest each of ``points`` (K, 3), or None without colours:
    fast-simplification moves vertices and drops their colours."""
    if colors is None:
        return None
    from scipy.spatial import cKDTree

    return np.asarray(colors)[cKDTree(vertices).query(points)[1]]

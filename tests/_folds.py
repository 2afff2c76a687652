"""Slow per-node references of what a fold touches, shared by the scoring and relighting tests."""

import numpy as np


def supported(tree, node):
    """Input vertices (K,) the node supports."""
    return tree.leaf_vertex[tree.leaf_lo[node]:tree.leaf_hi[node]]


def incident_faces(tree, verts):
    """Indices of the faces with a corner among ``verts``."""
    on = np.zeros(tree.n_vertices, bool)
    on[verts] = True
    return np.flatnonzero(on[tree.faces].any(1))


def left_faces(tree, node, corners=False):
    """Normals (K, 3) (length 2 x area) of the faces a fold of ``node`` alone leaves: a corner inside
    the node and one outside, the inside corners moved to its proxy (and those corners (K, 3, 3)
    with ``corners``)."""
    inside = np.zeros(tree.n_vertices, bool)
    inside[supported(tree, node)] = True
    f = tree.faces
    cnt = inside[f].sum(1)
    faces = f[(cnt > 0) & (cnt < 3)]
    p = np.where(inside[faces][:, :, None], tree.position[node].astype(np.float64), tree.vertices[faces])
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return (n, p) if corners else n

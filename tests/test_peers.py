"""The view-independent peers (experiments/peers.py) run to a triangle count, and meshoptimizer's
attribute-aware simplification (its binding needs its argument types declared) keeps colour edges."""

from __future__ import annotations

import numpy as np

import optim
from experiments.peers import compact, fast_simplify, meshopt_simplify


def _step_coloured_sphere():
    v, f = optim.icosphere(4)
    c = np.where((v[:, 0] > 0.05)[:, None], [[1.0, 0.1, 0.1]], [[0.1, 0.1, 1.0]]).astype(np.float32)
    return v, f, c


def test_peers_reach_the_triangle_count():
    v, f, c = _step_coloured_sphere()
    for faces in (meshopt_simplify(v, f, 500), meshopt_simplify(v, f, 500, c)):
        assert 450 <= len(faces) <= 500 and faces.max() < len(v)
    pv, pf = fast_simplify(v, f, 500)
    assert abs(len(pf) - 500) <= 10
    cv, cf, cc = compact(v, meshopt_simplify(v, f, 500), c)
    assert cf.max() == len(cv) - 1 and len(cc) == len(cv)


def test_attribute_simplification_keeps_the_colour_edge():
    v, f, c = _step_coloured_sphere()
    near_edge = np.abs(v[:, 0] - 0.05) < 0.08

    def edge_share(faces):
        used = np.unique(faces)
        return near_edge[used].mean()

    plain = edge_share(meshopt_simplify(v, f, 400))
    with_colour = edge_share(meshopt_simplify(v, f, 400, c))
    assert with_colour > plain + 0.05

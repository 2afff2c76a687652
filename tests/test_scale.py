"""Scale invariance: the same mesh in other units (x1e-6 .. x1e6) gives the same vertex tree and,
framed the same way, the same perceptual keys and cuts (issue: QEM order depended on the units)."""

from __future__ import annotations

import numpy as np
import pytest

import optim

#: powers of two scale float coordinates exactly: the trees must be identical
EXACT = (2.0 ** -20, 2.0 ** -10, 1.0, 2.0 ** 10, 2.0 ** 20)
#: decimal units round the float32 coordinates meshoptimizer reads (greedy collapse orders then differ
#: slightly): the cuts must agree
DECIMAL = (1e-6, 1e-3, 1e3, 1e6)


@pytest.fixture(scope="module")
def mesh():
    return optim.bumpy_sphere(3, seed=2, amplitude=0.12)


def _run(v, f, s, method):
    tree = optim.build_tree(v * s, f, method=method)
    view = optim.View.framing(tree.vertices, 30.0, direction=(0.3, 0.4, 0.8), lighting=optim.Lighting())
    keys = optim.score(tree, view)
    return tree, keys, optim.imperceptible_cut(tree, view), optim.budget_cut(tree, keys, 200)


@pytest.mark.parametrize("method", ["meshopt", "qem"])
def test_tree_and_keys_do_not_depend_on_units(mesh, method):
    v, f = mesh
    tree0, keys0, imp0, bud0 = _run(v, f, 1.0, method)
    for s in EXACT:
        tree, keys, imp, bud = _run(v, f, s, method)
        np.testing.assert_array_equal(tree.parent, tree0.parent, err_msg=f"tree at scale {s:g}")
        np.testing.assert_allclose(keys, keys0, rtol=2e-3, atol=1e-4, err_msg=f"keys at scale {s:g}")
        assert imp.triangles == imp0.triangles and np.array_equal(bud.unfolded, bud0.unfolded)
    for s in DECIMAL:
        tree, keys, imp, bud = _run(v, f, s, method)
        assert abs(imp.triangles - imp0.triangles) <= 0.03 * imp0.triangles, f"imperceptible cut at {s:g}"
        assert abs(np.median(keys[tree.internal]) / np.median(keys0[tree0.internal]) - 1) < 0.05
        assert bud.triangles <= 200 and abs(bud.triangles - bud0.triangles) <= 4

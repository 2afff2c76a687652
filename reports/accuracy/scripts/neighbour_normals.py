"""Issue 10: relit contrast from the change a fold makes to its neighbours' vertex normals (landed in
``optim._relight``: ``neighbour_normals``, ``_neighbour_shading``). The scripts here compare today's
relit columns with the columns before it (the node's own normal cone only), which this module rebuilds:
``cone_only_columns`` / ``cone_only_tree``.

Folding a node moves its supported vertices to the proxy. A renderer shades the faces around each
neighbour ``u`` (a vertex outside the node sharing a face with it) from ``u``'s area-weighted normal,
which sums the normals of ``u``'s faces; the faces ``u`` shares with the node change, so ``u``'s normal
changes (exactly: the sum of the new minus the old face normals). A flat panel folded beside a ridge
has a zero-width cone (contrast 0 before) but changes the ridge's normals: the cow's 9.78 JOD in the
motion judge. The 2-ring cone (``ring_cone.py``) bounded the *spread* of the neighbours' faces (1.2x
the triangles); this scores the *change* of their normals.
"""
import optim
from optim._relight import light_key, normal_cones
from ring_cone import cone_columns


def cone_only_columns(tree, light):
    """The relit columns without the neighbours' shading (as before it landed)."""
    return cone_columns(tree, light, normal_cones(tree)[1])


def cone_only_tree(v, f, c, light):
    t = optim.build_tree(v, f, c)
    t._derived[f"relight.columns.{light_key(light)}"] = cone_only_columns(t, light)
    return t

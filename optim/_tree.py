"""The vertex tree (VDSlib's data structure; seed 001 section 2, seed 004 section 5) and its builder.

Stages of :func:`build_tree`:

1. ``validate``: the bad-input policy of :func:`optim.validate_mesh` (degenerate, duplicate triangles
   and unreferenced vertices dropped and counted in ``tree.mesh_report``).
2. ``cluster``: a hierarchy over the input vertices, as a parent array (leaves = vertices):
   ``"octree"`` (tight octree, ``optim._octree``) or ``"qem"`` (quadric edge collapses,
   ``optim._qem``; the better hierarchy seed 001 section 6.3 asks for).
3. ``renumber``: top-down breadth-first numbering (root 0, ``parent[i] < i``, contiguous children).
4. ``aggregate``: bottom-up per node: vertex count, bounding box, colour and normal sums, luminance
   range, normal masks (OR), smallest vertex index; then proxies (octree: centroid; qem:
   quadric-optimal point), proxy colour and luminance, bounding spheres and geometric errors (exact
   over the supported vertices), fold contrast ``fold_delta`` (seed 004 section 5.2).
5. ``subtris``: each triangle's owner is the deepest of the three pairwise lowest common ancestors
   of its corners' leaves: exactly the node whose fold removes it (CSR ``subtri_start``/``subtris``).

Units: positions, ``center``, ``radius``, ``geom_error`` in object units; ``lum*`` and
``fold_delta`` are relative linear luminance in [0, 1] (seed 001: "intensity ... luminance output by a
standard computer monitor, normalized to the range [0, 1]").
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import os
from pathlib import Path

import numpy as np

from ._mesh import face_normals, validate_mesh

__all__ = [
    "Lighting",
    "VertexTree",
    "build_tree",
    "load_tree",
    "mesh_hash",
    "vertex_luminance",
    "normal_cells",
    "normal_cell_directions",
]

TREE_FORMAT = "plod-vertex-tree-1"
METHODS = ("qem", "octree")

# ----------------------------------------------------------------------------------------------
# intensity


@dataclasses.dataclass(frozen=True)
class Lighting:
    """Directional plus ambient pre-lighting for meshes without vertex colours (seeds assume pre-lit models).

    Relative luminance of a vertex with unit normal n: ``clip(ambient + diffuse * max(0, n . l), 0, 1)``
    with ``l`` the unit vector towards the light (``two_sided`` uses ``|n . l|``).
    """

    direction: tuple[float, float, float] = (0.4, 0.6, 0.7)
    ambient: float = 0.15
    diffuse: float = 0.85
    two_sided: bool = False

    def __post_init__(self):
        d = np.asarray(self.direction, dtype=np.float64)
        if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
            raise ValueError(f"Lighting: direction must be a finite nonzero 3-vector, got {self.direction!r}")
        for k in ("ambient", "diffuse"):
            x = float(getattr(self, k))
            if not np.isfinite(x) or x < 0:
                raise ValueError(f"Lighting: {k} must be a finite number >= 0, got {x!r}")
        object.__setattr__(self, "direction", tuple(float(x) for x in d))
        object.__setattr__(self, "ambient", float(self.ambient))
        object.__setattr__(self, "diffuse", float(self.diffuse))
        object.__setattr__(self, "two_sided", bool(self.two_sided))

    @classmethod
    def coerce(cls, x) -> "Lighting":
        """None -> default; a Lighting; a dict of fields; or a tuple (direction, ambient, diffuse)."""
        if x is None:
            return cls()
        if isinstance(x, cls):
            return x
        if isinstance(x, dict):
            unknown = set(x) - {f.name for f in dataclasses.fields(cls)}
            if unknown:
                raise ValueError(f"Lighting: unknown fields {sorted(unknown)}")
            return cls(**x)
        if isinstance(x, (tuple, list)) and len(x) in (1, 2, 3, 4):
            return cls(*x)
        raise ValueError(f"lighting must be None, a Lighting, a dict or a tuple; got {type(x).__name__}")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def intensity(self, normals: np.ndarray) -> np.ndarray:
        """Relative luminance (K,) float32 for unit normals (K, 3)."""
        d = np.asarray(self.direction, dtype=np.float64)
        d = d / np.linalg.norm(d)
        ndl = np.asarray(normals, dtype=np.float64) @ d
        ndl = np.abs(ndl) if self.two_sided else np.maximum(ndl, 0.0)
        return np.clip(self.ambient + self.diffuse * ndl, 0.0, 1.0).astype(np.float32)


def _srgb_luminance(rgb: np.ndarray) -> np.ndarray:
    """Relative luminance of sRGB colours (K, 3) in [0, 1]: Rec. 709 weights on linearised sRGB (IEC 61966-2-1).

    Same formula as ``pmetric.srgb_to_linear`` + ``pmetric.relative_luminance`` (numpy, for build speed).
    """
    c = np.asarray(rgb, dtype=np.float64)
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return (lin @ np.array([0.2126, 0.7152, 0.0722])).astype(np.float32)


def _vertex_normals(v: np.ndarray, f: np.ndarray, fn: np.ndarray | None = None) -> np.ndarray:
    """Area-weighted vertex normals (V, 3) float64, not normalised (zero for isolated vertices)."""
    if fn is None:
        fn = face_normals(v, f)  # |fn| = 2 area
    vn = np.zeros((v.shape[0], 3))
    idx = f.T.ravel()
    for a in range(3):
        vn[:, a] = np.bincount(idx, weights=np.tile(fn[:, a], 3), minlength=v.shape[0])
    return vn


def _unit(x: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(x, axis=-1, keepdims=True)
    return np.divide(x, n, out=np.zeros_like(x), where=n > 0)


def vertex_luminance(vertices, faces, colors=None, lighting=None) -> np.ndarray:
    """Relative linear luminance (V,) float32 of each vertex: from colours when given, else pre-lit.

    With colours: relative luminance of linearised sRGB. Without: :class:`Lighting` applied to
    area-weighted vertex normals (seed 001 assumes pre-lit models).
    """
    if colors is not None:
        return _srgb_luminance(colors)
    light = Lighting.coerce(lighting)
    v = np.asarray(vertices, dtype=np.float64)
    return light.intensity(_unit(_vertex_normals(v, np.asarray(faces))))


# ----------------------------------------------------------------------------------------------
# normal cube (seed 001 section 4.3; Zhang & Hoff 1997): 6 faces x 8 x 8 cells = 384 bits = 48 bytes


def normal_cells(normals: np.ndarray) -> np.ndarray:
    """Normal-cube cell (K,) int64 in 0..383 of each normal (K, 3) (need not be unit; zero -> cell of +x).

    Face = 2 * axis + (component < 0) for the dominant axis; the other two components (in axis order)
    divided by |dominant| give (u, v) in [-1, 1], cut into 8 x 8 cells: cell = 64 face + 8 iv + iu.
    Bit ``cell`` of a mask is byte ``cell // 8``, bit ``cell % 8`` (little-endian).
    """
    n = np.asarray(normals, dtype=np.float64)
    x, y, z = n[:, 0], n[:, 1], n[:, 2]
    ax_, ay, az = np.abs(x), np.abs(y), np.abs(z)
    axis = np.where((ax_ >= ay) & (ax_ >= az), 0, np.where(ay >= az, 1, 2))  # first maximum, as argmax
    dom = np.where(axis == 0, x, np.where(axis == 1, y, z))
    face = 2 * axis + (dom < 0)
    den = np.abs(dom)
    den = np.where(den > 0, den, 1.0)
    u = np.where(axis == 0, y, x) / den
    w = np.where(axis == 2, y, z) / den
    iu = np.clip(np.floor((u + 1.0) * 4.0), 0, 7).astype(np.int64)
    iv = np.clip(np.floor((w + 1.0) * 4.0), 0, 7).astype(np.int64)
    return face * 64 + iv * 8 + iu


def normal_cell_directions(corners: bool = False) -> np.ndarray:
    """Unit directions of the 384 normal-cube cells: centres (384, 3), or with ``corners`` (384, 4, 3).

    A cell contains every normal whose direction lies in the cone spanned by its 4 corner directions,
    so a view test that holds for all 4 corners holds for every normal in the cell.
    """
    cell = np.arange(384)
    face, rem = cell // 64, cell % 64
    iv, iu = rem // 8, rem % 8
    axis, neg = face // 2, face % 2
    other = np.array([[1, 2], [0, 2], [0, 1]])[axis]
    if corners:
        du = np.array([0, 1, 1, 0])
        dv = np.array([0, 0, 1, 1])
        u = (iu[:, None] + du) / 4.0 - 1.0
        w = (iv[:, None] + dv) / 4.0 - 1.0
    else:
        u = ((iu + 0.5) / 4.0 - 1.0)[:, None]
        w = ((iv + 0.5) / 4.0 - 1.0)[:, None]
    k = u.shape[1]
    out = np.zeros((384, k, 3))
    r = np.arange(384)[:, None]
    out[r, np.arange(k)[None, :], axis[:, None]] = np.where(neg, -1.0, 1.0)[:, None]
    out[r, np.arange(k)[None, :], other[:, 0][:, None]] = u
    out[r, np.arange(k)[None, :], other[:, 1][:, None]] = w
    out = _unit(out)
    return out if corners else out[:, 0]


# ----------------------------------------------------------------------------------------------
# the tree


_ARRAYS = (
    "vertices", "faces", "colors", "parent", "child_start", "child_count", "depth", "vertex_node",
    "position", "color", "center", "radius", "lum", "lum_min", "lum_max", "fold_delta", "geom_error",
    "normal_mask", "subtri_start", "subtris", "tri_node", "num_subtris", "leaf_lo", "leaf_hi",
    "leaf_vertex", "min_vertex",
)


@dataclasses.dataclass(eq=False)
class VertexTree:
    """A vertex tree: N nodes, V input vertices (the leaves), T input triangles (see docs/design.md).

    Nodes are numbered top-down (root 0, ``parent[i] < i``, children contiguous). Besides the fields
    of the design table it carries, for fast per-view extraction: ``leaf_lo``/``leaf_hi`` (N,) int32,
    the range of depth-first leaf positions a node supports; ``leaf_vertex`` (V,) int32, the input
    vertex at each depth-first leaf position; ``min_vertex`` (N,) int32, the smallest input vertex
    index a node supports. ``method``, ``lighting`` and ``mesh_report`` describe how it was built.
    """

    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray | None
    parent: np.ndarray
    child_start: np.ndarray
    child_count: np.ndarray
    depth: np.ndarray
    vertex_node: np.ndarray
    position: np.ndarray
    color: np.ndarray | None
    center: np.ndarray
    radius: np.ndarray
    lum: np.ndarray
    lum_min: np.ndarray
    lum_max: np.ndarray
    fold_delta: np.ndarray
    geom_error: np.ndarray
    normal_mask: np.ndarray
    subtri_start: np.ndarray
    subtris: np.ndarray
    tri_node: np.ndarray
    num_subtris: np.ndarray
    leaf_lo: np.ndarray
    leaf_hi: np.ndarray
    leaf_vertex: np.ndarray
    min_vertex: np.ndarray
    method: str = "octree"
    lighting: Lighting | None = None
    mesh_report: dict = dataclasses.field(default_factory=dict)

    # sizes ---------------------------------------------------------------------------------
    @property
    def n_nodes(self) -> int:
        return int(self.parent.shape[0])

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def n_triangles(self) -> int:
        return int(self.faces.shape[0])

    @property
    def nbytes(self) -> int:
        """Memory of all arrays, bytes."""
        return int(sum(getattr(self, k).nbytes for k in _ARRAYS if getattr(self, k) is not None))

    @functools.cached_property
    def internal(self) -> np.ndarray:
        """Indices (ascending, intp) of the internal nodes (the only nodes a cut can unfold)."""
        return np.flatnonzero(self.child_count > 0)

    @functools.cached_property
    def level_start(self) -> np.ndarray:
        """(max_depth + 2,) offsets: nodes of depth d are ``level_start[d]:level_start[d + 1]``."""
        return np.searchsorted(self.depth, np.arange(int(self.depth[-1]) + 2)).astype(np.int64)

    def __repr__(self) -> str:
        return (f"VertexTree(method={self.method!r}, nodes={self.n_nodes}, vertices={self.n_vertices}, "
                f"triangles={self.n_triangles}, depth={int(self.depth.max())}, colors={self.colors is not None})")

    # io ------------------------------------------------------------------------------------
    def save(self, path: str | os.PathLike, *, protect=()) -> Path:
        """Write the tree as one uncompressed .npz, atomically (``protect``: files never overwritten)."""
        from pmetric import atomic_path

        meta = {
            "format": TREE_FORMAT,
            "method": self.method,
            "lighting": None if self.lighting is None else self.lighting.to_dict(),
            "mesh_report": self.mesh_report,
        }
        arrays = {k: getattr(self, k) for k in _ARRAYS if getattr(self, k) is not None}
        with atomic_path(path, protect=tuple(protect)) as tmp:
            with open(tmp, "wb") as fh:
                np.savez(fh, __meta__=np.array(json.dumps(meta)), **arrays)
        return Path(path)

    def check(self) -> None:
        """Check the structural invariants (raises ValueError naming the first broken one)."""
        N, V, T = self.n_nodes, self.n_vertices, self.n_triangles
        p = self.parent
        if p[0] != -1 or (N > 1 and np.any(p[1:] >= np.arange(1, N))) or (N > 1 and np.any(p[1:] < 0)):
            raise ValueError("tree: parent must satisfy parent[0] = -1 and 0 <= parent[i] < i")
        if N > 1 and np.any(np.diff(p[1:]) < 0):
            raise ValueError("tree: children are not contiguous (parent[1:] must be non-decreasing)")
        if not np.array_equal(np.bincount(p[1:], minlength=N), self.child_count):
            raise ValueError("tree: child_count disagrees with parent")
        if self.subtri_start[-1] != T or not np.array_equal(np.sort(self.subtris), np.arange(T)):
            raise ValueError("tree: subtris is not a partition of the triangles")
        if not np.array_equal(self.tri_node[self.subtris], np.repeat(np.arange(N), self.num_subtris)):
            raise ValueError("tree: tri_node disagrees with subtris")
        if self.vertex_node.shape != (V,) or np.any(self.child_count[self.vertex_node] != 0):
            raise ValueError("tree: vertex_node must point at leaves")


def load_tree(path: str | os.PathLike) -> VertexTree:
    """Read a tree written by :meth:`VertexTree.save` (ValueError naming the file if it is not one)."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"tree file not found: {str(p)!r}")
    try:
        with np.load(p, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except Exception as exc:
        raise ValueError(f"cannot read tree file {str(p)!r}: {type(exc).__name__}: {exc}") from None
    try:
        meta = json.loads(str(data.pop("__meta__")))
    except KeyError:
        raise ValueError(f"{str(p)!r} is not a plod vertex tree (no metadata)") from None
    if meta.get("format") != TREE_FORMAT:
        raise ValueError(f"{str(p)!r}: unsupported tree format {meta.get('format')!r} (want {TREE_FORMAT!r})")
    missing = [k for k in _ARRAYS if k not in data and k not in ("colors", "color")]
    if missing:
        raise ValueError(f"{str(p)!r}: tree file lacks arrays {missing}")
    kw = {k: data.get(k) for k in _ARRAYS}
    N, V, T = kw["parent"].shape[0], kw["vertices"].shape[0], kw["faces"].shape[0]
    want = {"vertices": (V, 3), "faces": (T, 3), "colors": (V, 3), "vertex_node": (V,), "position": (N, 3),
            "color": (N, 3), "center": (N, 3), "normal_mask": (N, 48), "subtri_start": (N + 1,), "subtris": (T,),
            "tri_node": (T,), "leaf_vertex": (V,)}
    for k in _ARRAYS:
        shape = want.get(k, (N,))
        if kw[k] is not None and kw[k].shape != shape:
            raise ValueError(f"{str(p)!r}: tree array {k!r} has shape {kw[k].shape}, expected {shape} (corrupt file?)")
    light = meta.get("lighting")
    return VertexTree(**kw, method=meta.get("method", "octree"),
                      lighting=None if light is None else Lighting(**light),
                      mesh_report=meta.get("mesh_report", {}))


def mesh_hash(vertices, faces, colors=None, method: str = "qem", lighting=None) -> str:
    """Hex SHA-256 identifying a tree build: the mesh arrays (as float64/int64/float32), the method,
    the lighting (ignored when colours are given, as it does not enter the build) and the tree format.
    """
    h = hashlib.sha256()
    h.update(TREE_FORMAT.encode())
    h.update(str(method).encode())
    if colors is None:
        h.update(json.dumps(Lighting.coerce(lighting).to_dict(), sort_keys=True).encode())
    v = np.ascontiguousarray(np.asarray(vertices, dtype=np.float64))
    f = np.ascontiguousarray(np.asarray(faces, dtype=np.int64))
    h.update(str(v.shape).encode() + v.tobytes())
    h.update(str(f.shape).encode() + f.tobytes())
    if colors is not None:
        c = np.ascontiguousarray(np.asarray(colors, dtype=np.float32))
        h.update(str(c.shape).encode() + c.tobytes())
    return h.hexdigest()


# ----------------------------------------------------------------------------------------------
# build


def _list_rank(parent: np.ndarray) -> np.ndarray:
    """Synchronous pointer jumping (Wyllie): depth of each node = number of ancestors."""
    d = (parent >= 0).astype(np.int64)
    p = parent.copy()
    while True:
        act = np.flatnonzero(p >= 0)
        if act.size == 0:
            return d
        pa = p[act]
        dn = d[pa]
        pn = p[pa]
        d[act] += dn
        p[act] = pn


def _bfs_order(parent: np.ndarray, depth: np.ndarray, root: int):
    """Top-down numbering: sort by depth, then by the new index of the parent, then by old index.

    Returns ``(order, new_of_old)``: ``order[new] = old``.
    """
    n = parent.shape[0]
    by_depth = np.argsort(depth, kind="stable")
    counts = np.bincount(depth)
    starts = np.concatenate([[0], np.cumsum(counts)])
    new_of_old = np.empty(n, dtype=np.int64)
    order = np.empty(n, dtype=np.int64)
    order[0] = root
    new_of_old[root] = 0
    for d in range(1, counts.size):
        olds = by_depth[starts[d]:starts[d + 1]]
        keys = new_of_old[parent[olds]]
        o = olds[np.argsort(keys, kind="stable")]
        order[starts[d]:starts[d + 1]] = o
        new_of_old[o] = np.arange(starts[d], starts[d + 1])
    return order, new_of_old


class _Levels:
    """Level structure of a BFS-numbered tree, for bottom-up reductions and top-down scans."""

    def __init__(self, parent: np.ndarray, depth: np.ndarray):
        self.parent = parent
        D = int(depth[-1])
        self.start = np.searchsorted(depth, np.arange(D + 2))
        self.segs = []  # per level d (children at depth d + 1): (segment starts, parents)
        for d in range(D):
            s, e = self.start[d + 1], self.start[d + 2]
            par = parent[s:e]
            st = np.flatnonzero(np.concatenate([[True], par[1:] != par[:-1]]))
            self.segs.append((s, e, st, par[st]))

    def reduce_up(self, arr: np.ndarray, ufunc) -> np.ndarray:
        """Bottom-up: every internal node gets ``ufunc.reduce`` of its children (in place, returned)."""
        for s, e, st, pu in reversed(self.segs):
            arr[pu] = ufunc.reduceat(arr[s:e], st, axis=0)
        return arr


class _LCA:
    """Lowest common ancestors of leaf pairs by binary lifting on depth-first leaf ranges.

    Node x is an ancestor of leaf position p iff ``leaf_lo[x] <= p < leaf_hi[x]``; climbing from
    one leaf by powers of two while the ancestor does not hold the other leaf takes log2(depth)
    vectorised steps whatever the tree's shape (edge-collapse trees can be deep).
    """

    def __init__(self, parent, depth, leaf_lo, leaf_hi):
        self.lo, self.hi = leaf_lo, leaf_hi
        up = [np.where(parent >= 0, parent, 0)]
        while (1 << len(up)) <= int(depth.max()):
            up.append(up[-1].take(up[-1]))
        self.up = up

    def __call__(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        lo, hi = self.lo, self.hi
        pb = lo.take(b)
        x = a.astype(np.int64, copy=True)
        for u in reversed(self.up):
            y = u.take(x)
            outside = (lo.take(y) > pb) | (hi.take(y) <= pb)
            x = np.where(outside, y, x)
        inside = (lo.take(x) <= pb) & (pb < hi.take(x))
        return np.where(inside, x, self.up[0].take(x))


def _progress(enabled: bool, total: int):
    if not enabled:
        return None
    from rich.progress import Progress

    prog = Progress(transient=True)
    prog.start()
    task = prog.add_task("build tree", total=total)
    return prog, task


def build_tree(vertices, faces, colors=None, method: str = "qem", lighting=None, *, progress: bool = False,
               qem_aggressiveness: float = 7.0) -> VertexTree:
    """Build the vertex tree of a triangle mesh (seed 001 section 2; seed 004 section 5).

    Args:
        vertices: (V, 3) positions, object units. faces: (T, 3) vertex indices.
        colors: optional (V, 3) sRGB vertex colours in [0, 1]: vertex intensity is their relative
            luminance; without colours the mesh is pre-lit with ``lighting`` (:class:`Lighting`).
        method: ``"qem"`` (quadric edge-collapse hierarchy via fast-simplification, topped by a tight
            octree over what it cannot collapse) or ``"octree"`` (VDSlib's tight octree).
        lighting: :class:`Lighting`, dict or None (default light); used only without colours.
        progress: show stage progress with rich.

    Returns:
        :class:`VertexTree` over the *validated* mesh (see :func:`optim.validate_mesh`;
        ``tree.mesh_report`` lists what was dropped).
    """
    if method not in METHODS:
        raise ValueError(f"build_tree: method must be one of {METHODS}, got {method!r}")
    light = Lighting.coerce(lighting)
    pr = _progress(progress, 5)

    def step(desc):
        if pr is not None:
            pr[0].update(pr[1], advance=1, description=desc)

    try:
        v, f, c, report, fn = validate_mesh(vertices, faces, colors, count_nonmanifold=False, _normals=True)
        V, T = v.shape[0], f.shape[0]
        step("cluster")
        vn = _vertex_normals(v, f, fn)
        if method == "octree":
            from ._octree import octree_parents

            parent_old, _ = octree_parents(v)
            quadrics = None
        else:
            from ._qem import qem_parents, vertex_quadrics

            parent_old = qem_parents(v, f, aggressiveness=qem_aggressiveness)
            quadrics = vertex_quadrics(v, f, fn)
        step("renumber")
        tree = _assemble(v, f, c, vn, fn, parent_old, quadrics, light if c is None else None)
        tree.method = method
        tree.mesh_report = dataclasses.asdict(report)
        step("done")
        return tree
    finally:
        if pr is not None:
            pr[0].stop()


def _assemble(v, f, c, vn, fn, parent_old, quadrics, light) -> VertexTree:
    """Stages 3-5 of :func:`build_tree` for a hierarchy given as a parent array over V leaves + internals."""
    V, T = v.shape[0], f.shape[0]
    n = parent_old.shape[0]
    roots = np.flatnonzero(parent_old < 0)
    if roots.size != 1:
        raise ValueError(f"internal error: hierarchy has {roots.size} roots")
    depth_old = _list_rank(parent_old)
    order, new_of_old = _bfs_order(parent_old, depth_old, int(roots[0]))
    parent = np.full(n, -1, dtype=np.int64)
    parent[1:] = new_of_old[parent_old[order[1:]]]
    depth = depth_old[order]
    vertex_node = new_of_old[:V]
    N = n
    child_count = np.bincount(parent[1:], minlength=N)
    child_start = np.searchsorted(parent, np.arange(N), side="left")
    lv = _Levels(parent, depth)
    leaf = child_count == 0

    # --- aggregate bottom-up -------------------------------------------------------------------
    lum_v = _srgb_luminance(c) if c is not None else light.intensity(_unit(vn))
    ones = np.ones((V, 1))
    ssum = np.zeros((N, 10 if c is not None else 7))  # count, pos(3), normal(3)[, color(3)]
    ssum[vertex_node] = np.hstack([ones, v, vn] + ([c] if c is not None else []))
    lv.reduce_up(ssum, np.add)
    smin = np.zeros((N, 5))  # bbox min(3), lum min, min vertex
    smax = np.zeros((N, 4))  # bbox max(3), lum max
    smin[vertex_node] = np.hstack([v, lum_v[:, None], np.arange(V)[:, None]])
    smax[vertex_node] = np.hstack([v, lum_v[:, None]])
    lv.reduce_up(smin, np.minimum)
    lv.reduce_up(smax, np.maximum)
    # normal masks: triangle normal cells OR-ed into the corner leaves, then up the tree
    cell = normal_cells(fn)
    mask = np.zeros((N, 6), dtype=np.uint64)
    bits = np.left_shift(np.uint64(1), (cell % 64).astype(np.uint64))
    flat = mask.reshape(-1)
    for k in range(3):
        np.bitwise_or.at(flat, vertex_node[f[:, k]] * 6 + cell // 64, bits)
    lv.reduce_up(mask, np.bitwise_or)

    count = ssum[:, 0]
    centroid = ssum[:, 1:4] / count[:, None]
    if quadrics is not None:
        qn = np.zeros((N, quadrics.shape[1]))
        qn[vertex_node] = quadrics
        lv.reduce_up(qn, np.add)
        from ._qem import quadric_optimal

        pos = quadric_optimal(qn, centroid)
    else:
        pos = centroid
    pos[vertex_node] = v  # leaves: exactly the input vertex
    color = None
    if c is not None:
        color = (ssum[:, 7:10] / count[:, None]).astype(np.float32)
        color[vertex_node] = c
        lum = _srgb_luminance(color)
    else:
        lum = light.intensity(_unit(ssum[:, 4:7]))
    lum[vertex_node] = lum_v
    lum_min = np.minimum(smin[:, 3], lum).astype(np.float32)
    lum_max = np.maximum(smax[:, 3], lum).astype(np.float32)
    fold_delta = np.maximum(lum_max - lum, lum - lum_min).astype(np.float32)
    fold_delta[leaf] = 0.0
    bmin, bmax = smin[:, 0:3], smax[:, 0:3]
    center = 0.5 * (bmin + bmax)
    min_vertex = smin[:, 4].astype(np.int32)

    # --- depth-first leaf ranges (top-down) ------------------------------------------------------
    nleaf = leaf.astype(np.int64)
    lv.reduce_up(nleaf, np.add)
    leaf_lo = np.zeros(N, dtype=np.int64)
    for s, e, st, pu in lv.segs:
        cs = np.cumsum(nleaf[s:e])
        seg_id = np.repeat(np.arange(st.size), np.diff(np.append(st, e - s)))
        base = np.concatenate([[0], cs])[st]  # cumsum before each segment start
        excl = np.concatenate([[0], cs[:-1]]) - base[seg_id]
        leaf_lo[s:e] = leaf_lo[pu][seg_id] + excl
    leaf_hi = leaf_lo + nleaf
    leaf_vertex = np.empty(V, dtype=np.int64)
    leaf_vertex[leaf_lo[vertex_node]] = np.arange(V)

    # --- exact bounding radius and geometric error (over supported vertices) ----------------------
    center = center.astype(np.float32).astype(np.float64)  # measure from the stored (float32) centre
    pos = pos.astype(np.float32).astype(np.float64)
    radius = np.zeros(N)
    geom = np.zeros(N)
    vd = v.take(leaf_vertex, axis=0)  # vertices in depth-first order
    for d in range(len(lv.start) - 1):
        s, e = lv.start[d], lv.start[d + 1]
        nodes = np.arange(s, e)[~leaf[s:e]]
        if nodes.size == 0:
            continue
        lo, sz = leaf_lo.take(nodes), nleaf.take(nodes)
        off = np.concatenate([[0], np.cumsum(sz)[:-1]])
        pts = vd.take(np.repeat(lo - off, sz) + np.arange(int(sz.sum())), axis=0)
        dc = pts - np.repeat(center.take(nodes, axis=0), sz, axis=0)
        dp = pts - np.repeat(pos.take(nodes, axis=0), sz, axis=0)
        radius[nodes] = np.maximum.reduceat(np.einsum("ij,ij->i", dc, dc), off)
        geom[nodes] = np.maximum.reduceat(np.einsum("ij,ij->i", dp, dp), off)
    radius = np.sqrt(radius)
    geom = np.sqrt(geom)

    radius[vertex_node] = np.sqrt(((v - center[vertex_node]) ** 2).sum(1))  # float32 rounding of a leaf centre
    # round up so that the float32 sphere still holds every supported vertex
    radius = np.where(radius > 0, np.nextafter(radius.astype(np.float32), np.float32(np.inf)), 0.0)
    geom = np.where(geom > 0, np.nextafter(geom.astype(np.float32), np.float32(np.inf)), 0.0)

    # --- subtris: owner = deepest pairwise LCA of the corners' leaves ---------------------------
    lf = vertex_node.take(f)
    # two of the three pairwise LCAs coincide (the triple's LCA); the third is deeper or equal.
    # If LCA(0,1) != LCA(0,2) the deeper of the two is the answer; else LCA(1,2) decides.
    lca = _LCA(parent, depth, leaf_lo, leaf_hi)
    l01 = lca(lf[:, 0], lf[:, 1])
    l02 = lca(lf[:, 0], lf[:, 2])
    tri_node = np.where(depth.take(l01) >= depth.take(l02), l01, l02)
    same = np.flatnonzero(l01 == l02)
    tri_node[same] = lca(lf[same, 1], lf[same, 2])
    subtris = np.argsort(tri_node, kind="stable")
    num_subtris = np.bincount(tri_node, minlength=N)
    subtri_start = np.concatenate([[0], np.cumsum(num_subtris)])

    i32 = lambda x: np.ascontiguousarray(x, dtype=np.int32)  # noqa: E731
    f32 = lambda x: np.ascontiguousarray(x, dtype=np.float32)  # noqa: E731
    return VertexTree(
        vertices=v, faces=i32(f), colors=c, parent=i32(parent), child_start=i32(child_start),
        child_count=i32(child_count), depth=i32(depth), vertex_node=i32(vertex_node), position=f32(pos),
        color=color, center=f32(center), radius=f32(radius), lum=f32(lum), lum_min=lum_min, lum_max=lum_max,
        fold_delta=fold_delta, geom_error=f32(geom), normal_mask=np.ascontiguousarray(mask, dtype='<u8').view(np.uint8).reshape(N, 48),
        subtri_start=i32(subtri_start), subtris=i32(subtris), tri_node=i32(tri_node), num_subtris=i32(num_subtris),
        leaf_lo=i32(leaf_lo), leaf_hi=i32(leaf_hi), leaf_vertex=i32(leaf_vertex), min_vertex=min_vertex,
        lighting=light,
    )

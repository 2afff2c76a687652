"""The vertex tree (VDSlib's data structure [LHNW00 §2; LH01 §5]): :class:`VertexTree`, its file format
(:meth:`VertexTree.save`, :func:`load_tree`), its build identity (:func:`mesh_hash`) and the pre-lighting
of uncoloured meshes (:class:`Lighting`). The builder is :func:`optim._build.build_tree`.

Units: positions, ``center``, ``radius``, ``geom_error`` in object units (``position`` and ``center``
float32, relative to the tree's ``origin``: see :func:`local_origin`); ``lum*`` and
``fold_delta`` are relative linear luminance in [0, 1] ([LHNW00]: "intensity ... luminance output by a
standard computer monitor, normalized to the range [0, 1]").
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from pathlib import Path
from typing import Callable

import numpy as np

from pmetric import PlodError

from ._levels import Levels
from ._mesh import corner_sum, face_normals, real_or_nan
from ._normal_cube import _unit, unit_any_length

__all__ = [
    "Lighting",
    "VertexTree",
    "load_tree",
    "local_origin",
    "mesh_hash",
    "vertex_luminance",
]

TREE_FORMAT = "plod-vertex-tree-2"  # 2: the origin (trees of format 1 read with origin 0)
_READ_FORMATS = ("plod-vertex-tree-1", TREE_FORMAT)
METHODS = ("qem", "octree", "meshopt", "hybrid")

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
        try:
            d = np.asarray(self.direction, dtype=np.float64)
        except (TypeError, ValueError):
            d = None
        if d is None or d.shape != (3,) or not np.all(np.isfinite(d)) or not np.any(d):
            raise PlodError(f"Lighting: direction must be a finite nonzero 3-vector, got {self.direction!r}")
        for k in ("ambient", "diffuse"):
            v = getattr(self, k)
            x = real_or_nan(v)
            if not (np.isfinite(x) and x >= 0):
                raise PlodError(f"Lighting: {k} must be a finite number >= 0, got {v!r}")
            object.__setattr__(self, k, x)
        if not isinstance(self.two_sided, (bool, np.bool_)):
            raise PlodError(f"Lighting: two_sided must be True or False, got {self.two_sided!r}")
        object.__setattr__(self, "direction", tuple(float(x) for x in d))
        object.__setattr__(self, "two_sided", bool(self.two_sided))

    @property
    def unit(self) -> np.ndarray:
        """(3,) float64 unit vector towards the light (scaled by its largest component first, so a
        direction of 1e-200 or 1e200 units neither underflows nor overflows)."""
        return unit_any_length(self.direction)

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
                raise PlodError(f"Lighting: unknown fields {sorted(unknown)}")
            return cls(**x)
        if isinstance(x, (tuple, list)) and any(isinstance(y, cls) for y in x):
            raise PlodError(f"lighting: one light only (a directional light plus ambient), got {len(x)} Lighting "
                            "objects")
        if isinstance(x, (tuple, list)) and len(x) in (1, 2, 3, 4):
            return cls(*x)
        raise PlodError(f"lighting must be None, a Lighting, a dict or a tuple; got {type(x).__name__}")

    @classmethod
    def from_text(cls, text: str, flag: str = "--light") -> "Lighting":
        """``"DX,DY,DZ"`` or ``"DX,DY,DZ,AMBIENT"``: direction toward the light (object space) and
        ambient level in [0, 1] (default 0.15), diffuse ``1 - ambient`` (a surface facing the light is
        white). ``flag`` names the option in the error message."""
        parts = [p.strip() for p in str(text).split(",")]
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            vals = []
        if len(vals) not in (3, 4) or not np.all(np.isfinite(vals)):
            raise PlodError(f"{flag} needs DX,DY,DZ or DX,DY,DZ,AMBIENT (finite numbers), got {text!r}")
        if not np.any(vals[:3]):
            raise PlodError(f"{flag}: the light direction must be nonzero, got {text!r}")
        amb = vals[3] if len(vals) == 4 else cls.ambient
        if not 0.0 <= amb <= 1.0:
            raise PlodError(f"{flag}: AMBIENT must be in [0, 1], got {amb!r}")
        return cls(direction=tuple(vals[:3]), ambient=amb, diffuse=1.0 - amb)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def shade(self, cos) -> np.ndarray:
        """Relative luminance (float64) for cosines ``cos`` of normals to the light (``|n . l|`` already
        taken for a two-sided light)."""
        return np.clip(self.ambient + self.diffuse * np.maximum(cos, 0.0), 0.0, 1.0)

    def intensity(self, normals: np.ndarray, dtype=np.float32) -> np.ndarray:
        """Relative luminance (K,) ``dtype`` (computed in float64) for unit normals (K, 3)."""
        ndl = np.asarray(normals, dtype=np.float64) @ self.unit
        return self.shade(np.abs(ndl) if self.two_sided else ndl).astype(dtype)


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
    return corner_sum(f, fn, v.shape[0])


def vertex_luminance(vertices, faces, colors=None, lighting=None) -> np.ndarray:
    """Relative linear luminance (V,) float32 of each vertex: from colours when given, else pre-lit.

    With colours: relative luminance of linearised sRGB. Without: :class:`Lighting` applied to
    area-weighted vertex normals ([LHNW00] assumes pre-lit models).
    """
    from ._mesh import _check_arrays, _check_colors

    if colors is not None:  # the mesh is not needed (it may be None); the colours are one per vertex
        if vertices is not None and np.ndim(vertices) == 2:
            nv = np.shape(vertices)[0]
        else:
            nv = np.shape(colors)[0] if np.ndim(colors) else -1
        return _srgb_luminance(_check_colors(colors, nv, "vertex_luminance"))
    if np.shape(faces) == (0, 3):  # no faces (e.g. a cut drawn without its back faces): ambient only
        v, f = np.asarray(vertices, np.float64).reshape(-1, 3), np.zeros((0, 3), np.int64)
    else:
        v, f = _check_arrays(vertices, faces, "vertex_luminance")  # shapes, NaN, index range (PlodError)
    light = Lighting.coerce(lighting)
    return light.intensity(_unit(_vertex_normals(v, f)))


# ----------------------------------------------------------------------------------------------
# the tree


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


def local_origin(vertices) -> np.ndarray:
    """(3,) float64: the origin of a tree's float32 node coordinates for ``vertices`` (V, 3).

    Per axis 0, unless the bounding box's centre lies more than 4 diagonals from 0 on that axis: then
    the centre rounded to a multiple of ``q``, the power of two at or above the diagonal. The float32
    positions then carry the mesh's own size, not its distance from 0 (a mesh 1e7 units away with a
    diagonal of 1 kept about 1 unit of precision, and its keys and cuts were silently wrong). Such an
    origin is within ``q / 2`` of the centre and at least 3 diagonals from 0, so every coordinate lies
    within a factor of 2 of it and ``vertices - origin`` is exact (Sterbenz), as is adding it back.
    Meshes near 0 keep origin 0 and the same tree as without this."""
    v = np.asarray(vertices, np.float64)
    if v.size == 0:
        return np.zeros(3)
    lo, hi = v.min(axis=0), v.max(axis=0)
    diag = float(np.linalg.norm(hi - lo))
    centre = 0.5 * lo + 0.5 * hi
    far = np.abs(centre) > 4 * diag
    if diag <= 0 or not far.any():
        return np.zeros(3)
    q = 2.0 ** np.ceil(np.log2(diag))
    return np.where(far, np.round(centre / q) * q, 0.0)


def _origin_array(origin, who: str) -> np.ndarray:
    """``origin`` (None: 0) as a (3,) float64 array; PlodError naming ``who`` unless 3 finite numbers."""
    if origin is None:
        return np.zeros(3)
    try:
        o = np.array(origin, dtype=np.float64)
    except (TypeError, ValueError):
        o = None
    if o is None or o.shape != (3,) or not np.all(np.isfinite(o)):
        raise PlodError(f"{who}: origin must be 3 finite numbers, got {origin!r}")
    return o


_ARRAYS = (
    "vertices", "faces", "colors", "parent", "child_start", "child_count", "depth", "vertex_node",
    "position", "color", "center", "radius", "lum", "lum_min", "lum_max", "fold_delta", "geom_error",
    "normal_mask", "subtri_start", "subtris", "tri_node", "num_subtris", "leaf_lo", "leaf_hi",
    "leaf_vertex", "min_vertex",
)


@dataclasses.dataclass(frozen=True, eq=False)
class VertexTree:
    """A vertex tree: N nodes, V input vertices (the leaves), T input triangles (see docs/design.md).

    Nodes are numbered top-down (root 0, ``parent[i] < i``, children contiguous). Besides the fields
    of the design table it carries, for fast per-view extraction: ``leaf_lo``/``leaf_hi`` (N,) int32,
    the range of depth-first leaf positions a node supports; ``leaf_vertex`` (V,) int32, the input
    vertex at each depth-first leaf position; ``min_vertex`` (N,) int32, the smallest input vertex
    index a node supports. ``method``, ``lighting`` and ``mesh_report`` describe how it was built.
    ``origin`` (3,) float64: the float32 node arrays ``position`` and ``center`` are relative to it
    (:func:`local_origin`; 0 unless the mesh lies far from the coordinate origin for its size);
    ``vertices`` are the input's, unchanged, and :attr:`local_vertices` the same relative to ``origin``.

    Immutable: attributes cannot be set, and the arrays are read-only views (``flags.writeable`` is
    False; the builder's arrays are never written again). Data derived from the tree (the scoring
    context, the per-view indices of the cuts, ``internal``, ``levels``) is computed on first use and
    kept by :meth:`derived`, the one cache of a tree.
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
    origin: np.ndarray | None = None
    _derived: dict = dataclasses.field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self):
        for k in _ARRAYS:
            a = getattr(self, k)
            if a is not None:
                a = np.asarray(a).view()
                a.flags.writeable = False
                object.__setattr__(self, k, a)
        object.__setattr__(self, "origin", _readonly(_origin_array(self.origin, "tree")))

    def derived(self, name: str, build: Callable[[], object]):
        """The derived value ``name`` of this tree: ``build()`` on the first call, the same object on
        every later one. The one cache of a tree (valid for its lifetime, as the tree is immutable)."""
        cache = self._derived
        try:
            return cache[name]
        except KeyError:
            value = cache[name] = build()
            return value

    def has_derived(self, name: str) -> bool:
        """Whether :meth:`derived` already holds ``name`` (a builder that makes two values in one pass
        can then skip a value already made)."""
        return name in self._derived

    @property
    def local_vertices(self) -> np.ndarray:
        """(V, 3) the input vertices relative to :attr:`origin` (the frame of ``position`` and ``center``;
        exact: :func:`local_origin` makes the subtraction exact); ``vertices`` itself when the origin is 0."""
        if not self.origin.any():
            return self.vertices
        return self.derived("local_vertices", lambda: _readonly(np.asarray(self.vertices, np.float64) - self.origin))

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

    @property
    def internal(self) -> np.ndarray:
        """Indices (ascending, intp) of the internal nodes (the only nodes a cut can unfold)."""
        return self.derived("internal", lambda: _readonly(np.flatnonzero(self.child_count > 0)))

    @property
    def levels(self) -> Levels:
        """The :class:`optim._levels.Levels` of the whole tree (bottom-up reductions, top-down spreads)."""
        return self.derived("levels", lambda: Levels.from_depth(self.parent, self.depth))

    @property
    def level_start(self) -> np.ndarray:
        """(max_depth + 2,) offsets: nodes of depth d are ``level_start[d]:level_start[d + 1]``."""
        return self.derived("level_start", lambda: _readonly(np.asarray(self.levels.start, np.int64)))

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
            "origin": [float(x) for x in self.origin],  # repr of a float64 reads back exactly
        }
        arrays = {k: getattr(self, k) for k in _ARRAYS if getattr(self, k) is not None}
        with atomic_path(path, protect=protect) as tmp:
            with open(tmp, "wb") as fh:
                np.savez(fh, __meta__=np.array(json.dumps(meta)), **arrays)
        return Path(path)

    def check(self) -> None:
        """Check the structural invariants (raises PlodError naming the first broken one)."""
        N, V, T = self.n_nodes, self.n_vertices, self.n_triangles
        p = self.parent
        if p[0] != -1 or (N > 1 and np.any(p[1:] >= np.arange(1, N))) or (N > 1 and np.any(p[1:] < 0)):
            raise PlodError("tree: parent must satisfy parent[0] = -1 and 0 <= parent[i] < i")
        if N > 1 and np.any(np.diff(p[1:]) < 0):
            raise PlodError("tree: children are not contiguous (parent[1:] must be non-decreasing)")
        if not np.array_equal(np.bincount(p[1:], minlength=N), self.child_count):
            raise PlodError("tree: child_count disagrees with parent")
        st, sub = self.subtri_start, self.subtris
        if st[0] != 0 or st[-1] != T or np.any(np.diff(st) < 0) or (T and (sub.min() < 0 or sub.max() >= T)) \
                or not np.all(np.bincount(sub, minlength=T) == 1):  # each triangle once (O(T), no sort)
            raise PlodError("tree: subtris is not a partition of the triangles")
        if not np.array_equal(self.tri_node[sub], np.repeat(np.arange(N), self.num_subtris)):
            raise PlodError("tree: tri_node disagrees with subtris")
        vn = self.vertex_node
        if vn.shape != (V,) or (V and (vn.min() < 0 or vn.max() >= N)) or np.any(self.child_count[vn] != 0):
            raise PlodError("tree: vertex_node must point at leaves")
        if T and (self.faces.min() < 0 or self.faces.max() >= V):
            raise PlodError("tree: faces index vertices out of range")


def load_tree(path: str | os.PathLike) -> VertexTree:
    """Read a tree written by :meth:`VertexTree.save` (PlodError naming the file if it is not one)."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"tree file not found: {str(p)!r}")
    try:
        with np.load(p, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except Exception as exc:
        raise PlodError(f"cannot read tree file {str(p)!r}: {type(exc).__name__}: {exc}") from None
    try:
        meta = json.loads(str(data.pop("__meta__")))
    except KeyError:
        raise PlodError(f"{str(p)!r} is not a plod vertex tree (no metadata)") from None
    if meta.get("format") not in _READ_FORMATS:
        raise PlodError(f"{str(p)!r}: unsupported tree format {meta.get('format')!r} (want {TREE_FORMAT!r})")
    missing = [k for k in _ARRAYS if k not in data and k not in ("colors", "color")]
    if missing:
        raise PlodError(f"{str(p)!r}: tree file lacks arrays {missing}")
    kw = {k: data.get(k) for k in _ARRAYS}
    N, V, T = kw["parent"].shape[0], kw["vertices"].shape[0], kw["faces"].shape[0]
    want = {"vertices": (V, 3), "faces": (T, 3), "colors": (V, 3), "vertex_node": (V,), "position": (N, 3),
            "color": (N, 3), "center": (N, 3), "normal_mask": (N, 48), "subtri_start": (N + 1,), "subtris": (T,),
            "tri_node": (T,), "leaf_vertex": (V,)}
    for k in _ARRAYS:
        shape = want.get(k, (N,))
        if kw[k] is not None and kw[k].shape != shape:
            raise PlodError(f"{str(p)!r}: tree array {k!r} has shape {kw[k].shape}, expected {shape} (corrupt file?)")
    light = meta.get("lighting")
    tree = VertexTree(**kw, method=meta.get("method", "octree"),
                      lighting=None if light is None else Lighting(**light),
                      mesh_report=meta.get("mesh_report", {}),
                      origin=_origin_array(meta.get("origin"), f"{str(p)!r}: tree file (corrupt?)"))
    try:  # arrays of the right shapes may still not be a tree (a damaged or edited file): say so here
        tree.check()
    except (PlodError, IndexError, ValueError) as exc:
        raise PlodError(f"{str(p)!r}: not a valid vertex tree ({exc}; corrupt file?)") from None
    return tree


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

"""Tight-octree vertex clustering (VDSlib's default clustering [LE97], used by [LHNW00]).

Stages:

1. ``morton_codes``: quantise the points in their bounding cube to 21 bits per axis and interleave
   the bits into 63-bit Morton codes (vectorised magic-bit spreading).
2. sort the points by code; the longest common prefix (in 3-bit octree levels) of neighbours in
   that order tells at which octree level they split.
3. ``octree_parents``: the *branching* cells (cells with points in two or more child cells, plus
   bottom cells holding several identical codes) are the internal nodes of the tight octree: every
   single-child chain of the plain octree is collapsed. Each point hangs below the deepest branching
   cell that holds it; each branching cell below the deepest branching cell that strictly holds it.

All in numpy, O(P log P) (one sort and a few searchsorted calls).
"""

from __future__ import annotations

import numpy as np

LEVELS = 21  # bits per axis; 63-bit codes

__all__ = ["morton_codes", "octree_parents"]


def _spread3(x: np.ndarray) -> np.ndarray:
    """Spread the low 21 bits of ``x`` (uint64) so that bit i moves to bit 3 i."""
    x = x & np.uint64(0x1FFFFF)
    x = (x | (x << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    x = (x | (x << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    x = (x | (x << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    x = (x | (x << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    x = (x | (x << np.uint64(2))) & np.uint64(0x1249249249249249)
    return x


def morton_codes(points: np.ndarray) -> np.ndarray:
    """63-bit Morton codes (uint64, shape (P,)) of points (P, 3) in their bounding cube."""
    p = np.asarray(points, dtype=np.float64)
    lo = p.min(axis=0)
    side = float((p.max(axis=0) - lo).max())
    scale = (1 << LEVELS) / side if side > 0 else 0.0
    q = np.clip(np.floor((p - lo) * scale), 0, (1 << LEVELS) - 1).astype(np.uint64)
    return (_spread3(q[:, 0]) << np.uint64(2)) | (_spread3(q[:, 1]) << np.uint64(1)) | _spread3(q[:, 2])


def _common_levels(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Number of leading 3-bit octree digits two codes share (0..LEVELS), int64."""
    x = a ^ b
    n = _floor_log2(x) + (x != 0)  # bit length of x
    return LEVELS - (n + 2) // 3


def _floor_log2(x: np.ndarray) -> np.ndarray:
    """Position of the highest set bit of uint64 values (0 for 0 and 1), int64, by binary search
    (exact on uint64)."""
    n = np.zeros(x.shape, dtype=np.int64)
    for s in (32, 16, 8, 4, 2, 1):
        big = (x >> np.uint64(s)) != 0
        n += big * s
        x = np.where(big, x >> np.uint64(s), x)
    return n


def octree_parents(points: np.ndarray):
    """Tight-octree hierarchy over points.

    Args:
        points: (P, 3) positions, P >= 1.

    Returns:
        ``(parent, level)``: ``parent`` (P + M,) int64 over P leaves (the points, same order) followed
        by M internal nodes, -1 for the root; ``level`` (M,) int64 octree level of each internal
        node (0 = the bounding cube). With P == 1 the single point is the root (M = 0).
    """
    p = np.asarray(points, dtype=np.float64)
    P = p.shape[0]
    if P == 1:
        return np.array([-1], dtype=np.int64), np.zeros(0, dtype=np.int64)
    codes = morton_codes(p)
    order = np.argsort(codes, kind="stable")
    c = codes[order]
    lcp = _common_levels(c[:-1], c[1:])  # (P-1,) level at which pair i, i+1 separate (LEVELS = equal)

    # internal nodes: (level, prefix) of every neighbour pair, unique, as sentinel-bit keys
    shift = (3 * (LEVELS - lcp)).astype(np.uint64)
    prefix = c[:-1] >> shift
    keys = (np.uint64(1) << (3 * lcp).astype(np.uint64)) | prefix
    ukeys, pair_node = np.unique(keys, return_inverse=True)
    M = ukeys.size
    # level and prefix of each internal node, decoded from the key
    nlev = _key_level(ukeys)
    nshift = (3 * (LEVELS - nlev)).astype(np.uint64)
    npre = ukeys ^ (np.uint64(1) << (3 * nlev).astype(np.uint64))
    # sorted-point range [a, b] of each internal node
    lo_code = npre << nshift
    a = np.searchsorted(c, lo_code, side="left")
    # upper bound: last code with the same prefix
    b = np.searchsorted(c, lo_code | ((np.uint64(1) << nshift) - np.uint64(1)), side="right") - 1
    lcp_ext = np.concatenate([[-1], lcp, [-1]])  # lcp_ext[i] = lcp of pair (i-1, i)
    plev = np.maximum(lcp_ext[a], lcp_ext[b + 1])  # deepest branching level strictly above
    parent_int = np.full(M, -1, dtype=np.int64)
    has = plev >= 0
    pk = (np.uint64(1) << (3 * plev[has]).astype(np.uint64)) | (c[a[has]] >> (3 * (LEVELS - plev[has])).astype(np.uint64))
    parent_int[has] = np.searchsorted(ukeys, pk) + P
    # leaves: deepest branching cell holding the point
    llev = np.maximum(lcp_ext[:-1], lcp_ext[1:])  # (P,) in sorted order
    lk = (np.uint64(1) << (3 * llev).astype(np.uint64)) | (c >> (3 * (LEVELS - llev)).astype(np.uint64))
    leaf_parent = np.empty(P, dtype=np.int64)
    leaf_parent[order] = np.searchsorted(ukeys, lk) + P
    parent = np.concatenate([leaf_parent, parent_int])
    return parent, nlev


def _key_level(keys: np.ndarray) -> np.ndarray:
    """Octree level of sentinel-bit keys (bit length - 1) / 3."""
    return _floor_log2(keys) // 3

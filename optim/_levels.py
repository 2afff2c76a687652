"""Level-by-level propagation over a breadth-first tree: the one implementation used by the tree
build (bottom-up sums, minima, maxima, ORs), the scoring (maximum up [LH01 fn 2], culling down) and
the cuts (``repair_monotone``, closing a cut under ancestors).

Nodes are numbered level by level (depth d occupies ``start[d]:start[d + 1]``) with the children
of each parent contiguous, so every level is a run of child groups and one ``ufunc.reduceat`` per
level reduces them; ``parent[i]`` is the position of node i's parent (-1 for the root).
"""

from __future__ import annotations

import numpy as np

__all__ = ["Levels", "expand_ranges", "level_runs"]


def expand_ranges(start, count) -> np.ndarray:
    """Concatenation of ``arange(start[i], start[i] + count[i])`` over i (intp)."""
    count = count.astype(np.intp, copy=False)
    total = int(count.sum())
    if total == 0:
        return np.zeros(0, dtype=np.intp)
    off = np.cumsum(count) - count  # exclusive prefix sums
    return np.repeat(start.astype(np.intp) - off, count) + np.arange(total, dtype=np.intp)


def level_runs(start, lo, count, select=None):
    """Per level ``start[d]:start[d + 1]`` of a breadth-first tree: ``(nodes, idx, off)``: the level's
    nodes with ``select`` (default all) and ``count > 0``, the concatenated positions of their runs
    ``lo[n] : lo[n] + count[n]`` and each run's offset in ``idx`` (for ``ufunc.reduceat``). Levels with
    no such node are skipped. The runs of one level of a vertex tree (depth-first leaf ranges, or the
    corner runs sorted by them) are disjoint, so each level costs one pass over at most all elements."""
    for d in range(len(start) - 1):
        nodes = np.arange(start[d], start[d + 1])
        if select is not None:
            nodes = nodes[select[nodes]]
        sz = count[nodes]
        nodes, sz = nodes[sz > 0], sz[sz > 0]
        if nodes.size:
            yield nodes, expand_ranges(lo[nodes], sz), np.cumsum(sz) - sz


class Levels:
    """Child groups of every level of a breadth-first tree.

    ``parent`` (N,) positions of the parents (-1 for the root); ``start`` (D + 2,) level offsets.
    ``groups[k]`` for level k >= 1 (``groups[0]`` is None): ``(a, b, seg, pids)``: the level is
    ``a:b``, its child groups start at ``a + seg`` and belong to the parents at positions ``pids``.

    ``max_arity > 0`` also builds the slot form used by :meth:`max_up` (:meth:`_slots`): per level the
    parents' positions, one gather per child slot (while most groups fill the slot, every group, short
    ones padded with a child they have: max is idempotent; then only the groups that have that
    child) and, for the few groups with more than ``max_arity`` children, the positions of their
    remaining children (reduced by ``reduceat``).
    ``np.maximum.reduceat`` pays a per-group overhead that dominates on binary trees; one gather per
    child slot does not, and one group of 9 children no longer sends a whole level to ``reduceat``.
    """

    def __init__(self, parent: np.ndarray, start, *, max_arity: int = 0):
        self.parent = parent
        self.start = start
        self.groups = [None]
        self.slots = [None]
        for k in range(1, len(start) - 1):
            a, b = int(start[k]), int(start[k + 1])
            p = parent[a:b]
            seg = np.flatnonzero(np.r_[True, p[1:] != p[:-1]]) if b > a else np.zeros(0, np.int64)
            self.groups.append((a, b, seg, p[seg]))
            self.slots.append(self._slots(a, b, seg, p[seg], max_arity))

    @staticmethod
    def _slots(a, b, seg, pids, max_arity):
        """``(pids, rows, tail)`` of one level for :meth:`max_up`: ``rows`` one ``(sel, child)`` per
        child slot j < ``max_arity``: ``sel`` None and ``child`` (P,) positions of every group's j-th
        child (short groups padded with their last), or, once fewer than half of the groups have a
        j-th child, ``sel`` those groups and ``child`` their j-th children; ``tail`` None or
        ``(groups, positions, offsets)`` of the children beyond the slots (for ``reduceat``)."""
        if not len(pids) or max_arity <= 0:
            return None
        cnt = np.diff(np.r_[seg, b - a])
        arity = min(int(cnt.max()), max_arity)
        pos = (a + seg).astype(np.intp)
        rows = []
        for j in range(arity):
            sel = np.flatnonzero(cnt > j)
            if j == 0 or 2 * sel.size > cnt.size:
                rows.append((None, pos + np.minimum(j, cnt - 1)))
            else:
                rows.append((sel, pos[sel] + j))
        big = np.flatnonzero(cnt > arity)  # groups with children beyond the slots
        tail = None
        if big.size:
            rest = cnt[big] - arity
            tail = (big, expand_ranges(pos[big] + arity, rest), np.cumsum(rest) - rest)
        return pids.astype(np.intp), rows, tail

    @classmethod
    def from_depth(cls, parent: np.ndarray, depth: np.ndarray, **kw) -> "Levels":
        """Levels of a tree numbered breadth first with (non-decreasing) ``depth`` per node."""
        return cls(parent, np.searchsorted(depth, np.arange(int(depth[-1]) + 2)), **kw)

    def reduce_up(self, arr: np.ndarray, ufunc, *, include_self: bool = False) -> np.ndarray:
        """Bottom-up, deepest level first: every node with children gets ``ufunc.reduce`` of its
        children (``include_self``: combined with its own value). In place; returns ``arr``."""
        for k in range(len(self.groups) - 1, 0, -1):
            a, b, seg, pids = self.groups[k]
            if not len(pids):
                continue
            red = ufunc.reduceat(arr[a:b], seg, axis=0)
            arr[pids] = ufunc(arr[pids], red) if include_self else red
        return arr

    def max_up(self, key: np.ndarray) -> np.ndarray:
        """``key[parent] = max(key[parent], max key[children])``, deepest level first: each key becomes
        the maximum over its subtree [LH01 fn 2]. In place; equal to ``reduce_up(key, np.maximum,
        include_self=True)`` (max is exact), with one gather per child slot where slots were built."""
        for k in range(len(self.groups) - 1, 0, -1):
            sl = self.slots[k]
            if sl is None:
                a, b, seg, pids = self.groups[k]
                if len(pids):
                    key[pids] = np.maximum(key[pids], np.maximum.reduceat(key[a:b], seg))
                continue
            pids, rows, tail = sl
            m = key.take(pids)
            for sel, child in rows:
                if sel is None:
                    np.maximum(m, key.take(child), out=m)
                else:
                    m[sel] = np.maximum(m.take(sel), key.take(child))
            if tail is not None:
                big, idx, off = tail
                m[big] = np.maximum(m[big], np.maximum.reduceat(key.take(idx), off))
            key[pids] = m
        return key

    def spread_down(self, arr: np.ndarray, ufunc) -> np.ndarray:
        """Top-down, level by level: ``arr[i] = ufunc(arr[i], arr[parent[i]])`` (``np.logical_or``: a
        flag spreads to the whole subtree; ``np.logical_and``: closes a set under ancestors). In place."""
        par = self.parent
        for k in range(1, len(self.groups)):
            a, b = self.groups[k][:2]
            ufunc(arr[a:b], arr.take(par[a:b]), out=arr[a:b])
        return arr

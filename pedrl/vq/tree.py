"""Exact nearest-prototype search by a k-d tree, in numba (CPU); its specification is `pedrl.vq.nearest_prototype`.

The quantizer's states are far from filling their 28 dimensions: with the default feature weights (own features
4, walls 0.5, neighbours 0.2) three principal components hold 98 % of the prototypes' variance, so a k-d tree
over the prototypes prunes almost all of them. Measured on the states of the paper's room (K = 4096): a point's
exact nearest prototype is found after computing distances to a few dozen prototypes instead of 4096, which is
several times faster than the `(B, d) x (d, K)` product of the matrix search for the few hundred states a
decision encodes.

The answer is exact: boxes bound the distance from below, a subtree is skipped only when its bound exceeds the
best distance found (with a margin for rounding), and a distance is the float32 sum of the squared differences
taken column after column (columns in the order of decreasing variance), ties to the lowest prototype index. So
the id is the argmin of those distances, whatever the tree; the float32 matrix search and this one can only
disagree between prototypes whose distances tie within float32 rounding.

`TreeIndex` holds one tree per prototype set (`T` sets of `K` prototypes, one per learning process); a search
names each point's set.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch

from pedrl._numba import cached_njit

__all__ = ["LEAF_SIZE", "TreeArrays", "TreeIndex"]

LEAF_SIZE = 16
"""Prototypes per leaf, whose distances the kernel computes in vector lanes, 16 at a time (measured per state:
1.35 us with leaves of 8, 0.97 us with 16, 0.89 us with 32)."""
SCAN_ABOVE_COLUMNS = 8
"""A tree whose nodes split on more columns than this is searched by :func:`scan_point` instead: its boxes bound the
distances loosely, so the search visits most leaves (measured per state at K = 4096: log distances split on 4
columns, 1.5 us by the tree against 8 by the scan; the paper's raw distances on all 28, 36 us against 8.6). The fused
trial's encoding searches such sets by :mod:`pedrl.vq.pruned` instead (the same ids, about twice as fast)."""
_FAR = 1e18
"""Coordinates of the dummy prototypes that pad leaves to ``LEAF_SIZE``."""
_BOUND_SHRINK = 1.0 - 1e-5
"""Box bounds are shrunk by this factor before pruning: a bound summed in another order than a distance may
exceed it by a few float32 roundings."""
_STACK = 128
"""Depth-first stack of the search: two entries per level; a tree of K prototypes has about log2(K / 16) levels."""


def _build(points: np.ndarray) -> tuple[np.ndarray, ...]:
    """The k-d tree of ``points (K, d)`` float64: split at the median of the widest dimension of each node.

    Returns ``(order, start, end, left, right, low, high)``: ``order (K,)`` the prototype ids in tree order; per
    node (numbered depth first, left before right) its range ``[start, end)`` of ``order``, its children (``-1``
    at a leaf) and its box ``low/high (n, d)``. The node count and ranges depend only on ``K``, so trees of equally
    many prototypes stack.
    """
    return _build_tree(np.ascontiguousarray(points, dtype=np.float64), LEAF_SIZE)


@cached_njit(nogil=True)
def _build_tree(points, leaf_size):
    num, dim = points.shape
    capacity = 2 * num + 1
    order = np.arange(num)
    start = np.empty(capacity, dtype=np.int64)
    end = np.empty(capacity, dtype=np.int64)
    left = np.full(capacity, -1, dtype=np.int64)
    right = np.full(capacity, -1, dtype=np.int64)
    low = np.empty((capacity, dim))
    high = np.empty((capacity, dim))
    pending = np.empty((capacity, 4), dtype=np.int64)  # first, stop, parent, side (0 left, 1 right)
    pending[0] = (0, num, -1, 0)
    top = 1
    count = 0
    while top > 0:
        top -= 1
        first, stop, parent, side = pending[top]
        index = count
        count += 1
        if parent >= 0:
            if side == 0:
                left[parent] = index
            else:
                right[parent] = index
        start[index] = first
        end[index] = stop
        for c in range(dim):
            low[index, c] = np.inf
            high[index, c] = -np.inf
        for slot in range(first, stop):
            for c in range(dim):
                value = points[order[slot], c]
                low[index, c] = min(low[index, c], value)
                high[index, c] = max(high[index, c], value)
        if stop - first > leaf_size:
            split = np.argmax(high[index] - low[index])
            members = order[first:stop].copy()
            local = np.argsort(points[members, split], kind="mergesort")
            order[first:stop] = members[local]
            middle = first + (stop - first) // 2
            pending[top] = (middle, stop, index, 1)  # popped after the left child's whole subtree
            pending[top + 1] = (first, middle, index, 0)
            top += 2
    return order, start[:count], end[:count], left[:count], right[:count], low[:count], high[:count]


@cached_njit(nogil=True, inline="always")
def _box_distance(point, low, high, t, node):
    """Squared distance from ``point`` to the box of ``node`` over its leading columns (a lower bound).

    Full indices, no array views: a view costs two atomic reference-count updates in numba.
    """
    a0 = np.float32(0.0)
    a1 = np.float32(0.0)
    zero = np.float32(0.0)
    head = low.shape[2]
    for c in range(0, head - 1, 2):  # branch-free: mispredicted branches cost more than arithmetic
        g0 = max(max(low[t, node, c] - point[c], point[c] - high[t, node, c]), zero)
        g1 = max(max(low[t, node, c + 1] - point[c + 1], point[c + 1] - high[t, node, c + 1]), zero)
        a0 += g0 * g0
        a1 += g1 * g1
    if head % 2:
        c = head - 1
        g0 = max(max(low[t, node, c] - point[c], point[c] - high[t, node, c]), zero)
        a0 += g0 * g0
    return a0 + a1


@cached_njit(nogil=True)
def _search(points, sets, columns, tree, scan, ids, sq_dist):
    dim = points.shape[1]
    nodes = np.empty(_STACK, dtype=np.int64)
    point = np.empty(dim, dtype=np.float32)
    sums = np.empty(LEAF_SIZE, dtype=np.float32)
    for row in range(points.shape[0]):
        t = sets[row]
        for c in range(dim):
            point[c] = points[row, columns[t, c]]
        if scan:
            ids[row], sq_dist[row] = scan_point(point, t, tree.prototypes, tree.ids_of, sums)
        else:
            ids[row], sq_dist[row] = search_tree(point, t, tree, nodes, sums)


@cached_njit(nogil=True)
def search_point(point, t, prototypes, ids_of, leaf_of, left, right, split_dim, split_value, low, high, nodes, sums):
    """The nearest prototype of set ``t`` to ``point`` (its columns already in the set's order): ``(id, sq_dist)``,
    id 0 for a NaN point. ``nodes`` (``_STACK``) and ``sums`` (``LEAF_SIZE``) are scratch."""
    shrink = np.float32(_BOUND_SHRINK)
    best = np.float32(np.inf)
    best_id = ids_of.shape[1] * LEAF_SIZE
    nodes[0] = 0
    top = 1
    while top > 0:
        top -= 1
        node = nodes[top]
        if node and _box_distance(point, low, high, t, node) * shrink > best:
            continue
        first_child = left[node]
        if first_child < 0:  # a leaf: its 16 distances, one vector lane per prototype
            best, best_id = _visit_leaf(point, prototypes, ids_of, t, leaf_of[node], sums, best, best_id)
            continue
        second_child = right[node]
        # the child on the point's side of the split plane first; bounds are computed when popped
        if point[split_dim[t, node]] >= split_value[t, node]:
            first_child, second_child = second_child, first_child
        nodes[top] = second_child
        nodes[top + 1] = first_child
        top += 2
    return (best_id if best_id < ids_of.shape[1] * LEAF_SIZE else 0), best  # a NaN point: id 0


@cached_njit(nogil=True, inline="always")
def search_tree(point, t, tree, nodes, sums):
    """:func:`search_point` in set ``t`` of ``tree`` (:class:`TreeArrays`)."""
    return search_point(point, t, tree.prototypes, tree.ids_of, tree.leaf_of, tree.left, tree.right, tree.split_dim,
                        tree.split_value, tree.low, tree.high, nodes, sums)  # fmt: skip


@cached_njit(nogil=True)
def scan_point(point, t, prototypes, ids_of, sums):
    """:func:`search_point` by a scan of every leaf: the same answer (the nearest prototype, lowest id on ties, from
    the same float32 sums), faster where the tree prunes little: states spread over many dimensions (raw distances)
    make it visit most leaves, and a node costs more than a leaf."""
    best = np.float32(np.inf)
    best_id = ids_of.shape[1] * LEAF_SIZE
    for leaf in range(ids_of.shape[1]):
        best, best_id = _visit_leaf(point, prototypes, ids_of, t, leaf, sums, best, best_id)
    return (best_id if best_id < ids_of.shape[1] * LEAF_SIZE else 0), best  # a NaN point: id 0


@cached_njit(nogil=True, inline="always")
def _visit_leaf(point, prototypes, ids_of, t, leaf, sums, best, best_id):
    """The best squared distance and prototype so far, after the prototypes of ``leaf`` (lowest id on ties)."""
    if _leaf_distances(point, prototypes, t, leaf, sums) > best:  # no prototype of it can win, or tie
        return best, best_id
    for j in range(LEAF_SIZE):
        index = ids_of[t, leaf, j]
        if sums[j] < best or (sums[j] == best and index < best_id):
            best = sums[j]
            best_id = index
    return best, best_id


@cached_njit(nogil=True, inline="always")
def _leaf_distances(point, prototypes, t, leaf, sums):
    """Squared distances from ``point`` to the ``LEAF_SIZE`` (16) prototypes of a leaf, into ``sums``, and the least
    of them: sixteen independent chains over the columns, each column's sixteen values loaded first (the SLP
    vectorizer then packs loads, differences and sums into vectors). A leaf whose least distance exceeds the best
    so far is passed over with one comparison instead of sixteen."""
    s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = s8 = s9 = s10 = s11 = s12 = s13 = s14 = s15 = np.float32(0.0)
    for c in range(point.shape[0]):
        value = point[c]
        p0 = prototypes[t, leaf, c, 0]
        p1 = prototypes[t, leaf, c, 1]
        p2 = prototypes[t, leaf, c, 2]
        p3 = prototypes[t, leaf, c, 3]
        p4 = prototypes[t, leaf, c, 4]
        p5 = prototypes[t, leaf, c, 5]
        p6 = prototypes[t, leaf, c, 6]
        p7 = prototypes[t, leaf, c, 7]
        p8 = prototypes[t, leaf, c, 8]
        p9 = prototypes[t, leaf, c, 9]
        p10 = prototypes[t, leaf, c, 10]
        p11 = prototypes[t, leaf, c, 11]
        p12 = prototypes[t, leaf, c, 12]
        p13 = prototypes[t, leaf, c, 13]
        p14 = prototypes[t, leaf, c, 14]
        p15 = prototypes[t, leaf, c, 15]
        g0 = value - p0
        g1 = value - p1
        g2 = value - p2
        g3 = value - p3
        g4 = value - p4
        g5 = value - p5
        g6 = value - p6
        g7 = value - p7
        g8 = value - p8
        g9 = value - p9
        g10 = value - p10
        g11 = value - p11
        g12 = value - p12
        g13 = value - p13
        g14 = value - p14
        g15 = value - p15
        s0 += g0 * g0
        s1 += g1 * g1
        s2 += g2 * g2
        s3 += g3 * g3
        s4 += g4 * g4
        s5 += g5 * g5
        s6 += g6 * g6
        s7 += g7 * g7
        s8 += g8 * g8
        s9 += g9 * g9
        s10 += g10 * g10
        s11 += g11 * g11
        s12 += g12 * g12
        s13 += g13 * g13
        s14 += g14 * g14
        s15 += g15 * g15
    sums[0] = s0
    sums[1] = s1
    sums[2] = s2
    sums[3] = s3
    sums[4] = s4
    sums[5] = s5
    sums[6] = s6
    sums[7] = s7
    sums[8] = s8
    sums[9] = s9
    sums[10] = s10
    sums[11] = s11
    sums[12] = s12
    sums[13] = s13
    sums[14] = s14
    sums[15] = s15
    low0 = min(min(min(s0, s1), min(s2, s3)), min(min(s4, s5), min(s6, s7)))
    low1 = min(min(min(s8, s9), min(s10, s11)), min(min(s12, s13), min(s14, s15)))
    return min(low0, low1)


class TreeArrays(NamedTuple):
    """The k-d trees of ``T`` sets as the kernels read them (:meth:`TreeIndex.kernel_arrays`)."""

    prototypes: np.ndarray
    """``(T, L, d, LEAF_SIZE)`` float32: each leaf's prototypes, column by column (padded with far dummies)."""
    ids_of: np.ndarray
    """``(T, L, LEAF_SIZE)`` int64: their ids (``K`` for a dummy)."""
    leaf_of: np.ndarray
    """``(n,)`` int64: each node's leaf, -1 for an inner node."""
    left: np.ndarray
    """``(n,)`` int64: each node's left child (-1 at a leaf)."""
    right: np.ndarray
    """``(n,)`` int64: its right child."""
    split_dim: np.ndarray
    """``(T, n)`` int64: the column an inner node splits."""
    split_value: np.ndarray
    """``(T, n)`` float32: where."""
    low: np.ndarray
    """``(T, n, head)`` float32: each node's box, lower corner (the leading columns)."""
    high: np.ndarray
    """``(T, n, head)`` float32: upper corner."""


class TreeIndex:
    """Exact nearest-prototype search over ``T`` fixed sets of ``K`` prototypes ``(T, K, d)`` (CPU, numba).

    Each set's columns are reordered by decreasing variance, so that the box bounds need only the leading columns
    (up to the last one some node splits on). Leaves hold ``LEAF_SIZE`` prototypes as a ``(d, LEAF_SIZE)`` block
    (padded with far-away dummies), whose distances are computed 16 at a time in vector lanes. A search visits nodes
    depth first, the child on the point's side of the split first, and skips a node whose box lies farther than
    the best distance found. A tree whose splits use more than ``SCAN_ABOVE_COLUMNS`` columns prunes little, and is
    searched by a scan of its leaves instead (``scans``; the same answers).

    Args:
        prototypes: ``(K, d)`` (one set) or ``(T, K, d)`` float32 on the CPU.
    """

    def __init__(self, prototypes: torch.Tensor) -> None:
        if prototypes.device.type != "cpu":
            raise ValueError(f"the tree search runs on the CPU, got prototypes on {prototypes.device}")
        sets = prototypes.unsqueeze(0) if prototypes.ndim == 2 else prototypes
        if sets.ndim != 3 or sets.shape[1] == 0:
            raise ValueError(f"prototypes must be (K, d) or (T, K, d) with K > 0, got {tuple(prototypes.shape)}")
        self.num_sets, self.num_prototypes, self.dim = sets.shape
        values = sets.detach().to(torch.float64).numpy()
        self._columns = np.stack([np.argsort(-part.var(0), kind="stable") for part in values])  # (T, d)
        values = np.take_along_axis(values, self._columns[:, None, :], axis=2)
        trees = [_build(part) for part in values]
        _, start, end, self._left, self._right, _, _ = trees[0]
        inner = self._left >= 0
        split = [np.argmax(high[inner] - low[inner], axis=1) for *_, low, high in trees]
        head = max([int(columns.max()) + 1 for columns in split if columns.size] + [1])
        self._split_dim = np.zeros((self.num_sets, len(start)), dtype=np.int64)
        self._split_value = np.zeros((self.num_sets, len(start)), dtype=np.float32)
        for index, (*_, low, _high) in enumerate(trees):
            self._split_dim[index, inner] = split[index]
            self._split_value[index, inner] = low[self._right[inner], split[index]]
        self._low = np.ascontiguousarray(np.stack([low for *_, low, _ in trees])[:, :, :head], dtype=np.float32)
        self._high = np.ascontiguousarray(np.stack([high for *_, high in trees])[:, :, :head], dtype=np.float32)
        self.scans = head > SCAN_ABOVE_COLUMNS  # search by a scan of the leaves (same answers)
        # leaves as (d, LEAF_SIZE) blocks, padded with far-away dummies (id K, never the nearest)
        leaves = np.flatnonzero(~inner)
        self._leaf_of = np.full(len(start), -1, dtype=np.int64)
        self._leaf_of[leaves] = np.arange(len(leaves))
        slots = start[leaves, None] + np.arange(LEAF_SIZE)  # (L, LEAF_SIZE)
        real = slots < end[leaves, None]
        self._ids = np.empty((self.num_sets, len(leaves), LEAF_SIZE), dtype=np.int64)
        self._prototypes = np.empty((self.num_sets, len(leaves), self.dim, LEAF_SIZE), dtype=np.float32)
        for index, (order, *_) in enumerate(trees):
            ids = np.where(real, order[np.minimum(slots, self.num_prototypes - 1)], self.num_prototypes)
            self._ids[index] = ids
            block = np.where(real[..., None], values[index][np.minimum(ids, self.num_prototypes - 1)], _FAR)
            self._prototypes[index] = block.transpose(0, 2, 1)

    def kernel_arrays(self) -> TreeArrays:
        """What :func:`search_tree` reads after the point and its set (:class:`TreeArrays`); ``columns`` ``(T, d)``
        (:attr:`columns`) orders a point's values."""
        return TreeArrays(
            self._prototypes,
            self._ids,
            self._leaf_of,
            self._left,
            self._right,
            self._split_dim,
            self._split_value,
            self._low,
            self._high,
        )

    @property
    def columns(self) -> np.ndarray:
        """``(T, d)`` int64: the columns of set ``t`` in the order the tree reads them."""
        return self._columns

    def search(self, points: torch.Tensor, sets: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Nearest prototype of every point within its set.

        Args:
            points: ``(B, d)`` float32 on the CPU.
            sets: ``(B,)`` int64 in ``[0, T)``, the prototype set of every point (None: set 0, or the only one).

        Returns:
            ``(ids (B,) int64, sq_dist (B,) float32)``: the nearest prototype (lowest id on ties) and the squared
            distance to it.
        """
        if points.ndim != 2 or points.shape[1] != self.dim:
            raise ValueError(f"expected points (B, {self.dim}), got {tuple(points.shape)}")
        num = points.shape[0]
        if sets is None or self.num_sets == 1:
            sets = torch.zeros(num, dtype=torch.int64)
        elif sets.shape != (num,) or (num and not (int(sets.min()) >= 0 and int(sets.max()) < self.num_sets)):
            raise ValueError(f"sets must be ({num},) ints in [0, {self.num_sets}), got {sets}")
        ids = np.empty(num, dtype=np.int64)
        sq_dist = np.empty(num, dtype=np.float32)
        _search(
            np.ascontiguousarray(points.detach().to(torch.float32).numpy()),
            np.ascontiguousarray(sets.numpy(), dtype=np.int64),
            self._columns,
            self.kernel_arrays(),
            self.scans,
            ids,
            sq_dist,
        )
        return torch.from_numpy(ids), torch.from_numpy(sq_dist)

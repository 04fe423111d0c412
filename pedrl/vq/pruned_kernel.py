"""Numba kernels of :class:`pedrl.vq.pruned.PrunedIndex`; their specification is :func:`pedrl.vq.tree.scan_point` (the
same ids and float32 distances), checked against float64 brute force in ``tests/vq/test_pruned.py``.

A batch is the agents of one room that search one prototype set ``t``. :func:`prepare_batch` rotates each point
into the set's principal axes and finds a first candidate (a greedy walk over each prototype's nearest
prototypes, from the agent's previous prototype), whose scan distance gives the threshold ``T``;
:func:`search_batch` then visits the leaves pair by pair: each pair's columns ``0 .. cuts[0]`` for every agent
(:func:`_pass`), the next columns for the agents some lane of a leaf left within the threshold, and finally the scan's
own distance (:func:`exact_distance`) of every lane still within it.
"""

from __future__ import annotations

import numpy as np

from pedrl._numba import cached_njit

__all__ = ["LANES", "exact_distance", "prepare_batch", "search_batch"]

LANES = 16
"""Prototypes per leaf: one lane each, two vectors of eight."""
_LANE = tuple(np.uint64(j) for j in range(2 * LANES + 1))
"""Unsigned lane offsets: an unsigned index needs no negative-index check (four instructions a load)."""
SLACK = 2.0**-14
"""Relative and absolute margin of the threshold: ``T = ub (1 + SLACK) + SLACK (1 + |y|^2 + max |q|^2)``. It covers,
about ten times over, the float32 rounding of the scan's distance (``(d + 3) u`` relative, ``u = 2^-24``), of the
rotated coordinates (``u (|y| + |q|)``) and of the bounds' sums (``(d + 8) u (2 max |q|^2 + |y|^2)``), for ``d`` up
to 256 features."""
FALLBACK_NORM = 1e12
"""A point whose rotated squared norm is above this (or NaN) is searched by the scan instead: the margins above
assume no overflow."""


@cached_njit(nogil=True)
def exact_distance(point, rows, t, k):
    """The scan's squared distance from ``point`` to prototype ``k`` of set ``t``: float32 squares of float32
    differences, summed column after column from 0 (each lane of :func:`pedrl.vq.tree._leaf_distances` does the same
    operations in the same order, so the two are equal to the bit). No fast-math: nothing may be fused."""
    total = np.float32(0.0)
    for c in range(point.shape[0]):
        g = point[c] - rows[t, k, c]
        total += g * g
    return total


@cached_njit(nogil=True, fastmath=True)
def _approx_distance(padded, rows, t, k):
    """A squared distance in any summation order (vector lanes): only the greedy walk's guide."""
    total = np.float32(0.0)
    for c in range(rows.shape[2]):
        g = padded[c] - rows[t, k, c]
        total += g * g
    return total


@cached_njit(nogil=True, fastmath={"contract"}, inline="always")
def _pair_pass(y, a, cols, q, base, nq, n0, acc):
    """Columns ``0 .. cols`` of the 32 lanes of a pair of leaves at ``q[base + j]`` (32 apart from a column to the
    next): the partial bounds ``acc[a, 0:32]`` of agent ``a``, from the lanes' ``|q|^2`` over those columns
    ``nq[n0 + j]``. One broadcast of ``y`` feeds four vector FMAs."""
    a0, a1, a2, a3 = nq[n0], nq[n0 + 1], nq[n0 + 2], nq[n0 + 3]
    a4, a5, a6, a7 = nq[n0 + 4], nq[n0 + 5], nq[n0 + 6], nq[n0 + 7]
    a8, a9, a10, a11 = nq[n0 + 8], nq[n0 + 9], nq[n0 + 10], nq[n0 + 11]
    a12, a13, a14, a15 = nq[n0 + 12], nq[n0 + 13], nq[n0 + 14], nq[n0 + 15]
    a16, a17, a18, a19 = nq[n0 + 16], nq[n0 + 17], nq[n0 + 18], nq[n0 + 19]
    a20, a21, a22, a23 = nq[n0 + 20], nq[n0 + 21], nq[n0 + 22], nq[n0 + 23]
    a24, a25, a26, a27 = nq[n0 + 24], nq[n0 + 25], nq[n0 + 26], nq[n0 + 27]
    a28, a29, a30, a31 = nq[n0 + 28], nq[n0 + 29], nq[n0 + 30], nq[n0 + 31]
    o = np.uint64(base)
    for c in range(cols):
        v = y[a, c]
        a0, a1, a2, a3 = a0 + v * q[o], a1 + v * q[o + _LANE[1]], a2 + v * q[o + _LANE[2]], a3 + v * q[o + _LANE[3]]
        a4, a5, a6, a7 = (
            a4 + v * q[o + _LANE[4]],
            a5 + v * q[o + _LANE[5]],
            a6 + v * q[o + _LANE[6]],
            a7 + v * q[o + _LANE[7]],
        )
        a8, a9, a10, a11 = (
            a8 + v * q[o + _LANE[8]],
            a9 + v * q[o + _LANE[9]],
            a10 + v * q[o + _LANE[10]],
            a11 + v * q[o + _LANE[11]],
        )
        a12, a13, a14, a15 = (
            a12 + v * q[o + _LANE[12]],
            a13 + v * q[o + _LANE[13]],
            a14 + v * q[o + _LANE[14]],
            a15 + v * q[o + _LANE[15]],
        )
        a16, a17, a18, a19 = (
            a16 + v * q[o + _LANE[16]],
            a17 + v * q[o + _LANE[17]],
            a18 + v * q[o + _LANE[18]],
            a19 + v * q[o + _LANE[19]],
        )
        a20, a21, a22, a23 = (
            a20 + v * q[o + _LANE[20]],
            a21 + v * q[o + _LANE[21]],
            a22 + v * q[o + _LANE[22]],
            a23 + v * q[o + _LANE[23]],
        )
        a24, a25, a26, a27 = (
            a24 + v * q[o + _LANE[24]],
            a25 + v * q[o + _LANE[25]],
            a26 + v * q[o + _LANE[26]],
            a27 + v * q[o + _LANE[27]],
        )
        a28, a29, a30, a31 = (
            a28 + v * q[o + _LANE[28]],
            a29 + v * q[o + _LANE[29]],
            a30 + v * q[o + _LANE[30]],
            a31 + v * q[o + _LANE[31]],
        )
        o += _LANE[32]
    acc[a, 0], acc[a, 1], acc[a, 2], acc[a, 3] = a0, a1, a2, a3
    acc[a, 4], acc[a, 5], acc[a, 6], acc[a, 7] = a4, a5, a6, a7
    acc[a, 8], acc[a, 9], acc[a, 10], acc[a, 11] = a8, a9, a10, a11
    acc[a, 12], acc[a, 13], acc[a, 14], acc[a, 15] = a12, a13, a14, a15
    acc[a, 16], acc[a, 17], acc[a, 18], acc[a, 19] = a16, a17, a18, a19
    acc[a, 20], acc[a, 21], acc[a, 22], acc[a, 23] = a20, a21, a22, a23
    acc[a, 24], acc[a, 25], acc[a, 26], acc[a, 27] = a24, a25, a26, a27
    acc[a, 28], acc[a, 29], acc[a, 30], acc[a, 31] = a28, a29, a30, a31


@cached_njit(nogil=True, fastmath={"contract"}, inline="always")
def _pass(y, a, first, cols, q, base, stride, nq, n0, acc, h, fresh, bound):
    """Columns ``first .. first + cols`` of the 16 lanes at ``q[base + j]`` (``stride`` apart from a column to the
    next) added to the partial bounds ``acc[a, h : h + 16]`` of agent ``a`` (from 0 if ``fresh``), with the lanes'
    ``|q|^2`` over those columns ``nq[n0 + j]``; returns whether some lane is within ``bound``. One FMA per lane and
    column (``y . (-2 q)``), 16 lanes in four vector chains (even and odd columns)."""
    zero = np.float32(0.0)
    a0, a1 = (zero if fresh else acc[a, h]) + nq[n0], (zero if fresh else acc[a, h + 1]) + nq[n0 + 1]
    a2, a3 = (zero if fresh else acc[a, h + 2]) + nq[n0 + 2], (zero if fresh else acc[a, h + 3]) + nq[n0 + 3]
    a4, a5 = (zero if fresh else acc[a, h + 4]) + nq[n0 + 4], (zero if fresh else acc[a, h + 5]) + nq[n0 + 5]
    a6, a7 = (zero if fresh else acc[a, h + 6]) + nq[n0 + 6], (zero if fresh else acc[a, h + 7]) + nq[n0 + 7]
    a8, a9 = (zero if fresh else acc[a, h + 8]) + nq[n0 + 8], (zero if fresh else acc[a, h + 9]) + nq[n0 + 9]
    a10, a11 = (zero if fresh else acc[a, h + 10]) + nq[n0 + 10], (zero if fresh else acc[a, h + 11]) + nq[n0 + 11]
    a12, a13 = (zero if fresh else acc[a, h + 12]) + nq[n0 + 12], (zero if fresh else acc[a, h + 13]) + nq[n0 + 13]
    a14, a15 = (zero if fresh else acc[a, h + 14]) + nq[n0 + 14], (zero if fresh else acc[a, h + 15]) + nq[n0 + 15]
    b0 = b1 = b2 = b3 = b4 = b5 = b6 = b7 = b8 = b9 = b10 = b11 = b12 = b13 = b14 = b15 = zero
    o = np.uint64(base)
    p = np.uint64(base + stride)
    step = np.uint64(2 * stride)
    for c in range(first, first + cols, 2):  # two chains a lane: even columns in a, odd in b
        v, w = y[a, c], y[a, c + 1]
        a0, a1, a2, a3 = a0 + v * q[o], a1 + v * q[o + _LANE[1]], a2 + v * q[o + _LANE[2]], a3 + v * q[o + _LANE[3]]
        a4, a5, a6, a7 = (
            a4 + v * q[o + _LANE[4]],
            a5 + v * q[o + _LANE[5]],
            a6 + v * q[o + _LANE[6]],
            a7 + v * q[o + _LANE[7]],
        )
        a8, a9, a10, a11 = (
            a8 + v * q[o + _LANE[8]],
            a9 + v * q[o + _LANE[9]],
            a10 + v * q[o + _LANE[10]],
            a11 + v * q[o + _LANE[11]],
        )
        a12, a13, a14, a15 = (
            a12 + v * q[o + _LANE[12]],
            a13 + v * q[o + _LANE[13]],
            a14 + v * q[o + _LANE[14]],
            a15 + v * q[o + _LANE[15]],
        )
        b0, b1, b2, b3 = b0 + w * q[p], b1 + w * q[p + _LANE[1]], b2 + w * q[p + _LANE[2]], b3 + w * q[p + _LANE[3]]
        b4, b5, b6, b7 = (
            b4 + w * q[p + _LANE[4]],
            b5 + w * q[p + _LANE[5]],
            b6 + w * q[p + _LANE[6]],
            b7 + w * q[p + _LANE[7]],
        )
        b8, b9, b10, b11 = (
            b8 + w * q[p + _LANE[8]],
            b9 + w * q[p + _LANE[9]],
            b10 + w * q[p + _LANE[10]],
            b11 + w * q[p + _LANE[11]],
        )
        b12, b13, b14, b15 = (
            b12 + w * q[p + _LANE[12]],
            b13 + w * q[p + _LANE[13]],
            b14 + w * q[p + _LANE[14]],
            b15 + w * q[p + _LANE[15]],
        )
        o += step
        p += step
    a0, a1, a2, a3 = a0 + b0, a1 + b1, a2 + b2, a3 + b3
    a4, a5, a6, a7 = a4 + b4, a5 + b5, a6 + b6, a7 + b7
    a8, a9, a10, a11 = a8 + b8, a9 + b9, a10 + b10, a11 + b11
    a12, a13, a14, a15 = a12 + b12, a13 + b13, a14 + b14, a15 + b15
    acc[a, h], acc[a, h + 1], acc[a, h + 2], acc[a, h + 3] = a0, a1, a2, a3
    acc[a, h + 4], acc[a, h + 5], acc[a, h + 6], acc[a, h + 7] = a4, a5, a6, a7
    acc[a, h + 8], acc[a, h + 9], acc[a, h + 10], acc[a, h + 11] = a8, a9, a10, a11
    acc[a, h + 12], acc[a, h + 13], acc[a, h + 14], acc[a, h + 15] = a12, a13, a14, a15
    return (
        (a0 <= bound)
        | (a1 <= bound)
        | (a2 <= bound)
        | (a3 <= bound)
        | (a4 <= bound)
        | (a5 <= bound)
        | (a6 <= bound)
        | (a7 <= bound)
        | (a8 <= bound)
        | (a9 <= bound)
        | (a10 <= bound)
        | (a11 <= bound)
        | (a12 <= bound)
        | (a13 <= bound)
        | (a14 <= bound)
        | (a15 <= bound)
    )


@cached_njit(nogil=True)
def prepare_batch(points, n, hints, t, index, scratch):
    """Rotate the first ``n`` ``points`` (in set ``t``'s column order) into ``y``, walk from each one's hint (its
    previous prototype, if within ``[0, K)``) to a local nearest prototype, and set the thresholds ``bounds[a, p] = T -
    |y|^2`` over the columns of passes ``0 .. p``. ``best_id[a]`` is -1 for a point left to the scan (NaN or huge)."""
    cuts, mean, axes, rows, graph = index.cuts, index.mean, index.axes, index.rows, index.graph
    entry, norm_bound = index.entry, index.norm_bound
    y, norms, bounds, best, best_id = scratch.y, scratch.norms, scratch.bounds, scratch.best, scratch.best_id
    rotated, padded = scratch.rotated, scratch.padded
    dim, width = points.shape[1], axes.shape[2]
    count = rows.shape[1]
    for a in range(n):
        for c in range(width):
            rotated[c] = 0.0
        for j in range(dim):
            x = np.float64(points[a, j]) - mean[t, j]
            for c in range(width):
                rotated[c] += x * axes[t, j, c]
        total = 0.0
        p = 0
        for c in range(width):
            y[a, c] = np.float32(rotated[c])
            total += np.float64(y[a, c]) * np.float64(y[a, c])
            while p < cuts.shape[0] and c + 1 == cuts[p]:
                norms[a, p] = total
                p += 1
        if not total <= FALLBACK_NORM:
            best_id[a] = -1
            continue
        for c in range(padded.shape[0]):
            padded[c] = points[a, c] if c < dim else np.float32(0.0)
        current = hints[a] if 0 <= hints[a] < count else entry[t]
        near = _approx_distance(padded, rows, t, current)
        moved = True
        while moved:  # to the nearest of the current prototype's neighbours while one is nearer
            moved = False
            start = current
            for g in range(graph.shape[2]):
                k = graph[t, start, g]
                value = _approx_distance(padded, rows, t, k)
                if value < near:
                    near, current, moved = value, k, True
        best[a] = exact_distance(points[a], rows, t, current)
        best_id[a] = current
        _set_bounds(a, best[a], total, norm_bound[t], norms, bounds)


@cached_njit(nogil=True, inline="always")
def _within(acc, a, h, bound):
    """Whether some lane of ``acc[a, h : h + 16]`` is within ``bound``."""
    return (
        (acc[a, h] <= bound)
        | (acc[a, h + 1] <= bound)
        | (acc[a, h + 2] <= bound)
        | (acc[a, h + 3] <= bound)
        | (acc[a, h + 4] <= bound)
        | (acc[a, h + 5] <= bound)
        | (acc[a, h + 6] <= bound)
        | (acc[a, h + 7] <= bound)
        | (acc[a, h + 8] <= bound)
        | (acc[a, h + 9] <= bound)
        | (acc[a, h + 10] <= bound)
        | (acc[a, h + 11] <= bound)
        | (acc[a, h + 12] <= bound)
        | (acc[a, h + 13] <= bound)
        | (acc[a, h + 14] <= bound)
        | (acc[a, h + 15] <= bound)
    )


@cached_njit(nogil=True, inline="always")
def _compact(lists, flags, count, out, source):
    """The members ``i < count`` whose flag ``lists[flags, i]`` is set, into ``lists[out]`` (member ``i`` is agent
    ``i``, or ``lists[source, i]``); returns how many."""
    kept = 0
    for i in range(count):
        lists[out, kept] = i if source is None else lists[source, i]
        kept += lists[flags, i]
    return kept


@cached_njit(nogil=True, inline="always")
def _set_bounds(a, ub, total, norm_bound, norms, bounds):
    """``bounds[a, p] = T - |y|^2 (passes 0 .. p)`` for the threshold ``T`` of the scan distance ``ub`` (see SLACK)."""
    limit = np.float64(ub) * (1.0 + SLACK) + SLACK * (1.0 + total + norm_bound)
    for p in range(bounds.shape[1]):
        bounds[a, p] = np.float32(limit - norms[a, p])


@cached_njit(nogil=True, fastmath={"contract"})
def search_batch(points, n, t, index, scratch, counts):
    """The nearest prototype of each of the first ``n`` ``points`` prepared by :func:`prepare_batch`: ``best_id``
    and ``best`` (the scan's id and distance). ``counts`` adds the leaf-agent visits of the passes and the exact
    distances taken (the search's work, for the benchmark)."""
    cuts, ids, rows, norm_bound = index.cuts, index.ids, index.rows, index.norm_bound
    first_q, first_n, next_q, next_n = index.first_q, index.first_n, index.next_q, index.next_n
    last_q, last_n = index.last_q, index.last_n
    y, norms, bounds, best, best_id = scratch.y, scratch.norms, scratch.bounds, scratch.best, scratch.best_id
    acc, lists = scratch.acc, scratch.lists
    count = rows.shape[1]
    pairs = first_n.shape[1] // 32
    cols_a, cols_b, cols_c = cuts[0], cuts[1] - cuts[0], cuts[2] - cuts[1]
    qa, na = first_q[t], first_n[t]
    qb, nb, qc, nc = next_q[t], next_n[t], last_q[t], last_n[t]
    for pair in range(pairs):
        base = pair * cols_a * 32
        for a in range(n):  # flags at fixed addresses: no store waits for a bound
            _pair_pass(y, a, cols_a, qa, base, na, 32 * pair, acc)
            live = best_id[a] >= 0
            lists[0, a] = live and _within(acc, a, 0, bounds[a, 0])
            lists[1, a] = live and _within(acc, a, 16, bounds[a, 0])
        counts[0] += n
        for half in range(2):
            leaf = 2 * pair + half
            alive = _compact(lists, half, n, 2, None)
            counts[1] += alive
            for i in range(alive):
                a = lists[2, i]
                lists[4, i] = _pass(
                    y, a, cols_a, cols_b, qb, leaf * cols_b * 16, 16, nb, 16 * leaf, acc, 16 * half, False, bounds[a, 1]
                )
            alive = _compact(lists, 4, alive, 3, 2)
            counts[2] += alive
            for i in range(alive):
                a = lists[3, i]
                lists[4, i] = _pass(
                    y,
                    a,
                    cuts[1],
                    cols_c,
                    qc,
                    leaf * cols_c * 16,
                    16,
                    nc,
                    16 * leaf,
                    acc,
                    16 * half,
                    False,
                    bounds[a, 2],
                )
            kept = _compact(lists, 4, alive, 5, 3)
            for i in range(kept):
                a = lists[5, i]
                for j in range(LANES):
                    k = ids[t, leaf, j]
                    if acc[a, 16 * half + j] <= bounds[a, 2] and k < count:
                        counts[3] += 1
                        value = exact_distance(points[a], rows, t, k)
                        if value < best[a] or (value == best[a] and k < best_id[a]):
                            if value < best[a]:
                                _set_bounds(a, value, norms[a, norms.shape[1] - 1], norm_bound[t], norms, bounds)
                            best[a] = value
                            best_id[a] = k

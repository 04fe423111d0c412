"""Exact nearest-prototype search of spread states, batched over a room's agents (CPU, numba): the literal encoding.

The literal presets (``vq.distance_transform=none``, every feature weight 1) standardise all 28 features to unit
variance, so the prototypes fill all 28 dimensions (their principal components are nearly flat: the first holds
21 % of the variance, eight hold 56 %). A k-d tree then prunes nothing and :func:`pedrl.vq.tree.scan_point` scans
all 4096 prototypes of a set, 8.6 of a decision's 9.5 us per agent. Measured on the states of a literal paper_vqql
run (20 rooms of 20 agents, K = 4096), the cheap exact shortcuts do not apply: an agent's standardised state moves
3.6 units between decisions while half the gap between its nearest and second-nearest prototype is 0.08 (a
triangle-inequality cache never hits; the nearest prototype stays the same in 17 % of decisions), a ball of twice
the nearest distance round the nearest prototype holds 60 % of the prototypes, and a k-d tree over the principal
axes is 4 times slower than the scan. Nor does a matrix product over the room's states (``|q|^2 - 2 x . q`` by
MKL at one thread, then ``argmin``): 10.6 us per state a room at a time, 8.0 a decision of 20 rooms at a time, before
any recheck of near-ties (``python -m pedrl.bench.literal``, ``matmul_*``).

What does prune is a lower bound in the prototypes' principal axes: with ``y`` the point and ``q`` a prototype
rotated there, the squared distance is at least its sum over the leading columns, ``|y_S|^2 + |q_S|^2 - 2 y_S .
q_S``, one FMA per column and prototype. Leaves of 16 prototypes close in the first four principal coordinates are
visited pair by pair for all the agents of a room at once (a leaf stays in L1 while every agent reads it): columns
0-8 for every agent, 8-16 for the agents some lane of the leaf left within the threshold, 16-28 for those still
within it, then the scan's own float32 distance for each lane still within it. The threshold comes from a first
candidate: a greedy walk over each prototype's 16 nearest prototypes, from the agent's previous prototype, ends at
the nearest prototype in 57 % of decisions. Measured on those states: 40 % of the leaves reach the second pass, 8.6
% the third, 1.7 exact distances per agent; 4.3-4.6 us per state against the scan's 8.2-9.3 (1.9-2.1 times
faster; ``python -m pedrl.bench --only literal`` measures it on the states of a random walk), and a paper_vqql or
paper_it trial at one thread 1.8 times faster (0.79 s to 0.45 s, 20 rooms of 20 agents). The first pass over every
prototype (8 columns, about 2 us of the 4.3) is the floor of this method at numba's rate (about one FMA a cycle).

The answer is the scan's, to the bit: a prototype is passed over only when its bound exceeds the threshold ``T``
of the candidate's scan distance by the rounding margins of :data:`pedrl.vq.pruned_kernel.SLACK`, and the winner is
chosen among the candidate and the lanes within ``T`` by the scan's own float32 distance (the same summation,
column after column), ties to the lowest id. A point whose rotated norm is NaN or huge is left to the scan.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import torch

from pedrl._numba import cached_njit
from pedrl.vq.pruned_kernel import LANES, exact_distance, prepare_batch, search_batch

__all__ = [
    "GRAPH_BLOCK_BYTES",
    "GRAPH_MAX_PAIRS",
    "GRAPH_SIZE",
    "LEAD_COLUMNS",
    "BatchScratch",
    "PrunedArrays",
    "PrunedIndex",
    "batch_scratch",
    "graph_memory",
    "graph_size",
]

GRAPH_SIZE = 16
"""Nearest prototypes stored per prototype for the greedy walk to a first candidate (measured on literal states:
8 neighbours reach the nearest prototype in 43 % of decisions, 16 in 57 %, 32 in 69 % at twice the cost)."""
GRAPH_MAX_PAIRS = 2**32
"""Most prototype pairs whose distances build the nearest-prototype lists of an index (all its sets together: ``T
K^2``; about a minute and a half at one thread, 20 ns a pair). Past it the lists grow with ``K`` squared in time (200
000 prototypes: 14 minutes a set), so an index of more is built without them (:func:`graph_size`): the walk then starts
from the agent's previous prototype alone, the answer the same."""
GRAPH_BLOCK_BYTES = 256 << 20
"""Most bytes of the distance blocks (three ``rows x K`` float32 arrays) while the lists are built: memory linear in
``K``, 256 MiB whatever ``K`` is."""
LEAD_COLUMNS = 4
"""Leaves group prototypes by a k-d split of their first principal coordinates (4 or 8 measured alike)."""
_FAR_NORM = 1e30
"""Partial norm of the lanes that pad the last leaves: never within a threshold, never an id."""
_BATCH = 64
"""Points per batch of :meth:`PrunedIndex.search`."""


class PrunedIndex:
    """The literal encoding's search structures over ``T`` sets of ``K`` prototypes ``(T, K, d)`` (CPU).

    Each set's columns are ordered as :class:`pedrl.vq.tree.TreeIndex` orders them (decreasing variance), so that
    the exact distances are the scan's. :meth:`kernel_arrays` is what :func:`pedrl.vq.pruned_kernel.prepare_batch`
    and :func:`pedrl.vq.pruned_kernel.search_batch` read.

    Args:
        prototypes: ``(K, d)`` (one set) or ``(T, K, d)`` float32 on the CPU.
    """

    def __init__(self, prototypes: torch.Tensor) -> None:
        sets = prototypes.unsqueeze(0) if prototypes.ndim == 2 else prototypes
        if sets.ndim != 3 or sets.shape[1] == 0 or sets.device.type != "cpu":
            raise ValueError(f"prototypes must be (K, d) or (T, K, d) on the CPU with K > 0, got {tuple(sets.shape)}")
        self.num_sets, self.num_prototypes, self.dim = sets.shape
        values = sets.detach().to(torch.float64).numpy()
        self._columns = np.stack([np.argsort(-part.var(0), kind="stable") for part in values])  # as TreeIndex
        values = np.take_along_axis(values, self._columns[:, None, :], axis=2)
        width = -(-self.dim // 4) * 4  # rotated columns, padded to whole groups of four
        cuts = np.array([min(8, width), min(16, width), width], np.int64)
        parts = [_build_set(part, width, cuts) for part in values]
        graph = graph_size(self.num_sets, self.num_prototypes)
        self._arrays = PrunedArrays(
            cuts,
            np.stack([p["mean"] for p in parts]),
            np.stack([p["axes"] for p in parts]),
            *(np.ascontiguousarray(np.stack([p[name] for p in parts])) for name in _PASS_ARRAYS),
            np.stack([p["ids"] for p in parts]),
            np.stack([_padded_rows(part.astype(np.float32)) for part in values]),
            np.stack([_nearest_prototypes(part, graph) for part in values]),
            np.array([p["entry"] for p in parts], np.int64),
            np.array([p["norm_bound"] for p in parts]),
        )

    @property
    def columns(self) -> np.ndarray:
        """``(T, d)`` int64: the columns of set ``t`` in the order the search reads them (the tree's)."""
        return self._columns

    def kernel_arrays(self) -> PrunedArrays:
        """The ``index`` of :func:`pedrl.vq.pruned_kernel.prepare_batch` and ``search_batch``."""
        return self._arrays

    def search(
        self, points: torch.Tensor, sets: torch.Tensor | None = None, hints: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Nearest prototype of every point within its set: ``(ids (B,) int64, sq_dist (B,) float32)``, the scan's
        answer (lowest id on ties, id 0 for a NaN point).

        Args:
            points: ``(B, d)`` float32 on the CPU.
            sets: ``(B,)`` int64 in ``[0, T)`` (None: set 0).
            hints: ``(B,)`` int64 first guesses (any value; only speed depends on them), None: none.
        """
        if points.ndim != 2 or points.shape[1] != self.dim:
            raise ValueError(f"expected points (B, {self.dim}), got {tuple(points.shape)}")
        num = points.shape[0]
        sets = torch.zeros(num, dtype=torch.int64) if sets is None else sets
        if sets.shape != (num,) or (num and not (int(sets.min()) >= 0 and int(sets.max()) < self.num_sets)):
            raise ValueError(f"sets must be ({num},) ints in [0, {self.num_sets}), got {sets}")
        hints = torch.full((num,), -1, dtype=torch.int64) if hints is None else hints
        ids = np.empty(num, np.int64)
        sq_dist = np.empty(num, np.float32)
        _search_points(
            np.ascontiguousarray(points.detach().to(torch.float32).numpy()),
            np.ascontiguousarray(sets.numpy(), dtype=np.int64),
            np.ascontiguousarray(hints.numpy(), dtype=np.int64),
            self._columns,
            self._arrays,
            batch_scratch(_BATCH, self.dim),
            np.zeros(4, np.int64),
            ids,
            sq_dist,
        )
        return torch.from_numpy(ids), torch.from_numpy(sq_dist)


_PASS_ARRAYS = ("first_q", "first_n", "next_q", "next_n", "last_q", "last_n")


def _build_set(values: np.ndarray, width: int, cuts: np.ndarray) -> dict[str, Any]:
    """One set's principal axes, leaves and pass blocks (``values (K, d)`` float64, in the search's column order).

    A pass block holds ``-2 q`` for its columns, lane by lane (``first_q``: 32 lanes, a pair of leaves; the others
    16), and ``*_n`` the float32 sum of ``q^2`` over them; ``q`` is the float32 rotated prototype."""
    num, dim = values.shape
    mean = values.mean(0)
    centred = values - mean
    eigenvalues, vectors = np.linalg.eigh(centred.T @ centred / num)
    axes = np.zeros((dim, width))
    axes[:, :dim] = vectors[:, ::-1]  # decreasing variance
    rotated = (centred @ axes).astype(np.float32).astype(np.float64)
    leaves = _kd_leaves(rotated[:, :LEAD_COLUMNS])
    count = len(leaves) + len(leaves) % 2  # whole pairs
    ids = np.full((count, LANES), num, np.int64)
    blocks = np.zeros((count, LANES, width))
    real = np.zeros((count, LANES), bool)
    for index, members in enumerate(leaves):
        ids[index, : len(members)] = members
        blocks[index, : len(members)] = rotated[members]
        real[index, : len(members)] = True
    parts: dict[str, Any] = {"mean": mean, "axes": axes, "ids": ids}
    for name, first, stop in (("first", 0, cuts[0]), ("next", cuts[0], cuts[1]), ("last", cuts[1], cuts[2])):
        q = -2.0 * blocks[:, :, first:stop]  # (leaves, lanes, columns)
        norms = np.where(real, (blocks[:, :, first:stop] ** 2).sum(-1), _FAR_NORM)
        if name == "first":  # pairs of leaves: (pairs, columns, 32)
            q = q.reshape(count // 2, 2 * LANES, stop - first)
            norms = norms.reshape(count // 2, 2 * LANES)
        parts[f"{name}_q"] = q.transpose(0, 2, 1).astype(np.float32).ravel()
        parts[f"{name}_n"] = norms.astype(np.float32).ravel()
    parts["entry"] = int((centred**2).sum(1).argmin())
    parts["norm_bound"] = float((rotated**2).sum(1).max())
    return parts


def _kd_leaves(points: np.ndarray) -> list[np.ndarray]:
    """Leaves of at most ``LANES`` points: split at the median of the widest column (rounded down to whole leaves),
    recursively."""
    leaves: list[np.ndarray] = []
    pending = [np.arange(points.shape[0])]
    while pending:
        members = pending.pop()
        if len(members) <= LANES:
            leaves.append(members)
            continue
        part = points[members]
        split = int(np.argmax(part.max(0) - part.min(0)))
        ordered = members[np.argsort(part[:, split], kind="stable")]
        middle = max(len(ordered) // 2 // LANES * LANES, LANES)
        pending += [ordered[middle:], ordered[:middle]]  # the lower half is taken first
    return leaves


def _padded_rows(values: np.ndarray) -> np.ndarray:
    """``(K, d)`` float32 with zero columns up to a multiple of 8 (whole vectors for the greedy walk)."""
    rows = np.zeros((values.shape[0], -(-values.shape[1] // 8) * 8), np.float32)
    rows[:, : values.shape[1]] = values
    return rows


def graph_size(num_sets: int, num_prototypes: int) -> int:
    """Nearest prototypes listed per prototype in an index of ``num_sets`` sets of ``num_prototypes``:
    :data:`GRAPH_SIZE` (fewer for a small set), or 0 where building the lists would take more than
    :data:`GRAPH_MAX_PAIRS` pair distances."""
    if num_sets * num_prototypes * num_prototypes > GRAPH_MAX_PAIRS:
        return 0
    return max(0, min(GRAPH_SIZE, num_prototypes - 1))


def graph_memory(num_sets: int, num_prototypes: int) -> int:
    """Peak bytes of the nearest-prototype lists of an index of ``num_sets`` sets of ``num_prototypes``: the lists
    (int64) and, while one set's are built, its distance blocks (at most :data:`GRAPH_BLOCK_BYTES`)."""
    size = graph_size(num_sets, num_prototypes)
    if size == 0:
        return 0
    rows = _block_rows(num_prototypes)
    return 8 * num_sets * num_prototypes * size + 12 * rows * num_prototypes


def _block_rows(num_prototypes: int) -> int:
    """Prototypes whose distances to all the others one block of :func:`_nearest_prototypes` holds."""
    return max(1, min(1024, GRAPH_BLOCK_BYTES // (12 * num_prototypes)))


def _nearest_prototypes(values: np.ndarray, size: int) -> np.ndarray:
    """``(K, size)`` int64: each prototype's ``size`` nearest other prototypes (float32 distances; a guide only),
    in blocks of at most :data:`GRAPH_BLOCK_BYTES`."""
    if size == 0:
        return np.zeros((values.shape[0], 0), np.int64)
    points = torch.from_numpy(values).to(torch.float32)
    norms = (points * points).sum(1)
    rows = []
    for block in torch.split(torch.arange(points.shape[0]), _block_rows(points.shape[0])):
        distances = norms[block, None] + norms[None] - 2.0 * points[block] @ points.T
        distances[torch.arange(len(block)), block] = float("inf")
        rows.append(distances.topk(size, largest=False).indices)
    return torch.cat(rows).numpy().astype(np.int64)


class PrunedArrays(NamedTuple):
    """What :func:`pedrl.vq.pruned_kernel.prepare_batch` and ``search_batch`` read of a :class:`PrunedIndex`, per
    set ``t`` (:meth:`PrunedIndex.kernel_arrays`)."""

    cuts: np.ndarray
    """``(3,)`` int64: the rotated columns that end each of the three passes."""
    mean: np.ndarray
    """``(T, d)`` float64: each set's mean, subtracted before the rotation."""
    axes: np.ndarray
    """``(T, d, width)`` float64: each set's principal axes."""
    first_q: np.ndarray
    """The first pass's quantized leaf columns."""
    first_n: np.ndarray
    """The first pass's leaf norms."""
    next_q: np.ndarray
    """The second pass's quantized leaf columns."""
    next_n: np.ndarray
    """The second pass's leaf norms."""
    last_q: np.ndarray
    """The third pass's quantized leaf columns."""
    last_n: np.ndarray
    """The third pass's leaf norms."""
    ids: np.ndarray
    """``(T, leaves, 16)`` int64: the prototype of each leaf lane."""
    rows: np.ndarray
    """``(T, K, padded d)`` float32: the prototypes, for the exact distances."""
    graph: np.ndarray
    """``(T, K, GRAPH_SIZE)`` int64: each prototype's nearest others, for the walk from a hint."""
    entry: np.ndarray
    """``(T,)`` int64: where a walk without a hint starts."""
    norm_bound: np.ndarray
    """``(T,)`` float64: a bound of the rounding of the passes' norms."""


class BatchScratch(NamedTuple):
    """Scratch of a batch of points (:func:`batch_scratch`): the rotated points and their bounds, each point's best
    prototype so far, and the work lists of the passes."""

    y: np.ndarray
    norms: np.ndarray
    bounds: np.ndarray
    best: np.ndarray
    """``(B,)`` float32: each point's nearest distance found."""
    best_id: np.ndarray
    """``(B,)`` int64: its prototype; -1 for a point left to the scan (NaN or huge)."""
    acc: np.ndarray
    lists: np.ndarray
    rotated: np.ndarray
    padded: np.ndarray
    hints: np.ndarray
    """``(B,)`` int64: each point's first guess."""


@cached_njit(nogil=True)
def batch_scratch(agents, dim):
    """Scratch of a batch of up to ``agents`` points of ``dim`` features (:class:`BatchScratch`)."""
    width = (dim + 3) // 4 * 4
    return BatchScratch(
        np.empty((agents, width), np.float32),
        np.empty((agents, 3)),
        np.empty((agents, 3), np.float32),
        np.empty(agents, np.float32),
        np.empty(agents, np.int64),
        np.empty((agents, 2 * LANES), np.float32),
        np.empty((6, agents), np.int64),
        np.empty(width),
        np.empty((dim + 7) // 8 * 8, np.float32),
        np.empty(agents, np.int64),
    )


@cached_njit(nogil=True)
def _search_points(points, sets, hints, columns, index, scratch, counts, ids, sq_dist):
    """:meth:`PrunedIndex.search`: runs of points of one set, up to a batch at a time; a point the kernels leave
    to the scan is searched through every prototype by the scan's distance (NaN: id 0)."""
    batch = np.empty((scratch.y.shape[0], points.shape[1]), np.float32)
    rows = index.rows
    first = 0
    while first < points.shape[0]:
        t = sets[first]
        n = 0
        while first + n < points.shape[0] and sets[first + n] == t and n < batch.shape[0]:
            for c in range(points.shape[1]):
                batch[n, c] = points[first + n, columns[t, c]]
            scratch.hints[n] = hints[first + n]
            n += 1
        prepare_batch(batch, n, scratch.hints, t, index, scratch)
        search_batch(batch, n, t, index, scratch, counts)
        for a in range(n):
            if scratch.best_id[a] >= 0:
                ids[first + a], sq_dist[first + a] = scratch.best_id[a], scratch.best[a]
                continue
            best, best_id = np.float32(np.inf), rows.shape[1]
            for k in range(rows.shape[1]):
                value = exact_distance(batch[a], rows, t, k)
                if value < best:
                    best, best_id = value, k
            ids[first + a], sq_dist[first + a] = (best_id if best_id < rows.shape[1] else 0), best
        first += n

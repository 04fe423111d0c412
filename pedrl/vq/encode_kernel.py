"""Numba kernel of the encoding; its specification is :meth:`pedrl.vq.StateEncoder.prepare` followed by the k-d
tree's :func:`pedrl.vq.tree.search_point` (the nearest prototype), within stated tolerances
(``tests/trial/test_twins.py``): ``log1p`` is libm's, and the void fillings draw from the rooms' streams.

:func:`pack_encoder` lays out an encoder's quantizer (shared, per process, or IN-VQQL's union) as the flat arrays the
kernel reads.
"""

from __future__ import annotations

import weakref
from typing import Any, NamedTuple

import numpy as np
import torch

from pedrl._numba import cached_njit
from pedrl.sim.sensing import distance_indices
from pedrl.sim.streams import next_uniform
from pedrl.vq.encoder import StateEncoder
from pedrl.vq.pruned import BatchScratch, PrunedArrays, PrunedIndex, batch_scratch
from pedrl.vq.pruned_kernel import prepare_batch, search_batch
from pedrl.vq.quantizer import ProcessQuantizers, Quantizer, UnionQuantizer
from pedrl.vq.tree import _STACK, LEAF_SIZE, TreeArrays, TreeIndex, scan_point, search_tree

__all__ = [
    "EncodeBuffers",
    "EncoderArrays",
    "PackedEncoder",
    "draw_void",
    "encode_agent",
    "encode_buffers",
    "encode_room",
    "pack_encoder",
    "packed_sets",
]

_PI = np.float32(np.pi)
_TWO_PI = np.float32(2.0 * np.pi)
_PACKED: weakref.WeakKeyDictionary[Any, tuple[Any, PackedEncoder]] = weakref.WeakKeyDictionary()
"""Each quantizer's packed sets and tree, with the encoder settings and process count they were packed for."""


class EncoderArrays(NamedTuple):
    """An encoder's prototype sets as :func:`prepare_agent` reads them: ``T`` full-width sets (a plain quantizer is
    one, a union one per part), by :func:`pack_encoder`."""

    mean: np.ndarray
    """``(T, F)`` float32: each set's mean."""
    std: np.ndarray
    """``(T, F)`` float32: its scale (feature weights included)."""
    keep: np.ndarray
    """``(T, F)`` bool: the features a union's part reads (the others are 0 in its prototypes and points)."""
    offsets: np.ndarray
    """``(T,)`` int64: the first state id of each set."""
    columns: np.ndarray
    """``(T, F)`` int64: the tree's column order of each set."""
    distance_index: np.ndarray
    """``(D,)`` int64: the distance features (log-transformed with ``log_distances``)."""
    set_of: np.ndarray
    """``(P, k + 1)`` int64: the set of each process and number of sensed neighbours."""
    scan: bool
    """The sets are searched by a scan of their leaves (:attr:`pedrl.vq.tree.TreeIndex.scans`), in
    :func:`encode_room` by the pruned batch search."""


class PackedEncoder(NamedTuple):
    """What the encoding kernels read of an encoder's quantizer (:func:`pack_encoder`)."""

    arrays: EncoderArrays
    tree: TreeArrays
    pruned: PrunedArrays
    """:meth:`pedrl.vq.pruned.PrunedIndex.kernel_arrays` of the scanned sets (a stub for the others)."""


class EncodeBatch(NamedTuple):
    """Scratch of the batched search of a room's agents (:func:`_encode_batch`)."""

    scratch: BatchScratch
    points: np.ndarray
    sets: np.ndarray
    agents: np.ndarray
    hints: np.ndarray
    counts: np.ndarray
    """``(4,)`` int64: the search's work (:func:`pedrl.vq.pruned_kernel.search_batch`)."""


class EncodeBuffers(NamedTuple):
    """Scratch of :func:`encode_room` (:func:`encode_buffers`)."""

    x: np.ndarray
    point: np.ndarray
    nodes: np.ndarray
    sums: np.ndarray
    batch: EncodeBatch


@cached_njit(nogil=True)
def encode_agent(r, i, process, features, num_sensed, void, settings, encoder, tree, x, point, nodes, sums):
    """The state id of agent ``i`` of room ``r`` of learning ``process``: its features as the quantizer sees them
    (:func:`prepare_agent`) and the nearest prototype of its set plus the set's offset.

    ``encoder`` is :class:`EncoderArrays`; ``tree`` (:class:`pedrl.vq.tree.TreeArrays`) is searched by the tree or,
    with ``encoder.scan``, by a scan of its leaves (which :func:`encode_room` replaces by the pruned batch search: the
    same ids). ``x``, ``point`` ``(F,)``, ``nodes`` and ``sums`` are scratch.
    """
    t = prepare_agent(r, i, process, features, num_sensed, void, settings, encoder, x, point)
    if encoder.scan:
        found, _ = scan_point(point, t, tree.prototypes, tree.ids_of, sums)
    else:
        found, _ = search_tree(point, t, tree, nodes, sums)
    return found + encoder.offsets[t]


@cached_njit(nogil=True)
def prepare_agent(r, i, process, features, num_sensed, void, settings, encoder, x, point):
    """Agent ``i``'s features as the quantizer sees them (:meth:`pedrl.vq.StateEncoder.prepare`: void slots filled
    from its draws ``void[r, i]``, distances transformed), standardised by the set of its process and neighbours, in
    ``point`` in the set's column order; returns the set ``t``.

    ``settings`` is :class:`pedrl.vq.encoder.KernelEncoding`; a union's part reads only the features it ``keep``s
    (the others are 0 in its prototypes and in the point).
    """
    k, max_distance, max_speed = settings.num_neighbours, settings.max_distance, settings.max_speed
    min_distance, random_void, log_distances = settings.min_void_distance, settings.random_void, settings.log_distances
    mean, std, keep, columns, set_of = encoder.mean, encoder.std, encoder.keep, encoder.columns, encoder.set_of
    distance_index = encoder.distance_index
    sensed = num_sensed[r, i]
    for f in range(features.shape[2]):
        x[f] = features[r, i, f]
    if random_void and sensed < k:  # fill_void_neighbours: sorted uniforms from exponential spacings
        low = x[4 + 3 * (sensed - 1)] if sensed > 0 else min_distance
        span = max(max_distance - low, np.float32(0.0))
        total = -np.log1p(-void[r, i, k])
        for j in range(sensed, k):  # each spacing once, in point[j] (free until the standardisation below)
            point[j] = -np.log1p(-void[r, i, j])
            total += point[j]
        partial = np.float32(0.0)
        for j in range(sensed, k):
            partial += point[j]
            x[3 + 3 * j] = void[r, i, 2 * k + 1 + j] * np.float32(4.0 * max_speed) - np.float32(2.0 * max_speed)
            x[4 + 3 * j] = low + partial / total * span
            angle = _PI - _TWO_PI * void[r, i, k + 1 + j]
            x[5 + 3 * j] = _PI if angle <= -_PI else angle
    if log_distances:
        for d in distance_index:
            x[d] = np.log1p(x[d])
    t = set_of[process, min(sensed, k)]
    for c in range(point.shape[0]):
        column = columns[t, c]
        point[c] = (x[column] - mean[t, column]) / std[t, column] if keep[t, column] else np.float32(0.0)
    return t


@cached_njit(nogil=True)
def encode_room(r, process, present, base_rows, rows, features, num_sensed, void, settings, encoder, tree, pruned,
                buffers):  # fmt: skip
    """``rows[r]``: every ``present`` agent's flat table row (its table's first row plus its state id); the others
    get their table's first row. Where the sets are scanned (``encoder``'s ``scan``), the room's agents are searched
    together by :mod:`pedrl.vq.pruned_kernel` (the scan's ids), each from the prototype of its row before the call
    (its previous state in the fused trial; any value is only a guess)."""
    x, point, nodes, sums = buffers.x, buffers.point, buffers.nodes, buffers.sums
    if encoder.scan:
        _encode_batch(r, process, present, base_rows, rows, features, num_sensed, void, settings, encoder, tree, pruned,
                      x, sums, buffers.batch)  # fmt: skip
        return
    for i in range(rows.shape[1]):
        rows[r, i] = base_rows[r, i]
        if present[r, i]:
            rows[r, i] += encode_agent(r, i, process, features, num_sensed, void, settings, encoder, tree, x, point,
                                       nodes, sums)  # fmt: skip


@cached_njit(nogil=True)
def _encode_batch(r, process, present, base_rows, rows, features, num_sensed, void, settings, encoder, tree, pruned,
                  x, sums, batch):  # fmt: skip
    """:func:`encode_room` by :func:`pedrl.vq.pruned_kernel.search_batch`: the present agents grouped by prototype
    set (in the order of their first member), each group searched at once; a point the batch leaves to the scan
    (NaN or huge) is scanned."""
    scratch, points, sets, agents, hints = batch.scratch, batch.points, batch.sets, batch.agents, batch.hints
    offsets = encoder.offsets
    n = 0
    for i in range(rows.shape[1]):
        if present[r, i]:
            sets[n] = prepare_agent(r, i, process, features, num_sensed, void, settings, encoder, x, points[n])
            hints[n] = rows[r, i] - base_rows[r, i] - offsets[sets[n]]
            agents[n] = i
            n += 1
        rows[r, i] = base_rows[r, i]
    first = 0
    while first < n:
        t = sets[first]
        stop = first
        for m in range(first, n):  # the members of set t moved up to first .. stop
            if sets[m] == t:
                _swap(points, sets, agents, hints, m, stop)
                stop += 1
        group = points[first:stop]
        prepare_batch(group, stop - first, hints[first:stop], t, pruned, scratch)
        search_batch(group, stop - first, t, pruned, scratch, batch.counts)
        for m in range(stop - first):
            found = scratch.best_id[m]
            if found < 0:
                found, _ = scan_point(group[m], t, tree.prototypes, tree.ids_of, sums)
            rows[r, agents[first + m]] += found + offsets[t]
        first = stop


@cached_njit(nogil=True, inline="always")
def _swap(points, sets, agents, hints, a, b):
    """Exchange members ``a`` and ``b`` of a batch."""
    if a != b:
        for c in range(points.shape[1]):
            points[a, c], points[b, c] = points[b, c], points[a, c]
        sets[a], sets[b] = sets[b], sets[a]
        agents[a], agents[b] = agents[b], agents[a]
        hints[a], hints[b] = hints[b], hints[a]


@cached_njit(nogil=True)
def encode_buffers(agents, num_features):
    """Scratch of :func:`encode_room` for rooms of up to ``agents`` agents (:class:`EncodeBuffers`)."""
    batch = EncodeBatch(
        batch_scratch(agents, num_features),
        np.empty((agents, num_features), np.float32),
        np.empty(agents, np.int64),
        np.empty(agents, np.int64),
        np.empty(agents, np.int64),
        np.zeros(4, np.int64),
    )
    return EncodeBuffers(np.empty(num_features, np.float32), np.empty(num_features, np.float32),
                         np.empty(_STACK, np.int64), np.empty(LEAF_SIZE, np.float32), batch)  # fmt: skip


@cached_njit(nogil=True)
def draw_void(r, void, streams):
    for i in range(void.shape[1]):
        for j in range(void.shape[2]):
            void[r, i, j] = next_uniform(streams, r)


def pack_encoder(encoder: StateEncoder, processes: int) -> PackedEncoder:
    """What the encoding kernels read of ``encoder``'s quantizer, built once per quantizer (and again if it is used
    with other settings or processes)."""
    quantizer, key = encoder.quantizer, (encoder.settings, processes)
    if quantizer not in _PACKED or _PACKED[quantizer][0] != key:
        _PACKED[quantizer] = (key, _pack(encoder, processes))
    return _PACKED[quantizer][1]


def packed_sets(quantizer: Any) -> tuple[int, int]:
    """``(T, K)``: the prototype sets :func:`pack_encoder` lays out for ``quantizer`` and the size they are padded
    to, without packing them (what the memory checks count: :func:`pedrl.vq.pruned.graph_memory`). A quantizer it
    does not pack (a factored one: its own kernels) counts as one set of one prototype."""
    if isinstance(quantizer, Quantizer):
        return 1, quantizer.num_prototypes
    if isinstance(quantizer, UnionQuantizer):
        return len(quantizer.num_sensed), max(quantizer.part_sizes.values())
    if isinstance(quantizer, ProcessQuantizers):
        counts = [packed_sets(part) for part in quantizer.parts]
        return sum(count for count, _ in counts), max(size for _, size in counts)
    return 1, 1


def _pack(encoder: StateEncoder, processes: int) -> PackedEncoder:
    """Every prototype set as a full-width set: a plain quantizer is one set, a union one set per part (its
    features kept, the others 0), padded to the largest set with copies of its first prototype (a tie goes to the
    lower id, so a copy never wins)."""
    settings = encoder.settings
    width, k = settings.num_features, settings.num_neighbours
    sets: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, int]] = []

    def add(part: Quantizer | UnionQuantizer) -> list[int]:
        """The sets of ``part``, appended; returns the set of each number of sensed neighbours ``0 .. k``."""
        if isinstance(part, Quantizer):
            sets.append((part.mean, part.std, torch.ones(width, dtype=torch.bool), part.prototypes, 0))
            return [len(sets) - 1] * (k + 1)
        first = len(sets)
        for sensed in part.num_sensed:
            index, sub = part.part(sensed)
            mean, std, keep = torch.zeros(width), torch.ones(width), torch.zeros(width, dtype=torch.bool)
            mean[index], std[index], keep[index] = sub.mean, sub.std, True
            prototypes = torch.zeros(sub.num_prototypes, width)
            prototypes[:, index] = sub.prototypes
            sets.append((mean, std, keep, prototypes, part.offsets[sensed]))
        return (first + part.part_of(torch.arange(k + 1))).tolist()

    parts = quantizer.parts if isinstance(quantizer := encoder.quantizer, ProcessQuantizers) else None
    set_of = [add(part) for part in parts] if parts is not None else [add(quantizer)] * processes
    means, stds, keeps, prototype_sets, offsets = zip(*sets, strict=True)
    size = max(prototypes.shape[0] for prototypes in prototype_sets)
    padded = [torch.cat((p, p[:1].expand(size - p.shape[0], -1))) for p in prototype_sets]
    tree = TreeIndex(torch.stack(padded).float())
    # the scanned sets (the literal encoding) are searched by the pruned batch search instead; others carry a stub
    pruned = PrunedIndex(torch.stack(padded).float() if tree.scans else torch.zeros(1, 1, width))
    arrays = EncoderArrays(
        torch.stack(means).float().numpy(),
        torch.stack(stds).float().numpy(),
        torch.stack(keeps).numpy(),
        np.array(offsets, np.int64),
        np.ascontiguousarray(tree.columns),
        distance_indices(k, settings.num_walls).numpy(),
        np.array(set_of, np.int64),
        tree.scans,
    )
    return PackedEncoder(arrays, tree.kernel_arrays(), pruned.kernel_arrays())

"""Numba kernel of the encoding; its specification is :meth:`pedrl.vq.StateEncoder.prepare` followed by the k-d
tree's :func:`pedrl.vq.tree.search_point` (the nearest prototype), within stated tolerances
(``tests/trial/test_twins.py``): ``log1p`` is libm's, and the void fillings draw from the rooms' streams.

:func:`pack_encoder` lays out an encoder's quantizer (shared, per process, or IN-VQQL's union) as the flat arrays the
kernel reads.
"""

from __future__ import annotations

import weakref
from typing import Any

import numpy as np
import torch

from pedrl._numba import cached_njit
from pedrl.sim.sensing import distance_indices
from pedrl.sim.streams import next_uniform
from pedrl.vq.encoder import StateEncoder
from pedrl.vq.pruned import PrunedIndex, batch_scratch
from pedrl.vq.pruned_kernel import prepare_batch, search_batch
from pedrl.vq.quantizer import ProcessQuantizers, Quantizer, UnionQuantizer
from pedrl.vq.tree import _STACK, LEAF_SIZE, TreeIndex, scan_point, search_point

__all__ = ["draw_void", "encode_agent", "encode_buffers", "encode_room", "pack_encoder"]

_PI = np.float32(np.pi)
_TWO_PI = np.float32(2.0 * np.pi)
_PACKED: weakref.WeakKeyDictionary[Any, tuple[Any, tuple[Any, Any]]] = weakref.WeakKeyDictionary()
"""Each quantizer's packed sets and tree, with the encoder settings and process count they were packed for."""


@cached_njit(nogil=True)
def encode_agent(r, i, process, features, num_sensed, void, settings, encoder, tree, x, point, nodes, sums):
    """The state id of agent ``i`` of room ``r`` of learning ``process``: its features as the quantizer sees them
    (:func:`prepare_agent`) and the nearest prototype of its set plus the set's offset.

    ``encoder`` is ``(mean (T, F), std (T, F), keep (T, F), offsets (T,), columns (T, F), distance_index (D,),
    set_of (P, k + 1), scan)``; ``tree`` is :meth:`pedrl.vq.tree.TreeIndex.kernel_arrays`, searched by the tree or,
    with ``scan`` (:attr:`pedrl.vq.tree.TreeIndex.scans`), by a scan of its leaves, followed by
    :meth:`pedrl.vq.pruned.PrunedIndex.kernel_arrays`, which :func:`encode_room` searches instead of the scan (the
    same ids). ``x``, ``point`` ``(F,)``, ``nodes`` and ``sums`` are scratch.
    """
    offsets, scan = encoder[3], encoder[7]
    t = prepare_agent(r, i, process, features, num_sensed, void, settings, encoder, x, point)
    (prototypes, ids_of, leaf_of, left, right, split_dim, split_value, low_box, high_box) = tree[:9]
    if scan:
        found, _ = scan_point(point, t, prototypes, ids_of, sums)
    else:
        found, _ = search_point(
            point, t, prototypes, ids_of, leaf_of, left, right, split_dim, split_value, low_box, high_box, nodes, sums
        )
    return found + offsets[t]


@cached_njit(nogil=True)
def prepare_agent(r, i, process, features, num_sensed, void, settings, encoder, x, point):
    """Agent ``i``'s features as the quantizer sees them (:meth:`pedrl.vq.StateEncoder.prepare`: void slots filled
    from its draws ``void[r, i]``, distances transformed), standardised by the set of its process and neighbours, in
    ``point`` in the set's column order; returns the set ``t``.

    ``settings`` is ``(k, max_distance, max_speed, min_distance, random_void, log_distances)``; a union's part reads
    only the features it ``keep``s (the others are 0 in its prototypes and in the point).
    """
    k, max_distance, max_speed, min_distance, random_void, log_distances = settings
    mean, std, keep, _, columns, distance_index, set_of, _ = encoder
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
def encode_room(r, process, present, base_rows, rows, features, num_sensed, void, settings, encoder, tree, buffers):
    """``rows[r]``: every ``present`` agent's flat table row (its table's first row plus its state id); the others
    get their table's first row. Where the sets are scanned (``encoder``'s ``scan``), the room's agents are searched
    together by :mod:`pedrl.vq.pruned_kernel` (the scan's ids), each from the prototype of its row before the call
    (its previous state in the fused trial; any value is only a guess)."""
    x, point, nodes, sums, batch = buffers
    if encoder[7]:
        _encode_batch(r, process, present, base_rows, rows, features, num_sensed, void, settings, encoder, tree, x,
                      sums, batch)  # fmt: skip
        return
    for i in range(rows.shape[1]):
        rows[r, i] = base_rows[r, i]
        if present[r, i]:
            rows[r, i] += encode_agent(r, i, process, features, num_sensed, void, settings, encoder, tree, x, point,
                                       nodes, sums)  # fmt: skip


@cached_njit(nogil=True)
def _encode_batch(r, process, present, base_rows, rows, features, num_sensed, void, settings, encoder, tree, x, sums,
                  batch):  # fmt: skip
    """:func:`encode_room` by :func:`pedrl.vq.pruned_kernel.search_batch`: the present agents grouped by prototype
    set (in the order of their first member), each group searched at once; a point the batch leaves to the scan
    (NaN or huge) is scanned."""
    scratch, points, sets, agents, hints, counts = batch
    offsets, pruned = encoder[3], tree[9:]
    prototypes, ids_of = tree[0], tree[1]
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
        search_batch(group, stop - first, t, pruned, scratch, counts)
        for m in range(stop - first):
            found = scratch[4][m]
            if found < 0:
                found, _ = scan_point(group[m], t, prototypes, ids_of, sums)
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
    """Scratch of :func:`encode_room` for rooms of up to ``agents`` agents: ``(x, point, nodes, sums, batch)``, where
    ``batch`` is ``(scratch, points, sets, agents, hints, counts)`` of the batched search (``counts`` adds its work:
    leaf-agent visits of its three passes and exact distances, see :func:`pedrl.vq.pruned_kernel.search_batch`)."""
    batch = (
        batch_scratch(agents, num_features),
        np.empty((agents, num_features), np.float32),
        np.empty(agents, np.int64),
        np.empty(agents, np.int64),
        np.empty(agents, np.int64),
        np.zeros(4, np.int64),
    )
    return (np.empty(num_features, np.float32), np.empty(num_features, np.float32), np.empty(_STACK, np.int64),
            np.empty(LEAF_SIZE, np.float32), batch)  # fmt: skip


@cached_njit(nogil=True)
def draw_void(r, void, streams):
    for i in range(void.shape[1]):
        for j in range(void.shape[2]):
            void[r, i, j] = next_uniform(streams, r)


def pack_encoder(encoder: StateEncoder, processes: int) -> tuple[Any, Any]:
    """``(encoder, tree)`` tuples of :func:`encode_agent` for ``encoder``'s quantizer,
    built once per quantizer (and again if it is used with other settings or processes)."""
    quantizer, key = encoder.quantizer, (encoder.settings, processes)
    if quantizer not in _PACKED or _PACKED[quantizer][0] != key:
        _PACKED[quantizer] = (key, _pack(encoder, processes))
    return _PACKED[quantizer][1]


def _pack(encoder: StateEncoder, processes: int) -> tuple[Any, Any]:
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
    size = max(s[3].shape[0] for s in sets)
    padded = [torch.cat((s[3], s[3][:1].expand(size - s[3].shape[0], -1))) for s in sets]
    tree = TreeIndex(torch.stack(padded).float())
    # the scanned sets (the literal encoding) are searched by the pruned batch search instead; others carry a stub
    pruned = PrunedIndex(torch.stack(padded).float() if tree.scans else torch.zeros(1, 1, width))
    packed = (
        torch.stack([s[0] for s in sets]).float().numpy(),
        torch.stack([s[1] for s in sets]).float().numpy(),
        torch.stack([s[2] for s in sets]).numpy(),
        np.array([s[4] for s in sets], np.int64),
        np.ascontiguousarray(tree.columns),
        distance_indices(k, settings.num_walls).numpy(),
        np.array(set_of, np.int64),
        tree.scans,
    )
    return packed, tree.kernel_arrays() + pruned.kernel_arrays()

"""Numba kernel of the factored encoding; its specification is :meth:`pedrl.vq.StateEncoder.prepare` (distances
transformed; void slots are not read) followed by :meth:`pedrl.vq.FactoredQuantizer.encode`, within the tolerances of
``tests/trial/test_twins.py``: ``log1p`` is libm's, and the nearest prototype is found by a scan of exact squared
distances (lowest id on ties), where the torch quantizer uses its k-d tree or matrix search, so a state within
float32 rounding of two prototypes may get either.

The factors' quantizers are small (tens to hundreds of prototypes over 2 or 3 features) and each is scanned whole:
``K_own + k K_nb + w K_wall`` distances an agent-decision (2,112 for experiment=main_factored).
:func:`pack_factored` lays them out as :class:`FactoredArrays`; a plain encoder gets a stub of no slots, so that one
compiled fused trial serves both.
"""

from __future__ import annotations

import weakref
from typing import Any, NamedTuple

import numpy as np
import torch

from pedrl._numba import cached_njit
from pedrl.sim.sensing import FEATURES_PER_NEIGHBOUR, FEATURES_PER_WALL, NUM_OWN_FEATURES, distance_indices
from pedrl.vq.encoder import StateEncoder
from pedrl.vq.factored import FACTORS, FactoredQuantizer

__all__ = ["FactoredArrays", "encode_factored_room", "pack_factored"]

_OWN, _NEIGHBOUR, _WALL = (FACTORS.index(name) for name in ("own", "neighbour", "wall"))
"""Each factor's row in the :class:`FactoredArrays` (their order in ``FACTORS``)."""

_WIDTH = max(NUM_OWN_FEATURES, FEATURES_PER_NEIGHBOUR, FEATURES_PER_WALL)
_PACKED: weakref.WeakKeyDictionary[Any, FactoredArrays] = weakref.WeakKeyDictionary()


class FactoredArrays(NamedTuple):
    """A factored quantizer as :func:`encode_factored_room` reads it (:func:`pack_factored`); factor ``t`` is own (0),
    neighbour (1) or wall (2)."""

    mean: np.ndarray
    """``(3, 3)`` float32: each factor's feature means (a wall's third column unused)."""
    std: np.ndarray
    """``(3, 3)`` float32: its scales (weights included)."""
    prototypes: np.ndarray
    """``(3, K, 3)`` float32: its prototypes, padded to the largest K."""
    sizes: np.ndarray
    """``(3,)`` int64: each factor's K (0: the factor is not read)."""
    offsets: np.ndarray
    """``(3,)`` int64: its first id."""
    distance_index: np.ndarray
    """``(D,)`` int64: the distance features (log-transformed with ``log_distances``)."""
    num_slots: np.int64
    """M, the ids of a state (0: the encoder is not factored)."""


def pack_factored(encoder: StateEncoder | None) -> FactoredArrays:
    """``encoder``'s factored quantizer as the kernel reads it (built once per quantizer), or a stub of no slots for
    any other encoder (or None)."""
    quantizer = None if encoder is None else encoder.quantizer
    if not isinstance(quantizer, FactoredQuantizer):
        return _stub()
    if quantizer not in _PACKED:
        _PACKED[quantizer] = _pack(quantizer, encoder.settings)
    return _PACKED[quantizer]


def _stub() -> FactoredArrays:
    return FactoredArrays(
        np.zeros((3, _WIDTH), np.float32),
        np.ones((3, _WIDTH), np.float32),
        np.zeros((3, 1, _WIDTH), np.float32),
        np.zeros(3, np.int64),
        np.zeros(3, np.int64),
        np.zeros(0, np.int64),
        np.int64(0),
    )


def _pack(quantizer: FactoredQuantizer, settings: Any) -> FactoredArrays:
    parts, offsets = quantizer.parts, quantizer.offsets
    size = max(part.num_prototypes for part in parts.values())
    mean, std = np.zeros((3, _WIDTH), np.float32), np.ones((3, _WIDTH), np.float32)
    prototypes = np.zeros((3, size, _WIDTH), np.float32)
    sizes, firsts = np.zeros(3, np.int64), np.zeros(3, np.int64)
    for t, name in enumerate(FACTORS):
        if name in parts:
            part, dim = parts[name].to("cpu"), parts[name].dim
            mean[t, :dim], std[t, :dim] = part.mean.numpy(), part.std.numpy()
            prototypes[t, : part.num_prototypes, :dim] = part.prototypes.numpy()
            sizes[t], firsts[t] = part.num_prototypes, offsets[name]
    index = distance_indices(settings.num_neighbours, settings.num_walls).numpy()
    return FactoredArrays(mean, std, prototypes, sizes, firsts, index.astype(np.int64), np.int64(quantizer.num_slots))


@cached_njit(nogil=True, inline="always")
def _nearest(x, first, dim, t, arrays):
    """The id (with the factor's offset) of the prototype of factor ``t`` nearest to ``x[first : first + dim]``
    standardised: the lowest id of the least squared distance. The point is standardised once; a factor of 2
    features reads a third of 0 against its prototypes' padding of 0, which adds exactly 0."""
    mean, std, prototypes = arrays.mean, arrays.std, arrays.prototypes
    q0 = (x[first] - mean[t, 0]) / std[t, 0]
    q1 = (x[first + 1] - mean[t, 1]) / std[t, 1]
    q2 = (x[first + 2] - mean[t, 2]) / std[t, 2] if dim > 2 else np.float32(0.0)
    best, found = np.float32(np.inf), 0
    for c in range(arrays.sizes[t]):
        d0, d1, d2 = q0 - prototypes[t, c, 0], q1 - prototypes[t, c, 1], q2 - prototypes[t, c, 2]
        distance = d0 * d0 + d1 * d1 + d2 * d2
        if distance < best:
            best, found = distance, c
    return found + arrays.offsets[t]


@cached_njit(nogil=True)
def encode_factored_room(r, present, base_rows, slots, features, num_sensed, settings, arrays, x):
    """``slots[r]`` ``(N, M)``: every ``present`` agent's row set (its table's first row plus each slot's id; -1 for
    a neighbour slot beyond the sensed ones), the others an empty set (all -1). ``settings`` is
    :class:`pedrl.vq.encoder.KernelEncoding`, ``arrays`` :class:`FactoredArrays`; ``x (F,)`` is scratch."""
    k = settings.num_neighbours
    w = (features.shape[2] - NUM_OWN_FEATURES - FEATURES_PER_NEIGHBOUR * k) // FEATURES_PER_WALL
    for i in range(slots.shape[1]):
        if not present[r, i]:
            for m in range(slots.shape[2]):
                slots[r, i, m] = -1
            continue
        for f in range(features.shape[2]):
            x[f] = features[r, i, f]
        if settings.log_distances:
            for d in arrays.distance_index:
                x[d] = np.log1p(x[d])
        base = base_rows[r, i]
        slots[r, i, 0] = base + _nearest(x, 0, NUM_OWN_FEATURES, _OWN, arrays)
        m = 1
        if arrays.sizes[_NEIGHBOUR] > 0:
            for j in range(k):
                first = NUM_OWN_FEATURES + FEATURES_PER_NEIGHBOUR * j
                read = j < num_sensed[r, i]
                slots[r, i, m] = base + _nearest(x, first, FEATURES_PER_NEIGHBOUR, _NEIGHBOUR, arrays) if read else -1
                m += 1
        if arrays.sizes[_WALL] > 0:
            for j in range(w):
                first = NUM_OWN_FEATURES + FEATURES_PER_NEIGHBOUR * k + FEATURES_PER_WALL * j
                slots[r, i, m] = base + _nearest(x, first, FEATURES_PER_WALL, _WALL, arrays)
                m += 1


def encode_factored(encoder: StateEncoder, features: torch.Tensor, num_sensed: torch.Tensor) -> torch.Tensor:
    """The kernel's id sets ``(R * N, M)`` of observations ``features (R, N, F)`` (every agent present, table rows
    from 0): what the tests hold against :meth:`pedrl.vq.StateEncoder.encode`."""
    rooms, agents, width = features.shape
    arrays = pack_factored(encoder)
    slots = np.empty((rooms, agents, int(arrays.num_slots)), np.int64)
    present = np.ones((rooms, agents), np.bool_)
    base = np.zeros((rooms, agents), np.int64)
    feats, sensed = features.contiguous().numpy(), num_sensed.to(torch.int64).contiguous().numpy()
    x = np.empty(width, np.float32)
    for r in range(rooms):
        encode_factored_room(r, present, base, slots, feats, sensed, encoder.settings.kernel(), arrays, x)
    return torch.from_numpy(slots.reshape(rooms * agents, -1))

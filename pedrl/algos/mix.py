"""Training across scenarios (``mix``): rooms of other geometries that take turns with a phase's own room.

Each room is its own batched :class:`pedrl.sim.RoomEnv` of the trainer's ``P E`` replicas, so that ``step`` stays
one tensor program over one geometry; the rooms take turns trial by trial (:func:`room_of_trial`), learning into
the same tables over the same quantizer, whose states are gathered in every room (:func:`merge_gathered`).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from pedrl.trial.rollout import Gathered


def room_of_trial(trial: int, trials: int, rooms: int) -> int:
    """Index of the room that plays trial ``trial`` of a phase of ``trials`` trials among ``rooms`` rooms (0: the
    phase's own). The rooms take turns, and the phase's own room plays its last trial, whose figures are the
    phase's final ones."""
    return (trial - trials + 1) % rooms


def merge_gathered(parts: Sequence[Gathered]) -> Gathered:
    """The states gathered in several rooms as one set; its success rate is the rooms' mean."""
    if len(parts) == 1:
        return parts[0]
    return Gathered(
        torch.cat([part.states for part in parts]),
        torch.cat([part.num_sensed for part in parts]),
        torch.cat([part.process for part in parts]),
        sum(part.success_rate for part in parts) / len(parts),
    )

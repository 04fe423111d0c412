"""Numba kernel of the greedy walker; its specification is :class:`pedrl.sim.controllers.GreedyDoorController`, whose
choice it makes from the same feature (the heading relative to the line to the goal), with its random actions drawn
from a room's stream."""

from __future__ import annotations

import numpy as np

from pedrl._numba import cached_njit
from pedrl.sim.streams import next_uniform

__all__ = ["greedy_action"]

_PI = np.float32(np.pi)
_TWO_PI = np.float32(2.0 * np.pi)


@cached_njit(nogil=True, inline="always")
def greedy_action(angle, speed_changes, turn_changes, goal_frame, epsilon, streams, r):
    """The greedy walker's action for a heading ``angle`` (rad) relative to the line to its goal: the largest speed
    index and the turn that leaves the smallest angle to that line (in the ``goal`` frame the smallest offset); a
    uniform random action with probability ``epsilon``."""
    num_turns = turn_changes.shape[0]
    num_actions = speed_changes.shape[0] * num_turns
    if epsilon > 0 and next_uniform(streams, r) < epsilon:
        return min(np.int64(next_uniform(streams, r) * np.float32(num_actions)), num_actions - 1)
    turn, best = 0, np.float32(np.inf)
    for t in range(num_turns):
        residual = turn_changes[t] if goal_frame else (angle + turn_changes[t] + _PI) % _TWO_PI - _PI
        if abs(residual) < best:
            turn, best = t, abs(residual)
    return np.int64(np.argmax(speed_changes)) * num_turns + turn

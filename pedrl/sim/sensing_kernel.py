"""Numba kernel of the sensing; its specification is :func:`pedrl.sim.sensing.observe`, within stated tolerances.

``atan2``/``hypot`` are libm's, not torch's vector routines: features agree with the torch reference to about 1e-6
relative (``tests/trial/test_twins.py`` states and checks the tolerances).
"""

from __future__ import annotations

import numpy as np

from pedrl._numba import cached_njit

__all__ = ["sense_room", "wrap", "wrap_difference"]

_PI = np.float32(np.pi)
_TWO_PI = np.float32(2.0 * np.pi)


@cached_njit(nogil=True, inline="always")
def wrap(angle):
    """``pedrl.sim.geometry.wrap_angle`` of one float32 angle: into ``(-pi, pi]``."""
    wrapped = _PI - (_PI - angle) % _TWO_PI
    return _PI if wrapped <= -_PI else wrapped


@cached_njit(nogil=True, inline="always")
def wrap_difference(angle):
    """:func:`_wrap` of the difference of two angles in ``[-pi, pi]`` (``atan2``, wrapped headings): one turn added
    or taken away suffices (with the nearest chosen by squared distance, this took sensing from 0.67 to 0.47 us);
    anything else (a heading placed by hand outside that range) takes the remainder."""
    if angle > _PI:
        angle -= _TWO_PI
    elif angle <= -_PI:
        angle += _TWO_PI
    if angle > _PI or angle <= -_PI:
        return wrap(angle)
    return angle


@cached_njit(nogil=True, inline="always")
def _wall_offset(x, y, s, walls):
    """Closest point of wall ``s`` minus ``(x, y)`` (``Geometry.wall_offsets``): clamped to the box of an aligned
    wall, else projected and clamped to the segment."""
    starts, directions, inverse, low, high = walls.starts, walls.directions, walls.inverse, walls.low, walls.high
    if walls.aligned[s]:
        return min(max(x, low[s, 0]), high[s, 0]) - x, min(max(y, low[s, 1]), high[s, 1]) - y
    along = ((x - starts[s, 0]) * directions[s, 0] + (y - starts[s, 1]) * directions[s, 1]) * inverse[s]
    along = min(max(along, np.float32(0.0)), np.float32(1.0))
    return starts[s, 0] + along * directions[s, 0] - x, starts[s, 1] + along * directions[s, 1] - y


@cached_njit(nogil=True, inline="always")
def _insert(values, index, count, size, value, item):
    """Insert ``value`` (of ``item``) into the ascending ``values[:count]`` kept to ``size`` entries (a later equal
    value goes after); returns the new count."""
    if size == 0:
        return count
    if count < size:
        place = count
        count += 1
    elif value < values[size - 1]:
        place = size - 1
    else:
        return count
    while place > 0 and values[place - 1] > value:
        values[place] = values[place - 1]
        index[place] = index[place - 1]
        place -= 1
    values[place] = value
    index[place] = item
    return count


@cached_njit(nogil=True)
def sense_room(r, state, present, walls, k, w, features, num_sensed, distances, indices):
    """The deictic states of room ``r``'s ``present`` agents (:func:`pedrl.sim.sensing.observe` with observers and
    sensed both ``present``) into ``features[r]`` and ``num_sensed[r]``; the others get 0.

    ``walls`` is :class:`pedrl.sim.geometry.Walls`, ``state`` :class:`pedrl.sim.state.KernelState`; ``k`` and ``w``
    the neighbour and wall slots. ``distances`` float32 and ``indices`` int64 ``(2, max(N, S))`` are scratch.
    """
    positions, velocities, headings, speeds = state.positions, state.velocities, state.headings, state.speeds
    goals = state.targets
    num_agents = positions.shape[1]
    slots = min(k, num_agents - 1)
    near_d, wall_d, near_j, wall_s = distances[0], distances[1], indices[0], indices[1]
    walls_start = 3 + 3 * k
    for i in range(num_agents):
        features[r, i, :] = np.float32(0.0)
        num_sensed[r, i] = 0
        if not present[r, i]:
            continue
        x, y = positions[r, i, 0], positions[r, i, 1]
        to_x, to_y = goals[r, i, 0] - x, goals[r, i, 1] - y
        phi = np.arctan2(to_y, to_x)
        features[r, i, 0] = speeds[r, i]
        features[r, i, 1] = wrap_difference(headings[r, i] - phi)
        features[r, i, 2] = np.hypot(to_x, to_y)
        count = 0  # the `slots` nearest present others, nearest first, chosen by squared distance
        for j in range(num_agents):
            if j != i and present[r, j] and slots > 0:
                gap_x, gap_y = positions[r, j, 0] - x, positions[r, j, 1] - y
                count = _insert(near_d, near_j, count, slots, gap_x * gap_x + gap_y * gap_y, j)
        num_sensed[r, i] = count
        for slot in range(count):
            j = near_j[slot]
            along_x, along_y = positions[r, j, 0] - x, positions[r, j, 1] - y
            near_d[slot] = np.hypot(along_x, along_y)
            closing_x = velocities[r, j, 0] - velocities[r, i, 0]
            closing_y = velocities[r, j, 1] - velocities[r, i, 1]
            features[r, i, 3 + 3 * slot] = (closing_x * along_x + closing_y * along_y) / near_d[slot]
            features[r, i, 4 + 3 * slot] = near_d[slot]
            features[r, i, 5 + 3 * slot] = wrap_difference(np.arctan2(along_y, along_x) - phi)
        count = 0  # the w nearest walls, nearest first, chosen by squared distance
        for s in range(walls.starts.shape[0]):
            off_x, off_y = _wall_offset(x, y, s, walls)
            count = _insert(wall_d, wall_s, count, w, off_x * off_x + off_y * off_y, s)
        for slot in range(count):
            off_x, off_y = _wall_offset(x, y, wall_s[slot], walls)
            features[r, i, walls_start + 2 * slot] = np.hypot(off_x, off_y)
            features[r, i, walls_start + 2 * slot + 1] = wrap_difference(np.arctan2(off_y, off_x) - phi)

"""Numba kernel of the sensing; its specification is :func:`pedrl.sim.sensing.observe`, within stated tolerances.

``atan2``/``hypot`` are libm's, not torch's vector routines: features agree with the torch reference to about 1e-6
relative (``tests/trial/test_twins.py`` states and checks the tolerances).

The ``k`` nearest others and the ``w`` nearest walls are chosen by squared distance, as the scan over every agent
(every wall) in index order chooses them: the least by the key ``(squared distance, index)``, nearest first
(:func:`_insert`: a later equal value goes after). In a room of at least ``search.min_agents`` agents
(:func:`pedrl.sim.motion.common.neighbour_search`) a uniform grid of cells (:mod:`pedrl.sim.grid_kernel`) replaces the
scan over the agents, and, where there are at least :data:`_WALL_GRID_MIN` segments, a second grid the scan over the
walls: linear time in the crowd instead of quadratic. A query visits the cells ring by ring (Chebyshev distance
``rho`` from its own cell), keeps the best by the same key (:func:`_insert`, whatever order the candidates come in),
and stops once it holds its ``k`` and the ``k``-th squared distance is below the square of :func:`_covered`, a lower
bound on the distance to everything in the unvisited cells. The result is the scan's to the bit
(``tests/sim/test_grid_sensing.py``), because

- a point in a cell ``rho + 1`` or more rings out is at least ``rho`` cell sizes away: the cell index is monotone in
  the coordinate (clamping too), and its float32 rounding moves a point by far less than the slack that
  :func:`_covered` takes off (:data:`pedrl.sim.grid_kernel.SLACK` m plus
  :data:`pedrl.sim.grid_kernel.RELATIVE_SLACK` of the cell size and of the grid's coordinates);
- the bound is strict, so nothing unvisited can tie with the ``k``-th either, and the same float32 operations give
  the same squared distances whichever order the candidates come in;
- a wall segment is listed in every cell it passes within the slack of (:func:`pedrl.sim.grid_kernel.bin_segments`),
  so a segment not met is in no visited cell; each segment is measured once per query (a stamp per segment); the
  segments not wholly inside the crowd's box widened by its larger side (the padding points far away) are left out
  of the grid and measured by every query.

``search.reach_scale`` (1) is the tests' control: below 1 the bound trusts part of the next ring, at 0 one
whole ring, so the search stops a ring early and misses neighbours.
"""

from __future__ import annotations

import numpy as np

from pedrl._numba import cached_njit
from pedrl.sim.grid_kernel import RELATIVE_SLACK, SLACK, bin_points, bin_segments, cell_range, make_cells
from pedrl.sim.motion.common import Search

__all__ = ["NO_VELOCITY", "sense_room", "wrap", "wrap_difference"]

_PI = np.float32(np.pi)
_TWO_PI = np.float32(2.0 * np.pi)
_CELL_SCALE = np.float32(0.5)
"""The agents' cell size over ``sqrt(area k / n)`` (``n`` present agents in a box of ``area``, ``k`` neighbours):
about the distance to the ``k``-th nearest at the mean density, so most searches stop after ring 2."""
NO_VELOCITY = np.zeros((0, 0, 0, 2), np.float32)
""":func:`sense_room`'s ``velocity`` where nobody reads the neighbours' velocities (the tables' fused trial)."""
_WALL_GRID_MIN = 64
"""Rooms with fewer wall segments scan them all: a grid of walls pays off only where there are many."""
_WALL_CELL_SCALE = np.float32(2.0)
"""The walls' cell size over ``sqrt(area / s)`` (``s`` segments in the grid's box of ``area``)."""


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
    """Insert ``value`` (of ``item``) into ``values[:count]``, ascending by the key ``(value, item)`` and kept to
    ``size`` entries; returns the new count. Candidates met in any order are kept as a scan in index order keeps
    them (a later equal value after)."""
    if size == 0:
        return count
    if count < size:
        place = count
        count += 1
    elif value < values[size - 1] or (value == values[size - 1] and item < index[size - 1]):
        place = size - 1
    else:
        return count
    while place > 0 and (values[place - 1] > value or (values[place - 1] == value and index[place - 1] > item)):
        values[place] = values[place - 1]
        index[place] = index[place - 1]
        place -= 1
    values[place] = value
    index[place] = item
    return count


@cached_njit(nogil=True, inline="always")
def _ring_span(cells, cx, cy, rho, row, side):
    """The items ``[a, b)`` of one run of ring ``rho`` around cell ``(cx, cy)`` in ``row``: its whole part of the
    grid in the ring's first and last rows (``side`` 0; ``side`` 1 is empty), else its left (0) or right (1) cell."""
    nx = cells.shape[0]
    if row == cy - rho or row == cy + rho:
        if side == 1:
            return 0, 0
        x0, x1 = max(cx - rho, 0), min(cx + rho, nx - 1)
    else:
        x0 = x1 = cx - rho if side == 0 else cx + rho
        if x0 < 0 or x0 >= nx:
            return 0, 0
    return cells.start[row * nx + x0], cells.start[row * nx + x1 + 1]


@cached_njit(nogil=True, inline="always")
def _covered(rho, cells, scale, margin):
    """A distance (m) below that of everything in the cells beyond ring ``rho``: ``rho`` cell sizes less the slack
    ``margin`` (m) and :data:`RELATIVE_SLACK`; ``scale`` below 1 adds ``1 - scale`` cells (the tests' control)."""
    size = np.float32(1.0) / cells.box[2]
    return (np.float32(rho) + np.float32(1.0) - scale) * size * (np.float32(1.0) - RELATIVE_SLACK) - margin


@cached_njit(nogil=True, inline="always")
def _done(count, size, values, rho, cells, scale, margin):
    """Whether a ring search that holds ``count`` of ``size`` after ring ``rho`` has its answer."""
    if count < size:
        return False
    reach = _covered(rho, cells, scale, margin)
    return reach > np.float32(0.0) and values[size - 1] < reach * reach


@cached_njit(nogil=True, inline="always")
def _last_ring(cells, cx, cy):
    """The ring around cell ``(cx, cy)`` beyond which the grid has no cell."""
    return max(cx, cells.shape[0] - 1 - cx, cy, cells.shape[1] - 1 - cy)


@cached_njit(nogil=True)
def _nearest_agents(i, x, y, binned, cells, slots, values, index, scale, margin):
    """The ``slots`` nearest others of agent ``i`` at ``(x, y)`` among the agents binned in ``cells`` (``binned``:
    their positions in the order of ``cells.items``) into ``values`` (squared distances) and ``index``, by a ring
    search; returns how many."""
    cx, _, cy, _ = cell_range(cells, x, y, np.float32(0.0))
    count = 0
    for rho in range(_last_ring(cells, cx, cy) + 1):
        for row in range(max(cy - rho, 0), min(cy + rho, cells.shape[1] - 1) + 1):
            for side in range(2):
                a, b = _ring_span(cells, cx, cy, rho, row, side)
                for t in range(a, b):
                    j = cells.items[t]
                    if j != i:
                        gap_x, gap_y = binned[t, 0] - x, binned[t, 1] - y
                        count = _insert(values, index, count, slots, gap_x * gap_x + gap_y * gap_y, j)
        if _done(count, slots, values, rho, cells, scale, margin):
            break
    return count


@cached_njit(nogil=True)
def _nearest_walls(i, x, y, walls, grid, size, values, index, scale):
    """The ``size`` nearest walls of agent ``i`` at ``(x, y)`` (``grid``: :func:`_wall_grid`) into ``values`` and
    ``index``: the segments outside the grid, then a ring search of its cells; returns how many."""
    cells, outside, stamp, margin = grid
    count = 0
    for t in range(outside.shape[0]):
        s = outside[t]
        stamp[s] = i
        off_x, off_y = _wall_offset(x, y, s, walls)
        count = _insert(values, index, count, size, off_x * off_x + off_y * off_y, s)
    cx, _, cy, _ = cell_range(cells, x, y, np.float32(0.0))
    for rho in range(_last_ring(cells, cx, cy) + 1):
        for row in range(max(cy - rho, 0), min(cy + rho, cells.shape[1] - 1) + 1):
            for side in range(2):
                a, b = _ring_span(cells, cx, cy, rho, row, side)
                for t in range(a, b):
                    s = cells.items[t]
                    if stamp[s] != i:
                        stamp[s] = i
                        off_x, off_y = _wall_offset(x, y, s, walls)
                        count = _insert(values, index, count, size, off_x * off_x + off_y * off_y, s)
        if _done(count, size, values, rho, cells, scale, margin):
            break
    return count


@cached_njit(nogil=True)
def _box(points, use):
    """How many points ``use`` marks, and their box ``low_x, low_y, high_x, high_y``."""
    count = 0
    low_x = low_y = np.float32(np.inf)
    high_x = high_y = np.float32(-np.inf)
    for i in range(points.shape[0]):
        if use[i]:
            count += 1
            low_x, high_x = min(low_x, points[i, 0]), max(high_x, points[i, 0])
            low_y, high_y = min(low_y, points[i, 1]), max(high_y, points[i, 1])
    return count, low_x, low_y, high_x, high_y


@cached_njit(nogil=True, inline="always")
def _margin(low_x, low_y, high_x, high_y):
    """The slack (m) of a grid over the box: :data:`SLACK` plus :data:`RELATIVE_SLACK` of its largest coordinate
    (which bounds its sides), far above the float32 rounding of a cell index or a distance there."""
    return SLACK + RELATIVE_SLACK * max(abs(low_x), abs(low_y), abs(high_x), abs(high_y))


@cached_njit(nogil=True, inline="always")
def _bare():
    """A grid of one cell that holds nothing (where a search needs none)."""
    zero = np.float32(0.0)
    return make_cells(zero, zero, zero, zero, np.float32(1.0), 0, 0)


@cached_njit(nogil=True)
def _agent_grid(points, use, slots):
    """The present agents binned in a grid over their box (a bare grid where no one is present or ``slots`` is 0),
    their positions in the grid's order (read in sequence by the ring search), and its slack (m)."""
    count, low_x, low_y, high_x, high_y = _box(points, use)
    if count == 0 or slots == 0:
        return _bare(), np.empty((0, 2), np.float32), np.float32(0.0)
    width, height = high_x - low_x, high_y - low_y
    near = np.float32(max(min(slots, count - 1), 1)) / np.float32(count)
    size = np.sqrt(width * height * near) if width * height > 0 else max(width, height) * near
    cells = make_cells(low_x, low_y, high_x, high_y, _CELL_SCALE * size, points.shape[0], count)
    bin_points(cells, points, use)
    binned = np.empty((count, 2), np.float32)
    for t in range(count):
        binned[t, 0], binned[t, 1] = points[cells.items[t], 0], points[cells.items[t], 1]
    return cells, binned, _margin(low_x, low_y, high_x, high_y)


@cached_njit(nogil=True)
def _wall_grid(points, use, walls):
    """The walls of a room of many segments (else a bare grid: fewer than :data:`_WALL_GRID_MIN`, or no one present)
    as :func:`_nearest_walls` reads them: a grid of the segments wholly within the present agents' box widened by its
    larger side (binned over the box of those segments and the agents), the other segments ascending, a stamp per
    segment and the slack (m)."""
    starts, directions = walls.starts, walls.directions
    num_walls = starts.shape[0]
    count, low_x, low_y, high_x, high_y = _box(points, use)
    if count == 0 or num_walls < _WALL_GRID_MIN:
        return _bare(), np.empty(0, np.int64), np.empty(0, np.int64), np.float32(0.0)
    widen = max(high_x - low_x, high_y - low_y) + SLACK
    inside = np.empty(num_walls, np.bool_)
    box = np.array([low_x, low_y, high_x, high_y], np.float32)
    for s in range(num_walls):
        ends = (starts[s, 0], starts[s, 1], starts[s, 0] + directions[s, 0], starts[s, 1] + directions[s, 1])
        inside[s] = (
            min(ends[0], ends[2]) >= low_x - widen and max(ends[0], ends[2]) <= high_x + widen
            and min(ends[1], ends[3]) >= low_y - widen and max(ends[1], ends[3]) <= high_y + widen
        )  # fmt: skip
        if inside[s]:
            box[0], box[2] = min(box[0], ends[0], ends[2]), max(box[2], ends[0], ends[2])
            box[1], box[3] = min(box[1], ends[1], ends[3]), max(box[3], ends[1], ends[3])
    listed = max(inside.sum(), 1)
    area = max((box[2] - box[0]) * (box[3] - box[1]), np.float32(1e-6))
    cells = make_cells(box[0], box[1], box[2], box[3], _WALL_CELL_SCALE * np.sqrt(area / np.float32(listed)), 0, listed)
    margin = _margin(box[0], box[1], box[2], box[3])
    segments = bin_segments(cells, starts, directions, walls.inverse, margin)
    return segments, np.flatnonzero(~inside), np.full(num_walls, -1, np.int64), margin


@cached_njit(nogil=True, inline="always")
def _goal_features(r, i, state, features):
    """Agent ``i``'s speed, bearing of its goal and distance to it into ``features[r, i, :3]``; returns the goal's
    direction ``phi``, to which every bearing is relative."""
    x, y = state.positions[r, i, 0], state.positions[r, i, 1]
    to_x, to_y = state.targets[r, i, 0] - x, state.targets[r, i, 1] - y
    phi = np.arctan2(to_y, to_x)
    features[r, i, 0] = state.speeds[r, i]
    features[r, i, 1] = wrap_difference(state.headings[r, i] - phi)
    features[r, i, 2] = np.hypot(to_x, to_y)
    return phi


@cached_njit(nogil=True, inline="always")
def _near_features(r, i, state, phi, count, near_d, near_j, features, num_sensed, velocity):
    """The ``count`` neighbours ``near_j`` of agent ``i`` (nearest first) into its features: closing speed, distance,
    bearing each; and, where ``velocity`` has rooms, each one's velocity in ``i``'s goal frame into
    ``velocity[r, i]``."""
    positions, velocities = state.positions, state.velocities
    x, y = positions[r, i, 0], positions[r, i, 1]
    num_sensed[r, i] = count
    if velocity.shape[0] > 0:
        cos_phi, sin_phi = np.cos(phi), np.sin(phi)
        for slot in range(count):
            j = near_j[slot]
            velocity[r, i, slot, 0] = velocities[r, j, 0] * cos_phi + velocities[r, j, 1] * sin_phi
            velocity[r, i, slot, 1] = velocities[r, j, 1] * cos_phi - velocities[r, j, 0] * sin_phi
    for slot in range(count):
        j = near_j[slot]
        along_x, along_y = positions[r, j, 0] - x, positions[r, j, 1] - y
        near_d[slot] = np.hypot(along_x, along_y)
        closing_x = velocities[r, j, 0] - velocities[r, i, 0]
        closing_y = velocities[r, j, 1] - velocities[r, i, 1]
        features[r, i, 3 + 3 * slot] = (closing_x * along_x + closing_y * along_y) / near_d[slot]
        features[r, i, 4 + 3 * slot] = near_d[slot]
        features[r, i, 5 + 3 * slot] = wrap_difference(np.arctan2(along_y, along_x) - phi)


@cached_njit(nogil=True, inline="always")
def _wall_features(r, i, state, walls, phi, count, wall_s, first, features):
    """The ``count`` walls ``wall_s`` of agent ``i`` (nearest first) into its features from column ``first``:
    distance and bearing each."""
    x, y = state.positions[r, i, 0], state.positions[r, i, 1]
    for slot in range(count):
        off_x, off_y = _wall_offset(x, y, wall_s[slot], walls)
        features[r, i, first + 2 * slot] = np.hypot(off_x, off_y)
        features[r, i, first + 2 * slot + 1] = wrap_difference(np.arctan2(off_y, off_x) - phi)


@cached_njit(nogil=True)
def _sense_grid(r, state, present, walls, slots, w, first, scale, features, num_sensed, distances, indices, velocity):
    """:func:`sense_room` by the grids (module docstring), the agents queried cell by cell (near in memory)."""
    positions = state.positions
    near_d, wall_d, near_j, wall_s = distances[0], distances[1], indices[0], indices[1]
    cells, binned, margin = _agent_grid(positions[r], present[r], slots)
    wall_grid = _wall_grid(positions[r], present[r], walls)
    listed = binned.shape[0] > 0  # else no neighbour slot: by index
    for query in range(binned.shape[0] if listed else positions.shape[1]):
        i = cells.items[query] if listed else query
        if not present[r, i]:
            continue
        x, y = positions[r, i, 0], positions[r, i, 1]
        phi = _goal_features(r, i, state, features)
        count = _nearest_agents(i, x, y, binned, cells, slots, near_d, near_j, scale, margin) if listed else 0
        _near_features(r, i, state, phi, count, near_d, near_j, features, num_sensed, velocity)
        count = 0
        if wall_grid[2].shape[0] > 0 and w > 0:
            count = _nearest_walls(i, x, y, walls, wall_grid, w, wall_d, wall_s, scale)
        else:
            for s in range(walls.starts.shape[0]):
                off_x, off_y = _wall_offset(x, y, s, walls)
                count = _insert(wall_d, wall_s, count, w, off_x * off_x + off_y * off_y, s)
        _wall_features(r, i, state, walls, phi, count, wall_s, first, features)


@cached_njit(nogil=True, inline="always")
def room_search(room):
    """The neighbour search (:class:`pedrl.sim.motion.common.Search`) of a room whose kernel constants are ``room``
    (:class:`pedrl.sim.params.KernelRoom`: ``grid_min_agents``, ``grid_reach_scale``)."""
    return Search(room.grid_min_agents, room.grid_reach_scale)


@cached_njit(nogil=True)
def sense_room(r, state, present, walls, k, w, search, features, num_sensed, distances, indices, velocity):
    """The deictic states of room ``r``'s ``present`` agents (:func:`pedrl.sim.sensing.observe` with observers and
    sensed both ``present``) into ``features[r]`` and ``num_sensed[r]``; the others get 0.

    ``walls`` is :class:`pedrl.sim.geometry.Walls`, ``state`` :class:`pedrl.sim.state.KernelState`; ``k`` and ``w``
    the neighbour and wall slots; ``search`` the neighbour search (:class:`pedrl.sim.motion.common.Search`, the room's
    :func:`room_search`: grids from ``search.min_agents`` agents, :func:`_sense_grid`). ``distances`` float32 and
    ``indices`` int64 ``(2, max(N, S))`` are scratch. ``velocity`` float32 ``(R, N, k, 2)`` takes each sensed
    neighbour's velocity in the goal frame (the observation's ``neighbour_velocity``; 0 in empty slots), or has no
    rooms (:data:`NO_VELOCITY`) where nobody reads it.
    """
    positions = state.positions
    num_agents = positions.shape[1]
    slots = min(k, num_agents - 1)
    features[r] = np.float32(0.0)
    num_sensed[r] = 0
    if velocity.shape[0] > 0:
        velocity[r] = np.float32(0.0)
    if num_agents >= search.min_agents:
        _sense_grid(r, state, present, walls, slots, w, 3 + 3 * k, search.reach_scale, features, num_sensed, distances,
                    indices, velocity)  # fmt: skip
        return
    near_d, wall_d, near_j, wall_s = distances[0], distances[1], indices[0], indices[1]
    for i in range(num_agents):
        if not present[r, i]:
            continue
        x, y = positions[r, i, 0], positions[r, i, 1]
        phi = _goal_features(r, i, state, features)
        count = 0  # the `slots` nearest present others, nearest first, chosen by squared distance
        for j in range(num_agents):
            if j != i and present[r, j] and slots > 0:
                gap_x, gap_y = positions[r, j, 0] - x, positions[r, j, 1] - y
                count = _insert(near_d, near_j, count, slots, gap_x * gap_x + gap_y * gap_y, j)
        _near_features(r, i, state, phi, count, near_d, near_j, features, num_sensed, velocity)
        count = 0  # the w nearest walls, nearest first, chosen by squared distance
        for s in range(walls.starts.shape[0]):
            off_x, off_y = _wall_offset(x, y, s, walls)
            count = _insert(wall_d, wall_s, count, w, off_x * off_x + off_y * off_y, s)
        _wall_features(r, i, state, walls, phi, count, wall_s, 3 + 3 * k, features)

"""Numba kernels of the fused trial; their specification is the torch trial loop, within stated tolerances.

One call of :func:`fused_trial` runs a whole learning (or acting) trial of every room: per decision, each room's
step (:meth:`pedrl.sim.RoomEnv.step`: actions, the move by the contact rule through
:func:`pedrl.sim.motion.sequential_kernel.sequential_room` / :func:`~pedrl.sim.motion.sliding_kernel.sliding_room`, exits, rewards), its
observation (:func:`pedrl.sim.sensing.observe`), the encoding (:meth:`pedrl.vq.StateEncoder.prepare` and the k-d
tree's :func:`pedrl.vq.tree.search_point`), the TD update (:func:`pedrl.rl.td_update_torch`) and the epsilon-greedy
choice (:func:`pedrl.rl.epsilon_greedy`), with no torch operation per decision.

The learning processes run in parallel (``prange``); a process runs its ``E`` rooms in turn, decision by decision,
and owns its tables, so no two threads write the same row. Every room draws from its own counter-based stream
(splitmix64), so a seed gives the same trial at any thread count. The random numbers are not torch's, and
``atan2``/``hypot``/``log1p`` are libm's, not torch's vector routines: features agree with the torch reference to
about 1e-6 relative (``tests/algos/test_fused.py`` states and checks the tolerances).
"""

from __future__ import annotations

import numpy as np
from numba import prange

from pedrl._numba import cached_njit
from pedrl.rl.kernels import _row_max
from pedrl.sim.motion import PAIR_MARGIN
from pedrl.sim.motion.sequential_kernel import sequential_room
from pedrl.sim.motion.sliding_kernel import sliding_room
from pedrl.vq.tree import _STACK, LEAF_SIZE, scan_point, search_point

__all__ = ["act_room", "act_scratch", "encode_agent", "fused_trial", "seed_streams", "sense_room"]

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_PI = np.float32(np.pi)
_TWO_PI = np.float32(2.0 * np.pi)
# the contact rules, as act_room numbers them
STOP, SLIDE, HEADWAY, YIELD = 0, 1, 2, 3
_MARGIN = np.float32(PAIR_MARGIN)


@cached_njit(nogil=True, inline="always")
def _mix(z):
    """splitmix64's finaliser: a 64-bit hash."""
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@cached_njit(nogil=True)
def seed_streams(seed, streams):
    """One splitmix64 stream per room, from ``seed`` (uint64)."""
    for r in range(streams.shape[0]):
        streams[r] = _mix(seed + _GOLDEN * np.uint64(r + 1))


@cached_njit(nogil=True, inline="always")
def _uniform(streams, r):
    """The next float32 in ``[0, 1)`` of room ``r``'s stream (24 random bits)."""
    streams[r] += _GOLDEN
    return np.float32(np.float64(_mix(streams[r]) >> np.uint64(40)) * (1.0 / 16777216.0))


@cached_njit(nogil=True, inline="always")
def _wrap(angle):
    """``pedrl.sim.geometry.wrap_angle`` of one float32 angle: into ``(-pi, pi]``."""
    wrapped = _PI - (_PI - angle) % _TWO_PI
    return _PI if wrapped <= -_PI else wrapped


@cached_njit(nogil=True, inline="always")
def _wrap_difference(angle):
    """:func:`_wrap` of the difference of two angles in ``[-pi, pi]`` (``atan2``, wrapped headings): one turn added
    or taken away suffices (with the nearest chosen by squared distance, this took sensing from 0.67 to 0.47 us);
    anything else (a heading placed by hand outside that range) takes the remainder."""
    if angle > _PI:
        angle -= _TWO_PI
    elif angle <= -_PI:
        angle += _TWO_PI
    if angle > _PI or angle <= -_PI:
        return _wrap(angle)
    return angle


@cached_njit(nogil=True, inline="always")
def _wall_offset(x, y, s, walls):
    """Closest point of wall ``s`` minus ``(x, y)`` (``Geometry.wall_offsets``): clamped to the box of an aligned
    wall, else projected and clamped to the segment."""
    starts, directions, inverse, aligned, low, high = walls
    if aligned[s]:
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

    ``walls`` is ``(starts (S, 2), directions (S, 2), inverse (S,), aligned (S,), low (S, 2), high (S, 2))``
    float32 but ``aligned`` (bool); ``state`` is :func:`fused_trial`'s. ``distances`` float32 and ``indices`` int64
    ``(2, max(N, S))`` are scratch.
    """
    positions, velocities, headings, speeds, _, _, goals, _, _ = state
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
        features[r, i, 1] = _wrap_difference(headings[r, i] - phi)
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
            features[r, i, 5 + 3 * slot] = _wrap_difference(np.arctan2(along_y, along_x) - phi)
        count = 0  # the w nearest walls, nearest first, chosen by squared distance
        for s in range(walls[0].shape[0]):
            off_x, off_y = _wall_offset(x, y, s, walls)
            count = _insert(wall_d, wall_s, count, w, off_x * off_x + off_y * off_y, s)
        for slot in range(count):
            off_x, off_y = _wall_offset(x, y, wall_s[slot], walls)
            features[r, i, walls_start + 2 * slot] = np.hypot(off_x, off_y)
            features[r, i, walls_start + 2 * slot + 1] = _wrap_difference(np.arctan2(off_y, off_x) - phi)


@cached_njit(nogil=True)
def encode_agent(r, i, process, features, num_sensed, void, settings, encoder, tree, x, point, nodes, sums):
    """The state id of agent ``i`` of room ``r`` of learning ``process``: its features as the quantizer sees them
    (:meth:`pedrl.vq.StateEncoder.prepare`: void slots filled from its draws ``void[r, i]``, distances transformed),
    standardised by the set of its process and neighbours, and that set's nearest prototype plus its offset.

    ``settings`` is ``(k, max_distance, max_speed, min_distance, random_void, log_distances)``; ``encoder``
    ``(mean (T, F), std (T, F), keep (T, F), offsets (T,), columns (T, F), distance_index (D,), set_of (P, k + 1),
    scan)``:
    a union's part reads only the features it ``keep``s (the others are 0 in its prototypes and in the point);
    ``tree`` is :meth:`pedrl.vq.tree.TreeIndex.kernel_arrays`, searched by the tree or, with ``scan``
    (:attr:`pedrl.vq.tree.TreeIndex.scans`), by a scan of its leaves. ``x``, ``point`` ``(F,)``, ``nodes`` and
    ``sums`` are scratch.
    """
    k, max_distance, max_speed, min_distance, random_void, log_distances = settings
    mean, std, keep, offsets, columns, distance_index, set_of, scan = encoder
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
    (prototypes, ids_of, leaf_of, left, right, split_dim, split_value, low_box, high_box) = tree
    if scan:
        found, _ = scan_point(point, t, prototypes, ids_of, sums)
    else:
        found, _ = search_point(
            point, t, prototypes, ids_of, leaf_of, left, right, split_dim, split_value, low_box, high_box, nodes, sums
        )
    return found + offsets[t]


@cached_njit(nogil=True)
def act_scratch(num_agents):
    """The per-agent scratch of :func:`act_room`, one per thread: ``(priority, old_x, old_y, moved, flags (2, N),
    current (N, 2), rank_of)``."""
    return (np.empty(num_agents, np.float32), np.empty(num_agents, np.float32), np.empty(num_agents, np.float32),
            np.empty(num_agents, np.float32), np.empty((2, num_agents), np.bool_),
            np.empty((num_agents, 2), np.float32), np.empty(num_agents, np.int64))  # fmt: skip


@cached_njit(nogil=True)
def act_room(r, state, actions, room, walls, exits, work, events, scratch):
    """One decision of room ``r`` (:meth:`pedrl.sim.RoomEnv.step` without the observation): the ``actions``, the
    move by the room's contact rule, the exits, the clock and the rewards; ``state`` is updated in place.

    ``room`` is ``(speed_changes (9,), turn_changes (9,), max_speed, decision_length, num_substeps, radius, contact,
    door_first, time_gap, goal_frame, max_decisions, rewards (4,): goal, wall, agent, default, reward_progress,
    assigned (R, N), exit_goals (X, 2), waypoints (N, W, 2), route_length (N,), waypoint_radius)``, the last three
    the routes (flat: a parallel kernel takes no tuple in a tuple);
    ``exits`` ``(start, normal, tangent, span)``; ``work`` ``(R, N)``-shaped arrays of the move, the last the
    uniform draws that order the movers (``RoomEnv``'s ``priority``); ``events`` ``(reward, left, goal,
    crashed_wall, crashed_agent, acting, in_room)``, written for room ``r``.
    """
    positions, velocities, headings, speeds, active, exit_index, targets, decisions, stage = state
    speed_changes, turn_changes, max_speed, length, substeps, radius, contact, door_first, time_gap = room[:9]
    goal_frame, max_decisions, rewards, reward_progress, assigned, exit_goals = room[9:15]
    routes = room[15:]
    moved_to, step, going, present, order, depth, blocked, cut_wall, cut_body, reached, no_walls, draws = work
    reward, left, goal, crashed_wall, crashed_agent, acting, in_room = events
    priority, old_x, old_y, moved, flags, current, rank_of = scratch
    starts, directions, inverse, _, low, high = walls
    exit_start, exit_normal, exit_tangent, exit_span = exits
    zero = np.float32(0.0)
    num_agents = positions.shape[1]
    for i in range(num_agents):
        acting[r, i] = active[r, i]
        if active[r, i] and goal_frame:  # pedrl.sim.actions.apply_actions with bearings
            bearing = np.arctan2(targets[r, i, 1] - positions[r, i, 1], targets[r, i, 0] - positions[r, i, 0])
            speeds[r, i] = min(max(speed_changes[actions[r, i] // 9], zero), max_speed)
            headings[r, i] = _wrap(bearing + turn_changes[actions[r, i] % 9])
        elif active[r, i]:
            speeds[r, i] = min(max(speeds[r, i] + speed_changes[actions[r, i] // 9], zero), max_speed)
            headings[r, i] = _wrap(headings[r, i] + turn_changes[actions[r, i] % 9])
        velocities[r, i, 0] = speeds[r, i] * np.cos(headings[r, i])
        velocities[r, i, 1] = speeds[r, i] * np.sin(headings[r, i])
        old_x[i], old_y[i] = positions[r, i, 0], positions[r, i, 1]
        priority[i] = draws[r, i]
        if door_first:  # metres dominate, the uniform draw breaks ties
            distance = np.hypot(old_x[i] - targets[r, i, 0], old_y[i] - targets[r, i, 1])
            priority[i] = distance + priority[i] * np.float32(1e-3)
        present[r, i] = active[r, i]
        blocked[r, i] = cut_wall[r, i] = cut_body[r, i] = reached[r, i] = False
    order[r, :] = np.argsort(priority)
    if contact == STOP:
        per_substep = np.float32(length / substeps)
        for i in range(num_agents):
            step[r, i, 0] = velocities[r, i, 0] * per_substep
            step[r, i, 1] = velocities[r, i, 1] * per_substep
            going[r, i] = active[r, i] and (step[r, i, 0] != zero or step[r, i, 1] != zero)
            depth[r, i] = np.sqrt(step[r, i, 0] * step[r, i, 0] + step[r, i, 1] * step[r, i, 1]) + _MARGIN
        sequential_room(
            r, positions, step, going, present, depth, no_walls, low, high, np.float32(radius * radius),
            exit_start, exit_normal, exit_tangent, exit_span, order, np.float32(4.0 * radius * radius), moved_to,
            blocked, cut_wall, reached, moved, flags[0], flags[1], current,
        )  # fmt: skip
        for i in range(num_agents):
            cut_body[r, i] = blocked[r, i] and not cut_wall[r, i]
    else:
        for i in range(num_agents):
            going[r, i] = active[r, i] and (velocities[r, i, 0] != zero or velocities[r, i, 1] != zero)
        sliding_room(
            r, positions, velocities, going, present, order, starts, directions, inverse, exit_start, exit_normal,
            exit_tangent, exit_span, np.float32(radius * radius), np.float32(4.0 * radius * radius),
            np.float32(length / substeps), substeps, contact >= HEADWAY, contact == YIELD, np.float32(time_gap),
            np.float32(2.0 * radius), _MARGIN, moved_to, blocked, cut_wall, cut_body, reached, step[r], current,
            moved, rank_of,
        )  # fmt: skip
    decisions[r] += 1
    for i in range(num_agents):
        new_x, new_y = moved_to[r, i, 0], moved_to[r, i, 1]
        if contact != STOP:  # the speed is the distance walked; the heading stays the commanded one
            if acting[r, i]:
                walked = np.sqrt((new_x - old_x[i]) ** 2 + (new_y - old_y[i]) ** 2) / np.float32(length)
                speeds[r, i] = min(walked, max_speed)
            velocities[r, i, 0] = speeds[r, i] * np.cos(headings[r, i])
            velocities[r, i, 1] = speeds[r, i] * np.sin(headings[r, i])
        elif blocked[r, i]:
            speeds[r, i] = zero
            velocities[r, i, 0] = velocities[r, i, 1] = zero
        crashed_wall[r, i] = cut_wall[r, i]
        crashed_agent[r, i] = cut_body[r, i] and not cut_wall[r, i]
        left[r, i] = reached[r, i]
        in_room[r, i] = acting[r, i] and not reached[r, i]
        active[r, i] = in_room[r, i] and decisions[r] < max_decisions
        own = assigned[r, i] < 0
        if reached[r, i] and not own:  # the exit passed: the one whose goal point is nearest
            nearest, best = 0, np.float32(np.inf)
            for e in range(exit_goals.shape[0]):
                gap = (new_x - exit_goals[e, 0]) ** 2 + (new_y - exit_goals[e, 1]) ** 2
                if gap < best:
                    nearest, best = e, gap
            own = nearest == exit_index[r, i]
        goal[r, i] = reached[r, i] and own
        value = rewards[3]
        if crashed_agent[r, i]:
            value = rewards[2]
        if crashed_wall[r, i]:
            value = rewards[1]
        if goal[r, i]:
            value = rewards[0]
        if acting[r, i]:
            before = np.hypot(old_x[i] - targets[r, i, 0], old_y[i] - targets[r, i, 1])
            after = np.hypot(new_x - targets[r, i, 0], new_y - targets[r, i, 1])
            reward[r, i] = value + reward_progress * (before - after)
        else:
            reward[r, i] = zero
        positions[r, i, 0], positions[r, i, 1] = new_x, new_y
        if routes[0].shape[1] > 0:
            _advance(r, i, positions, stage, exit_index, targets, routes, exit_goals)


@cached_njit(nogil=True, inline="always")
def _route_point(i, stage, exit_index, routes, exit_goals):
    """``Spawns.route_point`` of agent ``i``: waypoint ``stage`` of its route, or its exit's goal point past it."""
    waypoints, route_length, _ = routes
    if stage < route_length[i]:
        return waypoints[i, stage, 0], waypoints[i, stage, 1]
    return exit_goals[exit_index, 0], exit_goals[exit_index, 1]


@cached_njit(nogil=True)
def _advance(r, i, positions, stage, exit_index, targets, routes, exit_goals):
    """``Spawns.advance`` of agent ``i`` of room ``r``: past each waypoint it reached (within the radius, or beyond
    the line through it across the way on), it aims at the next point."""
    route_length, radius = routes[1], routes[2]
    while stage[r, i] < route_length[i]:
        x, y = _route_point(i, stage[r, i], exit_index[r, i], routes, exit_goals)
        next_x, next_y = _route_point(i, stage[r, i] + 1, exit_index[r, i], routes, exit_goals)
        norm = max(np.sqrt((next_x - x) ** 2 + (next_y - y) ** 2), np.float32(1e-9))
        along_x, along_y = (next_x - x) / norm, (next_y - y) / norm
        off_x, off_y = positions[r, i, 0] - x, positions[r, i, 1] - y
        ahead = off_x * along_x + off_y * along_y
        side = off_x * along_y - off_y * along_x
        if off_x * off_x + off_y * off_y < radius * radius or (ahead >= 0 and abs(side) < radius):
            stage[r, i] += 1
        else:
            break
    targets[r, i, 0], targets[r, i, 1] = _route_point(i, stage[r, i], exit_index[r, i], routes, exit_goals)


@cached_njit(nogil=True, inline="always")
def _choose(table, row, epsilon, streams, r):
    """:func:`pedrl.rl.epsilon_greedy` of one row: a uniform action with probability ``epsilon``, else the
    ``floor(u c)``-th of the row's ``c`` tied maxima (action 0 for a NaN row)."""
    num_actions = table.shape[1]
    if _uniform(streams, r) < epsilon:
        return min(np.int64(_uniform(streams, r) * np.float32(num_actions)), num_actions - 1)
    best = _row_max(table, row)
    count = 0
    for a in range(num_actions):
        count += table[row, a] == best
    pick = min(np.int64(_uniform(streams, r) * np.float32(count)), count - 1)
    for a in range(num_actions):
        if table[row, a] == best:
            if pick == 0:
                return a
            pick -= 1
    return 0


@cached_njit(nogil=True)
def _td(first, rooms, table, rows, actions, reward, next_rows, events, alpha, gamma, errors, keys, tally):
    """Equation 1 for the transitions of rooms ``first .. first + rooms - 1`` (:func:`pedrl.rl.td_update_torch`):
    every error from the tables before the update, increments of one ``(row, action)`` averaged. Returns the sum of
    ``|TD error|`` and the number of updates. ``errors`` ``(rooms N,)``, ``keys`` and ``tally`` (a power of two of at
    least ``2 rooms N``) are scratch."""
    _, left, _, _, _, acting, _ = events
    num_agents, num_actions = rows.shape[1], table.shape[1]
    flat = table.reshape(-1)
    mask = keys.shape[0] - 1
    bits = np.uint64(64 - np.int64(np.log2(keys.shape[0])))
    keys[:] = -1
    tally[:] = 0
    total, count = 0.0, 0
    for b in range(rooms * num_agents):
        r, i = first + b // num_agents, b % num_agents
        if not acting[r, i]:
            continue
        next_value = np.float32(0.0) if left[r, i] else _row_max(table, next_rows[r, i])
        entry = rows[r, i] * num_actions + actions[r, i]
        errors[b] = (reward[r, i] + gamma * next_value) - flat[entry]
        slot = np.int64((np.uint64(entry) * _GOLDEN) >> bits)
        while keys[slot] != -1 and keys[slot] != entry:
            slot = (slot + 1) & mask
        keys[slot] = entry
        tally[slot] += 1
        total += abs(errors[b])
        count += 1
    for b in range(rooms * num_agents):
        r, i = first + b // num_agents, b % num_agents
        if not acting[r, i]:
            continue
        entry = rows[r, i] * num_actions + actions[r, i]
        slot = np.int64((np.uint64(entry) * _GOLDEN) >> bits)
        while keys[slot] != entry:
            slot = (slot + 1) & mask
        flat[entry] += errors[b] * ((np.float32(1.0) / np.float32(tally[slot])) * alpha)
    return total, count


@cached_njit(nogil=True)
def _encode_room(r, process, present, base_rows, rows, features, num_sensed, void, settings, encoder, tree, buffers):
    """``rows[r]``: every ``present`` agent's flat table row (its table's first row plus its state id); the others
    get their table's first row."""
    x, point, nodes, sums = buffers
    for i in range(rows.shape[1]):
        rows[r, i] = base_rows[r, i]
        if present[r, i]:
            rows[r, i] += encode_agent(r, i, process, features, num_sensed, void, settings, encoder, tree, x, point,
                                       nodes, sums)  # fmt: skip


@cached_njit(nogil=True)
def _draw_void(r, void, streams):
    for i in range(void.shape[1]):
        for j in range(void.shape[2]):
            void[r, i, j] = _uniform(streams, r)


@cached_njit(nogil=True)
def _run_process(
    p, rooms, state, room, walls, exits, encoder, tree, settings, learning, table, base_rows, process_of,
    streams, work, events, observed, void, totals, td_sums,
):  # fmt: skip
    """Every decision of process ``p``'s rooms ``p E .. p E + E - 1`` until they are empty; returns the decisions
    taken."""
    positions, _, _, speeds, active, _, _, _, _ = state
    k, random_void = settings[0], settings[4]
    epsilon, learn, alpha, gamma, void_each_decision = learning
    features, num_sensed, rows, next_rows, actions = observed
    reward, left, goal, crashed_wall, crashed_agent, acting, in_room = events
    num_agents, num_features = positions.shape[1], features.shape[2]
    w = (num_features - 3 - 3 * k) // 2  # the wall slots of the state's 3 + 3k + 2w features
    first = p * rooms
    size = max(num_agents, walls[0].shape[0])
    distances, indices = np.empty((2, size), np.float32), np.empty((2, size), np.int64)
    buffers = (np.empty(num_features, np.float32), np.empty(num_features, np.float32),
               np.empty(_STACK, np.int64), np.empty(LEAF_SIZE, np.float32))  # fmt: skip
    scratch = act_scratch(num_agents)
    slots = 1
    while slots < 2 * rooms * num_agents:
        slots *= 2
    errors = np.empty(rooms * num_agents, np.float32)
    keys, tally = np.empty(slots, np.int64), np.empty(slots, np.int64)
    for r in range(first, first + rooms):
        if random_void:
            _draw_void(r, void, streams)
        sense_room(r, state, active, walls, k, w, features, num_sensed, distances, indices)
        _encode_room(r, process_of[r], active, base_rows, rows, features, num_sensed, void, settings, encoder, tree,
                     buffers)  # fmt: skip
        for i in range(num_agents):
            if active[r, i]:
                actions[r, i] = _choose(table, rows[r, i], epsilon, streams, r)
    steps = 0
    while active[first : first + rooms].any():
        for r in range(first, first + rooms):
            for i in range(num_agents):
                work[-1][r, i] = _uniform(streams, r)
            act_room(r, state, actions, room, walls, exits, work, events, scratch)
            if random_void and void_each_decision:
                _draw_void(r, void, streams)
            sense_room(r, state, in_room, walls, k, w, features, num_sensed, distances, indices)
            _encode_room(r, process_of[r], in_room, base_rows, next_rows, features, num_sensed, void, settings,
                         encoder, tree, buffers)  # fmt: skip
        if learn:
            total, count = _td(first, rooms, table, rows, actions, reward, next_rows, events, alpha, gamma, errors,
                               keys, tally)  # fmt: skip
            td_sums[p, 0] += total
            td_sums[p, 1] += count
        for r in range(first, first + rooms):
            for i in range(num_agents):
                if acting[r, i]:
                    totals[0, r, i] += reward[r, i]
                    totals[1, r, i] += crashed_agent[r, i]
                    totals[2, r, i] += crashed_wall[r, i]
                    totals[3, r, i] += goal[r, i]
                    totals[4, r, i] += speeds[r, i]
                    totals[5, r, i] += 1.0
                rows[r, i] = next_rows[r, i]
                if active[r, i]:
                    actions[r, i] = _choose(table, rows[r, i], epsilon, streams, r)
        steps += 1
    return steps


@cached_njit(nogil=True, parallel=True)
def fused_trial(
    rooms, state, room, walls, exits, encoder, tree, settings, learning, table, base_rows, process_of,
    streams, work, events, observed, void, totals, td_sums, steps,
):  # fmt: skip
    """A whole trial of every room from its reset state: the processes ``p`` of ``E = rooms`` rooms each in
    parallel, each by :func:`_run_process`; ``steps[p]`` gets its decisions.

    ``state`` is the rooms' ``(positions (R, N, 2), velocities (R, N, 2), headings (R, N), speeds (R, N), active
    (R, N), exit_index (R, N), targets (R, N, 2), decisions (R,), stage (R, N))``, updated in place; ``learning``
    is ``(epsilon, learn, alpha, gamma, void_each_decision)``; ``totals`` ``(6, R, N)`` float64 gets each agent's
    return, body contacts, wall contacts, goal, speed sum and decisions; ``td_sums`` ``(P, 2)`` float64 the sum of ``|TD
    error|`` and the updates. The other tuples are those of :func:`act_room`, :func:`sense_room` and
    :func:`encode_agent`.
    """
    for p in prange(steps.shape[0]):
        steps[p] = _run_process(
            p, rooms, state, room, walls, exits, encoder, tree, settings, learning, table, base_rows, process_of,
            streams, work, events, observed, void, totals, td_sums,
        )  # fmt: skip

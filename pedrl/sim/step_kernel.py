"""Numba kernel of one decision of a room; its specification is :meth:`pedrl.sim.RoomEnv.step` without the
observation (the actions, the move by the room's contact rule, the exits, the clock, the rewards and the routes),
within stated tolerances (``tests/trial/test_twins.py``)."""

from __future__ import annotations

import numpy as np

from pedrl._numba import cached_njit
from pedrl.sim.motion.common import HEADWAY, PAIR_MARGIN, STOP, YIELD
from pedrl.sim.motion.sequential_kernel import sequential_room
from pedrl.sim.motion.sliding_kernel import sliding_room
from pedrl.sim.sensing_kernel import wrap

__all__ = ["act_room", "act_scratch"]

_MARGIN = np.float32(PAIR_MARGIN)


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
    assigned (R, N), exit_goals (X, 2), steer, steering (4,), waypoints (R, N, W, 2), route_length (R, N),
    waypoint_radius)``: ``steer`` is ``motion=continuous`` with the direction rule's ``(a, D, b, B)``; the last three
    the routes (flat: a parallel kernel takes no tuple in a tuple);
    ``exits`` ``(start, normal, tangent, span)``; ``work`` ``(R, N)``-shaped arrays of the move, the last the
    uniform draws that order the movers (``RoomEnv``'s ``priority``); ``events`` ``(reward, left, goal,
    crashed_wall, crashed_agent, acting, in_room)``, written for room ``r``.
    """
    positions, velocities, headings, speeds, active, exit_index, targets, decisions, stage = state
    speed_changes, turn_changes, max_speed, length, substeps, radius, contact, door_first, time_gap = room[:9]
    goal_frame, max_decisions, rewards, reward_progress, assigned, exit_goals, steer, steering = room[9:17]
    routes = room[17:]
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
            headings[r, i] = wrap(bearing + turn_changes[actions[r, i] % 9])
        elif active[r, i]:
            speeds[r, i] = min(max(speeds[r, i] + speed_changes[actions[r, i] // 9], zero), max_speed)
            headings[r, i] = wrap(headings[r, i] + turn_changes[actions[r, i] % 9])
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
            np.float32(2.0 * radius), _MARGIN, steer, steering, moved_to, blocked, cut_wall, cut_body, reached, step[r],
            current, moved, rank_of,
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
        if routes[0].shape[2] > 0:
            _advance(r, i, positions, stage, exit_index, targets, routes, exit_goals)


@cached_njit(nogil=True, inline="always")
def _route_point(r, i, stage, exit_index, routes, exit_goals):
    """``Spawns.route_point`` of agent ``i`` of room ``r``: waypoint ``stage`` of its route, or its exit's goal point
    past it."""
    waypoints, route_length, _ = routes
    if stage < route_length[r, i]:
        return waypoints[r, i, stage, 0], waypoints[r, i, stage, 1]
    return exit_goals[exit_index, 0], exit_goals[exit_index, 1]


@cached_njit(nogil=True)
def _advance(r, i, positions, stage, exit_index, targets, routes, exit_goals):
    """``Spawns.advance`` of agent ``i`` of room ``r``: past each waypoint it reached (within the radius, or beyond
    the line through it across the way on), it aims at the next point."""
    route_length, radius = routes[1], routes[2]
    while stage[r, i] < route_length[r, i]:
        x, y = _route_point(r, i, stage[r, i], exit_index[r, i], routes, exit_goals)
        next_x, next_y = _route_point(r, i, stage[r, i] + 1, exit_index[r, i], routes, exit_goals)
        norm = max(np.sqrt((next_x - x) ** 2 + (next_y - y) ** 2), np.float32(1e-9))
        along_x, along_y = (next_x - x) / norm, (next_y - y) / norm
        off_x, off_y = positions[r, i, 0] - x, positions[r, i, 1] - y
        ahead = off_x * along_x + off_y * along_y
        side = off_x * along_y - off_y * along_x
        if off_x * off_x + off_y * off_y < radius * radius or (ahead >= 0 and abs(side) < radius):
            stage[r, i] += 1
        else:
            break
    targets[r, i, 0], targets[r, i, 1] = _route_point(r, i, stage[r, i], exit_index[r, i], routes, exit_goals)

"""Numba kernel of one decision of a room; its specification is :meth:`pedrl.sim.RoomEnv.step` without the
observation (the actions, the move by the room's contact rule, the exits, the clock, the rewards and the routes),
within stated tolerances (``tests/trial/test_twins.py``)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from pedrl._numba import cached_njit
from pedrl.sim.actions import apply_action_kernel, apply_command_kernel, velocity_kernel
from pedrl.sim.motion.common import PAIR_MARGIN, STOP, KernelMoves
from pedrl.sim.motion.sequential_kernel import sequential_constants, sequential_room
from pedrl.sim.motion.sliding_kernel import sliding_constants, sliding_room
from pedrl.sim.rewards import crowded_kernel, deviation_kernel, passing_kernel, reward_kernel

__all__ = ["NO_COMMANDS", "ActScratch", "Events", "Work", "act_room", "act_scratch"]

_MARGIN = np.float32(PAIR_MARGIN)
NO_COMMANDS = np.zeros((0, 0, 2), np.float32)
""":func:`act_room`'s ``commands`` where the agents act by action index."""


class Work(NamedTuple):
    """The move's arrays of every room, ``(R, N)`` but ``moved_to`` and ``step`` ``(R, N, 2)`` and ``no_walls``
    (:func:`act_room` writes room ``r``'s rows; :meth:`allocate`)."""

    moved_to: np.ndarray
    step: np.ndarray
    going: np.ndarray
    present: np.ndarray
    order: np.ndarray
    depth: np.ndarray
    blocked: np.ndarray
    cut_wall: np.ndarray
    cut_body: np.ndarray
    reached: np.ndarray
    no_walls: np.ndarray
    """``(substeps, 1, 1)`` bool, all false: the walls are clamped by boxes in the stop rule's kernel."""
    draws: np.ndarray
    """float32: the uniform draws that order the movers (``RoomEnv``'s ``priority``), written before each call."""

    @classmethod
    def allocate(cls, rooms: int, agents: int, substeps: int) -> Work:
        shape = (rooms, agents)
        flags = [np.zeros(shape, np.bool_) for _ in range(6)]
        return cls(
            np.zeros((*shape, 2), np.float32),
            np.zeros((*shape, 2), np.float32),
            flags[0],
            flags[1],
            np.zeros(shape, np.int64),
            np.zeros(shape, np.float32),
            *flags[2:],
            np.zeros((substeps, 1, 1), np.bool_),
            np.zeros(shape, np.float32),
        )


class Events(NamedTuple):
    """What the latest decision did, ``(R, N)`` each (:func:`act_room` writes room ``r``'s rows)."""

    reward: np.ndarray
    left: np.ndarray
    """bool: passed an exit."""
    goal: np.ndarray
    """bool: passed its own exit."""
    crashed_wall: np.ndarray
    crashed_agent: np.ndarray
    acting: np.ndarray
    """bool: took the decision."""
    in_room: np.ndarray
    """bool: took it and is still in the room."""

    @classmethod
    def allocate(cls, rooms: int, agents: int) -> Events:
        return cls(np.zeros((rooms, agents), np.float32), *(np.zeros((rooms, agents), np.bool_) for _ in range(6)))


class ActScratch(NamedTuple):
    """Per-agent scratch of :func:`act_room`, one per thread (:func:`act_scratch`)."""

    priority: np.ndarray
    old_x: np.ndarray
    old_y: np.ndarray
    moved: np.ndarray
    acted_moved: np.ndarray
    passed: np.ndarray
    current: np.ndarray
    rank_of: np.ndarray
    deviation: np.ndarray
    passing: np.ndarray


@cached_njit(nogil=True)
def act_scratch(num_agents):
    """The per-agent scratch of :func:`act_room` (:class:`ActScratch`), one per thread."""
    return ActScratch(np.empty(num_agents, np.float32), np.empty(num_agents, np.float32),
                      np.empty(num_agents, np.float32), np.empty(num_agents, np.float32),
                      np.empty(num_agents, np.bool_), np.empty(num_agents, np.bool_),
                      np.empty((num_agents, 2), np.float32),
                      np.empty(num_agents, np.int64), np.zeros(num_agents, np.float32),
                      np.zeros(num_agents, np.bool_))  # fmt: skip


@cached_njit(nogil=True)
def act_room(r, state, actions, commands, room, walls, exits, routes, work, events, scratch):
    """One decision of room ``r`` (:meth:`pedrl.sim.RoomEnv.step` without the observation): the ``actions`` ``(R,
    N)`` int64, or where ``commands`` ``(R, N, 2)`` float32 has rows, their continuous commands
    (:func:`pedrl.sim.actions.apply_command_kernel`; an empty ``(0, 0, 2)`` array otherwise), the move by the room's
    contact rule, the exits, the clock and the rewards; ``state`` is updated in place.

    ``state`` is :class:`pedrl.sim.state.KernelState`, ``room`` :class:`pedrl.sim.params.KernelRoom`, ``walls``
    :class:`pedrl.sim.geometry.Walls`, ``exits`` :class:`pedrl.sim.geometry.Exits`, ``routes``
    :class:`pedrl.sim.spawning.Routes`; ``work`` (:class:`Work`) and ``events`` (:class:`Events`) get room ``r``'s
    rows, ``scratch`` is :func:`act_scratch`'s.
    """
    positions, velocities, headings, speeds = state.positions, state.velocities, state.headings, state.speeds
    active, exit_index, targets, decisions = state.active, state.exit_index, state.targets, state.decisions
    max_speed = room.max_speed
    length, substeps, contact = room.decision_length, room.num_substeps, room.contact
    moved_to, step, going, present, order = work.moved_to, work.step, work.going, work.present, work.order
    depth, blocked, cut_wall, cut_body, reached = work.depth, work.blocked, work.cut_wall, work.cut_body, work.reached
    reward, left, goal, acting, in_room = events.reward, events.left, events.goal, events.acting, events.in_room
    crashed_wall, crashed_agent = events.crashed_wall, events.crashed_agent
    priority, old_x, old_y = scratch.priority, scratch.old_x, scratch.old_y
    moved, current = scratch.moved, scratch.current
    zero = np.float32(0.0)
    num_agents = positions.shape[1]
    continuous = commands.shape[0] > 0
    for i in range(num_agents):
        acting[r, i] = active[r, i]
        if continuous:
            speeds[r, i], headings[r, i] = apply_command_kernel(
                room, active[r, i], speeds[r, i], headings[r, i], commands[r, i, 0], commands[r, i, 1],
                (positions[r, i, 0], positions[r, i, 1]), (targets[r, i, 0], targets[r, i, 1]),
            )  # fmt: skip
        else:
            speeds[r, i], headings[r, i] = apply_action_kernel(
                room, active[r, i], speeds[r, i], headings[r, i], actions[r, i],
                (positions[r, i, 0], positions[r, i, 1]), (targets[r, i, 0], targets[r, i, 1]),
            )  # fmt: skip
        velocities[r, i, 0], velocities[r, i, 1] = velocity_kernel(speeds[r, i], headings[r, i])
        scratch.deviation[i] = deviation_kernel(
            room, speeds[r, i], headings[r, i], (positions[r, i, 0], positions[r, i, 1]),
            (targets[r, i, 0], targets[r, i, 1]),
        )  # fmt: skip
        old_x[i], old_y[i] = positions[r, i, 0], positions[r, i, 1]
        priority[i] = work.draws[r, i]
        if room.door_first:  # metres dominate, the uniform draw breaks ties
            distance = np.hypot(old_x[i] - targets[r, i, 0], old_y[i] - targets[r, i, 1])
            priority[i] = distance + priority[i] * np.float32(1e-3)
        present[r, i] = active[r, i]
        blocked[r, i] = cut_wall[r, i] = cut_body[r, i] = reached[r, i] = False
    for i in range(num_agents):  # after every command is set: the oncoming walkers' tests read the others' velocities
        if scratch.deviation[i] != zero and crowded_kernel(room, r, i, positions, active, velocities, targets):
            scratch.deviation[i] = zero
        scratch.passing[i] = passing_kernel(room, r, i, positions, active, velocities, targets)
    order[r, :] = np.argsort(priority)
    if contact == STOP:
        per_substep = np.float32(length / substeps)
        for i in range(num_agents):
            step[r, i, 0] = velocities[r, i, 0] * per_substep
            step[r, i, 1] = velocities[r, i, 1] * per_substep
            going[r, i] = active[r, i] and (step[r, i, 0] != zero or step[r, i, 1] != zero)
            depth[r, i] = np.sqrt(step[r, i, 0] * step[r, i, 0] + step[r, i, 1] * step[r, i, 1]) + _MARGIN
        sequential_room(
            r, positions, step, going, present, depth, work.no_walls, walls.low, walls.high, exits, order,
            sequential_constants(room), KernelMoves(moved_to, blocked, cut_wall, cut_body, reached), moved,
            scratch.acted_moved, scratch.passed, current,
        )  # fmt: skip
        for i in range(num_agents):
            cut_body[r, i] = blocked[r, i] and not cut_wall[r, i]
    else:
        for i in range(num_agents):
            going[r, i] = active[r, i] and (velocities[r, i, 0] != zero or velocities[r, i, 1] != zero)
        moves = KernelMoves(moved_to, blocked, cut_wall, cut_body, reached)
        sliding_room(
            r, positions, velocities, going, present, order, walls, exits, sliding_constants(room), moves, step[r],
            current, moved, scratch.rank_of,
        )  # fmt: skip
    decisions[r] += 1
    for i in range(num_agents):
        new_x, new_y = moved_to[r, i, 0], moved_to[r, i, 1]
        if contact != STOP:  # the speed is the distance walked; the heading stays the commanded one
            if acting[r, i]:
                walked = np.sqrt((new_x - old_x[i]) ** 2 + (new_y - old_y[i]) ** 2) / np.float32(length)
                speeds[r, i] = min(walked, max_speed)
            velocities[r, i, 0], velocities[r, i, 1] = velocity_kernel(speeds[r, i], headings[r, i])
        elif blocked[r, i]:
            speeds[r, i] = zero
            velocities[r, i, 0] = velocities[r, i, 1] = zero
        crashed_wall[r, i] = cut_wall[r, i]
        crashed_agent[r, i] = cut_body[r, i] and not cut_wall[r, i]
        left[r, i] = reached[r, i]
        in_room[r, i] = acting[r, i] and not reached[r, i]
        active[r, i] = in_room[r, i] and decisions[r] < room.max_decisions
        goal[r, i] = reached[r, i] and _own_exit(r, i, new_x, new_y, exit_index, routes, exits.goals)
        reward[r, i] = reward_kernel(
            room, acting[r, i], goal[r, i], crashed_wall[r, i], crashed_agent[r, i], (old_x[i], old_y[i]),
            (new_x, new_y), (targets[r, i, 0], targets[r, i, 1]), scratch.deviation[i], scratch.passing[i],
        )  # fmt: skip
        positions[r, i, 0], positions[r, i, 1] = new_x, new_y
        if routes.waypoints.shape[2] > 0:
            _advance(r, i, positions, state.stage, exit_index, targets, routes, exits.goals)


@cached_njit(nogil=True, inline="always")
def _own_exit(r, i, x, y, exit_index, routes, exit_goals):
    """``Spawns.own_exit`` of agent ``i`` of room ``r``, which left at ``(x, y)``: an agent without an assigned exit
    reaches its goal through any exit, one with an assigned exit through its own, the exit whose goal point is
    nearest to where it left."""
    if routes.assigned[r, i] < 0:
        return True
    nearest, best = 0, np.float32(np.inf)
    for e in range(exit_goals.shape[0]):
        gap = (x - exit_goals[e, 0]) ** 2 + (y - exit_goals[e, 1]) ** 2
        if gap < best:
            nearest, best = e, gap
    return nearest == exit_index[r, i]


@cached_njit(nogil=True, inline="always")
def _route_point(r, i, stage, exit_index, routes, exit_goals):
    """``Spawns.route_point`` of agent ``i`` of room ``r``: waypoint ``stage`` of its route, or its exit's goal point
    past it."""
    if stage < routes.route_length[r, i]:
        return routes.waypoints[r, i, stage, 0], routes.waypoints[r, i, stage, 1]
    return exit_goals[exit_index, 0], exit_goals[exit_index, 1]


@cached_njit(nogil=True)
def _advance(r, i, positions, stage, exit_index, targets, routes, exit_goals):
    """``Spawns.advance`` of agent ``i`` of room ``r``: past each waypoint it reached (within the radius, or beyond
    the line through it across the way on), it aims at the next point."""
    route_length, radius = routes.route_length, routes.waypoint_radius
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

"""Numba kernel of the sliding contact models; its specification is
:func:`pedrl.sim.motion.sliding.move_agents_sliding_torch`, to the bit (same float32 operations in the same order).
``_nearest_wall_kernel`` is ``pedrl.sim.motion.sliding._nearest_wall``."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch

from pedrl._numba import cached_njit
from pedrl.sim.geometry import Geometry, Walls
from pedrl.sim.grid_kernel import (
    RELATIVE_SLACK,
    SLACK,
    bin_points,
    bin_segments,
    cell_range,
    make_cells,
)
from pedrl.sim.motion.common import (
    HEADWAY,
    PAIR_MARGIN,
    STEERING_CUTOFF,
    STEERING_NAMES,
    YIELD,
    KernelMoves,
    Movement,
    Search,
    Steering,
    neighbour_search,
    steering_constant,
)
from pedrl.sim.motion.sequential_kernel import _passes_exits
from pedrl.sim.sensing_kernel import room_search

__all__ = ["SEARCH", "SlidingConstants", "constants_of", "sliding_constants", "sliding_room", "sliding_substeps"]

SEARCH = neighbour_search()
"""The default neighbour search (:func:`pedrl.sim.motion.common.neighbour_search`)."""


class SlidingConstants(NamedTuple):
    """The constants of one decision under a sliding model (``slide``, ``headway``, ``yield``, ``continuous``), read by
    name by :func:`sliding_room`: built from the room's kernel constants by :func:`sliding_constants` (the fused
    step) and from the decision's arguments by :func:`sliding_substeps` (the torch room's dispatcher)."""

    radius_sq: np.float32
    """``r^2`` (m^2): a wall closer than ``r`` is entered."""
    contact_sq: np.float32
    """``(2 r)^2`` (m^2): a body closer than ``2 r`` is entered."""
    substep_length: np.float32
    """The duration of a sub-step (s)."""
    num_substeps: int
    headway: bool
    """The collision-free speed rule (``headway``, ``yield``, ``continuous``) with ``time_gap``."""
    yield_order: bool
    """Only bodies earlier in the order of action slow a mover (``yield``)."""
    time_gap: np.float32
    """``T`` (s) of the headway rule (1 where it is off, unused then)."""
    diameter: np.float32
    """``2 r`` (m)."""
    margin: np.float32
    """The exits' crossing margin (m, ``PAIR_MARGIN``)."""
    steer: bool
    """The direction rule of ``motion=continuous``, with the four values below (1 where it is off)."""
    neighbour_strength: np.float32
    neighbour_range: np.float32
    wall_strength: np.float32
    wall_range: np.float32
    search: Search
    """The neighbour search: grids from ``search.min_agents`` agents."""


@cached_njit(nogil=True)
def sliding_constants(room):
    """The :class:`SlidingConstants` of a decision of a room whose kernel constants are ``room``
    (:class:`pedrl.sim.params.KernelRoom`)."""
    radius = room.agent_radius
    return SlidingConstants(
        np.float32(radius * radius), np.float32(4.0 * radius * radius),
        np.float32(room.decision_length / room.num_substeps), room.num_substeps, room.contact >= HEADWAY,
        room.contact == YIELD, np.float32(room.time_gap), np.float32(2.0 * radius), np.float32(PAIR_MARGIN),
        room.continuous, room.steering_neighbour_strength, room.steering_neighbour_range, room.steering_wall_strength,
        room.steering_wall_range, room_search(room),
    )  # fmt: skip


@cached_njit(nogil=True, inline="always")
def _from_wall(x, y, s, starts, directions, inverse):
    """``(x, y)`` minus the closest point of wall ``s``: the projection clamped to the segment."""
    along = ((x - starts[s, 0]) * directions[s, 0] + (y - starts[s, 1]) * directions[s, 1]) * inverse[s]
    along = min(max(along, np.float32(0.0)), np.float32(1.0))
    return x - (starts[s, 0] + along * directions[s, 0]), y - (starts[s, 1] + along * directions[s, 1])


@cached_njit(nogil=True, inline="always")
def _nearest_wall_kernel(x, y, starts, directions, inverse, walls, c):
    """Squared distance to the nearest wall and that wall (``pedrl.sim.motion.sliding._nearest_wall`` of one point):
    over every wall, or (``c >= 0``) over those listed in cell ``c`` of ``walls`` (ascending: the same first
    minimum)."""
    nearest = np.float32(np.inf)
    index = 0
    first, last = (walls.start[c], walls.start[c + 1]) if c >= 0 else (0, starts.shape[0])
    for k in range(first, last):
        s = walls.items[k] if c >= 0 else k
        gap_x, gap_y = _from_wall(x, y, s, starts, directions, inverse)
        distance_sq = gap_x * gap_x + gap_y * gap_y
        if distance_sq < nearest:
            nearest = distance_sq
            index = s
    return nearest, index


@cached_njit(nogil=True, inline="always")
def _nearest_body(x, y, mover, here_x, here_y, current, present_row, grid, cells, reach):
    """Squared distance to the nearest present body other than ``mover``, and that body: over every body, or (``grid``)
    over those binned within ``reach`` of ``(here_x, here_y)``, the first minimum by index either way."""
    nearest = np.float32(np.inf)
    index = 0
    x0, x1, y0, y1 = cell_range(cells, here_x, here_y, reach) if grid else (0, 0, 0, 0)
    nx = cells.shape[0]
    for row in range(y0, y1 + 1):
        first, last = (cells.start[row * nx + x0], cells.start[row * nx + x1 + 1]) if grid else (0, current.shape[0])
        for k in range(first, last):
            j = cells.items[k] if grid else k
            if j == mover or not present_row[j]:
                continue
            gap_x = x - current[j, 0]
            gap_y = y - current[j, 1]
            distance_sq = gap_x * gap_x + gap_y * gap_y
            if distance_sq < nearest or (distance_sq == nearest and j < index):
                nearest = distance_sq
                index = j
    return nearest, index


_CUTOFF = np.float32(STEERING_CUTOFF)


@cached_njit(nogil=True, inline="always")
def _push(fx, fy, dx, dy, limit, strength, reach):
    """``(fx, fy)`` plus the repulsion ``strength exp((limit - d) / reach)`` along ``(dx, dy) / d`` (``add`` of
    ``pedrl.sim.motion.sliding.steer``), dropped below the cutoff."""
    distance = np.sqrt(dx * dx + dy * dy)
    exponent = (limit - distance) / reach
    if exponent > _CUTOFF and distance > np.float32(0.0):
        weight = strength * np.float32(np.exp(np.float64(exponent)))  # rounded through float64, as the torch twin
        fx = fx + weight * (dx / distance)
        fy = fy + weight * (dy / distance)
    return fx, fy


@cached_njit(nogil=True, inline="always")
def _cell_of(cells, x, y):
    """The index of the cell holding ``(x, y)``."""
    x0, _, y0, _ = cell_range(cells, x, y, np.float32(0.0))
    return y0 * cells.shape[0] + x0


@cached_njit(nogil=True, inline="always")
def _steer(i, r, velocities, current, present_row, starts, directions, inverse, radius, diameter, motion, grid,
           cells, walls, c, reach, near):  # fmt: skip
    """The wanted velocity of mover ``i`` under ``motion=continuous`` (``pedrl.sim.motion.sliding.steer`` of one
    agent): its commanded speed along the direction rule's unit vector (``motion``: :class:`SlidingConstants`). With
    ``grid``, over the bodies binned within ``reach`` (the rule's cut-off) and the walls listed in the mover's cell
    ``c``, summed in index order as the loop over all sums them; ``near`` ``(N,)`` int64 scratch."""
    zero = np.float32(0.0)
    cx = velocities[r, i, 0]
    cy = velocities[r, i, 1]
    speed = np.sqrt(cx * cx + cy * cy)
    if not speed > zero:
        return zero, zero
    ex = cx / speed
    ey = cy / speed
    fx = ex
    fy = ey
    strength, reach_of = motion.neighbour_strength, motion.neighbour_range
    x = current[i, 0]
    y = current[i, 1]
    if grid:  # the bodies whose term survives the cut-off, then summed in index order
        count = 0
        x0, x1, y0, y1 = cell_range(cells, x, y, reach)
        nx = cells.shape[0]
        for row in range(y0, y1 + 1):
            for k in range(cells.start[row * nx + x0], cells.start[row * nx + x1 + 1]):
                j = cells.items[k]
                if j == i or not present_row[j]:
                    continue
                dx = x - current[j, 0]
                dy = y - current[j, 1]
                distance = np.sqrt(dx * dx + dy * dy)
                if (diameter - distance) / motion.neighbour_range > _CUTOFF and distance > zero:
                    near[count] = j
                    count += 1
        near[:count].sort()
        for k in range(count):
            j = near[k]
            fx, fy = _push(fx, fy, x - current[j, 0], y - current[j, 1], diameter, strength, reach_of)
    else:
        for j in range(current.shape[0]):
            if j != i and present_row[j]:
                fx, fy = _push(fx, fy, x - current[j, 0], y - current[j, 1], diameter, strength, reach_of)
    first, last = (walls.start[c], walls.start[c + 1]) if grid else (0, starts.shape[0])
    for k in range(first, last):
        dx, dy = _from_wall(x, y, walls.items[k] if grid else k, starts, directions, inverse)
        fx, fy = _push(fx, fy, dx, dy, radius, motion.wall_strength, motion.wall_range)
    norm = np.sqrt(fx * fx + fy * fy)
    if norm > zero:
        return fx / norm * speed, fy / norm * speed
    return ex * speed, ey * speed


@cached_njit(nogil=True)
def _grids(r, velocities, current, present_row, starts, directions, inverse, radius, motion, num_substeps):
    """The grids of one decision of room ``r`` (``motion``: :class:`SlidingConstants`; ``num_substeps`` 0 without a
    grid): the bodies' cells (binned at each sub-step) over the box the present bodies cannot leave in the decision,
    the walls listed per cell, and the reaches (m) of the searches: the direction rule's bodies (its cut-off), the
    headway rule's (a gap of ``v T`` leaves the speed), a contact (the two moves of a sub-step); each times the
    search's ``reach_scale`` (1 but in the tests' control)."""
    diameter, substep_length, time_gap = motion.diameter, motion.substep_length, motion.time_gap
    headway, steer, scale = motion.headway, motion.steer, motion.search.reach_scale
    fastest = np.float32(0.0)
    low_x = low_y = np.float32(np.inf)
    high_x = high_y = np.float32(-np.inf)
    present = 0
    for i in range(current.shape[0]):
        if present_row[i]:
            present += 1
            fastest = max(fastest, np.sqrt(velocities[r, i, 0] ** 2 + velocities[r, i, 1] ** 2))
            low_x, high_x = min(low_x, current[i, 0]), max(high_x, current[i, 0])
            low_y, high_y = min(low_y, current[i, 1]), max(high_y, current[i, 1])
    step = fastest * substep_length
    slack = step * np.float32(num_substeps) + SLACK
    one = np.float32(1.0) + RELATIVE_SLACK
    body = (diameter + np.float32(2.0) * step) * one * scale + SLACK
    steer_reach = (diameter - _CUTOFF * motion.neighbour_range) * one * scale + SLACK if steer else np.float32(0.0)
    headway_reach = (diameter + fastest * time_gap) * one * scale + SLACK if headway else np.float32(0.0)
    steer_wall = radius - _CUTOFF * motion.wall_range if steer else np.float32(0.0)
    wall = (max(steer_wall, radius + step)) * one * scale + SLACK
    cells = make_cells(low_x - slack, low_y - slack, high_x + slack, high_y + slack,
                       max(body, steer_reach, headway_reach), current.shape[0], present)  # fmt: skip
    return cells, bin_segments(cells, starts, directions, inverse, wall), body, steer_reach, headway_reach


@cached_njit(nogil=True)
def _sliding(positions, velocities, going, present, order, segments, exits, motion, out):
    num_replicas, num_agents = going.shape
    wanted = np.empty((num_agents, 2), dtype=np.float32)
    current = np.empty((num_agents, 2), dtype=np.float32)
    factor = np.empty(num_agents, dtype=np.float32)
    rank_of = np.empty(num_agents, dtype=np.int64)
    for r in range(num_replicas):
        sliding_room(
            r, positions, velocities, going, present, order, segments, exits, motion, out, wanted, current, factor,
            rank_of,
        )  # fmt: skip


@cached_njit(nogil=True)
def sliding_room(
    r, positions, velocities, going, present, order, segments, exits, motion, out, wanted, current, factor, rank_of
):  # fmt: skip
    """The sub-steps of replica ``r`` (of :func:`sliding_substeps`) into ``out``
    (:class:`pedrl.sim.motion.common.KernelMoves`): ``segments`` is :class:`pedrl.sim.geometry.Walls`, ``exits``
    :class:`pedrl.sim.geometry.Exits`, ``motion`` :class:`SlidingConstants` (with a grid, the same numbers as every
    pair: :mod:`pedrl.sim.grid_kernel`); ``wanted``, ``current`` ``(N, 2)``, ``factor`` and ``rank_of`` ``(N,)`` are
    scratch."""
    starts, directions, inverse = segments.starts, segments.directions, segments.inverse
    exit_start, exit_normal, exit_tangent, exit_span = exits.start, exits.normal, exits.tangent, exits.span
    radius_sq, contact_sq, substep_length = motion.radius_sq, motion.contact_sq, motion.substep_length
    num_substeps, headway, yield_order = motion.num_substeps, motion.headway, motion.yield_order
    time_gap, diameter, margin, steer = motion.time_gap, motion.diameter, motion.margin, motion.steer
    blocked, cut_wall, cut_body, reached = out.blocked, out.cut_wall, out.cut_body, out.reached
    num_agents = going.shape[1]
    zero = np.float32(0.0)
    one = np.float32(1.0)
    if yield_order:  # each agent's place in the order of action, for the right of way
        for k in range(num_agents):
            rank_of[order[r, k]] = k
    for i in range(num_agents):
        current[i, 0] = positions[r, i, 0]
        current[i, 1] = positions[r, i, 1]
        wanted[i, 0] = velocities[r, i, 0] if present[r, i] else zero
        wanted[i, 1] = velocities[r, i, 1] if present[r, i] else zero
    radius = diameter * np.float32(0.5)  # float32(r) exactly
    grid = num_agents >= motion.search.min_agents
    cells, walls, body_reach, steer_reach, headway_reach = _grids(
        r, velocities, current, present[r], starts, directions, inverse, radius, motion, num_substeps if grid else 0
    )
    near = np.empty(num_agents if grid else 0, np.int64)
    nx = cells.shape[0]
    for _ in range(num_substeps):
        anyone = False
        for i in range(num_agents):
            anyone |= going[r, i]
        if not anyone:
            break
        if grid:
            bin_points(cells, current, present[r])
        if steer:  # the direction rule, from the positions at the start of the sub-step
            for i in range(num_agents):
                wanted[i, 0], wanted[i, 1] = zero, zero
                if present[r, i]:
                    c = _cell_of(cells, current[i, 0], current[i, 1]) if grid else -1
                    wanted[i, 0], wanted[i, 1] = _steer(
                        i, r, velocities, current, present[r], starts, directions, inverse, radius, diameter, motion,
                        grid, cells, walls, c, steer_reach, near,
                    )  # fmt: skip
        for i in range(num_agents):  # headway_factors, from the positions at the start of the sub-step
            factor[i] = one
            if not headway:
                continue
            speed = np.sqrt(wanted[i, 0] * wanted[i, 0] + wanted[i, 1] * wanted[i, 1])
            if not speed > zero:
                continue
            ex = wanted[i, 0] / speed
            ey = wanted[i, 1] / speed
            spacing = np.float32(np.inf)
            x0, x1, y0, y1 = cell_range(cells, current[i, 0], current[i, 1], headway_reach) if grid else (0, 0, 0, 0)
            for row in range(y0, y1 + 1):  # the bodies binned within reach, or (no grid) all
                first, last = (cells.start[row * nx + x0], cells.start[row * nx + x1 + 1]) if grid else (0, num_agents)
                for k in range(first, last):
                    j = cells.items[k] if grid else k
                    if j == i or not present[r, j] or (yield_order and rank_of[j] > rank_of[i]):
                        continue
                    ox = current[j, 0] - current[i, 0]
                    oy = current[j, 1] - current[i, 1]
                    if ox * ex + oy * ey >= zero and abs(ox * ey - oy * ex) <= diameter:
                        spacing = min(spacing, np.sqrt(ox * ox + oy * oy) - diameter)
            factor[i] = min(speed, max(spacing / time_gap, zero)) / speed
        for rank in range(num_agents):
            i = order[r, rank]
            if not going[r, i]:
                continue
            here_x = current[i, 0]
            here_y = current[i, 1]
            vx = wanted[i, 0]
            vy = wanted[i, 1]
            scale = factor[i] * substep_length
            target_x = here_x + vx * scale
            target_y = here_y + vy * scale
            c = _cell_of(cells, here_x, here_y) if grid else -1  # of the mover's binned place (not moved yet)
            wall_sq, wall = _nearest_wall_kernel(target_x, target_y, starts, directions, inverse, walls, c)
            body_sq, body = _nearest_body(target_x, target_y, i, here_x, here_y, current, present[r], grid, cells,
                                          body_reach)  # fmt: skip
            hits_wall = wall_sq < radius_sq
            hits_body = body_sq < contact_sq
            if hits_wall or hits_body:
                if hits_wall:  # from the closest point of that wall to the mover's centre
                    normal_x, normal_y = _from_wall(here_x, here_y, wall, starts, directions, inverse)
                else:
                    normal_x = here_x - current[body, 0]
                    normal_y = here_y - current[body, 1]
                norm = np.sqrt(normal_x * normal_x + normal_y * normal_y)
                if not norm > zero:
                    norm = one
                normal_x = normal_x / norm
                normal_y = normal_y / norm
                inward = min(vx * normal_x + vy * normal_y, zero)
                vx = vx - inward * normal_x
                vy = vy - inward * normal_y
                wanted[i, 0] = vx
                wanted[i, 1] = vy
                target_x = here_x + vx * scale
                target_y = here_y + vy * scale
                slid_sq, _ = _nearest_wall_kernel(target_x, target_y, starts, directions, inverse, walls, c)
                slid_body_sq, _ = _nearest_body(target_x, target_y, i, here_x, here_y, current, present[r], grid,
                                                cells, body_reach)  # fmt: skip
                slid_wall = slid_sq < radius_sq
                slid_body = slid_body_sq < contact_sq
                if hits_wall or slid_wall:
                    cut_wall[r, i] = True
                if hits_body or slid_body:
                    cut_body[r, i] = True
                if slid_wall or slid_body:  # stops for the decision, or (steer) waits for the next sub-step
                    blocked[r, i] = True
                    going[r, i] = steer
                    continue
            current[i, 0] = target_x
            current[i, 1] = target_y
            step_x = target_x - here_x
            step_y = target_y - here_y
            depth = np.sqrt(step_x * step_x + step_y * step_y) + margin
            if _passes_exits(target_x, target_y, depth, exit_start, exit_normal, exit_tangent, exit_span):
                reached[r, i] = True
                present[r, i] = False
                going[r, i] = False
    for i in range(num_agents):
        out.moved_to[r, i, 0] = current[i, 0]
        out.moved_to[r, i, 1] = current[i, 1]


def constants_of(
    *,
    agent_radius: float,
    substep_length: float,
    num_substeps: int,
    time_gap: float | None,
    yield_to_earlier: bool,
    steering: Steering | None,
    search: Search = SEARCH,
) -> SlidingConstants:
    """The :class:`SlidingConstants` of :func:`sliding_substeps`'s arguments (those of a room's kernel constants are
    :func:`sliding_constants`'s: ``tests/sim/test_params.py`` holds the two equal)."""
    return SlidingConstants(
        radius_sq=np.float32(agent_radius * agent_radius),
        contact_sq=np.float32(4.0 * agent_radius * agent_radius),
        substep_length=np.float32(substep_length),
        num_substeps=num_substeps,
        headway=time_gap is not None,
        yield_order=yield_to_earlier,
        time_gap=np.float32(1.0 if time_gap is None else time_gap),
        diameter=np.float32(2.0 * agent_radius),
        margin=np.float32(PAIR_MARGIN),
        steer=steering is not None,
        **{name: steering_constant(steering, name) for name in STEERING_NAMES},
        search=search,
    )


def sliding_substeps(
    *,
    positions: torch.Tensor,
    velocities: torch.Tensor,
    active: torch.Tensor,
    geometry: Geometry,
    wall_starts: torch.Tensor,
    wall_directions: torch.Tensor,
    wall_inverse: torch.Tensor,
    agent_radius: float,
    substep_length: float,
    num_substeps: int,
    order: torch.Tensor,
    time_gap: float | None,
    yield_to_earlier: bool = False,
    steering: Steering | None = None,
    search: Search = SEARCH,
) -> Movement:
    """:func:`pedrl.sim.motion.sliding.move_agents_sliding_torch`, agent by agent, compiled (same float32
    operations, same order).

    Args:
        positions: ``(R, N, 2)`` float32 at the start of the decision.
        velocities: ``(R, N, 2)`` float32 commanded velocities (m/s).
        active: ``(R, N)`` bool, agents in the room.
        geometry: the room (its exits).
        wall_starts: ``(S, 2)`` float32 wall starts.
        wall_directions: ``(S, 2)`` float32 wall directions (end minus start).
        wall_inverse: ``(S,)`` float32 inverse squared wall lengths (0 for a point).
        agent_radius: body radius (m).
        substep_length: duration of a sub-step (s).
        num_substeps: ``S``.
        order: ``(R, N)`` int64, the agents in their order of action.
        time_gap: ``T`` (s) of the headway rule, or ``None`` for ``slide``.
        yield_to_earlier: the ``yield`` rule: only bodies earlier in ``order`` slow a mover.
        steering: ``motion=continuous``'s direction rule, or None.
        search: :data:`SEARCH` (the tests change it).

    Returns:
        The :class:`~pedrl.sim.motion.Movement` of the decision.
    """
    shape = active.shape
    out = torch.empty_like(positions)
    blocked = torch.zeros(shape, dtype=torch.bool)
    cut_wall = torch.zeros(shape, dtype=torch.bool)
    cut_body = torch.zeros(shape, dtype=torch.bool)
    reached = torch.zeros(shape, dtype=torch.bool)
    going = active & (velocities != 0).any(-1)
    motion = constants_of(
        agent_radius=agent_radius,
        substep_length=substep_length,
        num_substeps=num_substeps,
        time_gap=time_gap,
        yield_to_earlier=yield_to_earlier,
        steering=steering,
        search=search,
    )
    # the wall segments given; the walls' boxes are the stop rule's, unread here
    segments = Walls(
        starts=wall_starts.numpy(),
        directions=wall_directions.numpy(),
        inverse=wall_inverse.numpy(),
        aligned=np.zeros(0, np.bool_),
        low=np.zeros((0, 2), np.float32),
        high=np.zeros((0, 2), np.float32),
    )
    flags = (blocked.numpy(), cut_wall.numpy(), cut_body.numpy(), reached.numpy())
    _sliding(
        positions.contiguous().numpy(),
        velocities.contiguous().numpy(),
        going.numpy().copy(),
        active.numpy().copy(),
        order.contiguous().numpy(),
        segments,
        geometry.kernel_exits(),
        motion,
        KernelMoves(out.numpy(), *flags),
    )
    return Movement(
        positions=out, blocked=blocked, crashed_wall=cut_wall, crashed_agent=cut_body & ~cut_wall, reached=reached
    )

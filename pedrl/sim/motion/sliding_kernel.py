"""Numba kernel of the sliding contact models; its specification is
:func:`pedrl.sim.motion.sliding.move_agents_sliding_torch`, to the bit (same float32 operations in the same order).
``_nearest_wall_kernel`` is ``pedrl.sim.motion.sliding._nearest_wall``."""

from __future__ import annotations

import numpy as np
import torch

from pedrl._numba import cached_njit
from pedrl.sim.geometry import Geometry
from pedrl.sim.motion.common import PAIR_MARGIN, STEERING_CUTOFF, Movement, Steering, steering_array
from pedrl.sim.motion.sequential_kernel import _passes_exits

__all__ = ["sliding_room", "sliding_substeps"]


@cached_njit(nogil=True, inline="always")
def _nearest_wall_kernel(x, y, starts, directions, inverse):
    """Squared distance to the nearest wall and that wall (``pedrl.sim.motion.sliding._nearest_wall`` of one point): the
    projection clamped to each segment."""
    nearest = np.float32(np.inf)
    index = 0
    for s in range(starts.shape[0]):
        along = ((x - starts[s, 0]) * directions[s, 0] + (y - starts[s, 1]) * directions[s, 1]) * inverse[s]
        along = min(max(along, np.float32(0.0)), np.float32(1.0))
        gap_x = x - (starts[s, 0] + along * directions[s, 0])
        gap_y = y - (starts[s, 1] + along * directions[s, 1])
        distance_sq = gap_x * gap_x + gap_y * gap_y
        if distance_sq < nearest:
            nearest = distance_sq
            index = s
    return nearest, index


@cached_njit(nogil=True, inline="always")
def _nearest_body(x, y, mover, current, present_row):
    """Squared distance to the nearest present body other than ``mover``, and that body."""
    nearest = np.float32(np.inf)
    index = 0
    for j in range(current.shape[0]):
        if j == mover or not present_row[j]:
            continue
        gap_x = x - current[j, 0]
        gap_y = y - current[j, 1]
        distance_sq = gap_x * gap_x + gap_y * gap_y
        if distance_sq < nearest:
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
def _steer(i, r, velocities, current, present_row, starts, directions, inverse, radius, diameter, steering):
    """The wanted velocity of mover ``i`` under ``motion=continuous`` (``pedrl.sim.motion.sliding.steer`` of one
    agent): its commanded speed along the direction rule's unit vector. ``steering`` is ``(a, D, b, B)``."""
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
    x = current[i, 0]
    y = current[i, 1]
    for j in range(current.shape[0]):
        if j == i or not present_row[j]:
            continue
        fx, fy = _push(fx, fy, x - current[j, 0], y - current[j, 1], diameter, steering[0], steering[1])
    for s in range(starts.shape[0]):
        along = ((x - starts[s, 0]) * directions[s, 0] + (y - starts[s, 1]) * directions[s, 1]) * inverse[s]
        along = min(max(along, zero), np.float32(1.0))
        dx = x - (starts[s, 0] + along * directions[s, 0])
        dy = y - (starts[s, 1] + along * directions[s, 1])
        fx, fy = _push(fx, fy, dx, dy, radius, steering[2], steering[3])
    norm = np.sqrt(fx * fx + fy * fy)
    if norm > zero:
        return fx / norm * speed, fy / norm * speed
    return ex * speed, ey * speed


@cached_njit(nogil=True)
def _sliding(
    positions, velocities, going, present, order, starts, directions, inverse, exit_start, exit_normal,
    exit_tangent, exit_span, radius_sq, contact_sq, substep_length, num_substeps, headway, yield_order, time_gap,
    diameter, margin, steer, steering, out, blocked, cut_wall, cut_body, reached,
):  # fmt: skip
    num_replicas, num_agents = going.shape
    wanted = np.empty((num_agents, 2), dtype=np.float32)
    current = np.empty((num_agents, 2), dtype=np.float32)
    factor = np.empty(num_agents, dtype=np.float32)
    rank_of = np.empty(num_agents, dtype=np.int64)
    for r in range(num_replicas):
        sliding_room(
            r, positions, velocities, going, present, order, starts, directions, inverse, exit_start, exit_normal,
            exit_tangent, exit_span, radius_sq, contact_sq, substep_length, num_substeps, headway, yield_order,
            time_gap, diameter, margin, steer, steering, out, blocked, cut_wall, cut_body, reached, wanted, current,
            factor, rank_of,
        )  # fmt: skip


@cached_njit(nogil=True)
def sliding_room(
    r, positions, velocities, going, present, order, starts, directions, inverse, exit_start, exit_normal,
    exit_tangent, exit_span, radius_sq, contact_sq, substep_length, num_substeps, headway, yield_order, time_gap,
    diameter, margin, steer, steering, out, blocked, cut_wall, cut_body, reached,
    wanted, current, factor, rank_of,
):  # fmt: skip
    """The sub-steps of replica ``r`` (of :func:`sliding_substeps`); ``wanted``, ``current`` ``(N, 2)``, ``factor`` and
    ``rank_of`` ``(N,)`` are scratch. ``steer``: ``motion=continuous``, with ``steering`` ``(a, D, b, B)`` float32."""
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
    for _ in range(num_substeps):
        anyone = False
        for i in range(num_agents):
            anyone |= going[r, i]
        if not anyone:
            break
        if steer:  # the direction rule, from the positions at the start of the sub-step
            radius = diameter * np.float32(0.5)  # float32(r) exactly
            for i in range(num_agents):
                wanted[i, 0], wanted[i, 1] = zero, zero
                if present[r, i]:
                    wanted[i, 0], wanted[i, 1] = _steer(
                        i, r, velocities, current, present[r], starts, directions, inverse, radius, diameter, steering
                    )
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
            for j in range(num_agents):
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
            wall_sq, wall = _nearest_wall_kernel(target_x, target_y, starts, directions, inverse)
            body_sq, body = _nearest_body(target_x, target_y, i, current, present[r])
            hits_wall = wall_sq < radius_sq
            hits_body = body_sq < contact_sq
            if hits_wall or hits_body:
                if hits_wall:  # closest point of that wall to the mover's centre
                    along = (
                        (here_x - starts[wall, 0]) * directions[wall, 0]
                        + (here_y - starts[wall, 1]) * directions[wall, 1]
                    ) * inverse[wall]
                    along = min(max(along, zero), one)
                    normal_x = here_x - (starts[wall, 0] + along * directions[wall, 0])
                    normal_y = here_y - (starts[wall, 1] + along * directions[wall, 1])
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
                slid_sq, _ = _nearest_wall_kernel(target_x, target_y, starts, directions, inverse)
                slid_body_sq, _ = _nearest_body(target_x, target_y, i, current, present[r])
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
        out[r, i, 0] = current[i, 0]
        out[r, i, 1] = current[i, 1]


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
    _sliding(
        positions.contiguous().numpy(),
        velocities.contiguous().numpy(),
        going.numpy().copy(),
        active.numpy().copy(),
        order.contiguous().numpy(),
        wall_starts.numpy(),
        wall_directions.numpy(),
        wall_inverse.numpy(),
        geometry.exits[:, 0].contiguous().numpy(),
        geometry.exit_normals.contiguous().numpy(),
        geometry.exit_tangents.contiguous().numpy(),
        geometry.exit_spans.contiguous().numpy(),
        np.float32(agent_radius * agent_radius),
        np.float32(4.0 * agent_radius * agent_radius),
        np.float32(substep_length),
        num_substeps,
        time_gap is not None,
        yield_to_earlier,
        np.float32(1.0 if time_gap is None else time_gap),
        np.float32(2.0 * agent_radius),
        np.float32(PAIR_MARGIN),
        steering is not None,
        steering_array(steering),
        out.numpy(),
        blocked.numpy(),
        cut_wall.numpy(),
        cut_body.numpy(),
        reached.numpy(),
    )
    return Movement(
        positions=out, blocked=blocked, crashed_wall=cut_wall, crashed_agent=cut_body & ~cut_wall, reached=reached
    )

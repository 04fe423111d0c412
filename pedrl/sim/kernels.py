"""Numba kernels of the room's moves; the specification of each is its torch twin ``pedrl.sim.dynamics.*_torch``.

On the CPU a decision of a few hundred agents is a few hundred small torch operations of microseconds each; the
same work written as loops and compiled costs a few microseconds in all. Each kernel here reproduces its torch twin
of `pedrl.sim.dynamics` to the bit (same float32 operations in the same order), which the tests check; the torch
code stays the reference and the path on other devices, and `pedrl.sim.dynamics` chooses between the two:

- :func:`sequential_substeps`: the sub-steps of :func:`pedrl.sim.dynamics.move_agents_sequential_torch`, whose own
  specification is the literal agent-by-agent loop :func:`pedrl.sim.reference.move_agents_sequential_literal`
  (this kernel is that loop, compiled);
- :func:`sliding_substeps`: :func:`pedrl.sim.dynamics.move_agents_sliding_torch`;
- ``_nearest_wall_kernel``: ``pedrl.sim.dynamics._nearest_wall``; ``_touches_walls`` and ``_passes_exits``:
  :meth:`Geometry.touches_walls <pedrl.sim.geometry.Geometry.touches_walls>` (axis-aligned walls) and
  :meth:`Geometry.passes_exits <pedrl.sim.geometry.Geometry.passes_exits>` of one point.
"""

from __future__ import annotations

import numpy as np
import torch

from pedrl._numba import cached_njit
from pedrl.sim.geometry import Geometry
from pedrl.sim.movement import PAIR_MARGIN, Movement

__all__ = ["sequential_room", "sequential_substeps", "sliding_room", "sliding_substeps"]


@cached_njit(nogil=True, inline="always")
def _touches_walls(x, y, low, high, radius_sq):
    """`Geometry.touches_walls` of an axis-aligned geometry: clamp to each wall's box, nearest squared gap."""
    nearest = np.float32(np.inf)
    for s in range(low.shape[0]):
        gap_x = min(max(x, low[s, 0]), high[s, 0]) - x
        gap_y = min(max(y, low[s, 1]), high[s, 1]) - y
        nearest = min(nearest, gap_x * gap_x + gap_y * gap_y)
    return nearest < radius_sq


@cached_njit(nogil=True, inline="always")
def _passes_exits(x, y, depth, start, normal, tangent, span):
    """`Geometry.passes_exits` of one point."""
    for e in range(start.shape[0]):
        offset_x = x - start[e, 0]
        offset_y = y - start[e, 1]
        beyond = offset_x * normal[e, 0] + offset_y * normal[e, 1]
        along = offset_x * tangent[e, 0] + offset_y * tangent[e, 1]
        if beyond >= 0 and beyond < depth and along >= 0 and along <= span[e]:
            return True
    return False


@cached_njit(nogil=True)
def _sequential(
    positions, step, going, present, depth, walls, low, high, radius_sq, start, normal, tangent, span,
    order, contact_sq, out, blocked, crashed_wall, reached,
):  # fmt: skip
    num_replicas, num_agents = going.shape
    moved = np.zeros(num_agents, dtype=np.float32)  # sub-steps moved, per agent of the replica
    acted_moved = np.zeros(num_agents, dtype=np.bool_)  # moved in this sub-step (it acted already)
    passed = np.zeros(num_agents, dtype=np.bool_)
    current = np.empty((num_agents, 2), dtype=np.float32)
    for r in range(num_replicas):
        sequential_room(
            r, positions, step, going, present, depth, walls, low, high, radius_sq, start, normal, tangent, span,
            order, contact_sq, out, blocked, crashed_wall, reached, moved, acted_moved, passed, current,
        )  # fmt: skip


@cached_njit(nogil=True)
def sequential_room(
    r, positions, step, going, present, depth, walls, low, high, radius_sq, start, normal, tangent, span,
    order, contact_sq, out, blocked, crashed_wall, reached, moved, acted_moved, passed, current,
):  # fmt: skip
    """The sub-steps of replica ``r`` (of :func:`sequential_substeps`); ``moved``, ``acted_moved``, ``passed`` ``(N,)``
    and ``current`` ``(N, 2)`` are scratch."""
    num_agents = going.shape[1]
    num_substeps = walls.shape[0]
    own_walls = low.shape[0] > 0  # axis-aligned walls: tested here, else ``walls`` holds the tests
    for i in range(num_agents):
        moved[i] = 0.0
        current[i, 0] = positions[r, i, 0]
        current[i, 1] = positions[r, i, 1]
    for k in range(num_substeps):
        anyone = False
        for i in range(num_agents):
            anyone |= going[r, i]
        if not anyone:
            break
        scale = np.float32(k + 1)
        for i in range(num_agents):
            acted_moved[i] = False
            passed[i] = False
        for rank in range(num_agents):
            i = order[r, rank]
            if not going[r, i]:
                continue
            proposal_x = positions[r, i, 0] + scale * step[r, i, 0]
            proposal_y = positions[r, i, 1] + scale * step[r, i, 1]
            if _touches_walls(proposal_x, proposal_y, low, high, radius_sq) if own_walls else walls[k, r, i]:
                blocked[r, i] = True
                crashed_wall[r, i] = True
                going[r, i] = False
                continue
            hit = False
            for j in range(num_agents):
                if j == i or not present[r, j]:
                    continue
                if acted_moved[j]:  # acted before i and moved: it stands on its proposal
                    other_x = positions[r, j, 0] + scale * step[r, j, 0]
                    other_y = positions[r, j, 1] + scale * step[r, j, 1]
                else:  # still to act, or stopped: where it stands
                    other_x = current[j, 0]
                    other_y = current[j, 1]
                gap_x = proposal_x - other_x
                gap_y = proposal_y - other_y
                if gap_x * gap_x + gap_y * gap_y < contact_sq:
                    hit = True
                    break
            if hit:
                blocked[r, i] = True
                going[r, i] = False
                continue
            acted_moved[i] = True
            if _passes_exits(proposal_x, proposal_y, depth[r, i], start, normal, tangent, span):
                reached[r, i] = True
                passed[i] = True
                going[r, i] = False
        for i in range(num_agents):
            if acted_moved[i]:
                moved[i] += np.float32(1.0)
            if passed[i]:
                present[r, i] = False
            current[i, 0] = positions[r, i, 0] + moved[i] * step[r, i, 0]
            current[i, 1] = positions[r, i, 1] + moved[i] * step[r, i, 1]
    for i in range(num_agents):
        out[r, i, 0] = current[i, 0]
        out[r, i, 1] = current[i, 1]


def sequential_substeps(
    *,
    positions: torch.Tensor,
    step: torch.Tensor,
    going: torch.Tensor,
    active: torch.Tensor,
    geometry: Geometry,
    agent_radius: float,
    num_substeps: int,
    walls: torch.Tensor | None,
    depth: torch.Tensor,
    priority: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The sub-steps of :func:`pedrl.sim.dynamics.move_agents_sequential_torch`, agent by agent, compiled.

    The float32 operations are torch's, in the same order: proposals ``p + k d``, the wall test of
    :meth:`Geometry.touches_walls` (done here for axis-aligned walls; ``walls (S, R, N)`` bool holds it for the
    others), :meth:`Geometry.passes_exits` with ``depth (R, N)``, and the contact test ``|gap|^2 < (2 r)^2``.

    Args:
        positions: ``(R, N, 2)`` float32 at the start of the decision.
        step: ``(R, N, 2)`` float32 move per sub-step.
        going: ``(R, N)`` bool, active agents with a non-zero step.
        active: ``(R, N)`` bool, agents in the room (bodies that collide).
        geometry: the room.
        agent_radius: body radius (m).
        num_substeps: ``S``.
        walls: ``(S, R, N)`` bool wall tests of the proposals, needed only when some wall is not axis-aligned.
        depth: ``(R, N)`` float32 depth of the exit test.
        priority: ``(R, N)`` order of action, lowest first.

    Returns:
        ``(positions, blocked, crashed_wall, reached)``.
    """
    shape = going.shape
    out = torch.empty_like(positions)
    blocked = torch.zeros(shape, dtype=torch.bool)
    crashed_wall = torch.zeros(shape, dtype=torch.bool)
    reached = torch.zeros(shape, dtype=torch.bool)
    if walls is None:
        walls = torch.zeros((num_substeps, *shape), dtype=torch.bool)  # the kernel tests the walls (if any)
        low, high = geometry.box_low, geometry.box_high
    else:
        low = high = torch.zeros((0, 2))
    radius_sq = agent_radius * agent_radius  # both products as torch's callers write them
    contact_sq = 4.0 * agent_radius * agent_radius
    _sequential(
        positions.contiguous().numpy(),
        step.contiguous().numpy(),
        going.numpy().copy(),
        active.numpy().copy(),
        depth.contiguous().numpy(),
        walls.contiguous().numpy(),
        low.contiguous().numpy(),
        high.contiguous().numpy(),
        np.float32(radius_sq),
        geometry.exits[:, 0].contiguous().numpy(),
        geometry.exit_normals.contiguous().numpy(),
        geometry.exit_tangents.contiguous().numpy(),
        geometry.exit_spans.contiguous().numpy(),
        priority.argsort(dim=1).numpy(),
        np.float32(contact_sq),
        out.numpy(),
        blocked.numpy(),
        crashed_wall.numpy(),
        reached.numpy(),
    )
    return out, blocked, crashed_wall, reached


@cached_njit(nogil=True, inline="always")
def _nearest_wall_kernel(x, y, starts, directions, inverse):
    """Squared distance to the nearest wall and that wall (``pedrl.sim.dynamics._nearest_wall`` of one point): the
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


@cached_njit(nogil=True)
def _sliding(
    positions, velocities, going, present, order, starts, directions, inverse, exit_start, exit_normal,
    exit_tangent, exit_span, radius_sq, contact_sq, substep_length, num_substeps, headway, yield_order, time_gap,
    diameter, margin, out, blocked, cut_wall, cut_body, reached,
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
            time_gap, diameter, margin, out, blocked, cut_wall, cut_body, reached, wanted, current, factor, rank_of,
        )  # fmt: skip


@cached_njit(nogil=True)
def sliding_room(
    r, positions, velocities, going, present, order, starts, directions, inverse, exit_start, exit_normal,
    exit_tangent, exit_span, radius_sq, contact_sq, substep_length, num_substeps, headway, yield_order, time_gap,
    diameter, margin, out, blocked, cut_wall, cut_body, reached,
    wanted, current, factor, rank_of,
):  # fmt: skip
    """The sub-steps of replica ``r`` (of :func:`sliding_substeps`); ``wanted``, ``current`` ``(N, 2)``, ``factor`` and
    ``rank_of`` ``(N,)`` are scratch."""
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
                if slid_wall or slid_body:
                    blocked[r, i] = True
                    going[r, i] = False
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
) -> Movement:
    """:func:`pedrl.sim.dynamics.move_agents_sliding_torch`, agent by agent, compiled (same float32 operations, same
    order).

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

    Returns:
        The :class:`~pedrl.sim.dynamics.Movement` of the decision.
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
        out.numpy(),
        blocked.numpy(),
        cut_wall.numpy(),
        cut_body.numpy(),
        reached.numpy(),
    )
    return Movement(
        positions=out, blocked=blocked, crashed_wall=cut_wall, crashed_agent=cut_body & ~cut_wall, reached=reached
    )

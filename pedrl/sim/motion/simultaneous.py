"""The motion model :class:`Simultaneous` (contact ``stop`` under the ``simultaneous`` collision rule): every mover's
proposal checked against every other's at once, all sub-steps of a decision resolved together (:func:`move_agents`);
its specification, sub-step after sub-step, is :func:`pedrl.sim.reference.move_agents_literal`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch

from pedrl.sim.geometry import Geometry
from pedrl.sim.motion.common import (
    PAIR_MARGIN,
    Motion,
    MotionModel,
    Movement,
    _discs_overlap,
    _swept_discs,
    _take,
    _upper_triangle,
)


@dataclass(frozen=True)
class Simultaneous(MotionModel):
    """Contact ``stop`` under the simultaneous collision rule: every mover's proposal is checked against every other's
    at once, and both parties of a conflict stop for the rest of the decision (:func:`move_agents`). No parameter: no
    order of action. Config: ``motion=simultaneous``. The fast path (the fused trial) does not run it."""

    name: ClassVar[str] = "simultaneous"
    contact: ClassVar[str] = "stop"
    rule: ClassVar[str] = "simultaneous"


def _wall_and_exit_times(
    geometry: Geometry,
    flat_positions: torch.Tensor,
    flat_step: torch.Tensor,
    moving: torch.Tensor,
    centre_x: torch.Tensor,
    centre_y: torch.Tensor,
    half_move: torch.Tensor,
    agent_radius: float,
    substep_row: torch.Tensor,
    never: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Step 1 of :func:`move_agents`: each agent's first sub-step touching a wall and first past an exit ``(R * N,)``
    (``never`` if none). A swept disc inside the clear box touches no wall and passes no exit, so only the other
    movers are traced sub-step by sub-step."""
    num_flat = flat_positions.shape[0]
    substep_scale = substep_row.to(flat_positions.dtype).unsqueeze(-1)  # (S, 1, 1)
    centres = torch.stack((centre_x, centre_y), dim=-1)
    clear = geometry.clear_of_walls(centres, margin=half_move + (agent_radius + PAIR_MARGIN))
    near_walls = (moving & ~clear).view(-1).nonzero().squeeze(1)  # (W,) flat agent indices
    first_wall = never.expand(num_flat).clone()  # (R * N,)
    first_door = first_wall.clone()
    if near_walls.shape[0] > 0:
        trace = _take(flat_positions, near_walls) + substep_scale * _take(flat_step, near_walls)  # (S, W, 2)
        hits_wall = geometry.touches_walls(trace, radius=agent_radius)
        first_wall.index_copy_(0, near_walls, torch.where(hits_wall, substep_row, never).amin(0))
        depth = _take(flat_step, near_walls).norm(dim=-1) + PAIR_MARGIN  # a crossing is at most one sub-step deep
        passes_door = geometry.passes_exits(trace, depth=depth)
        first_door.index_copy_(0, near_walls, torch.where(passes_door, substep_row, never).amin(0))
    return first_wall, first_door


def _collision_rounds(
    pairs: torch.Tensor,
    flat_positions: torch.Tensor,
    flat_step: torch.Tensor,
    moving: torch.Tensor,
    blocked_at: torch.Tensor,
    first_door: torch.Tensor,
    substep_row: torch.Tensor,
    never: torch.Tensor,
    contact_sq: float,
) -> torch.Tensor:
    """Step 3 of :func:`move_agents`: the collision rounds over the kept ``pairs (M, 3)`` (replica, i, j), in both
    orders (src proposes, dst is the obstacle), until no new agent is blocked. Returns the block times ``(R * N,)``."""
    num_replicas, num_agents = moving.shape
    num_flat, dtype = num_replicas * num_agents, flat_positions.dtype
    substep_scale = substep_row.to(dtype).unsqueeze(-1)  # (S, 1, 1)
    replica, first, second = pairs.unbind(1)
    one = replica * num_agents + first
    other = replica * num_agents + second
    src = torch.cat((one, other))  # (2M,)
    dst = torch.cat((other, one))
    proposals = _take(flat_positions, src) + substep_scale * _take(flat_step, src)  # (S, 2M, 2)
    dst_start, dst_step = _take(flat_positions, dst), _take(flat_step, dst)
    pair_replica = replica.repeat(2)
    src_still = ~_take(moving.view(-1), src)
    for _ in range(num_flat + 1):
        reached_at = torch.where(first_door < blocked_at, first_door, never)  # (R * N,)
        last_move = torch.minimum(blocked_at - 1, reached_at)  # last sub-step each agent moves in
        src_last = _take(last_move, src).masked_fill_(src_still, 0)  # a standing agent proposes nothing
        dst_substep = torch.minimum(substep_row, _take(last_move, dst))  # (S, 2M)
        gaps = proposals - (dst_start + dst_substep.to(dtype).unsqueeze(-1) * dst_step)  # (S, 2M, 2)
        conflict = (gaps * gaps).sum(-1) < contact_sq
        conflict &= (substep_row <= src_last) & (substep_row <= _take(reached_at, dst))
        first_conflict = torch.where(conflict, substep_row, never).amin(0)  # (2M,)
        if not bool((first_conflict < never).any()):
            break
        earliest = never.expand(num_replicas).clone()
        earliest = earliest.scatter_reduce_(0, pair_replica, first_conflict, reduce="amin")  # (R,)
        committed = torch.where(first_conflict == _take(earliest, pair_replica), first_conflict, never)
        blocked_at = blocked_at.scatter_reduce(0, src, committed, reduce="amin")
    else:  # pragma: no cover - each round blocks at least one agent for good
        raise RuntimeError("collision resolution did not converge")
    return blocked_at


def move_agents(
    *,
    positions: torch.Tensor,
    velocities: torch.Tensor,
    active: torch.Tensor,
    motion: Motion,
) -> Movement:
    """Move every active agent through one decision, sub-stepped, with the collision rule of the module.

    The sub-steps are resolved together rather than one after another. Without collisions agent ``i`` is at
    ``P_i[k] = p_i + k * d_i`` after sub-step ``k`` (``d_i`` the move per sub-step). A collision only stops
    agents, so the whole decision is described by one block time ``B_i`` per agent (the sub-step whose
    proposal was refused; ``S + 1`` if none) and one door time ``E_i``; after sub-step ``k`` the agent is at
    ``P_i[min(k, B_i - 1, E_i)]``.

    1. Walls and the door do not depend on other agents: ``B_i`` starts as the first sub-step whose proposal
       touches a wall (unless the agent passes an exit first) and ``E_i`` as the first past an exit. Only
       movers whose swept disc (the straight move widened by the radius) leaves the geometry's clear box
       (``[r, W - r] x [r, L - r]`` in the paper's room) are traced sub-step by sub-step; the others touch no wall.
    2. A conservative pre-filter (overlapping swept discs) keeps only the pairs that could ever touch during
       the decision. With none, the decision is already solved.
    3. Otherwise, repeat: evaluate every kept pair at every sub-step under the current block times, find each
       replica's earliest sub-step with a conflicting mover, and block exactly the movers in conflict at that
       sub-step. Blocks change positions only from their sub-step on, so everything earlier stays valid;
       this is, round for round, the sub-step loop with its "until no new agent is blocked" iteration. One
       host sync per round ("did anything change"); it only stops agents, so it ends after at most ``R * N``
       rounds.

    Positions are always computed as ``p + k * d`` with the same operations, so the checks and the result
    agree to the bit. Host syncs per decision: one for each of the two pre-filters and one per round; none
    depends on the number of sub-steps. ``tests/sim/test_dynamics.py`` checks the result against its
    specification, the literal sub-step loop :func:`pedrl.sim.reference.move_agents_literal`.

    Args:
        positions: Positions at the start of the decision ``(R, N, 2)`` (m).
        velocities: Velocities for the decision ``(R, N, 2)`` (m/s).
        active: Agents in the room ``(R, N)`` bool; the others neither move nor collide.
        motion: The room and the decision's constants (:class:`~pedrl.sim.motion.Motion`).

    Returns:
        The :class:`Movement` of the decision.
    """
    geometry, agent_radius, decision_length, num_substeps = motion.values()
    num_replicas, num_agents, _ = positions.shape
    device, dtype = positions.device, positions.dtype
    never = torch.tensor(num_substeps + 1, device=device)  # "no such sub-step"
    contact_sq = 4.0 * agent_radius * agent_radius

    step = velocities * (decision_length / num_substeps)  # (R, N, 2)
    moving = active & (step != 0).any(-1)
    step = step * moving.unsqueeze(-1)
    substep_row = torch.arange(1, num_substeps + 1, device=device).view(-1, 1)  # (S, 1)
    flat_positions = positions.reshape(-1, 2)  # (R * N, 2)
    flat_step = step.reshape(-1, 2)

    # swept discs: centre of the straight move and half its length
    centre_x, centre_y, half_move = _swept_discs(positions, step, active, num_substeps)

    # 1. walls and exits, agent by agent (only movers near a wall are traced)
    first_wall, first_door = _wall_and_exit_times(
        geometry, flat_positions, flat_step, moving, centre_x, centre_y, half_move, agent_radius, substep_row, never
    )
    blocked_at = torch.where(first_wall <= first_door, first_wall, never)  # (R * N,)

    # 2. pairs whose swept discs overlap, each unordered pair once
    candidate = _discs_overlap(centre_x, centre_y, half_move, agent_radius) & _upper_triangle(num_agents, device)
    pairs = candidate.nonzero()  # (M, 3): replica, i, j

    # 3. collision rounds over the kept pairs
    if pairs.shape[0] > 0:
        blocked_at = _collision_rounds(
            pairs, flat_positions, flat_step, moving, blocked_at, first_door, substep_row, never, contact_sq
        )

    reached_at = torch.where(first_door < blocked_at, first_door, never)
    last_move = torch.minimum(blocked_at - 1, reached_at).view(num_replicas, num_agents)
    blocked = (blocked_at < never).view(num_replicas, num_agents)
    crashed_wall = blocked & (blocked_at == first_wall).view(num_replicas, num_agents)
    return Movement(
        positions=positions + last_move.to(dtype).unsqueeze(-1) * step,
        blocked=blocked,
        crashed_wall=crashed_wall,
        crashed_agent=blocked & ~crashed_wall,
        reached=(reached_at < never).view(num_replicas, num_agents),
    )

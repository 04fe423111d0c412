"""Actions, speed and heading updates, and sub-stepped kinematics with collisions (torch; numba kernels on the CPU).

An action ``a`` in ``[0, 81)`` is ``speed_index * 9 + turn_index``. In the paper's ``heading`` action frame index 4
of each axis is the no-op, so ``NOOP_ACTION = 40`` keeps speed and heading; in the ``goal`` frame an action sets the
speed and the heading relative to the goal (``ACTION_FRAMES``).

A decision of ``decision_length`` seconds is integrated in ``num_substeps`` equal sub-steps. In each
sub-step every moving agent proposes its next position; a proposal is blocked when the agent's circle
intersects a wall (``dist(centre, segment) < radius``) or another active body (``|p_i - p_j| < 2 radius``,
using the other's proposal if it is still moving, else its position). Blocked agents stay where they are and
stop for the rest of the decision. Blocking is iterated, for all agents at once, until no new agent is
blocked. An agent whose centre passes an exit (``Geometry.passes_exits``; in the paper's room ``y >= length``
within the door) has left: it stops there and no longer collides.

:func:`move_agents` computes exactly this rule, but resolves all sub-steps of a decision together instead of
looping over them: see its docstring. The rule written literally, sub-step after sub-step, is its specification
:func:`pedrl.sim.reference.move_agents_literal`.

Twins: a rule with a numba kernel (`pedrl.sim.kernels`) has a dispatcher under its plain name, the one callers use
(:func:`move_agents_sequential`, :func:`move_agents_sliding`), which runs the kernel on the CPU and otherwise its
torch code under the name ``*_torch`` (:func:`move_agents_sequential_torch`, :func:`move_agents_sliding_torch`);
the kernel returns the torch code's numbers to the bit.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Final

import torch

from pedrl._numba import use_kernels
from pedrl.sim.geometry import Geometry, X, Y, wrap_angle
from pedrl.sim.movement import PAIR_MARGIN, Movement

NUM_SPEED_CHANGES: Final = 9
NUM_TURNS: Final = 9
NUM_ACTIONS: Final = NUM_SPEED_CHANGES * NUM_TURNS
NOOP_INDEX: Final = 4
NOOP_ACTION: Final = NOOP_INDEX * NUM_TURNS + NOOP_INDEX
DEFAULT_SPEED_RATIOS: Final = (-1.0, -0.5, -0.25, -0.1, 0.0, 0.1, 0.25, 0.5, 1.0)
"""Speed change per decision, as a fraction of ``max_speed``."""
DEFAULT_TURN_RATIOS: Final = (-0.75, -0.25, -0.08, -0.025, 0.0, 0.025, 0.08, 0.25, 0.75)
"""Heading change per decision, as a fraction of pi (the paper gives none): turns of 4.5, 14.4, 45 and 135 degrees
either way. The smallest turn is fine enough to line up with a 1 m opening: within four decisions any heading
error falls to at most 2.25 degrees, so a full-speed step of 2.5 m lands within 0.1 m of the aimed line (the
clearance of a 0.4 m body in a 1 m opening); ``COARSE_TURN_RATIOS`` left up to 9 degrees (0.39 m)."""
COARSE_TURN_RATIOS: Final = (-0.75, -0.5, -0.25, -0.1, 0.0, 0.1, 0.25, 0.5, 0.75)
"""The turn ratios before issue 19 (smallest turn 18 degrees), kept for old runs and the golden trajectories."""
ACTION_FRAMES: Final = ("heading", "goal")
"""What an action changes. ``heading`` (the paper): the speed and the heading change by the ratios from their
current values. ``goal``: the speed index sets the speed to ``speed_ratios[i] * max_speed`` and the turn index sets
the heading to the bearing of the agent's goal point (its door or waypoint) plus ``turn_ratios[j] * pi``: the
greedy walker is one action, and an action means the same whatever the heading before it."""
GOAL_SPEED_RATIOS: Final = (0.0, 0.2, 0.4, 0.6, 0.7, 0.8, 0.9, 0.95, 1.0)
"""Speeds of the ``goal`` frame's 9 speed indices, as fractions of ``max_speed``: the main job's
(``conf/experiment/main.yaml``), most of them near the top."""
GOAL_TURN_RATIOS: Final = (-0.5, -0.25, -0.1, -0.05, 0.0, 0.05, 0.1, 0.25, 0.5)
"""Headings of the ``goal`` frame's 9 turn indices, relative to the bearing of the goal, as fractions of pi: 0,
+-9, +-18, +-45 and +-90 degrees (the main job's)."""


def decode_actions(actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Split actions into speed and turn indices.

    Args:
        actions: Actions ``(R, N)`` int64 in ``[0, 81)``.

    Returns:
        ``speed_index`` and ``turn_index``, each ``(R, N)`` int64 in ``[0, 9)``.
    """
    return torch.div(actions, NUM_TURNS, rounding_mode="floor"), torch.remainder(actions, NUM_TURNS)


def encode_actions(*, speed_index: torch.Tensor, turn_index: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`decode_actions`: ``speed_index * 9 + turn_index`` (int64, same shape)."""
    return speed_index * NUM_TURNS + turn_index


def apply_actions(
    *,
    speeds: torch.Tensor,
    headings: torch.Tensor,
    actions: torch.Tensor,
    speed_changes: torch.Tensor,
    turn_changes: torch.Tensor,
    max_speed: float,
    active: torch.Tensor,
    bearings: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Apply one decision's actions to speeds and headings.

    The ``heading`` frame (``bearings`` None): ``s <- clip(s + speed_changes[speed_index], 0, max_speed)`` and
    ``theta <- wrap(theta + turn_changes[turn_index])``. The ``goal`` frame (``bearings`` given):
    ``s <- clip(speed_changes[speed_index], 0, max_speed)`` and ``theta <- wrap(bearing + turn_changes[turn_index])``
    (``ACTION_FRAMES``). Inactive agents keep their values.

    Args:
        speeds: Speeds ``(R, N)`` (m/s).
        headings: Headings ``(R, N)`` (rad).
        actions: Actions ``(R, N)`` int64 in ``[0, 81)``.
        speed_changes: Speed change of each speed index ``(9,)`` (m/s), i.e. ``speed_ratios * max_speed``.
        turn_changes: Heading change of each turn index ``(9,)`` (rad), i.e. ``turn_ratios * pi``.
        max_speed: Maximum speed (m/s).
        active: Agents that act ``(R, N)`` bool.
        bearings: The ``goal`` frame: the world angle ``(R, N)`` (rad) from each agent to its goal point.

    Returns:
        New ``speeds`` ``(R, N)`` (m/s) and ``headings`` ``(R, N)`` (rad).
    """
    speed_index, turn_index = decode_actions(actions.reshape(-1))
    # index_select: plain indexing opens a parallel region for a few thousand indices already
    speed_change = speed_changes.index_select(0, speed_index).view_as(speeds)
    turn_change = turn_changes.index_select(0, turn_index).view_as(headings)
    if bearings is None:
        new_speeds = (speeds + speed_change).clamp_(0.0, max_speed)
        new_headings = wrap_angle(headings + turn_change)
    else:
        new_speeds = speed_change.clamp(0.0, max_speed)
        new_headings = wrap_angle(bearings + turn_change)
    return torch.where(active, new_speeds, speeds), torch.where(active, new_headings, headings)


def velocities_from(*, speeds: torch.Tensor, headings: torch.Tensor) -> torch.Tensor:
    """Velocity vectors ``s * (cos theta, sin theta)``.

    Args:
        speeds: Speeds ``(R, N)`` (m/s).
        headings: Headings ``(R, N)`` (rad).

    Returns:
        Velocities ``(R, N, 2)`` (m/s).
    """
    # one op (no parallel region for small tensors, unlike cos and sin); equal to s * (cos, sin) to 1 ulp
    return torch.view_as_real(torch.polar(speeds, headings))


def count_substeps(*, max_speed: float, decision_length: float, substep_length: float) -> int:
    """Number of sub-steps so that no body moves more than ``substep_length`` per sub-step.

    Args:
        max_speed: Maximum speed (m/s).
        decision_length: Duration of one decision (s).
        substep_length: Longest move per sub-step (m).

    Returns:
        ``ceil(max_speed * decision_length / substep_length)``, at least 1.
    """
    # The tiny relative slack keeps e.g. 2.5 / 0.5 at 5 despite float rounding.
    return max(1, math.ceil(max_speed * decision_length / substep_length * (1.0 - 1e-9)))


def _take(values: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """``values[index]`` along dim 0 (``index_select``, which stays serial for small sizes)."""
    return values.index_select(0, index)


@lru_cache(maxsize=16)
def _eye(num_agents: int, device: torch.device) -> torch.Tensor:
    """``(N, N)`` bool identity: no agent collides with itself."""
    return torch.eye(num_agents, dtype=torch.bool, device=device)


@lru_cache(maxsize=16)
def _upper_triangle(num_agents: int, device: torch.device) -> torch.Tensor:
    """``(N, N)`` bool, True above the diagonal: each unordered pair once."""
    return torch.ones(num_agents, num_agents, dtype=torch.bool, device=device).triu_(1)


def _swept_discs(
    positions: torch.Tensor, step: torch.Tensor, active: torch.Tensor, num_substeps: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Discs covering each agent's straight move of a decision: centres x, y and half the move, each ``(R, N)`` (m).

    ``step (R, N, 2)`` is the move per sub-step (0 for agents that stand); inactive agents get a NaN centre, which
    never overlaps anything.
    """
    half = 0.5 * num_substeps
    half_move = half * torch.linalg.vector_norm(step, dim=-1)
    centre_x = torch.where(active, positions[..., X] + half * step[..., X], torch.nan)
    centre_y = positions[..., Y] + half * step[..., Y]
    return centre_x, centre_y, half_move


def _discs_overlap(
    centre_x: torch.Tensor, centre_y: torch.Tensor, half_move: torch.Tensor, agent_radius: float
) -> torch.Tensor:
    """``(R, N, N)`` bool: the swept discs of two agents, widened by their bodies, overlap (they may touch)."""
    gap_x = centre_x.unsqueeze(2) - centre_x.unsqueeze(1)
    gap_y = centre_y.unsqueeze(2) - centre_y.unsqueeze(1)
    limit = half_move.unsqueeze(2) + half_move.unsqueeze(1) + (2.0 * agent_radius + PAIR_MARGIN)
    return gap_x * gap_x + gap_y * gap_y < limit * limit


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
    geometry: Geometry,
    agent_radius: float,
    decision_length: float,
    num_substeps: int,
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
        geometry: The room.
        agent_radius: Body radius (m).
        decision_length: Duration of the decision (s).
        num_substeps: Number of sub-steps ``S``.

    Returns:
        The :class:`Movement` of the decision.
    """
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


COLLISION_RULES: Final = ("sequential", "simultaneous")
"""``sequential`` (default): the paper's reading, movers resolved one after another in a random order drawn per
decision; ``simultaneous``: every proposal checked against every other proposal at once (:func:`move_agents`)."""


def _sequential_steps(
    positions: torch.Tensor, velocities: torch.Tensor, active: torch.Tensor, decision_length: float, num_substeps: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """What both paths of :func:`move_agents_sequential` start from: the move per sub-step ``(R, N, 2)``, the movers
    ``(R, N)`` bool, the depth of the exit test ``(R, N)`` and the sub-step numbers ``1..S`` ``(S, 1, 1, 1)``."""
    step = velocities * (decision_length / num_substeps)  # (R, N, 2)
    going = active & (step != 0).any(-1)  # still moving in this decision
    depth = step.norm(dim=-1) + PAIR_MARGIN  # of the exit test: a centre moves less than this per sub-step
    substeps = torch.arange(1, num_substeps + 1, device=positions.device).to(positions.dtype).view(-1, 1, 1, 1)
    return step, going, depth, substeps


def move_agents_sequential(
    *,
    positions: torch.Tensor,
    velocities: torch.Tensor,
    active: torch.Tensor,
    geometry: Geometry,
    agent_radius: float,
    decision_length: float,
    num_substeps: int,
    priority: torch.Tensor,
    sync_free: bool = False,
    compiled: bool | None = None,
) -> Movement:
    """Move every active agent through one decision with the paper's collision rule, resolved sequentially.

    Paper section 5: "In a collision, the agent stops and the other object or agent cannot go into the bounding
    circumference of the agent." Only the agent whose own move would enter a wall or another body stops; the
    body it would have entered keeps going. Within each sub-step the movers act one after another in the order
    of ``priority`` (lowest first, a random permutation per decision): a mover's proposal ``p_i + d_i`` is
    refused when its circle would intersect a wall, or the body of an agent that already acted in this
    sub-step (at its new position if it moved, else where it stands), or the body of an agent still to act
    (where it stands now). Refused agents stop for the rest of the decision. So no body ever overlaps
    another, and two agents heading for the same spot no longer both freeze: the first to act takes it.

    The specification is the literal agent-by-agent loop :func:`pedrl.sim.reference.move_agents_sequential_literal`.
    This function chooses how to compute it, with the same numbers to the bit either way: on the CPU with numba,
    the walls in torch and the sub-steps in that loop compiled (:func:`pedrl.sim.kernels.sequential_substeps`),
    without hundreds of small operations; otherwise (other devices, ``compiled=False``, ``sync_free``)
    :func:`move_agents_sequential_torch`.

    Args:
        positions: Positions at the start of the decision ``(R, N, 2)`` (m).
        velocities: Velocities for the decision ``(R, N, 2)`` (m/s).
        active: Agents in the room ``(R, N)`` bool; the others neither move nor collide.
        geometry: The room.
        agent_radius: Body radius (m).
        decision_length: Duration of the decision (s).
        num_substeps: Number of sub-steps ``S``.
        priority: Order of action ``(R, N)`` float (lowest acts first); distinct values within a replica.
        sync_free: Bounded iterations with masks instead of convergence tests read on the host (torch path).
        compiled: Use the compiled CPU kernel (None: on the CPU when numba is there and not ``sync_free``).

    Returns:
        The :class:`Movement` of the decision.
    """
    if use_kernels(positions.device, False if sync_free and compiled is None else compiled):
        from pedrl.sim.kernels import sequential_substeps  # imports numba: only where it is used

        step, going, depth, step_scale = _sequential_steps(positions, velocities, active, decision_length, num_substeps)
        walls = None
        if not geometry.axis_aligned:  # the kernel tests axis-aligned walls itself
            walls = _touch_walls(positions + step_scale * step, geometry, agent_radius, exact_everywhere=False)
        moved_to, blocked, crashed_wall, reached = sequential_substeps(
            positions=positions,
            step=step,
            going=going,
            active=active,
            geometry=geometry,
            agent_radius=agent_radius,
            num_substeps=num_substeps,
            walls=walls,
            depth=depth,
            priority=priority,
        )
        return Movement(moved_to, blocked, crashed_wall, blocked & ~crashed_wall, reached)
    return move_agents_sequential_torch(
        positions=positions,
        velocities=velocities,
        active=active,
        geometry=geometry,
        agent_radius=agent_radius,
        decision_length=decision_length,
        num_substeps=num_substeps,
        priority=priority,
        sync_free=sync_free,
    )


def move_agents_sequential_torch(
    *,
    positions: torch.Tensor,
    velocities: torch.Tensor,
    active: torch.Tensor,
    geometry: Geometry,
    agent_radius: float,
    decision_length: float,
    num_substeps: int,
    priority: torch.Tensor,
    sync_free: bool = False,
) -> Movement:
    """:func:`move_agents_sequential` in torch, on any device (same arguments but ``compiled``, same result).

    How it is computed, with the same floating-point operations as the literal agent-by-agent loop
    :func:`pedrl.sim.reference.move_agents_sequential_literal` (``tests/sim/test_dynamics.py`` checks every output
    to the bit):

    1. Proposals ``p + k d`` do not depend on collisions, so the walls, the exits and the proposal-to-proposal
       contacts of every sub-step are evaluated at once. Only pairs whose swept discs (straight move widened by
       the radius) overlap can ever touch; they are kept as a dense ``(R, N, N)`` mask.
    2. Without such a pair the decision is solved in closed form: each mover walks until the first sub-step
       whose proposal touches a wall (it stops there) or passes the door (it leaves).
    3. Otherwise the sub-steps run in turn, and within each the order of action is resolved for all agents at
       once by a fixed-point iteration over the kept pairs: after round ``t`` the ``t`` first movers of each
       replica are final, so ``N`` rounds always suffice.

    With ``sync_free`` (for CUDA) nothing is read back on the host: step 2 is skipped, every sub-step runs and
    every sub-step with a kept pair runs exactly ``N`` rounds, which leaves the fixed point unchanged; the
    result is the same. Otherwise sub-steps stop once nobody moves and rounds once nothing changes.
    """
    num_agents = positions.shape[1]
    device, dtype = positions.device, positions.dtype
    contact_sq = 4.0 * agent_radius * agent_radius
    step, going, depth, step_scale = _sequential_steps(positions, velocities, active, decision_length, num_substeps)
    # p + k d, as in move_agents, so that moves without collisions agree to the bit between the two rules
    proposals = positions + step_scale * step  # (S, R, N, 2)
    walls = _touch_walls(proposals, geometry, agent_radius, exact_everywhere=sync_free)  # (S, R, N)
    passes_door = geometry.passes_exits(proposals, depth=depth)

    # pairs that can touch during the decision: swept discs overlap; [r, i, j]: i the mover, j the obstacle
    centre_x, centre_y, half_move = _swept_discs(positions, step * going.unsqueeze(-1), active, num_substeps)
    candidate = _discs_overlap(centre_x, centre_y, half_move, agent_radius) & ~_eye(num_agents, device)
    if not sync_free and not bool(candidate.any()):
        return _walk_to_walls(positions, step, going, walls, passes_door)

    pairs = _DensePairs(candidate) if sync_free else _ListedPairs(candidate)
    dst_first = pairs.dst(priority) < pairs.src(priority)  # the obstacle acts before the mover
    # x and y apart: a sum over a last axis of 2 is slow on CPU; gx * gx + gy * gy is that sum to the bit
    proposal_x, proposal_y = proposals[..., X], proposals[..., Y]  # (S, R, N)
    gap_x = pairs.src(proposal_x) - pairs.dst(proposal_x)
    gap_y = pairs.src(proposal_y) - pairs.dst(proposal_y)
    hits_new_all = pairs.restrict((gap_x * gap_x + gap_y * gap_y < contact_sq) & dst_first)  # every sub-step
    present = active.clone()  # bodies that collide (in the room)
    blocked = torch.zeros_like(active)
    crashed_wall = torch.zeros_like(active)
    reached = torch.zeros_like(active)
    moved_substeps = torch.zeros(active.shape, dtype=dtype, device=device)
    current = positions
    rounds = num_agents if sync_free else num_agents + 1
    for index in range(num_substeps):
        if not sync_free and not bool(going.any()):
            break
        hits_wall = going & walls[index]
        candidates = going & ~hits_wall  # movers not stopped by a wall
        gap_x = pairs.src(proposal_x[index]) - pairs.dst(current[..., X])
        gap_y = pairs.src(proposal_y[index]) - pairs.dst(current[..., Y])
        hits_now = pairs.restrict((gap_x * gap_x + gap_y * gap_y < contact_sq) & pairs.dst(present))
        hits_new = hits_new_all[index]
        # a conflict only matters for a candidate mover, and only candidates move: no "going" masks needed
        moved = candidates
        if sync_free or bool((hits_now | hits_new).any()):
            for _ in range(rounds):
                dst_moves = pairs.dst(moved)
                conflict = (hits_now & ~(dst_first & dst_moves)) | (hits_new & dst_moves)
                new_moved = candidates & ~pairs.any_by_src(conflict)
                if not sync_free and bool(torch.equal(new_moved, moved)):
                    break
                moved = new_moved
            else:
                if not sync_free:  # pragma: no cover - round t fixes the t-th mover of every replica
                    raise RuntimeError("sequential collision resolution did not converge")
        moved_substeps = moved_substeps + moved.to(dtype)
        current = positions + moved_substeps.unsqueeze(-1) * step
        blocked |= going & ~moved
        crashed_wall |= hits_wall
        passed = moved & passes_door[index]  # a mover stands on its proposal
        reached |= passed
        present &= ~passed
        going = moved & ~passed

    return Movement(
        positions=current,
        blocked=blocked,
        crashed_wall=crashed_wall,
        crashed_agent=blocked & ~crashed_wall,
        reached=reached,
    )


def _touch_walls(points: torch.Tensor, geometry: Geometry, radius: float, *, exact_everywhere: bool) -> torch.Tensor:
    """``geometry.touches_walls(points)`` ``(...)`` bool for points ``(..., 2)``, to the bit.

    Unless ``exact_everywhere``, the exact test runs only on the points outside the geometry's clear box shrunk by
    ``r + PAIR_MARGIN`` (``nonzero``, a host read); the others touch no wall.
    """
    if exact_everywhere:
        return geometry.touches_walls(points, radius=radius)
    clear = geometry.clear_of_walls(points, margin=radius + PAIR_MARGIN)
    near = (~clear).view(-1).nonzero().squeeze(1)
    touches = torch.zeros(clear.numel(), dtype=torch.bool, device=points.device)
    if near.shape[0] > 0:
        touches[near] = geometry.touches_walls(points.reshape(-1, 2).index_select(0, near), radius=radius)
    return touches.view(clear.shape)


class _DensePairs:
    """Mover-obstacle pairs as a dense ``(R, N, N)`` mask ``[r, i, j]`` (i the mover): fixed shapes, for CUDA."""

    def __init__(self, candidate: torch.Tensor) -> None:
        self.mask = candidate

    def src(self, values: torch.Tensor) -> torch.Tensor:
        """Per-agent ``(..., R, N)`` values of each pair's mover, ``(..., R, N, 1)``."""
        return values.unsqueeze(-1)

    def dst(self, values: torch.Tensor) -> torch.Tensor:
        """Per-agent ``(..., R, N)`` values of each pair's obstacle, ``(..., R, 1, N)``."""
        return values.unsqueeze(-2)

    def restrict(self, flags: torch.Tensor) -> torch.Tensor:
        """``flags`` of every pair, False outside the kept pairs."""
        return flags & self.mask

    def any_by_src(self, flags: torch.Tensor) -> torch.Tensor:
        """``(R, N)``: whether any kept pair of each mover is flagged."""
        return flags.any(-1)


class _ListedPairs:
    """Mover-obstacle pairs listed by flat agent index (``nonzero`` of the mask): small tensors, for the CPU."""

    def __init__(self, candidate: torch.Tensor) -> None:
        num_replicas, num_agents, _ = candidate.shape
        replica, mover, obstacle = candidate.nonzero().unbind(1)  # (M,) each; both orders of every pair
        self._src = replica * num_agents + mover
        self._dst = replica * num_agents + obstacle
        self._shape = (num_replicas, num_agents)

    def src(self, values: torch.Tensor) -> torch.Tensor:
        """Per-agent ``(..., R, N)`` values of each pair's mover, ``(..., M)``."""
        return values.flatten(-2).index_select(-1, self._src)

    def dst(self, values: torch.Tensor) -> torch.Tensor:
        """Per-agent ``(..., R, N)`` values of each pair's obstacle, ``(..., M)``."""
        return values.flatten(-2).index_select(-1, self._dst)

    def restrict(self, flags: torch.Tensor) -> torch.Tensor:
        """``flags`` of every pair (all pairs are kept ones)."""
        return flags

    def any_by_src(self, flags: torch.Tensor) -> torch.Tensor:
        """``(R, N)``: whether any pair of each mover is flagged."""
        counts = torch.zeros(self._shape[0] * self._shape[1], dtype=torch.int32, device=flags.device)
        return (counts.index_add_(0, self._src, flags.to(torch.int32)) > 0).view(self._shape)


def _walk_to_walls(
    positions: torch.Tensor, step: torch.Tensor, going: torch.Tensor, walls: torch.Tensor, passes_door: torch.Tensor
) -> Movement:
    """The sequential rule when no two movers can touch: each walks until its first wall (stop) or the door (out).

    ``walls`` and ``passes_door`` ``(S, R, N)`` bool say whether the proposal of each sub-step touches a wall or
    is past the door. A proposal that does both is refused (the wall is checked first).
    """
    num_substeps = walls.shape[0]
    substep = torch.arange(1, num_substeps + 1, device=positions.device).view(-1, 1, 1)
    never = num_substeps + 1
    first_wall = torch.where(walls, substep, never).amin(0)  # (R, N)
    first_door = torch.where(passes_door, substep, never).amin(0)
    blocked = going & (first_wall <= first_door) & (first_wall < never)
    reached = going & (first_door < first_wall)
    moves = torch.minimum(first_wall - 1, first_door).masked_fill_(~going, 0)
    return Movement(
        positions=positions + moves.to(positions.dtype).unsqueeze(-1) * step,
        blocked=blocked,
        crashed_wall=blocked,
        crashed_agent=torch.zeros_like(blocked),
        reached=reached,
    )


# ---------------------------------------------------------------------------------------------------- contact models

CONTACT_MODELS: Final = ("stop", "slide", "headway", "yield")
"""What a body does when its move would enter another body or a wall (``RoomEnv(contact=...)``).

``stop``: it stops for the rest of the decision (:func:`move_agents_sequential` or :func:`move_agents`, the paper's
reading). ``slide``: it keeps the part of its move tangent to the contact (:func:`move_agents_sliding`).
``headway``: the collision-free speed rule (Tordeux, Chraibi & Seyfried 2016) sets the speed walked from the nearest
body ahead, and ``slide`` is the safety net (:func:`move_agents_sliding` with a ``time_gap``). ``yield``: ``headway``
with a right of way: only the bodies that act before the mover in the order of the sequential rule (with
``collision_order=door_first``, those nearer the goal) slow it; it slides past the others (``yield_to_earlier``).
Two bodies converging on a door then never hold each other up: the one nearer goes, the other keeps its gap.
"""


def _sqrt(values: torch.Tensor) -> torch.Tensor:
    """Correctly rounded float32 square root, as the kernels' (torch's vectorised float32 ``sqrt`` is off by one ulp
    for about 1 value in 150); through float64, whose rounding to float32 is then exact."""
    return values.double().sqrt().to(values.dtype)


def headway_factors(
    *,
    positions: torch.Tensor,
    velocities: torch.Tensor,
    present: torch.Tensor,
    agent_radius: float,
    time_gap: float,
    rank: torch.Tensor | None = None,
) -> torch.Tensor:
    """Share of its wanted speed each agent walks under the collision-free speed rule.

    As JuPedSim's ``CollisionFreeSpeedModel`` (``GetSpacing``, ``OptimalSpeed``): with ``e`` the unit heading of the
    wanted velocity ``v`` and ``o = p_j - p_i``, body ``j`` is ahead when ``o . e >= 0`` and inside the corridor when
    ``|o x e| <= 2 r``; the spacing ``s`` is the smallest ``|o| - 2 r`` over those bodies (infinite if none), and the
    speed walked is ``min(|v|, max(0, s / T))``. Bodies beside the mover do not slow it.

    Args:
        positions: Centres ``(R, N, 2)`` (m).
        velocities: Wanted velocities ``(R, N, 2)`` (m/s).
        present: Bodies in the room ``(R, N)`` bool; only they slow others.
        agent_radius: Body radius ``r`` (m).
        time_gap: ``T`` (s).
        rank: ``None``, or each agent's place ``(R, N)`` int64 in the order of action: then only bodies of a lower
            rank (acting before) count for the spacing (the ``yield`` rule's right of way).

    Returns:
        ``min(|v|, max(0, s / T)) / |v|`` ``(R, N)`` float32 in ``[0, 1]``; 1 where ``|v| = 0``.
    """
    num_agents = positions.shape[1]
    diameter = 2.0 * agent_radius
    vx, vy = velocities[..., X], velocities[..., Y]
    wanted = _sqrt(vx * vx + vy * vy)  # (R, N)
    moving = wanted > 0
    ex = torch.where(moving, vx / torch.where(moving, wanted, 1.0), 0.0)
    ey = torch.where(moving, vy / torch.where(moving, wanted, 1.0), 0.0)
    x, y = positions[..., X], positions[..., Y]
    ox = x.unsqueeze(1) - x.unsqueeze(2)  # [r, i, j]: p_j - p_i
    oy = y.unsqueeze(1) - y.unsqueeze(2)
    ahead = ox * ex.unsqueeze(2) + oy * ey.unsqueeze(2)
    side = (ox * ey.unsqueeze(2) - oy * ex.unsqueeze(2)).abs()
    corridor = (ahead >= 0) & (side <= diameter) & present.unsqueeze(1) & ~_eye(num_agents, positions.device)
    if rank is not None:
        corridor &= rank.unsqueeze(1) < rank.unsqueeze(2)  # [r, i, j]: j acts before i
    spacing = torch.where(corridor, _sqrt(ox * ox + oy * oy) - diameter, torch.inf).amin(-1)  # (R, N)
    walked = torch.minimum(wanted, (spacing / time_gap).clamp_min(0.0))
    return torch.where(moving, walked / torch.where(moving, wanted, 1.0), 1.0)


def _wall_segments(geometry: Geometry) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Wall starts ``(S, 2)``, directions ``(S, 2)`` and inverse squared lengths ``(S,)`` (0 for a point)."""
    starts = geometry.walls[:, 0]
    directions = geometry.walls[:, 1] - starts
    length_sq = directions[:, X] * directions[:, X] + directions[:, Y] * directions[:, Y]
    inverse = torch.where(length_sq > 0, 1.0 / length_sq.clamp_min(1e-30), 0.0)
    return starts.contiguous(), directions.contiguous(), inverse.contiguous()


def _nearest_wall(points: torch.Tensor, starts: torch.Tensor, directions: torch.Tensor, inverse: torch.Tensor):
    """Squared distance ``(R,)`` from each point ``(R, 2)`` to its nearest wall, that wall ``(R,)`` and the closest
    point of it ``(R, 2)``: the projection clamped to the segment, as the kernel computes it."""
    along = (
        (points[:, None, X] - starts[:, X]) * directions[:, X] + (points[:, None, Y] - starts[:, Y]) * directions[:, Y]
    ) * inverse
    along = along.clamp(0.0, 1.0)  # (R, S)
    wall_x = starts[:, X] + along * directions[:, X]
    wall_y = starts[:, Y] + along * directions[:, Y]
    gap_x = points[:, None, X] - wall_x
    gap_y = points[:, None, Y] - wall_y
    distance_sq, nearest = (gap_x * gap_x + gap_y * gap_y).min(-1)
    return distance_sq, nearest


def _closest_on_wall(
    points: torch.Tensor, wall: torch.Tensor, starts, directions, inverse
) -> tuple[torch.Tensor, torch.Tensor]:
    """Closest point ``x, y`` ``(R,)`` of wall ``wall (R,)`` to each point ``(R, 2)``."""
    start, direction, inv = starts[wall], directions[wall], inverse[wall]
    along = ((points[:, X] - start[:, X]) * direction[:, X] + (points[:, Y] - start[:, Y]) * direction[:, Y]) * inv
    along = along.clamp(0.0, 1.0)
    return start[:, X] + along * direction[:, X], start[:, Y] + along * direction[:, Y]


def move_agents_sliding(
    *,
    positions: torch.Tensor,
    velocities: torch.Tensor,
    active: torch.Tensor,
    geometry: Geometry,
    agent_radius: float,
    decision_length: float,
    num_substeps: int,
    priority: torch.Tensor,
    time_gap: float | None = None,
    yield_to_earlier: bool = False,
    compiled: bool | None = None,
) -> Movement:
    """Move every active agent through one decision with the ``slide`` contact model (``headway`` with ``time_gap``,
    ``yield`` with ``yield_to_earlier`` too).

    The sub-steps run in turn; within each the movers act one after another in the order of ``priority`` (lowest
    first), each from where it stands: its proposal is ``c + v * f * dt`` (``dt`` the sub-step, ``f`` 1, or the
    share of :func:`headway_factors` computed from the positions at the start of the sub-step when ``time_gap`` is
    given). A proposal whose circle would enter a wall (``dist < r``) or a present body (``|gap| < 2 r``, others at
    their current positions, which already include this sub-step's move of those that acted before) is replaced by
    the slid one: with ``n`` the unit normal of the contact at the mover's centre (from the closest point of the
    nearest wall if a wall is entered, else from the nearest entered body), the inward part ``min(v . n, 0) n`` is
    removed from ``v``, and the mover keeps this tangent velocity for the rest of the decision. If the slid proposal
    enters anything too, the mover stays where it is and stops for the rest of the decision (``blocked``). Nobody
    ever overlaps. A mover whose centre passes an exit has left and no longer collides.

    Contact (the crash flags): ``crashed_wall`` when, in some sub-step, a wall entered by the proposal or by the slid
    proposal cut the mover's move; ``crashed_agent`` when a body did so and no wall did. With ``time_gap`` the move
    is the headway-limited one: slowing for a body ahead is not a contact; the safety net firing is.

    The specification is :func:`move_agents_sliding_torch`, a loop over sub-steps and movers. This function chooses
    how to compute it: on the CPU (with numba) :func:`pedrl.sim.kernels.sliding_substeps`, the same loop compiled,
    with the same float32 operations in the same order (``tests/sim/test_contact.py`` checks the two agree to the
    bit on random scenes and in every scenario; exact ties between the nearest walls or bodies are the one place
    they could differ, when both pick a different one of two equally near); otherwise (CUDA, ``compiled=False``,
    ``PEDRL_NO_NUMBA=1``) the torch loop itself.

    Args:
        positions: Positions at the start of the decision ``(R, N, 2)`` (m).
        velocities: Commanded velocities ``(R, N, 2)`` (m/s).
        active: Agents in the room ``(R, N)`` bool; the others neither move nor collide.
        geometry: The room.
        agent_radius: Body radius ``r`` (m).
        decision_length: Duration of the decision (s).
        num_substeps: Number of sub-steps ``S``.
        priority: Order of action ``(R, N)`` float (lowest acts first).
        time_gap: ``T`` (s) of the collision-free speed rule, or ``None`` for plain ``slide``.
        yield_to_earlier: With ``time_gap``, only bodies that act before the mover (lower ``priority``) slow it.
        compiled: Use the compiled CPU kernel (None: on the CPU when numba is there).

    Returns:
        The :class:`Movement` of the decision; ``blocked`` marks movers stopped because even the slid move was
        refused.
    """
    if use_kernels(positions.device, compiled):
        from pedrl.sim.kernels import sliding_substeps  # imports numba: only where it is used

        starts, directions, inverse = _wall_segments(geometry)
        return sliding_substeps(
            positions=positions,
            velocities=velocities,
            active=active,
            geometry=geometry,
            wall_starts=starts,
            wall_directions=directions,
            wall_inverse=inverse,
            agent_radius=agent_radius,
            substep_length=decision_length / num_substeps,
            num_substeps=num_substeps,
            order=priority.argsort(dim=1),
            time_gap=time_gap,
            yield_to_earlier=yield_to_earlier,
        )
    return move_agents_sliding_torch(
        positions=positions,
        velocities=velocities,
        active=active,
        geometry=geometry,
        agent_radius=agent_radius,
        decision_length=decision_length,
        num_substeps=num_substeps,
        priority=priority,
        time_gap=time_gap,
        yield_to_earlier=yield_to_earlier,
    )


def move_agents_sliding_torch(
    *,
    positions: torch.Tensor,
    velocities: torch.Tensor,
    active: torch.Tensor,
    geometry: Geometry,
    agent_radius: float,
    decision_length: float,
    num_substeps: int,
    priority: torch.Tensor,
    time_gap: float | None = None,
    yield_to_earlier: bool = False,
) -> Movement:
    """:func:`move_agents_sliding` in torch, on any device (same arguments but ``compiled``, same result): the
    specification of :func:`pedrl.sim.kernels.sliding_substeps`.

    It loops over sub-steps and movers in Python, vectorised over replicas only (about 0.5 ms per mover and sub-step
    on a CPU core, 65 ms a decision for 20 rooms of 20 agents against 1 ms compiled): it is the path on CUDA and with
    ``PEDRL_NO_NUMBA=1``.
    """
    device = positions.device
    starts, directions, inverse = _wall_segments(geometry)
    order = priority.argsort(dim=1)
    num_replicas, num_agents = active.shape
    substep_length = decision_length / num_substeps
    radius_sq = agent_radius * agent_radius
    contact_sq = 4.0 * agent_radius * agent_radius
    rows = torch.arange(num_replicas, device=device)
    agents = torch.arange(num_agents, device=device)
    on_cpu = device.type == "cpu"  # early exits read the host; skipped elsewhere (same result)

    wanted = velocities * active.unsqueeze(-1)  # (R, N, 2), the tangent part after a contact
    current = positions.clone()
    going = active & (velocities != 0).any(-1)
    present = active.clone()
    blocked = torch.zeros_like(active)
    cut_wall = torch.zeros_like(active)
    cut_body = torch.zeros_like(active)
    reached = torch.zeros_like(active)

    def enters(points: torch.Tensor, others: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Whether circles at ``points (R, 2)`` enter a wall / a body, the nearest wall and the nearest body."""
        wall_sq, wall = _nearest_wall(points, starts, directions, inverse)
        gap_x = points[:, None, X] - current[..., X]
        gap_y = points[:, None, Y] - current[..., Y]
        body_sq, body = torch.where(others, gap_x * gap_x + gap_y * gap_y, torch.inf).min(-1)
        return wall_sq < radius_sq, body_sq < contact_sq, wall, body

    rank_of = order.argsort(dim=1) if yield_to_earlier else None  # each agent's place in the order of action
    for _ in range(num_substeps):
        if on_cpu and not bool(going.any()):
            break
        if time_gap is None:
            factor = torch.ones_like(current[..., X])
        else:
            factor = headway_factors(
                positions=current,
                velocities=wanted,
                present=present,
                agent_radius=agent_radius,
                time_gap=time_gap,
                rank=rank_of,
            )
        for rank in range(num_agents):
            mover_index = order[:, rank]  # (R,)
            mover = going[rows, mover_index]
            if on_cpu and not bool(mover.any()):
                continue
            here = current[rows, mover_index]  # (R, 2)
            velocity = wanted[rows, mover_index]
            scale = (factor[rows, mover_index] * substep_length).unsqueeze(-1)  # (R, 1) s
            others = present & (agents != mover_index.unsqueeze(-1))  # (R, N)
            proposal = here + velocity * scale
            hits_wall, hits_body, wall, body = enters(proposal, others)
            hit = mover & (hits_wall | hits_body)
            # the contact's unit normal at the mover's centre
            wall_x, wall_y = _closest_on_wall(here, wall, starts, directions, inverse)
            other = current[rows, body]
            normal_x = here[:, X] - torch.where(hits_wall, wall_x, other[:, X])
            normal_y = here[:, Y] - torch.where(hits_wall, wall_y, other[:, Y])
            norm = _sqrt(normal_x * normal_x + normal_y * normal_y)
            norm = torch.where(norm > 0, norm, 1.0)
            normal_x, normal_y = normal_x / norm, normal_y / norm
            inward = (velocity[:, X] * normal_x + velocity[:, Y] * normal_y).clamp_max(0.0)
            tangent = torch.stack((velocity[:, X] - inward * normal_x, velocity[:, Y] - inward * normal_y), -1)
            slid = here + tangent * scale
            slid_wall, slid_body, _, _ = enters(slid, others)
            refused = hit & (slid_wall | slid_body)
            moves = mover & ~refused
            target = torch.where(hit.unsqueeze(-1), slid, proposal)
            cut_wall[rows, mover_index] |= mover & (hits_wall | (hit & slid_wall))
            cut_body[rows, mover_index] |= mover & (hits_body | (hit & slid_body))
            blocked[rows, mover_index] |= refused
            wanted[rows, mover_index] = torch.where(hit.unsqueeze(-1), tangent, velocity)
            current[rows, mover_index] = torch.where(moves.unsqueeze(-1), target, here)
            step_x, step_y = target[:, X] - here[:, X], target[:, Y] - here[:, Y]
            depth = _sqrt(step_x * step_x + step_y * step_y) + PAIR_MARGIN
            passed = moves & geometry.passes_exits(target, depth=depth)
            reached[rows, mover_index] |= passed
            present[rows, mover_index] &= ~passed
            going[rows, mover_index] = moves & ~passed

    return Movement(
        positions=current,
        blocked=blocked,
        crashed_wall=cut_wall,
        crashed_agent=cut_body & ~cut_wall,
        reached=reached,
    )

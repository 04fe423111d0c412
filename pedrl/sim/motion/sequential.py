"""The motion model :class:`Stop` (the paper's reading): movers act one after another in an order drawn per decision
(the ``sequential`` collision rule), and only the one whose own move would enter a wall or a body stops.

:func:`move_agents_sequential` dispatches to the numba kernel (:mod:`pedrl.sim.motion.sequential_kernel`) on the
CPU and to :func:`move_agents_sequential_torch` elsewhere; the two give the same numbers to the bit."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch

from pedrl._numba import use_kernels
from pedrl.sim.geometry import Geometry, X, Y
from pedrl.sim.motion.common import (
    PAIR_MARGIN,
    Motion,
    MotionModel,
    Movement,
    _discs_overlap,
    _eye,
    _swept_discs,
    check_order,
)


@dataclass(frozen=True)
class Stop(MotionModel):
    """Contact ``stop`` under the sequential collision rule (the paper's reading, section 5: "In a collision, the agent
    stops and the other object or agent cannot go into the bounding circumference of the agent"): movers act one
    after another in ``order``; one whose own move would enter a wall or a body stops for the rest of the decision
    (:func:`move_agents_sequential`). Config: ``motion=stop`` (``env.motion.order``).

    Attributes:
        order: ``random`` (a permutation drawn per decision) or ``door_first`` (nearest to its goal point first).
    """

    name: ClassVar[str] = "stop"
    contact: ClassVar[str] = "stop"
    order: str = "random"

    def __post_init__(self) -> None:
        object.__setattr__(self, "order", check_order(self.order))


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
    motion: Motion,
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
    the walls in torch and the sub-steps in that loop compiled
    (:func:`pedrl.sim.motion.sequential_kernel.sequential_substeps`), without hundreds of small operations;
    otherwise (other devices, ``compiled=False``, ``sync_free``) :func:`move_agents_sequential_torch`.

    Args:
        positions: Positions at the start of the decision ``(R, N, 2)`` (m).
        velocities: Velocities for the decision ``(R, N, 2)`` (m/s).
        active: Agents in the room ``(R, N)`` bool; the others neither move nor collide.
        motion: The room and the decision's constants (:class:`~pedrl.sim.motion.Motion`).
        priority: Order of action ``(R, N)`` float (lowest acts first); distinct values within a replica.
        sync_free: Bounded iterations with masks instead of convergence tests read on the host (torch path).
        compiled: Use the compiled CPU kernel (None: on the CPU when numba is there and not ``sync_free``).

    Returns:
        The :class:`Movement` of the decision.
    """
    geometry, agent_radius, decision_length, num_substeps = motion.values()
    if use_kernels(positions.device, False if sync_free and compiled is None else compiled):
        from pedrl.sim.motion.sequential_kernel import sequential_substeps  # imports numba: only where it is used

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
        positions=positions, velocities=velocities, active=active, motion=motion, priority=priority, sync_free=sync_free
    )


def move_agents_sequential_torch(
    *,
    positions: torch.Tensor,
    velocities: torch.Tensor,
    active: torch.Tensor,
    motion: Motion,
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
    geometry, agent_radius, decision_length, num_substeps = motion.values()
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

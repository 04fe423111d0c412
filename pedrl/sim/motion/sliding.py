"""The motion models :class:`Slide`, :class:`Headway`, :class:`Yield` and :class:`Continuous`: a mover keeps the
tangent part of a move that would enter something, under ``headway``/``yield`` walks at the collision-free speed
(Tordeux, Chraibi & Seyfried 2016), and on the continuous walking layer steers by its direction rule too.

:func:`move_agents_sliding` dispatches to the numba kernel (:mod:`pedrl.sim.motion.sliding_kernel`) on the CPU and to
:func:`move_agents_sliding_torch` elsewhere; the two give the same numbers to the bit."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar, Final

import torch

from pedrl._numba import use_kernels
from pedrl.common.checks import check_choice, check_number
from pedrl.sim.geometry import X, Y
from pedrl.sim.motion.common import (
    MOTION_KEY,
    PAIR_MARGIN,
    STEERING_CUTOFF,
    Motion,
    MotionModel,
    Movement,
    Steering,
    _eye,
    check_order,
    check_time_gap,
)

MAX_TIME_STEP: Final = 0.05
"""Longest time step (s) of the continuous walking layer (:class:`Continuous`)."""
CONTINUOUS_CONTACTS: Final = ("headway", "yield")
"""The contact rules of the continuous walking layer: it walks by the collision-free speed rule."""


@dataclass(frozen=True)
class Slide(MotionModel):
    """Contact ``slide``: a mover whose move would enter a body or a wall keeps the part of its move tangent to the
    contact for the rest of the decision, and stops only if even that would enter something; the movers act in
    ``order`` (:func:`move_agents_sliding`). Config: ``motion=slide`` (``env.motion.order``).

    Attributes:
        order: ``random`` or ``door_first`` (:data:`~pedrl.sim.motion.COLLISION_ORDERS`).
    """

    name: ClassVar[str] = "slide"
    contact: ClassVar[str] = "slide"
    order: str = "random"

    def __post_init__(self) -> None:
        object.__setattr__(self, "order", check_order(self.order))


@dataclass(frozen=True)
class Headway(MotionModel):
    """Contact ``headway``, the collision-free speed rule (Tordeux, Chraibi & Seyfried 2016, as JuPedSim's
    ``CollisionFreeSpeedModel``): the action sets the heading and the wanted speed ``v``, and the speed walked is
    ``min(v, max(0, (s - 2 r) / time_gap))`` with ``s`` the distance to the nearest body ahead within the corridor of
    half-width ``2 r`` (:func:`headway_factors`, every sub-step); walls are slid along and ``slide`` is the safety net
    against bodies. Config: ``motion=headway`` (``env.motion.time_gap``, ``env.motion.order``).

    Attributes:
        time_gap: ``T`` (s, ``> 0``; 1 s as JuPedSim's default).
        order: The order in which the movers act (:data:`~pedrl.sim.motion.COLLISION_ORDERS`).
    """

    name: ClassVar[str] = "headway"
    contact: ClassVar[str] = "headway"
    time_gap: float = 1.0
    order: str = "random"

    def __post_init__(self) -> None:
        object.__setattr__(self, "time_gap", check_time_gap(self.time_gap))
        object.__setattr__(self, "order", check_order(self.order))


@dataclass(frozen=True)
class Yield(Headway):
    """Contact ``yield``: :class:`Headway` with a right of way: only the bodies that act before the mover in ``order``
    (with ``door_first``, those nearer the goal) slow it, and it slides past the others, so two bodies converging on
    a door never hold each other up. Config: ``motion=yield`` (``env.motion.time_gap``, ``env.motion.order``)."""

    name: ClassVar[str] = "yield"
    contact: ClassVar[str] = "yield"


@dataclass(frozen=True)
class Continuous(MotionModel):
    """The continuous walking layer: a decision sets the desired direction and speed, and the collision-free speed
    model with its direction rule (:class:`~pedrl.sim.motion.Steering`; Tordeux, Chraibi & Seyfried 2016, as
    JuPedSim's ``CollisionFreeSpeedModel``) walks every body at steps of at most ``time_step``, the slide the safety
    net. Config: ``motion=continuous`` (``env.motion.contact``, ``.time_gap``, ``.order``, ``.time_step``,
    ``.steering.neighbour_strength`` ...).

    Attributes:
        contact: The collision-free speed rule it walks by: ``headway`` or ``yield`` (:class:`Headway`,
            :class:`Yield`).
        time_gap: ``T`` of that rule (s, ``> 0``).
        order: The order in which the movers act (:data:`~pedrl.sim.motion.COLLISION_ORDERS`).
        time_step: The longest time step (s, in ``(0, MAX_TIME_STEP]``).
        steering: The direction rule's strengths and ranges (JuPedSim's defaults).
    """

    name: ClassVar[str] = "continuous"
    contact: str = "headway"
    time_gap: float = 1.0
    order: str = "random"
    time_step: float = 0.05
    steering: Steering = field(default_factory=Steering)

    def __post_init__(self) -> None:
        object.__setattr__(self, "contact", check_choice(f"{MOTION_KEY}.contact", self.contact, CONTINUOUS_CONTACTS))
        object.__setattr__(self, "time_gap", check_time_gap(self.time_gap))
        object.__setattr__(self, "order", check_order(self.order))
        step = check_number(f"{MOTION_KEY}.time_step", self.time_step, low=0.0, high=MAX_TIME_STEP, low_open=True)
        object.__setattr__(self, "time_step", step)
        if not isinstance(self.steering, Steering):
            raise ValueError(
                f"{MOTION_KEY}.steering={self.steering!r} is invalid: must be a Steering (its keys: neighbour_strength,"
                " neighbour_range, wall_strength, wall_range)"
            )


def _sqrt(values: torch.Tensor) -> torch.Tensor:
    """Correctly rounded float32 square root, as the kernels' (torch's vectorised float32 ``sqrt`` is off by one ulp
    for about 1 value in 150); through float64, whose rounding to float32 is then exact."""
    return values.double().sqrt().to(values.dtype)


def _exp(values: torch.Tensor) -> torch.Tensor:
    """Correctly rounded float32 exponential, as the kernel's: through float64 (torch's vectorised float32 ``exp`` and
    the kernel's may differ in the last bit, which a contact can amplify)."""
    return values.double().exp().to(values.dtype)


@dataclass(frozen=True)
class SlidingMotion(Motion):
    """The constants of a decision under ``slide`` (no ``time_gap``), ``headway`` (a ``time_gap``) or ``yield`` (a
    ``time_gap`` and ``yield_to_earlier``), and of ``motion=continuous`` (``steering`` too).

    Attributes:
        time_gap: ``T`` of the collision-free speed rule (s); None for ``slide``.
        yield_to_earlier: Only the bodies that act before the mover slow it (``yield``).
        steering: ``motion=continuous``: the walking direction is recomputed at every sub-step from the commanded one
            by the direction rule (:func:`steer`), and a mover the safety net refuses only waits for the next
            sub-step; None: the decision's direction is kept (bar slides), and a refused mover stops for the decision.
    """

    time_gap: float | None = None
    yield_to_earlier: bool = False
    steering: Steering | None = None


def steer(
    *,
    positions: torch.Tensor,
    commanded: torch.Tensor,
    present: torch.Tensor,
    agent_radius: float,
    steering: Steering,
    walls: tuple[torch.Tensor, torch.Tensor, torch.Tensor],
) -> torch.Tensor:
    """The wanted velocities of a sub-step under ``motion=continuous``: each commanded speed along the direction of
    :class:`Steering` (from the commanded direction, the present bodies and the walls).

    The sums run body by body and wall by wall in index order, as the kernel's (``sliding_kernel._steer``).

    Args:
        positions: Centres ``(R, N, 2)`` (m).
        commanded: Commanded velocities ``(R, N, 2)`` (m/s): speed and direction ``e0``.
        present: Bodies in the room ``(R, N)`` bool; only they repel, and only they get a velocity.
        agent_radius: Body radius ``r`` (m).
        steering: The rule's constants.
        walls: :meth:`~pedrl.sim.geometry.Geometry.wall_segments` of the room.

    Returns:
        Wanted velocities ``(R, N, 2)`` (m/s): ``|commanded| e``, zero where the commanded speed is 0 or not present.
    """
    starts, directions, inverse = walls
    num_agents = positions.shape[1]
    cx, cy = commanded[..., X], commanded[..., Y]
    speed = _sqrt(cx * cx + cy * cy)
    moving = present & (speed > 0)
    safe = torch.where(moving, speed, 1.0)
    ex, ey = torch.where(moving, cx / safe, 0.0), torch.where(moving, cy / safe, 0.0)
    fx, fy = ex, ey
    x, y = positions[..., X], positions[..., Y]
    agents = torch.arange(num_agents, device=positions.device)

    def add(fx, fy, dx, dy, limit, strength, reach, use):
        distance = _sqrt(dx * dx + dy * dy)
        exponent = (limit - distance) / reach
        use = use & (exponent > STEERING_CUTOFF) & (distance > 0)
        weight = torch.where(use, strength * _exp(exponent), 0.0)
        safe_distance = torch.where(use, distance, 1.0)
        return fx + weight * (dx / safe_distance), fy + weight * (dy / safe_distance)

    diameter = 2.0 * agent_radius
    for j in range(num_agents):
        use = present[:, j : j + 1] & (agents != j)
        fx, fy = add(
            fx, fy, x - x[:, j : j + 1], y - y[:, j : j + 1], diameter,
            steering.neighbour_strength, steering.neighbour_range, use,
        )  # fmt: skip
    for s in range(starts.shape[0]):
        along = ((x - starts[s, X]) * directions[s, X] + (y - starts[s, Y]) * directions[s, Y]) * inverse[s]
        along = along.clamp(0.0, 1.0)
        dx = x - (starts[s, X] + along * directions[s, X])
        dy = y - (starts[s, Y] + along * directions[s, Y])
        fx, fy = add(fx, fy, dx, dy, agent_radius, steering.wall_strength, steering.wall_range, moving)
    norm = _sqrt(fx * fx + fy * fy)
    turned = norm > 0
    safe_norm = torch.where(turned, norm, 1.0)
    wx = torch.where(turned, fx / safe_norm, ex) * speed
    wy = torch.where(turned, fy / safe_norm, ey) * speed
    return torch.where(moving.unsqueeze(-1), torch.stack((wx, wy), -1), 0.0)


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
    motion: SlidingMotion,
    priority: torch.Tensor,
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
    how to compute it: on the CPU (with numba) :func:`pedrl.sim.motion.sliding_kernel.sliding_substeps`, the same
    loop compiled, with the same float32 operations in the same order (``tests/sim/test_contact.py`` checks the
    two agree to the bit on random scenes and in every scenario; exact ties between the nearest walls or bodies are
    the one place they could differ, when both pick a different one of two equally near); otherwise (CUDA,
    ``compiled=False``, ``PEDRL_NO_NUMBA=1``) the torch loop itself.

    Args:
        positions: Positions at the start of the decision ``(R, N, 2)`` (m).
        velocities: Commanded velocities ``(R, N, 2)`` (m/s).
        active: Agents in the room ``(R, N)`` bool; the others neither move nor collide.
        motion: The room and the decision's constants (:class:`~pedrl.sim.motion.SlidingMotion`).
        priority: Order of action ``(R, N)`` float (lowest acts first).
        compiled: Use the compiled CPU kernel (None: on the CPU when numba is there).

    Returns:
        The :class:`Movement` of the decision; ``blocked`` marks movers stopped because even the slid move was
        refused.
    """
    geometry, agent_radius, decision_length, num_substeps, time_gap, yield_to_earlier, steering = motion.values()
    if use_kernels(positions.device, compiled):
        from pedrl.sim.motion.sliding_kernel import sliding_substeps  # imports numba: only where it is used

        starts, directions, inverse = geometry.wall_segments()
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
            steering=steering,
        )
    return move_agents_sliding_torch(
        positions=positions, velocities=velocities, active=active, motion=motion, priority=priority
    )


def move_agents_sliding_torch(
    *,
    positions: torch.Tensor,
    velocities: torch.Tensor,
    active: torch.Tensor,
    motion: SlidingMotion,
    priority: torch.Tensor,
) -> Movement:
    """:func:`move_agents_sliding` in torch, on any device (same arguments but ``compiled``, same result): the
    specification of :func:`pedrl.sim.motion.sliding_kernel.sliding_substeps`.

    It loops over sub-steps and movers in Python, vectorised over replicas only (about 0.5 ms per mover and sub-step
    on a CPU core, 65 ms a decision for 20 rooms of 20 agents against 1 ms compiled): it is the path on CUDA and with
    ``PEDRL_NO_NUMBA=1``.
    """
    geometry, agent_radius, decision_length, num_substeps, time_gap, yield_to_earlier, steering = motion.values()
    device = positions.device
    starts, directions, inverse = geometry.wall_segments()
    commanded = velocities * active.unsqueeze(-1)
    order = priority.argsort(dim=1)
    num_replicas, num_agents = active.shape
    substep_length = decision_length / num_substeps
    radius_sq = agent_radius * agent_radius
    contact_sq = 4.0 * agent_radius * agent_radius
    rows = torch.arange(num_replicas, device=device)
    agents = torch.arange(num_agents, device=device)
    on_cpu = device.type == "cpu"  # early exits read the host; skipped elsewhere (same result)

    wanted = commanded.clone()  # (R, N, 2), the tangent part after a contact
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
        if steering is not None:  # motion=continuous: the direction rule, from the positions at the sub-step's start
            wanted = steer(
                positions=current, commanded=commanded, present=present, agent_radius=agent_radius,
                steering=steering, walls=(starts, directions, inverse),
            )  # fmt: skip
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
            # a refused mover stops for the decision, or under motion=continuous waits for the next sub-step
            going[rows, mover_index] = (moves if steering is None else mover) & ~passed

    return Movement(
        positions=current,
        blocked=blocked,
        crashed_wall=cut_wall,
        crashed_agent=cut_body & ~cut_wall,
        reached=reached,
    )

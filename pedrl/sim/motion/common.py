"""What every motion model shares: the :class:`MotionModel` base of the model dataclasses (each in the module of its
kernels), the :class:`Movement` a decision returns, the names of the collision rules and contact models (one
enumeration, which the kernels number by position), the checks of the parameters the models share, and the pair
pre-filters."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, is_dataclass
from functools import lru_cache
from typing import Any, ClassVar, Final, NamedTuple

import numpy as np
import torch

from pedrl.common.checks import check_choice, check_number, check_real
from pedrl.sim.geometry import Geometry, X, Y

PAIR_MARGIN: Final = 1e-3
"""Slack (m) of the conservative pre-filters of :func:`move_agents`; it only widens them."""


@dataclass(frozen=True)
class Movement:
    """Outcome of one decision's movement.

    Attributes:
        positions: Positions after the decision ``(R, N, 2)`` (m).
        blocked: Agents stopped by a collision ``(R, N)`` bool; under ``stop`` their speed becomes 0.
        crashed_wall: Agents whose move a wall cut ``(R, N)`` bool: blocked by it (``stop``), or deflected or
            blocked by it (``slide``, ``headway``: :func:`move_agents_sliding`).
        crashed_agent: Agents whose move another body cut, and no wall ``(R, N)`` bool (as ``crashed_wall``).
        reached: Agents whose centre passed an exit ``(R, N)`` bool.
    """

    positions: torch.Tensor
    blocked: torch.Tensor
    crashed_wall: torch.Tensor
    crashed_agent: torch.Tensor
    reached: torch.Tensor


COLLISION_RULES: Final = ("sequential", "simultaneous")
"""``sequential``: the paper's reading, movers resolved one after another in an order drawn per decision
(:class:`~pedrl.sim.motion.Stop` and every sliding model); ``simultaneous``: every proposal checked against every
other proposal at once (:class:`~pedrl.sim.motion.Simultaneous`, :func:`move_agents`)."""
COLLISION_ORDERS: Final = ("random", "door_first")
"""The orders in which the sequential rule lets the movers act in each decision (a model's ``order``): ``random``, a
random permutation per decision (random sequential update); ``door_first``, nearest to the goal point first, ties at
random (a queue moves up together instead of each follower stalling for a decision whenever it acts before its
leader)."""


CONTACT_MODELS: Final = ("stop", "slide", "headway", "yield")
"""What a body does when its move would enter another body or a wall (a motion model's ``contact``).

``stop``: it stops for the rest of the decision (:func:`move_agents_sequential` or :func:`move_agents`, the paper's
reading). ``slide``: it keeps the part of its move tangent to the contact (:func:`move_agents_sliding`).
``headway``: the collision-free speed rule (Tordeux, Chraibi & Seyfried 2016) sets the speed walked from the nearest
body ahead, and ``slide`` is the safety net (:func:`move_agents_sliding` with a ``time_gap``). ``yield``: ``headway``
with a right of way: only the bodies that act before the mover in its ``order`` (with ``door_first``, those nearer
the goal) slow it; it slides past the others (``yield_to_earlier``). Two bodies converging on a door then never hold
each other up: the one nearer goes, the other keeps its gap.
"""
MOTION_KEY: Final = "env.motion"
"""The config key of a room's motion model: its messages name its fields under it (``env.motion.time_gap``)."""


def check_order(value: Any) -> str:
    """A model's ``order`` (:data:`COLLISION_ORDERS`), else a one-line ``ValueError`` naming the config key."""
    return check_choice(f"{MOTION_KEY}.order", value, COLLISION_ORDERS)


def check_time_gap(value: Any) -> float:
    """A model's ``time_gap`` ``T`` (s, ``> 0``), else a one-line ``ValueError`` naming the config key."""
    return check_real(f"{MOTION_KEY}.time_gap", value, unit="s", positive=True)


class MotionModel:
    """How bodies move through a decision: the base of the frozen dataclasses that each describe one model with its
    parameters (:class:`~pedrl.sim.motion.Stop`, :class:`~pedrl.sim.motion.Simultaneous`,
    :class:`~pedrl.sim.motion.Slide`, :class:`~pedrl.sim.motion.Headway`, :class:`~pedrl.sim.motion.Yield`,
    :class:`~pedrl.sim.motion.Continuous`), each in the module of its kernels and validating its parameters when it is
    made. What the room and the kernels read of any model is below; a model that has no such parameter answers the
    class default.

    Attributes:
        name: The model's name in a config (``env.motion.name``; ``motion=<name>`` on the command line).
        contact: The contact rule its kernels run (:data:`CONTACT_MODELS`).
        rule: The collision rule (:data:`COLLISION_RULES`).
        order: The order of action of the sequential rule (:data:`COLLISION_ORDERS`).
        time_gap: ``T`` of the collision-free speed rule (s), or None.
        time_step: The longest time step of the continuous walking layer (s), or None (the step model).
        steering: The direction rule of the walking layer (:class:`Steering`), or None.
    """

    name: ClassVar[str]
    contact: ClassVar[str]
    rule: ClassVar[str] = "sequential"
    order: str = "random"
    time_gap: float | None = None
    time_step: float | None = None
    steering: Steering | None = None

    def to_config(self) -> dict[str, Any]:
        """The model as a config node: ``{"name": ..., <field>: <value>, ...}`` (a nested dataclass as a mapping),
        which :func:`~pedrl.sim.motion.motion_from_config` reads back."""
        values = {item.name: getattr(self, item.name) for item in fields(self)}  # type: ignore[arg-type]
        return {"name": self.name} | {key: asdict(v) if is_dataclass(v) else v for key, v in values.items()}


@dataclass(frozen=True)
class Motion:
    """The constants of one decision's movement, shared by every motion model.

    Attributes:
        geometry: The room.
        agent_radius: Body radius ``r`` (m).
        decision_length: Duration of the decision (s).
        num_substeps: Number of sub-steps ``S``.
    """

    geometry: Geometry
    agent_radius: float
    decision_length: float
    num_substeps: int

    def values(self) -> tuple[Any, ...]:
        """The fields in declaration order (no copies)."""
        return tuple(getattr(self, item.name) for item in fields(self))


# the contact models as the numba kernels number them (positions in CONTACT_MODELS)
STOP, SLIDE, HEADWAY, YIELD = (CONTACT_MODELS.index(name) for name in ("stop", "slide", "headway", "yield"))


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


STEERING_CUTOFF: Final = -20.0
"""A term of the direction rule whose exponent ``(l - d) / D`` is below this is dropped: it would weigh at most
``2e-9`` of its strength (the rule is otherwise unchanged; it bounds the work to the bodies and walls nearby)."""


GRID_MIN_AGENTS: Final = 80
"""Rooms with at least this many agents find neighbours in grids of cells (:mod:`pedrl.sim.grid_kernel`, linear time),
the others over all pairs. The numbers are the same either way; measured on the walking layer (20 sub-steps a
decision), the grid took 1.15-1.2x the pairs' time at 40 agents, 0.9-1.1x at 60 and 0.75-1.0x at 100
(``docs/performance.md``)."""


class KernelMoves(NamedTuple):
    """What a motion model's kernel writes for room ``r`` (``sequential_room``, ``sliding_room``): ``moved_to``
    ``(R, N, 2)`` float32 (m) and the flags ``(R, N)`` bool of :class:`Movement` (``cut_wall``: a wall cut the move,
    ``cut_body``: a body did; the sequential rule leaves ``cut_body`` to its caller)."""

    moved_to: np.ndarray
    blocked: np.ndarray
    cut_wall: np.ndarray
    cut_body: np.ndarray
    reached: np.ndarray


class Search(NamedTuple):
    """The kernels' neighbour search, read by name (:func:`neighbour_search`; the room's kernel constants hold it as
    ``KernelRoom.grid_min_agents`` and ``grid_reach_scale``)."""

    min_agents: int
    """Rooms of at least this many agents search grids of cells, the others every pair."""
    reach_scale: np.float32
    """The grids' reaches are scaled by it: 1 is exact; the tests' control shrinks it."""


def neighbour_search(min_agents: int = GRID_MIN_AGENTS, reach_scale: float = 1.0) -> Search:
    """The kernels' neighbour search (:class:`Search`): grids from ``min_agents`` agents, reaches times
    ``reach_scale``."""
    return Search(int(min_agents), np.float32(reach_scale))


MAX_STRENGTH: Final = 1e6
"""Largest strength ``a`` or ``b`` of the direction rule."""
MAX_RANGE: Final = 10.0
"""Largest range ``D`` or ``B`` (m) of the direction rule."""


@dataclass(frozen=True)
class Steering:
    """The direction rule of the collision-free speed model (Tordeux, Chraibi & Seyfried 2016, "Collision-free speed
    model for pedestrian dynamics", eq. 4; JuPedSim's ``CollisionFreeSpeedModel``): the walking direction is the unit
    vector of ``e0 + sum_j a exp((2 r - d_ij) / D) n_ji + sum_w b exp((r - d_iw) / B) n_wi``, with ``e0`` the
    commanded direction, ``n_ji`` the unit vector from body ``j`` to the mover, ``n_wi`` from the closest point of
    wall ``w`` to it. The defaults are JuPedSim's (``strength_neighbor_repulsion`` 8, ``range_neighbor_repulsion``
    0.1 m, ``strength_geometry_repulsion`` 5, ``range_geometry_repulsion`` 0.02 m). Each value is checked when it is
    made (strengths in ``[0, MAX_STRENGTH]``, ranges in ``(0, MAX_RANGE]`` m).

    Attributes:
        neighbour_strength: ``a`` (dimensionless).
        neighbour_range: ``D`` (m).
        wall_strength: ``b`` (dimensionless).
        wall_range: ``B`` (m).
    """

    neighbour_strength: float = 8.0
    neighbour_range: float = 0.1
    wall_strength: float = 5.0
    wall_range: float = 0.02

    def __post_init__(self) -> None:
        for item in fields(self):
            key, value = f"{MOTION_KEY}.steering.{item.name}", getattr(self, item.name)
            if item.name.endswith("strength"):
                checked = check_number(key, value, low=0.0, high=MAX_STRENGTH)
            else:
                checked = check_number(key, value, low=0.0, high=MAX_RANGE, low_open=True)
            object.__setattr__(self, item.name, checked)


STEERING_NAMES: Final = tuple(item.name for item in fields(Steering))
"""The direction rule's parameters, the names the kernels read them by (``KernelRoom.steering_<name>``,
``SlidingConstants.<name>``)."""


def steering_constant(steering: Steering | None, name: str) -> np.float32:
    """The kernels' value of the direction rule's parameter ``name`` (a field of :class:`Steering`), float32; 1 when
    there is no rule (unused then)."""
    return np.float32(1.0 if steering is None else getattr(steering, name))

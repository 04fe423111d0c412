"""The deictic state of each agent (paper Table 1), its feature layout, and the helpers built on it.

The reference line joins the agent's centre to its goal (the door centre in the paper's room; in general the
agent's current waypoint or exit, ``RoomEnv.targets``); its world angle is ``phi``. Every angle is
relative to ``phi`` and wrapped to ``(-pi, pi]``. With ``k`` neighbours and ``w`` walls there are
``3 + 3k + 2w`` features (28 for the paper's ``k = 7``, ``w = 2``):

=======  ==========================  ==============================================================  ====
index    name                        definition                                                      unit
=======  ==========================  ==============================================================  ====
0        ``speed``                   own speed ``s``                                                 m/s
1        ``velocity_angle``          ``wrap(theta - phi)``                                           rad
2        ``door_distance``           distance from the centre to its goal (the door centre)          m
3+3i     ``neighbour{i}_rel_speed``  ``(v_j - v_i) . u_ij``, ``u_ij`` the unit vector from i to j    m/s
4+3i     ``neighbour{i}_distance``   centre-to-centre distance to the i-th nearest active agent      m
5+3i     ``neighbour{i}_angle``      ``wrap(atan2(p_j - p_i) - phi)``                                rad
3+3k+2j  ``wall{j}_distance``        distance to the closest point of the j-th nearest wall segment  m
4+3k+2j  ``wall{j}_angle``           ``wrap(angle of that closest point - phi)``                     rad
=======  ==========================  ==============================================================  ====

Neighbours and walls are sorted nearest first. Neighbour slots without a neighbour are 0 and flagged False in
the neighbour mask.

Beside the state, not part of it: each sensed neighbour's velocity in the agent's goal frame,
``neighbour_velocity (R, N, k, 2)`` = ``(v_j . e_phi, v_j . e_phi_perp)`` (m/s; ``e_phi`` the unit vector of the
reference line, ``e_phi_perp`` it turned a quarter left), 0 in empty slots. The paper's state gives only the
closing speed of a neighbour; a learner that reads this (``algo.neighbour_velocity`` of the neural learner) can tell a
walker coming at it from a slower one ahead.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from typing import Final

import torch

from pedrl.sim.geometry import TWO_PI, Geometry, X, Y, wrap_angle

NUM_OWN_FEATURES: Final = 3
FEATURES_PER_NEIGHBOUR: Final = 3
FEATURES_PER_WALL: Final = 2
SPEED: Final = 0
"""Index of the own speed in the state (then ``VELOCITY_ANGLE``, ``DOOR_DISTANCE``)."""
VELOCITY_ANGLE: Final = 1
DOOR_DISTANCE: Final = 2
REL_SPEED: Final = 0
"""Offset of the relative speed inside a neighbour's 3 features (then ``DISTANCE``, ``ANGLE``)."""
DISTANCE: Final = 1
ANGLE: Final = 2
MIN_VOID_DISTANCE: Final = 0.8
"""Lower end (m) of the distances :func:`fill_void_neighbours` draws when nothing is sensed: two body radii of 0.4 m."""


def num_features(num_neighbours: int, num_walls: int) -> int:
    """Length ``3 + 3k + 2w`` of the state with ``k`` neighbours and ``w`` walls."""
    return NUM_OWN_FEATURES + FEATURES_PER_NEIGHBOUR * num_neighbours + FEATURES_PER_WALL * num_walls


def feature_names(num_neighbours: int, num_walls: int) -> list[str]:
    """Names of the features, in layout order (see the module docstring).

    Args:
        num_neighbours: Number ``k`` of sensed neighbours.
        num_walls: Number ``w`` of sensed walls.

    Returns:
        ``3 + 3k + 2w`` names: ``speed``, ``velocity_angle``, ``door_distance``, ``neighbour0_rel_speed``...
    """
    names = ["speed", "velocity_angle", "door_distance"]
    for i in range(num_neighbours):
        names += [f"neighbour{i}_rel_speed", f"neighbour{i}_distance", f"neighbour{i}_angle"]
    for j in range(num_walls):
        names += [f"wall{j}_distance", f"wall{j}_angle"]
    return names


def feature_indices(
    num_sensed: int, num_neighbours: int, num_walls: int, *, device: str | torch.device = "cpu"
) -> torch.Tensor:
    """Indices of the features of a state with ``num_sensed`` neighbours: the projection Gamma of IN-VQQL.

    The own features, the first ``num_sensed`` neighbour slots and all wall features, in layout order.

    Args:
        num_sensed: Number of neighbours actually sensed, in ``[0, num_neighbours]``.
        num_neighbours: Number ``k`` of neighbour slots of the full state.
        num_walls: Number ``w`` of sensed walls.
        device: Device of the returned tensor.

    Returns:
        Indices into the full state, int64 ``(3 + 3 * num_sensed + 2w,)``.

    Raises:
        ValueError: If ``num_sensed`` is outside ``[0, num_neighbours]``.
    """
    if not 0 <= num_sensed <= num_neighbours:
        raise ValueError(f"num_sensed={num_sensed!r} is invalid: must be in [0, num_neighbours={num_neighbours}]")
    walls_start = NUM_OWN_FEATURES + FEATURES_PER_NEIGHBOUR * num_neighbours
    own_and_neighbours = torch.arange(NUM_OWN_FEATURES + FEATURES_PER_NEIGHBOUR * num_sensed, device=device)
    walls = torch.arange(walls_start, walls_start + FEATURES_PER_WALL * num_walls, device=device)
    return torch.cat((own_and_neighbours, walls))


def distance_indices(num_neighbours: int, num_walls: int, *, device: str | torch.device = "cpu") -> torch.Tensor:
    """Indices of the distance features (m): the door's, each neighbour's and each wall's, in layout order.

    Args:
        num_neighbours: Number ``k`` of neighbour slots.
        num_walls: Number ``w`` of sensed walls.
        device: Device of the returned tensor.

    Returns:
        int64 ``(1 + k + w,)``.
    """
    walls_start = NUM_OWN_FEATURES + FEATURES_PER_NEIGHBOUR * num_neighbours
    neighbours = range(NUM_OWN_FEATURES + DISTANCE, walls_start, FEATURES_PER_NEIGHBOUR)
    walls = range(walls_start, walls_start + FEATURES_PER_WALL * num_walls, FEATURES_PER_WALL)  # wall{j}_distance
    return torch.tensor([DOOR_DISTANCE, *neighbours, *walls], dtype=torch.int64, device=device)


@dataclass(frozen=True)
class Observation:
    """The sensed states of all agents.

    Attributes:
        features: States ``(R, N, 3 + 3k + 2w)`` float32; rows of non-observers are 0.
        num_sensed: Neighbours sensed ``(R, N)`` int64, ``min(sensed others, k)``; 0 for non-observers.
        neighbour_mask: Which neighbour slots hold a neighbour ``(R, N, k)`` bool.
        neighbour_velocity: Each slot's neighbour's velocity in the goal frame ``(R, N, k, 2)`` float32 (module
            docstring), 0 in empty slots and for non-observers.
    """

    features: torch.Tensor
    num_sensed: torch.Tensor
    neighbour_mask: torch.Tensor
    neighbour_velocity: torch.Tensor


def observe(
    *,
    positions: torch.Tensor,
    velocities: torch.Tensor,
    headings: torch.Tensor,
    speeds: torch.Tensor,
    observers: torch.Tensor,
    sensed: torch.Tensor,
    geometry: Geometry,
    num_neighbours: int,
    num_walls: int,
    goals: torch.Tensor | None = None,
) -> Observation:
    """Compute the deictic state of every agent (module docstring layout).

    Args:
        positions: Positions ``(R, N, 2)`` (m).
        velocities: Velocities ``(R, N, 2)`` (m/s).
        headings: Headings ``(R, N)`` (rad).
        speeds: Speeds ``(R, N)`` (m/s).
        observers: Agents whose state is computed ``(R, N)`` bool; the other rows are 0.
        sensed: Agents that can be sensed as neighbours ``(R, N)`` bool (an agent never senses itself).
        geometry: Walls and exits.
        goals: Each agent's target ``(R, N, 2)`` (m), the other end of its reference line: its waypoint or exit
            (``RoomEnv.targets``); ``None`` is the goal point of the first exit for everyone.
        num_neighbours: Number ``k`` of neighbour slots, ``>= 0``.
        num_walls: Number ``w`` of sensed walls, at most ``geometry.num_walls``.

    Returns:
        The :class:`Observation`.
    """
    num_replicas, num_agents, _ = positions.shape
    device = positions.device
    shape = (num_replicas, num_agents)
    slots = min(num_neighbours, num_agents - 1)  # neighbour slots that can ever be filled
    if goals is None:
        goals = geometry.exit_goals[0].expand(num_replicas, num_agents, 2)
    goal_x, goal_y = goals[..., X], goals[..., Y]
    x, y = positions[..., X], positions[..., Y]
    to_goal_x = goal_x - x  # the reference line, (R, N)
    to_goal_y = goal_y - y
    # world angles of the heading, the neighbours and the walls; made relative to phi and wrapped at once
    angles = [headings.unsqueeze(-1)]

    if slots > 0:
        offset_x = x.unsqueeze(1) - x.unsqueeze(2)  # [r, i, j] = x_j - x_i, (R, N, N)
        offset_y = y.unsqueeze(1) - y.unsqueeze(2)
        hidden = ~sensed.unsqueeze(1) | _eye(num_agents, device)
        distance = torch.hypot(offset_x, offset_y).masked_fill_(hidden, math.inf)
        distance, nearest = torch.topk(distance, slots, dim=-1, largest=False, sorted=True)  # (R, N, k')
        neighbour_mask = torch.isfinite(distance) & observers.unsqueeze(-1)
        along_x = torch.gather(offset_x, 2, nearest)  # p_j - p_i, (R, N, k')
        along_y = torch.gather(offset_y, 2, nearest)
        velocity_x, velocity_y = velocities[..., X], velocities[..., Y]
        closing_x = torch.gather(velocity_x.unsqueeze(1).expand(*shape, num_agents), 2, nearest)
        closing_y = torch.gather(velocity_y.unsqueeze(1).expand(*shape, num_agents), 2, nearest)
        moving = torch.stack((closing_x, closing_y), dim=-1)  # v_j, (R, N, k', 2)
        closing_x = closing_x - velocity_x.unsqueeze(-1)  # v_j - v_i
        closing_y = closing_y - velocity_y.unsqueeze(-1)
        rel_speed = (closing_x * along_x + closing_y * along_y) / distance
        angles.append(torch.atan2(along_y, along_x))
    else:
        neighbour_mask = torch.zeros(*shape, 0, dtype=torch.bool, device=device)
        moving = torch.zeros(*shape, 0, 2, device=device)

    if num_walls > 0:
        offsets = geometry.wall_offsets(positions)  # closest point - p, (R, N, S, 2)
        wall_distance = torch.hypot(offsets[..., X], offsets[..., Y])
        wall_distance, order = torch.topk(wall_distance, num_walls, dim=-1, largest=False)  # (R, N, w)
        offsets = torch.gather(offsets, 2, order.unsqueeze(-1).expand(-1, -1, -1, 2))
        angles.append(torch.atan2(offsets[..., Y], offsets[..., X]))

    reference = torch.atan2(to_goal_y, to_goal_x).unsqueeze(-1)  # phi (R, N, 1)
    cos_phi, sin_phi = torch.cos(reference), torch.sin(reference)
    velocity = torch.stack((moving[..., X] * cos_phi + moving[..., Y] * sin_phi,
                            moving[..., Y] * cos_phi - moving[..., X] * sin_phi), dim=-1)  # fmt: skip
    angle = wrap_angle(torch.cat(angles, dim=-1) - reference)  # (R, N, 1 + k' + w)
    own = torch.stack((speeds, angle[..., 0], torch.hypot(to_goal_x, to_goal_y)), dim=-1)
    parts = [own]
    if slots > 0:
        neighbours = torch.stack((rel_speed, distance, angle[..., 1 : 1 + slots]), dim=-1)  # (R, N, k', 3)
        parts.append(neighbours.masked_fill_(~neighbour_mask.unsqueeze(-1), 0.0).flatten(2))
    velocity = velocity.masked_fill_(~neighbour_mask.unsqueeze(-1), 0.0)
    if slots < num_neighbours:
        parts.append(torch.zeros(*shape, FEATURES_PER_NEIGHBOUR * (num_neighbours - slots), device=device))
        neighbour_mask = torch.nn.functional.pad(neighbour_mask, (0, num_neighbours - slots))
        velocity = torch.nn.functional.pad(velocity, (0, 0, 0, num_neighbours - slots))
    if num_walls > 0:
        parts.append(torch.stack((wall_distance, angle[..., 1 + slots :]), dim=-1).flatten(2))  # (R, N, 2w)
    features = torch.cat(parts, dim=-1).masked_fill_(~observers.unsqueeze(-1), 0.0)
    return Observation(features=features, num_sensed=neighbour_mask.sum(-1), neighbour_mask=neighbour_mask,
                       neighbour_velocity=velocity)  # fmt: skip


@lru_cache(maxsize=16)
def _eye(num_agents: int, device: torch.device) -> torch.Tensor:
    """``(N, N)`` bool identity: an agent never senses itself."""
    return torch.eye(num_agents, dtype=torch.bool, device=device)


def fill_void_neighbours(
    obs: torch.Tensor,
    num_sensed: torch.Tensor,
    *,
    num_neighbours: int,
    num_walls: int,
    max_distance: float,
    max_speed: float,
    generator: torch.Generator | None = None,
    min_distance: float = MIN_VOID_DISTANCE,
    uniform: torch.Tensor | None = None,
) -> torch.Tensor:
    """Fill the empty neighbour slots with random valid values (IT-VQQL, paper section 5.1).

    For a state with ``n = num_sensed`` neighbours, the slots ``n .. k-1`` get

    - distance: the order statistics of ``k - n`` draws uniform in ``[low, high]`` (drawn sorted, by
      exponential spacings), where ``low`` is the last sensed distance (``min_distance`` when ``n = 0``) and
      ``high = max(max_distance, low)``; so the slots stay sorted nearest first and no filled neighbour is
      nearer than a sensed one;
    - angle: uniform in ``(-pi, pi]`` (rad);
    - relative speed: uniform in ``[-2 max_speed, 2 max_speed]`` (m/s), the range of ``(v_j - v_i) . u_ij``.

    The own features, the sensed slots and the wall features are returned unchanged. Rows are filled whatever
    the agent's state; mask inactive agents yourself if they must stay 0.

    Args:
        obs: States ``(..., 3 + 3k + 2w)``.
        num_sensed: Neighbours actually sensed ``(...)`` int64, in ``[0, k]``.
        num_neighbours: Number ``k`` of neighbour slots.
        num_walls: Number ``w`` of wall slots.
        max_distance: Largest distance to draw (m), e.g. the room diagonal.
        max_speed: Maximum agent speed (m/s).
        generator: Source of randomness, on the device of ``obs``.
        min_distance: Lower end of the distances when nothing is sensed (m); default two body radii of 0.4 m.
        uniform: The random draws to use ``(..., 3k + 1)`` in ``[0, 1)`` (see :func:`void_draws`), instead of
            drawing new ones from ``generator``: the same draws give an agent the same filling for the same
            sensed state, so a trainer draws them once per agent and trial.

    Returns:
        A new tensor of the shape of ``obs`` with the empty slots filled.

    Raises:
        ValueError: If the last dimension of ``obs`` does not match ``num_neighbours`` and ``num_walls``.
    """
    expected = num_features(num_neighbours, num_walls)
    if obs.shape[-1] != expected:
        raise ValueError(
            f"obs.shape[-1]={obs.shape[-1]} is invalid: must be 3 + 3 * {num_neighbours} + 2 * {num_walls} = {expected}"
        )
    if num_neighbours == 0:
        return obs.clone()
    k = num_neighbours
    batch = obs.shape[:-1]
    start, stop = NUM_OWN_FEATURES, NUM_OWN_FEATURES + FEATURES_PER_NEIGHBOUR * k
    neighbours = obs[..., start:stop].unflatten(-1, (k, FEATURES_PER_NEIGHBOUR))  # (..., k, 3)
    void = torch.arange(k, device=obs.device) >= num_sensed.unsqueeze(-1)  # (..., k)
    last = torch.gather(neighbours[..., DISTANCE], -1, (num_sensed - 1).clamp_min(0).unsqueeze(-1))
    low = torch.where(num_sensed.unsqueeze(-1) > 0, last, min_distance)  # (..., 1)
    span = (max_distance - low).clamp_min_(0.0)  # high - low, high = max(max_distance, low)

    if uniform is None:
        uniform = void_draws(batch, num_neighbours=k, generator=generator, device=obs.device)
    # Sorted uniforms without sorting: with E_1 .. E_{m+1} iid exponential, the partial sums of the first m
    # over the total are the order statistics of m uniforms. Sensed slots (a prefix) contribute 0.
    spacing = uniform[..., : k + 1].neg().log1p_().neg_()  # Exp(1), finite since uniform < 1
    partial = torch.where(void, spacing[..., :k], 0.0).cumsum(-1)
    distance = low + partial / (partial[..., -1:] + spacing[..., k:]) * span
    angle = math.pi - TWO_PI * uniform[..., k + 1 : 2 * k + 1]
    angle = angle.masked_fill_(angle <= -math.pi, math.pi)  # (-pi, pi]
    rel_speed = uniform[..., 2 * k + 1 :] * (4.0 * max_speed) - 2.0 * max_speed
    filled = torch.stack((rel_speed, distance, angle), dim=-1)
    neighbours = torch.where(void.unsqueeze(-1), filled, neighbours).flatten(-2)
    return torch.cat((obs[..., :start], neighbours, obs[..., stop:]), dim=-1)


def void_draws(
    batch: tuple[int, ...],
    *,
    num_neighbours: int,
    generator: torch.Generator | None = None,
    device: str | torch.device = "cpu",
) -> torch.Tensor:
    """Uniform draws ``(*batch, 3k + 1)`` in ``[0, 1)`` for :func:`fill_void_neighbours` (``uniform=``)."""
    return torch.rand((*batch, 3 * num_neighbours + 1), generator=generator, device=device)


@functools.cache
def compiled_observe() -> Callable[..., Observation]:
    """:func:`~pedrl.sim.sensing.observe` through ``torch.compile`` (static shapes), built once per process.

    Every room of one shape shares its graph: a new trial, a partial reset or another room of the same size reuses
    it (``tests/sim/test_env.py`` checks that the graph count stays constant). Inductor caches the compiled code
    on disk (``TORCHINDUCTOR_CACHE_DIR``), so later processes compile faster.
    """
    return torch.compile(observe, dynamic=False)

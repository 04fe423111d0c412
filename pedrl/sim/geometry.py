"""The room: a rectangle with a door in one short side, bounded by five wall segments (pure torch).

The room is ``[0, width] x [0, length]`` (metres). The door is a gap of ``door_width`` centred on the side
``y = length``; the goal point is ``(width / 2, length + goal_depth)``, the door centre by default. The five
walls, in this order:

====  ===========  =====================================
 0    bottom       ``(0, 0) - (width, 0)``
 1    right        ``(width, 0) - (width, length)``
 2    top_right    ``(width, length) - (door_right, length)``
 3    top_left     ``(door_left, length) - (0, length)``
 4    left         ``(0, length) - (0, 0)``
====  ===========  =====================================

Segments are ``(S, 2, 2)`` tensors: segment ``s`` runs from ``segments[s, 0]`` to ``segments[s, 1]``.
Point tensors have any leading shape, e.g. ``(R, N, 2)``, with axis constants ``X = 0``, ``Y = 1``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Final

import torch

X: Final = 0
Y: Final = 1
NUM_WALLS: Final = 5
WALL_NAMES: Final = ("bottom", "right", "top_right", "top_left", "left")
TWO_PI: Final = 2.0 * math.pi


def wrap_angle(angles: torch.Tensor) -> torch.Tensor:
    """Wrap angles to ``(-pi, pi]``.

    Args:
        angles: Angles in radians, any shape.

    Returns:
        The same angles wrapped to ``(-pi, pi]`` (rad), same shape and dtype.
    """
    wrapped = math.pi - torch.remainder(math.pi - angles, TWO_PI)
    # remainder can round up to exactly 2 pi in float32, which would give -pi: the same direction as pi.
    return wrapped.masked_fill_(wrapped <= -math.pi, math.pi)


def build_walls(*, width: float, length: float, door_width: float, device: str | torch.device = "cpu") -> torch.Tensor:
    """The five wall segments of the room, in the documented order.

    Args:
        width: Room width along x (m).
        length: Room length along y (m); the door is in the side ``y = length``.
        door_width: Width of the door gap (m), centred at ``x = width / 2``.
        device: Device of the returned tensor.

    Returns:
        Wall segments, float32 ``(5, 2, 2)`` (m).
    """
    door_left = width / 2.0 - door_width / 2.0
    door_right = width / 2.0 + door_width / 2.0
    return torch.tensor(
        [
            [[0.0, 0.0], [width, 0.0]],
            [[width, 0.0], [width, length]],
            [[width, length], [door_right, length]],
            [[door_left, length], [0.0, length]],
            [[0.0, length], [0.0, 0.0]],
        ],
        dtype=torch.float32,
        device=device,
    )


def closest_points_on_segments(points: torch.Tensor, segments: torch.Tensor) -> torch.Tensor:
    """Closest point of every segment to every point (general segments; see also :class:`RoomGeometry`).

    Args:
        points: Points ``(..., 2)`` (m).
        segments: Segments ``(S, 2, 2)`` (m); a segment of length 0 is a point.

    Returns:
        Closest points ``(..., S, 2)`` (m).
    """
    starts = segments[:, 0]
    directions = segments[:, 1] - starts
    length_sq = (directions * directions).sum(-1)
    inverse = torch.where(length_sq > 0, 1.0 / length_sq.clamp_min(1e-30), torch.zeros_like(length_sq))
    offsets = points.unsqueeze(-2) - starts  # (..., S, 2)
    along = ((offsets * directions).sum(-1) * inverse).clamp(0.0, 1.0)  # (..., S)
    return starts + along.unsqueeze(-1) * directions


def distances_to_segments(points: torch.Tensor, segments: torch.Tensor) -> torch.Tensor:
    """Euclidean distance from every point to every segment.

    Args:
        points: Points ``(..., 2)`` (m).
        segments: Segments ``(S, 2, 2)`` (m).

    Returns:
        Distances ``(..., S)`` (m).
    """
    closest = closest_points_on_segments(points, segments)
    return torch.linalg.vector_norm(points.unsqueeze(-2) - closest, dim=-1)


@dataclass(frozen=True, eq=False)
class RoomGeometry:
    """The room, its door and its walls, fixed at build time (for the simulation, evaluation and plots).

    Attributes:
        width: Room width along x (m).
        length: Room length along y (m); the door is in the side ``y = length``.
        door_width: Width of the door gap (m).
        walls: The five wall segments, float32 ``(5, 2, 2)`` (m), order as in the module docstring.
    """

    width: float
    length: float
    door_width: float
    walls: torch.Tensor
    goal_depth: float = 0.0
    _box_low: torch.Tensor = field(init=False, repr=False)
    _box_high: torch.Tensor = field(init=False, repr=False)

    def __post_init__(self) -> None:
        # Every wall is axis-aligned, so its closest point to p is p clamped to the wall's bounding box.
        object.__setattr__(self, "_box_low", self.walls.amin(1))  # (5, 2)
        object.__setattr__(self, "_box_high", self.walls.amax(1))

    @classmethod
    def build(
        cls,
        *,
        width: float,
        length: float,
        door_width: float,
        goal_depth: float = 0.0,
        device: str | torch.device = "cpu",
    ) -> RoomGeometry:
        """Build the room of the given size (m) with its walls on ``device``."""
        walls = build_walls(width=width, length=length, door_width=door_width, device=device)
        return cls(
            width=float(width),
            length=float(length),
            door_width=float(door_width),
            walls=walls,
            goal_depth=float(goal_depth),
        )

    @property
    def door_left(self) -> float:
        """x of the left door post (m)."""
        return self.width / 2.0 - self.door_width / 2.0

    @property
    def door_right(self) -> float:
        """x of the right door post (m)."""
        return self.width / 2.0 + self.door_width / 2.0

    @property
    def goal(self) -> tuple[float, float]:
        """The goal point ``(width / 2, length + goal_depth)`` (m): the door centre when ``goal_depth = 0``."""
        return (self.width / 2.0, self.length + self.goal_depth)

    @property
    def device(self) -> torch.device:
        """Device of the wall tensor."""
        return self.walls.device

    @property
    def diagonal(self) -> float:
        """Length of the room diagonal (m): no two points of the room are further apart."""
        return math.hypot(self.width, self.length)

    def closest_wall_points(self, points: torch.Tensor) -> torch.Tensor:
        """Closest point of each wall to each point; equal to :func:`closest_points_on_segments` of the walls.

        Args:
            points: Points ``(..., 2)`` (m).

        Returns:
            Closest points ``(..., 5, 2)`` (m).
        """
        return torch.clamp(points.unsqueeze(-2), self._box_low, self._box_high)

    def wall_offsets(self, points: torch.Tensor) -> torch.Tensor:
        """Offsets from each point to the closest point of each wall.

        Args:
            points: Points ``(..., 2)`` (m).

        Returns:
            Closest point minus point ``(..., 5, 2)`` (m), walls in the documented order.
        """
        return self.closest_wall_points(points) - points.unsqueeze(-2)

    def squared_wall_distances(self, points: torch.Tensor) -> torch.Tensor:
        """Squared distance from each point to each wall.

        Args:
            points: Points ``(..., 2)`` (m).

        Returns:
            Squared distances ``(..., 5)`` (m^2).
        """
        offsets = self.wall_offsets(points)
        return (offsets * offsets).sum(-1)

    def touches_walls(self, points: torch.Tensor, *, radius: float) -> torch.Tensor:
        """Whether a disc of ``radius`` centred at each point intersects a wall (``dist < radius``).

        Args:
            points: Disc centres ``(..., 2)`` (m).
            radius: Disc radius (m).

        Returns:
            ``(...)`` bool.
        """
        return self.squared_wall_distances(points).amin(-1) < radius * radius

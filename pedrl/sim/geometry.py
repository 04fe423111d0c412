"""Geometry of the simulation: wall segments, exits, spawn areas and routes, as tensors (pure torch).

A walkable area is bounded by wall segments and exit segments. An agent leaves through any exit: it has left once
its centre is on the far side of an exit segment (within the exit's span). :class:`Geometry` is the compiled form of
a walkable area, the one the simulation reads; its one description is a scenario of ``pedrl.scenarios`` (the paper's
room one of them), which :meth:`Geometry.build` compiles from the segments of a shapely polygon (this package may
not import shapely). Routes, where an area has them, are a :class:`RouteTable` (built with the scenario).

The compiled area pads its walls to a multiple of :data:`WALL_PADDING` with points far away, so that rooms of
different shapes share tensor shapes. Segments are ``(S, 2, 2)`` tensors: segment ``s`` runs from ``segments[s, 0]``
to ``segments[s, 1]``. Point tensors have any leading shape, e.g. ``(R, N, 2)``, with axis constants ``X = 0``,
``Y = 1``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Final, NamedTuple

import numpy as np
import torch

X: Final = 0
Y: Final = 1
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


def closest_points_on_segments(points: torch.Tensor, segments: torch.Tensor) -> torch.Tensor:
    """Closest point of every segment to every point (general segments; see also :class:`Geometry`).

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


WALL_PADDING: Final = 8
"""Walls are padded with far-away points to a multiple of this count."""
FAR: Final = 1.0e6
"""Coordinate (m) of the padding points: never among the sensed walls, never touched."""


def inside_polygon(points: torch.Tensor, edges: torch.Tensor) -> torch.Tensor:
    """Even-odd test of points against the closed boundary ``edges`` (outer ring and holes, any order).

    The tensor counterpart, for points on the device, of shapely's ``contains_xy``; points on an edge count as
    either side.

    Args:
        points: Points ``(..., 2)`` (m).
        edges: Boundary segments ``(P, 2, 2)`` (m), forming closed rings.

    Returns:
        ``(...)`` bool.
    """
    start, end = edges[:, 0], edges[:, 1]  # (P, 2)
    x, y = points[..., X].unsqueeze(-1), points[..., Y].unsqueeze(-1)  # (..., 1)
    straddles = (start[:, Y] > y) != (end[:, Y] > y)  # (..., P)
    dy = end[:, Y] - start[:, Y]
    crossing_x = start[:, X] + (y - start[:, Y]) * (end[:, X] - start[:, X]) / torch.where(dy == 0, 1.0, dy)
    return ((straddles & (x < crossing_x)).sum(-1) % 2) == 1


@dataclass(frozen=True, eq=False)
class SpawnArea:
    """Where a group of agents starts, which exit it takes, and its route there.

    Attributes:
        box: Bounding box ``(x_min, y_min, x_max, y_max)`` of the area (m): centres are drawn uniformly in it,
            shrunk by the body radius, and kept if inside ``edges`` and clear of every wall.
        edges: Boundary segments of the area ``(P, 2, 2)`` (m).
        area: Area (m^2).
        perimeter: Perimeter (m).
        exit: Index of the exit the group takes, or -1 for each agent's nearest exit (decided at placement).
        weight: Share of the agents in this group (relative to the other groups).
        waypoints: Points ``(K, 2)`` (m) the agents aim at in turn before their exit (the reference line of the
            state runs to the current one); ``(0, 2)`` for none.
    """

    box: tuple[float, float, float, float]
    edges: torch.Tensor
    area: float
    perimeter: float
    exit: int = -1
    weight: float = 1.0
    waypoints: torch.Tensor | None = None

    @property
    def is_box(self) -> bool:
        """Whether the area is its bounding box (an axis-aligned rectangle)."""
        x_min, y_min, x_max, y_max = self.box
        return abs((x_max - x_min) * (y_max - y_min) - self.area) <= 1e-9 * max(self.area, 1.0)

    def free_area(self, radius: float) -> float:
        """Area (m^2) where a centre may lie, clear of the boundary by ``radius``: the inner parallel body,
        ``area - perimeter r + 4 r^2``, exact for rectangles, an estimate for other shapes."""
        return max(self.area - self.perimeter * radius + 4.0 * radius * radius, 0.0)


@dataclass(frozen=True, eq=False)
class RouteTable:
    """The routes of a walkable area: a visibility graph's nodes, each node's route length to each exit and the next
    node on that route (``pedrl.scenarios`` builds it with the scenario; the one route type of the package).

    Attributes:
        nodes: Route corners ``(M, 2)`` float64 (m), clear of the walls.
        lengths: Route length from each node to ``ends[e]`` ``(M, E)`` float64 (m); inf: no route.
        next_node: The next node on that route ``(M, E)`` int64; -1: the exit itself.
        ends: Where the routes end ``(E, 2)`` float64 (m): a point inside each exit, the clearance in from its middle.

    A compiled area (:class:`Geometry`) derives from it what the room reads: the route lengths to its goal points
    (:attr:`Geometry.route_costs`), the nodes in float32 (:attr:`Geometry.route_nodes`) and the wall corners a line
    of sight keeps clear of (:attr:`Geometry.route_corners`).
    """

    nodes: torch.Tensor
    lengths: torch.Tensor
    next_node: torch.Tensor
    ends: torch.Tensor

    __hash__ = None  # equal by value, as the scenario that holds it

    def __eq__(self, other: object) -> bool:
        """The same routes: every tensor equal (dtype and device included)."""
        if not isinstance(other, RouteTable):
            return NotImplemented
        return all(
            torch.equal(a, b) and a.dtype == b.dtype for a, b in zip(self.tensors(), other.tensors(), strict=True)
        )

    def tensors(self) -> tuple[torch.Tensor, ...]:
        """``(nodes, lengths, next_node, ends)``."""
        return self.nodes, self.lengths, self.next_node, self.ends

    def to(self, device: str | torch.device) -> RouteTable:
        """The same table on ``device``."""
        return RouteTable(*(t.to(device) for t in self.tensors()))


class Walls(NamedTuple):
    """The walls as the numba kernels read them (:meth:`Geometry.kernel_walls`), float32 but ``aligned``."""

    starts: np.ndarray
    """``(S, 2)`` each wall's first end (m)."""
    directions: np.ndarray
    """``(S, 2)`` from its first end to its second (m)."""
    inverse: np.ndarray
    """``(S,)`` one over its squared length (0 for a point)."""
    aligned: np.ndarray
    """``(S,)`` bool: axis-aligned (its closest point is a point clamped to its box)."""
    low: np.ndarray
    """``(S, 2)`` the lower corner of its bounding box (m)."""
    high: np.ndarray
    """``(S, 2)`` the upper corner of its bounding box (m)."""


class Exits(NamedTuple):
    """The exits as the numba kernels read them (:meth:`Geometry.kernel_exits`), float32."""

    start: np.ndarray
    """``(E, 2)`` each exit's first end (m)."""
    normal: np.ndarray
    """``(E, 2)`` its unit normal out of the area."""
    tangent: np.ndarray
    """``(E, 2)`` from its first end to its second (m)."""
    span: np.ndarray
    """``(E,)`` its squared length (m^2)."""
    goals: np.ndarray
    """``(E, 2)`` its goal point (m)."""


@dataclass(frozen=True, eq=False)
class Geometry:
    """A walkable area compiled for the simulation: walls, exits, spawn areas and routes as tensors on one device.

    Attributes:
        walls: Wall segments ``(S, 2, 2)`` float32 (m), the ``num_walls`` real ones first, then padding points.
        num_walls: Number of real wall segments.
        exits: Exit segments ``(E, 2, 2)`` float32 (m), on the boundary.
        exit_normals: Unit normals ``(E, 2)`` pointing out of the walkable area through each exit.
        spawns: The spawn areas (at least one).
        bounds: ``(x_min, y_min, x_max, y_max)`` of the walkable area (m).
        clear_box: An axis-aligned box ``(x_min, y_min, x_max, y_max)`` inside the walkable area that no wall or
            exit crosses (m), for the fast paths of the collision rules; a box of zero size disables them.
        goal_depth: How far behind each exit its goal point lies (m, ``>= 0``): the room's ``goal_depth``.
        waypoint_radius: Distance (m) at which an agent counts a waypoint as reached and aims at the next.
        name: A label (the scenario's name).
        routes: The area's :class:`RouteTable` (:mod:`pedrl.sim.routing`), or None where every start sees every
            exit.
        exit_goals: Goal point of each exit ``(E, 2)`` float32 (m), derived: its centre, ``goal_depth`` behind it.
        route_nodes: ``routes.nodes`` in float32 ``(M, 2)`` (m), derived; None without routes.
        route_costs: Route length from each node to each exit's goal point ``(M, E)`` float32 (m), derived:
            ``routes.lengths`` plus the last leg from the route's end to the goal point; None without routes.
        route_corners: Wall corners ``(C, 2)`` float32 (m) that a line of sight keeps clear of
            (:data:`pedrl.sim.routing.CORNER_CLEARANCE`), derived: the ends of the walls, less the exits' own ends;
            None without routes.
        box_low: Lower corner of each wall's bounding box ``(S, 2)`` (m), derived from ``walls``: an axis-aligned
            wall's closest point to ``p`` is ``p`` clamped to its box (exact).
        box_high: Upper corner of each wall's bounding box ``(S, 2)`` (m), derived from ``walls``.
        aligned_walls: Which walls are axis-aligned ``(S,)`` bool, derived from ``walls``: their closest point is
            the point clamped to their box.
        axis_aligned: Whether every wall (padding included) is axis-aligned, derived from ``walls``: the wall
            queries (and the sequential kernel) then clamp to the boxes alone.
        exit_tangents: ``exits[:, 1] - exits[:, 0]`` ``(E, 2)`` (m), derived from ``exits``.
        exit_spans: Squared length of each exit ``(E,)`` (m^2), derived from ``exits``: a point is within an exit's
            span when its offset from ``exits[:, 0]`` projects onto the tangent in ``[0, exit_spans]``.

    The derived attributes are computed when the geometry is made (``dataclasses.replace`` with another
    ``goal_depth`` recomputes the goal points); the kernels read them as they are.
    """

    walls: torch.Tensor
    num_walls: int
    exits: torch.Tensor
    exit_normals: torch.Tensor
    spawns: tuple[SpawnArea, ...]
    bounds: tuple[float, float, float, float]
    clear_box: tuple[float, float, float, float]
    goal_depth: float = 0.0
    waypoint_radius: float = 2.0
    name: str = "custom"
    routes: RouteTable | None = None
    exit_goals: torch.Tensor = field(init=False, repr=False)
    route_nodes: torch.Tensor | None = field(init=False, repr=False)
    route_costs: torch.Tensor | None = field(init=False, repr=False)
    route_corners: torch.Tensor | None = field(init=False, repr=False)
    box_low: torch.Tensor = field(init=False, repr=False)
    box_high: torch.Tensor = field(init=False, repr=False)
    aligned_walls: torch.Tensor = field(init=False, repr=False)
    axis_aligned: bool = field(init=False, repr=False)
    exit_tangents: torch.Tensor = field(init=False, repr=False)
    exit_spans: torch.Tensor = field(init=False, repr=False)

    def __post_init__(self) -> None:
        # For an axis-aligned wall the closest point to p is p clamped to the wall's bounding box (exact).
        object.__setattr__(self, "box_low", self.walls.amin(1))  # (S, 2)
        object.__setattr__(self, "box_high", self.walls.amax(1))
        object.__setattr__(self, "aligned_walls", (self.walls[:, 1] - self.walls[:, 0] == 0).any(-1))  # (S,)
        object.__setattr__(self, "axis_aligned", bool(self.aligned_walls.all()))
        tangents = self.exits[:, 1] - self.exits[:, 0]
        object.__setattr__(self, "exit_tangents", tangents)
        object.__setattr__(self, "exit_spans", (tangents * tangents).sum(-1))
        depth = self.goal_depth
        goals = [  # in float64 from the float32 exits, then rounded once
            [(a[X] + b[X]) / 2.0 + depth * n[X], (a[Y] + b[Y]) / 2.0 + depth * n[Y]]
            for (a, b), n in zip(self.exits.double().tolist(), self.exit_normals.double().tolist(), strict=True)
        ]
        object.__setattr__(
            self, "exit_goals", torch.tensor(goals, dtype=torch.float32, device=self.device).reshape(-1, 2)
        )
        nodes, costs, corners = (None, None, None) if self.routes is None else _routes_for(self, goals)
        object.__setattr__(self, "route_nodes", nodes)
        object.__setattr__(self, "route_costs", costs)
        object.__setattr__(self, "route_corners", corners)

    @classmethod
    def build(
        cls,
        *,
        walls: Any,
        exits: Any,
        exit_normals: Any,
        spawns: Sequence[SpawnArea],
        bounds: tuple[float, float, float, float],
        clear_box: tuple[float, float, float, float] | None = None,
        goal_depth: float = 0.0,
        waypoint_radius: float = 2.0,
        name: str = "custom",
        routes: RouteTable | None = None,
        device: str | torch.device = "cpu",
    ) -> Geometry:
        """Build a geometry from plain coordinates (m): walls ``(S, 2, 2)``, exits ``(E, 2, 2)`` and their outward
        normals ``(E, 2)``; pads the walls to a multiple of :data:`WALL_PADDING` and moves everything to ``device``.
        The compiler of ``pedrl.scenarios`` (``Scenario.geometry``) is its caller.
        """
        walls = torch.as_tensor(walls, dtype=torch.float32).reshape(-1, 2, 2)
        exits = torch.as_tensor(exits, dtype=torch.float32).reshape(-1, 2, 2)
        normals = torch.as_tensor(exit_normals, dtype=torch.float32).reshape(-1, 2)
        num_walls = walls.shape[0]
        padding = -num_walls % WALL_PADDING
        walls = torch.cat((walls, torch.full((padding, 2, 2), FAR)))
        spawns = tuple(
            replace(
                spawn,
                edges=spawn.edges.to(device=device, dtype=torch.float32),
                waypoints=(
                    torch.zeros(0, 2) if spawn.waypoints is None else torch.as_tensor(spawn.waypoints).reshape(-1, 2)
                ).to(device=device, dtype=torch.float32),
            )
            for spawn in spawns
        )
        return cls(
            walls=walls.to(device),
            num_walls=num_walls,
            exits=exits.to(device),
            exit_normals=normals.to(device),
            spawns=spawns,
            bounds=tuple(float(v) for v in bounds),
            clear_box=tuple(float(v) for v in (bounds if clear_box is None else clear_box)),
            goal_depth=float(goal_depth),
            waypoint_radius=float(waypoint_radius),
            name=name,
            routes=None if routes is None else routes.to(device),
        )

    # ------------------------------------------------------------------ properties

    @property
    def num_exits(self) -> int:
        """Number of exits."""
        return self.exits.shape[0]

    @property
    def device(self) -> torch.device:
        """Device of the wall tensor."""
        return self.walls.device

    @property
    def diagonal(self) -> float:
        """Diagonal of the bounding box (m): no two points of the walkable area are further apart."""
        x_min, y_min, x_max, y_max = self.bounds
        return math.hypot(x_max - x_min, y_max - y_min)

    @property
    def boundary(self) -> torch.Tensor:
        """The closed boundary of the walkable area ``(num_walls + E, 2, 2)``: real walls and exits."""
        return torch.cat((self.walls[: self.num_walls], self.exits))

    # ------------------------------------------------------------------ walls

    def closest_wall_points(self, points: torch.Tensor) -> torch.Tensor:
        """Closest point of each wall to each point: ``(..., S, 2)`` (m) for points ``(..., 2)``.

        Axis-aligned walls (every wall of the rectilinear scenarios) clamp the point to the wall's box, which is
        exact; other walls project onto the segment (:func:`closest_points_on_segments`).
        """
        clamped = torch.clamp(points.unsqueeze(-2), self.box_low, self.box_high)
        if self.axis_aligned:
            return clamped
        return torch.where(self.aligned_walls.unsqueeze(-1), clamped, closest_points_on_segments(points, self.walls))

    def wall_offsets(self, points: torch.Tensor) -> torch.Tensor:
        """Closest point of each wall minus each point ``(..., S, 2)`` (m)."""
        return self.closest_wall_points(points) - points.unsqueeze(-2)

    def squared_wall_distances(self, points: torch.Tensor) -> torch.Tensor:
        """Squared distance from each point ``(..., 2)`` to each wall ``(..., S)`` (m^2)."""
        offsets = self.wall_offsets(points)
        return (offsets * offsets).sum(-1)

    def touches_walls(self, points: torch.Tensor, *, radius: float) -> torch.Tensor:
        """Whether a disc of ``radius`` centred at each point ``(..., 2)`` intersects a wall (``dist < radius``)."""
        return self.squared_wall_distances(points).amin(-1) < radius * radius

    def clear_of_walls(self, points: torch.Tensor, *, margin: float) -> torch.Tensor:
        """Whether a disc of radius ``margin`` at each point ``(..., 2)`` lies inside :attr:`clear_box`: it
        then touches no wall and is past no exit. Conservative: ``False`` says nothing."""
        x_min, y_min, x_max, y_max = self.clear_box
        half_x, half_y = 0.5 * (x_max - x_min), 0.5 * (y_max - y_min)
        mid_x, mid_y = x_min + half_x, y_min + half_y
        return ((points[..., X] - mid_x).abs_() <= half_x - margin) & (
            (points[..., Y] - mid_y).abs_() <= half_y - margin
        )

    # ------------------------------------------------------------------ exits

    def passes_exits(self, points: torch.Tensor, *, depth: float | torch.Tensor) -> torch.Tensor:
        """Whether each centre ``(..., 2)`` is past an exit: on its far side, by less than ``depth`` (m, a number
        or a tensor of shape ``(...)``), within its span. A centre moving less than ``depth`` per check can get
        past the line of an exit only through its span (walls stop the others), so a crossing is always caught;
        the depth keeps points of a non-convex area that lie far beyond an exit's line from counting."""
        if isinstance(depth, torch.Tensor):
            depth = depth.unsqueeze(-1)
        offset = points.unsqueeze(-2) - self.exits[:, 0]  # (..., E, 2)
        beyond = offset[..., X] * self.exit_normals[:, X] + offset[..., Y] * self.exit_normals[:, Y]
        along = offset[..., X] * self.exit_tangents[:, X] + offset[..., Y] * self.exit_tangents[:, Y]
        return ((beyond >= 0) & (beyond < depth) & (along >= 0) & (along <= self.exit_spans)).any(-1)

    def nearest_exits(self, points: torch.Tensor) -> torch.Tensor:
        """Index of the exit whose goal point is nearest to each point ``(..., 2)``: ``(...)`` int64."""
        offset = points.unsqueeze(-2) - self.exit_goals
        return (offset * offset).sum(-1).argmin(-1)

    def inside(self, points: torch.Tensor) -> torch.Tensor:
        """Whether each point ``(..., 2)`` lies inside the walkable area (even-odd against :attr:`boundary`)."""
        return inside_polygon(points, self.boundary)

    def wall_segments(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Wall starts ``(S, 2)``, directions ``(S, 2)`` and inverse squared lengths ``(S,)`` (0 for a point)."""
        starts = self.walls[:, 0]
        directions = self.walls[:, 1] - starts
        length_sq = directions[:, X] * directions[:, X] + directions[:, Y] * directions[:, Y]
        inverse = torch.where(length_sq > 0, 1.0 / length_sq.clamp_min(1e-30), 0.0)
        return starts.contiguous(), directions.contiguous(), inverse.contiguous()

    def kernel_walls(self) -> Walls:
        """The walls as the numba kernels read them (:class:`Walls`, on the CPU)."""
        starts, directions, inverse = self.wall_segments()
        parts = (starts, directions, inverse, self.aligned_walls, self.box_low, self.box_high)
        return Walls(*(t.contiguous().numpy() for t in parts))

    def kernel_exits(self) -> Exits:
        """The exits as the numba kernels read them (:class:`Exits`, on the CPU)."""
        parts = (self.exits[:, 0], self.exit_normals, self.exit_tangents, self.exit_spans, self.exit_goals)
        return Exits(*(t.contiguous().numpy() for t in parts))

    def to(self, device: str | torch.device) -> Geometry:
        """The same geometry with every tensor on ``device``."""
        spawns = tuple(
            replace(spawn, edges=spawn.edges.to(device), waypoints=spawn.waypoints.to(device)) for spawn in self.spawns
        )
        return replace(
            self,
            walls=self.walls.to(device),
            exits=self.exits.to(device),
            exit_normals=self.exit_normals.to(device),
            spawns=spawns,
            routes=None if self.routes is None else self.routes.to(device),
        )


def _routes_for(geometry: Geometry, goals: list) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """What the room reads of ``geometry.routes`` for its goal points ``goals`` (float64 lists): the nodes in float32,
    the route lengths to the goal points (the last leg added in float64, then rounded once) and the wall corners
    that a line of sight keeps clear of (the ends of the real walls, less the exits' own ends)."""
    routes, device = geometry.routes, geometry.device
    ends = routes.ends.to(torch.float64)
    last_leg = torch.linalg.vector_norm(
        torch.tensor(goals, dtype=torch.float64, device=device).reshape(-1, 2) - ends, dim=-1
    )
    corners = torch.unique(geometry.walls[: geometry.num_walls].reshape(-1, 2), dim=0)
    jambs = geometry.exits.reshape(-1, 2)
    on_exit = ((corners.unsqueeze(1) - jambs) ** 2).sum(-1).lt(1e-8).any(-1)
    return routes.nodes.to(torch.float32), (routes.lengths + last_leg).float(), corners[~on_exit]


def extent(geometry: Geometry) -> tuple[float, float]:
    """The ``(width, length)`` of ``geometry``'s bounds (m): its extent along x and y."""
    x_min, y_min, x_max, y_max = geometry.bounds
    return x_max - x_min, y_max - y_min


def spawn_counts(num_agents: int, weights: Sequence[float]) -> tuple[int, ...]:
    """Split ``num_agents`` among spawn groups in proportion to ``weights`` (largest remainder, ties to the first).

    Agents are numbered group by group: the first ``counts[0]`` belong to group 0, and so on.
    """
    total = float(sum(weights))
    exact = [num_agents * weight / total for weight in weights]
    counts = [math.floor(share) for share in exact]
    by_remainder = sorted(range(len(weights)), key=lambda index: (counts[index] - exact[index], index))
    for index in by_remainder[: num_agents - sum(counts)]:
        counts[index] += 1
    return tuple(counts)

"""The scenario model: a walkable polygon with exits and spawn areas (shapely objects), checked when it is made,
and turned into the tensors of :class:`pedrl.sim.Geometry` (:meth:`Scenario.geometry`), a room
(:meth:`Scenario.room`) or the plain view :mod:`pedrl.analysis` takes (:meth:`Scenario.analysis_geometry`)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Final

import numpy as np
import shapely
import torch
from shapely.geometry import LineString, Point, Polygon, box

from pedrl.scenarios.polygons import TOLERANCE, bounds_text, check_extent, check_polygon, coords_text
from pedrl.sim.env import MAX_DENSITY, RoomEnv
from pedrl.sim.geometry import Geometry, RouteTable, SpawnArea, spawn_counts
from pedrl.sim.params import RoomParams

if TYPE_CHECKING:
    from pedrl.analysis.trajectories import AreaGeometry

MAX_EXITS: Final = 1_000
"""Most exits of a scenario (``scenario.exits``)."""
MAX_SPAWNS: Final = 1_000
"""Most spawn areas of a scenario (``scenario.spawn``)."""
EXIT_OVERLAP: Final = 1e-3
"""Length (m) of boundary two exits may share: more, and they overlap (two names for one opening), which is refused."""


@dataclass(frozen=True)
class Spawn:
    """A spawn area: where a group starts, its share of the agents, its exit (-1: nearest) and its waypoints."""

    area: Polygon
    weight: float = 1.0
    exit: int = -1
    waypoints: tuple[tuple[float, float], ...] = ()


@dataclass(frozen=True)
class Scenario:
    """A walkable polygon with exits and spawn areas (shapely objects), plus named measurement lines.

    Attributes:
        name: The scenario's name.
        walkable: The walkable area.
        exits: The open exits, segments on the boundary of ``walkable``.
        spawns: The spawn areas.
        lines: Named measurement lines (e.g. ``"opening"`` across the bottleneck), for flows.
        waypoint_radius: Distance (m) at which a waypoint counts as reached.
        routes: The area's routes to its exits (:class:`~pedrl.sim.geometry.RouteTable`,
            :func:`~pedrl.scenarios.routes.with_routes`), where some start may not see an exit (else None).
    """

    name: str
    walkable: Polygon
    exits: tuple[LineString, ...]
    spawns: tuple[Spawn, ...]
    lines: Mapping[str, LineString] = field(default_factory=dict)
    waypoint_radius: float = 2.0
    routes: RouteTable | None = None

    def __post_init__(self) -> None:
        check_polygon(self.walkable, "the walkable area")
        check_extent(self.walkable, f"the walkable area {bounds_text(self.walkable)} of scenario {self.name!r}")
        if not self.exits:
            raise ValueError(f"scenario {self.name!r} has no open exit: at least one is needed")
        for what, items, most in (("exits", self.exits, MAX_EXITS), ("spawn areas", self.spawns, MAX_SPAWNS)):
            if len(items) > most:
                raise ValueError(f"scenario {self.name!r} has {len(items)} {what}: at most {most}")
        boundary = self.walkable.boundary.buffer(TOLERANCE)  # once: it is the slow part of each exit's check
        for index, exit_ in enumerate(self.exits):
            if exit_.length <= 0 or boundary.covers(exit_) is False:
                raise ValueError(
                    f"exit {index} {coords_text(exit_)} is invalid: it must be a segment on the boundary of the"
                    " walkable area"
                )
        overlap = overlapping_exits(self.exits)
        if overlap is not None:
            first, second, shared = overlap
            raise ValueError(
                f"exits {first} {coords_text(self.exits[first])} and {second} {coords_text(self.exits[second])} are"
                f" invalid: they overlap by {shared:.6g} m; an opening is one exit (merge them, or move one)"
            )
        if not self.spawns:
            raise ValueError(f"scenario {self.name!r} has no spawn area")
        grown = self.walkable.buffer(TOLERANCE)
        for index, spawn in enumerate(self.spawns):
            check_polygon(spawn.area, f"spawn area {index}")
            if not grown.covers(spawn.area):
                raise ValueError(
                    f"spawn area {index} {bounds_text(spawn.area)} is invalid: it must lie inside the walkable area"
                    f" {bounds_text(self.walkable)}"
                )
            if not -1 <= spawn.exit < len(self.exits):
                raise ValueError(
                    f"spawn area {index} exit={spawn.exit} is invalid: must be -1 (nearest) or in"
                    f" [0, {len(self.exits)})"
                )

    def check_capacity(self, num_agents: int, agent_radius: float) -> None:
        """One-line ``ValueError`` if ``num_agents`` bodies cannot be placed in the spawn areas.

        The bodies of a group may cover at most :data:`~pedrl.sim.env.MAX_DENSITY` of the part of its spawn area
        where a centre can lie (the area eroded by the radius, and clear of the walls).
        """
        counts = spawn_counts(num_agents, [spawn.weight for spawn in self.spawns])
        free_space = self.walkable.buffer(-agent_radius)
        for index, (spawn, count) in enumerate(zip(self.spawns, counts, strict=True)):
            free = spawn.area.buffer(-agent_radius).intersection(free_space).area
            body = count * math.pi * agent_radius**2
            if body > MAX_DENSITY * free:
                most = int(MAX_DENSITY * free / (math.pi * agent_radius**2))
                raise ValueError(
                    f"num_agents={num_agents} is invalid: {count} bodies of radius {agent_radius} m cannot be placed"
                    f" in spawn area {index} of scenario {self.name!r} ({spawn.area.area:.4g} m^2): at most {most} fit"
                    f" there ({MAX_DENSITY:.0%} of its free area)"
                )

    def room(
        self,
        params: RoomParams | None = None,
        *,
        num_replicas: int = 1,
        num_agents: int = 20,
        device: str | torch.device = "cpu",
        **settings: Any,
    ) -> RoomEnv:
        """A room in this scenario: ``RoomEnv(self.geometry(), params, ...)``, its settings ``params`` (None: the
        defaults) with the keyword ``settings`` over them (``scenario.room(num_agents=40, max_speed=1.34)``). The
        room checks every value against the area (its own estimate of the spawn areas' room included), then
        :meth:`check_capacity` checks the agents against the exact free areas.

        Raises:
            ValueError: one line naming the bad value, or a keyword that is no setting of the room.
        """
        params = RoomParams.from_settings(settings) if params is None else replace(params, **settings)
        room = RoomEnv(self.geometry(), params, num_replicas=num_replicas, num_agents=num_agents, device=device)
        self.check_capacity(room.num_agents, room.params.agent_radius)
        return room

    def geometry(self, *, goal_depth: float = 0.0, device: str | torch.device = "cpu") -> Geometry:
        """The simulation's :class:`~pedrl.sim.Geometry`: walls are the boundary minus the exits."""
        walls = _segments(walls_without_exits(self.walkable, self.exits))
        exits = [list(exit_.coords)[:2] for exit_ in self.exits]
        normals = [_outward_normal(self.walkable, exit_) for exit_ in self.exits]
        spawns = tuple(
            SpawnArea(
                box=tuple(spawn.area.bounds),
                edges=torch.tensor(_ring_segments(spawn.area), dtype=torch.float32).reshape(-1, 2, 2),
                area=spawn.area.area,
                perimeter=spawn.area.length,
                exit=spawn.exit,
                weight=spawn.weight,
                waypoints=torch.tensor(spawn.waypoints, dtype=torch.float32).reshape(-1, 2),
            )
            for spawn in self.spawns
        )
        return Geometry.build(
            walls=torch.tensor(walls, dtype=torch.float32).reshape(-1, 2, 2),
            exits=exits,
            exit_normals=normals,
            spawns=spawns,
            bounds=tuple(self.walkable.bounds),
            clear_box=_clear_box(self.walkable),
            goal_depth=goal_depth,
            waypoint_radius=self.waypoint_radius,
            name=self.name,
            routes=self.routes,
            device=device,
        )

    def analysis_geometry(self, geometry: Geometry | None = None) -> AreaGeometry:
        """The plain view of this scenario's area that :mod:`pedrl.analysis` takes: its polygon (:meth:`to_wkt`),
        with the walls, exits and exit normals of its simulation's ``geometry`` (by default :meth:`geometry`; the
        one a room holds is the same, on any device).

        :mod:`pedrl.analysis` (and matplotlib with it) is imported here, when a view is asked for, not with this module.
        """
        from pedrl.analysis.trajectories import AreaGeometry

        geometry = self.geometry() if geometry is None else geometry
        return AreaGeometry(
            wkt=self.to_wkt(),
            walls=geometry.walls[: geometry.num_walls].cpu().numpy(),
            exits=geometry.exits.cpu().numpy(),
            exit_normals=geometry.exit_normals.cpu().numpy(),
            name=self.name,
        )

    def to_wkt(self) -> str:
        """The walkable area as WKT (PedPy's ``WalkableArea`` reads it)."""
        return self.walkable.wkt


@dataclass(frozen=True, kw_only=True)
class PaperRoom(Scenario):
    """The paper's room (:func:`paper_room`): a :class:`Scenario` that also keeps its three sizes, so that its
    analysis view is the closed-form :class:`~pedrl.analysis.RoomGeometry`.

    Attributes:
        width: Extent along x (m).
        length: Extent along y (m).
        door_width: Width of the door, centred in the side ``y = length`` (m).
    """

    width: float
    length: float
    door_width: float

    def analysis_geometry(self, geometry: Geometry | None = None) -> AreaGeometry:
        """The room as :class:`~pedrl.analysis.RoomGeometry` (``geometry`` is not needed: three sizes describe it)."""
        from pedrl.analysis.trajectories import RoomGeometry

        return RoomGeometry(width=self.width, length=self.length, door_width=self.door_width)


def overlapping_exits(exits: Sequence[LineString]) -> tuple[int, int, float] | None:
    """The first pair of ``exits`` ``(i, j)``, ``i < j``, that share more than :data:`EXIT_OVERLAP` of their length
    (within :data:`TOLERANCE` of each other: the same segment, or two pieces of one wall that overlap), with that
    length (m); None if no two do. Exits that only touch, end to end or at a corner, share none. Candidate pairs come
    from a search tree, so a thousand exits cost no million tests."""
    if len(exits) < 2:
        return None
    shapes = np.array(exits, dtype=object)
    left, right = shapely.STRtree(shapes).query(shapes, predicate="dwithin", distance=TOLERANCE)
    keep = left < right
    left, right = left[keep], right[keep]
    shared = shapely.length(shapely.intersection(shapes[left], shapely.buffer(shapes[right], TOLERANCE)))
    hits = np.flatnonzero(shared > EXIT_OVERLAP)
    if not hits.size:
        return None
    first = min(hits, key=lambda hit: (left[hit], right[hit]))
    return int(left[first]), int(right[first]), float(min(shared[first], shapes[left[first]].length))


def _segments(lines: Any) -> list[list[list[float]]]:
    """Every straight segment of a (multi)line geometry: ``[[[x1, y1], [x2, y2]], ...]``."""
    segments = []
    for part in shapely.get_parts(shapely.line_merge(lines) if lines.geom_type == "MultiLineString" else lines):
        coords = list(part.coords)
        segments += [[list(a), list(b)] for a, b in zip(coords[:-1], coords[1:], strict=True) if a != b]
    return segments


def _ring_segments(polygon: Polygon) -> list[list[list[float]]]:
    """Segments of every ring of a polygon (exterior and holes)."""
    return _segments(shapely.MultiLineString([polygon.exterior, *polygon.interiors]))


def walls_without_exits(walkable: Polygon, exits: tuple[LineString, ...]) -> Any:
    """The boundary of ``walkable`` minus its ``exits``, at any angle. The boundary is first snapped to the exits'
    end points (each becomes a vertex of it), so that an exit is a piece of the boundary to the bit: an exit in a wall
    that is not axis-aligned lies on it only to rounding, and a plain difference left the whole wall standing."""
    ends = shapely.MultiPoint([point for exit_ in exits for point in exit_.coords])
    boundary = shapely.snap(walkable.boundary, ends, TOLERANCE)
    return boundary.difference(shapely.union_all(exits))


def _outward_normal(walkable: Polygon, exit_: LineString) -> list[float]:
    """Unit normal of ``exit_`` pointing out of ``walkable``."""
    (x1, y1), (x2, y2) = list(exit_.coords)[:2]
    length = math.hypot(x2 - x1, y2 - y1)
    normal = [(y2 - y1) / length, -(x2 - x1) / length]
    middle = ((x1 + x2) / 2, (y1 + y2) / 2)
    probe = Point(middle[0] - 1e-3 * normal[0], middle[1] - 1e-3 * normal[1])  # inside if the normal points out
    return normal if walkable.contains(probe) else [-normal[0], -normal[1]]


def _clear_box(walkable: Polygon) -> tuple[float, float, float, float]:
    """An axis-aligned box inside ``walkable``: the area itself if it is a rectangle, else the square inscribed in
    its largest inscribed circle."""
    if walkable.equals(box(*walkable.bounds)):
        return tuple(walkable.bounds)
    radius_line = shapely.maximum_inscribed_circle(walkable)
    (cx, cy), _ = list(radius_line.coords)
    half = radius_line.length / math.sqrt(2.0) * (1 - 1e-6)
    return (cx - half, cy - half, cx + half, cy + half)

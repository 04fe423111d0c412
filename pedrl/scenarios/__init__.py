"""Scenarios: walkable areas from polygons (shapely), with exits, spawn areas and routes, built into a sim geometry.

A scenario is a walkable polygon (an outer boundary with holes for obstacles, as in PedPy and JuPedSim), exit segments
on its boundary, and spawn areas (polygons inside it), each with a share of the agents, the exit they take (or each
agent's nearest) and an optional route of waypoints. :func:`build_scenario` makes one from a ``scenario`` config
(the ``scenario/`` Hydra group), :meth:`Scenario.geometry` turns it into the tensors of
:class:`pedrl.sim.Geometry`, and :meth:`Scenario.analysis_geometry` into the plain view of that geometry that
:mod:`pedrl.analysis` takes. shapely does every polygon operation: validity, boundaries, containment, erosion.

Built-in scenarios (:data:`SCENARIOS`):

=============  =====================================================================================================
``paper_room``  the paper's room: ``width x length`` (the ``env`` keys), a door of ``door_width`` centred in the far
                short side; agents start anywhere
``bottleneck``  a waiting area feeding a corridor through an opening of ``opening`` m (Seyfried / Liddle layout);
                agents start in the waiting area; the exit is the far end of the corridor
``corridor``    a straight corridor, two groups starting at opposite ends, each heading for the other end (lanes)
``corner``      RiMEA test 6: a 2 m wide corridor turning left; agents start in its first 6 m, and aim at the corner
                before the exit
``four_exits``  RiMEA test 9: a 30 m x 20 m room with four 1 m exits, two in each long side; ``closed_exits`` closes
                some (they become walls); each agent takes its nearest open exit
``custom``      ``geometry``: a WKT file of the walkable polygon, or its WKT text; ``exits``: ``[[x1, y1, x2, y2],
                ...]`` segments on its boundary; ``spawn``: ``[[x_min, y_min, x_max, y_max], ...]`` boxes (default:
                the whole area)
=============  =====================================================================================================

A checkpoint holds its room: :func:`inline_geometry` turns a ``geometry`` file into the WKT text of its polygon
when training starts, and a stored scenario is built with ``files=False``, so that loading a checkpoint opens no
file it names. WKT input is bounded (:func:`read_geometry`): a regular file of at most :data:`MAX_WKT_BYTES`, UTF-8
with or without a byte-order mark, at most :data:`MAX_VERTICES` vertices and :data:`MAX_WKT_NESTING` levels of
parentheses; Z (and M) coordinates are dropped with a warning. Every coordinate lies within
:data:`MAX_COORDINATE` of the origin, where float32 positions keep millimetres.
"""

from __future__ import annotations

import inspect
import math
import os
import re
import stat
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

import numpy as np
import shapely
import torch
from shapely.geometry import LineString, Point, Polygon, box

from pedrl.notices import warn
from pedrl.sim.checks import check_number, first_line, shown
from pedrl.sim.env import MAX_DENSITY, RoomEnv
from pedrl.sim.geometry import Geometry, SpawnArea, spawn_counts

if TYPE_CHECKING:
    from pedrl.analysis.trajectories import AreaGeometry

SCENARIOS: Final = ("paper_room", "bottleneck", "corridor", "corner", "four_exits", "custom")
"""Names accepted by ``scenario.name``."""
WAYPOINT_SETBACK: Final = 0.8
"""Distance (m) before and after the bottleneck's entrance of the waypoints that line agents up with it."""
TOLERANCE: Final = 1e-6
"""Distance (m) within which an exit counts as lying on the boundary, and a spawn area inside the walkable area."""
LIDDLE_WIDTHS: Final = (0.9, 1.0, 1.1, 1.2, 1.4, 1.6, 1.8, 2.0, 2.3, 2.5)
"""Bottleneck widths (m) of the Seyfried / Liddle experiments."""
LIDDLE_FLOWS: Final = (1.71, 2.02, 2.19, 2.53, 2.91, 3.11, 3.91, 3.91, 4.52, 5.55)
"""Measured flows (1/s) through the bottleneck at :data:`LIDDLE_WIDTHS` (Liddle et al.; about ``J = 2.22 w - 0.25``)."""
MAX_COORDINATE: Final = 10_000.0
"""Largest ``|x|`` and ``|y|`` (m) of a scenario: float32 positions are 1 mm apart at 10 km from the origin (and 0.5 m
apart at UTM-like 5,400 km), so a room beyond it is refused rather than simulated with drifting positions."""
MAX_WKT_BYTES: Final = 10_000_000
"""Largest WKT file (bytes), or WKT text (characters), of a custom polygon: 10 MB."""
MAX_VERTICES: Final = 10_000
"""Most vertices of a custom polygon (all rings together)."""
MAX_WKT_NESTING: Final = 8
"""Most levels of parentheses in WKT (a POLYGON has 2, a GEOMETRYCOLLECTION of MULTIPOLYGONs 4)."""
MAX_EXITS: Final = 1_000
"""Most exits of a scenario (``scenario.exits``)."""
MAX_SPAWNS: Final = 1_000
"""Most spawn areas of a scenario (``scenario.spawn``)."""
MISSING: Final = "???"
"""A mandatory config value left unset (OmegaConf's marker, kept as text by ``to_container``)."""
_WKT_TEXT: Final = re.compile(
    r"\s*(?:MULTIPOLYGON|POLYGON|GEOMETRYCOLLECTION|MULTILINESTRING|LINESTRING|LINEARRING|MULTIPOINT|POINT)"
    r"\s*(?:ZM|Z|M)?\s*(?:\(|EMPTY\b)",
    re.IGNORECASE,
)


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
    """

    name: str
    walkable: Polygon
    exits: tuple[LineString, ...]
    spawns: tuple[Spawn, ...]
    lines: Mapping[str, LineString] = field(default_factory=dict)
    waypoint_radius: float = 2.0

    def __post_init__(self) -> None:
        _check_polygon(self.walkable, "the walkable area")
        _check_extent(self.walkable, f"the walkable area {_bounds(self.walkable)} of scenario {self.name!r}")
        if not self.exits:
            raise ValueError(f"scenario {self.name!r} has no open exit: at least one is needed")
        for what, items, most in (("exits", self.exits, MAX_EXITS), ("spawn areas", self.spawns, MAX_SPAWNS)):
            if len(items) > most:
                raise ValueError(f"scenario {self.name!r} has {len(items)} {what}: at most {most}")
        boundary = self.walkable.boundary.buffer(TOLERANCE)  # once: it is the slow part of each exit's check
        for index, exit_ in enumerate(self.exits):
            if exit_.length <= 0 or boundary.covers(exit_) is False:
                raise ValueError(
                    f"exit {index} {_coords(exit_)} is invalid: it must be a segment on the boundary of the walkable"
                    " area"
                )
        if not self.spawns:
            raise ValueError(f"scenario {self.name!r} has no spawn area")
        grown = self.walkable.buffer(TOLERANCE)
        for index, spawn in enumerate(self.spawns):
            _check_polygon(spawn.area, f"spawn area {index}")
            if not grown.covers(spawn.area):
                raise ValueError(
                    f"spawn area {index} {_bounds(spawn.area)} is invalid: it must lie inside the walkable area"
                    f" {_bounds(self.walkable)}"
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

    def room(self, **room_kwargs: Any) -> RoomEnv:
        """``RoomEnv(**room_kwargs)`` in this scenario: the room validates every value (its own estimate of the
        spawn areas' room included), then :meth:`check_capacity` checks the agents against the exact free areas.

        Raises:
            ValueError: one line naming the bad value.
        """
        goal_depth = check_number("goal_depth", room_kwargs.get("goal_depth", 0.0), low=0.0, high=math.inf)
        room = RoomEnv(**room_kwargs, geometry=self.geometry(goal_depth=goal_depth))
        self.check_capacity(room.num_agents, room.agent_radius)
        return room

    def geometry(self, *, goal_depth: float = 0.0, device: str | torch.device = "cpu") -> Geometry:
        """The simulation's :class:`~pedrl.sim.Geometry`: walls are the boundary minus the exits."""
        walls = _segments(self.walkable.boundary.difference(shapely.union_all(self.exits)))
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


# ---------------------------------------------------------------------------------------------- built-in scenarios


def paper_room(*, width: float = 60.0, length: float = 100.0, door_width: float = 2.0) -> Scenario:
    """The paper's room: a door of ``door_width`` centred in the side ``y = length``; agents start anywhere.

    Its sizes are the ``env`` keys, and messages name them so (:func:`build_scenario` names ``scenario.width`` when
    the scenario config sets it)."""
    width = _length("env.width", width)
    length = _length("env.length", length)
    door_width = _length("env.door_width", door_width)
    if door_width > width:
        raise ValueError(
            f"env.door_width={door_width!r} is invalid: the door must fit in its wall, at most width={width!r} m"
            " (env.width)"
        )
    room = box(0.0, 0.0, width, length)
    door = LineString([(width / 2 + door_width / 2, length), (width / 2 - door_width / 2, length)])
    return PaperRoom("paper_room", room, (door,), (Spawn(room),), width=width, length=length, door_width=door_width)


def bottleneck(
    *,
    opening: float = 1.2,
    corridor_length: float = 4.0,
    room_width: float = 10.0,
    room_length: float = 10.0,
    spawn_length: float = 8.0,
) -> Scenario:
    """Waiting area ``[0, room_width] x [0, room_length]``, a corridor of ``opening`` x ``corridor_length`` centred on
    its far side; agents start in the first ``spawn_length`` m of the waiting area and leave at the corridor's end.
    The measurement line ``"opening"`` spans the corridor's entrance."""
    _positive(opening=opening, corridor_length=corridor_length, room_width=room_width, room_length=room_length)
    _positive(spawn_length=spawn_length)
    if opening > room_width:
        raise ValueError(f"scenario.opening={opening!r} is invalid: at most room_width={room_width!r} m")
    if room_length + corridor_length > MAX_COORDINATE:
        raise ValueError(
            f"scenario.corridor_length={corridor_length!r} is invalid: room_length + corridor_length must be at most"
            f" {MAX_COORDINATE:g} m (float32 positions drift farther from the origin)"
        )
    if room_length <= WAYPOINT_SETBACK:
        raise ValueError(
            f"scenario.room_length={room_length!r} is invalid: must be > {WAYPOINT_SETBACK} m (agents line up with"
            f" the opening {WAYPOINT_SETBACK} m in front of it, inside the waiting area)"
        )
    left, right = (room_width - opening) / 2, (room_width + opening) / 2
    end = room_length + corridor_length
    walkable = shapely.union(box(0.0, 0.0, room_width, room_length), box(left, room_length, right, end))
    walkable = shapely.normalize(shapely.simplify(walkable, 0.0))
    spawn = box(0.0, 0.0, room_width, min(spawn_length, room_length - WAYPOINT_SETBACK))
    lines = {"opening": LineString([(left, room_length), (right, room_length)])}
    # the route lines agents up with the opening before they aim at the exit: with bodies that stop on contact
    # (no sliding), a straight line from the side to the exit catches a door post and holds the agent there
    centre = room_width / 2
    route = (
        (centre, room_length - WAYPOINT_SETBACK),
        (centre, room_length + min(WAYPOINT_SETBACK, corridor_length / 2)),
    )
    exit_ = LineString([(right, end), (left, end)])
    return Scenario(
        "bottleneck", walkable, (exit_,), (Spawn(spawn, exit=0, waypoints=route),), lines, waypoint_radius=0.4
    )


def corridor(*, length: float = 40.0, width: float = 5.0, spawn_length: float = 12.0) -> Scenario:
    """A corridor ``[0, length] x [0, width]`` open at both ends; half the agents start in its first
    ``spawn_length`` m and leave at ``x = length``, the other half the other way. Line ``"middle"`` crosses it."""
    _positive(length=length, width=width, spawn_length=spawn_length)
    if 2 * spawn_length > length:
        raise ValueError(f"scenario.spawn_length={spawn_length!r} is invalid: at most length / 2 = {length / 2!r} m")
    walkable = box(0.0, 0.0, length, width)
    east = LineString([(length, 0.0), (length, width)])
    west = LineString([(0.0, width), (0.0, 0.0)])
    spawns = (
        Spawn(box(0.0, 0.0, spawn_length, width), exit=0),
        Spawn(box(length - spawn_length, 0.0, length, width), exit=1),
    )
    lines = {"middle": LineString([(length / 2, 0.0), (length / 2, width)])}
    return Scenario("corridor", walkable, (east, west), spawns, lines)


def corner(*, width: float = 2.0, leg: float = 12.0, spawn_length: float = 10.0) -> Scenario:
    """RiMEA test 6: a corridor of ``width`` along x for ``leg`` m, turning left into a leg along y of ``leg`` m; the
    agents start in its first ``spawn_length`` m, aim at the corner's centre, then at the exit at the end."""
    _positive(width=width, leg=leg, spawn_length=spawn_length)
    if leg <= width:
        raise ValueError(
            f"scenario.leg={leg!r} is invalid: must be > scenario.width={width!r} m (each leg of the corner is longer"
            " than the corridor is wide)"
        )
    walkable = shapely.normalize(shapely.union(box(0.0, 0.0, leg, width), box(leg - width, 0.0, leg, leg)))
    exit_ = LineString([(leg, leg), (leg - width, leg)])
    turn = (leg - width / 2, width / 2)
    spawn = Spawn(box(0.0, 0.0, min(spawn_length, leg - width), width), exit=0, waypoints=(turn,))
    return Scenario("corner", walkable, (exit_,), (spawn,), waypoint_radius=width / 2)


def four_exits(
    *,
    width: float = 30.0,
    length: float = 20.0,
    exit_width: float = 1.0,
    closed_exits: Sequence[int] = (),
    margin: float = 1.0,
    spawn_margin: float = 0.0,
) -> Scenario:
    """RiMEA test 9: a room ``width x length`` with four exits of ``exit_width``, two in each long side, ``margin`` m
    from the short sides (0: bottom left, 1: bottom right, 2: top left, 3: top right); ``closed_exits`` become walls.
    Agents start anywhere at least ``spawn_margin`` m from the walls (RiMEA 9: doors 4 m from the side walls,
    persons 2 m from every wall)."""
    _positive(width=width, length=length, exit_width=exit_width, margin=margin)
    room = box(0.0, 0.0, width, length)
    if 2 * (margin + exit_width) > width:
        raise ValueError(f"scenario.exit_width={exit_width!r} is invalid: two exits must fit in each long side")
    if not 0.0 <= spawn_margin < min(width, length) / 2:
        raise ValueError(
            f"scenario.spawn_margin={spawn_margin!r} is invalid: must be in [0, {min(width, length) / 2:g}) m"
        )
    exits = [
        LineString([(margin + exit_width, 0.0), (margin, 0.0)]),
        LineString([(width - margin, 0.0), (width - margin - exit_width, 0.0)]),
        LineString([(margin, length), (margin + exit_width, length)]),
        LineString([(width - margin - exit_width, length), (width - margin, length)]),
    ]
    closed = sorted({_index("closed_exits", value, 4) for value in closed_exits})
    if len(closed) == 4:
        raise ValueError("scenario.closed_exits=[0, 1, 2, 3] is invalid: at least one exit must stay open")
    open_exits = tuple(exit_ for index, exit_ in enumerate(exits) if index not in closed)
    spawn = box(spawn_margin, spawn_margin, width - spawn_margin, length - spawn_margin)
    return Scenario("four_exits", room, open_exits, (Spawn(spawn),))


def custom(
    *,
    geometry: str | Path | Polygon,
    exits: Sequence[Sequence[float]] | None = None,
    spawn: Sequence[Sequence[float]] | None = None,
) -> Scenario:
    """A user's walkable area: ``geometry`` a WKT file holding one polygon (holes allowed), or that WKT text (what a
    checkpoint stores), read under the bounds of :func:`read_geometry`; ``exits`` segments ``[x1, y1, x2, y2]`` on
    its boundary, ``spawn`` boxes ``[x_min, y_min, x_max, y_max]`` (default: the whole area, each agent taking its
    nearest exit). Every message names the key (``scenario.exits[1]``) and the value."""
    walkable = geometry if isinstance(geometry, Polygon) else read_geometry(geometry)
    exit_values = _entries("exits", exits, MAX_EXITS, required=True)
    lines = [
        LineString(_numbers(f"scenario.exits[{i}]", v, 4).reshape(2, 2).tolist()) for i, v in enumerate(exit_values)
    ]
    boundary = walkable.boundary.buffer(TOLERANCE)
    for index, line in enumerate(lines):
        if line.length <= 0 or not boundary.covers(line):
            raise ValueError(
                f"scenario.exits[{index}]={shown(exit_values[index])} is invalid: it must be a segment on the boundary"
                f" of the walkable area {_bounds(walkable)}"
            )
    spawn_values = _entries("spawn", spawn, MAX_SPAWNS, required=False)
    grown = walkable.buffer(TOLERANCE)
    areas = []
    for index, value in enumerate(spawn_values):
        area = box(*_numbers(f"scenario.spawn[{index}]", value, 4).tolist())
        if area.area <= 0 or not grown.covers(area):
            raise ValueError(
                f"scenario.spawn[{index}]={shown(value)} is invalid: spawn area {index} must lie inside the walkable"
                f" area {_bounds(walkable)}, with an area > 0"
            )
        areas.append(Spawn(area))
    return Scenario("custom", walkable, tuple(lines), tuple(areas) or (Spawn(walkable),))


BUILDERS: Final = {
    "paper_room": paper_room,
    "bottleneck": bottleneck,
    "corridor": corridor,
    "corner": corner,
    "four_exits": four_exits,
    "custom": custom,
}


def build_scenario(
    config: Mapping[str, Any] | None, *, room: Mapping[str, Any] | None = None, files: bool = True
) -> Scenario:
    """The scenario of a ``scenario`` config (``name`` and the builder's keys; ``None`` is the paper's room).

    ``room`` holds the ``env`` settings: the paper's room takes its ``width``, ``length`` and ``door_width`` there.
    A ``geometry`` (a WKT file or WKT text) makes any scenario ``custom``. ``files=False`` (a config stored in a
    checkpoint) refuses a ``geometry`` that names a file instead of holding the WKT text: nothing is opened.

    Raises:
        ValueError: one line naming the bad value and what is allowed.
    """
    settings = dict(config or {"name": "paper_room"})
    check_scenario_sizes(settings)
    name = settings.pop("name", "paper_room")
    if not isinstance(name, str) or name not in BUILDERS:
        raise ValueError(f"scenario.name={shown(name)} is invalid: must be one of {', '.join(SCENARIOS)}")
    if name != "custom" and settings.get("geometry") is not None:  # a user's polygon replaces the scenario's own
        name = "custom"
        settings = {key: settings.get(key) for key in ("geometry", "exits", "spawn")}
    elif name != "custom":
        for key in ("exits", "spawn"):
            if settings.get(key) is not None:
                raise ValueError(
                    f"scenario.{key} is set without scenario.geometry: it describes a custom polygon (a WKT file)"
                )
    if name == "custom":  # read here, where it is known whether a file may be opened
        settings["geometry"] = read_geometry(settings.get("geometry"), files=files)
    settings = {key: value for key, value in settings.items() if value is not None}
    if name == "paper_room":
        room = room or {}
        for key in ("width", "length", "door_width"):  # named where they were set: scenario.width, else env.width
            if key in settings or key in room:
                _length(f"{'scenario' if key in settings else 'env'}.{key}", settings.get(key, room.get(key)))
        settings = {key: room[key] for key in ("width", "length", "door_width") if key in room} | settings
    builder = BUILDERS[name]
    allowed = list(inspect.signature(builder).parameters)
    for key in settings:
        if key not in allowed:
            raise ValueError(
                f"scenario.{shown(key)[1:-1]} is not a setting of scenario {name!r}: allowed:"
                f" {', '.join(allowed) or 'none'}"
            )
    try:
        return builder(**settings)
    except (TypeError, shapely.errors.GEOSException) as err:
        raise ValueError(f"scenario {name!r} is invalid: {_reason(err)}") from None


def check_scenario_sizes(config: Any) -> None:
    """One-line ``ValueError`` for a ``scenario`` config too large to build: more than :data:`MAX_EXITS` exits or
    :data:`MAX_SPAWNS` spawn areas, or a ``geometry`` longer than :data:`MAX_WKT_BYTES`. It only counts, so it runs
    before anything else looks at a stored config; other values are checked when the scenario is built."""
    if not isinstance(config, Mapping):
        return
    geometry = config.get("geometry")
    if isinstance(geometry, str) and len(geometry) > MAX_WKT_BYTES:
        raise ValueError(
            f"scenario.geometry={shown(geometry)} is invalid: at most {MAX_WKT_BYTES} characters (a WKT file name,"
            " or WKT text)"
        )
    for key, most in (("exits", MAX_EXITS), ("spawn", MAX_SPAWNS)):
        value = config.get(key)
        if isinstance(value, list | tuple) and len(value) > most:
            raise ValueError(f"scenario.{key} holds {len(value)} entries: at most {most}")


def geometry_file(config: Any) -> str | None:
    """The file a ``scenario`` config names as its ``geometry`` (a value that is not WKT text), else None."""
    geometry = config.get("geometry") if isinstance(config, Mapping) else None
    if geometry is None or geometry == MISSING or is_wkt_text(geometry):
        return None
    return str(geometry) if isinstance(geometry, str | os.PathLike) else None


def is_wkt_text(value: Any) -> bool:
    """``value`` is WKT text (it starts with a geometry type such as ``POLYGON (``), not the name of a file."""
    return isinstance(value, str) and _WKT_TEXT.match(value.removeprefix("\ufeff")) is not None


def inline_geometry(config: Mapping[str, Any], *, files: bool = True) -> dict[str, Any]:
    """``config`` (a ``scenario`` config) with its ``geometry``, a WKT file or WKT text, replaced by the WKT text of
    its polygon (2D, every digit kept): what a checkpoint stores, so that it holds its room instead of naming a file
    that may change or vanish. The file is read once, here, under the bounds of :func:`read_geometry`.

    Raises:
        ValueError: one line naming ``scenario.geometry``, for a file or text that is not a bounded polygon.
    """
    config = dict(config)
    geometry = config.get("geometry")
    if geometry is not None and geometry != MISSING:
        polygon = read_geometry(geometry, files=files)
        config["geometry"] = shapely.to_wkt(polygon, rounding_precision=-1, output_dimension=2)
    return config


def read_geometry(value: Any, *, key: str = "scenario.geometry", files: bool = True) -> Polygon:
    """The polygon of a ``geometry`` value: WKT text (:func:`parse_wkt`), or a WKT file (:func:`read_wkt`) unless
    ``files`` is False (a stored config, which must hold the text).

    Raises:
        ValueError: one line naming ``key`` and the value (cut to a short line), and what is allowed.
    """
    if value is None or value == MISSING:
        raise ValueError(f"{key} is missing: give a WKT file holding the walkable POLYGON, or the WKT text itself")
    if is_wkt_text(value):
        if len(value) > MAX_WKT_BYTES:
            raise ValueError(f"{key}={shown(value)} is invalid: WKT text of at most {MAX_WKT_BYTES} characters")
        return parse_wkt(value, what=f"{key}={shown(value)}")
    if not isinstance(value, str | os.PathLike) or not str(value):
        raise ValueError(f"{key}={shown(value)} is invalid: must be a WKT file or WKT text holding one POLYGON")
    if not files:
        raise ValueError(
            f"{key}={shown(str(value))} is invalid: a stored scenario holds the WKT text of its polygon, not the"
            " name of a file"
        )
    return read_wkt(value, key=key)


def read_wkt(path: str | Path, *, key: str = "scenario.geometry") -> Polygon:
    """The polygon of a WKT file (one ``POLYGON``, or a collection holding exactly one), else a one-line error.

    The file must be a regular file (a FIFO, a device or a folder is refused before anything is read) of at most
    :data:`MAX_WKT_BYTES`, UTF-8 with or without a byte-order mark; its text is checked by :func:`parse_wkt`.

    Raises:
        ValueError: one line naming ``key``, the file (cut to a short line) and what is allowed.
    """
    what = f"{key}={shown(str(path))}"
    data = _read_bounded(path, what)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise ValueError(
            f"{what} is invalid: it is not UTF-8 text (byte 0x{data[err.start]:02x} at offset {err.start}): save it as"
            " UTF-8, with or without a byte-order mark"
        ) from None
    return parse_wkt(text, what=what)


def parse_wkt(text: str, *, what: str = "scenario.geometry") -> Polygon:
    """The polygon of WKT text (one ``POLYGON``, or a collection holding exactly one), checked before it is parsed.

    At most :data:`MAX_WKT_NESTING` levels of parentheses and :data:`MAX_VERTICES` vertices (counted from the text,
    so a huge polygon is refused at once); Z and M coordinates are dropped with a warning (the footprint is used);
    the polygon must be valid and lie within :data:`MAX_COORDINATE` of the origin.

    Args:
        text: the WKT, with or without a byte-order mark.
        what: names the value in messages: the key and the file or text (``scenario.geometry='room.wkt'``).

    Raises:
        ValueError: one line starting with ``what``.
    """
    text = text.removeprefix("\ufeff").strip()
    if "\0" in text:
        raise ValueError(f"{what} is invalid: it holds a NUL character: not WKT text")
    depth = _nesting(text)
    if depth > MAX_WKT_NESTING:
        raise ValueError(
            f"{what} is invalid: its parentheses nest {depth} deep, at most {MAX_WKT_NESTING} (one POLYGON, or a"
            " collection holding one)"
        )
    vertices = text.count(",") + 1  # WKT separates vertices (and parts) with commas: at least this many
    if vertices > MAX_VERTICES:
        raise ValueError(f"{what} is invalid: it holds {vertices} vertices, at most {MAX_VERTICES}")
    try:
        shape = shapely.from_wkt(text)
    except (shapely.errors.GEOSException, ValueError, TypeError) as err:
        raise ValueError(f"{what} is invalid: not WKT ({_reason(err)})") from None
    if shape is not None and (shapely.has_z(shape) or getattr(shapely, "has_m", lambda _: False)(shape)):
        warn(f"{what}: its Z coordinates are dropped: a room is 2D, its polygon's footprint is used")
        shape = shapely.force_2d(shape)
    polygons = [] if shape is None else [part for part in shapely.get_parts(shape) if isinstance(part, Polygon)]
    if len(polygons) != 1:
        raise ValueError(f"{what} is invalid: it must hold exactly one POLYGON, it holds {len(polygons)}")
    _check_polygon(polygons[0], what)
    _check_extent(polygons[0], what)
    return polygons[0]


# ---------------------------------------------------------------------------------------------- helpers


def _read_bounded(path: str | Path, what: str) -> bytes:
    """The bytes of a regular file of at most :data:`MAX_WKT_BYTES`; anything else is refused without reading it."""
    try:  # O_NONBLOCK: opening a FIFO returns at once, to be refused below, instead of waiting for a writer
        descriptor = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except (OSError, ValueError) as err:
        raise ValueError(
            f"{what} is invalid: cannot read it ({getattr(err, 'strerror', None) or _reason(err)})"
        ) from None
    try:
        info = os.fstat(descriptor)
        mode, size = info.st_mode, info.st_size
        if not stat.S_ISREG(mode):
            raise ValueError(f"{what} is invalid: it is {_file_kind(mode)}, not a regular file: give a WKT file")
        if size > MAX_WKT_BYTES:
            raise ValueError(f"{what} is invalid: it holds {size} bytes, at most {MAX_WKT_BYTES} (10 MB)")
        chunks, read = [], 0
        while read <= MAX_WKT_BYTES:
            chunk = os.read(descriptor, min(1 << 20, MAX_WKT_BYTES + 1 - read))
            if not chunk:
                break
            chunks.append(chunk)
            read += len(chunk)
    except OSError as err:
        raise ValueError(f"{what} is invalid: cannot read it ({err.strerror or _reason(err)})") from None
    finally:
        os.close(descriptor)
    if read > MAX_WKT_BYTES:  # it grew while it was read
        raise ValueError(f"{what} is invalid: it holds more than {MAX_WKT_BYTES} bytes (10 MB)")
    return b"".join(chunks)


def _file_kind(mode: int) -> str:
    kinds = (
        (stat.S_ISDIR, "a directory"),
        (stat.S_ISFIFO, "a FIFO (named pipe)"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
    )
    return next((kind for test, kind in kinds if test(mode)), "a special file")


def _nesting(text: str) -> int:
    """Deepest level of parentheses in ``text`` (vectorised: the text may hold 10 MB)."""
    codes = np.frombuffer(text.encode("utf-8", "replace"), dtype=np.uint8)
    steps = (codes == ord("(")).astype(np.int32) - (codes == ord(")")).astype(np.int32)
    return int(np.cumsum(steps).max(initial=0))


def _check_extent(polygon: Polygon, what: str) -> None:
    """Refuse a polygon with a coordinate beyond :data:`MAX_COORDINATE`, where float32 positions would drift."""
    coordinates = shapely.get_coordinates(polygon)
    if not bool(np.isfinite(coordinates).all()):
        raise ValueError(f"{what} is invalid: it holds a coordinate that is not a finite number")
    farthest = float(np.abs(coordinates).max(initial=0.0))
    if farthest > MAX_COORDINATE:
        spacing = float(np.spacing(np.float32(farthest)))
        finest = float(np.spacing(np.float32(MAX_COORDINATE))) * 1000
        raise ValueError(
            f"{what} is invalid: it reaches {farthest:.6g} m from the origin, where float32 positions are"
            f" {spacing:.2g} m apart; every |x| and |y| must be at most {MAX_COORDINATE:g} m ({finest:.1g} mm apart"
            " there): move it near (0, 0)"
        )


def _check_polygon(polygon: Polygon, what: str) -> None:
    if not isinstance(polygon, Polygon) or polygon.is_empty:
        raise ValueError(
            f"{what} is invalid: must be a non-empty polygon, got {getattr(polygon, 'geom_type', polygon)}"
        )
    if not polygon.is_valid:
        reason = shapely.is_valid_reason(polygon)
        raise ValueError(f"{what} {_bounds(polygon)} is invalid: {reason} (a polygon must not intersect itself)")


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


def _positive(**values: Any) -> None:
    for name, value in values.items():
        _length(f"scenario.{name}", value)


def _length(key: str, value: Any) -> float:
    """A size of a built-in scenario: a finite number in ``(0, MAX_COORDINATE]`` m, named ``key`` in messages."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"{key}={shown(value)} is invalid: must be a finite number > 0 (m)")
    if value > MAX_COORDINATE:
        raise ValueError(
            f"{key}={value!r} is invalid: must be a finite number > 0 and at most {MAX_COORDINATE:g} m (float32"
            " positions drift farther from the origin)"
        )
    return float(value)


def _entries(key: str, value: Any, most: int, *, required: bool) -> list[Any]:
    """The list ``scenario.<key>`` (exits or spawn boxes): missing, not a list, or too long gives one line."""
    if value is None or value == MISSING or (isinstance(value, list | tuple) and not value):
        if required:
            raise ValueError(
                f"scenario.{key} is missing: give at least one exit segment [x1, y1, x2, y2] on the boundary"
            )
        return []
    if not isinstance(value, list | tuple):
        raise ValueError(f"scenario.{key}={shown(value)} is invalid: must be a list of [x1, y1, x2, y2] lists")
    if len(value) > most:
        raise ValueError(f"scenario.{key} holds {len(value)} entries: at most {most}")
    return list(value)


def _numbers(name: str, value: Any, count: int) -> torch.Tensor:
    numbers = None
    if isinstance(value, list | tuple) and len(value) == count:
        try:
            numbers = torch.tensor([float(v) for v in value], dtype=torch.float64)
        except (TypeError, ValueError, OverflowError):
            numbers = None
    if numbers is None or not bool(torch.isfinite(numbers).all()):
        raise ValueError(f"{name}={shown(value)} is invalid: must be {count} finite numbers (m)")
    return numbers


def _index(name: str, value: Any, size: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < size:
        raise ValueError(f"scenario.{name} holds {value!r}: must be exit indices in [0, {size})")
    return value


def _reason(err: BaseException) -> str:
    """First line of an error, cut short: a parser may quote the text it read."""
    line = first_line(err)
    return line if len(line) <= 120 else line[:120] + "..."


def _coords(line: LineString) -> str:
    return "[" + ", ".join(f"({x:g}, {y:g})" for x, y in line.coords) + "]"


def _bounds(polygon: Any) -> str:
    x_min, y_min, x_max, y_max = polygon.bounds
    return f"[{x_min:g}, {y_min:g}] x [{x_max:g}, {y_max:g}]"

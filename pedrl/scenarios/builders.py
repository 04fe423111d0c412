"""The built-in scenarios (:data:`SCENARIOS`), and :func:`build_scenario`, which makes one from a ``scenario``
config (the ``scenario/`` Hydra group) and names the config key of every bad value."""

from __future__ import annotations

import inspect
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Final

import shapely
import torch
from shapely.geometry import LineString, Polygon, box

from pedrl.common.checks import shown
from pedrl.scenarios.model import MAX_EXITS, MAX_SPAWNS, PaperRoom, Scenario, Spawn, overlapping_exits
from pedrl.scenarios.polygons import MAX_COORDINATE, MISSING, TOLERANCE, bounds_text, check_reach, short_reason
from pedrl.scenarios.routes import with_routes
from pedrl.scenarios.wkt import MAX_WKT_BYTES, read_geometry

SCENARIOS: Final = ("paper_room", "bottleneck", "corridor", "corner", "four_exits", "hall", "custom")
"""Names accepted by ``scenario.name``."""
WAYPOINT_SETBACK: Final = 0.8
"""Distance (m) before and after the bottleneck's entrance of the waypoints that line agents up with it."""
LIDDLE_WIDTHS: Final = (0.9, 1.0, 1.1, 1.2, 1.4, 1.6, 1.8, 2.0, 2.2, 2.5)
"""Bottleneck widths (m) of the Liddle et al. (2011) experiments (4 m long bottlenecks), as JuPedSim's bottleneck test
reads them from Liddle's data (``lid_w``: the data's width column over 100, hence 2.2 m, not 2.3 m)."""
LIDDLE_FLOWS: Final = (1.71, 2.02, 2.19, 2.53, 2.91, 3.11, 3.91, 3.91, 4.52, 5.55)
"""Measured flows (1/s) through the bottleneck at :data:`LIDDLE_WIDTHS` (Liddle et al. 2011, as JuPedSim's
bottleneck test reads them, ``lid_f``, rounded; about ``J = 2.22 w - 0.25``)."""


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


MAX_SHARE: Final = 1e6
"""Largest share of a corridor's ``ratio``: the shares only split the agents, and their sum must stay finite."""


def corridor(
    *, length: float = 40.0, width: float = 5.0, spawn_length: float = 12.0, ratio: Sequence[float] = (1.0, 1.0)
) -> Scenario:
    """A corridor ``[0, length] x [0, width]`` open at both ends; the agents start in its two ends of
    ``spawn_length`` m in the shares ``ratio`` (west end walking east : east end walking west; half and half by
    default) and leave at the other end. Line ``"middle"`` crosses it."""
    _positive(length=length, width=width, spawn_length=spawn_length)
    if (
        isinstance(ratio, str | bytes)
        or not isinstance(ratio, Sequence)
        or len(ratio) != 2
        or not all(isinstance(w, int | float) and not isinstance(w, bool) and math.isfinite(w) for w in ratio)
        or min(ratio) < 0
        or not 0 < max(ratio) <= MAX_SHARE
    ):
        raise ValueError(
            f"scenario.ratio={shown(ratio)} is invalid: must be two shares in [0, {MAX_SHARE:g}], at least one > 0"
            " (west end walking east, east end walking west)"
        )
    if 2 * spawn_length > length:
        raise ValueError(f"scenario.spawn_length={spawn_length!r} is invalid: at most length / 2 = {length / 2!r} m")
    walkable = box(0.0, 0.0, length, width)
    east = LineString([(length, 0.0), (length, width)])
    west = LineString([(0.0, width), (0.0, 0.0)])
    spawns = (
        Spawn(box(0.0, 0.0, spawn_length, width), weight=float(ratio[0]), exit=0),
        Spawn(box(length - spawn_length, 0.0, length, width), weight=float(ratio[1]), exit=1),
    )
    lines = {"middle": LineString([(length / 2, 0.0), (length / 2, width)])}
    return Scenario("corridor", walkable, (east, west), spawns, lines)


def straight_corridor(length: float = 40.0, width: float = 2.0) -> Scenario:
    """RiMEA test 1's corridor, ``length x width``, closed at ``x = 0``, its exit the far end (the validation suite's
    RiMEA 1 and the free-walking probe, :mod:`pedrl.trial.walking`)."""
    _positive(length=length, width=width)
    walkable = box(0.0, 0.0, length, width)
    exit_ = LineString([(length, 0.0), (length, width)])
    return Scenario("rimea_1", walkable, (exit_,), (Spawn(box(0.0, 0.0, min(2.0, length), width), exit=0),))


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


def hall(
    *,
    width: float = 200.0,
    length: float = 100.0,
    exit_width: float = 3.0,
    exits_per_side: int = 3,
    spawn_margin: float = 2.0,
) -> Scenario:
    """A large hall (a station concourse, an arena's floor): ``width x length`` with ``exits_per_side`` exits of
    ``exit_width`` evenly spaced along each of its four sides; agents start anywhere at least ``spawn_margin`` m from
    the walls and each takes its nearest exit. For crowds of thousands to hundreds of thousands."""
    _positive(width=width, length=length, exit_width=exit_width)
    if not isinstance(exits_per_side, int) or isinstance(exits_per_side, bool) or not 1 <= exits_per_side <= 100:
        raise ValueError(f"scenario.exits_per_side={exits_per_side!r} is invalid: must be an integer in [1, 100]")
    if exits_per_side * exit_width >= min(width, length) / 2:
        raise ValueError(
            f"scenario.exit_width={exit_width!r} is invalid: {exits_per_side} exits of it must take less than half"
            f" of the shorter side ({min(width, length):g} m)"
        )
    if not 0.0 <= spawn_margin < min(width, length) / 2:
        raise ValueError(
            f"scenario.spawn_margin={spawn_margin!r} is invalid: must be in [0, {min(width, length) / 2:g}) m"
        )
    exits = []
    for k in range(exits_per_side):  # counter-clockwise along each side, so that each is on the boundary
        share = (k + 0.5) / exits_per_side
        x, y, half = width * share, length * share, exit_width / 2
        exits += [
            LineString([(x - half, 0.0), (x + half, 0.0)]),
            LineString([(width, y - half), (width, y + half)]),
            LineString([(x + half, length), (x - half, length)]),
            LineString([(0.0, y + half), (0.0, y - half)]),
        ]
    spawn = box(spawn_margin, spawn_margin, width - spawn_margin, length - spawn_margin)
    return Scenario("hall", box(0.0, 0.0, width, length), tuple(exits), (Spawn(spawn),))


def custom(
    *,
    geometry: str | Path | Polygon,
    exits: Sequence[Sequence[float]] | None = None,
    spawn: Sequence[Sequence[float]] | None = None,
) -> Scenario:
    """A user's walkable area: ``geometry`` a WKT file holding one polygon (holes allowed), or that WKT text (what a
    checkpoint stores), read under the bounds of :func:`read_geometry`; ``exits`` segments ``[x1, y1, x2, y2]`` on
    its boundary, ``spawn`` boxes ``[x_min, y_min, x_max, y_max]`` (default: the whole area, each agent taking its
    exit by route length). A room that is not convex gets a route graph, and each walker its own route round the walls
    (:func:`~pedrl.scenarios.routes.with_routes`; the built-in scenarios are convex or carry their own waypoints).
    Every message names the key (``scenario.exits[1]``) and the value."""
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
                f" of the walkable area {bounds_text(walkable)}"
            )
    overlap = overlapping_exits(lines)
    if overlap is not None:
        first, second, shared = overlap
        raise ValueError(
            f"scenario.exits[{first}]={shown(exit_values[first])} and scenario.exits[{second}]="
            f"{shown(exit_values[second])} are invalid: they overlap by {shared:.6g} m; an opening is one exit (merge"
            " them, or move one)"
        )
    spawn_values = _entries("spawn", spawn, MAX_SPAWNS, required=False)
    grown = walkable.buffer(TOLERANCE)
    areas = []
    for index, value in enumerate(spawn_values):
        area = box(*_numbers(f"scenario.spawn[{index}]", value, 4).tolist())
        if area.area <= 0 or not grown.covers(area):
            raise ValueError(
                f"scenario.spawn[{index}]={shown(value)} is invalid: spawn area {index} must lie inside the walkable"
                f" area {bounds_text(walkable)}, with an area > 0"
            )
        areas.append(Spawn(area))
    return with_routes(Scenario("custom", walkable, tuple(lines), tuple(areas) or (Spawn(walkable),)))


BUILDERS: Final = {
    "paper_room": paper_room,
    "bottleneck": bottleneck,
    "corridor": corridor,
    "corner": corner,
    "four_exits": four_exits,
    "hall": hall,
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
    if config is not None and not isinstance(config, Mapping):
        raise ValueError(
            f"scenario={shown(config)} is invalid: must be a mapping with a name (scenario.name: one of"
            f" {', '.join(SCENARIOS)}) and that scenario's keys"
        )
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
        raise ValueError(f"scenario {name!r} is invalid: {short_reason(err)}") from None


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
    check_reach(float(numbers.abs().max()), f"{name}={shown(value)}")  # before float32 geometry makes it inf
    return numbers


def _index(name: str, value: Any, size: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < size:
        raise ValueError(f"scenario.{name} holds {value!r}: must be exit indices in [0, {size})")
    return value

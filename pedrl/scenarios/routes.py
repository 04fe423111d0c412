"""Routes through any walkable area: the shortest path from a spawn area to an exit round the walls, as waypoints.

A walker senses its goal point (its distance and bearing, paper Table 1); in a room whose exit is out of sight from
where it starts, that point lies behind a wall. :func:`with_routes` gives each spawn area that cannot see its exit
the corners of the shortest path to it, which the room then serves as the walker's goal point in turn
(:class:`~pedrl.sim.spawning.Spawns`: the route's next point, then the exit), on the torch path and the fast path
alike, and the validation suite hands the same waypoints to JuPedSim.

The path is the shortest one through a visibility graph (networkx, a dependency of torch) over the walkable area
shrunk by a clearance (:data:`CLEARANCES`): its nodes are the shrunk area's corners, the spawn area's centre and a
point the clearance inside the exit's middle; two nodes are joined when the segment between them lies in the shrunk
area. Its waypoints are the path's corners, the clearance off the walls they turn round.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Final

import networkx as nx
import shapely
from shapely.geometry import LineString, Point, Polygon
from shapely.ops import nearest_points

from pedrl.scenarios.model import Scenario

CLEARANCES: Final = (0.5, 0.25)
"""Distances (m) the route keeps from the walls, tried in turn: 0.5 m (a pedestrian's 0.2 m body and room to turn
without grazing the corner), else 0.25 m for a start area that can only get out through an opening narrower than
1 m (a body and a margin: openings under 0.5 m are closed to routes, as they are to a 0.2 m body)."""
CLEARANCE: Final = CLEARANCES[-1]
"""The least clearance: a start area that reaches no exit keeping it is refused."""
WAYPOINT_RADIUS: Final = 0.6
"""Distance (m) at which a walker on a route counts a corner as reached: a corner is where the walker must pass, so
the room's wider default (2 m) would let it aim past the corner and into the wall it turns round."""
SNAP: Final = 1e-7
"""Slack (m) of the test that a segment lies in the shrunk area (its corners lie on that area's boundary)."""


def with_routes(scenario: Scenario) -> Scenario:
    """``scenario`` with a route for each spawn area that has none and cannot see its exit: the corners of the
    shortest path from the area's centre to the exit. A spawn area heading for the nearest exit (``exit`` -1) that
    sees none takes the exit of the shortest route. Spawn areas that see their exit, or have hand-made waypoints, are
    kept as they are.

    Raises:
        ValueError: one line naming the spawn area (its index and bounds) from which no exit can be reached with
            :data:`CLEARANCE` from the walls.
    """
    spawns = []
    for index, spawn in enumerate(scenario.spawns):
        if spawn.waypoints:
            spawns.append(spawn)
            continue
        for clearance in CLEARANCES:
            free = scenario.walkable.buffer(-clearance, join_style="mitre")
            area = spawn.area
            start = _inside(free, area.representative_point() if area.area else area.centroid)
            exits = range(len(scenario.exits)) if spawn.exit < 0 else (spawn.exit,)
            goals = {e: _goal(scenario, e, clearance) for e in exits}
            reachable = {e: route for e in exits if (route := shortest_route(free, start, goals[e])) is not None}
            if reachable:
                break
        else:
            bounds = ", ".join(f"{value:g}" for value in spawn.area.bounds)
            raise ValueError(
                f"scenario spawn area {index} (bounds {bounds}) reaches no exit: no way to"
                f" {'any exit' if spawn.exit < 0 else f'exit {spawn.exit}'} keeps {CLEARANCE:g} m from the walls"
            )
        if any(not route for route in reachable.values()):  # an exit in sight: the room's own choice stands
            spawns.append(spawn)
            continue
        best = min(reachable, key=lambda e: _length(start, reachable[e], goals[e]))
        spawns.append(replace(spawn, exit=best, waypoints=tuple(reachable[best])))
    if tuple(spawns) == scenario.spawns:
        return scenario
    return replace(scenario, spawns=tuple(spawns), waypoint_radius=min(scenario.waypoint_radius, WAYPOINT_RADIUS))


def shortest_route(free: Polygon, start: Point, goal: Point) -> list[tuple[float, float]] | None:
    """The corners of the shortest path from ``start`` to ``goal`` within ``free`` (the walkable area shrunk by the
    clearance): ``[]`` when ``goal`` is in sight, None when no path exists."""
    area = free.buffer(SNAP)  # once: every sight test of the graph reads it
    shapely.prepare(area)
    if _sees(area, start, goal):
        return []
    corners = {
        (x, y)
        for ring in (free.geoms if hasattr(free, "geoms") else (free,))
        for boundary in (ring.exterior, *ring.interiors)
        for x, y in boundary.coords
    }
    nodes = [(start.x, start.y), (goal.x, goal.y), *sorted(corners)]
    graph = nx.Graph()
    graph.add_nodes_from(range(len(nodes)))
    for a in range(len(nodes)):
        for b in range(a + 1, len(nodes)):
            if _sees(area, Point(nodes[a]), Point(nodes[b])):
                graph.add_edge(a, b, weight=math.dist(nodes[a], nodes[b]))
    try:
        path = nx.shortest_path(graph, 0, 1, weight="weight")
    except nx.NetworkXNoPath:
        return None
    return [nodes[node] for node in path[1:-1]]


def _sees(area: Polygon, a: Point, b: Point) -> bool:
    """Whether the segment from ``a`` to ``b`` lies in ``area`` (the shrunk area grown by :data:`SNAP`)."""
    segment = LineString([a, b]) if not a.equals(b) else a
    return bool(shapely.covers(area, segment))


def _goal(scenario: Scenario, exit_index: int, clearance: float) -> Point:
    """A point ``clearance`` inside the middle of exit ``exit_index``."""
    exit_ = scenario.exits[exit_index]
    middle = exit_.interpolate(0.5, normalized=True)
    (x0, y0), (x1, y1) = exit_.coords[0], exit_.coords[-1]
    length = math.hypot(x1 - x0, y1 - y0)
    normal = (-(y1 - y0) / length, (x1 - x0) / length)
    for sign in (1.0, -1.0):  # the side of the exit the area lies on
        inward = Point(middle.x + sign * clearance * normal[0], middle.y + sign * clearance * normal[1])
        if scenario.walkable.contains(inward):
            return inward
    return middle


def _inside(free: Polygon, point: Point) -> Point:
    """``point``, or the nearest point of ``free`` when it lies within the clearance of a wall."""
    if free.covers(point) or free.is_empty:
        return point
    return nearest_points(free, point)[0]


def _length(start: Point, corners: list[tuple[float, float]], goal: Point) -> float:
    points = [(start.x, start.y), *corners, (goal.x, goal.y)]
    return sum(math.dist(a, b) for a, b in zip(points, points[1:], strict=False))


__all__ = ["CLEARANCE", "CLEARANCES", "shortest_route", "with_routes"]

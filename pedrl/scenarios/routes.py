"""Routes through any walkable area: each walker's shortest path to its exit round the walls, as waypoints.

A walker senses its goal point (its distance and bearing, paper Table 1); in a room whose exit is out of sight from
where it starts, that point lies behind a wall. :func:`with_routes` gives such a room (a walkable area that is not
convex) a route graph, and the room gives each walker, at placement, its own route: the corners of its shortest path
to its exit, which the room then serves as the walker's goal point in turn (:mod:`pedrl.sim.routing`,
:class:`~pedrl.sim.spawning.Spawns`), on the torch path and the fast path alike; the validation suite and
``pedrl-eval`` hand the same waypoints to JuPedSim. Route lengths also choose a walker's nearest exit.

The graph is a visibility graph (shapely for sight, networkx for Dijkstra, both dependencies already) over the
walkable area shrunk by a clearance (:data:`CLEARANCES`) and simplified within :data:`SIMPLIFY` (a wall of many short
segments shrinks to a line of as many corners): its nodes are that area's corners, at most :data:`MAX_ROUTE_NODES`,
and a point the clearance inside each exit's middle; two nodes are joined when the segment between them lies in the
shrunk area. A route's waypoints are corners, the clearance off the walls they turn round. JuPedSim's
``RoutingEngine`` (a navigation mesh) was not used: it is an optional extra here, and routes must exist without it.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Final

import networkx as nx
import numpy as np
import shapely
import torch
from shapely.geometry import LineString, Point, Polygon
from shapely.ops import nearest_points

from pedrl.scenarios.model import Scenario
from pedrl.sim.geometry import RouteTable

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
SIMPLIFY: Final = 0.05
"""Tolerance (m) of the simplification of the shrunk area, a quarter of a 0.2 m body's radius: a corner within it of
the line through the corners kept beside it is left out (Douglas-Peucker, keeping the area's topology), and the routes
are those round the simplified area, whose walls lie within it of the shrunk area's. A wall drawn with thousands of
short segments (a comb of 0.2 m teeth, a curve exported from a drawing) shrinks to a line holding as many corners;
an area with no corner that close to a straight line (every built-in and held-out room) is routed as it is."""
MAX_ROUTE_NODES: Final = 1_000
"""Most corners of a route graph: its sight tests grow as their square (a graph of 1,000 corners holds up to 500,000
lines of sight, and takes seconds to build); a room whose shrunk area keeps more is refused before any compute."""


def with_routes(scenario: Scenario) -> Scenario:
    """``scenario`` with its :class:`~pedrl.sim.geometry.RouteTable` where some start may not see an exit: the
    walkable area is not convex and some spawn area has no hand-made waypoints. The graph's nodes are the corners of
    the area shrunk by the first clearance of :data:`CLEARANCES` at which every such spawn area reaches an exit it may
    take; the room then gives each walker its own route at placement (:mod:`pedrl.sim.routing`).

    Raises:
        ValueError: one line naming the spawn area (its index and bounds) from which no exit can be reached with
            :data:`CLEARANCE` from the walls.
    """
    routed = [index for index, spawn in enumerate(scenario.spawns) if not spawn.waypoints]
    if not routed or _convex(scenario.walkable):
        return scenario
    for clearance in CLEARANCES:
        graph, free, area = route_graph(scenario, clearance)
        stuck = [index for index in routed if not _reaches(scenario, graph, free, area, index)]
        if not stuck:
            return replace(scenario, routes=graph, waypoint_radius=min(scenario.waypoint_radius, WAYPOINT_RADIUS))
    spawn = scenario.spawns[stuck[0]]
    bounds = ", ".join(f"{value:g}" for value in spawn.area.bounds)
    raise ValueError(
        f"scenario spawn area {stuck[0]} (bounds {bounds}) reaches no exit: no way to"
        f" {'any exit' if spawn.exit < 0 else f'exit {spawn.exit}'} keeps {CLEARANCE:g} m from the walls"
    )


def route_graph(scenario: Scenario, clearance: float) -> tuple[RouteTable, Polygon, Polygon]:
    """The visibility graph of ``scenario``'s walkable area shrunk by ``clearance`` (and simplified within
    :data:`SIMPLIFY`): its corners' shortest routes to each exit (networkx's Dijkstra from the point ``clearance``
    inside each exit's middle); with the shrunk area and that area grown by :data:`SNAP` and prepared, which every
    sight test reads.

    Raises:
        ValueError: one line naming the area's vertices and corners, where it keeps more than
            :data:`MAX_ROUTE_NODES` corners.
    """
    free = scenario.walkable.buffer(-clearance, join_style="mitre")
    simple = free.simplify(SIMPLIFY)  # Douglas-Peucker, topology kept: some of free's corners, none moved
    if shapely.get_num_coordinates(simple) < shapely.get_num_coordinates(free) and simple.is_valid:
        free = simple  # drawn with many short segments: routed round the simplified area
    area = free.buffer(SNAP)  # once: every sight test reads it
    shapely.prepare(area)
    corners = sorted(
        {
            (x, y)
            for ring in (free.geoms if hasattr(free, "geoms") else (free,))
            for boundary in (ring.exterior, *ring.interiors)
            for x, y in boundary.coords
        }
    )
    if len(corners) > MAX_ROUTE_NODES:
        vertices = shapely.get_num_coordinates(scenario.walkable) - 1 - len(scenario.walkable.interiors)
        raise ValueError(
            f"scenario {scenario.name!r} is too intricate to route: its walkable area of {vertices} vertices keeps"
            f" {len(corners)} corners {clearance:g} m in from the walls (simplified within {SIMPLIFY:g} m), at most"
            f" {MAX_ROUTE_NODES}: draw it with fewer, longer walls"
        )
    ends = [_goal(scenario, index, clearance) for index in range(len(scenario.exits))]
    nodes = [*corners, *((end.x, end.y) for end in ends)]
    graph = _visibility_graph(area, nodes)
    costs = [[math.inf] * len(ends) for _ in corners]
    next_node = [[-1] * len(ends) for _ in corners]
    for exit_index in range(len(ends)):
        end = len(corners) + exit_index
        lengths, paths = nx.single_source_dijkstra(graph, end, weight="weight")
        for node in range(len(corners)):
            if node in lengths:
                costs[node][exit_index] = lengths[node]
                following = paths[node][-2]
                next_node[node][exit_index] = following if following < len(corners) else -1
    table = RouteTable(
        nodes=torch.tensor(corners, dtype=torch.float64).reshape(-1, 2),
        lengths=torch.tensor(costs, dtype=torch.float64).reshape(-1, len(ends)),
        next_node=torch.tensor(next_node, dtype=torch.int64).reshape(-1, len(ends)),
        ends=torch.tensor(nodes[len(corners) :], dtype=torch.float64).reshape(-1, 2),
    )
    return table, free, area


def _visibility_graph(area: Polygon, nodes: list[tuple[float, float]]) -> nx.Graph:
    """``nodes`` joined where the segment between them lies in ``area`` (grown and prepared), weighted by its
    length: each node's lines to the later nodes tested at once (:func:`_sees_all`), edges added in order."""
    graph = nx.Graph()
    graph.add_nodes_from(range(len(nodes)))
    for a in range(len(nodes)):
        for b in (a + 1 + np.flatnonzero(_sees_all(area, nodes[a], nodes[a + 1 :]))).tolist():
            graph.add_edge(a, b, weight=math.dist(nodes[a], nodes[b]))
    return graph


def _reaches(scenario: Scenario, graph: RouteTable, free: Polygon, area: Polygon, index: int) -> bool:
    """Whether spawn area ``index`` (from a point inside it) sees an exit it may take, or a node with a route to one;
    ``free`` and ``area`` as :func:`route_graph` returns them."""
    spawn = scenario.spawns[index]
    start = _inside(free, spawn.area.representative_point() if spawn.area.area else spawn.area.centroid)
    exits = range(len(scenario.exits)) if spawn.exit < 0 else (spawn.exit,)
    ends, lengths = graph.ends.tolist(), graph.lengths.tolist()
    if any(_sees(area, start, Point(ends[e])) for e in exits):
        return True
    routed = [
        tuple(node) for m, node in enumerate(graph.nodes.tolist()) if any(math.isfinite(lengths[m][e]) for e in exits)
    ]
    return bool(_sees_all(area, (start.x, start.y), routed).any())


def _convex(walkable: Polygon) -> bool:
    """Whether every point of ``walkable`` sees every other one (a convex polygon without holes)."""
    return not walkable.interiors and walkable.convex_hull.area - walkable.area <= 1e-9 * max(walkable.area, 1.0)


def _sees(area: Polygon, a: Point, b: Point) -> bool:
    """Whether the segment from ``a`` to ``b`` lies in ``area`` (the shrunk area grown by :data:`SNAP`)."""
    segment = LineString([a, b]) if not a.equals(b) else a
    return bool(shapely.covers(area, segment))


def _sees_all(area: Polygon, a: tuple[float, float], others: list[tuple[float, float]]) -> np.ndarray:
    """:func:`_sees` from ``a`` to each of ``others``, at once: ``(len(others),)`` bool."""
    if not others:
        return np.zeros(0, dtype=bool)
    ends = np.asarray(others, dtype=float).reshape(-1, 2)
    start = np.broadcast_to(np.asarray(a, dtype=float), ends.shape)
    same = (ends == start).all(-1)  # a segment of no length is the point itself
    shapes = shapely.linestrings(np.stack((start, ends), axis=1))
    shapes[same] = shapely.points(ends[same])
    return shapely.covers(area, shapes)


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


__all__ = ["CLEARANCE", "CLEARANCES", "MAX_ROUTE_NODES", "SIMPLIFY", "WAYPOINT_RADIUS", "route_graph", "with_routes"]

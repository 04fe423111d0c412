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
``hall``        a large hall, 200 m x 100 m by default, with ``exits_per_side`` exits of ``exit_width`` evenly spaced
                along each side; each agent takes its nearest exit (crowds of thousands and more)
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

from pedrl.scenarios.builders import (
    BUILDERS,
    LIDDLE_FLOWS,
    LIDDLE_WIDTHS,
    SCENARIOS,
    WAYPOINT_SETBACK,
    bottleneck,
    build_scenario,
    check_scenario_sizes,
    corner,
    corridor,
    custom,
    four_exits,
    hall,
    paper_room,
)
from pedrl.scenarios.model import MAX_EXITS, MAX_SPAWNS, PaperRoom, Scenario, Spawn
from pedrl.scenarios.polygons import MAX_COORDINATE, MISSING, TOLERANCE
from pedrl.scenarios.wkt import (
    MAX_VERTICES,
    MAX_WKT_BYTES,
    MAX_WKT_NESTING,
    geometry_file,
    inline_geometry,
    is_wkt_text,
    parse_wkt,
    read_geometry,
    read_wkt,
)

__all__ = [
    "BUILDERS",
    "LIDDLE_FLOWS",
    "LIDDLE_WIDTHS",
    "MAX_COORDINATE",
    "MAX_EXITS",
    "MAX_SPAWNS",
    "MAX_VERTICES",
    "MAX_WKT_BYTES",
    "MAX_WKT_NESTING",
    "MISSING",
    "SCENARIOS",
    "TOLERANCE",
    "WAYPOINT_SETBACK",
    "PaperRoom",
    "Scenario",
    "Spawn",
    "bottleneck",
    "build_scenario",
    "check_scenario_sizes",
    "corner",
    "corridor",
    "custom",
    "four_exits",
    "hall",
    "geometry_file",
    "inline_geometry",
    "is_wkt_text",
    "paper_room",
    "parse_wkt",
    "read_geometry",
    "read_wkt",
]

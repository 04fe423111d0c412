"""Each walker's exit and its route there, chosen at placement (pure torch): the tactical and strategic levels.

A room whose walkable area hides an exit from some start carries a :class:`~pedrl.sim.geometry.RouteTable`: the nodes
of a visibility graph of the area (its corners, kept clear of the walls), each node's route length to each exit and
the next node on that route (built with the scenario, :func:`pedrl.scenarios.routes.with_routes`), which the compiled
area (:class:`~pedrl.sim.geometry.Geometry`) reads for its goal points. At placement:

- :func:`route_lengths`: a walker's route length to an exit is the straight line to the exit's goal point when it sees
  it, else the shortest ``|p - node| + cost[node, exit]`` over the nodes it sees (the first node is its first
  waypoint). Sight is a segment that crosses no wall and passes no wall corner closer than :data:`CORNER_CLEARANCE`
  (a walker that barely sees past a corner goes round the corner's node instead of grazing it); a walker that sees
  no node that way (it starts in a corner's shadow) takes the nodes it sees at all. Without a table, route lengths are
  the straight lines.
- :func:`choose_exits`: a walker without an assigned exit takes the one of least estimated time, its route length over
  the top speed plus, with ``queue_weight`` > 0, ``queue_weight`` times the wait behind the walkers ahead of it (with a
  shorter route) that head for the same exit, at :data:`SPECIFIC_FLOW` per metre of exit width. The walkers' choices
  depend on each other; they are settled by fictitious play (Brown 1951): :data:`CHOICE_ROUNDS` rounds in which every
  walker answers the mean of the others' earlier choices, which converges in congestion games such as this one
  (Monderer and Shapley 1996). The choice is made once, at placement, and not revised during the walk.
- :func:`follow_routes`: the walker's waypoints, its first node and then each next node, up to the exit.
"""

from __future__ import annotations

from typing import Any, Final

import torch

from pedrl.common.checks import check_number
from pedrl.sim.geometry import Geometry, X, Y

__all__ = [
    "CHOICE_ROUNDS",
    "CORNER_CLEARANCE",
    "MAX_QUEUE_WEIGHT",
    "SPECIFIC_FLOW",
    "check_queue_weight",
    "choose_exits",
    "follow_routes",
    "route_lengths",
    "sight",
]

CORNER_CLEARANCE: Final = 0.25
"""Distance (m) from a wall corner within which a line of sight counts as blocked: a 0.2 m body and a margin."""
SPECIFIC_FLOW: Final = 1.3
"""Persons per second and metre of exit width that a queue drains at (SFPE Handbook's 1.3 /(m s) for doors)."""
MAX_QUEUE_WEIGHT: Final = 100.0
"""Largest ``queue_weight``: beyond it the route lengths no longer count."""
CHOICE_ROUNDS: Final = 24
"""Rounds of fictitious play that settle the walkers' exit choices when the queue is weighed."""
SIGHT_CHUNK_BYTES: Final = 64 * 2**20
"""Most bytes the temporaries of one chunk of the sight tests take: a room of thousands of walls and corners tests its
lines of sight chunk by chunk, its memory bounded whatever its size (a 5,000-vertex wall once asked for 2 GB at
once)."""
SIGHT_BYTES: Final = 64
"""Bytes of temporaries per point, target and wall (or corner) of a sight test: a measured upper bound."""


def check_queue_weight(value: Any) -> float | None:
    """``value`` as a ``queue_weight`` (None: the room's own), or a one-line ``ValueError``/``TypeError``."""
    return None if value is None else check_number("queue_weight", value, low=0.0, high=MAX_QUEUE_WEIGHT)


def _cross(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return a[..., X] * b[..., Y] - a[..., Y] * b[..., X]


def sight(
    points: torch.Tensor, targets: torch.Tensor, walls: torch.Tensor, corners: torch.Tensor | None
) -> torch.Tensor:
    """Whether each point ``(R, N, 2)`` sees each target ``(T, 2)``: ``(R, N, T)`` bool, true when the segment
    between them crosses none of the ``walls`` ``(S, 2, 2)`` and, with ``corners`` ``(C, 2)``, passes none of them
    closer than :data:`CORNER_CLEARANCE` (corners that close to the point itself do not count)."""
    clear = ~_crossing(points, targets, walls)
    return clear if corners is None else clear & ~_grazing(points, targets, corners)


def _in_chunks(test, points: torch.Tensor, targets: torch.Tensor, items: torch.Tensor) -> torch.Tensor:
    """``test(points, targets, items)`` ``(R, N, T)`` bool, computed in chunks of point-target pairs whose
    temporaries, :data:`SIGHT_BYTES` per pair and item (wall or corner), stay under :data:`SIGHT_CHUNK_BYTES`: the
    memory of a room of many walls or corners is bounded, and every pair's answer is the one of the whole at once
    (each pair's test reads only its own point and target)."""
    shape = (*points.shape[:-1], targets.shape[0])
    pairs_per_chunk = max(1, SIGHT_CHUNK_BYTES // (SIGHT_BYTES * max(items.shape[0], 1)))
    flat = points.reshape(-1, 2)
    count, num_targets = flat.shape[0], targets.shape[0]
    if count * num_targets <= pairs_per_chunk:
        return test(points, targets, items)
    out = torch.empty(count, num_targets, dtype=torch.bool, device=points.device)
    point_step = max(1, pairs_per_chunk // max(num_targets, 1))
    target_step = min(num_targets, pairs_per_chunk)
    for start in range(0, count, point_step):
        chunk = flat[start : start + point_step].unsqueeze(0)  # (1, P, 2)
        for first in range(0, num_targets, target_step):
            out[start : start + point_step, first : first + target_step] = test(
                chunk, targets[first : first + target_step], items
            )[0]
    return out.reshape(shape)


def _crossing(points: torch.Tensor, targets: torch.Tensor, walls: torch.Tensor) -> torch.Tensor:
    """Whether the segment from each point ``(R, N, 2)`` to each target ``(T, 2)`` crosses a wall: ``(R, N, T)``,
    in bounded chunks (:func:`_in_chunks`)."""
    return _in_chunks(_crossing_all, points, targets, walls)


def _crossing_all(points: torch.Tensor, targets: torch.Tensor, walls: torch.Tensor) -> torch.Tensor:
    """:func:`_crossing` at once: ``(R, N, T, S)`` temporaries."""
    start = points[:, :, None, None, :]  # (R, N, 1, 1, 2)
    span = targets[None, None, :, None, :] - start  # (R, N, T, 1, 2)
    wall_start, wall_span = walls[:, 0], walls[:, 1] - walls[:, 0]  # (S, 2)
    offset = wall_start - start  # (R, N, 1, S, 2)
    denominator = _cross(span, wall_span)
    along = _cross(offset, wall_span) / denominator  # where on the segment it meets the wall's line
    across = _cross(offset, span) / denominator  # where on the wall
    return ((along >= 0) & (along <= 1) & (across >= 0) & (across <= 1)).any(-1)  # parallel: nan, no crossing


def _grazing(points: torch.Tensor, targets: torch.Tensor, corners: torch.Tensor) -> torch.Tensor:
    """Whether the segment from each point to each target passes a corner ``(C, 2)`` closer than
    :data:`CORNER_CLEARANCE`, bar the corners that close to the point itself: ``(R, N, T)``, in bounded chunks
    (:func:`_in_chunks`)."""
    return _in_chunks(_grazing_all, points, targets, corners)


def _grazing_all(points: torch.Tensor, targets: torch.Tensor, corners: torch.Tensor) -> torch.Tensor:
    """:func:`_grazing` at once: ``(R, N, T, C)`` temporaries."""
    start = points[:, :, None, None, :]
    span = targets[None, None, :, None, :] - start  # (R, N, T, 1, 2)
    to_corner = corners - start  # (R, N, 1, C, 2)
    t = ((to_corner * span).sum(-1) / (span * span).sum(-1).clamp_min(1e-12)).clamp(0.0, 1.0)
    gap = to_corner - t.unsqueeze(-1) * span
    near = (gap * gap).sum(-1) < CORNER_CLEARANCE**2
    own = (to_corner * to_corner).sum(-1) < CORNER_CLEARANCE**2
    return (near & ~own).any(-1)


def route_lengths(positions: torch.Tensor, geometry: Geometry) -> tuple[torch.Tensor, torch.Tensor]:
    """Each walker's route length to each exit ``(R, N, E)`` (m) and the first node of that route ``(R, N, E)``
    int64 (-1: straight to the exit's goal point), for walkers at ``positions`` ``(R, N, 2)`` in the compiled area
    ``geometry`` (its exits' goal points, real walls and routes). Without routes: the straight lines."""
    goals, walls = geometry.exit_goals, geometry.walls[: geometry.num_walls]
    straight = torch.linalg.vector_norm(goals - positions.unsqueeze(-2), dim=-1)  # (R, N, E)
    if geometry.routes is None:
        return straight, torch.full_like(straight, -1, dtype=torch.int64)
    nodes = geometry.route_nodes
    inf = torch.tensor(torch.inf, device=positions.device)
    via = torch.linalg.vector_norm(nodes - positions.unsqueeze(-2), dim=-1).unsqueeze(-1) + geometry.route_costs
    targets = torch.cat((goals, nodes))  # the exits' goal points, then the nodes
    open_ = ~_crossing(positions, targets, walls)  # (R, N, E + M)
    exits = goals.shape[0]

    def through(sees: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        best, node = torch.where(sees[..., exits:].unsqueeze(-1), via, inf).min(-2)  # (R, N, E)
        return torch.where(sees[..., :exits], straight, best), torch.where(sees[..., :exits], -1, node)

    lengths, first = through(open_ & ~_grazing(positions, targets, geometry.route_corners))  # clear of the corners
    plain_lengths, plain_first = through(open_)  # any sight at all
    keep = torch.isfinite(lengths).any(-1, keepdim=True)  # (R, N, 1): some exit reached clear of the corners
    lengths, first = torch.where(keep, lengths, plain_lengths), torch.where(keep, first, plain_first)
    unseen = ~torch.isfinite(lengths).any(-1, keepdim=True)  # no route at all (rounding at a wall): straight lines
    return torch.where(unseen, straight, lengths), torch.where(unseen, -1, first)


def choose_exits(
    lengths: torch.Tensor,
    assigned: torch.Tensor,
    widths: torch.Tensor,
    *,
    max_speed: float,
    queue_weight: float,
) -> torch.Tensor:
    """Each walker's exit ``(R, N)`` int64: its ``assigned`` one ``(R, N)`` where that is >= 0, else the one of
    least estimated time (module docstring) from the route ``lengths`` ``(R, N, E)`` (m) and the exits' ``widths``
    ``(E,)`` (m); ties to the lower exit index. Weighing the queue holds an ``(R, N, N, E)`` table of who is ahead
    of whom: 16 MB for RiMEA 9's 1000 walkers and 4 exits in one room."""
    times = lengths / max_speed
    fixed = assigned >= 0
    choice = torch.where(fixed, assigned, times.argmin(-1))
    if queue_weight <= 0 or lengths.shape[-1] == 1:
        return choice
    num_agents = lengths.shape[1]
    index = torch.arange(num_agents, device=lengths.device)
    # ahead[r, i, j, e]: walker j's route to e is shorter than walker i's (ties: the lower index is ahead)
    mine, theirs = lengths.unsqueeze(2), lengths.unsqueeze(1)  # (R, N, 1, E), (R, 1, N, E)
    earlier = (index[None, :] < index[:, None])[None, :, :, None]
    ahead = ((theirs < mine) | ((theirs == mine) & earlier)).to(lengths.dtype)
    wait = queue_weight / (SPECIFIC_FLOW * widths)  # s per walker ahead
    one_hot = torch.nn.functional.one_hot(choice, lengths.shape[-1]).to(lengths.dtype)
    mean = one_hot.clone()
    for rounds in range(1, CHOICE_ROUNDS + 1):  # fixed rounds, no host sync
        queue = torch.einsum("rije,rje->rie", ahead, mean)  # expected walkers ahead at each exit
        answer = torch.where(fixed, assigned, (times + queue * wait).argmin(-1))
        one_hot = torch.nn.functional.one_hot(answer, lengths.shape[-1]).to(lengths.dtype)
        mean = mean + (one_hot - mean) / (rounds + 1)
    return answer


def follow_routes(first: torch.Tensor, exits: torch.Tensor, geometry: Geometry) -> tuple[torch.Tensor, torch.Tensor]:
    """The waypoints ``(R, N, M, 2)`` (NaN past a route's end) and route length ``(R, N)`` int64 of walkers whose
    routes start at node ``first`` ``(R, N)`` (-1: none) towards ``exits`` ``(R, N)`` in the compiled area
    ``geometry`` (with routes): each node, then the next one on the way to the exit, until the exit."""
    nodes, next_node = geometry.route_nodes, geometry.routes.next_node
    num_nodes = nodes.shape[0]
    shape = first.shape
    waypoints = torch.full((*shape, num_nodes, 2), torch.nan, device=first.device)
    length = torch.zeros(shape, dtype=torch.int64, device=first.device)
    node = first
    for step in range(num_nodes):  # a shortest route visits each node at most once
        on = node >= 0
        safe = node.clamp_min(0)
        waypoints[:, :, step] = torch.where(on.unsqueeze(-1), nodes[safe], torch.nan)
        length += on.to(torch.int64)
        node = torch.where(on, next_node[safe, exits], -1)
    return waypoints, length

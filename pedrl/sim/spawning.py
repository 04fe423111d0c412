"""Who starts where and heads where: the spawn groups of a walkable area as per-agent tables (pure torch).

:class:`Spawns` numbers the agents group by group (``spawn_counts``), draws their start positions by rejection
sampling in their spawn areas (or checks hand-placed ones), gives each its exit and its route there at placement
(its group's hand-made waypoints, else its own shortest route, :mod:`pedrl.sim.routing`) and walks it along them.
:func:`check_density` refuses, before any compute, more bodies than a spawn area can hold.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, Final, NamedTuple

import numpy as np
import torch

from pedrl.sim.geometry import Geometry, X, Y, inside_polygon, wrap_angle
from pedrl.sim.pairs import close_pairs, overlaps_earlier
from pedrl.sim.room_checks import read_option
from pedrl.sim.routing import choose_exits, follow_routes, route_lengths

MAX_DENSITY: Final = 0.35
"""Largest share of the free room area (where centres may lie) that the bodies may cover at placement."""
PLACEMENT_TOLERANCE: Final = 1e-4
"""Slack (m) when checking hand-placed positions against walls and other bodies."""


class PlacementError(ValueError):
    """The agents could not be placed in the room without overlaps."""


def check_density(
    geometry: Geometry,
    counts: Sequence[int],
    num_agents: Any,
    *,
    agent_radius: float,
    room: tuple[float, float],
) -> None:
    """Raise a one-line ``ValueError`` if the ``counts[i]`` bodies of spawn group ``i`` would cover more than
    :data:`MAX_DENSITY` of the free area of its spawn area; ``num_agents`` (as the user wrote it) and the ``room``'s
    ``(width, length)`` (m) are for the message."""
    width, length = room
    for index, (spawn, count) in enumerate(zip(geometry.spawns, counts, strict=True)):
        free_area = spawn.free_area(agent_radius)
        body_area = count * math.pi * agent_radius**2
        if body_area > MAX_DENSITY * free_area:
            where = (
                f"a {width} m x {length} m room"
                if len(geometry.spawns) == 1 and spawn.box == geometry.bounds
                else f"spawn area {index} ({spawn.area:.4g} m^2, {count} of the agents)"
            )
            share = f"{body_area / free_area:.0%}" if free_area > 0 else "all"
            raise ValueError(
                f"num_agents={num_agents!r} is invalid: {count} bodies of radius {agent_radius} m cannot be"
                f" placed in {where} (they would cover {share} of the free area; at most {MAX_DENSITY:.0%})"
            )


class Routes(NamedTuple):
    """Who heads where, as the numba kernels read it (:meth:`Spawns.kernel_routes`)."""

    assigned: np.ndarray
    """``(R, N)`` int64: each agent's group's exit, -1 where chosen at placement."""
    waypoints: np.ndarray
    """``(R, N, K, 2)`` float32: each agent's route (m)."""
    route_length: np.ndarray
    """``(R, N)`` int64: the waypoints of each agent's route."""
    waypoint_radius: np.float32
    """Distance (m) at which a waypoint counts as reached."""


class Spawns:
    """The spawn groups of a room of ``R`` replicas as per-agent tables (agents numbered group by group).

    Attributes:
        geometry: The walkable area, on ``device``.
        group: The spawn group of each agent ``(N,)`` int64.
        low: The lowest centre of each agent's drawing box ``(N, 2)`` (m): its spawn box shrunk by the radius.
        span: The extent of each agent's drawing box ``(N, 2)`` (m).
        assigned_exit: The exit of each agent's group ``(N,)`` int64; -1: chosen at placement (:meth:`assign`).
        hand_made: Whether each agent's group has hand-made waypoints ``(N,)`` bool (else its route is its own).
        waypoints: Each agent's route in each replica ``(R, N, K, 2)`` (m), NaN past its end; set at placement.
        route_length: The number of waypoints of each agent's route ``(R, N)`` int64; set at placement.
        agent_radius, num_replicas, width, length, device: As given; num_agents: ``N = sum(counts)``.
    """

    def __init__(
        self,
        geometry: Geometry,
        counts: Sequence[int],
        *,
        agent_radius: float,
        num_replicas: int,
        room: tuple[float, float],
        device: torch.device,
    ) -> None:
        """Build the tables of ``geometry``'s spawn areas (on ``device``), ``counts[i]`` agents in area ``i``; the
        ``room``'s ``(width, length)`` (m) is for the message of a failed placement."""
        self.geometry = geometry
        self.agent_radius = agent_radius
        self.num_replicas = num_replicas
        self.num_agents = sum(counts)
        self.width, self.length = room
        self.device = device
        radius = agent_radius
        group = torch.repeat_interleave(torch.arange(len(counts), device=device), torch.tensor(counts, device=device))
        self.group = group  # (N,)
        low, span, exits = [], [], []
        for spawn in geometry.spawns:
            x_min, y_min, x_max, y_max = spawn.box
            low.append([x_min + radius, y_min + radius])
            span.append([x_max - x_min - 2.0 * radius, y_max - y_min - 2.0 * radius])
            exits.append(spawn.exit)
        self.low = torch.tensor(low, device=device)[group]  # (N, 2)
        self.span = torch.tensor(span, device=device)[group]
        self.assigned_exit = torch.tensor(exits, device=device)[group]  # (N,), -1: nearest
        # another exit than its group's can be passed: only with two exits or more and an assigned one
        self.checks_exits = geometry.exits.shape[0] > 1 and any(exit_ >= 0 for exit_ in exits)
        own = 0 if geometry.routes is None else geometry.routes.nodes.shape[0]  # a shortest route's longest
        most = max(own, *(spawn.waypoints.shape[0] for spawn in geometry.spawns))
        routes = torch.full((len(geometry.spawns), most, 2), math.nan, device=device)
        for index, spawn in enumerate(geometry.spawns):
            routes[index, : spawn.waypoints.shape[0]] = spawn.waypoints
        counts = torch.tensor([s.waypoints.shape[0] for s in geometry.spawns], device=device)
        self.hand_made = (counts > 0)[group]
        self.waypoints = routes[group].expand(num_replicas, -1, -1, -1).clone()  # (R, N, K, 2)
        self.route_length = counts[group].expand(num_replicas, -1).clone()  # (R, N)
        self.exit_widths = geometry.exit_spans.sqrt()

    @property
    def has_routes(self) -> bool:
        """Whether any agent may have waypoints."""
        return self.waypoints.shape[2] > 0

    # ------------------------------------------------------------------ start

    def kernel_routes(self) -> Routes:
        """The routes as the numba kernels read them (:class:`Routes`, on the CPU)."""
        return Routes(
            self.assigned_exit.expand(self.num_replicas, -1).contiguous().numpy(),
            self.waypoints.to(torch.float32).contiguous().numpy(),
            self.route_length.contiguous().numpy(),
            np.float32(self.geometry.waypoint_radius),
        )

    def start(
        self,
        options: Mapping[str, Any],
        replicas: torch.Tensor,
        generator: torch.Generator,
        *,
        max_speed: float,
        rounds: int,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Start positions ``(R, N, 2)``, headings ``(R, N)`` and speeds ``(R, N)`` for the reset replicas ``(R,)``.

        Each is read from ``options`` (see :meth:`RoomEnv.reset`) if given there, else drawn from ``generator``: the
        positions by :meth:`place` (at most ``rounds`` rounds), the headings uniform; the speeds default to 0.
        """
        shape = (self.num_replicas, self.num_agents)
        positions = read_option(options, "positions", (*shape, 2), device=self.device)
        if positions is None:
            positions = self.place(replicas, generator, rounds=rounds)
        else:
            self.check_positions(positions, replicas)
        headings = read_option(options, "headings", shape, device=self.device)
        if headings is None:
            uniform = torch.rand(shape, generator=generator, device=self.device)
            headings = math.pi - 2.0 * math.pi * uniform
        headings = wrap_angle(headings)
        speeds = read_option(options, "speeds", shape, device=self.device)
        if speeds is None:
            speeds = torch.zeros(shape, device=self.device)
        elif bool((((speeds < 0) | (speeds > max_speed)) & replicas.unsqueeze(-1)).any()):
            raise ValueError(f"options['speeds'] is invalid: every speed must be in [0, max_speed={max_speed}] m/s")
        return positions, headings, speeds

    def uniform_positions(self, shape: tuple[int, ...], generator: torch.Generator) -> torch.Tensor:
        """Centres uniform in each agent's spawn box shrunk by the body radius ``(*shape, 2)`` (m)."""
        uniform = torch.rand((*shape, 2), generator=generator, device=self.device)
        return self.low + uniform * self.span

    def misplaced(self, positions: torch.Tensor) -> torch.Tensor:
        """``(R, N)`` bool: the centre is outside its spawn area or its body touches a wall."""
        touches = self.geometry.touches_walls(positions, radius=self.agent_radius)
        outside = torch.zeros_like(touches)
        for index, spawn in enumerate(self.geometry.spawns):
            if not spawn.is_box:  # a box holds every centre drawn in it
                outside |= (self.group == index) & ~inside_polygon(positions, spawn.edges)
        return touches | outside

    def place(self, replicas: torch.Tensor, generator: torch.Generator, *, rounds: int) -> torch.Tensor:
        """Non-overlapping positions ``(R, N, 2)`` in the spawn areas for the chosen replicas ``(R,)``, by rejection.

        Each round redraws only the agents that overlap an earlier-indexed agent of their replica, lie outside
        their spawn area or touch a wall; after ``rounds`` rounds, a :class:`PlacementError`.
        """
        shape = (self.num_replicas, self.num_agents)
        positions = self.uniform_positions(shape, generator)
        for _ in range(rounds):
            overlapping = overlaps_earlier(positions, 2.0 * self.agent_radius)
            redraw = (overlapping | self.misplaced(positions)) & replicas.unsqueeze(-1)
            if not bool(redraw.any()):
                return positions
            positions = torch.where(redraw.unsqueeze(-1), self.uniform_positions(shape, generator), positions)
        raise PlacementError(
            f"could not place num_agents={self.num_agents} agents of radius {self.agent_radius} m in the"
            f" {self.width} m x {self.length} m room after {rounds} rounds of rejection"
            " sampling: use fewer agents or a larger room"
        )

    def check_positions(self, positions: torch.Tensor, replicas: torch.Tensor) -> None:
        """Raise ``ValueError`` if a hand-placed body of a reset replica is outside, on a wall or overlaps."""
        chosen = replicas.unsqueeze(-1)
        clearance = self.agent_radius - PLACEMENT_TOLERANCE
        wall_sq = self.geometry.squared_wall_distances(positions).amin(-1)
        inside = self.geometry.inside(positions)
        bad = chosen & ~(inside & (wall_sq >= clearance * clearance))
        if bool(bad.any()):
            replica, agent = (int(index) for index in bad.nonzero()[0])
            x, y = (float(value) for value in positions[replica, agent])
            raise ValueError(
                f"options['positions'] is invalid: agent {agent} of replica {replica} at ({x:.4g}, {y:.4g})"
                f" m is outside the room or closer than agent_radius={self.agent_radius} m to a wall"
            )
        replica, agent, other = close_pairs(positions, 2.0 * self.agent_radius - PLACEMENT_TOLERANCE)
        overlapping = replicas[replica]
        if bool(overlapping.any()):  # the first pair in (replica, agent, other) order
            key = (replica * self.num_agents + agent) * self.num_agents + other
            first = int(torch.where(overlapping, key, key.max() + 1).argmin())
            replica, agent, other = int(replica[first]), int(agent[first]), int(other[first])
            raise ValueError(
                f"options['positions'] is invalid: agents {other} and {agent} of replica {replica} overlap"
                f" (centres closer than 2 * agent_radius = {2.0 * self.agent_radius} m)"
            )

    # ------------------------------------------------------------------ exits and routes

    def assign(
        self, positions: torch.Tensor, chosen: torch.Tensor, *, max_speed: float, queue_weight: float
    ) -> torch.Tensor:
        """The exit ``(R, N)`` int64 of each agent placed at ``positions`` ``(R, N, 2)``: its group's, else the one
        of least route length (with ``queue_weight`` > 0, of least time with the queue weighed;
        :func:`~pedrl.sim.routing.choose_exits`); the agents of the ``chosen`` replicas ``(R, 1)`` bool also get
        their routes there (:attr:`waypoints`, :attr:`route_length`)."""
        geometry = self.geometry
        lengths, first = route_lengths(positions, geometry)
        assigned = self.assigned_exit.expand(positions.shape[:-1])
        exits = choose_exits(lengths, assigned, self.exit_widths, max_speed=max_speed, queue_weight=queue_weight)
        if geometry.routes is not None:
            own = ~self.hand_made & chosen  # (R, N)
            waypoints, length = follow_routes(first.gather(-1, exits.unsqueeze(-1)).squeeze(-1), exits, geometry)
            self.waypoints[..., : waypoints.shape[2], :] = torch.where(
                own[..., None, None], waypoints, self.waypoints[..., : waypoints.shape[2], :]
            )
            self.route_length = torch.where(own, length, self.route_length)
        return exits

    def own_exit(self, left: torch.Tensor, positions: torch.Tensor, exit_index: torch.Tensor) -> torch.Tensor:
        """Which of the agents that ``left`` the room ``(R, N)`` at ``positions`` ``(R, N, 2)`` left through their
        own exit ``exit_index``: an agent of a group with an assigned exit that leaves through another one (the
        corridor's walkers stepping back out of the end they started at) did not reach its goal. An agent without
        an assigned exit reaches its goal through any exit; the exit passed is the one nearest to where it left."""
        if not self.checks_exits:
            return left
        through = self.geometry.nearest_exits(positions)
        return left & ((self.assigned_exit < 0) | (through == exit_index))

    def route_point(self, stage: torch.Tensor, exit_index: torch.Tensor) -> torch.Tensor:
        """Waypoint ``stage`` of each agent's route ``(R, N, 2)``, or its exit's goal point past the route's end."""
        goals = self.geometry.exit_goals[exit_index]  # (R, N, 2)
        if self.waypoints.shape[2] == 0:
            return goals
        index = stage.clamp(max=self.waypoints.shape[2] - 1)[..., None, None].expand(-1, -1, 1, 2)
        waypoint = torch.gather(self.waypoints, 2, index).squeeze(2)
        return torch.where((stage < self.route_length).unsqueeze(-1), waypoint, goals)

    def advance(
        self, positions: torch.Tensor, stage: torch.Tensor, exit_index: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The new stage ``(R, N)`` and target ``(R, N, 2)`` of agents at ``positions`` that aimed at ``stage``:
        those that reached their waypoint aim at the next point of their route.

        A waypoint is reached within ``waypoint_radius`` of it, or past it: beyond the line through it across the
        direction to the next point, less than ``waypoint_radius`` to the side. (Agents move up to ``max_speed /
        decisions_per_second`` per decision, so they overshoot a small disc.)
        """
        radius = self.geometry.waypoint_radius
        for _ in range(self.waypoints.shape[2]):  # fixed rounds, no host sync
            current = self.route_point(stage, exit_index)
            direction = self.route_point(stage + 1, exit_index) - current
            direction = direction / torch.linalg.vector_norm(direction, dim=-1, keepdim=True).clamp_min(1e-9)
            offset = positions - current
            ahead = offset[..., X] * direction[..., X] + offset[..., Y] * direction[..., Y]
            side = offset[..., X] * direction[..., Y] - offset[..., Y] * direction[..., X]
            near = (offset * offset).sum(-1) < radius * radius
            arrived = (near | ((ahead >= 0) & (side.abs() < radius))) & (stage < self.route_length)
            stage = stage + arrived.to(torch.int64)
        return stage, self.route_point(stage, exit_index)

"""Measures of the validation suite, on trajectories only: Weidmann's curve, PedPy's Voronoi and N-t measures, the
lane order parameter and the physical invariants.

Everything here reads a :class:`~pedrl.analysis.Recording` (positions and in-room flags per frame), whichever model
produced it: a pedrl room driven by a controller, JuPedSim, or a crowd scripted by a test.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
import shapely
from shapely.geometry import LineString, Polygon

from pedrl.analysis import Recording

WEIDMANN: Final = {"v0": 1.34, "gamma": 1.913, "rho_max": 5.4}
"""Weidmann's speed-density relation, ``v = v0 (1 - exp(-gamma (1/rho - 1/rho_max)))`` (m/s, 1/m^2)."""
WEIDMANN_RADIUS: Final = math.sqrt(2.0 / (math.sqrt(3.0) * WEIDMANN["rho_max"])) / 2.0
"""Radius (m, 0.231) of the discs whose densest (hexagonal) packing is Weidmann's jam density 5.4 /m^2."""


# ---------------------------------------------------------------------------------------------- Weidmann


def weidmann_speed(density: Any, *, v0: float, gamma: float, rho_max: float) -> np.ndarray:
    """Weidmann's speed (m/s) at ``density`` (1/m^2), 0 at and above ``rho_max``."""
    density = np.asarray(density, dtype=np.float64)
    with np.errstate(divide="ignore"):
        speed = v0 * (1.0 - np.exp(-gamma * (1.0 / density - 1.0 / rho_max)))
    return np.clip(speed, 0.0, None)


def hex_packing(radius: float) -> float:
    """Densest packing (1/m^2) of discs of ``radius`` (m): ``2 / (sqrt(3) d^2)``."""
    return 2.0 / (math.sqrt(3.0) * (2.0 * radius) ** 2)


def density_scale(radius: float) -> float:
    """Factor from Weidmann's densities to a model's with bodies of ``radius`` (m): 1 up to
    :data:`WEIDMANN_RADIUS`, else ``hex_packing(radius) / 5.4``, so that the model's jam density is its densest
    packing. Dividing a measured density by it is the shape-preserving rescale: ``v_model(rho) = v_W(rho / s)``."""
    return min(1.0, hex_packing(radius) / WEIDMANN["rho_max"])


# ---------------------------------------------------------------------------------------------- PedPy


def pedpy_trajectory(recording: Recording, replica: int) -> Any:
    """One replica's in-room agent-frames as a PedPy ``TrajectoryData`` (id, frame, x, y)."""
    import pandas as pd
    import pedpy

    frames, agents = np.nonzero(recording.in_room[replica])
    xy = recording.positions[replica, frames, agents].astype(np.float64)
    data = pd.DataFrame({"id": agents, "frame": frames, "x": xy[:, 0], "y": xy[:, 1]})
    return pedpy.TrajectoryData(data=data, frame_rate=recording.frame_rate)


def crossing_times(recording: Recording, line: LineString) -> list[np.ndarray]:
    """Per replica, the sorted times (s) at which agents cross ``line`` (PedPy's N-t)."""
    import pedpy

    measurement_line = pedpy.MeasurementLine(line)
    times = []
    for replica in range(recording.in_room.shape[0]):
        traj = pedpy_trajectory(recording, replica)
        _, crossing_frames = pedpy.compute_n_t(traj_data=traj, measurement_line=measurement_line)
        times.append(np.sort(crossing_frames["frame"].to_numpy()) / recording.frame_rate)
    return times


def steady_flow(times: np.ndarray, *, trim: float = 0.1) -> float:
    """Flow (1/s) of one run's sorted crossing ``times`` (s): the crossings between the first and last ``trim`` share
    of them, over the time they took (the steady part of N-t). NaN when fewer than two crossings remain or they share
    one instant."""
    count = len(times)
    first, last = int(math.floor(trim * count)), int(math.ceil((1.0 - trim) * count)) - 1
    if last - first < 1 or times[last] <= times[first]:
        return math.nan
    return (last - first) / float(times[last] - times[first])


def voronoi_samples(
    recording: Recording, walkable: Polygon, area: Polygon, *, start: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame Voronoi density (1/m^2) and Voronoi speed (m/s) in the measurement ``area`` from time ``start``
    (s) on, from PedPy, pooled over replicas (frames with nobody in the area are left out)."""
    import pedpy

    walkable_area = pedpy.WalkableArea(walkable)
    measurement_area = pedpy.MeasurementArea(area)
    densities, speeds = [], []
    for replica in range(recording.in_room.shape[0]):
        traj = pedpy_trajectory(recording, replica)
        polygons = pedpy.compute_individual_voronoi_polygons(traj_data=traj, walkable_area=walkable_area)
        density, intersection = pedpy.compute_voronoi_density(
            individual_voronoi_data=polygons, measurement_area=measurement_area
        )
        speed = pedpy.compute_individual_speed(
            traj_data=traj, frame_step=1, speed_calculation=pedpy.SpeedCalculation.BORDER_SINGLE_SIDED
        )
        voronoi_speed = pedpy.compute_voronoi_speed(
            traj_data=traj,
            individual_speed=speed,
            individual_voronoi_intersection=intersection,
            measurement_area=measurement_area,
        )
        merged = density.merge(voronoi_speed, on="frame")
        merged = merged[(merged["density"] > 0) & (merged["frame"] >= start * recording.frame_rate)]
        densities.append(merged["density"].to_numpy())
        speeds.append(merged["speed"].to_numpy())
    return np.concatenate(densities), np.concatenate(speeds)


# ---------------------------------------------------------------------------------------------- lanes


def lane_order_values(
    positions: np.ndarray,
    active: np.ndarray,
    direction: np.ndarray,
    *,
    lane_width: float,
    window: tuple[float, float],
    reach: float,
    min_agents: int,
) -> np.ndarray:
    """Rex and Löwen's lane order ``phi_j = ((L_j - O_j) / (L_j + O_j))^2`` of every agent-frame in a crowded window.

    ``L_j`` counts the agents walking the way of agent ``j`` in its lane, ``j`` itself included, and ``O_j`` those
    walking the other way: agents less than ``lane_width / 2`` to the side and less than ``reach`` along x. Random
    mixing gives about ``1 / (L + O)``, perfect lanes 1. A frame counts only when the window holds at least
    ``min_agents`` agents, some walking each way: a lone agent would score 1 whatever it does.

    Args:
        positions: ``(R, T, N, 2)`` centres (m).
        active: ``(R, T, N)`` in-room flags.
        direction: ``(N,)`` +1 / -1, the way each agent walks.
        lane_width: Width (m) of a lane, centred on the agent.
        window: ``(x_min, x_max)`` of the agents counted (m).
        reach: Longitudinal distance (m) within which agents count.
        min_agents: Fewest agents in the window for a frame to count.

    Returns:
        ``phi_j`` of every counted agent-frame.
    """
    values: list[np.ndarray] = []
    for frame in range(positions.shape[1]):
        for replica in range(positions.shape[0]):
            x = positions[replica, frame, :, 0]
            here = active[replica, frame] & (x >= window[0]) & (x <= window[1])
            sign = direction[here]
            if here.sum() < min_agents or (sign > 0).all() or (sign < 0).all():
                continue
            xy = positions[replica, frame, here]
            dx = np.abs(xy[:, None, 0] - xy[None, :, 0])
            dy = np.abs(xy[:, None, 1] - xy[None, :, 1])
            lane = (dy < lane_width / 2) & (dx < reach)  # the diagonal: the agent itself, in its own lane
            same = (lane & (sign[:, None] == sign[None, :])).sum(1)
            opposite = (lane & (sign[:, None] != sign[None, :])).sum(1)
            values.append(((same - opposite) / (same + opposite)) ** 2)
    return np.concatenate(values) if values else np.zeros(0)


# ---------------------------------------------------------------------------------------------- invariants


@dataclass
class InvariantTally:
    """Physical invariants over every recorded frame of a controller's runs: no overlap, nobody through a wall or
    outside the walkable area, no displacement above the model's speed limit."""

    frames: int = 0
    agent_frames: int = 0
    min_gap: float = math.inf  # centre distance minus body diameter (m), over pairs of in-room agents
    min_wall_clearance: float = math.inf  # centre-to-wall distance minus body radius (m)
    outside: int = 0  # agent-frames of in-room agents whose centre lies outside the walkable area
    max_step_ratio: float = 0.0  # largest displacement per frame over max_speed / frame_rate
    broken_in: set[str] = field(default_factory=set)  # labels of the runs that broke an invariant

    def add(self, recording: Recording, walkable: Polygon, exits: tuple[LineString, ...], *, label: str = "") -> None:
        """Record every frame of ``recording``, simulated in ``walkable`` with ``exits`` (``label``: which run)."""
        from scipy.spatial import cKDTree

        walls = walkable.boundary.difference(shapely.union_all(exits)) if exits else walkable.boundary
        grown = walkable.buffer(1e-4)
        positions, active, radius = recording.positions.astype(np.float64), recording.in_room, recording.radius
        run = InvariantTally(frames=positions.shape[0] * positions.shape[1], agent_frames=int(active.sum()))
        xy = positions[active]
        if xy.size:
            points = shapely.points(xy)
            run.min_wall_clearance = float(shapely.distance(walls, points).min()) - radius
            run.outside = int((~shapely.contains(grown, points)).sum())
        for frame in range(positions.shape[1]):
            for replica in range(positions.shape[0]):
                here = positions[replica, frame, active[replica, frame]]
                if len(here) >= 2:
                    nearest, _ = cKDTree(here).query(here, k=2)
                    run.min_gap = min(run.min_gap, float(nearest[:, 1].min()) - 2 * radius)
        both = active[:, :-1] & active[:, 1:]
        steps = np.linalg.norm(positions[:, 1:] - positions[:, :-1], axis=-1)[both]
        if steps.size:
            run.max_step_ratio = float(steps.max()) * recording.frame_rate / recording.max_speed
        self.frames += run.frames
        self.agent_frames += run.agent_frames
        self.min_gap = min(self.min_gap, run.min_gap)
        self.min_wall_clearance = min(self.min_wall_clearance, run.min_wall_clearance)
        self.outside += run.outside
        self.max_step_ratio = max(self.max_step_ratio, run.max_step_ratio)
        if not run.passed:
            self.broken_in.add(label)

    @property
    def passed(self) -> bool:
        """All invariants held over at least one recorded agent-frame (a slack of 1e-4 m covers float32 rounding)."""
        tolerance = 1e-4
        return (
            self.agent_frames > 0
            and self.min_gap >= -tolerance
            and self.min_wall_clearance >= -tolerance
            and self.outside == 0
            and self.max_step_ratio <= 1 + 1e-4
        )

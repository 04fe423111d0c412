"""Measures of the validation suite, on trajectories only: Weidmann's curve, PedPy's Voronoi and N-t measures,
Feliciani and Nishinari's lane order parameter and crossing times, and the physical invariants.

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


def lane_order_frames(
    positions: np.ndarray,
    active: np.ndarray,
    direction: np.ndarray,
    *,
    window: tuple[float, float],
    width: float,
    row: float,
    min_agents: int,
    shuffles: int = 0,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Feliciani and Nishinari's order parameter ``Phi`` of every counted frame, with its chance level.

    The measurement area ``window x [0, width]`` is cut along the walking direction into rows ``row`` wide. In a row
    ``j`` holding ``n_j^+`` agents walking to +x and ``n_j^-`` walking to -x, ``phi_j = ((n_j^+ - n_j^-) /
    (n_j^+ + n_j^-))^2``; a frame's ``Phi`` is the mean of ``phi_j`` over its occupied rows (1: every row holds one
    direction). A frame counts only when the area holds at least ``min_agents`` agents, some walking each way. The
    chance level of a frame is its ``Phi`` with the directions of the agents in the area shuffled (the mean over
    ``shuffles`` seeded permutations): rows that hold one agent score 1 whatever it does, so thin rows and a sparse
    area raise ``Phi`` with no lanes at all.

    Args:
        positions: ``(R, T, N, 2)`` centres (m).
        active: ``(R, T, N)`` in-room flags.
        direction: ``(N,)`` +1 / -1, the way each agent walks.
        window: ``(x_min, x_max)`` of the measurement area (m).
        width: Width (m) of the corridor, cut into rows from ``y = 0``.
        row: Width (m) of a row.
        min_agents: Fewest agents in the area for a frame to count.
        shuffles: Permutations of the directions per counted frame for its chance level (0: none, NaN).
        seed: Seed of the permutations.

    Returns:
        ``Phi``, the number of agents in the area and the chance level of every counted frame.
    """
    rows = max(1, math.ceil(width / row - 1e-9))
    rng = np.random.default_rng(seed)
    phis, counts, chances = [], [], []
    for replica in range(positions.shape[0]):
        for frame in range(positions.shape[1]):
            x, y = positions[replica, frame, :, 0], positions[replica, frame, :, 1]
            here = active[replica, frame] & (x >= window[0]) & (x <= window[1])
            sign = direction[here]
            if here.sum() < min_agents or (sign > 0).all() or (sign < 0).all():
                continue
            index = np.clip(np.floor(y[here] / row).astype(int), 0, rows - 1)
            shuffled = rng.permuted(np.tile(sign, (shuffles, 1)), axis=1)
            orders = _rows_order(index, np.vstack([sign, shuffled]), rows)
            phis.append(orders[0])
            counts.append(int(here.sum()))
            chances.append(float(orders[1:].mean()) if shuffles else math.nan)
    return np.array(phis), np.array(counts, dtype=np.int64), np.array(chances)


FACE_AHEAD: Final = 2.0
"""How far in front (m) an agent walking the other way counts as faced (:func:`face_to_face_share`): two strides."""


def face_to_face_share(
    positions: np.ndarray,
    active: np.ndarray,
    direction: np.ndarray,
    *,
    window: tuple[float, float],
    radius: float,
    ahead: float = FACE_AHEAD,
) -> float | None:
    """The share of the agent-frames in the measurement area ``window`` in which an agent walking the other way is
    less than ``ahead`` m in front (along the agent's own walking direction) and less than a body's width (two
    ``radius``) to its side, so that the two cannot pass without one of them stepping aside: the encounters that lanes
    avoid. On the walking layer it sets the time to cross: a walker facing one walks at about half its free speed, one
    in a lane behind another at 0.8-0.9 of it (docs/results.md). None where the area holds nobody.

    Args:
        positions: ``(R, T, N, 2)`` centres (m).
        active: ``(R, T, N)`` in-room flags.
        direction: ``(N,)`` +1 / -1, the way each agent walks along x.
        window: ``(x_min, x_max)`` of the measurement area (m).
        radius: The bodies' radius (m).
        ahead: How far in front (m) an oncoming walker counts.
    """
    facing = counted = 0
    sign = direction.astype(np.float64)
    opposite = sign[:, None] != sign[None, :]
    for replica in range(positions.shape[0]):
        for frame in range(positions.shape[1]):
            x, y = positions[replica, frame, :, 0], positions[replica, frame, :, 1]
            present = active[replica, frame]
            here = present & (x >= window[0]) & (x <= window[1])
            if not here.any():
                continue
            forward = (x[None, :] - x[:, None]) * sign[:, None]  # [i, j]: how far j is in front of i
            near = opposite & present[None, :] & (forward > 0) & (forward < ahead)
            near &= np.abs(y[None, :] - y[:, None]) < 2.0 * radius
            facing += int(near[here].any(axis=1).sum())
            counted += int(here.sum())
    return facing / counted if counted else None


def _rows_order(index: np.ndarray, signs: np.ndarray, rows: int) -> np.ndarray:
    """``Phi`` of one frame for each line of ``signs`` ``(K, n)``: the mean ``((n^+ - n^-) / (n^+ + n^-))^2`` over
    the rows ``index`` ``(n,)`` that hold an agent (the same rows for every line)."""
    total = np.bincount(index, minlength=rows)  # n^+ + n^- per row
    net = np.stack([np.bincount(index, weights=line, minlength=rows) for line in signs])  # n^+ - n^- per row
    occupied = total > 0
    return np.mean((net[:, occupied] / total[occupied]) ** 2, axis=1)


def crossing_durations(
    positions: np.ndarray, active: np.ndarray, direction: np.ndarray, *, window: tuple[float, float], frame_rate: float
) -> np.ndarray:
    """Times (s) agents took to walk through ``window`` (x, m) the way they walk: from crossing its near end to
    crossing its far end, each crossing interpolated linearly between the two frames around it. Agents that start
    past the near end, or do not cross the far end while in the room, are left out.

    Args:
        positions: ``(R, T, N, 2)`` centres (m).
        active: ``(R, T, N)`` in-room flags.
        direction: ``(N,)`` +1 / -1, the way each agent walks.
        window: ``(x_min, x_max)`` of the area (m).
        frame_rate: Frames per second.
    """
    progress = positions[..., 0] * direction  # grows as an agent walks its way
    times = []
    for replica, agent in np.ndindex(progress.shape[0], progress.shape[2]):
        walked = np.where(active[replica, :, agent], progress[replica, :, agent], np.nan)
        start, end = (window[0], window[1]) if direction[agent] > 0 else (-window[1], -window[0])
        entered, left = _first_crossing(walked, start), _first_crossing(walked, end)
        if walked[0] < start and entered is not None and left is not None and left > entered:
            times.append((left - entered) / frame_rate)
    return np.array(times)


def _first_crossing(walked: np.ndarray, level: float) -> float | None:
    """Fractional frame at which ``walked`` (NaN: out of the room) first reaches ``level``, or None."""
    reached = np.nonzero(walked >= level)[0]
    if not reached.size or reached[0] == 0:
        return None
    after = reached[0]
    before = walked[after - 1]
    return after - 1 + (level - before) / (walked[after] - before)


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
        return not self.broken()

    def broken(self) -> list[str]:
        """The invariants that did not hold, each with its measured number (empty: :attr:`passed`)."""
        tolerance = 1e-4
        criteria = [
            (self.agent_frames > 0, "no agent-frame recorded"),
            (self.min_gap >= -tolerance, f"bodies overlap by {-self.min_gap:.3g} m"),
            (self.min_wall_clearance >= -tolerance, f"a body reaches {-self.min_wall_clearance:.3g} m into a wall"),
            (self.outside == 0, f"{self.outside} agent-frames outside the area"),
            (self.max_step_ratio <= 1 + 1e-4, f"a step {self.max_step_ratio:.3g} times what the top speed allows"),
        ]
        return [text for held, text in criteria if not held]

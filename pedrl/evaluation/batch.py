"""What one batch of evaluated trials is: a :class:`BatchRecord`, recorded by the engine decision by decision or by a
:class:`Recorder` (another simulator) whole."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from pedrl.analysis import Trajectories
from pedrl.analysis.trajectories import Geometry
from pedrl.sim import RoomEnv


@runtime_checkable
class Recorder(Protocol):
    """Simulates whole trials itself in place of a controller that acts in the room decision by decision: another
    simulator on the room's initial scenes (:class:`pedrl.evaluation.jupedsim_reference.JuPedSimReference`)."""

    def check(self, env: RoomEnv) -> None:
        """One-line ``ValueError`` if it cannot simulate the trials of ``env`` (before any compute)."""
        ...

    def record(self, env: RoomEnv) -> BatchRecord:
        """Reset ``env`` (its generator draws the scenes) and record one trial from every replica's scene."""
        ...


@dataclass(frozen=True)
class BatchRecord:
    """One trial in each of R replicas, recorded frame by frame (numpy, on the host).

    Attributes:
        positions: ``(R, T, N, 2)`` agent centres (m), frame 0 the initial state, frame t after decision t.
        velocities: ``(R, T, N, 2)`` velocities (m/s).
        active: ``(R, T, N)`` bool, the agent is in frame t (it took decision t; every agent in frame 0).
        reached: ``(R, N)`` bool, the agent passed the door.
        exit_time: ``(R, N)`` time (s) at which it passed the door, NaN if it did not.
        crashes: ``(R, N)`` contacts with bodies: decisions in which another body cut its move (``crashed_agent``);
            NaN where the simulator has no such event (``controller=jupedsim``).
        wall_crashes: ``(R, N)`` decisions in which a wall cut its move (``crashed_wall``), counted apart; NaN as
            ``crashes``.
        speed_sum: ``(R,)`` sum over agents and decisions taken of the speed after the decision (m/s).
        speed_sq_sum: ``(R,)`` the same sum of squared speeds (m^2/s^2).
        speed_count: ``(R,)`` decisions taken (agent-decisions).
    """

    positions: np.ndarray
    velocities: np.ndarray
    active: np.ndarray
    reached: np.ndarray
    exit_time: np.ndarray
    crashes: np.ndarray
    wall_crashes: np.ndarray
    speed_sum: np.ndarray
    speed_sq_sum: np.ndarray
    speed_count: np.ndarray

    def trajectories(self, replica: int, geometry: Geometry, framerate: float) -> Trajectories:
        return Trajectories(
            positions=self.positions[replica],
            velocities=self.velocities[replica],
            active=self.active[replica],
            framerate=framerate,
            geometry=geometry,
        )

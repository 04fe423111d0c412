"""The one container of recorded runs, :class:`Recording`: what ``pedrl-eval`` records batch by batch, what the
validation suite's crowds (pedrl's and JuPedSim's) return, and what the fused trial's trace becomes.

A batch is ``(R, T, N, ...)``: runs, frames (frame 0 the start, ``frame_rate`` frames per second), agents. One run of
it, for the measures of this package, is a :class:`~pedrl.analysis.Trajectories` (:meth:`Recording.run`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pedrl.analysis.trajectories import Geometry, Trajectories

__all__ = ["Recording"]


@dataclass(frozen=True, kw_only=True)
class Recording:
    """R runs of N agents, frame by frame (numpy, on the host).

    Attributes:
        positions: ``(R, T, N, 2)`` agent centres (m), frame 0 the start. From the frame at which an agent left on, it
            holds where it left (past its exit).
        in_room: ``(R, T, N)`` bool: the agent is in the area at frame t (it has not left and its run has not ended).
        exit_time: ``(R, N)`` the time (s) at which the agent left through its own exit, NaN if it did not.
        frame_rate: Frames per second (1/s).
        velocities: ``(R, T, N, 2)`` velocities (m/s) of each frame, or None where the model gives none.
        radius: The body radius of the model that walked (m), where known.
        max_speed: The fastest speed that model allows (m/s), where known: a frame's displacement is at most
            ``max_speed / frame_rate``.
    """

    positions: np.ndarray
    in_room: np.ndarray
    exit_time: np.ndarray
    frame_rate: float
    velocities: np.ndarray | None = None
    radius: float | None = None
    max_speed: float | None = None

    @property
    def left(self) -> np.ndarray:
        """``(R, N)`` bool: the agent left through its own exit."""
        return np.isfinite(self.exit_time)

    @property
    def evacuated(self) -> float:
        """Share of agents that left."""
        return float(self.left.mean())

    def acted(self) -> np.ndarray:
        """``(R, T, N)`` bool: the agents of frame t, those in the area at frame t - 1 (frame 0: at the start); in a
        pedrl room, those that took decision t, including the one in which they left."""
        return np.concatenate((self.in_room[:, :1], self.in_room[:, :-1]), axis=1)

    def run(self, index: int, geometry: Geometry) -> Trajectories:
        """Run ``index`` as :class:`~pedrl.analysis.Trajectories` in ``geometry`` (its agents of each frame:
        :meth:`acted`)."""
        velocities = self.velocities if self.velocities is not None else np.zeros_like(self.positions)
        return Trajectories(
            positions=self.positions[index],
            velocities=velocities[index],
            active=self.acted()[index],
            framerate=self.frame_rate,
            geometry=geometry,
        )

"""The one type of recorded crowds, :class:`Recording`: what a trial records (the torch loop and the fused trial
alike), what ``pedrl-eval`` evaluates batch by batch, what the validation suite's crowds (pedrl's and JuPedSim's)
return, and what the trajectory files are written from.

It lives on the floor of the layering (numpy only) so that the trial, which records it, and the analysis, which
reads it, both import it without importing each other. A batch is ``(R, T, N, ...)``: runs, frames (frame 0 the
start, ``frame_rate`` frames per second), agents. One run of it, for the measures of :mod:`pedrl.analysis`, is a
:class:`~pedrl.analysis.Trajectories` (:meth:`pedrl.analysis.Trajectories.of_run`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Recording"]


@dataclass(frozen=True, kw_only=True)
class Recording:
    """R runs of N agents, frame by frame (numpy, on the host).

    Attributes:
        positions: ``(R, T, N, 2)`` agent centres (m), frame 0 the start. From the frame at which an agent left on, it
            holds where it left (past its exit); a run that ended early keeps its last frame.
        in_room: ``(R, T, N)`` bool: the agent is in the area at frame t (it has not left and its run has not ended).
        exit_time: ``(R, N)`` the time (s) at which the agent left through its own exit, NaN if it did not.
        frame_rate: Frames per second (1/s): a pedrl room's decisions per second, or fewer for a crowd too large to
            record every decision (:func:`pedrl.trial.fused.record_every`).
        velocities: ``(R, T, N, 2)`` velocities (m/s) of each frame, or None where the model gives none.
        radius: The body radius of the model that walked (m), where known.
        max_speed: The fastest speed that model allows (m/s), where known: a frame's displacement is at most
            ``max_speed / frame_rate``.
        crashes: ``(R, N)`` contacts with bodies: decisions in which another body cut its move (``crashed_agent``);
            NaN where the simulator has no such event (JuPedSim); None where not counted.
        wall_crashes: ``(R, N)`` decisions in which a wall cut its move (``crashed_wall``), counted apart; as
            ``crashes``.
        speed_sum: ``(R,)`` sum over agents and decisions taken of the speed after the decision (m/s), over the
            recorded frames where not every decision is; None where not counted.
        speed_sq_sum: ``(R,)`` the same sum of squared speeds (m^2/s^2).
        speed_count: ``(R,)`` decisions taken (agent-decisions).
    """

    positions: np.ndarray
    in_room: np.ndarray
    exit_time: np.ndarray
    frame_rate: float
    velocities: np.ndarray | None = None
    radius: float | None = None
    max_speed: float | None = None
    crashes: np.ndarray | None = None
    wall_crashes: np.ndarray | None = None
    speed_sum: np.ndarray | None = None
    speed_sq_sum: np.ndarray | None = None
    speed_count: np.ndarray | None = None

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

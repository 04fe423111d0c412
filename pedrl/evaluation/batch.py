"""What one batch of evaluated trials is: a :class:`BatchRecord`, recorded by the engine decision by decision or by a
:class:`Recorder` (another simulator) whole."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from pedrl.analysis import Recording
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


@dataclass(frozen=True, kw_only=True)
class BatchRecord(Recording):
    """One trial in each of R replicas (a :class:`~pedrl.analysis.Recording`: frame t after decision t), with the
    per-agent counts of the trial.

    Attributes:
        crashes: ``(R, N)`` contacts with bodies: decisions in which another body cut its move (``crashed_agent``);
            NaN where the simulator has no such event (``controller=jupedsim``).
        wall_crashes: ``(R, N)`` decisions in which a wall cut its move (``crashed_wall``), counted apart; NaN as
            ``crashes``.
        speed_sum: ``(R,)`` sum over agents and decisions taken of the speed after the decision (m/s).
        speed_sq_sum: ``(R,)`` the same sum of squared speeds (m^2/s^2).
        speed_count: ``(R,)`` decisions taken (agent-decisions).
    """

    crashes: np.ndarray
    wall_crashes: np.ndarray
    speed_sum: np.ndarray
    speed_sq_sum: np.ndarray
    speed_count: np.ndarray

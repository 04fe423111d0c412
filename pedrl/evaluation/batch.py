"""What records one batch of evaluated trials whole, in place of the engine's decision-by-decision trial: a
:class:`Recorder` (another simulator). Either way the batch is a :class:`~pedrl.common.recording.Recording`."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from pedrl.common.recording import Recording
from pedrl.sim import RoomEnv


@runtime_checkable
class Recorder(Protocol):
    """Simulates whole trials itself in place of a controller that acts in the room decision by decision: another
    simulator on the room's initial scenes (:class:`pedrl.evaluation.jupedsim_reference.JuPedSimReference`)."""

    def check(self, env: RoomEnv) -> None:
        """One-line ``ValueError`` if it cannot simulate the trials of ``env`` (before any compute)."""
        ...

    def record(self, env: RoomEnv) -> Recording:
        """Reset ``env`` (its generator draws the scenes) and record one trial from every replica's scene."""
        ...

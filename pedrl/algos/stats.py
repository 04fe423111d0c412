"""What a trial reports: :class:`TrialStats`, per learning process, from the torch loop and the fused trial alike."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import torch

TOTALS: Final = ("return", "crashes_agent", "crashes_wall", "reached", "speed_sum", "decisions")
"""Per-agent totals a trial accumulates, in the order of the rows of :func:`run_trial`'s accumulator."""


@dataclass
class TrialStats:
    """Per-process statistics of one trial, each ``(P,)``."""

    success_rate: torch.Tensor
    episodic_return: torch.Tensor
    crashes_agent: torch.Tensor
    crashes_wall: torch.Tensor
    mean_speed: torch.Tensor
    td_error: torch.Tensor
    decisions: int = 0
    agent_decisions: int = 0

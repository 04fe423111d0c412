"""Exploration schedules: the epsilon of epsilon-greedy as a function of the trial index.

The paper starts at `epsilon = 0.4` (Table 3, "initial rate for exploratory policy") but does not say how it decays.
pedrl decays it linearly to `end` over a fraction of each phase's trial budget (`LinearSchedule`, configured by
`epsilon_start`, `epsilon_end`, `epsilon_decay_fraction`) and holds it there; an exponential decay is available
too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

__all__ = ["ConstantSchedule", "ExponentialSchedule", "LinearSchedule", "Schedule"]


class Schedule(Protocol):
    """Anything that maps a trial index (0-based) to a value."""

    def __call__(self, trial: int) -> float: ...


@dataclass(frozen=True)
class ConstantSchedule:
    """The same `value` at every trial."""

    value: float

    def __call__(self, trial: int) -> float:
        """`value`."""
        return self.value


@dataclass(frozen=True)
class LinearSchedule:
    """Linear decay from `start` at trial 0 to `end` at trial `decay_trials`, then constant.

    `value(t) = start + (end - start) * min(t / decay_trials, 1)`; `decay_trials <= 0` gives `end` throughout.

    Attributes:
        start: value at trial 0 (the paper's epsilon: 0.4).
        end: value from trial `decay_trials` on.
        decay_trials: trials over which the value moves from `start` to `end`.
    """

    start: float
    end: float
    decay_trials: int

    def __call__(self, trial: int) -> float:
        """The value at 0-based `trial` (negative trials count as 0)."""
        if self.decay_trials <= 0:
            return self.end
        fraction = min(max(trial, 0) / self.decay_trials, 1.0)
        return self.start + (self.end - self.start) * fraction


@dataclass(frozen=True)
class ExponentialSchedule:
    """Exponential decay from `start` towards `end`, halving the gap every `half_life` trials.

    `value(t) = end + (start - end) * 0.5 ** (t / half_life)`.

    Attributes:
        start: value at trial 0.
        end: asymptote.
        half_life: trials for the gap to `end` to halve (> 0).
    """

    start: float
    end: float
    half_life: float

    def __post_init__(self) -> None:
        if not self.half_life > 0:
            raise ValueError(f"half_life must be positive, got {self.half_life}")

    def __call__(self, trial: int) -> float:
        """The value at 0-based `trial` (negative trials count as 0)."""
        return self.end + (self.start - self.end) * math.pow(0.5, max(trial, 0) / self.half_life)

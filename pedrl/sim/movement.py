"""What a decision's movement returns (:class:`Movement`), shared by the torch moves (:mod:`pedrl.sim.dynamics`) and
their numba kernels (:mod:`pedrl.sim.kernels`), which import it from here so that neither imports the other."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import torch

PAIR_MARGIN: Final = 1e-3
"""Slack (m) of the conservative pre-filters of :func:`move_agents`; it only widens them."""


@dataclass(frozen=True)
class Movement:
    """Outcome of one decision's movement.

    Attributes:
        positions: Positions after the decision ``(R, N, 2)`` (m).
        blocked: Agents stopped by a collision ``(R, N)`` bool; under ``stop`` their speed becomes 0.
        crashed_wall: Agents whose move a wall cut ``(R, N)`` bool: blocked by it (``stop``), or deflected or
            blocked by it (``slide``, ``headway``: :func:`move_agents_sliding`).
        crashed_agent: Agents whose move another body cut, and no wall ``(R, N)`` bool (as ``crashed_wall``).
        reached: Agents whose centre passed an exit ``(R, N)`` bool.
    """

    positions: torch.Tensor
    blocked: torch.Tensor
    crashed_wall: torch.Tensor
    crashed_agent: torch.Tensor
    reached: torch.Tensor

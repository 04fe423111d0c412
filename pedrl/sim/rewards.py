"""Immediate rewards per decision (paper Table 2)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import torch

MAX_REWARD: Final = 1e6
"""Largest ``|reward|`` (and ``reward_progress``, per m) accepted. Q values and returns are float32 sums of rewards
over up to ``max_decisions`` decisions (bounded by ``max|r| / (1 - gamma)`` and ``max|r| * max_decisions``); this
keeps them about 20 orders of magnitude below float32's 3.4e38 (``reward_goal=1e38`` learned inf and NaN tables)."""


@dataclass(frozen=True)
class RewardTable:
    """Reward values of one decision (paper Table 2 defaults).

    Attributes:
        goal: Reaching the door.
        crash_wall: A wall contact during the decision: a wall cut the agent's move (stopped it under the ``stop``
            contact model, deflected or stopped it under ``slide`` and ``headway``; see ``RoomEnv``'s ``contact``).
        crash_agent: A body contact (and no wall contact) during the decision: another body cut the agent's move.
        default: Anything else.
    """

    goal: float = 100.0
    crash_wall: float = -15.0
    crash_agent: float = -4.0
    default: float = 0.0


def compute_rewards(
    *,
    table: RewardTable,
    reached: torch.Tensor,
    crashed_wall: torch.Tensor,
    crashed_agent: torch.Tensor,
    acting: torch.Tensor,
) -> torch.Tensor:
    """Reward of each agent for one decision.

    ``goal`` if it reached the door, else ``crash_wall`` if it hit a wall, else ``crash_agent`` if it hit an
    agent, else ``default``; 0 for agents that did not act (inactive at the start of the decision).

    Args:
        table: The reward values.
        reached: Agents that reached the door ``(R, N)`` bool.
        crashed_wall: Agents whose move a wall cut ``(R, N)`` bool.
        crashed_agent: Agents whose move another body cut, and no wall ``(R, N)`` bool.
        acting: Agents active during the decision ``(R, N)`` bool.

    Returns:
        Rewards ``(R, N)`` float32.
    """
    reward = torch.where(crashed_agent, table.crash_agent, table.default)
    reward = torch.where(crashed_wall, table.crash_wall, reward)
    reward = torch.where(reached, table.goal, reward)
    return torch.where(acting, reward, 0.0).to(torch.float32)

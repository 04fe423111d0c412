"""Rewards per decision (paper Table 2)."""

import torch

from pedrl.sim.rewards import RewardTable, compute_rewards


def test_reward_priority_goal_then_wall_then_agent_then_default():
    # columns: nothing, agent crash, wall crash, wall and agent crash, reached, reached after a crash, inactive
    reached = torch.tensor([[False, False, False, False, True, True, True]])
    crashed_wall = torch.tensor([[False, False, True, True, False, True, True]])
    crashed_agent = torch.tensor([[False, True, False, True, False, True, False]])
    acting = torch.tensor([[True, True, True, True, True, True, False]])
    reward = compute_rewards(
        table=RewardTable(), reached=reached, crashed_wall=crashed_wall, crashed_agent=crashed_agent, acting=acting
    )
    assert reward.dtype == torch.float32
    assert reward.tolist() == [[0.0, -4.0, -15.0, -15.0, 100.0, 100.0, 0.0]]


def test_reward_values_come_from_the_table():
    table = RewardTable(goal=1.0, crash_wall=-2.0, crash_agent=-3.0, default=-0.5)
    flags = torch.tensor([[True, False, False, False]])
    reward = compute_rewards(
        table=table,
        reached=flags,
        crashed_wall=flags.roll(1, -1),
        crashed_agent=flags.roll(2, -1),
        acting=torch.ones(1, 4, dtype=torch.bool),
    )
    assert reward.tolist() == [[1.0, -2.0, -3.0, -0.5]]
    assert RewardTable() == RewardTable(goal=100.0, crash_wall=-15.0, crash_agent=-4.0, default=0.0)

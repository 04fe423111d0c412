"""Tabular Q-learning on flat table rows: Q tables, epsilon-greedy action selection, the TD update, schedules."""

from pedrl.rl.qlearning import td_update
from pedrl.rl.qtable import NUM_ACTIONS, epsilon_greedy, greedy, in_huge_pages, table_rows, zeros_q_values
from pedrl.rl.schedules import ConstantSchedule, ExponentialSchedule, LinearSchedule, Schedule

__all__ = [
    "NUM_ACTIONS",
    "ConstantSchedule",
    "ExponentialSchedule",
    "LinearSchedule",
    "Schedule",
    "epsilon_greedy",
    "greedy",
    "in_huge_pages",
    "table_rows",
    "td_update",
    "zeros_q_values",
]

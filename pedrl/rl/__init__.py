"""Tabular Q-learning on flat table rows: Q tables, epsilon-greedy action selection, the TD update, schedules, and
the learned policy (:class:`TabularPolicy`: a state encoder, the tables and the agent-to-table rule); and the neural
learner's policy (:class:`NeuralPolicy`: a Q-network per learning process, :mod:`pedrl.rl.network`), whose update is
:mod:`pedrl.rl.deep_q` (PPO's, :mod:`pedrl.rl.ppo`), and its twin with a continuous head (:class:`ContinuousPolicy`)."""

from pedrl.rl.neural import ContinuousPolicy, NeuralPolicy
from pedrl.rl.policy import PolicyController, TableLayout, TabularPolicy
from pedrl.rl.qlearning import td_update, td_update_torch
from pedrl.rl.qtable import (
    NUM_ACTIONS,
    epsilon_greedy,
    factored_values,
    greedy,
    in_huge_pages,
    table_rows,
    zeros_q_values,
)
from pedrl.rl.schedules import ConstantSchedule, ExponentialSchedule, LinearSchedule, Schedule

__all__ = [
    "NUM_ACTIONS",
    "ConstantSchedule",
    "ContinuousPolicy",
    "ExponentialSchedule",
    "LinearSchedule",
    "NeuralPolicy",
    "PolicyController",
    "Schedule",
    "TableLayout",
    "TabularPolicy",
    "epsilon_greedy",
    "factored_values",
    "greedy",
    "in_huge_pages",
    "table_rows",
    "td_update",
    "td_update_torch",
    "zeros_q_values",
]

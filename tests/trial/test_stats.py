"""A trial's statistics (`pedrl.trial.stats.TrialStats`) from per-agent totals: analytic cases of the crowd's
figures, evacuation time and door flow, as ``pedrl-eval`` defines them."""

import math

import torch

from pedrl.trial.stats import TOTALS, TrialStats


def totals_of(reached: list[list[int]], decisions: list[list[int]]) -> torch.Tensor:
    """Totals ``(len(TOTALS), R * N)`` of rooms whose agents reached (1/0) after the given decisions."""
    rooms, agents = len(reached), len(reached[0])
    totals = torch.zeros(len(TOTALS), rooms * agents)
    totals[TOTALS.index("reached")] = torch.tensor(reached, dtype=torch.float32).reshape(-1)
    totals[TOTALS.index("decisions")] = torch.tensor(decisions, dtype=torch.float32).reshape(-1)
    return totals


def stats(reached, decisions, processes: int, length: float = 0.5) -> TrialStats:
    return TrialStats.from_totals(
        totals_of(reached, decisions),
        processes=processes,
        num_agents=len(reached[0]),
        decision_length=length,
        td_error=torch.zeros(processes),
        decisions=max(max(d) for d in decisions),
    )


def test_evacuation_time_and_door_flow_of_rooms_that_empty():
    # process 0: two rooms; agents leave at decisions 2, 4, 6 and 3, 3, 5; decisions last 0.5 s
    figures = stats([[1, 1, 1], [1, 1, 1]], [[2, 4, 6], [3, 3, 5]], processes=1)
    assert figures.evacuation_time.tolist() == [(3.0 + 2.5) / 2]
    # (n - 1) / (t_last - t_first): 2 / 2 s and 2 / 1 s, averaged over the rooms
    assert figures.door_flow.tolist() == [(1.0 + 2.0) / 2]
    assert figures.success_rate.tolist() == [1.0]


def test_a_room_that_keeps_agents_lasts_the_whole_trial_and_flows_only_with_two_exits():
    # process 0: one agent out at decision 3, one held to the clock (10); process 1: nobody out
    figures = stats([[1, 0], [0, 0]], [[3, 10], [10, 10]], processes=2, length=1.0)
    assert figures.evacuation_time.tolist() == [10.0, 10.0]
    assert all(math.isnan(v) for v in figures.door_flow.tolist())  # no two exits: no flow measured
    assert figures.success_rate.tolist() == [0.5, 0.0]
    # control: two agents leaving at the same decision give no flow either (no time between them)
    same = stats([[1, 1]], [[4, 4]], processes=1)
    assert math.isnan(same.door_flow.item()) and same.evacuation_time.item() == 2.0

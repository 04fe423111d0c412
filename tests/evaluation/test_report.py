"""Under ``pedrl-eval``'s table, whether its scenes are enough to rank the controllers on fails."""

from __future__ import annotations

from pedrl.evaluation import print_table
from pedrl.evaluation.report import ranking_lines


def row(controller: str, agents: int, fails: float, std: float, trials: int) -> dict:
    return {
        "controller": controller,
        "agents": agents,
        "fails_pct": fails,
        "fails_std": std,
        "trials": trials,
        "mean_speed": 1.0,
        "speed_std": 0.1,
        "evacuation_time_s": 70.0,
        "evacuated_trials": trials,
        "stuck_pct": fails,
        "door_flow": 1.3,
        "crashes_per_agent": 1.0,
        "wall_crashes_per_agent": 0.5,
    }


def test_ten_scenes_are_too_few_to_rank_a_ten_point_gap():
    # the quickstart's first result: the shipped main crowd and the greedy walker, 10 scenes at 100 agents
    (line,) = ranking_lines([row("learned", 100, 18.3, 29.5, 10), row("greedy", 100, 7.6, 22.8, 10)])
    assert line.startswith("100 agents: fails learned - greedy = +10.70 ± 23.58 points")
    assert "too few scenes to rank learned and greedy on fails" in line


def test_a_gap_beyond_two_standard_errors_is_ranked():
    (line,) = ranking_lines([row("learned", 100, 18.3, 20.0, 400), row("greedy", 100, 7.6, 20.0, 400)])
    assert line.endswith("learned fails more than greedy")
    (line,) = ranking_lines([row("learned", 60, 1.0, 2.0, 400), row("greedy", 60, 3.0, 2.0, 400)])
    assert line.endswith("learned fails less than greedy")


def test_no_spread_and_no_gap_is_the_same_on_every_scene():
    (line,) = ranking_lines([row("learned", 20, 0.0, 0.0, 10), row("greedy", 20, 0.0, 0.0, 10)])
    assert line.endswith("the same fails on every scene")


def test_one_controller_alone_is_not_ranked():
    assert ranking_lines([row("learned", 20, 1.0, 1.0, 10)]) == []


def test_the_table_ends_with_a_line_per_count_and_reference(capsys):
    rows = [
        row("learned", 20, 0.0, 0.0, 10),
        row("greedy", 20, 0.0, 0.0, 10),
        row("jupedsim", 20, 1.0, 3.0, 10),
        row("learned", 100, 18.3, 29.5, 10),
        row("greedy", 100, 7.6, 22.8, 10),
    ]
    print_table(rows, "learned and greedy")
    out = capsys.readouterr().out.splitlines()
    ranked = [line.strip() for line in out if "standard errors over" in line]
    assert [line.split(":")[0] for line in ranked] == ["20 agents", "20 agents", "100 agents"]
    assert "fails learned - jupedsim" in ranked[1]

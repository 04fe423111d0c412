"""The action set: turn ratios fine enough to line up with a 1 m opening (issue 19), against the coarse set."""

import math

import pytest
import torch

from pedrl.scenarios import paper_room
from pedrl.sim import COARSE_TURN_RATIOS, DEFAULT_TURN_RATIOS
from pedrl.sim.controllers import GreedyDoorController
from pedrl.sim.motion import Slide

STEP = 2.5  # m, a full-speed decision at the default max_speed
CLEARANCE = 0.1  # m, either side of a 0.4 m body in a 1 m opening
LINED_UP = math.asin(CLEARANCE / STEP)  # rad: a step with this heading error ends CLEARANCE off the aimed line


def residual_after(turns: tuple[float, ...], errors: torch.Tensor, decisions: int) -> torch.Tensor:
    """Heading errors (rad) left after ``decisions`` greedy turns, each the one leaving the smallest error."""
    options = torch.tensor(turns, dtype=torch.float64) * math.pi
    for _ in range(decisions):
        left = torch.remainder(errors.unsqueeze(-1) + options + math.pi, 2 * math.pi) - math.pi
        errors = left.gather(-1, left.abs().argmin(-1, keepdim=True)).squeeze(-1)
    return errors


def test_any_heading_lines_up_within_four_decisions():
    errors = torch.linspace(-math.pi, math.pi, 20001, dtype=torch.float64)
    fine = residual_after(DEFAULT_TURN_RATIOS, errors, 4).abs().max().item()
    coarse = residual_after(COARSE_TURN_RATIOS, errors, 4).abs().max().item()
    assert fine <= LINED_UP, math.degrees(fine)  # 2.25 degrees: a 2.5 m step lands within 0.1 m
    assert coarse > 3 * LINED_UP, math.degrees(coarse)  # the control: 9 degrees, 0.39 m off


def lone_walkers_out(turns: tuple[float, ...]) -> float:
    """Share of lone greedy walkers (bodies of 0.45 m) that pass a 1 m door of the paper's room in 200 decisions."""
    env = paper_room(door_width=1.0).room(
        num_replicas=200, num_agents=1, agent_radius=0.45, turn_ratios=turns, motion=Slide()
    )
    obs, info = env.reset(seed=1)
    controller = GreedyDoorController()
    out = torch.zeros(env.num_replicas, 1, dtype=torch.bool)
    for _ in range(env.max_decisions):
        obs, _, terminated, _, info = env.step(controller.act(env, obs, info))
        out |= terminated
    return out.float().mean().item()


@pytest.mark.parametrize(("turns", "low", "high"), [(DEFAULT_TURN_RATIOS, 0.97, 1.0), (COARSE_TURN_RATIOS, 0.0, 0.92)])
def test_lone_walkers_line_up_with_a_narrow_door(turns, low, high):
    """With 5 cm to spare either side, walkers aiming straight at the door get through with the fine turns; with
    the coarse ones (smallest turn 18 degrees) about one in seven stays pinned against a door post."""
    assert low <= lone_walkers_out(turns) <= high

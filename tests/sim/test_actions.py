"""The action set: turn ratios fine enough to line up with a 1 m opening (issue 19), against the coarse set."""

import math

import numpy as np
import pytest
import torch

from pedrl._numba import numba_available
from pedrl.scenarios import paper_room
from pedrl.sim import COARSE_TURN_RATIOS, DEFAULT_TURN_RATIOS
from pedrl.sim.actions import (
    GOAL_SPEED_RATIOS,
    GOAL_TURN_RATIOS,
    NUM_ACTIONS,
    apply_action_kernel,
    apply_actions,
    velocities_from,
    velocity_kernel,
)
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
    for _ in range(env.params.max_decisions):
        obs, _, terminated, _, info = env.step(controller.act(env, obs, info))
        out |= terminated
    return out.float().mean().item()


@pytest.mark.parametrize(("turns", "low", "high"), [(DEFAULT_TURN_RATIOS, 0.97, 1.0), (COARSE_TURN_RATIOS, 0.0, 0.92)])
def test_lone_walkers_line_up_with_a_narrow_door(turns, low, high):
    """With 5 cm to spare either side, walkers aiming straight at the door get through with the fine turns; with
    the coarse ones (smallest turn 18 degrees) about one in seven stays pinned against a door post."""
    assert low <= lone_walkers_out(turns) <= high


@pytest.mark.skipif(not numba_available(), reason="numba")
@pytest.mark.parametrize("frame", ["heading", "goal"])
def test_the_codec_kernel_is_the_torch_codec_of_one_agent(frame):
    """apply_action_kernel and velocity_kernel (the fused step's) against apply_actions and velocities_from, every
    action, active or not, both frames."""
    ratios = {"speed_ratios": GOAL_SPEED_RATIOS, "turn_ratios": GOAL_TURN_RATIOS} if frame == "goal" else {}
    env = paper_room(width=10.0, length=12.0).room(num_agents=2, action_frame=frame, **ratios)
    room = env.params.kernel_room(env)
    generator = torch.Generator().manual_seed(1)
    shape = (1, 2 * NUM_ACTIONS)
    actions = torch.arange(NUM_ACTIONS).repeat(2).reshape(shape)
    active = (torch.arange(shape[1]) < NUM_ACTIONS).reshape(shape)
    speeds = torch.rand(shape, generator=generator) * env.params.max_speed
    headings = (torch.rand(shape, generator=generator) * 2 - 1) * math.pi
    positions, targets = (torch.rand(*shape, 2, generator=generator) * 10 for _ in range(2))
    to_goal = targets - positions
    bearings = torch.atan2(to_goal[..., 1], to_goal[..., 0]) if frame == "goal" else None
    want_speeds, want_headings = apply_actions(
        speeds=speeds,
        headings=headings,
        actions=actions,
        speed_changes=env.speed_changes,
        turn_changes=env.turn_changes,
        max_speed=env.params.max_speed,
        active=active,
        bearings=bearings,
    )
    want_velocities = velocities_from(speeds=want_speeds, headings=want_headings)[0].numpy()
    for i in range(shape[1]):
        position = (np.float32(positions[0, i, 0]), np.float32(positions[0, i, 1]))
        target = (np.float32(targets[0, i, 0]), np.float32(targets[0, i, 1]))
        speed, heading = apply_action_kernel(
            room, bool(active[0, i]), np.float32(speeds[0, i]), np.float32(headings[0, i]), int(actions[0, i]),
            position, target,
        )  # fmt: skip
        assert speed == want_speeds[0, i].item()
        assert heading == pytest.approx(want_headings[0, i].item(), abs=1e-6)  # libm's atan2 against torch's
        np.testing.assert_allclose(velocity_kernel(speed, heading), want_velocities[i], rtol=1e-6, atol=1e-6)

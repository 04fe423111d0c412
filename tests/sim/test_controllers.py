"""The non-learned greedy controller of pedrl.sim.controllers, on hand-made observations (the learned policy:
tests/rl/test_policy.py)."""

from types import SimpleNamespace

import pytest
import torch

from pedrl.sim import COARSE_TURN_RATIOS
from pedrl.sim.actions import GOAL_SPEED_RATIOS, GOAL_TURN_RATIOS
from pedrl.sim.controllers import GreedyDoorController


def test_greedy_controller_turns_towards_the_door_at_full_speed():
    params = SimpleNamespace(
        speed_ratios=(-1.0, -0.5, -0.25, -0.1, 0.0, 0.1, 0.25, 0.5, 1.0),
        turn_ratios=COARSE_TURN_RATIOS,
        action_frame="heading",
    )
    env = SimpleNamespace(params=params)
    obs = torch.zeros(1, 4, 28)
    obs[0, :, 1] = torch.tensor([0.0, 0.2, -torch.pi / 2, 3.0])  # heading relative to the door direction (rad)
    actions = GreedyDoorController().act(env, obs, {})
    speed_index, turn_index = actions // 9, actions % 9
    assert speed_index.tolist() == [[8, 8, 8, 8]]  # +1.0 max speed
    assert turn_index.tolist() == [[4, 3, 7, 0]]  # no turn, -0.1 pi, +0.5 pi, -0.75 pi


def test_greedy_controller_in_the_goal_frame_takes_the_top_speed_straight_at_the_door_whatever_its_heading():
    params = SimpleNamespace(speed_ratios=GOAL_SPEED_RATIOS, turn_ratios=GOAL_TURN_RATIOS, action_frame="goal")
    env = SimpleNamespace(params=params)
    obs = torch.zeros(1, 4, 28)
    obs[0, :, 1] = torch.tensor([0.0, 0.2, -torch.pi / 2, 3.0])
    actions = GreedyDoorController().act(env, obs, {})
    assert (actions == 8 * 9 + 4).all()  # speed ratio 1.0, offset 0 from the line to the door


def test_greedy_controller_with_epsilon_replaces_that_share_of_its_actions():
    params = SimpleNamespace(
        speed_ratios=(-1.0, -0.5, -0.25, -0.1, 0.0, 0.1, 0.25, 0.5, 1.0),
        turn_ratios=COARSE_TURN_RATIOS,
        action_frame="heading",
    )
    env = SimpleNamespace(params=params, num_actions=81)
    obs = torch.zeros(50, 200, 28)  # every agent faces the door: the greedy action is 8 * 9 + 4 = 76
    noisy = GreedyDoorController(epsilon=0.3, generator=torch.Generator().manual_seed(0)).act(env, obs, {})
    changed = float((noisy != 76).double().mean())
    assert changed == pytest.approx(0.3 * 80 / 81, abs=0.01)  # a random action is the greedy one 1 time in 81
    again = GreedyDoorController(epsilon=0.3, generator=torch.Generator().manual_seed(0)).act(env, obs, {})
    assert torch.equal(noisy, again)
    assert torch.equal(GreedyDoorController(epsilon=0.0).act(env, obs, {}), torch.full((50, 200), 76))
    with pytest.raises(ValueError, match="epsilon"):
        GreedyDoorController(epsilon=-0.1)

"""The Q-network's heads (:data:`pedrl.rl.network.HEADS`): the branching head's values are a state value plus one
advantage per speed and per turn index, and a stored network reloads with its head."""

import pytest
import torch

from pedrl.rl.network import QNetwork, head_of, head_outputs
from pedrl.rl.neural import neural_from_tensors


def test_the_branching_head_adds_a_speed_and_a_turn_advantage_to_a_state_value():
    network = QNetwork(2, 6, [16], 81, head="branching", generator=torch.Generator().manual_seed(0))
    assert network.widths == (6, 16, 19) and network.actions == 81
    values = network(torch.randn(2, 5, 6, generator=torch.Generator().manual_seed(1))).view(2, 5, 9, 9)
    # two actions that differ in the speed alone differ by the same amount whatever the turn (and the other way)
    speed_gap = values[..., 8, :] - values[..., 3, :]
    turn_gap = values[..., :, 4] - values[..., :, 0]
    torch.testing.assert_close(speed_gap, speed_gap[..., :1].expand_as(speed_gap))
    torch.testing.assert_close(turn_gap, turn_gap[..., :1].expand_as(turn_gap))
    # the control: a joint head has no such structure
    joint = QNetwork(2, 6, [16], 81, generator=torch.Generator().manual_seed(0))
    free = joint(torch.randn(2, 5, 6, generator=torch.Generator().manual_seed(1))).view(2, 5, 9, 9)
    gap = free[..., 8, :] - free[..., 3, :]
    assert not torch.allclose(gap, gap[..., :1].expand_as(gap))


def test_the_mean_value_over_the_actions_is_the_state_value():
    network = QNetwork(1, 4, [8], 81, head="branching", generator=torch.Generator().manual_seed(2))
    x = torch.randn(1, 3, 4)
    raw = x
    for layer, (weight, bias) in enumerate(zip(network.weights, network.biases, strict=True)):
        raw = torch.baddbmm(bias, raw, weight)
        raw = torch.relu(raw) if layer == 0 else raw
    torch.testing.assert_close(network(x).mean(-1), raw[..., 0])


def test_a_stored_network_reloads_with_its_head(tmp_path):
    from pedrl.vq.encoder import EncoderSettings

    settings = EncoderSettings(num_neighbours=1, num_walls=1, max_distance=10.0, max_speed=1.0)
    width = settings.num_features + settings.num_neighbours
    for head in ("joint", "branching"):
        network = QNetwork(1, width, [8], 81, head=head, generator=torch.Generator().manual_seed(0))
        tensors = {**network.tensors("network"), "inputs/mean": torch.zeros(settings.num_features),
                   "inputs/std": torch.ones(settings.num_features)}  # fmt: skip
        policy = neural_from_tensors(settings, tensors, num_actions=81)
        assert policy.network.head == head and policy.num_actions == 81
        x = torch.randn(1, 2, width)
        torch.testing.assert_close(policy.network(x), network(x))


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: head_outputs("dueling", 81), "head='dueling' is invalid: must be one of joint, branching"),
        (lambda: head_outputs("branching", 5), "head='branching' is invalid for 5 actions"),
        (lambda: head_of(20, 81), "gives 20 values: must give 81 .joint. or 19 .branching."),
    ],
)
def test_bad_heads_are_one_line(call, message):
    with pytest.raises(ValueError, match=message) as error:
        call()
    assert "\n" not in str(error.value)

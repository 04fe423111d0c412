"""The neural learner's parts: P networks as one module, the replay rings, and the double DQN update."""

import pytest
import torch

from pedrl.rl.deep_q import DoubleDQN, DQNSettings
from pedrl.rl.network import QNetwork, check_hidden
from pedrl.rl.neural import NeuralPolicy
from pedrl.rl.replay import Batch, ReplayBuffer
from pedrl.vq.encoder import EncoderSettings, StateEncoder

SETTINGS = EncoderSettings(num_neighbours=2, num_walls=1, max_distance=20.0, max_speed=2.0)  # F = 3 + 6 + 2 = 11


def _policy(processes=2, hidden=(8,), seed=0) -> NeuralPolicy:
    width = SETTINGS.num_features + SETTINGS.num_neighbours
    network = QNetwork(processes, width, hidden, 5, generator=torch.Generator().manual_seed(seed))
    mean, std = torch.zeros(SETTINGS.num_features), torch.ones(SETTINGS.num_features)
    return NeuralPolicy(StateEncoder(SETTINGS), network, mean, std)


def _update(policy, **changes) -> DoubleDQN:
    settings = dict(gamma=0.9, batch_size=4, learning_starts=0, train_every=1, gradient_steps=1, target_every=1000,
                    reward_scale=1.0, max_grad_norm=10.0) | changes  # fmt: skip
    return DoubleDQN(policy, DQNSettings(**settings), learning_rate=0.01)


def test_the_processes_networks_are_the_separate_networks_they_stand_for():
    policy = _policy(processes=3, hidden=(6, 4))
    x = torch.randn(3, 5, policy.num_inputs)
    together = policy.network(x)
    for p in range(3):
        h = x[p]
        for layer, (w, b) in enumerate(zip(policy.network.weights, policy.network.biases, strict=True)):
            h = h @ w[p] + b[p]
            h = torch.relu(h) if layer < 2 else h
        torch.testing.assert_close(together[p], h)


def test_values_route_every_row_through_its_own_process():
    policy = _policy(processes=3)
    x = torch.randn(7, policy.num_inputs)
    process = torch.tensor([2, 0, 1, 2, 2, 0, 1])
    values = policy.values(x, process)
    for row in range(7):
        expected = policy.network(x[row].expand(3, 1, -1))[process[row], 0]
        torch.testing.assert_close(values[row], expected)


def test_inputs_flag_the_sensed_neighbour_slots():
    policy = _policy()
    obs = torch.rand(3, SETTINGS.num_features)
    inputs = policy.inputs(obs, torch.tensor([0, 1, 2]), decision=0)
    assert inputs[:, -2:].tolist() == [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]


def test_a_process_update_ignores_every_other_process_batch():
    """P processes are P independent runs: process 0's weights after a step do not depend on process 1's data."""
    runs = []
    for other in (0.0, 100.0):
        policy = _policy(processes=2)
        update = _update(policy)
        generator = torch.Generator().manual_seed(1)
        inputs = torch.randn(2, 4, policy.num_inputs, generator=generator)
        rewards = torch.tensor([[1.0, -1.0, 0.5, 2.0], [other] * 4])
        batch = Batch(
            inputs, torch.tensor([[0, 1, 2, 3]] * 2), rewards, inputs.flip(1), torch.zeros(2, 4, dtype=torch.bool)
        )
        update.descend(batch)
        runs.append([w.detach().clone() for w in policy.network.weights])
    assert all(torch.equal(a[0], b[0]) for a, b in zip(*runs, strict=True))
    assert not all(torch.equal(a[1], b[1]) for a, b in zip(*runs, strict=True))


def test_the_target_is_the_double_dqn_target():
    """y = r + gamma Q_target(s', argmax_a Q_online(s', a)), r alone after a terminal step: the step's |TD error| is
    |Q(s, a) - y| with that y, the action chosen by the online network and valued by the target network."""
    policy = _policy(processes=1, hidden=(4,))
    update = _update(policy, gamma=0.5)
    with torch.no_grad():
        for target_w, w in zip(update.target.weights, policy.network.weights, strict=True):
            target_w.copy_(-3.0 * w)  # the target network values actions otherwise than the online one
    generator = torch.Generator().manual_seed(2)
    s, s_next = (torch.randn(1, 3, policy.num_inputs, generator=generator) for _ in range(2))
    actions, rewards = torch.tensor([[1, 4, 0]]), torch.tensor([[1.0, 3.0, -2.0]])
    terminated = torch.tensor([[False, True, False]])
    with torch.no_grad():
        chosen = policy.network(s_next).argmax(2, keepdim=True)
        y = rewards + 0.5 * torch.where(terminated, 0.0, update.target(s_next).gather(2, chosen).squeeze(2))
        q = policy.network(s).gather(2, actions.unsqueeze(2)).squeeze(2)
        single = policy.network(s_next).max(2).values  # what plain DQN's target network would not give
        assert not torch.allclose(update.target(s_next).gather(2, chosen).squeeze(2), single)
    update.descend(Batch(s, actions, rewards, s_next, terminated))
    _, td = update.take_sums()
    torch.testing.assert_close(td, (q - y).abs().mean(1))


def test_an_n_step_target_discounts_the_bootstrap_by_gamma_to_the_horizon():
    """With horizons (n-step returns), y = R + gamma^h Q_target(s_h, argmax Q(s_h, a)): a transition of horizon 1
    takes the one-step target, one of horizon 3 the bootstrap discounted three times."""
    policy = _policy(processes=1, hidden=(4,))
    update = _update(policy, gamma=0.5)
    generator = torch.Generator().manual_seed(3)
    s, s_next = (torch.randn(1, 2, policy.num_inputs, generator=generator) for _ in range(2))
    actions, rewards = torch.tensor([[2, 2]]), torch.tensor([[1.0, 1.0]])
    terminated, horizons = torch.zeros(1, 2, dtype=torch.bool), torch.tensor([[1, 3]], dtype=torch.uint8)
    with torch.no_grad():
        chosen = policy.network(s_next).argmax(2, keepdim=True)
        bootstrap = update.target(s_next).gather(2, chosen).squeeze(2)
        q = policy.network(s).gather(2, actions.unsqueeze(2)).squeeze(2)
    y = rewards + torch.tensor([[0.5, 0.125]]) * bootstrap
    update.descend(Batch(s, actions, rewards, s_next, terminated, horizons))
    _, td = update.take_sums()
    torch.testing.assert_close(td, (q - y).abs().mean(1))
    assert not torch.allclose(td, (q - rewards - 0.5 * bootstrap).abs().mean(1))  # the one-step target differs


def test_the_target_network_follows_every_target_every_steps():
    policy = _policy(processes=1)
    update = _update(policy, target_every=2)
    batch = Batch(torch.randn(1, 4, policy.num_inputs), torch.zeros(1, 4, dtype=torch.int64), torch.ones(1, 4),
                  torch.randn(1, 4, policy.num_inputs), torch.zeros(1, 4, dtype=torch.bool))  # fmt: skip
    start = update.target.weights[0].clone()
    update.descend(batch)
    assert torch.equal(update.target.weights[0], start)
    update.descend(batch)
    assert torch.equal(update.target.weights[0], policy.network.weights[0])


def test_replay_rings_wrap_and_sample_what_they_hold():
    buffer = ReplayBuffer(2, 4, 3)
    for step in range(3):
        rows = torch.arange(3, dtype=torch.float32) + 10 * step
        transitions = Batch(rows[:, None].expand(3, 3), rows.long(), rows, rows[:, None].expand(3, 3), rows > 100)
        buffer.add(torch.tensor([0, 0, 1]), transitions)
    assert buffer.sizes.tolist() == [4, 3] and buffer.size == 3
    assert sorted(buffer.rewards[0].tolist()) == [10.0, 11.0, 20.0, 21.0]  # the oldest overwritten
    sample = buffer.sample(64, torch.Generator().manual_seed(0))
    assert set(sample.rewards[1].tolist()) <= {2.0, 12.0, 22.0} and set(sample.rewards[0].tolist()) <= {
        10.0,
        11.0,
        20.0,
        21.0,
    }


@pytest.mark.parametrize(
    ("hidden", "message"), [([0], "each layer width"), ("256", "must be a list"), ([True], "each")]
)
def test_bad_layer_widths_are_one_line(hidden, message):
    with pytest.raises(ValueError, match=message):
        check_hidden(hidden)

"""The PPO update's parts (:mod:`pedrl.rl.ppo`): generalised advantages on hand-made trajectories, and the clipped
step moving each process's probabilities the way its advantages say, and no further than the clip."""

import pytest
import torch

from pedrl.rl.network import QNetwork
from pedrl.rl.neural import command_means
from pedrl.rl.ppo import PPOSettings, PPOUpdate, advantages, gaussian_logprob


def _trajectory(rewards, values, *, terminated=(), cut=(), bootstrap=0.0):
    """One row's trajectory ``(T, 1)``: it ends at its last step, terminal if ``terminated`` holds it, else cut."""
    steps = len(rewards)
    column = lambda items: torch.tensor(items, dtype=torch.float32).unsqueeze(1)  # noqa: E731
    ended = torch.zeros(steps, 1, dtype=torch.bool)
    ended[-1] = True
    term = torch.zeros(steps, 1, dtype=torch.bool)
    for t in terminated:
        term[t] = True
    boot = torch.zeros(steps, 1)
    for t in cut:
        boot[t] = bootstrap
    return column(rewards), column(values), term, ended, boot


@pytest.mark.parametrize("terminal", [True, False], ids=["left", "cut"])
def test_advantages_with_lambda_1_are_discounted_returns_minus_values(terminal):
    """lambda = 1: A_t = sum_k gamma^k r_t+k (+ gamma^(T-t) V_boot where the clock cut it) - V_t; returns A + V."""
    rewards, values, gamma = [1.0, -2.0, 3.0, 0.5], [0.3, -0.1, 0.7, 2.0], 0.9
    parts = _trajectory(rewards, values, terminated=[3] if terminal else [], cut=[] if terminal else [3], bootstrap=5.0)
    adv, returns = advantages(*parts, gamma=gamma, gae_lambda=1.0)
    tail = 0.0 if terminal else 5.0
    for t in range(4):
        expected = sum(gamma**k * rewards[t + k] for k in range(4 - t)) + gamma ** (4 - t) * tail
        assert adv[t, 0].item() == pytest.approx(expected - values[t], abs=1e-5)
        assert returns[t, 0].item() == pytest.approx(expected, abs=1e-5)


def test_advantages_with_lambda_0_are_one_step_td_errors_and_rows_are_apart():
    """lambda = 0: A_t = r_t + gamma V_t+1 - V_t; a second row that did nothing (zeros) keeps zero advantages."""
    rewards, values, gamma = [1.0, 2.0, 3.0], [0.5, 1.5, -1.0], 0.5
    parts = [torch.cat([p, torch.zeros_like(p)], dim=1) for p in _trajectory(rewards, values, terminated=[2])]
    adv, _ = advantages(*parts, gamma=gamma, gae_lambda=0.0)
    expected = [1.0 + 0.5 * 1.5 - 0.5, 2.0 + 0.5 * -1.0 - 1.5, 3.0 - (-1.0)]
    torch.testing.assert_close(adv[:, 0], torch.tensor(expected))
    assert not bool(adv[:, 1].any())


def _update(processes=2, outputs=5, log_std=None, **changes):
    """An update of small networks (``outputs`` of the actor; with ``log_std``, the continuous head's)."""
    settings = dict(gamma=0.9, gae_lambda=0.95, clip_coef=0.2, value_coef=0.5, entropy_coef=0.0, epochs=1,
                    minibatches=1, max_grad_norm=100.0, reward_scale=1.0, normalize_advantages=False)  # fmt: skip
    settings |= changes
    generator = torch.Generator().manual_seed(0)
    actor = QNetwork(processes, 3, (8,), outputs, generator=generator)
    critic = QNetwork(processes, 3, (8,), 1, generator=generator)
    return PPOUpdate(actor, critic, PPOSettings(**settings), learning_rate=0.05, log_std=log_std, company_column=2)


def _rollout(update, reward: float, steps: int = 4, rows: int = 2):
    """Every row takes action 2 at every step of one trajectory, rewarded ``reward`` a step (terminal at its end)."""
    inputs = torch.randn(steps, rows, 3, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        process = torch.arange(rows) % update.actor.processes
        every = update.actor(inputs.reshape(1, -1, 3).expand(update.actor.processes, -1, -1))  # (P, T rows, 5)
        logits = every.view(-1, steps, rows, 5)[process, :, torch.arange(rows)].transpose(0, 1)  # (T, rows, 5)
        logprobs = torch.log_softmax(logits, dim=2)[..., 2]
    ended = torch.zeros(steps, rows, dtype=torch.bool)
    ended[-1] = True
    zeros = torch.zeros(steps, rows)
    return {"inputs": inputs, "actions": torch.full((steps, rows), 2), "logprobs": logprobs, "values": zeros,
            "rewards": torch.full((steps, rows), reward), "terminated": ended.clone(), "ended": ended,
            "valid": torch.ones(steps, rows, dtype=torch.bool), "bootstrap": zeros}, process  # fmt: skip


@pytest.mark.parametrize(("reward", "direction"), [(1.0, 1), (-1.0, -1)], ids=["good", "bad"])
def test_a_step_makes_an_action_with_a_positive_advantage_likelier_and_a_negative_one_rarer(reward, direction):
    update = _update()
    rollout, process = _rollout(update, reward)
    before = rollout["logprobs"].clone()
    update.learn(rollout, process, torch.Generator().manual_seed(0))
    after, _ = _rollout(update, reward)
    assert bool((direction * (after["logprobs"] - before) > 0).all())


@pytest.mark.parametrize(("clip", "moves"), [(0.2, False), (10.0, True)], ids=["clipped", "within_the_clip"])
def test_past_the_clip_a_good_action_gets_no_further_push(clip, moves):
    """Decisions whose probability ratio already exceeds 1 + c (stored probabilities 3 times smaller than now) with a
    positive advantage give the actor no gradient: it stays as it is; with a wider clip (control) it moves."""
    update = _update(clip_coef=clip)
    rollout, process = _rollout(update, 1.0)
    rollout["logprobs"] -= torch.log(torch.tensor(3.0))
    actor = [w.clone() for w in update.actor.weights]
    update.learn(rollout, process, torch.Generator().manual_seed(0))
    assert moves != all(torch.equal(w, a) for w, a in zip(update.actor.weights, actor, strict=True))


def test_a_process_without_decisions_keeps_its_networks():
    update = _update(processes=2)
    rollout, process = _rollout(update, 1.0)
    process = torch.zeros_like(process)  # every row is process 0's
    second = [w[1].clone() for w in (*update.actor.weights, *update.critic.weights)]
    first = update.actor.weights[0][0].clone()
    update.learn(rollout, process, torch.Generator().manual_seed(0))
    assert all(
        torch.equal(w[1], s) for w, s in zip((*update.actor.weights, *update.critic.weights), second, strict=True)
    )
    assert not torch.equal(update.actor.weights[0][0], first)  # process 0 learned


# ---------------------------------------------------------------------- the continuous head
def test_the_gaussian_log_density_is_torchs_normal():
    generator = torch.Generator().manual_seed(3)
    mean, log_std = torch.randn(5, 2, generator=generator), 0.3 * torch.randn(5, 2, generator=generator)
    sample = mean + torch.randn(5, 2, generator=generator)
    expected = torch.distributions.Normal(mean, log_std.exp()).log_prob(sample).sum(-1)
    torch.testing.assert_close(gaussian_logprob(sample, mean, log_std), expected)


def _continuous_rollout(inputs, actions, *, logprobs=None, rewards=None, **extra):
    """One trajectory per row of ``inputs (T, rows, D)`` taking ``actions`` (terminal at its last step), values 0,
    rewards and log-probabilities 0 unless given."""
    steps, rows = inputs.shape[:2]
    ended = torch.zeros(steps, rows, dtype=torch.bool)
    ended[-1] = True
    zeros = torch.zeros(steps, rows)
    return {"inputs": inputs, "actions": actions, "logprobs": zeros if logprobs is None else logprobs,
            "values": zeros, "rewards": zeros if rewards is None else rewards, "terminated": ended.clone(),
            "ended": ended, "valid": torch.ones(steps, rows, dtype=torch.bool), "bootstrap": zeros,
            **extra}  # fmt: skip


@pytest.mark.parametrize(("reward", "direction"), [(1.0, 1), (-1.0, -1)], ids=["good", "bad"])
def test_a_continuous_step_moves_the_mean_towards_a_good_command_and_away_from_a_bad_one(reward, direction):
    """Every row's sample lies 0.5 above the actor's mean on both outputs; a positive advantage moves the means
    towards it (the log-density of the sample rises), a negative one away; the spread is learned too."""
    update = _update(processes=1, outputs=2, log_std=torch.zeros(1, 2))
    steps, rows = 4, 3
    inputs = torch.randn(steps, rows, 3, generator=torch.Generator().manual_seed(1))

    def density(sample):
        with torch.no_grad():
            mean = update.actor(inputs.reshape(1, -1, 3)).view(steps, rows, 2)
            return gaussian_logprob(sample, mean, update.log_std.view(1, 1, 2)), mean

    _, mean = density(torch.zeros(steps, rows, 2))
    sample = mean + 0.5
    before, _ = density(sample)
    rollout = _continuous_rollout(inputs, sample, logprobs=before, rewards=torch.full((steps, rows), reward))
    spread = update.log_std.detach().clone()
    update.learn(rollout, torch.zeros(rows, dtype=torch.int64), torch.Generator().manual_seed(0))
    after, _ = density(sample)
    assert bool((direction * (after - before) > 0).all())
    assert not torch.equal(update.log_std.detach(), spread)


@pytest.mark.parametrize(("prior", "alone"), [(0.0, True), (1.0, True), (1.0, False)], ids=["without", "with", "gated"])
def test_the_heading_prior_pulls_the_mean_heading_towards_the_goal_bearing(prior, alone):
    """Decisions without advantage (every reward and value 0): the clipped objective has nothing to learn, so without
    the prior the actor stays as it is (the control); with it one step takes the rows' mean headings (output 1, before
    the squash) nearer to 0, the goal bearing: their mean square more than halves; on decisions the rollout does not
    mark ``alone`` (a walker in company under ``algo.prior_radius``) it pulls nothing."""
    update = _update(processes=1, outputs=2, log_std=torch.zeros(1, 2), heading_prior=prior)
    steps, rows = 4, 3
    inputs = torch.randn(steps, rows, 3, generator=torch.Generator().manual_seed(1))

    def means():
        with torch.no_grad():
            return update.actor(inputs.reshape(1, -1, 3)).view(steps, rows, 2)

    before = means()
    rollout = _continuous_rollout(inputs, before.clone(), alone=torch.full((steps, rows), alone))
    actor = [w.clone() for w in update.actor.weights]
    update.learn(rollout, torch.zeros(rows, dtype=torch.int64), torch.Generator().manual_seed(0))
    if prior and alone:
        assert means()[..., 1].square().mean() < 0.5 * before[..., 1].square().mean()
    else:
        assert all(torch.equal(w, a) for w, a in zip(update.actor.weights, actor, strict=True))


def test_a_company_heading_adds_its_term_only_where_another_is_sensed():
    """``command_means``: two outputs are the means as they are; of three, the heading is the second output alone
    where the company flag reads 0 and the second plus the third where it reads 1; the speed is the first."""
    outputs = torch.tensor([[0.3, 0.2, -0.5], [0.3, 0.2, -0.5], [1.0, -0.1, 0.4]])
    inputs = torch.tensor([[9.0, 0.0], [9.0, 1.0], [9.0, 1.0]])  # column 1: the company flag
    means = command_means(outputs, inputs, 1)
    torch.testing.assert_close(means, torch.tensor([[0.3, 0.2], [0.3, -0.3], [1.0, 0.3]]))
    assert torch.equal(command_means(outputs[:, :2], inputs, 1), outputs[:, :2])


def test_the_heading_prior_pulls_the_heading_alone_and_leaves_the_company_term():
    """An actor with a company heading (three outputs; input column 2 the company flag), decisions without advantage:
    the prior pulls the heading alone (output 1) towards the goal bearing (its mean square more than halves) and not
    the company term: the last layer's weights and bias of output 2 stay as they were (no gradient reaches them), where
    those of output 1 move."""
    update = _update(processes=1, outputs=3, log_std=torch.zeros(1, 2), heading_prior=1.0)
    steps, rows = 4, 3
    inputs = torch.randn(steps, rows, 3, generator=torch.Generator().manual_seed(1))
    inputs[..., 2] = (torch.arange(rows) % 2).float()  # rows 1: in company; rows 0 and 2: alone

    def outputs():
        with torch.no_grad():
            return update.actor(inputs.reshape(1, -1, 3)).view(steps, rows, 3)

    before = outputs()
    rollout = _continuous_rollout(inputs, command_means(before, inputs, 2))
    last_w, last_b = update.actor.weights[-1].detach().clone(), update.actor.biases[-1].detach().clone()
    update.learn(rollout, torch.zeros(rows, dtype=torch.int64), torch.Generator().manual_seed(0))
    assert outputs()[..., 1].square().mean() < 0.5 * before[..., 1].square().mean()
    assert torch.equal(update.actor.weights[-1][..., 2], last_w[..., 2])
    assert torch.equal(update.actor.biases[-1][..., 2], last_b[..., 2])
    assert not torch.equal(update.actor.weights[-1][..., 1], last_w[..., 1])


@pytest.mark.parametrize("heading", ["added", "routed"])
def test_routed_decisions_in_company_teach_the_company_term_only(heading):
    """Every decision in company with an advantage (one good command taken): ``added`` moves the last layer's weights
    of the heading alone (output 1) and of the company term (output 2); ``routed`` moves only the company term's, the
    heading alone holding still (no gradient reaches it from a decision in company)."""
    update = _update(processes=1, outputs=3, log_std=torch.zeros(1, 2), company_heading=heading)
    steps, rows = 4, 3
    inputs = torch.randn(steps, rows, 3, generator=torch.Generator().manual_seed(1))
    inputs[..., 2] = 1.0  # everyone senses another
    with torch.no_grad():
        means = command_means(update.actor(inputs.reshape(1, -1, 3)).view(steps, rows, 3), inputs, 2)
    logprobs = gaussian_logprob(means + 0.5, means, torch.zeros(1, 1, 2))
    rollout = _continuous_rollout(inputs, means + 0.5, logprobs=logprobs, rewards=torch.ones(steps, rows))
    last = update.actor.weights[-1].detach().clone()
    update.learn(rollout, torch.zeros(rows, dtype=torch.int64), torch.Generator().manual_seed(0))
    assert not torch.equal(update.actor.weights[-1][..., 2], last[..., 2])
    assert torch.equal(update.actor.weights[-1][..., 1], last[..., 1]) == (heading == "routed")

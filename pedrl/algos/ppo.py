"""PPO: shared-parameter proximal policy optimisation, one actor and one critic per learning process, learned from
whole trials (:mod:`pedrl.rl.ppo`; CleanRL's ``ppo.py`` is the style anchor).

``algo=ppo`` learns in the rooms, with the observations, actions, rewards, motion models and scenario mixes of the
other learners, on the learning run they share (:class:`pedrl.algos.run.LearningRun`). A run reads top to bottom as:

1. record the states of a random walk (``gather_trials`` trials) for the standardisation of the inputs (as the DQN);
2. ``trials`` trials, split into ``iterations`` blocks each ending with a checkpoint: in each, every agent samples
   its action from its process's actor (its exploration: no epsilon), the trial's decisions are kept whole
   (:class:`pedrl.rl.ppo.Rollout`), and at its end the actor and critic take ``epochs`` passes of ``minibatches``
   steps of the clipped objective over them.

The actor is a network of the DQN's kind (:class:`pedrl.rl.network.QNetwork`). With ``actions=discrete`` it gives
one logit per action and the learned policy is a :class:`pedrl.rl.NeuralPolicy` that acts on the most probable one;
with ``actions=continuous`` it gives the mean of a squashed Gaussian over the ``goal`` frame's speed ratio and heading
offset (:mod:`pedrl.rl.ppo`), and the learned policy is a :class:`pedrl.rl.ContinuousPolicy` that commands its mean.
``pedrl-eval``, ``pedrl-validate``, the PettingZoo crowd and ``pedrl-export`` (ONNX included) run either as they run
the DQN's; the critic, the Gaussian's spread and Adam's state are in the checkpoints only, for an exact resume.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Final

import torch
from tqdm.auto import tqdm

from pedrl.algos.networks import NetworkConfig, NetworkRun, checked_count, decisions_on, random_walk_standardisation
from pedrl.algos.phase import Phase
from pedrl.algos.records import RunRecord
from pedrl.algos.run import RunSpec
from pedrl.common.checks import (
    check_bool,
    check_choice,
    check_integer,
    check_memory,
    check_number,
)
from pedrl.rl.network import QNetwork
from pedrl.rl.neural import (
    COMPANY_HEADINGS,
    COMPANY_WIDTH,
    ContinuousPolicy,
    NeuralPolicy,
    company_column,
    squash,
)
from pedrl.rl.ppo import METRICS, PPOSettings, PPOUpdate, Rollout, gaussian_logprob
from pedrl.sim import RoomEnv
from pedrl.sim.actions import COMMAND_WIDTH
from pedrl.sim.rewards import MAX_DEVIATION_RADIUS, in_company
from pedrl.trial.crowd import run_crowd
from pedrl.trial.loop import Driver
from pedrl.trial.rollout import TrialStats

MAX_EPOCHS: Final = 1_000
"""Largest ``epochs`` (passes over a trial's decisions)."""
MAX_MINIBATCHES: Final = 100_000
"""Largest ``minibatches`` (steps per pass)."""
ACTION_HEADS: Final = ("discrete", "continuous")
"""Values of ``actions``: the 81 discrete actions, or a continuous command (module docstring)."""


@dataclass(frozen=True)
class PPOConfig(NetworkConfig):
    """The settings of ``algo=ppo`` (each an ``algo`` key): the network learners' (:class:`NetworkConfig`; its
    ``hidden`` the actor's and the critic's, its ``max_grad_norm`` each network's), then its own, every value checked
    when the record is made.

    Attributes:
        gae_lambda: the advantage's lambda (1: Monte-Carlo returns minus the value; 0: one-step TD errors).
        clip_coef: the clipping of the probability ratio, ``c``.
        value_coef: the weight of the critic's loss.
        entropy_coef: the weight of the policy's entropy (a bonus).
        epochs: passes over a trial's decisions.
        minibatches: gradient steps per pass (each on an equal share of every process's decisions).
        normalize_advantages: standardise the advantages within each minibatch (CleanRL's default).
        actions: the action head (:data:`ACTION_HEADS`); ``continuous`` needs ``env.action_frame=goal``.
        init_std: the continuous head's first standard deviation (of the Gaussian before the squash; learned after).
        heading_prior: the weight of the continuous head's pull of its mean heading towards the goal bearing in every
            state (:mod:`pedrl.rl.ppo`; 0: none; only with ``actions=continuous``).
        prior_radius: that pull only on decisions with no other walker within this many m (0: on every decision).
        company_heading: :data:`pedrl.rl.neural.COMPANY_HEADINGS`: ``added``, the continuous head's heading is a
            heading alone plus a term that acts only where the walker senses another, the heading prior pulling the
            heading alone; ``routed``, so too, and a decision in company teaches the company term only
            (:func:`pedrl.rl.neural.command_means`); ``none``: one heading.
    """

    learning_rate: float = 3e-4
    max_grad_norm: float = 0.5
    gae_lambda: float = 0.95
    clip_coef: float = 0.2
    value_coef: float = 0.5
    entropy_coef: float = 0.01
    epochs: int = 4
    minibatches: int = 8
    normalize_advantages: bool = True
    actions: str = "discrete"
    init_std: float = 1.0
    heading_prior: float = 0.0
    prior_radius: float = 0.0
    company_heading: str = "none"

    def __post_init__(self) -> None:
        super().__post_init__()
        check_number("gae_lambda", self.gae_lambda, low=0.0, high=1.0)
        check_number("clip_coef", self.clip_coef, low=0.0, high=10.0, low_open=True)
        check_number("value_coef", self.value_coef, low=0.0, high=1e6)
        check_number("entropy_coef", self.entropy_coef, low=0.0, high=1e6)
        check_integer("epochs", self.epochs, minimum=1, maximum=MAX_EPOCHS)
        check_integer("minibatches", self.minibatches, minimum=1, maximum=MAX_MINIBATCHES)
        check_bool("normalize_advantages", self.normalize_advantages)
        check_choice("actions", self.actions, ACTION_HEADS)
        check_number("init_std", self.init_std, low=0.0, high=10.0, low_open=True)
        check_number("heading_prior", self.heading_prior, low=0.0, high=1e6)
        check_number("prior_radius", self.prior_radius, low=0.0, high=MAX_DEVIATION_RADIUS)
        check_choice("company_heading", self.company_heading, COMPANY_HEADINGS)
        if self.heading_prior and self.actions != "continuous":
            raise ValueError(
                f"algo.heading_prior={self.heading_prior!r} is invalid with algo.actions={self.actions}: the pull of"
                " the mean heading needs the continuous head (algo.actions=continuous), or heading_prior 0"
            )
        if self.company_heading != "none" and self.actions != "continuous":
            raise ValueError(
                f"algo.company_heading={self.company_heading} is invalid with algo.actions={self.actions}: the company"
                " heading is a term of the continuous head's heading (algo.actions=continuous), or company_heading none"
            )

    def update(self) -> PPOSettings:
        """The settings of the update (:class:`pedrl.rl.ppo.PPOSettings`)."""
        keys = (item.name for item in fields(PPOSettings))
        return PPOSettings(**{key: getattr(self, key) for key in keys})


class PPOActor(Driver):
    """PPO in the trial loop: every acting agent samples its action from its process's actor; each decision goes to
    the trial's :class:`~pedrl.rl.ppo.Rollout` with the action's log-probability and the critic's value."""

    sync_free = True
    stepped = True

    def __init__(
        self,
        policy: NeuralPolicy,
        critic: QNetwork,
        *,
        generator: torch.Generator,
        reward_scale: float,
        log_std: torch.Tensor | None = None,
        prior_radius: float = 0.0,
    ):
        self.policy, self.critic, self.generator, self.reward_scale = policy, critic, generator, reward_scale
        self.log_std = log_std  # the continuous head's (P, 2); None: discrete
        self.prior_radius = prior_radius  # > 0: mark the decisions with nobody within it, for the heading prior
        self.processes = policy.num_processes

    def begin(self, env: Any, obs: torch.Tensor, info: Any) -> None:
        self.process, _ = self.policy.layout.of(env.num_replicas, env.num_agents, env.device)
        self._env, self.rollout = env, Rollout()
        self._inputs = self.policy.inputs_of(obs, info, env.active.reshape(-1))

    def act(self, env: Any, obs: torch.Tensor, info: Any) -> torch.Tensor:
        active = env.active.reshape(-1)
        rows = torch.nonzero(active).squeeze(1)
        batch, device = active.shape[0], active.device
        continuous = self.log_std is not None
        actions = torch.zeros((batch, COMMAND_WIDTH) if continuous else batch, device=device,
                              dtype=torch.float32 if continuous else torch.int64)  # fmt: skip
        logprobs, values = torch.zeros(batch, device=device), torch.zeros(batch, device=device)
        if rows.shape[0]:
            with torch.no_grad():
                inputs, process = self._inputs.index_select(0, rows), self.process.index_select(0, rows)
                outputs = self.policy.values(inputs, process)
                if continuous:  # a Gaussian sample around the actor's mean, squashed into the command below
                    log_std = self.log_std.index_select(0, process)
                    noise = torch.randn(outputs.shape, generator=self.generator, device=device)
                    chosen = outputs + log_std.exp() * noise
                    logprob = gaussian_logprob(chosen, outputs, log_std)
                else:
                    log_all = torch.log_softmax(outputs, dim=1)
                    chosen = torch.multinomial(log_all.exp(), 1, generator=self.generator).squeeze(1)
                    logprob = log_all.gather(1, chosen.unsqueeze(1)).squeeze(1)
                actions.index_copy_(0, rows, chosen)
                logprobs.index_copy_(0, rows, logprob)
                values.index_copy_(0, rows, self.policy.values(inputs, process, network=self.critic).squeeze(1))
        alone = active
        if self.prior_radius > 0:  # nobody within the radius: the decisions the heading prior pulls
            alone = active & ~in_company(env.positions, env.active, self.prior_radius).reshape(-1)
        self._step = dict(inputs=self._inputs, actions=actions, logprobs=logprobs, values=values, valid=active,
                          alone=alone)  # fmt: skip
        if continuous:
            return squash(actions).view(env.num_replicas, env.num_agents, COMMAND_WIDTH)
        return actions.view(env.num_replicas, env.num_agents)

    def observe(self, obs, info, reward, terminated, valid) -> None:
        next_inputs = self.policy.inputs_of(obs, info, valid & ~terminated)
        ended = valid & (terminated | ~self._env.active.reshape(-1))
        cut = torch.nonzero(ended & ~terminated).squeeze(1)  # the clock ended these trajectories: bootstrap
        bootstrap = torch.zeros_like(reward)
        if cut.shape[0]:
            with torch.no_grad():
                value = self.policy.values(next_inputs.index_select(0, cut), self.process.index_select(0, cut),
                                           network=self.critic)  # fmt: skip
            bootstrap.index_copy_(0, cut, value.squeeze(1))
        self.rollout.add(**self._step, rewards=reward * self.reward_scale, terminated=terminated & valid,
                         ended=ended, bootstrap=bootstrap)  # fmt: skip
        self._inputs = next_inputs


class PPO(NetworkRun):
    """Shared-parameter PPO (module docstring), a :class:`pedrl.algos.networks.NetworkRun`.

    Args:
        run: what the run is (of ``run.vq`` only ``distance_transform`` is read, as by the DQN).
        **settings: the keys of :class:`PPOConfig`.
    """

    name = "ppo"
    settings_class = PPOConfig

    def __init__(self, run: RunSpec, **settings: Any) -> None:
        super().__init__(run, **settings)
        self.continuous = self.algo.actions == "continuous"
        if self.continuous:
            for room in [self.env, *self._mix_envs]:
                if room.params.action_frame != "goal":
                    raise ValueError(
                        f"algo.actions=continuous is invalid with env.action_frame={room.params.action_frame!r}: a "
                        "command sets the speed and the heading from the goal bearing (env.action_frame=goal)"
                    )
            self.policy_class = ContinuousPolicy
        self.outputs = self.env.num_actions
        if self.continuous:
            self.outputs = COMMAND_WIDTH if self.algo.company_heading == "none" else COMPANY_WIDTH
        self.settings = self.algo.update()
        check_memory(
            self.memory_needs(),
            device=self.device,
            advice="lower algo.hidden, processes, rooms_per_process, the agents, algo.gather_trials or "
            "env.max_decisions",
        )

    def memory_needs(self) -> dict[str, float]:
        """Estimated bytes of the largest allocations: a trial's decisions (inputs and five numbers per agent and
        decision, twice: as kept and as stacked), the networks with Adam's moments, a decision of the largest room."""
        rooms = [self.env, *self._mix_envs]
        rows = max(room.num_replicas * room.num_agents * room.params.max_decisions for room in rooms)
        widths = (self.width, *self.algo.hidden)
        weights = sum((a + 1) * b for a, b in zip(widths[:-1], widths[1:], strict=True)) * self.processes * 4
        gathered = self.gather_trials * sum(r.num_replicas * r.num_agents * r.params.max_decisions for r in rooms)
        return {
            "a trial's decisions": 2 * rows * (self.width + 8) * 4,
            "gathered states": 2 * gathered * self.encoder_settings.num_features * 4,
            "networks and Adam": 2 * 3 * (weights + (widths[-1] + 1) * (self.outputs + 1) * 4),
            "room": max(room.step_memory() for room in rooms),
        }

    # ------------------------------------------------------------------ the network run's hooks
    def start(self) -> None:
        """A new run: seed, standardise by a random walk, build the actor, the critic and the update."""
        mean, std, self.summary = random_walk_standardisation(self)
        build = dict(generator=self.generator, device=self.device)
        actor = QNetwork(self.processes, self.width, self.hidden, self.outputs, **build)
        critic = QNetwork(self.processes, self.width, self.hidden, 1, **build)
        self.policy = self.make_policy(actor, mean, std)
        self.update = self.make_update(actor, critic)
        self.summary["parameters"] = actor.num_parameters + critic.num_parameters

    def make_update(self, actor: QNetwork, critic: QNetwork) -> PPOUpdate:
        """The update of ``actor`` and ``critic`` (continuous: with the Gaussian's spread at ``init_std``)."""
        log_std = None
        if self.continuous:
            log_std = torch.full((self.processes, COMMAND_WIDTH), math.log(self.algo.init_std), device=self.device)
        return PPOUpdate(actor, critic, self.settings, self.algo.learning_rate, log_std=log_std,
                         company_column=company_column(self.encoder_settings))  # fmt: skip

    def network_shape(self) -> tuple[tuple[int, ...], str]:
        return (self.width, *self.hidden, self.outputs), "joint"

    def restore_tensors(self, policy: NeuralPolicy, tensors: dict[str, torch.Tensor], meta: dict[str, Any]):
        """The update (the critic, Adam's state, its count) of a checkpoint."""
        critic = QNetwork(self.processes, self.width, self.hidden, 1, device=self.device)
        update = self.make_update(policy.network, critic)
        update.load_tensors(tensors)
        update.updates = checked_count(meta, "updates")
        return {"update": update}

    def epsilon(self, global_trial: int) -> float:
        return 0.0  # PPO explores by sampling its actor

    def learn_trial(self, env: RoomEnv, room: int, epsilon: float, bar: tqdm) -> TrialStats:
        driver = PPOActor(self.policy, self.update.critic, generator=self.generator,
                          reward_scale=self.settings.reward_scale, log_std=self.update.log_std,
                          prior_radius=self.algo.prior_radius)  # fmt: skip
        stats = run_crowd(env, driver, fused=self.fused, progress=decisions_on(bar)).stats
        self._figures = self.update.learn(driver.rollout.stack(), driver.process, self.generator)
        return stats

    def check_trial(self, phase: Phase, trial: int, stats: TrialStats) -> None:
        finite = all(bool(torch.isfinite(value).all()) for value in self._figures.values())
        if not (finite and bool(torch.isfinite(stats.episodic_return).all())):
            raise ValueError(
                f"iteration {phase.index}, trial {trial}: the returns or the losses turned inf or NaN: lower "
                "algo.learning_rate or algo.reward_scale"
            )

    def log_trial(self, record: RunRecord, global_trial: int) -> None:
        for name in METRICS:
            record.logger.log_spread(global_trial, f"ppo/{name}", self._figures[name].double())
        record.logger.log_scalars(global_trial, {"ppo/gradient_steps": self.update.updates})

    def state_tensors(self) -> dict[str, torch.Tensor]:
        """The actor (as the policy: ``network/...``, ``inputs/...``), the critic, (continuous) the Gaussian's spread
        and Adam's state."""
        return {**self.policy.tensors(), **self.update.tensors()}

    def state_metadata(self, global_trial: int) -> dict[str, Any]:
        return {"global_trial": global_trial, "updates": self.update.updates, "distortion": math.nan}

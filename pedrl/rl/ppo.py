"""Proximal policy optimisation with shared parameters (Schulman et al. 2017; the style of CleanRL's ``ppo.py``): one
actor and one critic per learning process, shared by all its agents (independent learners with shared parameters,
as in CrowdRL's crowd), learned from whole trials.

A trial's decisions are kept as :class:`Rollout` (every agent-row of every room at every decision); at its end
:func:`advantages` gives each decision its generalised advantage (Schulman et al. 2016) and return, and
:meth:`PPOUpdate.learn` takes ``epochs`` passes of ``minibatches`` gradient steps of the clipped objective

    L = -min(rho A, clip(rho, 1 - c, 1 + c) A) + value_coef (V - R)^2 / 2 - entropy_coef H [+ heading_prior mu_h^2]

with ``rho`` the new over the old probability of the action taken. A walker's trajectory ends where it leaves
(terminal: no bootstrap) or where the clock cuts its trial (the critic's value of its last observation bootstraps).

Two action heads: the 81 discrete actions (a categorical over the actor's logits), or a continuous command (the
actor's two outputs are the mean of a Gaussian with a learned, state-independent standard deviation per process,
``log_std``; a sample ``u`` is squashed into the command, :func:`pedrl.rl.neural.squash`). The squash is fixed, so the
ratio ``rho`` is taken on ``u`` (its Jacobian cancels) and the entropy is the Gaussian's. With ``heading_prior`` the
continuous head's mean heading ``mu_h`` (before the squash: 0 is the goal bearing) is pulled towards the goal bearing
in every state: the mean term of a KL divergence to a default policy that walks straight at the goal (KL-regularised
RL, Todorov 2007; Galashov et al. 2019), so that the actor turns off the goal bearing only where the advantages pay
for it, where others are, and not where their signal is too weak to pin the heading down, alone. A rollout's optional
``alone`` field restricts the pull to the decisions it marks (``algo.prior_radius``: nobody within that radius).
An actor with a company heading (``algo.company_heading``: three outputs, :func:`pedrl.rl.neural.command_means`) has
the heading alone pulled, not the term that acts only where another walker is sensed; under ``routed`` a decision in
company teaches that term only.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import torch

from pedrl.rl.network import QNetwork, clip_gradients, load_optimizer_tensors, optimizer_tensors
from pedrl.rl.neural import command_means


@dataclass(frozen=True)
class PPOSettings:
    """The hyper-parameters of the update (each an ``algo`` key of ``algo=ppo``)."""

    gamma: float
    gae_lambda: float
    clip_coef: float
    value_coef: float
    entropy_coef: float
    epochs: int
    minibatches: int
    max_grad_norm: float
    reward_scale: float
    normalize_advantages: bool = True
    heading_prior: float = 0.0
    company_heading: str = "none"


class Rollout:
    """One trial's decisions of every row ``(R N)``, in order: what each acting row saw, did and got.

    Attributes (after :meth:`stack`): ``inputs (T, B, D)``, ``actions`` (``(T, B)`` indices, or the continuous
    head's Gaussian samples ``(T, B, 2)`` before the squash), ``logprobs``, ``values``, ``rewards`` (in learned
    units), ``terminated``, ``ended`` (its trajectory ends here: left, or cut by the clock), ``valid`` (it acted)
    ``(T, B)``, ``bootstrap (T, B)``, the critic's value of the observation after a decision the clock cut (0
    elsewhere), and ``alone (T, B)``, the decisions the heading prior pulls.
    """

    FIELDS = (
        "inputs",
        "actions",
        "logprobs",
        "values",
        "rewards",
        "terminated",
        "ended",
        "valid",
        "bootstrap",
        "alone",
    )

    def __init__(self) -> None:
        self.steps: dict[str, list[torch.Tensor]] = {name: [] for name in self.FIELDS}

    def add(self, **step: torch.Tensor) -> None:
        """One decision's ``(B, ...)`` tensors, one per field."""
        for name in self.FIELDS:
            self.steps[name].append(step[name])

    def __len__(self) -> int:
        return len(self.steps["valid"])

    def stack(self) -> dict[str, torch.Tensor]:
        """The fields ``(T, B, ...)``."""
        return {name: torch.stack(parts) for name, parts in self.steps.items()}


def advantages(
    rewards: torch.Tensor,
    values: torch.Tensor,
    terminated: torch.Tensor,
    ended: torch.Tensor,
    bootstrap: torch.Tensor,
    *,
    gamma: float,
    gae_lambda: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Generalised advantages and returns ``(T, B)`` of one trial: ``delta_t = r_t + gamma V_next - V_t`` with
    ``V_next`` the next decision's value, the ``bootstrap`` where the clock cut the trajectory, 0 where the walker
    left; ``A_t = delta_t + gamma lambda A_t+1`` within a trajectory. Rows that did not act get 0 (masked later)."""
    steps = rewards.shape[0]
    result = torch.zeros_like(rewards)
    following = torch.zeros_like(rewards[0])  # A_t+1
    next_value = torch.zeros_like(rewards[0])  # V_t+1
    for t in range(steps - 1, -1, -1):
        after = torch.where(terminated[t], 0.0, torch.where(ended[t], bootstrap[t], next_value))
        delta = rewards[t] + gamma * after - values[t]
        result[t] = delta + gamma * gae_lambda * torch.where(ended[t], 0.0, following)
        following, next_value = result[t], values[t]
    return result, result + values


class PPOUpdate:
    """The actor's and the critic's optimizer and the clipped update (module docstring).

    Args:
        actor: ``P`` networks giving the 81 actions' logits, or (continuous) the Gaussian's 2 means.
        critic: ``P`` networks giving one value.
        settings: the hyper-parameters.
        learning_rate: Adam's step size.
        log_std: the continuous head: ``(P, 2)`` the log standard deviations of the Gaussian (learned); None: the
            discrete head.
        company_column: the input column of the company flag, read by an actor with a company heading
            (:func:`pedrl.rl.neural.company_column`; no default: column 0 is a feature, not the flag).
    """

    def __init__(
        self,
        actor: QNetwork,
        critic: QNetwork,
        settings: PPOSettings,
        learning_rate: float,
        *,
        log_std: torch.Tensor | None = None,
        company_column: int,
    ) -> None:
        self.actor, self.critic, self.settings = actor, critic, settings
        self.company_column = company_column
        self.log_std = None if log_std is None else torch.nn.Parameter(log_std)
        self.optimizer = torch.optim.Adam(self.parameters(), lr=learning_rate, foreach=True)
        self.updates = 0
        """Gradient steps taken."""

    def learn(
        self, rollout: Mapping[str, torch.Tensor], process: torch.Tensor, generator: torch.Generator
    ) -> dict[str, torch.Tensor]:
        """``epochs`` passes of ``minibatches`` steps over the acting decisions of ``rollout`` (:meth:`Rollout.stack`),
        row ``b`` learned by process ``process[b]``'s networks. Each process draws its own permutation of its
        decisions; a process with fewer decisions than the largest repeats some of its own to fill its share, one with
        none learns nothing.

        Returns ``(P,)`` means over the steps: ``policy_loss``, ``value_loss``, ``entropy``, ``approx_kl`` (the
        ``(rho - 1) - log rho`` estimate) and ``clip_fraction``."""
        settings = self.settings
        trajectory = (rollout[name] for name in ("rewards", "values", "terminated", "ended", "bootstrap"))
        adv, returns = advantages(*trajectory, gamma=settings.gamma, gae_lambda=settings.gae_lambda)
        valid = rollout["valid"]
        step_of, row_of = torch.nonzero(valid, as_tuple=True)
        owner = process[row_of]
        data = {
            "inputs": rollout["inputs"][step_of, row_of],
            "actions": rollout["actions"][step_of, row_of],
            "logprobs": rollout["logprobs"][step_of, row_of],
            "values": rollout["values"][step_of, row_of],
            "advantages": adv[step_of, row_of],
            "returns": returns[step_of, row_of],
            "alone": rollout.get("alone", valid)[step_of, row_of].float(),  # a rollout without it: every decision
        }
        processes = self.actor.processes
        sums = torch.zeros(5, processes, device=valid.device)
        steps = 0
        members = [torch.nonzero(owner == p).squeeze(1) for p in range(processes)]
        width = max(int(m.shape[0]) for m in members)
        if width == 0:
            return dict(zip(METRICS, sums, strict=True))
        present = torch.tensor([m.shape[0] > 0 for m in members], device=valid.device).float()
        for _ in range(settings.epochs):
            order = torch.stack([_shuffled(m, width, generator) for m in members])  # (P, M)
            for columns in torch.tensor_split(torch.arange(width, device=order.device), settings.minibatches):
                if columns.numel() == 0:
                    continue
                index = order[:, columns]
                sums += self._step({name: tensor[index] for name, tensor in data.items()}, present)
                steps += 1
        return dict(zip(METRICS, sums / max(steps, 1), strict=True))

    def parameters(self) -> list[torch.Tensor]:
        """What Adam steps: the actor's, the critic's and (continuous) the log standard deviations."""
        extra = [] if self.log_std is None else [self.log_std]
        return [*self.actor.parameters(), *self.critic.parameters(), *extra]

    def _step(self, batch: Mapping[str, torch.Tensor], present: torch.Tensor) -> torch.Tensor:
        """One gradient step of every process on ``batch`` ``(P, b, ...)``, of those ``present`` (1, else 0) only; its
        ``(5, P)`` figures."""
        settings = self.settings
        raw = self.actor(batch["inputs"])
        if self.log_std is None:
            log_all = torch.log_softmax(raw, dim=2)
            logprob = log_all.gather(2, batch["actions"].unsqueeze(2)).squeeze(2)
            entropy = -(log_all.exp() * log_all).sum(2)
        else:
            routed = settings.company_heading == "routed"
            outputs = command_means(raw, batch["inputs"], self.company_column, routed=routed)
            log_std = self.log_std.unsqueeze(1)  # (P, 1, 2)
            logprob = gaussian_logprob(batch["actions"], outputs, log_std)
            entropy = (log_std + 0.5 * (1.0 + math.log(2 * math.pi))).sum(2).expand_as(logprob)
        log_ratio = logprob - batch["logprobs"]
        ratio = log_ratio.exp()
        adv = batch["advantages"]
        if settings.normalize_advantages:
            adv = (adv - adv.mean(1, keepdim=True)) / (adv.std(1, keepdim=True, unbiased=False) + 1e-8)
        clipped = ratio.clamp(1.0 - settings.clip_coef, 1.0 + settings.clip_coef)
        policy_loss = -torch.min(ratio * adv, clipped * adv).mean(1)
        value = self.critic(batch["inputs"]).squeeze(2)
        value_loss = 0.5 * (value - batch["returns"]).pow(2).mean(1)
        loss = policy_loss + settings.value_coef * value_loss - settings.entropy_coef * entropy.mean(1)
        if self.log_std is not None and settings.heading_prior:
            # the heading alone (a company heading's first term): what the walker commands where nobody is sensed
            loss = loss + settings.heading_prior * (raw[..., 1].square() * batch["alone"]).mean(1)
        loss = loss * present  # a process that made no decision learns nothing
        self.optimizer.zero_grad(set_to_none=True)
        loss.sum().backward()  # the processes share no weight: each gets its own gradient
        for network in (self.actor, self.critic):
            clip_gradients(network, settings.max_grad_norm)
        if self.log_std is not None:
            torch.nn.utils.clip_grad_norm_([self.log_std], settings.max_grad_norm, foreach=True)
        self.optimizer.step()
        self.updates += 1
        with torch.no_grad():
            kl = ((ratio - 1.0) - log_ratio).mean(1)
            clip_fraction = ((ratio - 1.0).abs() > settings.clip_coef).float().mean(1)
        return torch.stack((policy_loss.detach(), value_loss.detach(), entropy.mean(1).detach(), kl, clip_fraction))

    # ------------------------------------------------------------------ files
    def tensors(self) -> dict[str, torch.Tensor]:
        """The critic, (continuous) the log standard deviations and Adam's state as named tensors (``critic/...``,
        ``actor/log_std``, ``optimizer/<i>.<key>``)."""
        extra = {} if self.log_std is None else {LOG_STD_KEY: self.log_std.detach()}
        return {**self.critic.tensors("critic"), **extra, **optimizer_tensors(self.optimizer)}

    def load_tensors(self, tensors: Mapping[str, torch.Tensor]) -> None:
        """Take the critic, the log standard deviations and Adam's state of :meth:`tensors` (one line for a missing or
        misshapen one)."""
        self.critic.load_tensors(tensors, "critic")
        if self.log_std is not None:
            stored = tensors.get(LOG_STD_KEY)
            shape = tuple(self.log_std.shape)
            if stored is None or tuple(stored.shape) != shape or stored.dtype != torch.float32:
                found = "missing" if stored is None else f"{stored.dtype} {tuple(stored.shape)}"
                raise ValueError(f"tensor {LOG_STD_KEY} is {found}: must be float32 {shape}")
            if not bool(torch.isfinite(stored).all()):
                raise ValueError(f"tensor {LOG_STD_KEY} holds NaN or infinite values: must be finite")
            with torch.no_grad():
                self.log_std.copy_(stored)
        load_optimizer_tensors(self.optimizer, self.parameters(), tensors)


LOG_STD_KEY = "actor/log_std"
"""The continuous head's log standard deviations in a checkpoint (``(P, 2)`` float32)."""


def gaussian_logprob(sample: torch.Tensor, mean: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
    """Log-density ``(...)`` of ``sample (..., 2)`` under independent Gaussians of ``mean`` and ``log_std`` (summed
    over the last axis)."""
    z = (sample - mean) * torch.exp(-log_std)
    return (-0.5 * z * z - log_std - 0.5 * math.log(2 * math.pi)).sum(-1)


METRICS = ("policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction")
"""The figures of :meth:`PPOUpdate.learn`, logged as ``ppo/<name>``."""


def _shuffled(members: torch.Tensor, width: int, generator: torch.Generator) -> torch.Tensor:
    """``width`` of ``members`` in a random order (each at least once; cycled where ``width`` is larger)."""
    count = members.shape[0]
    if count == 0:
        return torch.zeros(width, dtype=torch.int64, device=members.device)
    order = members[torch.randperm(count, generator=generator, device=generator.device).to(members.device)]
    return order.repeat(-(-width // count))[:width]

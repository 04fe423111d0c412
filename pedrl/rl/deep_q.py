"""Double deep Q-learning, the update of the neural learner (van Hasselt, Guez & Silver 2016; the style of CleanRL's
``dqn.py``): ``y = r + gamma (1 - terminated) Q_target(s', argmax_a Q(s', a))`` (with n-step returns ``r`` the
discounted sum of a transition's ``h`` rewards and ``gamma^h`` the discount), a Huber loss on ``Q(s, a) - y``,
Adam, the gradient of each learning process clipped to ``max_grad_norm`` on its own, and the target network copied
from the online one every ``target_every`` steps. A decision cut by the clock bootstraps (it is not terminal), as
the tables' update does. The driver that feeds it in the trial loop is :class:`pedrl.algos.dqn_learning.DeepQLearner`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import torch

from pedrl.rl.network import clip_gradients, load_optimizer_tensors, optimizer_tensors
from pedrl.rl.neural import NeuralPolicy
from pedrl.rl.replay import Batch, ReplayBuffer


@dataclass(frozen=True)
class DQNSettings:
    """The hyper-parameters of an update (each is an ``algo`` key of ``algo=dqn``)."""

    gamma: float
    batch_size: int
    learning_starts: int
    train_every: int
    gradient_steps: int
    target_every: int
    reward_scale: float
    max_grad_norm: float
    balanced: bool = False
    """Batches draw every room of the memory equally often (``algo.replay_balance=room``), else uniformly."""
    n_step: int = 1
    """Decisions a transition's return sums before it bootstraps (``algo.n_step``; fewer where its trial ended)."""


class DoubleDQN:
    """The online network's optimizer, its target network and the update (module docstring).

    Counters: ``updates`` (gradient steps taken) and ``decisions`` (decisions seen); the sums of each process's loss
    and mean |TD error| over the steps since the last :meth:`take_sums`."""

    def __init__(self, policy: NeuralPolicy, settings: DQNSettings, learning_rate: float) -> None:
        self.policy, self.settings = policy, settings
        network = policy.network
        self.target = network.twin(device=policy.device)
        self.target.load_state_dict(network.state_dict())
        self.target.requires_grad_(False)
        self.optimizer = torch.optim.Adam(network.parameters(), lr=learning_rate, foreach=True)
        self.updates = self.decisions = 0
        self._sums = torch.zeros(2, network.processes, device=policy.device)
        self._summed = 0

    def learn(self, buffer: ReplayBuffer, generator: torch.Generator) -> None:
        """After a decision: the update's steps, when due and the rings hold ``learning_starts`` transitions each."""
        settings = self.settings
        self.decisions += 1
        if buffer.size < settings.learning_starts or self.decisions % settings.train_every:
            return
        for _ in range(settings.gradient_steps):
            self.descend(buffer.sample(settings.batch_size, generator, balanced=settings.balanced))

    def descend(self, batch: Batch) -> None:
        """One gradient step of every process on ``batch`` ``(P, B, ...)``."""
        network, settings = self.policy.network, self.settings
        with torch.no_grad():
            best = network(batch.next_inputs).argmax(dim=2, keepdim=True)
            following = self.target(batch.next_inputs).gather(2, best).squeeze(2)
            discount = settings.gamma if batch.horizons is None else settings.gamma ** batch.horizons.float()
            targets = batch.rewards + discount * torch.where(batch.terminated, 0.0, following)
        values = network(batch.inputs).gather(2, batch.actions.unsqueeze(2)).squeeze(2)
        losses = torch.nn.functional.smooth_l1_loss(values, targets, reduction="none").mean(dim=1)  # (P,)
        self.optimizer.zero_grad(set_to_none=True)
        losses.sum().backward()  # the processes share no weight: each gets its own gradient
        clip_gradients(network, settings.max_grad_norm)
        self.optimizer.step()
        self.updates += 1
        if self.updates % settings.target_every == 0:
            self.target.load_state_dict(network.state_dict())
        self._sums += torch.stack((losses.detach(), (values.detach() - targets).abs().mean(dim=1)))
        self._summed += 1

    def take_sums(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(loss, |TD error|)`` ``(P,)`` each, means over the steps since the last call (0 without a step)."""
        means = self._sums / max(self._summed, 1)
        self._sums.zero_()
        self._summed = 0
        return means[0], means[1]

    # ------------------------------------------------------------------ files
    def tensors(self) -> dict[str, torch.Tensor]:
        """The target network and Adam's state as named tensors (``target/...``, ``optimizer/<i>.<key>``)."""
        return {**self.target.tensors("target"), **optimizer_tensors(self.optimizer)}

    def load_tensors(self, tensors: Mapping[str, torch.Tensor]) -> None:
        """Take the target network and Adam's state of :meth:`tensors` (one line for a missing or misshapen one)."""
        self.target.load_tensors(tensors, "target")
        load_optimizer_tensors(self.optimizer, self.policy.network.parameters(), tensors)

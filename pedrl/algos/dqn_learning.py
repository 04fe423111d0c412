"""The neural learner in the trial loop: the driver that acts with the Q-network, feeds the replay memory and calls
the update (:mod:`pedrl.rl.deep_q`).

At every decision the :class:`DeepQLearner` encodes the agents still in a room, acts epsilon-greedily on their
process's network, stores each acting agent's transition in its process's ring, and every ``train_every`` decisions
takes ``gradient_steps`` steps of :class:`pedrl.rl.deep_q.DoubleDQN` on a batch of each ring. With n-step returns
(``algo.n_step`` > 1) a :class:`pedrl.rl.replay.NStepWindow` holds each trial's last decisions and stores the
transitions they complete.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch

from pedrl.rl.deep_q import DoubleDQN
from pedrl.rl.neural import NeuralPolicy
from pedrl.rl.replay import Batch, NStepWindow, ReplayBuffer
from pedrl.trial.loop import Driver


class DeepQLearner(Driver):
    """The neural learner in the trial loop (module docstring): acts with ``policy`` at ``epsilon`` and, if
    ``update`` is given, stores transitions in ``buffer`` (marked as played in the run's ``room``) and learns."""

    sync_free = True
    stepped = True

    def __init__(
        self,
        policy: NeuralPolicy,
        *,
        epsilon: float,
        generator: torch.Generator,
        update: DoubleDQN | None = None,
        buffer: ReplayBuffer | None = None,
        room: int = 0,
    ) -> None:
        self.policy, self.epsilon, self.generator = policy, epsilon, generator
        self.update, self.buffer, self.room = update, buffer, room
        self.processes = policy.num_processes

    def begin(self, env: Any, obs: torch.Tensor, info: Mapping[str, Any]) -> None:
        self._process, _ = self.policy.layout.of(env.num_replicas, env.num_agents, env.device)
        self._env = env
        steps = self.update.settings.n_step if self.update is not None else 1
        self._window = NStepWindow(steps, self.update.settings.gamma) if steps > 1 else None
        self._inputs = self.policy.inputs_of(obs, info, env.active.reshape(-1))

    def act(self, env: Any, obs: torch.Tensor, info: Mapping[str, Any]) -> torch.Tensor:
        active = env.active.reshape(-1)
        rows = torch.nonzero(active).squeeze(1)
        actions = torch.zeros(active.shape[0], dtype=torch.int64, device=active.device)
        if rows.shape[0]:
            with torch.no_grad():
                values = self.policy.values(self._inputs.index_select(0, rows), self._process.index_select(0, rows))
            actions.index_copy_(0, rows, self.policy.choose(values, self.epsilon, self.generator))
        self._actions = actions
        return actions.view(env.num_replicas, env.num_agents)

    def observe(self, obs, info, reward, terminated, valid) -> None:
        next_inputs = self.policy.inputs_of(obs, info, valid & ~terminated)
        if self.update is not None:
            scale = self.update.settings.reward_scale
            taken = Batch(self._inputs, self._actions, reward * scale, next_inputs, terminated)
            if self._window is None:
                rows = torch.nonzero(valid).squeeze(1)
                transitions = Batch(*(t.index_select(0, rows) for t in taken[:5]))
            else:  # the trial ends for the walkers that left and for those the clock cut
                rows, transitions = self._window.fold(taken, valid, terminated | ~self._env.active.reshape(-1))
            self.buffer.add(self._process.index_select(0, rows), transitions, self.room)
            self.update.learn(self.buffer, self.generator)
        self._inputs = next_inputs

    def td_error(self) -> torch.Tensor:
        """``(P,)`` the trial's mean absolute TD error over its gradient steps (0 without one); the mean loss goes to
        ``loss``."""
        if self.update is None:
            self.loss = torch.zeros(self.processes)
            return super().td_error()
        self.loss, td = self.update.take_sums()
        return td

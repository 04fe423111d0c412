"""DQN: the neural learner beside the tables, one Q-network per learning process shared by all its agents.

``algo=dqn`` learns in the rooms, with the observations, actions, rewards, motion models and scenario mixes of the
tabular trainers, and writes the same learning curve, TensorBoard scalars and checkpoints (one per iteration, and
``last.safetensors`` to resume from). What it learns is a :class:`pedrl.rl.NeuralPolicy`, which ``pedrl-eval``,
``pedrl-validate`` and ``pedrl-export`` (to safetensors or ONNX) read from its checkpoints.

A run reads top to bottom as:

1. record the states of a random walk (``gather_trials`` trials) for the standardisation of the network's inputs;
2. learn for ``trials`` trials, split into ``iterations`` blocks each ending with a checkpoint, by double deep
   Q-learning (:mod:`pedrl.algos.dqn_learning`), the agents acting epsilon-greedily (linear decay from
   ``epsilon_start`` to ``epsilon_end`` over ``epsilon_decay_fraction`` of the trials).

The physics and sensing of each decision run in the compiled kernels (:class:`pedrl.trial.stepped.CompiledRoom`)
wherever the fused trial could run the room (``fused`` null or true), else in the torch step (``fused=false``, the
reference); the network acts in torch between them, on the CPU or ``device=cuda``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Final

import torch
from tqdm.auto import tqdm

from pedrl.algos.dqn_learning import DeepQLearner
from pedrl.algos.networks import NetworkConfig, NetworkRun, checked_count, decisions_on, random_walk_standardisation
from pedrl.algos.phase import Phase
from pedrl.algos.records import RunRecord
from pedrl.algos.run import RunSpec
from pedrl.common.checks import (
    LARGE_RUN_S,
    YEAR_S,
    check_choice,
    check_epsilons,
    check_integer,
    check_memory,
    check_number,
    duration,
)
from pedrl.rl import LinearSchedule
from pedrl.rl.deep_q import DoubleDQN, DQNSettings
from pedrl.rl.network import QNetwork, head_outputs
from pedrl.rl.neural import NeuralPolicy
from pedrl.rl.qtable import NUM_ACTIONS
from pedrl.rl.replay import ReplayBuffer
from pedrl.sim import RoomEnv
from pedrl.trial.crowd import run_crowd
from pedrl.trial.rollout import TrialStats

MAX_BATCH: Final = 1 << 20
"""Largest ``batch_size`` (transitions per process and step)."""
MAX_GRADIENT_STEPS: Final = 10_000
"""Largest ``gradient_steps`` (per round, after a decision): even at the fastest step (:data:`FASTEST_STEP_S`) a
round then takes a second for every decision; the presets take 1 or 2."""
FASTEST_STEP_S: Final = 1e-4
"""Seconds of a gradient step no machine beats (a GPU's, bound by its kernel launches): a run whose worst case at this
pace passes a year is refused."""
CPU_TRANSITION_S: Final = 40e-6
"""Seconds a gradient step takes per transition of its batch on one CPU thread (``main_dqn``'s network, two hidden
layers of 256: two steps of 512 transitions in 42 ms, docs/performance.md): the printed estimate's pace."""
GATHER_COPIES: Final = 2
"""Copies of every gathered state in the memory estimate: as recorded, and concatenated."""
REPLAY_BALANCES: Final = ("none", "room")
"""How a batch is drawn from the replay memory (``algo.replay_balance``): uniformly, or every room alike."""
MAX_N_STEP: Final = 100
"""Largest ``n_step`` (decisions a return sums; the rings keep a horizon in a byte)."""


@dataclass(frozen=True)
class DQNConfig(NetworkConfig):
    """The settings of ``algo=dqn`` (each an ``algo`` key): the network learners' (:class:`NetworkConfig`), then its
    own, every value checked when the record is made.

    Attributes:
        head: the network's last layer, ``joint`` (a value per action) or ``branching`` (a state value and an
            advantage per speed and per turn index: :data:`pedrl.rl.network.HEADS`).
        n_step: decisions a transition's return sums before it bootstraps (1: one-step Q-learning; fewer where the
            walker's trial ends before).
        batch_size: transitions per process and gradient step.
        buffer_size: transitions each process's replay memory holds.
        replay_balance: ``none`` (batches uniform over the memory) or ``room`` (every room of the run, its own and each
            ``mix`` room, drawn equally often: :data:`REPLAY_BALANCES`).
        learning_starts: transitions each memory holds before the first gradient step.
        train_every: decisions between two rounds of gradient steps.
        gradient_steps: gradient steps per round.
        target_every: gradient steps between two copies of the online network into the target network.
        epsilon_start, epsilon_end, epsilon_decay_fraction: the exploration schedule over the run's trials.
    """

    head: str = "joint"
    n_step: int = 1
    batch_size: int = 256
    buffer_size: int = 100_000
    replay_balance: str = "none"
    learning_starts: int = 5_000
    train_every: int = 1
    gradient_steps: int = 1
    target_every: int = 500
    epsilon_start: float = 1.0
    epsilon_end: float = 0.05
    epsilon_decay_fraction: float = 0.5

    def __post_init__(self) -> None:
        super().__post_init__()
        for key in ("train_every", "target_every"):
            check_integer(key, getattr(self, key), minimum=1)
        check_integer("gradient_steps", self.gradient_steps, minimum=1, maximum=MAX_GRADIENT_STEPS)
        head_outputs(self.head, NUM_ACTIONS)
        check_integer("n_step", self.n_step, minimum=1, maximum=MAX_N_STEP)
        check_integer("batch_size", self.batch_size, minimum=1, maximum=MAX_BATCH)
        check_integer("buffer_size", self.buffer_size, minimum=self.batch_size)
        check_integer("learning_starts", self.learning_starts, minimum=0, maximum=self.buffer_size)
        check_choice("replay_balance", self.replay_balance, REPLAY_BALANCES)
        check_epsilons(self.epsilon_start, self.epsilon_end)
        check_number("epsilon_decay_fraction", self.epsilon_decay_fraction, low=0.0, high=1.0, low_open=True)

    def update(self) -> DQNSettings:
        """The settings of the update (:class:`pedrl.rl.deep_q.DQNSettings`)."""
        return DQNSettings(self.gamma, self.batch_size, self.learning_starts, self.train_every, self.gradient_steps,
                           self.target_every, self.reward_scale, self.max_grad_norm, self.replay_balance == "room",
                           self.n_step)  # fmt: skip


class DQN(NetworkRun):
    """Double DQN with a target network and a replay memory per learning process (module docstring), a
    :class:`pedrl.algos.networks.NetworkRun`.

    Args:
        run: what the run is (of ``run.vq`` only ``distance_transform`` is read: the inputs are the states as the
            tables' quantizer sees them).
        **settings: the keys of :class:`DQNConfig`.
    """

    name = "dqn"
    settings_class = DQNConfig

    def __init__(self, run: RunSpec, **settings: Any) -> None:
        super().__init__(run, **settings)
        algo = self.algo
        self.learning_rate, self.buffer_size, self.head = algo.learning_rate, algo.buffer_size, algo.head
        self.settings = algo.update()
        decay = max(1, round(algo.epsilon_decay_fraction * algo.trials))
        self.schedule = LinearSchedule(algo.epsilon_start, algo.epsilon_end, decay)
        check_memory(
            self.memory_needs(),
            device=self.device,
            advice="lower algo.buffer_size, algo.hidden, algo.batch_size, processes, rooms_per_process, the agents, "
            "algo.gather_trials or env.max_decisions",
        )
        self._check_learning_length()

    # ------------------------------------------------------------------ what a run is
    def memory_needs(self) -> dict[str, float]:
        """Estimated bytes of the largest allocations: the replay memory, the networks with Adam's moments (online,
        target, two moments: four copies), a batch's activations, and a decision of the largest room."""
        widths = (self.width, *self.hidden, head_outputs(self.head, self.env.num_actions))
        weights = sum((a + 1) * b for a, b in zip(widths[:-1], widths[1:], strict=True)) * self.processes * 4
        batch = self.settings.batch_size * self.processes * sum(widths) * 4 * 6  # forward, backward, targets
        rooms = [self.env, *self._mix_envs]
        rows = self.gather_trials * sum(r.num_replicas * r.num_agents * r.params.max_decisions for r in rooms)
        return {
            "replay memory": ReplayBuffer.bytes_needed(
                self.processes, self.buffer_size, self.width, horizons=self.settings.n_step > 1
            ),  # fmt: skip
            "gathered states": GATHER_COPIES * rows * self.encoder_settings.num_features * 4,
            "networks and Adam": 4 * weights,
            "batch": batch,
            "room": max(room.step_memory() for room in rooms),
        }

    def gradient_steps_at_most(self) -> int:
        """Gradient steps of the whole run if no walker leaves before its trial's end: a round of
        ``gradient_steps`` every ``train_every`` decisions of every trial (of the longest room)."""
        longest = max(room.params.max_decisions for room in [self.env, *self._mix_envs])
        return self.trials * -(-longest // self.settings.train_every) * self.settings.gradient_steps

    def _check_learning_length(self) -> None:
        """Refuse, in one line naming the keys, a run whose gradient steps would take more than a year at the fastest
        step; print the estimate of a run that would take more than a few minutes on one CPU thread."""
        steps = self.gradient_steps_at_most()
        keys = (
            f"algo.trials={self.trials} x env.max_decisions / algo.train_every={self.settings.train_every} x "
            f"algo.gradient_steps={self.settings.gradient_steps}"
        )
        if steps * FASTEST_STEP_S > YEAR_S:
            raise ValueError(
                f"algo.gradient_steps={self.settings.gradient_steps} is invalid here: {keys} gives up to {steps:.3g} "
                f"gradient steps, {duration(steps * FASTEST_STEP_S)} at {FASTEST_STEP_S * 1e3:g} ms a step (faster "
                f"than any machine): must be at most {YEAR_S / FASTEST_STEP_S:.3g} steps (a year): lower "
                "algo.gradient_steps, algo.trials or env.max_decisions, or raise algo.train_every"
            )
        cpu = steps * self.settings.batch_size * self.processes * CPU_TRANSITION_S
        if self.progress and cpu > LARGE_RUN_S:
            print(
                f"dqn: a long run: up to {steps:.3g} gradient steps of {self.settings.batch_size} transitions in each "
                f"of {self.processes} processes ({keys}, if no walker leaves early), {duration(cpu)} at "
                f"{CPU_TRANSITION_S * 1e6:g} us a transition on one CPU thread; each trial shows its decisions",
                flush=True,
            )

    # ------------------------------------------------------------------ the network run's hooks
    def start(self) -> None:
        """A new run: seed, gather the random walk's states, standardise by them, build the network, the memory
        and the update."""
        mean, std, self.summary = random_walk_standardisation(self)
        network = QNetwork(self.processes, self.width, self.hidden, self.env.num_actions, head=self.head,
                           generator=self.generator, device=self.device)  # fmt: skip
        self.policy = self.make_policy(network, mean, std)
        self.update = DoubleDQN(self.policy, self.settings, self.learning_rate)
        self.buffer = self.make_buffer()
        self.summary["parameters"] = network.num_parameters

    def make_buffer(self) -> ReplayBuffer:
        """An empty replay memory of the run's processes (keeping horizons with n-step returns)."""
        return ReplayBuffer(self.processes, self.buffer_size, self.width, horizons=self.settings.n_step > 1,
                            device=self.device)  # fmt: skip

    def network_shape(self) -> tuple[tuple[int, ...], str]:
        return (self.width, *self.hidden, head_outputs(self.head, self.env.num_actions)), self.head

    def restore_tensors(self, policy: NeuralPolicy, tensors: dict[str, torch.Tensor], meta: dict[str, Any]):
        """The update (the target network, Adam's state, its counts) and the replay memory of a checkpoint."""
        update = DoubleDQN(policy, self.settings, self.learning_rate)
        update.load_tensors(tensors)
        update.updates, update.decisions = checked_count(meta, "updates"), checked_count(meta, "decisions")
        buffer = self.make_buffer()
        buffer.load_tensors(tensors)
        return {"update": update, "buffer": buffer}

    def epsilon(self, global_trial: int) -> float:
        return self.schedule(global_trial)

    def learn_trial(self, env: RoomEnv, room: int, epsilon: float, bar: tqdm) -> TrialStats:
        self._driver = DeepQLearner(self.policy, epsilon=epsilon, generator=self.generator, update=self.update,
                                    buffer=self.buffer, room=room)  # fmt: skip
        return run_crowd(env, self._driver, fused=self.fused, progress=decisions_on(bar)).stats

    def check_trial(self, phase: Phase, trial: int, stats: TrialStats) -> None:
        if not (bool(torch.isfinite(stats.episodic_return).all()) and bool(torch.isfinite(self._driver.loss).all())):
            raise ValueError(
                f"iteration {phase.index}, trial {trial}: the returns or the loss turned inf or NaN: lower "
                "algo.learning_rate or algo.reward_scale"
            )

    def log_trial(self, record: RunRecord, global_trial: int) -> None:
        record.logger.log_spread(global_trial, "losses/q_loss", self._driver.loss.double())
        record.logger.log_scalars(global_trial, {"dqn/gradient_steps": self.update.updates,
                                                 "dqn/replay_size": self.buffer.size})  # fmt: skip

    def state_tensors(self) -> dict[str, torch.Tensor]:
        """The network, the target network, Adam's state and the replay memory: everything a resume needs."""
        return {**self.policy.tensors(), **self.update.tensors(), **self.buffer.tensors()}

    def state_metadata(self, global_trial: int) -> dict[str, Any]:
        return {"global_trial": global_trial, "updates": self.update.updates, "decisions": self.update.decisions,
                "distortion": math.nan}  # fmt: skip

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
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Final

import torch
from tqdm.auto import tqdm

from pedrl.algos.dqn_learning import DeepQLearner
from pedrl.algos.dqn_restore import load_dqn_resume
from pedrl.algos.mix import room_of_trial
from pedrl.algos.phase import MAX_TRIALS, Phase, TrainResult
from pedrl.algos.records import RunRecord, final_figures, interactive, report_phase
from pedrl.common.checks import (
    LARGE_RUN_S,
    YEAR_S,
    check_bool,
    check_choice,
    check_device,
    check_epsilons,
    check_integer,
    check_memory,
    check_number,
    check_trials_per_iteration,
    duration,
)
from pedrl.configs import TrainingRoom
from pedrl.io.files import remove_temporaries_in
from pedrl.rl import LinearSchedule
from pedrl.rl.deep_q import DoubleDQN, DQNSettings
from pedrl.rl.network import QNetwork, check_hidden, head_outputs
from pedrl.rl.neural import NeuralPolicy, input_width
from pedrl.rl.qtable import NUM_ACTIONS
from pedrl.rl.replay import ReplayBuffer
from pedrl.sim import RoomEnv
from pedrl.trial.crowd import choose_path, run_crowd
from pedrl.trial.rollout import gather
from pedrl.trial.walking import WalkingLog
from pedrl.vq.encoder import EncoderSettings, StateEncoder
from pedrl.vq.settings import VQSettings

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
MIN_STD: Final = 1e-3
"""A feature whose spread on the random walk is below this (a constant) is standardised by 1 instead."""


class DQN:
    """Double DQN with a target network and a replay memory per learning process (module docstring).

    Args:
        num_agents: learning agents per room.
        trials: total learning trials.
        iterations: blocks the trials are split into, each ending with a checkpoint ``iter_XXXX``.
        gather_trials: random-walk trials whose states standardise the inputs.
        hidden: widths of the hidden layers.
        head: the network's last layer, ``joint`` (a value per action) or ``branching`` (a state value and an
            advantage per speed and per turn index: :data:`pedrl.rl.network.HEADS`).
        neighbour_velocity: the network also reads each sensed neighbour's velocity in the goal frame (beside the
            28 features, which give only its closing speed: :mod:`pedrl.sim.sensing`).
        learning_rate: Adam's step size.
        gamma: discount.
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
        reward_scale: rewards are multiplied by this before they are learned (Q-values in these units).
        max_grad_norm: each process's gradient is clipped to this norm.
        epsilon_start, epsilon_end, epsilon_decay_fraction: the exploration schedule over the run's trials.
        env, mix, home, vq, processes, rooms_per_process, checkpoint_every, device, seed, run_dir, tensorboard,
            walking_probes, progress, run_config, fused: as :class:`pedrl.algos.base.Trainer`'s (of ``vq`` only
            ``distance_transform`` is read: the inputs are the states as the tables' quantizer sees them).
    """

    name = "dqn"

    def __init__(
        self,
        *,
        env: Callable[..., RoomEnv],
        vq: VQSettings | Mapping[str, Any],
        num_agents: int = 20,
        trials: int = 200,
        iterations: int = 1,
        gather_trials: int = 2,
        hidden: Sequence[int] = (256, 256),
        head: str = "joint",
        neighbour_velocity: bool = False,
        learning_rate: float = 5e-4,
        gamma: float = 0.91,
        n_step: int = 1,
        batch_size: int = 256,
        buffer_size: int = 100_000,
        replay_balance: str = "none",
        learning_starts: int = 5_000,
        train_every: int = 1,
        gradient_steps: int = 1,
        target_every: int = 500,
        reward_scale: float = 0.1,
        max_grad_norm: float = 10.0,
        epsilon_start: float = 1.0,
        epsilon_end: float = 0.05,
        epsilon_decay_fraction: float = 0.5,
        processes: int = 1,
        rooms_per_process: int = 1,
        checkpoint_every: int = 0,
        device: str | torch.device = "cpu",
        seed: int = 0,
        run_dir: str | Path = ".",
        tensorboard: bool = True,
        walking_probes: int = 0,
        progress: bool = True,
        run_config: Mapping[str, Any] | None = None,
        mix: Sequence[TrainingRoom] = (),
        home: str = "room",
        fused: bool | None = None,
    ) -> None:
        if (vq.factors if isinstance(vq, VQSettings) else (vq or {}).get("factors")) is not None:  # a table's key
            raise ValueError(
                "vq.factors is invalid with algo=dqn: the network reads the whole state (of the vq group it reads "
                "distance_transform only); use algo=vqql or algo=it_vqql for a factored table"
            )
        self.vq = vq if isinstance(vq, VQSettings) else VQSettings.from_config(vq)  # every other key checked
        _check_settings(locals())
        self.num_agents, self.trials, self.iterations, self.gather_trials = (
            num_agents,
            trials,
            iterations,
            gather_trials,
        )
        self.learning_rate, self.buffer_size, self.hidden = learning_rate, buffer_size, tuple(hidden)
        self.head, self.neighbour_velocity = head, neighbour_velocity
        self.settings = DQNSettings(gamma, batch_size, learning_starts, train_every, gradient_steps, target_every,
                                    reward_scale, max_grad_norm, replay_balance == "room", n_step)  # fmt: skip
        self.schedule = LinearSchedule(epsilon_start, epsilon_end, max(1, round(epsilon_decay_fraction * trials)))
        self.processes, self.rooms_per_process, self.checkpoint_every = processes, rooms_per_process, checkpoint_every
        self.device, self.seed, self.run_dir = check_device(device), seed, Path(run_dir)
        self.tensorboard, self.progress, self.config = tensorboard, progress, dict(run_config or {})
        self.generator = torch.Generator(device=self.device)
        replicas = processes * rooms_per_process
        self.env = env(num_replicas=replicas, num_agents=num_agents, device=self.device)
        self.home, self.mix = home, list(mix)
        self._mix_envs = [e.factory(num_replicas=replicas, num_agents=e.num_agents, device=self.device) for e in mix]
        self.fused = fused
        self.walking = WalkingLog(walking_probes, trials, self.env.params, env)
        self.path, why_not = self.trial_path()  # fused=true refused before any compute
        self.encoder_settings = EncoderSettings.for_room(
            self.env, distance_transform=self.vq.distance_transform
        ).spanning(self.mix)
        self.width = input_width(self.encoder_settings, neighbour_velocity=neighbour_velocity)
        check_memory(
            self.memory_needs(),
            device=self.device,
            advice="lower algo.buffer_size, algo.hidden, algo.batch_size, processes, rooms_per_process, the agents, "
            "algo.gather_trials or env.max_decisions",
        )
        self._check_learning_length()

    # ------------------------------------------------------------------ what a run is
    def phases(self) -> list[Phase]:
        """The iterations: equal blocks of the trials (the first ones a trial longer when they do not divide)."""
        block, extra = divmod(self.trials, self.iterations)
        return [
            Phase(i + 1, self.num_agents, block + (1 if i < extra else 0), self.gather_trials, 1.0)
            for i in range(self.iterations)
        ]

    def trial_path(self) -> tuple[str, str | None]:
        """``("fused", None)``: the compiled kernels step every room; else ``("torch", why)``. One line for
        ``fused=true`` where they cannot."""
        return tuple(choose_path([self.env, *self._mix_envs], None, self.fused))

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

    def rooms(self) -> list[tuple[str, RoomEnv]]:
        """The labelled rooms the run trains in: its own, then the ``mix`` rooms (drawing from its generator)."""
        for room in self._mix_envs:
            room.generator = self.env.generator
        return [(self.home, self.env), *((e.label, room) for e, room in zip(self.mix, self._mix_envs, strict=True))]

    # ------------------------------------------------------------------ the run
    def fit(self, *, resume_from: str | Path | None = None) -> TrainResult:
        """Gather, then learn every iteration (or the rest of them, when resuming); returns the final figures."""
        phases = self.phases()
        remove_temporaries_in(self.run_dir / "checkpoints")
        resumed = load_dqn_resume(self, resume_from) if resume_from is not None else None
        record = RunRecord(self.run_dir, tensorboard=self.tensorboard, config=self.config,
                           wall_time_before=resumed.wall_time_s if resumed else 0.0)  # fmt: skip
        if resumed is not None and resumed.done:
            return TrainResult.finished(self.run_dir, record.checkpoint_path, resumed.wall_time_s, resumed.final, [])
        start = resumed.global_trial if resumed is not None else 0
        record.open(start, resumed=resumed is not None)
        stats = None
        try:
            if resumed is None:
                self.start()
                record.logger.log_scalars(0, {f"dqn/{key}": value for key, value in self.summary.items()})
            else:
                self.policy, self.update, self.buffer = resumed.policy, resumed.update, resumed.buffer
                self.generator.set_state(resumed.rng_trainer)
                self.env.generator.set_state(resumed.rng_env)
            stats = self._learn(phases, start, record)
        finally:
            record.close()
        final = final_figures(stats) if stats is not None else dict(resumed.final if resumed else {})
        return TrainResult(final, self.run_dir, record.checkpoint_path, record.wall_time(), [self.summary])

    def start(self) -> None:
        """A new run: seed, gather the random walk's states, standardise by them, build the network, the memory
        and the update."""
        self.generator.manual_seed(self.seed * 10_007 + 1)
        self.env.reset(seed=self.seed * 10_007 + 2)
        encoder = StateEncoder(self.encoder_settings)
        gathered = [
            gather(room, encoder, None, trials=self.gather_trials, epsilon=1.0, processes=self.processes,
                   generator=self.generator)
            for _, room in self.rooms()
        ]  # fmt: skip
        states = torch.cat([part.states for part in gathered])
        mean, std = states.mean(0), states.std(0)
        std = torch.where(std < MIN_STD, 1.0, std)
        network = QNetwork(self.processes, self.width, self.hidden, self.env.num_actions, head=self.head,
                           generator=self.generator, device=self.device)  # fmt: skip
        self.policy = self.make_policy(network, mean.float().contiguous(), std.float().contiguous())
        self.update = DoubleDQN(self.policy, self.settings, self.learning_rate)
        self.buffer = self.make_buffer()
        self.summary = {"gathered_states": int(states.shape[0]),
                        "gather_success_rate": sum(p.success_rate for p in gathered) / len(gathered),
                        "parameters": network.num_parameters}  # fmt: skip

    def make_buffer(self) -> ReplayBuffer:
        """An empty replay memory of the run's processes (keeping horizons with n-step returns)."""
        return ReplayBuffer(self.processes, self.buffer_size, self.width, horizons=self.settings.n_step > 1,
                            device=self.device)  # fmt: skip

    def make_policy(self, network: QNetwork, mean: torch.Tensor, std: torch.Tensor) -> NeuralPolicy:
        """The run's policy over ``network`` (its rooms ``p E .. p E + E - 1`` act with process ``p``'s network)."""
        return NeuralPolicy(StateEncoder(self.encoder_settings), network, mean, std,
                            rooms_per_process=self.rooms_per_process,
                            neighbour_velocity=self.neighbour_velocity)  # fmt: skip

    def _learn(self, phases: list[Phase], start: int, record: RunRecord):
        """The trials from global trial ``start`` on, each logged, with the checkpoints."""
        stats, global_trial = None, 0
        rooms = self.rooms()
        for phase in phases:
            first = max(0, start - global_trial)
            global_trial += first
            if first >= phase.trials:
                continue
            description = f"dqn iteration {phase.index}/{len(phases)} ({phase.num_agents} agents)"
            tic = time.perf_counter()
            bar = tqdm(range(first, phase.trials), desc=description, disable=not (self.progress and interactive()),
                       leave=False)  # fmt: skip
            for trial in bar:
                epsilon = self.schedule(global_trial)
                index = room_of_trial(trial, phase.trials, len(rooms))
                label, room = rooms[index]
                trial_tic = time.perf_counter()
                driver = DeepQLearner(self.policy, epsilon=epsilon, generator=self.generator, update=self.update,
                                      buffer=self.buffer, room=index)  # fmt: skip
                stats = run_crowd(room, driver, fused=self.fused, progress=_decisions_on(bar)).stats
                self._check_finite(phase, trial, stats, driver.loss)
                rate = stats.agent_decisions / (time.perf_counter() - trial_tic)
                walking = self.walking.measure(global_trial, self.policy)
                record.log_trial(phase, trial, global_trial, epsilon, stats, rate, room=label, agents=room.num_agents,
                                 per_room=bool(self.mix), walking=walking)  # fmt: skip
                record.logger.log_spread(global_trial, "losses/q_loss", driver.loss.double())
                record.logger.log_scalars(global_trial, {"dqn/gradient_steps": self.update.updates,
                                                         "dqn/replay_size": self.buffer.size})  # fmt: skip
                global_trial += 1
                bar.set_postfix(success=f"{stats.success_rate.mean():.2f}", eps=f"{epsilon:.3f}")
                done = trial + 1 == phase.trials
                if done or (self.checkpoint_every and (trial + 1) % self.checkpoint_every == 0):
                    self._save(record, phase, trial + 1, global_trial, stats, iteration=done)
            bar.close()
            if self.progress and not interactive():
                report_phase(description, phase.trials - first, tic, stats)
            record.logger.flush()
        return stats

    @staticmethod
    def _check_finite(phase: Phase, trial: int, stats, loss: torch.Tensor) -> None:
        if not (bool(torch.isfinite(stats.episodic_return).all()) and bool(torch.isfinite(loss).all())):
            raise ValueError(
                f"iteration {phase.index}, trial {trial}: the returns or the loss turned inf or NaN: lower "
                "algo.learning_rate or algo.reward_scale"
            )

    def _save(self, record: RunRecord, phase: Phase, trial: int, global_trial: int, stats, *, iteration: bool) -> None:
        """Write the checkpoint after ``trial`` trials of ``phase`` (everything a resume needs, the memory included)."""
        tensors = {
            **self.policy.tensors(),
            **self.update.tensors(),
            **self.buffer.tensors(),
            "rng/trainer": self.generator.get_state(),
            "rng/env": self.env.generator.get_state(),
        }
        metadata = {
            "algo": self.name,
            "iteration": phase.index,
            "trial": trial,
            "phase_complete": trial >= phase.trials,
            "agents": phase.num_agents,
            "global_trial": global_trial,
            "updates": self.update.updates,
            "decisions": self.update.decisions,
            "distortion": math.nan,
            "summaries": [self.summary],
            "encoder": self.encoder_settings.to_metadata(),
            "final": final_figures(stats) if stats is not None else {},
            "trial_path": self.path,
        }
        record.save(tensors, metadata, phase, iteration=iteration)


def _decisions_on(bar: tqdm) -> Callable[[int, int], None] | None:
    """A trial's progress callback that shows its decisions and the agents left on ``bar`` about once a second (a
    trial of many gradient steps is long); None where the bar is off."""
    if bar.disable:
        return None
    shown_at = [time.monotonic()]

    def show(decisions: int, left: int) -> None:
        if time.monotonic() - shown_at[0] >= 1.0:
            shown_at[0] = time.monotonic()
            bar.set_postfix(decision=decisions, agents_left=left)

    return show


def _check_settings(settings: Mapping[str, Any]) -> None:
    """One line for the first of a DQN's ``settings`` (its constructor's arguments) that is out of range."""
    check_trials_per_iteration(settings["trials"], settings["iterations"], maximum=MAX_TRIALS)
    for key in ("num_agents", "train_every", "target_every", "processes", "rooms_per_process"):
        check_integer(key, settings[key], minimum=1)
    check_integer("gather_trials", settings["gather_trials"], minimum=1, maximum=MAX_TRIALS)
    check_integer("gradient_steps", settings["gradient_steps"], minimum=1, maximum=MAX_GRADIENT_STEPS)
    check_hidden(settings["hidden"])
    head_outputs(settings["head"], NUM_ACTIONS)
    check_number("learning_rate", settings["learning_rate"], low=0.0, high=1.0, low_open=True)
    check_number("gamma", settings["gamma"], low=0.0, high=1.0)
    check_integer("n_step", settings["n_step"], minimum=1, maximum=MAX_N_STEP)
    check_integer("batch_size", settings["batch_size"], minimum=1, maximum=MAX_BATCH)
    check_integer("buffer_size", settings["buffer_size"], minimum=settings["batch_size"])
    check_integer("learning_starts", settings["learning_starts"], minimum=0, maximum=settings["buffer_size"])
    check_choice("replay_balance", settings["replay_balance"], REPLAY_BALANCES)
    check_number("reward_scale", settings["reward_scale"], low=0.0, low_open=True, high=1e6)
    check_number("max_grad_norm", settings["max_grad_norm"], low=0.0, low_open=True, high=1e9)
    check_epsilons(settings["epsilon_start"], settings["epsilon_end"])
    check_number("epsilon_decay_fraction", settings["epsilon_decay_fraction"], low=0.0, high=1.0, low_open=True)
    check_integer("checkpoint_every", settings["checkpoint_every"], minimum=0)
    check_bool("neighbour_velocity", settings["neighbour_velocity"])
    check_bool("progress", settings["progress"])
    check_bool("logger.tensorboard", settings["tensorboard"])

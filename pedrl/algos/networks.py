"""The learners of one network per learning process (the DQN, PPO): what they share on the learning run.

A :class:`NetworkRun` is a :class:`pedrl.algos.run.LearningRun` whose run is ``trials`` trials in ``iterations``
blocks (each ending with a checkpoint ``iter_XXXX``) of ``num_agents`` agents in the run's room and its ``mix``, over
the inputs of :class:`pedrl.rl.NeuralPolicy` (the deictic state as the tables' quantizer sees it, standardised by a
random walk, :func:`random_walk_standardisation`). It owns the set-up, the blocks, the start-or-resume of the run and
the checks of a checkpoint's network and progress; a learner adds its settings record (``settings_class``), its
``start`` (the networks, the update), ``restore_tensors`` (what else a checkpoint holds), ``epsilon``, and the
trial hooks of the base.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Final

import torch
from tqdm.auto import tqdm

from pedrl.algos.phase import MAX_TRIALS, Phase
from pedrl.algos.records import RunRecord
from pedrl.algos.run import LearningRun, RunSpec, open_resume
from pedrl.common.checks import check_bool, check_integer, check_number, check_trials_per_iteration
from pedrl.io import CheckpointError
from pedrl.policy_files import RNG_KEYS, check_rng_state
from pedrl.rl.network import QNetwork, check_hidden
from pedrl.rl.neural import NeuralPolicy, input_width
from pedrl.rl.policy import POLICY_READERS
from pedrl.sim import RoomEnv
from pedrl.trial.rollout import TrialStats, gather
from pedrl.vq.encoder import EncoderSettings, StateEncoder

MIN_STD: Final = 1e-3
"""A feature whose spread on the random walk is below this (a constant) is standardised by 1 instead."""


@dataclass(frozen=True)
class NetworkConfig:
    """The ``algo`` keys every network learner has (its record, ``settings_class``, derives from this one and checks
    its own keys after these), every value checked when the record is made.

    Attributes:
        num_agents: learning agents per room.
        trials: total learning trials.
        iterations: blocks the trials are split into, each ending with a checkpoint ``iter_XXXX``.
        gather_trials: random-walk trials whose states standardise the inputs.
        hidden: widths of the hidden layers.
        neighbour_velocity: the network also reads each sensed neighbour's velocity in the goal frame (beside the
            28 features, which give only its closing speed: :mod:`pedrl.sim.sensing`).
        learning_rate: Adam's step size.
        gamma: discount.
        reward_scale: rewards are multiplied by this before they are learned (values in these units).
        max_grad_norm: each process's gradient is clipped to this norm.
    """

    num_agents: int = 20
    trials: int = 200
    iterations: int = 1
    gather_trials: int = 2
    hidden: Sequence[int] = (256, 256)
    neighbour_velocity: bool = False
    learning_rate: float = 5e-4
    gamma: float = 0.91
    reward_scale: float = 0.1
    max_grad_norm: float = 10.0

    def __post_init__(self) -> None:
        check_trials_per_iteration(self.trials, self.iterations, maximum=MAX_TRIALS)
        check_integer("num_agents", self.num_agents, minimum=1)
        check_integer("gather_trials", self.gather_trials, minimum=1, maximum=MAX_TRIALS)
        object.__setattr__(self, "hidden", check_hidden(self.hidden))
        check_bool("neighbour_velocity", self.neighbour_velocity)
        check_number("learning_rate", self.learning_rate, low=0.0, high=1.0, low_open=True)
        check_number("gamma", self.gamma, low=0.0, high=1.0)
        check_number("reward_scale", self.reward_scale, low=0.0, low_open=True, high=1e6)
        check_number("max_grad_norm", self.max_grad_norm, low=0.0, low_open=True, high=1e9)


@dataclass
class ResumedNetwork:
    """A checked checkpoint of a :class:`NetworkRun`: where the run stands, its policy, and the learner's own state
    (``state``: its update, its memory, as :meth:`NetworkRun.restore_tensors` gives them)."""

    global_trial: int
    done: bool
    policy: NeuralPolicy
    state: dict[str, Any]
    rng_trainer: torch.Tensor
    rng_env: torch.Tensor
    wall_time_s: float
    final: dict[str, float]
    summaries: list[dict[str, Any]]


class NetworkRun(LearningRun):
    """The base of the network learners (module docstring).

    Args:
        run: what the run is (of ``run.vq`` only ``distance_transform`` is read: the inputs are the states as the
            tables' quantizer sees them).
        **settings: the keys of the learner's ``settings_class`` (a :class:`NetworkConfig`).
    """

    phase_word = "iteration"
    settings_class: ClassVar[type[NetworkConfig]]
    policy_class: type[NeuralPolicy] = NeuralPolicy
    """The class of the learned policy (its ``learner`` is the run's)."""

    @property
    def learner(self) -> str:  # type: ignore[override]
        """The learner of the run's policy: its class's (``neural``, or ``continuous``)."""
        return self.policy_class.learner

    def __init__(self, run: RunSpec, **settings: Any) -> None:
        if run.vq.factors is not None:  # a table's key
            raise ValueError(
                f"vq.factors is invalid with algo={self.name}: a network reads the whole state (of the vq group it "
                "reads distance_transform only); use algo=vqql or algo=it_vqql for a factored table"
            )
        algo = self.settings_class(**settings)
        super().__init__(run)
        self.algo = algo
        self.num_agents, self.trials, self.iterations, self.gather_trials = (
            algo.num_agents,
            algo.trials,
            algo.iterations,
            algo.gather_trials,
        )
        self.hidden, self.neighbour_velocity = algo.hidden, algo.neighbour_velocity
        self.env = self.env_factory(num_replicas=run.replicas, num_agents=algo.num_agents, device=self.device)
        self.log_walking(algo.trials, self.env)
        self.path, _ = self.trial_path()  # fused=true refused before any compute
        self.encoder_settings = EncoderSettings.for_room(
            self.env, distance_transform=self.vq.distance_transform
        ).spanning(self.mix)
        self.width = input_width(self.encoder_settings, neighbour_velocity=algo.neighbour_velocity)
        self.summary: dict[str, Any] = {}

    # ------------------------------------------------------------------ what a network learner defines
    def start(self) -> None:
        """A new run: standardise by a random walk, build the networks and the update (and the memory)."""
        raise NotImplementedError

    def network_shape(self) -> tuple[tuple[int, ...], str]:
        """The widths and the head the config makes of the policy's network."""
        return (self.width, *self.hidden, self.env.num_actions), "joint"

    def restore_tensors(self, policy: NeuralPolicy, tensors: dict[str, torch.Tensor], meta: dict[str, Any]):
        """The learner's own state from a checkpoint's ``tensors`` and ``meta`` (one-line ``ValueError``), as a
        mapping of attribute names to values (set on the learner when the run continues)."""
        raise NotImplementedError

    def epsilon(self, global_trial: int) -> float:
        """The exploration rate of the run's ``global_trial``-th trial."""
        raise NotImplementedError

    # ------------------------------------------------------------------ the run's hooks
    def phases(self) -> list[Phase]:
        """The iterations: equal blocks of the trials (the first ones a trial longer when they do not divide)."""
        block, extra = divmod(self.trials, self.iterations)
        return [
            Phase(i + 1, self.num_agents, block + (1 if i < extra else 0), self.gather_trials, 1.0)
            for i in range(self.iterations)
        ]

    def own_rooms(self) -> list[RoomEnv]:
        return [self.env]

    def summaries(self) -> list[dict[str, Any]]:
        return [self.summary]

    def make_policy(self, network: QNetwork, mean: torch.Tensor, std: torch.Tensor) -> NeuralPolicy:
        """The run's policy over ``network`` (its rooms ``p E .. p E + E - 1`` act with process ``p``'s network)."""
        return self.policy_class(StateEncoder(self.encoder_settings), network, mean, std,
                                 rooms_per_process=self.rooms_per_process,
                                 neighbour_velocity=self.neighbour_velocity)  # fmt: skip

    def learn(self, record: RunRecord, resumed: ResumedNetwork | None) -> TrialStats | None:
        """Start (gather, standardise, build) or continue ``resumed``, then the iterations' trials from there on."""
        if resumed is None:
            self.start()
            record.logger.log_scalars(0, {f"{self.name}/{key}": value for key, value in self.summary.items()})
        else:
            self.policy = resumed.policy
            for name, value in resumed.state.items():
                setattr(self, name, value)
            self.generator.set_state(resumed.rng_trainer)
            self.env.generator.set_state(resumed.rng_env)
        start = resumed.global_trial if resumed is not None else 0
        stats, global_trial = None, 0
        rooms = self.rooms(self.env)
        for phase in self.phases():
            first = min(phase.trials, max(0, start - global_trial))  # trials of the phase done before the resume
            global_trial += first
            if first == phase.trials:
                continue
            schedule = lambda _, at: self.epsilon(at)  # noqa: E731
            stats, global_trial = self.run_trials(phase, rooms, first, global_trial, record, epsilon=schedule,
                                                  policy=self.policy)  # fmt: skip
            record.logger.flush()
        return stats

    def resume(self, path: str | Path) -> ResumedNetwork:
        """The checkpoint ``path`` checked (:func:`pedrl.algos.run.open_resume`, then its progress, its network
        against the config's, the learner's own tensors and the generators).

        Raises:
            CheckpointError: one line naming the file and what is wrong.
        """
        checkpoint = open_resume(self, path)
        meta, where = checkpoint.metadata, f"checkpoint {str(path)!r}"
        try:
            global_trial, done = trial_progress(self, meta)
            tensors = checkpoint.tensors
            read = POLICY_READERS[self.learner]
            policy = read(self.encoder_settings, tensors, num_actions=self.env.num_actions)
            widths, head = self.network_shape()
            if (policy.num_processes, policy.network.widths) != (self.processes, widths):
                raise ValueError(
                    f"the network is {policy.num_processes} x {list(policy.network.widths)}: the config makes "
                    f"{self.processes} x {list(widths)}"
                )
            if policy.network.head != head:
                raise ValueError(f"the network's head is {policy.network.head}: the config makes {head}")
            policy = self.make_policy(policy.network, policy.mean, policy.std)
            policy.network.requires_grad_(True)
            state = self.restore_tensors(policy, tensors, meta)
            rng = [check_rng_state(name, tensors[name]) if name in tensors else missing_tensor(name)
                   for name in RNG_KEYS]  # fmt: skip
        except ValueError as err:
            raise CheckpointError(f"{where}: {err}") from None
        summaries = meta.get("summaries") or [{}]
        self.summary = dict(summaries[0]) if isinstance(summaries[0], dict) else {}
        final = {key: float(value) for key, value in (meta.get("final") or {}).items()}
        return ResumedNetwork(global_trial, done, policy, state, rng[0], rng[1], float(meta.get("wall_time_s", 0.0)),
                              final, [self.summary])  # fmt: skip


def random_walk_standardisation(learner: NetworkRun) -> tuple[torch.Tensor, torch.Tensor, dict[str, Any]]:
    """A network learner's start: seed its generators from its run's seed, record the states of ``gather_trials``
    random-walk trials in each of its rooms, and return their mean and standard deviation ``(F,)`` (1 where a feature
    is constant), which standardise the network's inputs, with the summary of the walk."""
    learner.generator.manual_seed(learner.seed * 10_007 + 1)
    learner.env.reset(seed=learner.seed * 10_007 + 2)
    encoder = StateEncoder(learner.encoder_settings)
    gathered = [
        gather(room, encoder, None, trials=learner.gather_trials, epsilon=1.0, processes=learner.processes,
               generator=learner.generator)
        for _, room in learner.rooms(learner.env)
    ]  # fmt: skip
    states = torch.cat([part.states for part in gathered])
    mean, std = states.mean(0), states.std(0)
    std = torch.where(std < MIN_STD, 1.0, std)
    summary = {"gathered_states": int(states.shape[0]),
               "gather_success_rate": sum(p.success_rate for p in gathered) / len(gathered)}  # fmt: skip
    return mean.float().contiguous(), std.float().contiguous(), summary


def trial_progress(learner: NetworkRun, meta: dict[str, Any]) -> tuple[int, bool]:
    """The checkpoint's global trial (checked against its iteration and trial) and whether the run is done."""
    phases = learner.phases()
    iteration, trial = meta.get("iteration"), meta.get("trial")
    indices = [phase.index for phase in phases]
    if isinstance(iteration, bool) or iteration not in indices:
        raise ValueError(f"metadata iteration={iteration!r} is invalid: must be one of {indices}")
    phase = phases[iteration - 1]
    if isinstance(trial, bool) or not isinstance(trial, int) or not 1 <= trial <= phase.trials:
        raise ValueError(f"metadata trial={trial!r} is invalid: must be an integer in [1, {phase.trials}]")
    global_trial = sum(p.trials for p in phases[: iteration - 1]) + trial
    if meta.get("global_trial") != global_trial:
        raise ValueError(f"metadata global_trial={meta.get('global_trial')!r} is invalid: must be {global_trial}")
    return global_trial, global_trial == learner.trials


def checked_count(meta: dict[str, Any], key: str) -> int:
    """The metadata's count ``key``, an integer >= 0 (one line otherwise)."""
    value = meta.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"metadata {key}={value!r} is invalid: must be an integer >= 0")
    return value


def missing_tensor(name: str) -> torch.Tensor:
    raise ValueError(f"tensor {name} is missing")


def decisions_on(bar: tqdm) -> Callable[[int, int], None] | None:
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

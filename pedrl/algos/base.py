"""The machinery shared by VQQL, IT-VQQL and IN-VQQL.

Every algorithm of the paper is a sequence of *phases* (an IT-VQQL iteration, an IN-VQQL stage, or the single
VQQL run). A phase reads top to bottom as:

1. gather states from the room, following the previous phase's policy (or a random walk),
2. fit a vector quantizer on them (k-means over standardised states),
3. learn Q tables from scratch over its prototypes, trial after trial,
4. log the learning curve and write a checkpoint.

Subclasses say what the phases are and how states are quantized; this class does the rest once, on the run every
learner shares (:mod:`pedrl.algos.run`: the rooms, the trial loop, the logs, the checkpoints and resume).

All ``R`` learning processes (the paper averages 20) run in lock-step in one tensor program: process ``r`` owns
the tables ``q_values[r]`` and ``E = rooms_per_process`` rooms whose agents all learn into them. With the
default ``E = 1`` this is the paper's setting; ``E > 1`` gives each table ``E`` times more experience per
decision (and larger tensor batches), at the price of learning from several rooms at once.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from tqdm.auto import tqdm

from pedrl.algos.budget import check_gathering_yield, memory_needs
from pedrl.algos.fitting import (
    factored_problem,
    feature_weights,
    fit_factored_quantizer,
    fit_plain_quantizer,
    fit_quantizers,
)
from pedrl.algos.mix import merge_gathered
from pedrl.algos.phase import Phase
from pedrl.algos.records import RunRecord
from pedrl.algos.restore import RestoredState, restore_state
from pedrl.algos.run import LearningRun, RunSpec, open_resume
from pedrl.common.checks import check_choice, check_epsilons, check_memory, check_number
from pedrl.rl import LinearSchedule, zeros_q_values
from pedrl.rl.policy import TABLE_LEARNER, TabularPolicy
from pedrl.sim import RoomEnv
from pedrl.trial.crowd import run_crowd
from pedrl.trial.loop import Learner
from pedrl.trial.rollout import Gathered, TrialStats, check_finite, gather
from pedrl.vq import Quantizer
from pedrl.vq.encoder import VOID_DRAWS, VOID_FEATURES, EncoderSettings, StateEncoder
from pedrl.vq.factored import check_factor_slots

TABLES = ("agent", "process")
"""Values of ``algo.tables``: one Q table per learning agent (the paper), or one per process shared by its agents."""


class Trainer(LearningRun):
    """Base class of the paper's trainers: a :class:`pedrl.algos.run.LearningRun` whose phases each fit a quantizer
    and learn tables over it.

    Args:
        run: what the run is (rooms, processes, device, seed, folder, checkpoints, logging).
        alpha: learning rate of equation 1.
        gamma: discount of equation 1.
        epsilon_start: initial exploration rate (Table 3: 0.4).
        epsilon_end: final exploration rate.
        epsilon_decay_fraction: fraction of a phase's trials over which epsilon decays linearly to ``epsilon_end``.
        void_features: how empty neighbour slots are quantized: ``"zero"`` (left at 0) or ``"random"``
            (filled with random valid values, paper section 5.1).
        void_draws: when the random filling is drawn: ``"trial"`` (once per agent and trial) or ``"decision"``
            (at every encode).
        tables: ``"agent"`` (the paper's independent learners: one table per learning agent, ``A = N``) or
            ``"process"`` (one table per learning process, shared by all its agents, ``A = 1``: N times more
            experience per table and entry; evaluation then drives every agent with it).

    Phase ``i`` seeds its generators from ``(run.seed, i)``.
    """

    name = "base"
    learner = TABLE_LEARNER

    def __init__(
        self,
        run: RunSpec,
        *,
        alpha: float = 0.35,
        gamma: float = 0.91,
        epsilon_start: float = 0.4,
        epsilon_end: float = 0.1,
        epsilon_decay_fraction: float = 0.5,
        void_features: str = "zero",
        void_draws: str = "trial",
        tables: str = "process",
    ) -> None:
        super().__init__(run)
        check_number("alpha", alpha, low=0.0, high=1.0, low_open=True)
        check_number("gamma", gamma, low=0.0, high=1.0)
        check_epsilons(epsilon_start, epsilon_end)
        check_number("epsilon_decay_fraction", epsilon_decay_fraction, low=0.0, high=1.0, low_open=True)
        check_choice("void_features", void_features, VOID_FEATURES)
        check_choice("void_draws", void_draws, VOID_DRAWS)
        check_choice("tables", tables, TABLES)
        self.tables = tables
        self.alpha, self.gamma, self.epsilon_decay_fraction = alpha, gamma, epsilon_decay_fraction
        self.epsilon_start, self.epsilon_end = epsilon_start, epsilon_end
        self._envs: dict[int, RoomEnv] = {}
        for num_agents in sorted({phase.num_agents for phase in self.phases()}):
            self.env_for(num_agents)  # validates the phases and the room parameters before any compute
        self.feature_weights()  # validates the neighbour weights before any compute
        room = next(iter(self._envs.values()))
        self.trial_path()  # fused=true refused before any compute
        self.encoder_settings = EncoderSettings.for_room(
            room,
            void_features=void_features,
            void_draws=void_draws,
            distance_transform=self.vq.distance_transform,
        ).spanning(self.mix)
        settings = self.encoder_settings
        check_factor_slots(self.vq.factor_specs, num_neighbours=settings.num_neighbours, num_walls=settings.num_walls)
        check_memory(
            memory_needs(self),
            device=self.device,
            advice="lower processes, rooms_per_process, vq.num_prototypes, vq.max_states, the agents, "
            "algo.gather_trials or env.max_decisions",
        )
        check_gathering_yield(self)
        self.log_walking(sum(p.trials for p in self.phases()), room)
        self._summaries: list[dict[str, Any]] = []

    # ------------------------------------------------------------------ what subclasses define
    def phases(self) -> list[Phase]:
        """The phases of the algorithm, in order."""
        raise NotImplementedError

    def fit_quantizer(
        self,
        phase: Phase,
        states: torch.Tensor,
        num_sensed: torch.Tensor,
        previous: Any | None,
        num_prototypes: int | None = None,
    ) -> tuple[Any, float]:
        """Fit this phase's quantizer on gathered ``states (M, F)`` with ``num_sensed (M,)`` neighbours.

        ``previous`` is the previous phase's quantizer (None in the first phase). ``num_prototypes`` is the number
        of prototypes the fit adds (None: ``vq.num_prototypes``; k-means keeps fewer when the states hold fewer
        distinct ones). The default fits one :class:`pedrl.vq.Quantizer` over the full states (VQQL, IT-VQQL), or
        with ``vq.factors`` a :class:`pedrl.vq.FactoredQuantizer` (each factor on its slots of the states).

        Returns:
            The quantizer (anything with ``encode``, ``num_prototypes`` and ``state_dict``) and the final
            distortion (mean squared distance to the nearest prototype, standardised units).
        """
        if self.vq.factor_specs is None:
            return self.fit_plain_quantizer(states, num_prototypes=num_prototypes)
        return fit_factored_quantizer(states, num_sensed, self.vq, self.encoder_settings, self.generator)

    def kept_prototypes(self, previous: Any | None) -> int:
        """Prototypes of the previous phase's quantizer ``previous`` that this phase's quantizer keeps besides those
        its fit adds: none by default (each phase fits a new quantizer); IN-VQQL's union keeps them all."""
        return 0

    def check_quantizer(self, part: Any, position: int) -> str | None:
        """Why ``part`` (a process's quantizer, or the shared one, read from a checkpoint of the phase at
        ``position``) cannot be this trainer's, or None. The default expects a :class:`pedrl.vq.Quantizer` over the
        full state with at most ``vq.num_prototypes`` prototypes (k-means keeps fewer when the data has fewer
        distinct states)."""
        features = self.encoder_settings.num_features
        if self.vq.factor_specs is not None:
            return factored_problem(part, self.vq)
        if not isinstance(part, Quantizer):
            return f"is a {type(part).__name__}: must be a Quantizer"
        if part.dim != features or not 1 <= part.num_prototypes <= self.vq.num_prototypes:
            return (
                f"has {part.num_prototypes} prototypes of {part.dim} features: must have 1 to "
                f"vq.num_prototypes={self.vq.num_prototypes} prototypes of {features} features"
            )
        return None

    def epsilon_schedule(self, phase: Phase) -> Callable[[int], float]:
        """Exploration rate at each trial of ``phase``: linear from ``epsilon_start`` to ``epsilon_end`` over
        ``epsilon_decay_fraction`` of the phase's trials, then constant (every phase learns from scratch)."""
        return LinearSchedule(
            start=self.epsilon_start,
            end=self.epsilon_end,
            decay_trials=max(1, round(self.epsilon_decay_fraction * phase.trials)),
        )

    def num_tables(self, phase: Phase) -> int:
        """A, the Q tables per process in ``phase``: one per agent, or one shared (``tables``)."""
        return phase.num_agents if self.tables == "agent" else 1

    def max_prototypes(self, phase: Phase) -> int:
        """Most states of the quantizer of ``phase`` (its tables' K): ``vq.num_prototypes`` (or the factors'
        together) unless it grows."""
        return self.vq.table_states

    def continues_previous(self, phase: Phase) -> bool:
        """True when ``phase`` keeps the previous phase's quantizer and tables instead of starting afresh."""
        return False

    def initial_q_values(
        self, phase: Phase, quantizer: Any, previous: tuple[Any, torch.Tensor] | None, num_actions: int
    ) -> torch.Tensor:
        """The tables ``(P, A, K, U)`` a phase that fitted ``quantizer`` starts learning from: zeros (the paper: no
        transfer between phases)."""
        return zeros_q_values(
            self.processes, self.num_tables(phase), quantizer.num_prototypes, num_actions, device=self.device
        )

    def gather_tables(self, phase: Phase, previous: tuple[Any, torch.Tensor] | None):
        """The (quantizer, q_values) followed while gathering phase ``phase``'s states, or None: a random walk (the
        default; IT-VQQL follows the previous iteration's tables, IN-VQQL the previous stage's replicated)."""
        return None

    # ------------------------------------------------------------------ the run's hooks
    def own_rooms(self) -> list[RoomEnv]:
        return list(self._envs.values())

    def resume(self, path: str | Path) -> RestoredState:
        return restore_state(self, open_resume(self, path))

    def summaries(self) -> list[dict[str, Any]]:
        return self._summaries

    def learn(self, record: RunRecord, resumed: RestoredState | None) -> TrialStats | None:
        """Every phase from the first or from ``resumed`` on: its quantizer and tables (resumed mid-phase,
        continued, or gathered and fitted anew), then its trials in turn in every room."""
        phases = self.phases()
        start, first_trial, previous, distortion = 0, 0, None, math.nan
        if resumed is not None:
            start = resumed.position + 1 if resumed.phase_complete else resumed.position
            first_trial = 0 if resumed.phase_complete else resumed.trial
            previous = (resumed.quantizer, resumed.q_values) if resumed.phase_complete else None
            distortion = resumed.distortion
        global_trial = resumed.global_trial if resumed is not None else 0
        self._summaries = list(resumed.summaries) if resumed is not None else []
        stats: TrialStats | None = None
        for position in range(start, len(phases)):
            phase = phases[position]
            env = self.env_for(phase.num_agents)
            if position == start and first_trial > 0:
                quantizer, q_values = resumed.quantizer, resumed.q_values
                self.generator.set_state(resumed.rng_trainer)
                env.generator.set_state(resumed.rng_env)
            else:
                first_trial = 0
                self._seed_phase(phase, env)
                if not (self.continues_previous(phase) and previous is not None):
                    quantizer, q_values, distortion = self._new_tables(phase, env, previous, record, global_trial)
                else:
                    quantizer, q_values = previous
            self._tables, self._distortion = (quantizer, q_values), distortion
            self._policy = self.policy(quantizer, q_values)
            schedule = self.epsilon_schedule(phase)
            stats, global_trial = self.run_trials(
                phase,
                self.rooms(env),
                first_trial,
                global_trial,
                record,
                epsilon=lambda trial, _, at=schedule: at(trial),
                policy=self._policy,
            )
            previous = (quantizer, q_values)
            record.logger.flush()
        return stats

    def learn_trial(self, env: RoomEnv, room: int, epsilon: float, bar: tqdm) -> TrialStats:
        return self._trial(env, self._policy, epsilon=epsilon, learn=True)

    def check_trial(self, phase: Phase, trial: int, stats: TrialStats) -> None:
        check_finite(phase.index, trial, stats, self._policy.q_values, last=trial + 1 == phase.trials)

    def state_tensors(self) -> dict[str, torch.Tensor]:
        return self.policy(*self._tables).tensors()

    def state_metadata(self, global_trial: int) -> dict[str, Any]:
        return {"distortion": self._distortion}

    def _new_tables(self, phase, env, previous, record, global_trial) -> tuple[Any, torch.Tensor, float]:
        """Gather the phase's states (following the previous tables, or a random walk), fit its quantizer, and make
        its first tables; the phase's summary goes to the run's summaries and TensorBoard (at ``global_trial``, the
        phase's first)."""
        gathered = self.gather(phase, env, previous)
        quantizer, distortion = self.fit_quantizers(phase, gathered, previous[0] if previous else None)
        q_values = self.initial_q_values(phase, quantizer, previous, env.num_actions)
        self._summaries.append(
            record.log_phase(phase, global_trial, gathered, quantizer.num_prototypes, distortion, q_values)
        )
        return quantizer, q_values, distortion

    # ------------------------------------------------------------------ the parts of a phase
    def gather(self, phase: Phase, env: RoomEnv, previous: tuple[Any, torch.Tensor] | None) -> Gathered:
        """Record the states visited in ``phase.gather_trials`` trials, following :meth:`gather_tables` (or a random
        walk) with exploration ``phase.gather_epsilon``."""
        tables = self.gather_tables(phase, previous)
        policy = self.policy(*tables) if tables is not None else None
        encoder = StateEncoder(self.encoder_settings)
        settings = dict(trials=phase.gather_trials, epsilon=phase.gather_epsilon, processes=self.processes)
        return merge_gathered(
            [gather(room, encoder, policy, **settings, generator=self.generator) for _, room in self.rooms(env)]
        )

    def fit_quantizers(self, phase: Phase, gathered: Gathered, previous: Any | None) -> tuple[Any, float]:
        """The phase's quantizer (one per process, or shared; :func:`pedrl.algos.fitting.fit_quantizers`), each part
        fitted by :meth:`fit_quantizer`, and its mean distortion."""
        return fit_quantizers(
            phase,
            gathered,
            previous,
            lambda states, num_sensed, part, count: self.fit_quantizer(phase, states, num_sensed, part, count),
            vq=self.vq,
            processes=self.processes,
            kept=self.kept_prototypes(previous),
            generator=self.generator,
        )

    def fit_plain_quantizer(
        self, states: torch.Tensor, feature_index: torch.Tensor | None = None, *, num_prototypes: int | None = None
    ) -> tuple[Quantizer, float]:
        """One :class:`pedrl.vq.Quantizer` on ``states (M, F)`` (``feature_index``: the features of a projection)."""
        return fit_plain_quantizer(states, self.vq, self.feature_weights(feature_index), self.generator, num_prototypes)

    def feature_weights(self, feature_index: torch.Tensor | None = None) -> torch.Tensor:
        """Per-feature weights ``(F,)`` (or of the features ``feature_index`` selects) from the ``vq`` settings."""
        room = next(iter(self._envs.values()))
        return feature_weights(self.vq, room.params.num_neighbours, room.num_features, self.device, feature_index)

    def policy(self, quantizer: Any, q_values: torch.Tensor) -> TabularPolicy:
        """The tables ``q_values (P, A, K, U)`` over ``quantizer`` as a policy of this trainer's rooms (rooms
        ``p E .. p E + E - 1`` act with process ``p``'s tables)."""
        encoder = StateEncoder(self.encoder_settings, quantizer)
        return TabularPolicy(encoder, q_values, rooms_per_process=self.rooms_per_process)

    def run_trial(
        self, env: RoomEnv, quantizer: Any, q_values: torch.Tensor, *, epsilon: float, learn: bool
    ) -> TrialStats:
        """One trial in every room with the tables ``q_values`` over ``quantizer`` (:meth:`_trial`)."""
        return self._trial(env, self.policy(quantizer, q_values), epsilon=epsilon, learn=learn)

    def _trial(self, env: RoomEnv, policy: TabularPolicy, *, epsilon: float, learn: bool) -> TrialStats:
        """A :class:`~pedrl.trial.loop.Learner`'s trial with this trainer's generator and equation 1's constants, on
        the path ``fused`` chooses (:func:`pedrl.trial.crowd.run_crowd`)."""
        learner = Learner(
            policy, epsilon=epsilon, generator=self.generator, learn=learn, alpha=self.alpha, gamma=self.gamma
        )
        return run_crowd(env, learner, fused=self.fused).stats

    def env_for(self, num_agents: int) -> RoomEnv:
        """The trainer's ``P E`` rooms with ``num_agents`` agents (built once)."""
        if num_agents not in self._envs:
            self._envs[num_agents] = self.env_factory(
                num_replicas=self.processes * self.rooms_per_process,
                num_agents=num_agents,
                device=self.device,
            )
        return self._envs[num_agents]

    # ------------------------------------------------------------------ bookkeeping
    def _seed_phase(self, phase: Phase, env: RoomEnv) -> None:
        phase_seed = self.seed * 10_007 + phase.index
        self.generator.manual_seed(phase_seed)
        env.reset(seed=phase_seed + 1)

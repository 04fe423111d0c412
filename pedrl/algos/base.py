"""The machinery shared by VQQL, IT-VQQL and IN-VQQL.

Every algorithm of the paper is a sequence of *phases* (an IT-VQQL iteration, an IN-VQQL stage, or the single
VQQL run). A phase reads top to bottom as:

1. gather states from the room, following the previous phase's policy (or a random walk),
2. fit a vector quantizer on them (k-means over standardised states),
3. learn Q tables from scratch over its prototypes, trial after trial,
4. log the learning curve and write a checkpoint.

Subclasses say what the phases are and how states are quantized; this class does the rest once.

All ``R`` learning processes (the paper averages 20) run in lock-step in one tensor program: process ``r`` owns
the tables ``q_values[r]`` and ``E = rooms_per_process`` rooms whose agents all learn into them. With the
default ``E = 1`` this is the paper's setting; ``E > 1`` gives each table ``E`` times more experience per
decision (and larger tensor batches), at the price of learning from several rooms at once.
"""

from __future__ import annotations

import json
import math
import sys
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import torch
from tqdm.auto import tqdm

from pedrl.algos.restore import RestoredState, check_stored_config, restore_state
from pedrl.io import CheckpointError, CsvWriter, RunLogger, load_checkpoint, save_checkpoint
from pedrl.io.files import remove_temporaries_in
from pedrl.notices import warn
from pedrl.rl import LinearSchedule, epsilon_greedy, table_rows, td_update, zeros_q_values
from pedrl.sim import RoomEnv
from pedrl.sim.checks import check_bool, check_choice, check_device, check_integer, check_memory, check_number
from pedrl.sim.sensing import distance_indices, fill_void_neighbours, void_draws
from pedrl.vq import ProcessQuantizers, Quantizer
from pedrl.vq.kmeans import default_chunk_size

TABLES = ("agent", "process")
"""Values of ``algo.tables``: one Q table per learning agent (the paper), or one per process shared by its agents."""
MAX_TRIALS = 10**9
"""Most learning trials of one phase: years of compute at the fastest measured rates; more is a typo (or a
``trials_growth`` that overflows)."""
TABLE_COPIES = 2
"""Q tables alive at once in the memory estimate: the phase's and the previous phase's (followed while gathering,
through a replication to the new agents in IN-VQQL that is freed before the new tables are made)."""
GATHER_COPIES = 3
"""Copies of every gathered state in the memory estimate: as recorded, concatenated, and prepared for k-means."""
KMEANS_COPIES = 4
"""Copies of the states one k-means fit holds: subsampled, standardised, weighted, and their nearest distances."""
KMEANS_INITS = ("kmeans++", "random")
"""Values of ``vq.init``: k-means++ seeding or K random states (see :func:`pedrl.vq.kmeans`)."""
_KMEANS_SHRINK = "k-means: the data has only"
"""Start of k-means' own warning when it keeps fewer prototypes; the trainers say it once, in their words."""
CURVE_METRICS = ("success_rate", "episodic_return", "crashes_agent", "crashes_wall", "mean_speed", "td_error")
DEVICE_CHECK_EVERY = 8
"""Decisions between two reads of "is any room still occupied" by the trial loop on a GPU (each read waits)."""
_TOTALS = ("return", "crashes_agent", "crashes_wall", "reached", "speed_sum", "decisions")
"""Per-agent totals a trial accumulates, in the order of the rows of ``run_trial``'s accumulator."""
CURVE_COLUMNS = (
    "phase",
    "agents",
    "trial",
    "global_trial",
    "epsilon",
    *(f"{m}_{s}" for m in CURVE_METRICS for s in ("mean", "std")),
    "decisions_per_s",
)


@dataclass(frozen=True)
class Phase:
    """One iteration (IT-VQQL), stage (IN-VQQL) or the single VQQL run.

    Attributes:
        index: 1-based phase number, as in the paper's figures.
        num_agents: agents in the room, all of them learning.
        trials: learning trials of this phase.
        gather_trials: trials run to gather the quantizer's training states.
        gather_epsilon: exploration rate while gathering (1.0 is a random walk).
    """

    index: int
    num_agents: int
    trials: int
    gather_trials: int
    gather_epsilon: float


@dataclass(frozen=True)
class VQSettings:
    """How quantizers are fitted (the ``vq`` config group).

    Attributes:
        num_prototypes: K, the number of prototypes (the paper's best: 4096).
        max_iterations: Lloyd iteration cap.
        tolerance: stop when the relative decrease of distortion falls below it.
        max_states: cap on gathered states kept for k-means (a uniform random subset is kept).
        init: k-means initialisation (see :func:`pedrl.vq.kmeans`).
        chunk_size: rows per block in distance computations (bounds memory; None: the measured best).
        weight_own: weight of the agent's own features (speed, velocity angle, door distance) after
            standardisation; 1 is the paper's plain standardisation.
        weight_neighbours: weight of the neighbour features after standardisation: one number for every
            neighbour, or one per neighbour rank (nearest first, ``k`` numbers), so that the nearest neighbours
            are resolved more finely than the far ones.
        weight_walls: weight of every wall feature after standardisation.
        distance_transform: ``"none"`` (the paper's raw distances) or ``"log"`` (``log(1 + d)`` for every distance
            feature before standardisation: fine near the door and the neighbours, coarse far away).
        per_process: one quantizer per learning process, fitted on that process's own states (the paper's
            processes are independent); False: one quantizer fitted on all processes' states and shared.
    """

    num_prototypes: int = 4096
    max_iterations: int = 50
    tolerance: float = 1e-4
    max_states: int = 200_000
    init: str = "kmeans++"
    chunk_size: int | None = None
    weight_own: float = 4.0
    weight_neighbours: float | Sequence[float] = 0.2
    weight_walls: float = 0.5
    per_process: bool = True
    distance_transform: str = "log"

    def __post_init__(self) -> None:
        """Check every value (except the neighbour weights, which need the room) before any compute."""
        check_integer("vq.num_prototypes", self.num_prototypes, minimum=2)
        check_integer("vq.max_iterations", self.max_iterations, minimum=1)
        check_number("vq.tolerance", self.tolerance, low=0.0)
        check_integer("vq.max_states", self.max_states, minimum=1)
        if self.max_states < self.num_prototypes:
            raise ValueError(
                f"vq.max_states={self.max_states!r} is invalid: must be at least vq.num_prototypes="
                f"{self.num_prototypes} (k-means needs at least one state per prototype)"
            )
        check_choice("vq.init", self.init, KMEANS_INITS)
        if self.chunk_size is not None:
            check_integer("vq.chunk_size", self.chunk_size, minimum=1)
        check_number("vq.weight_own", self.weight_own, low=0.0, low_open=True)
        check_number("vq.weight_walls", self.weight_walls, low=0.0, low_open=True)
        check_bool("vq.per_process", self.per_process)
        check_choice("vq.distance_transform", self.distance_transform, ("none", "log"))

    @classmethod
    def from_config(cls, values: Mapping[str, Any]) -> VQSettings:
        """Settings from the ``vq`` config group; an unknown key is a one-line ``ValueError``."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"vq.{unknown[0]} is not a quantizer setting: allowed: {', '.join(sorted(known))}")
        return cls(**dict(values))


@dataclass
class TrialStats:
    """Per-process statistics of one trial, each ``(R,)``."""

    success_rate: torch.Tensor
    episodic_return: torch.Tensor
    crashes_agent: torch.Tensor
    crashes_wall: torch.Tensor
    mean_speed: torch.Tensor
    td_error: torch.Tensor
    decisions: int = 0
    agent_decisions: int = 0


@dataclass
class TrainResult:
    """What :meth:`Trainer.fit` returns: final figures and where the outputs are.

    ``wall_time_s`` is the run's wall time over every segment (a resumed run adds the time up to its checkpoint).
    """

    final: dict[str, float]
    run_dir: Path
    checkpoint: Path
    wall_time_s: float
    phases: list[dict[str, Any]] = field(default_factory=list)
    finished_before: bool = False
    """The run was resumed from the checkpoint of its last phase: nothing was left to do or written."""


class Trainer:
    """Base class of the paper's trainers.

    Args:
        env: a callable building the room, ``env(num_replicas=, num_agents=, device=)`` (a ``functools.partial`` of
            :class:`pedrl.sim.RoomEnv`, as Hydra's ``_partial_`` gives).
        vq: quantizer settings.
        processes: R, independent learning processes run in lock-step.
        rooms_per_process: E, rooms whose agents share their process's tables.
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
        checkpoint_every: also write ``last.safetensors`` every this many trials inside a phase (0: only at the
            end of each phase).
        device: ``"cpu"`` or ``"cuda"``.
        seed: the run's seed; phase ``i`` seeds its generators from ``(seed, i)``.
        run_dir: where outputs go.
        tensorboard: write TensorBoard events.
        progress: show a progress bar.
        run_config: the resolved run config, stored in checkpoints and compared on resume.
    """

    name = "base"

    def __init__(
        self,
        *,
        env: Callable[..., RoomEnv],
        vq: VQSettings | Mapping[str, Any],
        processes: int = 20,
        rooms_per_process: int = 1,
        alpha: float = 0.35,
        gamma: float = 0.91,
        epsilon_start: float = 0.4,
        epsilon_end: float = 0.1,
        epsilon_decay_fraction: float = 0.5,
        void_features: str = "zero",
        void_draws: str = "trial",
        tables: str = "process",
        checkpoint_every: int = 0,
        device: str | torch.device = "cpu",
        seed: int = 0,
        run_dir: str | Path = ".",
        tensorboard: bool = True,
        progress: bool = True,
        run_config: Mapping[str, Any] | None = None,
    ) -> None:
        self.vq = vq if isinstance(vq, VQSettings) else VQSettings.from_config(vq)
        check_integer("processes", processes, minimum=1)
        check_integer("rooms_per_process", rooms_per_process, minimum=1)
        check_integer("checkpoint_every", checkpoint_every, minimum=0)
        check_bool("progress", progress)
        check_bool("logger.tensorboard", tensorboard)
        check_number("alpha", alpha, low=0.0, high=1.0, low_open=True)
        check_number("gamma", gamma, low=0.0, high=1.0)
        check_number("epsilon_start", epsilon_start, low=0.0, high=1.0)
        check_number("epsilon_end", epsilon_end, low=0.0, high=1.0)
        check_number("epsilon_decay_fraction", epsilon_decay_fraction, low=0.0, high=1.0, low_open=True)
        check_choice("void_features", void_features, ("zero", "random"))
        check_choice("void_draws", void_draws, ("trial", "decision"))
        check_choice("tables", tables, TABLES)
        self.device = check_device(device)
        self.env_factory = env
        self.processes = processes
        self.rooms_per_process = rooms_per_process
        self.alpha = alpha
        self.gamma = gamma
        self.epsilon_start = epsilon_start
        self.epsilon_end = epsilon_end
        self.epsilon_decay_fraction = epsilon_decay_fraction
        self.void_features = void_features
        self.void_draws = void_draws
        self.tables = tables
        self._void_uniform: torch.Tensor | None = None
        self.checkpoint_every = checkpoint_every
        self.seed = seed
        self.run_dir = Path(run_dir)
        self.tensorboard = tensorboard
        self.progress = progress
        self.config = dict(run_config or {})
        self.generator = torch.Generator(device=self.device)
        self._envs: dict[int, RoomEnv] = {}
        for phase in self.phases():
            self._check_phase(phase)
        for num_agents in sorted({phase.num_agents for phase in self.phases()}):
            self._env(num_agents)  # validates the room parameters before any compute
        self.feature_weights()  # validates the neighbour weights before any compute
        env = next(iter(self._envs.values()))
        self._distance_columns = distance_indices(env.num_neighbours, env.num_walls, device=self.device)
        self._distance_mask = torch.zeros(env.num_features, dtype=torch.bool, device=self.device)
        self._distance_mask[self._distance_columns] = True
        self._row_cache: dict[tuple[int, int, int], torch.Tensor] = {}
        self._process_cache: dict[int, torch.Tensor] = {}
        check_memory(
            self.memory_needs(),
            device=self.device,
            advice="lower processes, rooms_per_process, vq.num_prototypes, vq.max_states, the agents, "
            "algo.gather_trials or env.max_decisions",
        )
        self._check_gathering_yield()

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
        distinct ones). The default fits one :class:`pedrl.vq.Quantizer` over the full states (VQQL, IT-VQQL).

        Returns:
            The quantizer (anything with ``encode``, ``num_prototypes`` and ``state_dict``) and the final
            distortion (mean squared distance to the nearest prototype, standardised units).
        """
        return self.fit_plain_quantizer(states, num_prototypes=num_prototypes)

    def kept_prototypes(self, previous: Any | None) -> int:
        """Prototypes of the previous phase's quantizer ``previous`` that this phase's quantizer keeps besides those
        its fit adds: none by default (each phase fits a new quantizer); IN-VQQL's union keeps them all."""
        return 0

    def encode(
        self, quantizer: Any, obs: torch.Tensor, num_sensed: torch.Tensor, process: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Prototype ids ``(B,)`` of observations ``(B, F)`` with ``num_sensed (B,)`` neighbours.

        ``process (B,)`` names the learning process of every row, whose quantizer encodes it when there is one per
        process; None means the trainers' layout (``B / R`` consecutive rows per process).
        """
        if isinstance(quantizer, ProcessQuantizers):
            return quantizer.encode(obs, num_sensed, process=process)
        return quantizer.encode(obs)

    def quantizer_from_state_dict(self, tensors: dict[str, torch.Tensor]) -> Any:
        """Rebuild the quantizer saved in a checkpoint (one per process, or one shared)."""
        if ProcessQuantizers.holds(tensors):
            return ProcessQuantizers.from_state_dict(tensors, self.part_from_state_dict)
        return self.part_from_state_dict(tensors)

    def part_from_state_dict(self, tensors: dict[str, torch.Tensor]) -> Any:
        """Rebuild one (per-process or shared) quantizer from its state dict."""
        return Quantizer.from_state_dict(tensors)

    def check_quantizer(self, part: Any, position: int) -> str | None:
        """Why ``part`` (a process's quantizer, or the shared one, read from a checkpoint of the phase at
        ``position``) cannot be this trainer's, or None. The default expects a :class:`pedrl.vq.Quantizer` over the
        full state with at most ``vq.num_prototypes`` prototypes (k-means keeps fewer when the data has fewer
        distinct states)."""
        features = next(iter(self._envs.values())).num_features
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
        """Most states of the quantizer of ``phase`` (its tables' K): ``vq.num_prototypes`` unless it grows."""
        return self.vq.num_prototypes

    def memory_needs(self) -> dict[str, float]:
        """Estimated bytes of a run's largest allocations, by what they hold: the worst phase of each.

        Q tables ``(R, A, K, 81)`` float32 (:data:`TABLE_COPIES` of them), the gathered states
        (``gather_trials x R E N x max_decisions`` rows of ``F`` float32, :data:`GATHER_COPIES` copies), one k-means
        fit (``vq.max_states`` states, :data:`KMEANS_COPIES` copies, and a ``chunk_size x K`` block of scores) and
        one decision of the room (:meth:`pedrl.sim.RoomEnv.step_memory`).
        """
        tables = gathered = kmeans = room = 0
        chunk = self.vq.chunk_size or default_chunk_size(self.device)
        for phase in self.phases():
            env = self._env(phase.num_agents)
            entries = self.processes * self.num_tables(phase) * self.max_prototypes(phase) * env.num_actions
            tables = max(tables, TABLE_COPIES * entries * 4)
            rooms = self.processes * self.rooms_per_process
            rows = phase.gather_trials * rooms * phase.num_agents * env.max_decisions
            gathered = max(gathered, rows * (GATHER_COPIES * env.num_features * 4 + 16))
            fit_rows = min(rows, self.vq.max_states)
            kmeans = max(kmeans, (KMEANS_COPIES * fit_rows * env.num_features + chunk * self.vq.num_prototypes) * 4)
            room = max(room, env.step_memory())
        return {"Q tables": tables, "gathered states": gathered, "k-means": kmeans, "room": room}

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
        """The (quantizer, q_values) followed while gathering phase ``phase``'s states, or None (random walk)."""
        return previous

    # ------------------------------------------------------------------ the shared loop
    def fit(self, *, resume_from: str | Path | None = None) -> TrainResult:
        """Run every phase (or the rest of them, when resuming) and return the final figures."""
        self._clock = (time.perf_counter(), 0.0)
        phases = self.phases()
        start_phase, start_trial, previous, resumed = 0, 0, None, None
        checkpoint_path = self.run_dir / "checkpoints" / "last.safetensors"
        remove_temporaries_in(checkpoint_path.parent)  # left by a process killed while writing a checkpoint
        if resume_from is not None:
            resumed = self._load_resume(resume_from)
            self._clock = (self._clock[0], resumed.wall_time_s)
            start_phase = resumed.position + 1 if resumed.phase_complete else resumed.position
            start_trial = 0 if resumed.phase_complete else resumed.trial
            previous = (resumed.quantizer, resumed.q_values) if resumed.phase_complete else None
            if start_phase == len(phases):
                return self._finished_result(resumed, checkpoint_path)
        global_trial = sum(p.trials for p in phases[:start_phase]) + start_trial
        logger = RunLogger(
            self.run_dir, tensorboard=self.tensorboard, purge_step=global_trial if resumed is not None else None
        )
        if resumed is None:
            logger.log_text("config", _markdown_table(self.config))
        curve = CsvWriter(
            self.run_dir / "learning_curve.csv",
            CURVE_COLUMNS,
            keep_rows=_rows_before(global_trial) if resumed is not None else None,
        )
        summaries: list[dict[str, Any]] = list(resumed.summaries) if resumed is not None else []
        last_stats: TrialStats | None = None
        try:
            for position in range(start_phase, len(phases)):
                phase = phases[position]
                env = self._env(phase.num_agents)
                if resumed is not None and position == start_phase and start_trial > 0:
                    quantizer, q_values = resumed.quantizer, resumed.q_values
                    self.generator.set_state(resumed.rng_trainer)
                    env.generator.set_state(resumed.rng_env)
                    distortion = resumed.distortion
                elif self.continues_previous(phase) and previous is not None:
                    quantizer, q_values = previous
                    self._seed_phase(phase, env)
                else:
                    self._seed_phase(phase, env)
                    # --- 1. gather states following the previous policy (or a random walk)
                    states, num_sensed, process, gather_success = self.gather(phase, env, previous)
                    # --- 2. fit the quantizer (one per learning process unless vq.per_process is false)
                    quantizer, distortion = self.fit_quantizers(
                        phase, states, num_sensed, process, previous[0] if previous else None
                    )
                    # --- 3. new tables: from scratch (the paper), or the algorithm's start (IT-VQQL's value transfer)
                    q_values = self.initial_q_values(phase, quantizer, previous, env.num_actions)
                    summaries.append(
                        {
                            "phase": phase.index,
                            "agents": phase.num_agents,
                            "gathered_states": int(states.shape[0]),
                            "gather_success_rate": gather_success,
                            "prototypes": int(quantizer.num_prototypes),
                            "distortion": distortion,
                            "q_table_mib": q_values.numel() * q_values.element_size() / 2**20,
                        }
                    )
                    logger.log_scalars(
                        global_trial,
                        {
                            "vq/distortion": distortion,
                            "vq/prototypes": quantizer.num_prototypes,
                            "vq/gather_success_rate": gather_success,
                            "vq/q_table_mib": summaries[-1]["q_table_mib"],
                        },
                    )
                first_trial = start_trial if (resumed is not None and position == start_phase) else 0
                schedule = self.epsilon_schedule(phase)
                description = f"{self.name} phase {phase.index}/{len(phases)} ({phase.num_agents} agents)"
                phase_tic = time.perf_counter()
                bar = tqdm(
                    range(first_trial, phase.trials),
                    desc=description,
                    disable=not (self.progress and _interactive()),
                    leave=False,
                )
                for trial in bar:
                    epsilon = schedule(trial)
                    tic = time.perf_counter()
                    stats = self.run_trial(env, quantizer, q_values, epsilon=epsilon, learn=True)
                    self._check_finite(phase, trial, stats, q_values)
                    elapsed = time.perf_counter() - tic
                    rate = stats.agent_decisions / elapsed
                    self._log_trial(logger, curve, phase, trial, global_trial, epsilon, stats, rate)
                    global_trial += 1
                    last_stats = stats
                    bar.set_postfix(success=f"{stats.success_rate.mean():.2f}", eps=f"{epsilon:.3f}")
                    done = trial + 1
                    if self.checkpoint_every and done % self.checkpoint_every == 0 and done < phase.trials:
                        self._save(
                            phase, done, quantizer, q_values, distortion, summaries, env, last_stats, iteration=False
                        )
                bar.close()
                if self.progress and not _interactive():
                    self._report_phase(description, phase.trials - first_trial, phase_tic, last_stats)
                self._save(
                    phase, phase.trials, quantizer, q_values, distortion, summaries, env, last_stats, iteration=True
                )
                previous = (quantizer, q_values)
                logger.flush()
        finally:
            curve.close()
            logger.close()
        final = _final_figures(last_stats) if last_stats is not None else {}
        return TrainResult(
            final=final,
            run_dir=self.run_dir,
            checkpoint=checkpoint_path,
            wall_time_s=self._wall_time(),
            phases=summaries,
        )

    def _finished_result(self, resumed: RestoredState, checkpoint_path: Path) -> TrainResult:
        """The result of a run resumed from the checkpoint of its last phase: nothing to do, nothing rewritten."""
        return TrainResult(
            final=dict(resumed.final),
            run_dir=self.run_dir,
            checkpoint=checkpoint_path,
            wall_time_s=resumed.wall_time_s,
            phases=list(resumed.summaries),
            finished_before=True,
        )

    def _wall_time(self) -> float:
        """Wall time of the run so far (s): this segment plus the segments before the checkpoint resumed from."""
        start, before = self._clock
        return before + time.perf_counter() - start

    def _check_finite(self, phase: Phase, trial: int, stats: TrialStats, q_values: torch.Tensor) -> None:
        """Stop with one line when learning turned inf or NaN: the trial's returns and TD errors, and at the
        phase's last trial the tables themselves (a full pass, too slow for every trial)."""
        finite = bool(torch.isfinite(stats.episodic_return).all() and torch.isfinite(stats.td_error).all())
        if finite and trial + 1 == phase.trials:
            finite = bool(torch.isfinite(q_values).all())
        if not finite:
            raise ValueError(
                f"phase {phase.index}, trial {trial}: the returns or Q tables turned inf or NaN (float32 overflow): "
                "the rewards (env.reward_*) must be much smaller"
            )

    @staticmethod
    def _report_phase(description: str, trials: int, tic: float, stats: TrialStats | None) -> None:
        """One line per phase instead of a progress bar when the console is not a terminal (a log file)."""
        success = f", success {float(stats.success_rate.mean()):.2f}" if stats is not None else ""
        print(f"{description}: {trials} trials in {time.perf_counter() - tic:.1f} s{success}", flush=True)

    def gather(
        self, phase: Phase, env: RoomEnv, previous: tuple[Any, torch.Tensor] | None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, float]:
        """Record the states visited in ``phase.gather_trials`` trials.

        Returns:
            states ``(M, F)`` (void slots filled as configured), their neighbour counts ``(M,)``, the learning
            process whose rooms visited them ``(M,)`` int64, and the success rate while gathering.
        """
        policy = self.gather_tables(phase, previous)
        if policy is not None:
            quantizer, q_values = policy
            base_rows = self._rows(q_values, phase.num_agents)
        rooms = self.processes * self.rooms_per_process
        process_of_row = self._process_of_rows(phase.num_agents)
        chunks, counts, owners, successes = [], [], [], []
        for _ in range(phase.gather_trials):
            obs, info = env.reset()
            reached = torch.zeros(rooms, phase.num_agents, dtype=torch.bool, device=self.device)
            while True:
                active = env.active.reshape(-1)
                flat_obs = self._prepare(
                    obs.reshape(-1, env.num_features), info["num_sensed"].reshape(-1), info["decision"]
                )
                chunks.append(flat_obs[active])
                counts.append(info["num_sensed"].reshape(-1)[active])
                owners.append(process_of_row[active])
                if policy is None:
                    actions = torch.randint(
                        env.num_actions,
                        (rooms * phase.num_agents,),
                        generator=self.generator,
                        device=self.device,
                    )
                else:
                    rows = base_rows + self.encode(quantizer, flat_obs, info["num_sensed"].reshape(-1))
                    actions = epsilon_greedy(q_values, rows, phase.gather_epsilon, self.generator)
                obs, _, terminated, truncated, info = env.step(actions.view(rooms, phase.num_agents))
                reached |= info["reached"]
                if not bool(env.active.any()):
                    break
            successes.append(reached.float().mean())
        states, num_sensed, process = torch.cat(chunks), torch.cat(counts), torch.cat(owners)
        return states, num_sensed, process, float(torch.stack(successes).mean())

    def fit_quantizers(
        self,
        phase: Phase,
        states: torch.Tensor,
        num_sensed: torch.Tensor,
        process: torch.Tensor,
        previous: Any | None,
    ) -> tuple[Any, float]:
        """This phase's quantizer: one :class:`pedrl.vq.ProcessQuantizers` part per learning process, each fitted
        on the states its own rooms visited (``vq.per_process``, default), or one shared by all processes.

        Each fit sees at most ``vq.max_states`` states (a uniform random subset). When the states of some process
        hold fewer distinct states than ``vq.num_prototypes``, k-means keeps fewer prototypes there, and every
        process is fitted again with that smallest count (the processes' Q tables stack, so they share K), with a
        one-line warning and no error. Returns the quantizer and the mean distortion of its parts.
        """
        kept = self.kept_prototypes(previous)
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=_KMEANS_SHRINK, category=UserWarning)  # said once below
            if not self.vq.per_process:
                quantizer, distortion = self.fit_quantizer(phase, *self._subsample(states, num_sensed), previous)
                self._report_shrink(phase, quantizer.num_prototypes - kept, None)
                return quantizer, distortion
            parts, distortions = [], []
            for index in range(self.processes):
                mine = process == index
                part, distortion = self.fit_quantizer(
                    phase,
                    *self._subsample(states[mine], num_sensed[mine]),
                    previous.parts[index] if previous is not None else None,
                )
                parts.append(part)
                distortions.append(distortion)
            sizes = [part.num_prototypes for part in parts]
            smallest = min(sizes)
            for index, size in enumerate(sizes):
                if size > smallest:
                    mine = process == index
                    parts[index], distortions[index] = self.fit_quantizer(
                        phase,
                        *self._subsample(states[mine], num_sensed[mine]),
                        previous.parts[index] if previous is not None else None,
                        num_prototypes=smallest - kept,
                    )
        self._report_shrink(phase, smallest - kept, sizes.index(smallest))
        return ProcessQuantizers(parts), sum(distortions) / len(distortions)

    def _report_shrink(self, phase: Phase, fitted: int, process: int | None) -> None:
        """One line when the quantizer of ``phase`` got ``fitted < vq.num_prototypes`` prototypes, because the
        states gathered by ``process`` (None: by all, for a shared quantizer) hold no more distinct ones."""
        wanted = self.vq.num_prototypes
        if fitted >= wanted:
            return
        whose = "the gathered states" if process is None else f"the states gathered by process {process}"
        every = "the quantizer" if process is None else "every process's quantizer"
        warn(
            f"phase {phase.index} ({_agents(phase.num_agents)}): {whose} hold only {fitted} distinct states for "
            f"vq.num_prototypes={wanted}; {every} uses K = {fitted} in this phase (raise algo.gather_trials "
            f"to keep {wanted})"
        )

    def _check_gathering_yield(self) -> None:
        """Refuse, before any compute, a ``vq.num_prototypes`` that no gathering can reach: k-means needs a distinct
        state per prototype, and a phase records at most ``gather_trials x E x N x max_decisions`` states per
        process (``R`` times that for a shared quantizer). Fewer distinct states than that (agents leave the room
        early) only shrink K, with a warning (:meth:`fit_quantizers`)."""
        for phase in self.phases():
            env = self._env(phase.num_agents)
            factors = {
                "algo.gather_trials": phase.gather_trials,
                "rooms_per_process": self.rooms_per_process,
                "agents": phase.num_agents,
                "env.max_decisions": env.max_decisions,
            }
            if not self.vq.per_process:
                factors = {"processes": self.processes, **factors}
            most = math.prod(factors.values())
            if most < self.vq.num_prototypes:
                scope = "for the shared quantizer" if not self.vq.per_process else "per process"
                product = " x ".join(
                    _agents(value) if key == "agents" else f"{key}={value}" for key, value in factors.items()
                )
                raise ValueError(
                    f"vq.num_prototypes={self.vq.num_prototypes} is invalid: phase {phase.index} gathers at most "
                    f"{most} states {scope} ({product}) and k-means needs one per prototype: must be at most "
                    f"{most}, or raise algo.gather_trials"
                )

    def _subsample(self, states: torch.Tensor, num_sensed: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        if states.shape[0] <= self.vq.max_states:
            return states, num_sensed
        keep = torch.randperm(states.shape[0], generator=self.generator, device=self.device)[: self.vq.max_states]
        return states[keep], num_sensed[keep]

    def run_trial(
        self, env: RoomEnv, quantizer: Any, q_values: torch.Tensor, *, epsilon: float, learn: bool
    ) -> TrialStats:
        """Run one trial in every room, acting epsilon-greedily and (if ``learn``) applying equation 1.

        ``q_values`` is ``(R, A, K, U)`` with ``A`` equal to the room's agents (or dividing it: agent ``n`` uses
        table ``n mod A``). Only the agents still in a room are encoded. On CPU the loop ends as soon as every room
        is empty; on other devices it reads that flag only every ``DEVICE_CHECK_EVERY`` decisions, so that no
        decision waits for the host (the extra decisions of empty rooms change nothing).
        """
        rooms, num_agents = env.num_replicas, env.num_agents
        on_cpu = self.device.type == "cpu"
        obs, info = env.reset()
        base_rows = self._rows(q_values, num_agents)
        in_room = env.active.reshape(-1)
        rows = base_rows + self.encode_observations(quantizer, obs, info, rows_mask=in_room if on_cpu else None)
        # per agent: return, crashes with agents, crashes with walls, reached, speed sum, decisions
        totals = torch.zeros(len(_TOTALS), rooms * num_agents, device=self.device)
        td_total = torch.zeros(2, device=self.device)  # sum of |TD error|, number of updates
        decisions = torch.zeros((), dtype=torch.int64, device=self.device)
        step = 0
        while True:
            valid = env.active.reshape(-1)
            actions = epsilon_greedy(q_values, rows, epsilon, self.generator)
            obs, reward, terminated, truncated, info = env.step(actions.view(rooms, num_agents))
            reward, terminated = reward.reshape(-1), terminated.reshape(-1)
            in_room = valid & ~terminated  # their next state is needed: in the room, or cut by the clock
            next_rows = base_rows + self.encode_observations(
                quantizer, obs, info, rows_mask=in_room if on_cpu else None
            )
            if learn:
                td = td_update(
                    q_values,
                    rows,
                    actions,
                    reward,
                    next_rows,
                    terminated,
                    valid,
                    alpha=self.alpha,
                    gamma=self.gamma,
                )
                td_total += torch.stack((td.abs().sum(), valid.sum()))
            validf = valid.float()
            events = (info["crashed_agent"], info["crashed_wall"], info["reached"])
            totals += torch.stack(
                (reward, *(event.reshape(-1) for event in events), info["speed"].reshape(-1) * validf, validf)
            )
            decisions += valid.any()
            rows = next_rows
            step += 1
            if (on_cpu or step % DEVICE_CHECK_EVERY == 0) and not bool(env.active.any()):
                break
        returns, crashes_agent, crashes_wall, reached, speed_sum, moves = totals.view(len(_TOTALS), self.processes, -1)
        speed = speed_sum.sum(1) / moves.sum(1).clamp_min(1)
        per_process = self.processes
        td_error = (td_total[0] / td_total[1].clamp_min(1)).expand(per_process) if learn else torch.zeros(per_process)
        return TrialStats(
            success_rate=reached.mean(1).cpu(),
            episodic_return=returns.mean(1).cpu(),
            crashes_agent=crashes_agent.mean(1).cpu(),
            crashes_wall=crashes_wall.mean(1).cpu(),
            mean_speed=speed.cpu(),
            td_error=td_error.cpu(),
            decisions=int(decisions),
            agent_decisions=int(moves.sum()),
        )

    def encode_observations(
        self,
        quantizer: Any,
        obs: torch.Tensor,
        info: Mapping[str, Any],
        process: torch.Tensor | None = None,
        *,
        rows_mask: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Prototype ids ``(R * N,)`` of a room's observations ``(R, N, F)``, void slots treated as configured.

        ``process (R * N,)``: the learning process of every agent (see :meth:`encode`). ``rows_mask (R * N,)`` bool:
        encode only these agents (those still in a room); the others get id 0. With every agent masked in, or
        ``None``, all are encoded at once.
        """
        num_sensed = info["num_sensed"].reshape(-1)
        prepared = self._prepare(obs.reshape(-1, obs.shape[-1]), num_sensed, info["decision"])
        if rows_mask is not None:
            selected = rows_mask.nonzero().squeeze(1)
            if selected.shape[0] < rows_mask.shape[0]:
                if process is None:
                    process = self._process_of_rows(obs.shape[1])
                ids = torch.zeros(rows_mask.shape[0], dtype=torch.int64, device=obs.device)
                if selected.shape[0] > 0:
                    own = self.encode(
                        quantizer,
                        prepared.index_select(0, selected),
                        num_sensed.index_select(0, selected),
                        process.index_select(0, selected),
                    )
                    ids.index_copy_(0, selected, own)
                return ids
        return self.encode(quantizer, prepared, num_sensed, process)

    # ------------------------------------------------------------------ helpers
    def feature_weights(self, feature_index: torch.Tensor | None = None) -> torch.Tensor:
        """Per-feature weights ``(F,)`` (or of the features ``feature_index`` selects) from the ``vq`` settings."""
        env = next(iter(self._envs.values()))
        own, neighbours = 3, 3 * env.num_neighbours
        weights = torch.full((env.num_features,), self.vq.weight_walls, dtype=torch.float64, device=self.device)
        weights[:own] = self.vq.weight_own
        per_rank = torch.as_tensor(self._neighbour_weights(env.num_neighbours), dtype=torch.float64)
        weights[own : own + neighbours] = per_rank.repeat_interleave(3).to(self.device)
        return weights if feature_index is None else weights[feature_index]

    def _neighbour_weights(self, num_neighbours: int) -> list[float]:
        """``vq.weight_neighbours`` as one weight per neighbour rank, validated (one line naming the value)."""
        value = self.vq.weight_neighbours
        weights = [value] * num_neighbours if isinstance(value, int | float) else list(value)
        allowed = f"a number > 0 or a list of {num_neighbours} numbers > 0 (one per neighbour, nearest first)"
        if len(weights) != num_neighbours or not all(
            isinstance(w, int | float) and not isinstance(w, bool) and math.isfinite(w) and w > 0 for w in weights
        ):
            raise ValueError(f"vq.weight_neighbours={value!r} is invalid: must be {allowed}")
        return [float(w) for w in weights]

    def fit_plain_quantizer(
        self, states: torch.Tensor, feature_index: torch.Tensor | None = None, *, num_prototypes: int | None = None
    ) -> tuple[Quantizer, float]:
        """Fit one :class:`pedrl.vq.Quantizer` on ``states (M, F)`` with the ``vq`` settings.

        ``feature_index`` names the features of ``states`` when they are a projection of the full state;
        ``num_prototypes`` is K (None: ``vq.num_prototypes``).
        """
        quantizer, result = Quantizer.fit(
            states,
            self.vq.num_prototypes if num_prototypes is None else num_prototypes,
            generator=self.generator,
            max_iterations=self.vq.max_iterations,
            tolerance=self.vq.tolerance,
            init=self.vq.init,
            chunk_size=self.vq.chunk_size,
            feature_weights=self.feature_weights(feature_index),
        )
        return quantizer, float(result.distortion[-1])

    def _prepare(self, obs: torch.Tensor, num_sensed: torch.Tensor, decision: int) -> torch.Tensor:
        """Observations ``(B, F)`` as the quantizer sees them: void slots filled, distances transformed.

        ``vq.distance_transform="log"`` replaces every distance feature ``d`` (door, neighbours, walls) by
        ``log(1 + d)`` (m -> log m), so that the quantizer resolves near things finely and far ones coarsely.

        ``void_features="random"`` fills void neighbour slots with random valid values (section 5.1);
        ``void_draws`` sets when the randomness is drawn: ``"trial"`` (default) once per agent at the first decision
        of a trial, so that within a trial the same state always gets the same filling and the same prototype;
        ``"decision"`` anew at every encode (noise that the last agents in the room act on).
        """
        if self.void_features == "random":
            obs = self._fill_void(obs, num_sensed, decision)
        if self.vq.distance_transform == "log":
            obs = torch.where(self._distance_mask, obs.log1p(), obs)  # other columns may be < -1: NaN, not taken
        return obs

    def _fill_void(self, obs: torch.Tensor, num_sensed: torch.Tensor, decision: int) -> torch.Tensor:
        env = next(iter(self._envs.values()))
        stale = self._void_uniform is None or self._void_uniform.shape[0] != obs.shape[0]
        if self.void_draws == "decision" or decision == 0 or stale:
            self._void_uniform = void_draws(
                (obs.shape[0],), num_neighbours=env.num_neighbours, generator=self.generator, device=self.device
            )
        return fill_void_neighbours(
            obs,
            num_sensed,
            num_neighbours=env.num_neighbours,
            num_walls=env.num_walls,
            max_distance=env.max_distance,
            max_speed=env.max_speed,
            uniform=self._void_uniform,
        )

    def _process_of_rows(self, num_agents: int) -> torch.Tensor:
        """Learning process of every agent of every room, flat ``(R * E * N,)``: rooms ``p E .. p E + E - 1``
        belong to process ``p``."""
        if num_agents not in self._process_cache:
            rows_per_process = self.rooms_per_process * num_agents
            process = torch.arange(self.processes, device=self.device).repeat_interleave(rows_per_process)
            self._process_cache[num_agents] = process
        return self._process_cache[num_agents]

    def _rows(self, q_values: torch.Tensor, num_agents: int) -> torch.Tensor:
        """Flat row offsets ``(R * E * N,)`` of every agent's table in ``q_values.view(-1, U)``."""
        processes, tables, num_states, _ = q_values.shape
        key = (tables, num_states, num_agents)
        if key not in self._row_cache:
            self._row_cache[key] = self._build_rows(tables, num_states, num_agents)
        return self._row_cache[key]

    def _build_rows(self, tables: int, num_states: int, num_agents: int) -> torch.Tensor:
        process = self._process_of_rows(num_agents)
        table = (
            torch.arange(num_agents, device=self.device)
            .remainder(tables)
            .repeat(self.processes * self.rooms_per_process)
        )
        return table_rows(process, table, 0, num_tables=tables, num_states=num_states)

    def _env(self, num_agents: int) -> RoomEnv:
        if num_agents not in self._envs:
            self._envs[num_agents] = self.env_factory(
                num_replicas=self.processes * self.rooms_per_process,
                num_agents=num_agents,
                device=self.device,
            )
        return self._envs[num_agents]

    def _check_phase(self, phase: Phase) -> None:
        check_integer("num_agents", phase.num_agents, minimum=1)
        check_integer("trials", phase.trials, minimum=1)
        check_integer("gather_trials", phase.gather_trials, minimum=1)
        check_number("gather_epsilon", phase.gather_epsilon, low=0.0, high=1.0)

    def _seed_phase(self, phase: Phase, env: RoomEnv) -> None:
        phase_seed = self.seed * 10_007 + phase.index
        self.generator.manual_seed(phase_seed)
        env.reset(seed=phase_seed + 1)

    def _log_trial(self, logger, curve, phase, trial, global_trial, epsilon, stats: TrialStats, rate) -> None:
        row: dict[str, Any] = {
            "phase": phase.index,
            "agents": phase.num_agents,
            "trial": trial,
            "global_trial": global_trial,
            "epsilon": epsilon,
            "decisions_per_s": rate,
        }
        for metric in CURVE_METRICS:
            values = getattr(stats, metric).double()
            row[f"{metric}_mean"] = float(values.mean())
            row[f"{metric}_std"] = float(values.std(unbiased=False))
            tag = "losses/td_error" if metric == "td_error" else f"charts/{metric}"
            logger.log_spread(global_trial, tag, values)
        logger.log_scalars(
            global_trial,
            {"charts/decisions_per_s": rate, "charts/epsilon": epsilon, "charts/phase": phase.index},
        )
        curve.write(row)

    def _save(self, phase, trial, quantizer, q_values, distortion, summaries, env, stats, *, iteration: bool) -> None:
        tensors = {
            "q_values": q_values,
            "rng/trainer": self.generator.get_state(),
            "rng/env": env.generator.get_state(),
            **{f"quantizer/{k}": v for k, v in quantizer.state_dict().items()},
        }
        metadata = {
            "algo": self.name,
            "iteration": phase.index,
            "trial": trial,
            "phase_complete": trial >= phase.trials,
            "agents": phase.num_agents,
            "distortion": distortion,
            "summaries": summaries,
            "config": self.config,
            "wall_time_s": self._wall_time(),
            "final": _final_figures(stats) if stats is not None else {},
        }
        folder = self.run_dir / "checkpoints"
        if iteration:
            save_checkpoint(folder / f"iter_{phase.index:04d}.safetensors", tensors=tensors, metadata=metadata)
        save_checkpoint(folder / "last.safetensors", tensors=tensors, metadata=metadata)

    def _load_resume(self, path: str | Path) -> RestoredState:
        """Read and validate the checkpoint to continue from (see :mod:`pedrl.algos.restore`)."""
        checkpoint = load_checkpoint(path, device=self.device)
        meta = checkpoint.metadata
        if meta.get("algo") != self.name:
            raise CheckpointError(
                f"checkpoint {str(path)!r} was written by algo={meta.get('algo')!r}, not {self.name!r}"
            )
        mismatch = _config_mismatch(check_stored_config(checkpoint), self.config)
        if mismatch:
            raise CheckpointError(f"checkpoint {str(path)!r} comes from an incompatible configuration: {mismatch}")
        return restore_state(self, checkpoint)


# ---------------------------------------------------------------------- small pure helpers
def _agents(count: int) -> str:
    """``1 agent``, ``20 agents``."""
    return f"{count} agent" if count == 1 else f"{count} agents"


def _interactive() -> bool:
    """True when stderr is a terminal, where a progress bar redraws in place (in a log file it would not)."""
    return sys.stderr.isatty()


_RESUME_INDEPENDENT = ("resume", "device", "progress", "logger", "hydra", "threads")
"""Top-level keys that may change on resume: the results do not depend on them."""


def _rows_before(global_trial: int) -> Callable[[Mapping[str, str]], bool]:
    """Keeps the learning-curve rows of the trials before ``global_trial`` (those a resumed run does not redo)."""

    def keep(row: Mapping[str, str]) -> bool:
        value = row.get("global_trial") or ""
        return value.isdigit() and int(value) < global_trial

    return keep


_NEWER_KEYS = {"env.compile_sensing": False, "env.contact": "stop", "env.time_gap": 1.0, "algo.value_transfer": False}
"""Keys added after checkpoints were first written, with the value the runs of older checkpoints had."""


def _config_mismatch(saved: Mapping[str, Any], current: Mapping[str, Any], prefix: str = "") -> str:
    """The first differing key between two nested configs, ignoring keys that may change on resume; a key that an
    older checkpoint lacks counts as its value in ``_NEWER_KEYS``."""
    for key in sorted(set(saved) | set(current)):
        if not prefix and key in _RESUME_INDEPENDENT:
            continue
        a = saved.get(key, _NEWER_KEYS.get(f"{prefix}{key}", "<absent>"))
        b = current.get(key, "<absent>")
        if isinstance(a, Mapping) and isinstance(b, Mapping):
            found = _config_mismatch(a, b, f"{prefix}{key}.")
            if found:
                return found
        elif a != b:
            return f"{prefix}{key} was {_short_json(a)} there and is {_short_json(b)} here"
    return ""


def _short_json(value: Any, limit: int = 80) -> str:
    """``value`` as JSON, cut to ``limit`` characters: a room's WKT text may run to megabytes."""
    text = json.dumps(value)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def _final_figures(stats: TrialStats) -> dict[str, float]:
    figures = {}
    for metric in CURVE_METRICS:
        values = getattr(stats, metric).double()
        figures[f"{metric}_mean"] = float(values.mean())
        figures[f"{metric}_std"] = float(values.std(unbiased=False))
    return figures


def _markdown_table(config: Mapping[str, Any]) -> str:
    rows = ["|parameter|value|", "|-|-|"]

    def walk(node: Mapping[str, Any], prefix: str) -> None:
        for key, value in node.items():
            if isinstance(value, Mapping):
                walk(value, f"{prefix}{key}.")
            else:
                rows.append(f"|{prefix}{key}|{value}|")

    walk(config, "")
    return "\n".join(rows)

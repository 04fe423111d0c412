"""One learning run, any learner: what a run is (:class:`RunSpec`) and what every learner does the same way
(:class:`LearningRun`).

A run reads top to bottom as: its rooms (its own and the ``mix`` rooms, one generator driving every scene), then
:meth:`LearningRun.fit`: resume from a checkpoint or start, then the learner's phases (an IT-VQQL iteration, an
IN-VQQL stage, a block of a network's trials), each a loop of trials (:meth:`LearningRun.run_trials`) in the rooms in
turn, every trial logged (``learning_curve.csv``, TensorBoard, the free-walking probe) and a checkpoint written
every ``checkpoint_every`` trials and at the end of each phase (``iter_XXXX`` and ``last``), then the final figures.

A learner fills the named hooks: :meth:`~LearningRun.phases`, :meth:`~LearningRun.resume` (checks the checkpoint's
own tensors after :func:`open_resume` checked what every checkpoint holds), :meth:`~LearningRun.learn` (the phases,
each through :meth:`~LearningRun.run_trials` with its :meth:`~LearningRun.learn_trial`), and what a checkpoint holds
(:meth:`~LearningRun.state_tensors`, :meth:`~LearningRun.state_metadata`). The tables' trainer
(:class:`pedrl.algos.base.Trainer`: VQQL, IT-VQQL, IN-VQQL, the factored table) and the network's
(:class:`pedrl.algos.dqn.DQN`) are two.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Final, Protocol

import torch
from tqdm.auto import tqdm

from pedrl.algos.mix import room_of_trial
from pedrl.algos.phase import Phase, TrainResult
from pedrl.algos.records import RunRecord, final_figures, interactive, report_phase
from pedrl.algos.restore import config_mismatch
from pedrl.common.checks import check_bool, check_device, check_integer
from pedrl.configs import TrainingRoom, check_stored_config, current_form
from pedrl.io import Checkpoint, CheckpointError, load_checkpoint
from pedrl.io.files import remove_temporaries_in
from pedrl.sim import RoomEnv
from pedrl.trial.crowd import choose_path
from pedrl.trial.rollout import TrialStats
from pedrl.trial.walking import WalkingLog
from pedrl.vq.settings import VQSettings


@dataclass(frozen=True)
class RunSpec:
    """What a run is, whatever learns in it; every value checked when it is made (one line naming the key).

    Attributes:
        env: a callable building the room, ``env(num_replicas=, num_agents=, device=)`` (a ``functools.partial`` of
            :class:`pedrl.sim.RoomEnv`, as :func:`pedrl.configs.env_factory` gives).
        vq: the quantizer settings (a mapping is read as :class:`pedrl.vq.settings.VQSettings`); a network reads
            ``distance_transform`` only.
        mix: rooms of other scenarios that take turns with the run's own room, trial by trial (:mod:`pedrl.algos.mix`).
        home: the label of the run's own room in ``learning_curve.csv`` and TensorBoard (its scenario's name).
        processes: P, independent learning processes run in lock-step.
        rooms_per_process: E, rooms whose agents learn into their process's tables or network.
        checkpoint_every: also write ``last.safetensors`` every this many trials inside a phase (0: only at the end
            of each phase).
        device: ``"cpu"`` or ``"cuda"``.
        seed: the run's seed.
        run_dir: where outputs go.
        tensorboard: write TensorBoard events.
        walking_probes: free-walking probes of the learned policy over the run (:class:`pedrl.trial.walking.WalkingLog`;
            0: none).
        progress: show a progress bar.
        run_config: the resolved run config, stored in checkpoints and compared on resume.
        fused: run the trials in the compiled kernels (None: wherever they can; False: the torch loop, the reference;
            True: refused in one line, before any compute, for a room they cannot run).
    """

    env: Callable[..., RoomEnv]
    vq: VQSettings | Mapping[str, Any] = field(default_factory=VQSettings)
    mix: Sequence[TrainingRoom] = ()
    home: str = "room"
    processes: int = 20
    rooms_per_process: int = 1
    checkpoint_every: int = 0
    device: str | torch.device = "cpu"
    seed: int = 0
    run_dir: str | Path = "."
    tensorboard: bool = True
    walking_probes: int = 0
    progress: bool = True
    run_config: Mapping[str, Any] = field(default_factory=dict)
    fused: bool | None = None

    def __post_init__(self) -> None:
        vq = self.vq if isinstance(self.vq, VQSettings) else VQSettings.from_config(self.vq)
        check_integer("processes", self.processes, minimum=1)
        check_integer("rooms_per_process", self.rooms_per_process, minimum=1)
        check_integer("checkpoint_every", self.checkpoint_every, minimum=0)
        check_bool("progress", self.progress)
        check_bool("logger.tensorboard", self.tensorboard)
        for name, value in (("vq", vq), ("mix", tuple(self.mix)), ("device", check_device(self.device)),
                            ("run_dir", Path(self.run_dir)), ("run_config", dict(self.run_config))):  # fmt: skip
            object.__setattr__(self, name, value)

    @property
    def replicas(self) -> int:
        """Rooms of each of the run's scenarios, ``processes x rooms_per_process``."""
        return self.processes * self.rooms_per_process


RUN_KEYS: Final = tuple(item.name for item in fields(RunSpec))
"""The keys of a :class:`RunSpec`: a learner's constructor takes the record, not these."""


class Resumed(Protocol):
    """What :meth:`LearningRun.fit` reads of a checked checkpoint (a learner's own record holds more)."""

    global_trial: int
    done: bool
    wall_time_s: float
    final: dict[str, float]
    summaries: list[dict[str, Any]]


def open_resume(trainer: LearningRun, path: str | Path) -> Checkpoint:
    """The checkpoint ``trainer`` continues from, read and checked for what every learner's holds: written by the
    same learner, from a config that differs only in keys the results do not depend on
    (:data:`pedrl.algos.restore.RESUME_INDEPENDENT`), with its trials on the same path (fused or torch).

    Raises:
        CheckpointError: one line naming the file and what is wrong.
    """
    checkpoint = load_checkpoint(path, device=trainer.device)
    meta, where = checkpoint.metadata, f"checkpoint {str(path)!r}"
    if meta.get("algo") != trainer.name:
        raise CheckpointError(f"{where} was written by algo={meta.get('algo')!r}, not {trainer.name!r}")
    mismatch = config_mismatch(current_form(check_stored_config(checkpoint)), trainer.config)
    if mismatch:
        raise CheckpointError(f"{where} comes from an incompatible configuration: {mismatch}")
    started, (now, why) = meta.get("trial_path"), trainer.trial_path()
    if started is not None and started != now:  # e.g. PEDRL_NO_NUMBA set, or another device, since the run started
        raise CheckpointError(
            f"{where} ran its trials on the {started} path and this resume would run them on the {now} path "
            f"({why or 'the fused trial can run here'}): a seed gives other numbers on each; resume where the run "
            "started (unset PEDRL_NO_NUMBA, the same device and fused)"
        )
    return checkpoint


class LearningRun:
    """The base of every learner (module docstring): the run's record, rooms, generator, logs and checkpoints.

    Attributes set from the :class:`RunSpec`: ``run`` itself and ``vq``, ``processes``, ``rooms_per_process``,
    ``checkpoint_every``, ``device``, ``seed``, ``run_dir``, ``tensorboard``, ``progress``, ``config`` (the run
    config), ``home``, ``mix``, ``fused``, ``env_factory``; ``generator``, the learner's generator on the device.
    """

    name = "base"
    learner = ""
    """The learner of the run's policy (:data:`pedrl.rl.policy.POLICY_READERS`), stored in every checkpoint."""
    phase_word = "phase"
    """What a phase is called in the progress lines (``iteration`` for a network's blocks of trials)."""

    def __init__(self, run: RunSpec) -> None:
        if not isinstance(run, RunSpec):
            raise TypeError(f"run={run!r} is invalid: must be a pedrl.algos.RunSpec")
        self.run = run
        self.vq, self.env_factory = run.vq, run.env
        self.processes, self.rooms_per_process, self.checkpoint_every = (
            run.processes,
            run.rooms_per_process,
            run.checkpoint_every,
        )
        self.device, self.seed, self.run_dir = run.device, run.seed, run.run_dir
        self.tensorboard, self.progress, self.config = run.tensorboard, run.progress, dict(run.run_config)
        self.home, self.mix, self.fused = run.home, list(run.mix), run.fused
        self.generator = torch.Generator(device=self.device)
        self._mix_envs = [
            entry.factory(num_replicas=run.replicas, num_agents=entry.num_agents, device=self.device)
            for entry in run.mix
        ]

    # ------------------------------------------------------------------ what a learner defines
    def phases(self) -> list[Phase]:
        """The run's phases, in order."""
        raise NotImplementedError

    def own_rooms(self) -> list[RoomEnv]:
        """The rooms of the run's own scenario (one per count of agents its phases use)."""
        raise NotImplementedError

    def resume(self, path: str | Path) -> Resumed:
        """The checked state of the checkpoint ``path`` to continue from (:func:`open_resume` first)."""
        raise NotImplementedError

    def learn(self, record: RunRecord, resumed: Resumed | None) -> TrialStats | None:
        """Every phase from the start or from ``resumed`` on; returns the last trial's statistics."""
        raise NotImplementedError

    def learn_trial(self, env: RoomEnv, room: int, epsilon: float, bar: tqdm) -> TrialStats:
        """One learning trial in ``env`` (the ``room``-th of :meth:`rooms`) at exploration ``epsilon``."""
        raise NotImplementedError

    def check_trial(self, phase: Phase, trial: int, stats: TrialStats) -> None:
        """Refuse, in one line, a trial whose figures or learned values turned inf or NaN."""

    def log_trial(self, record: RunRecord, global_trial: int) -> None:
        """The learner's own scalars after a trial."""

    def state_tensors(self) -> dict[str, torch.Tensor]:
        """What a checkpoint holds of the learner (its policy and what a resume needs), the generators aside."""
        raise NotImplementedError

    def state_metadata(self, global_trial: int) -> dict[str, Any]:
        """The learner's own metadata of a checkpoint (after ``agents``, before ``summaries``)."""
        return {}

    def summaries(self) -> list[dict[str, Any]]:
        """The run's summaries so far (one per phase of the tables, one of the network's start)."""
        return []

    # ------------------------------------------------------------------ the rooms
    def rooms(self, env: RoomEnv) -> list[tuple[str, RoomEnv]]:
        """The labelled rooms a phase whose own room is ``env`` trains in: ``env``, then the ``mix`` rooms. These
        draw from ``env``'s generator, so that one stream (``rng/env`` in a checkpoint) drives every room."""
        for room in self._mix_envs:
            room.generator = env.generator
        return [(self.home, env), *((entry.label, room) for entry, room in zip(self.mix, self._mix_envs, strict=True))]

    def trial_path(self) -> tuple[str, str | None]:
        """Where the trials run, ``"fused"`` or ``"torch"`` (a seed gives other numbers on each), and why not on the
        fused one (None when they do): what a resume must keep."""
        name, why_not = choose_path([*self.own_rooms(), *self._mix_envs], None, self.fused)
        return name, why_not

    def log_walking(self, trials: int, room: RoomEnv) -> None:
        """Probe the policy's free walking ``run.walking_probes`` times over the run's ``trials``."""
        self.walking = WalkingLog(self.run.walking_probes, trials, room.params, self.env_factory)

    # ------------------------------------------------------------------ the run
    def fit(self, *, resume_from: str | Path | None = None) -> TrainResult:
        """Run every phase (or the rest of them, when resuming) and return the final figures."""
        remove_temporaries_in(self.run_dir / "checkpoints")  # left by a process killed while writing a checkpoint
        resumed = self.resume(resume_from) if resume_from is not None else None
        before = resumed.wall_time_s if resumed is not None else 0.0
        record = RunRecord(self.run_dir, tensorboard=self.tensorboard, config=self.config, wall_time_before=before)
        if resumed is not None and resumed.done:
            finished = (resumed.wall_time_s, resumed.final, resumed.summaries)
            return TrainResult.finished(self.run_dir, record.checkpoint_path, *finished)
        record.open(resumed.global_trial if resumed is not None else 0, resumed=resumed is not None)
        stats = None
        try:
            stats = self.learn(record, resumed)
        finally:
            record.close()
        final = final_figures(stats) if stats is not None else dict(resumed.final if resumed else {})
        return TrainResult(final, self.run_dir, record.checkpoint_path, record.wall_time(), self.summaries())

    def run_trials(
        self,
        phase: Phase,
        rooms: list[tuple[str, RoomEnv]],
        first_trial: int,
        global_trial: int,
        record: RunRecord,
        *,
        epsilon: Callable[[int, int], float],
        policy: Any,
    ) -> tuple[TrialStats | None, int]:
        """Trials ``first_trial .. phase.trials - 1`` of ``phase``, each in its turn's room of ``rooms`` at
        ``epsilon(trial, global_trial)`` (:meth:`learn_trial`), checked, logged (with ``policy``'s free-walking
        probe) and checkpointed every ``checkpoint_every`` trials and at the phase's end. Returns the last trial's
        statistics and the next global trial."""
        description = f"{self.name} {self.phase_word} {phase.index}/{len(self.phases())} ({phase.num_agents} agents)"
        tic = time.perf_counter()
        bar = tqdm(range(first_trial, phase.trials), desc=description,
                   disable=not (self.progress and interactive()), leave=False)  # fmt: skip
        stats = None
        for trial in bar:
            rate_eps = epsilon(trial, global_trial)
            index = room_of_trial(trial, phase.trials, len(rooms))
            label, env = rooms[index]
            trial_tic = time.perf_counter()
            stats = self.learn_trial(env, index, rate_eps, bar)
            self.check_trial(phase, trial, stats)
            rate = stats.agent_decisions / (time.perf_counter() - trial_tic)
            walking = self.walking.measure(global_trial, policy)
            record.log_trial(phase, trial, global_trial, rate_eps, stats, rate, room=label, agents=env.num_agents,
                             per_room=bool(self.mix), walking=walking)  # fmt: skip
            self.log_trial(record, global_trial)
            global_trial += 1
            bar.set_postfix(success=f"{stats.success_rate.mean():.2f}", eps=f"{rate_eps:.3f}")
            done = trial + 1 == phase.trials
            if done or (self.checkpoint_every and (trial + 1) % self.checkpoint_every == 0):
                self.save(record, phase, trial + 1, global_trial, stats, rooms[0][1], iteration=done)
        bar.close()
        if self.progress and not interactive():
            report_phase(description, phase.trials - first_trial, tic, stats)
        return stats, global_trial

    def save(
        self,
        record: RunRecord,
        phase: Phase,
        trial: int,
        global_trial: int,
        stats: TrialStats | None,
        env: RoomEnv,
        *,
        iteration: bool,
    ) -> None:
        """Write the checkpoint of ``phase`` after ``trial`` of its trials (``iteration``: its last, also
        ``iter_XXXX``), with the generators (that of ``env``, the phase's own room, drives every room)."""
        rng = {"rng/trainer": self.generator.get_state(), "rng/env": env.generator.get_state()}
        tensors = {**self.state_tensors(), **rng}
        metadata = {
            "algo": self.name,
            "learner": self.learner,
            "iteration": phase.index,
            "trial": trial,
            "phase_complete": trial >= phase.trials,
            "agents": phase.num_agents,
            **self.state_metadata(global_trial),
            "summaries": self.summaries(),
            "encoder": self.encoder_settings.to_metadata(),
            "final": final_figures(stats) if stats is not None else {},
            "trial_path": self.trial_path()[0],
        }
        record.save(tensors, metadata, phase, iteration=iteration)

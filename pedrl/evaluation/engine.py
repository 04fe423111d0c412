"""The evaluation engine: a checkpoint made ready to simulate, its trials recorded, the figures of Tables 4/5.

Every function takes plain arguments (no config): :func:`pedrl.evaluation.config.evaluate` turns the eval config
into them. The outputs and the definitions of the ``scaling.csv`` columns are in the :mod:`pedrl.evaluation`
docstring.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Final

import numpy as np
import torch

from pedrl.analysis import (
    DensityMap,
    FundamentalDiagram,
    animate_trial,
    compute_density_map,
    compute_fundamental_diagram,
    trajectories_for_export,
    write_geometry_wkt,
    write_jupedsim_sqlite,
    write_pedpy_trajectory,
)
from pedrl.analysis.trajectories import Geometry, Trajectories
from pedrl.common.checks import first_line
from pedrl.common.progress import progress_bar
from pedrl.common.recording import Recording
from pedrl.evaluation.batch import Recorder
from pedrl.evaluation.jupedsim_reference import JuPedSimReference
from pedrl.evaluation.report import write_density_map, write_fundamental_diagram, write_scaling_json
from pedrl.integrations.jupedsim import JuPedSimModel
from pedrl.io import CsvWriter, RunLogger
from pedrl.policy_files import load_policy, overridden, room_factory, room_settings
from pedrl.rl.policy import PolicyController
from pedrl.scenarios import Scenario, paper_room
from pedrl.sim import RoomEnv
from pedrl.sim.controllers import Controller, GreedyDoorController
from pedrl.trial.crowd import choose_path, run_crowd

SCALING_COLUMNS: Final = (
    "controller",
    "agents",
    "fails_pct",
    "fails_std",
    "mean_speed",
    "speed_std",
    "evacuation_time_s",
    "evacuated_trials",
    "evacuated_pct",
    "stuck_pct",
    "door_flow",
    "crashes_per_agent",
    "wall_crashes_per_agent",
    "trials",
)
STUCK_WINDOW: Final = 20
"""Decisions at the end of a trial over which an agent still in the room counts as stuck if it did not move."""
STUCK_PATH: Final = 0.4
"""Path length (m) over those decisions below which it did not move: less than one body radius."""
ENV_SEED_STRIDE: Final = 1009
"""Room seed of an agent count: ``seed * ENV_SEED_STRIDE + agents`` (a prime, so counts never share a seed)."""
CONTROLLER_SEED_STRIDE: Final = 1013
"""Controller seed of an agent count: ``seed * CONTROLLER_SEED_STRIDE + agents``."""


# ---------------------------------------------------------------------- what is evaluated
@dataclass
class LoadedPolicy:
    """A learned policy made ready to simulate.

    Attributes:
        controller: what chooses the actions, or a :class:`Recorder` that simulates the trials itself.
        env_factory: ``env_factory(num_replicas=, num_agents=, device=)`` builds the checkpoint's room, in its
            scenario or the one asked for; ``env_factory.scenario`` is that :class:`~pedrl.scenarios.Scenario`.
        env_settings: the checkpoint's ``env`` config (bodies, speeds, sensing, rewards), plain values.
        processes: P, the learning processes stored in the file.
        tables: A, the learned tables per process.
        algo: the algorithm that learned the policy.
    """

    controller: Controller | Recorder
    env_factory: Any
    env_settings: dict[str, Any]
    processes: int
    tables: int
    algo: str


def load_controller(
    path: str | Path,
    *,
    controller: str,
    epsilon: float,
    device: torch.device,
    max_decisions: int | None,
    queue_weight: float | None = None,
    scenario: dict[str, Any] | None = None,
    jupedsim: JuPedSimModel | None = None,
    kind: str = "checkpoint",
) -> LoadedPolicy:
    """Read the policy of a training checkpoint (``kind="checkpoint"``) or of an exported policy file
    (``kind="policy"``) with :func:`pedrl.load_policy`, and make it ready to simulate.

    Nothing from the file is executed, its stored config may name no code, and every tensor is checked, whichever
    the controller. The rooms are built in ``scenario`` (a ``scenario`` config), else in the policy's own (the
    paper's room for checkpoints that predate scenarios). ``controller`` is ``learned`` (the policy's tables),
    ``greedy`` or ``jupedsim`` (JuPedSim's ``jupedsim`` model, default
    :class:`~pedrl.integrations.jupedsim.JuPedSimModel`'s, with the room's body radius).

    Raises:
        CheckpointError: one line, for a missing, foreign, corrupt or crafted file.
    """
    other = {"checkpoint": "pass it as policy=", "policy": "pass it as checkpoint="}[kind]
    policy = load_policy(path, device=device, kind=kind, hint=other)
    try:  # the file's own room is stored in it and opens no file; the user's scenario may name a WKT file
        factory = room_factory(policy, scenario, max_decisions=max_decisions, queue_weight=queue_weight)
    except (KeyError, TypeError) as err:  # a ValueError names the scenario's or max_decisions' bad value itself
        raise ValueError(f"the room of {kind} {str(path)!r} cannot be built ({first_line(err)})") from None
    env_settings = room_settings(policy) | overridden(max_decisions=max_decisions, queue_weight=queue_weight)
    label = (factory, env_settings, policy.num_processes, policy.num_tables, policy.metadata["algo"])
    if controller == "greedy":
        return LoadedPolicy(GreedyDoorController(epsilon=epsilon, generator=torch.Generator(device=device)), *label)
    if controller == "jupedsim":
        reference = JuPedSimReference(factory.scenario, jupedsim if jupedsim is not None else JuPedSimModel())
        return LoadedPolicy(reference, *label)
    # one generator draws the exploration, the ties and random void fillings (IT-VQQL): one seed covers them all
    return LoadedPolicy(policy.controller(epsilon, torch.Generator(device=device)), *label)


# ---------------------------------------------------------------------- recording
PROGRESS_AGENTS: Final = 5_000
"""Batches of at least this many agents (all rooms together) show a progress bar on the terminal."""


class CrowdProgress:
    """The progress of the decisions of a batch of ``env``'s rooms, with the agents left, on stderr: a bar (tqdm) on a
    terminal, a line every few percent in a log (:func:`pedrl.common.progress.progress_bar`); a no-op for batches
    smaller than :data:`PROGRESS_AGENTS`."""

    def __init__(self, env: RoomEnv, label: str, *, always: bool = False) -> None:
        self.bar = None
        if always or env.num_replicas * env.num_agents >= PROGRESS_AGENTS:
            self.bar = progress_bar(env.params.max_decisions, label, unit="decision")

    def __call__(self, decisions: int, left: int) -> None:
        if self.bar is not None:
            self.bar.update(decisions - self.bar.n)
            self.bar.set_postfix(agents_left=left, refresh=False)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def record_batch(
    env: RoomEnv,
    controller: Controller,
    *,
    fused: bool | None = False,
    label: str = "pedrl-eval",
    progress: bool = False,
) -> Recording:
    """Reset ``env`` (its generator draws the scene) and run one trial in every replica to its end, with a progress
    bar named ``label`` for a large crowd, or for any with ``progress`` (:class:`CrowdProgress`).

    ``fused``: the learned tables or the greedy walker through the fused trial's kernels (on the CPU, one compiled
    pass per batch), or the torch loop, the reference (False); None: the fused pass wherever it can run
    (:func:`pedrl.trial.crowd.run_crowd` chooses). The two agree within the fused trial's tolerances, not to the bit
    (their random streams differ). A crowd too large to record every decision is recorded every few
    (:func:`pedrl.trial.fused.record_every`; the frame rate says how often).
    """
    bar = CrowdProgress(env, label, always=progress)
    try:
        record = run_crowd(env, controller, fused=fused, record=True, progress=bar).record
    finally:
        bar.close()
    return replace(record, exit_time=record.exit_time.astype(np.float32))  # the evaluation's exit times: float32


def check_fused_controller(controller: Controller, envs: Iterable[RoomEnv], fused: bool | None = True) -> None:
    """One-line ``ValueError`` when ``fused=true`` cannot hold: the learned or greedy ``controller`` cannot run
    through the fused trial in one of ``envs`` (JuPedSim runs its own model, whatever ``fused`` says)."""
    if not isinstance(controller, Recorder):
        choose_path(envs, controller, fused, record=True)


# ---------------------------------------------------------------------- statistics
@dataclass
class ScalingStats:
    """Per-trial figures of one agent count, gathered batch after batch."""

    fails_pct: list[float] = field(default_factory=list)
    evacuation_times: list[float] = field(default_factory=list)
    door_flows: list[float] = field(default_factory=list)
    crashes_per_agent: list[float] = field(default_factory=list)
    wall_crashes_per_agent: list[float] = field(default_factory=list)
    stuck_pct: list[float] = field(default_factory=list)
    speed_sum: float = 0.0
    speed_sq_sum: float = 0.0
    speed_count: int = 0

    def add(self, record: Recording, keep: int) -> None:
        """Add the first ``keep`` replicas of ``record``."""
        reached, exit_time = record.left[:keep], record.exit_time[:keep]
        num_agents = reached.shape[1]
        self.fails_pct.extend((100.0 * (1.0 - reached.mean(axis=1))).tolist())
        self.crashes_per_agent.extend((record.crashes[:keep].sum(axis=1) / num_agents).tolist())
        self.wall_crashes_per_agent.extend((record.wall_crashes[:keep].sum(axis=1) / num_agents).tolist())
        in_room = record.acted()[:keep, -1] & ~reached  # acted in the trial's last decision and did not reach
        self.stuck_pct.extend((100.0 * stuck_agents(record.positions[:keep], in_room).mean(axis=1)).tolist())
        self.speed_sum += float(record.speed_sum[:keep].sum())
        self.speed_sq_sum += float(record.speed_sq_sum[:keep].sum())
        self.speed_count += int(record.speed_count[:keep].sum())
        for passed, times in zip(reached, exit_time, strict=True):
            times = times[passed]
            if passed.all():
                self.evacuation_times.append(float(times.max()))
            if times.size >= 2 and times.max() > times.min():
                self.door_flows.append(float((times.size - 1) / (times.max() - times.min())))

    def row(self, agents: int, controller: str) -> dict[str, Any]:
        """The ``scaling.csv`` row of ``controller`` at ``agents`` (see the :mod:`pedrl.evaluation` docstring)."""
        fails = np.asarray(self.fails_pct)
        count = max(self.speed_count, 1)
        mean_speed = self.speed_sum / count
        variance = max(self.speed_sq_sum / count - mean_speed**2, 0.0)
        return {
            "controller": controller,
            "agents": agents,
            "fails_pct": float(fails.mean()),
            "fails_std": float(fails.std()),
            "mean_speed": mean_speed,
            "speed_std": math.sqrt(variance),
            "evacuation_time_s": float(np.mean(self.evacuation_times)) if self.evacuation_times else math.nan,
            "evacuated_trials": len(self.evacuation_times),
            "evacuated_pct": 100.0 * len(self.evacuation_times) / max(len(self.fails_pct), 1),
            "stuck_pct": float(np.mean(self.stuck_pct)),
            "door_flow": float(np.mean(self.door_flows)) if self.door_flows else math.nan,
            "crashes_per_agent": float(np.mean(self.crashes_per_agent)),
            "wall_crashes_per_agent": float(np.mean(self.wall_crashes_per_agent)),
            "trials": len(self.fails_pct),
        }


def stuck_agents(positions: np.ndarray, in_room: np.ndarray) -> np.ndarray:
    """Agents still in the room at the end whose last ``STUCK_WINDOW`` decisions moved them less than ``STUCK_PATH``.

    Args:
        positions: ``(R, T, N, 2)`` centres (m), frame 0 the initial state.
        in_room: ``(R, N)`` bool, the agent was still in the room when the clock cut the trial (it neither reached
            its goal nor left through another group's exit).

    Returns:
        ``(R, N)`` bool.
    """
    window = positions[:, -(STUCK_WINDOW + 1) :]  # the last 20 decisions (all of them in shorter trials)
    path = np.linalg.norm(np.diff(window, axis=1), axis=-1).sum(axis=1)  # (R, N) m
    return in_room & (path < STUCK_PATH)


# ---------------------------------------------------------------------- the evaluation
@dataclass(frozen=True)
class EvalSettings:
    """The plain values of an evaluation (the eval config's, validated by
    :func:`pedrl.evaluation.config.validate_config`).

    Attributes:
        trials: trials per learning process and agent count.
        seed: seeds the rooms and the controller of every agent count (``ENV_SEED_STRIDE``,
            ``CONTROLLER_SEED_STRIDE``) and the samples drawn in the fundamental-diagram figure.
        controller: the controller's name (``learned``, ``greedy`` or ``jupedsim``), for the titles.
        radius: Gaussian radius (m) of the local density (``measurement.radius``).
        distance: distance (m) of the measurement point in front of the door centre (``measurement.distance``).
        min_density: frames below this local density (1/m^2) give no diagram sample (``measurement.min_density``).
        plot_points: most samples drawn per agent count in the figure (``measurement.plot_points``).
        tile_size: density-map tile size (m) (``density_map.tile_size``).
        export_trials: simulated trials written as PedPy trajectories (``export.trials``).
        export_fps: their frames per second, None for the recording's (``export.fps``;
            :func:`pedrl.analysis.trajectories_for_export`).
        animation: write ``animation_<agents>.gif`` (``animation.enabled``).
        animation_fps: its frames per second (``animation.fps``).
        animation_max_frames: its most frames, None for all (``animation.max_frames``).
        tensorboard: write TensorBoard events under ``tb/``.
        fused: record through the fused trial's kernels (:func:`record_batch`); None: wherever they can run.
        progress: a progress bar for every batch, whatever its size (a long run's; else only for batches of at least
            :data:`PROGRESS_AGENTS` agents).
    """

    trials: int
    seed: int
    controller: str
    radius: float
    distance: float
    min_density: float
    plot_points: int
    tile_size: float
    export_trials: int
    animation: bool
    animation_fps: float
    animation_max_frames: int | None
    tensorboard: bool
    fused: bool | None = None
    export_fps: float | None = None
    progress: bool = False


def output_paths(
    run_dir: str | Path, settings: EvalSettings, counts: Sequence[int], *, processes: int
) -> tuple[list[Path], list[Path]]:
    """The folders and files :func:`evaluate_policy` writes under ``run_dir`` for the agent counts ``counts`` of a
    policy of ``processes`` learning processes: what is checked before any compute
    (:func:`pedrl.io.files.check_outputs`)."""
    run_dir = Path(run_dir)
    folders = [run_dir]
    files = [run_dir / "scaling.csv", run_dir / "scaling.json"]
    files += [run_dir / f"fundamental_diagram.{ext}" for ext in ("csv", "png")]
    if settings.tensorboard:
        folders.append(run_dir / "tb")
    exported = min(settings.export_trials, settings.trials * processes)
    if exported:
        folders.append(run_dir / "trajectories")
        files.append(run_dir / "trajectories" / "geometry.wkt")
    for agents in counts:
        files += [run_dir / f"density_map_{agents}.{ext}" for ext in ("npy", "png")]
        if settings.animation:
            files.append(run_dir / f"animation_{agents}.gif")
        if exported:
            folder = run_dir / "trajectories" / f"agents_{agents}"
            folders.append(folder)
            files += [folder / f"trial_{run:03d}.{ext}" for run in range(exported) for ext in ("txt", "sqlite")]
    return folders, files


def build_rooms(
    policy: LoadedPolicy, counts: Sequence[int], *, trials_per_batch: int, device: torch.device
) -> dict[int, RoomEnv]:
    """The checkpoint's room for every agent count of ``counts``, each simulating ``trials_per_batch`` trials of
    every learning process at once (``policy.processes * trials_per_batch`` replicas)."""
    return {
        int(agents): policy.env_factory(
            num_replicas=policy.processes * trials_per_batch, num_agents=int(agents), device=device
        )
        for agents in counts
    }


def room_geometry(envs: dict[int, RoomEnv], scenario: Scenario | None = None) -> Geometry:
    """The area of ``envs`` (all of them share it) as the analysis functions take it: the plain view that
    ``scenario``, which built their geometry, gives of it (:meth:`~pedrl.scenarios.Scenario.analysis_geometry`);
    no scenario is the paper's room of the rooms' sizes, as for :func:`~pedrl.scenarios.build_scenario`."""
    first = next(iter(envs.values()))
    if scenario is None:
        scenario = paper_room(width=first.width, length=first.length, door_width=first.door_width)
    return scenario.analysis_geometry(first.geometry)


def measurement_point(geometry: Geometry, distance: float) -> np.ndarray:
    """The point of the fundamental diagram: ``distance`` m inside the area from the centre of its (first) door."""
    return geometry.door_center - distance * geometry.door_normal


def evaluate_policy(
    policy: LoadedPolicy,
    envs: dict[int, RoomEnv],
    geometry: Geometry,
    settings: EvalSettings,
    *,
    run_dir: str | Path,
    config_text: str | None = None,
) -> list[dict[str, Any]]:
    """Simulate ``policy`` in every room of ``envs`` (one per agent count) and write every output under
    ``run_dir``; returns the ``scaling.csv`` rows.

    The rooms come from :func:`build_rooms`, ``geometry`` from :func:`room_geometry`; the outputs are listed in the
    :mod:`pedrl.evaluation` docstring. ``config_text``, when given, is logged to TensorBoard as the run's config.
    """
    run_dir = Path(run_dir)
    point = tuple(float(v) for v in measurement_point(geometry, settings.distance))
    label = f"{policy.algo} ({settings.controller})"
    run_dir.mkdir(parents=True, exist_ok=True)
    logger = RunLogger(run_dir, tensorboard=settings.tensorboard)
    if config_text is not None:
        logger.log_text("eval/config", "```\n" + config_text + "```")
    table: CsvWriter | None = None  # started at the first row: a run failing before it leaves no header-only table
    diagrams: dict[int, FundamentalDiagram] = {}
    rows: list[dict[str, Any]] = []
    print(
        f"pedrl-eval: {label}, {policy.processes} processes x {policy.tables} tables, agents {list(envs)}, "
        f"{settings.trials} trials per process -> {run_dir}",
        flush=True,
    )

    # ---- one agent count after another
    try:
        for agents, env in envs.items():
            tic = time.perf_counter()
            env.generator.manual_seed(settings.seed * ENV_SEED_STRIDE + agents)
            if isinstance(policy.controller, PolicyController | GreedyDoorController):
                policy.controller.generator.manual_seed(settings.seed * CONTROLLER_SEED_STRIDE + agents)
            stats, diagram, density = simulate_agent_count(env, policy, settings, geometry, point, run_dir)
            row = stats.row(agents, settings.controller)
            rows.append(row)
            table = table or CsvWriter(run_dir / "scaling.csv", SCALING_COLUMNS)
            table.write(row)
            diagrams[agents] = diagram
            title = f"{label}: {agents} agents, {row['trials']} trials"
            figure = write_density_map(run_dir, density, geometry, agents=agents, title=title)
            logger.log_figure(f"eval/density_map_{agents}", figure)
            logger.log_scalars(agents, {f"eval/{k}": v for k, v in row.items() if k not in ("agents", "controller")})
            print(
                f"  {agents:>4} agents: fails {row['fails_pct']:5.1f} ± {row['fails_std']:4.1f} %, "
                f"speed {row['mean_speed']:.2f} ± {row['speed_std']:.2f} m/s, stuck {row['stuck_pct']:.1f} %, "
                f"contacts {row['crashes_per_agent']:.1f} per agent (walls {row['wall_crashes_per_agent']:.1f}), "
                f"door flow {row['door_flow']:.2f} /s, "
                f"evacuated {row['evacuated_pct']:.0f} % of trials "
                f"(simulated in {time.perf_counter() - tic:.1f} s of wall time)",
                flush=True,
            )
        figure = write_fundamental_diagram(
            run_dir,
            diagrams,
            label=label,
            point=point,
            radius=settings.radius,
            max_points=settings.plot_points,
            seed=settings.seed,
        )
        logger.log_figure("eval/fundamental_diagram", figure)
    finally:
        if table is not None:
            table.close()
        logger.close()
    write_scaling_json(run_dir, rows)
    return rows


def write_scaling(run_dir: str | Path, rows: list[dict[str, Any]]) -> None:
    """``scaling.csv`` (replaced atomically) and ``scaling.json`` of ``run_dir``, holding ``rows``."""
    table = CsvWriter(Path(run_dir) / "scaling.csv", SCALING_COLUMNS)
    try:
        for row in rows:
            table.write(row)
    finally:
        table.close()
    write_scaling_json(Path(run_dir), rows)


def simulate_agent_count(
    env: RoomEnv,
    policy: LoadedPolicy,
    settings: EvalSettings,
    geometry: Geometry,
    point: tuple[float, float],
    run_dir: Path,
) -> tuple[ScalingStats, FundamentalDiagram, DensityMap]:
    """``settings.trials`` trials per process in batches: Table 4/5 figures, diagram samples, density map, exports."""
    stats = ScalingStats()
    diagrams: list[FundamentalDiagram] = []
    density: DensityMap | None = None
    runs_per_batch = env.num_replicas  # processes * trials_per_batch; replica i of batch b is run b * R + i
    total_runs = settings.trials * policy.processes
    to_export = min(settings.export_trials, total_runs)
    folder = run_dir / "trajectories" / f"agents_{env.num_agents}"
    for first_run in range(0, total_runs, runs_per_batch):
        if isinstance(policy.controller, Recorder):
            record = policy.controller.record(env)
        else:
            label = f"{env.num_agents} agents, runs {first_run + 1}-{min(first_run + runs_per_batch, total_runs)}"
            record = record_batch(env, policy.controller, fused=settings.fused, label=label, progress=settings.progress)
        keep = min(runs_per_batch, total_runs - first_run)
        stats.add(record, keep)
        runs = [Trajectories.of_run(record, i, geometry) for i in range(keep)]
        diagram = compute_fundamental_diagram(
            runs, point=point, radius=settings.radius, min_density=settings.min_density
        )
        diagrams.append(_offset_trials(diagram, first_run))
        batch_map = compute_density_map(runs, tile_size=settings.tile_size, geometry=geometry)
        density = batch_map if density is None else _add_maps(density, batch_map)
        if first_run == 0 and settings.animation:
            animate_trial(
                runs[0],
                run_dir / f"animation_{env.num_agents}.gif",
                fps=settings.animation_fps,
                max_frames=settings.animation_max_frames,
                agent_radius=env.params.agent_radius,
                max_speed=env.params.max_speed,
            )
        for i in range(min(keep, to_export - first_run)):
            if first_run + i == 0:
                folder.mkdir(parents=True, exist_ok=True)
                write_geometry_wkt(run_dir / "trajectories" / "geometry.wkt", geometry)
            exported = trajectories_for_export(runs[i], framerate=settings.export_fps)
            write_pedpy_trajectory(folder / f"trial_{first_run + i:03d}.txt", exported)
            write_jupedsim_sqlite(folder / f"trial_{first_run + i:03d}.sqlite", exported)
    assert density is not None  # at least one batch ran
    return stats, _concatenate_diagrams(diagrams), density


def _offset_trials(diagram: FundamentalDiagram, offset: int) -> FundamentalDiagram:
    return replace(diagram, trial=diagram.trial + offset)


def _concatenate_diagrams(diagrams: Sequence[FundamentalDiagram]) -> FundamentalDiagram:
    return replace(
        diagrams[0],
        density=np.concatenate([d.density for d in diagrams]),
        speed=np.concatenate([d.speed for d in diagrams]),
        flow=np.concatenate([d.flow for d in diagrams]),
        trial=np.concatenate([d.trial for d in diagrams]),
        frame=np.concatenate([d.frame for d in diagrams]),
    )


def _add_maps(a: DensityMap, b: DensityMap) -> DensityMap:
    return replace(a, counts=a.counts + b.counts, num_frames=a.num_frames + b.num_frames)

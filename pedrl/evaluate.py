"""``pedrl-eval``: reload a checkpoint and simulate it with more agents (paper section 6, Tables 4 and 5).

``main`` is a thin ``@hydra.main`` wrapper around the importable ``evaluate(cfg)``.

The checkpoint's stored training config rebuilds its room, its trainer (which knows how observations are
quantized) and its quantizer; its tables ``q_values (P, A, K, U)`` drive the agents (``controller=learned``), or the
non-learned :class:`~pedrl.algos.controllers.GreedyDoorController` does (``controller=greedy``). For every agent
count of ``agents`` it simulates ``trials`` trials with the tables of every one of the P learning processes
(``trials * P`` simulated trials, numbered ``run = trial * P + process``); agent ``n`` acts with table ``n mod A``.
Initial positions depend only on ``seed`` and the agent count, so both controllers face the same scenarios.

Outputs, under the run directory:

- ``scaling.csv`` (and ``scaling.json``): one row per agent count, the columns of ``SCALING_COLUMNS``:

  ``agents``; ``fails_pct`` and ``fails_std``: mean and standard deviation over the simulated trials of the
  percentage of agents that did not reach the door (Tables 4/5); ``mean_speed`` and ``speed_std`` (m/s): mean and
  standard deviation of the speed of every agent after every decision it took; ``evacuation_time_s``: mean time
  until the last agent passed the door, over the ``evacuated_trials`` trials in which every agent did;
  ``evacuated_pct``: the share of trials (%) in which every agent passed the door; ``stuck_pct``: the share of
  agents (%) still in the room at the end of their trial whose path over its last ``STUCK_WINDOW = 20`` decisions
  was shorter than ``STUCK_PATH = 0.4`` m (one body radius): frozen, not merely slow;
  ``door_flow`` (persons/s): mean over trials with at least two distinct passing times of
  ``(n - 1) / (t_last - t_first)``, n agents passing the door between the first and the last passing time;
  ``crashes_per_agent``: decisions in which an agent hit a wall or another agent, per agent and trial;
  ``trials``: simulated trials (``trials * P``).
- ``fundamental_diagram.csv`` (``agents, trial, frame, density, speed, flow``) and ``fundamental_diagram.png``:
  Gaussian local density (1/m^2), local speed (m/s) and flow (1/(m s)) of equations 2-5, radius
  ``measurement.radius``, sampled every frame at the point ``measurement.distance`` in front of the door centre,
  one colour and fitted curve per agent count.
- ``density_map_<agents>.npy`` (int64 ``(nx, ny)`` agent-frames per tile, x-major, of all trials) and ``.png``.
- ``trajectories/geometry.wkt`` and ``trajectories/agents_<agents>/trial_XXX.txt`` (PedPy text format) for the
  first ``export.trials`` simulated trials (``XXX`` is the run number).
- ``animation_<agents>.gif``: the first simulated trial, agents coloured by speed.
- ``tb/``: TensorBoard scalars ``eval/<column>`` (step = agent count), the figures as images, the config as text.

Frames: frame 0 is the initial state and frame ``t`` the state after decision ``t``; an agent is in frame ``t``
when it took decision ``t`` (so it appears in the frame where it passes the door, beyond the door line, and in
the last frame of a trial cut by ``max_decisions``).
"""

from __future__ import annotations

import copy
import csv
import json
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Any, Final

import hydra
import numpy as np
import torch
from matplotlib.figure import Figure
from omegaconf import DictConfig, ListConfig, OmegaConf

from pedrl.algos.controllers import Controller, GreedyDoorController, LearnedController
from pedrl.analysis import (
    DensityMap,
    FundamentalDiagram,
    RoomGeometry,
    SpeedDensityModel,
    Trajectories,
    animate_trial,
    compute_density_map,
    compute_fundamental_diagram,
    fit_speed_density,
    plot_density_map,
    plot_fundamental_diagram,
    write_geometry_wkt,
    write_pedpy_trajectory,
)
from pedrl.cli import hydra_output_dir, run_reporting_errors
from pedrl.io import CheckpointError, CsvWriter, RunLogger, load_checkpoint
from pedrl.sim import RoomEnv
from pedrl.sim.validation import (
    MAX_SEED,
    check_bool,
    check_choice,
    check_device,
    check_integer,
    check_memory,
    check_number,
)

CONFIG_DIR = str(Path(__file__).resolve().parent.parent / "conf")
SCALING_COLUMNS: Final = (
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
    "trials",
)
STUCK_WINDOW: Final = 20
"""Decisions at the end of a trial over which an agent still in the room counts as stuck if it did not move."""
STUCK_PATH: Final = 0.4
"""Path length (m) over those decisions below which it did not move: less than one body radius."""
DENSITY_MAP_BYTES_PER_TILE: Final = 40
"""Bytes per density-map tile in the memory estimate: the int64 counts, numpy's float64 histogram and the sum."""
RECORD_BYTES_PER_AGENT_FRAME: Final = 80
"""Bytes per recorded agent-frame of a batch in the memory estimate: positions and velocities (float32 x 2) on the
device, stacked on the host and again as trajectories, and the activity flags."""
FUNDAMENTAL_COLUMNS: Final = ("agents", "trial", "frame", "density", "speed", "flow")
CONTROLLERS: Final = ("learned", "greedy")
ENV_SEED_STRIDE: Final = 1009
"""Room seed of an agent count: ``seed * ENV_SEED_STRIDE + agents`` (a prime, so counts never share a seed)."""
CONTROLLER_SEED_STRIDE: Final = 1013
"""Controller seed of an agent count: ``seed * CONTROLLER_SEED_STRIDE + agents``."""


# ---------------------------------------------------------------------- what is evaluated
@dataclass
class Policy:
    """A checkpoint made ready to simulate.

    Attributes:
        controller: what chooses the actions.
        env_factory: ``env_factory(num_replicas=, num_agents=, device=)`` builds the checkpoint's room.
        processes: P, the learning processes stored in the checkpoint.
        tables: A, the learned tables per process.
        algo: the algorithm that wrote the checkpoint.
    """

    controller: Controller
    env_factory: Any
    processes: int
    tables: int
    algo: str


def load_policy(
    path: str | Path, *, controller: str, epsilon: float, device: torch.device, max_decisions: int | None
) -> Policy:
    """Reload a checkpoint written by ``pedrl-train``: its room, quantizer and tables.

    The room and the trainer are built from the known classes only, with the stored config's values validated as
    if a user had typed them; a stored config that names code (a ``_target_`` other than pedrl's room and
    trainers, anywhere) is refused before anything is built. Every tensor is checked against that config
    (:func:`pedrl.algos.restore.restore_state`), whichever the controller.

    Raises:
        CheckpointError: one line, for a missing, foreign, corrupt or crafted file, or one whose trainer cannot
            be rebuilt.
    """
    from omegaconf.errors import OmegaConfBaseException

    from pedrl.algos.registry import env_factory
    from pedrl.algos.restore import check_stored_config, restore_state
    from pedrl.runtime import build_trainer

    checkpoint = load_checkpoint(path, device=device)
    saved = copy.deepcopy(check_stored_config(checkpoint))  # plain values only, no _target_ but pedrl's
    saved["device"] = str(device)
    if max_decisions is not None:
        saved["env"]["max_decisions"] = max_decisions
    try:
        trainer = build_trainer(OmegaConf.create(saved), run_dir=Path(path).parent)
        factory = env_factory(saved["env"])
    except (ValueError, OmegaConfBaseException, KeyError, TypeError) as err:
        raise CheckpointError(
            f"checkpoint {str(path)!r} holds a config this pedrl refuses ({_first_line(err)})"
        ) from None
    state = restore_state(trainer, checkpoint, continue_training=False)
    q_values, quantizer = state.q_values, state.quantizer
    processes, tables = q_values.shape[0], q_values.shape[1]
    if controller == "greedy":
        greedy = GreedyDoorController(epsilon=epsilon, generator=torch.Generator(device=device))
        return Policy(greedy, factory, processes, tables, trainer.name)
    learned = LearnedController(
        q_values=q_values,
        encode=partial(trainer.encode_observations, quantizer),
        epsilon=epsilon,
        # the trainer's generator also fills void neighbour slots (IT-VQQL): one seed covers both
        generator=trainer.generator,
    )
    return Policy(learned, factory, processes, tables, trainer.name)


# ---------------------------------------------------------------------- recording
@dataclass(frozen=True)
class BatchRecord:
    """One trial in each of R replicas, recorded frame by frame (numpy, on the host).

    Attributes:
        positions: ``(R, T, N, 2)`` agent centres (m), frame 0 the initial state, frame t after decision t.
        velocities: ``(R, T, N, 2)`` velocities (m/s).
        active: ``(R, T, N)`` bool, the agent is in frame t (it took decision t; every agent in frame 0).
        reached: ``(R, N)`` bool, the agent passed the door.
        exit_time: ``(R, N)`` time (s) at which it passed the door, NaN if it did not.
        crashes: ``(R, N)`` decisions in which it hit a wall or another agent.
        speed_sum: ``(R,)`` sum over agents and decisions taken of the speed after the decision (m/s).
        speed_sq_sum: ``(R,)`` the same sum of squared speeds (m^2/s^2).
        speed_count: ``(R,)`` decisions taken (agent-decisions).
    """

    positions: np.ndarray
    velocities: np.ndarray
    active: np.ndarray
    reached: np.ndarray
    exit_time: np.ndarray
    crashes: np.ndarray
    speed_sum: np.ndarray
    speed_sq_sum: np.ndarray
    speed_count: np.ndarray

    def trajectories(self, replica: int, geometry: RoomGeometry, framerate: float) -> Trajectories:
        return Trajectories(
            positions=self.positions[replica],
            velocities=self.velocities[replica],
            active=self.active[replica],
            framerate=framerate,
            geometry=geometry,
        )


def record_batch(env: RoomEnv, controller: Controller) -> BatchRecord:
    """Reset ``env`` (its generator draws the scene) and run one trial in every replica to its end."""
    obs, info = env.reset()
    shape = env.active.shape
    device = env.positions.device
    positions, velocities, active = [env.positions.cpu()], [env.velocities.cpu()], [env.active.cpu()]
    reached = torch.zeros(shape, dtype=torch.bool, device=device)
    exit_time = torch.full(shape, float("nan"), device=device)
    crashes = torch.zeros(shape, dtype=torch.int64, device=device)
    speed_sum = torch.zeros(shape, dtype=torch.float64, device=device)
    speed_sq_sum = torch.zeros(shape, dtype=torch.float64, device=device)
    speed_count = torch.zeros(shape, dtype=torch.int64, device=device)
    decision = 0
    while bool(env.active.any()):
        acting = env.active
        actions = controller.act(env, obs, info)
        obs, _, _, _, info = env.step(actions)
        decision += 1
        reached |= info["reached"]
        exit_time = torch.where(info["reached"], decision * env.decision_length, exit_time)
        crashes += (info["crashed_agent"] | info["crashed_wall"]).to(torch.int64)
        speed = torch.where(acting, info["speed"].double(), 0.0)
        speed_sum += speed
        speed_sq_sum += speed * speed
        speed_count += acting.to(torch.int64)
        positions.append(env.positions.cpu())
        velocities.append(env.velocities.cpu())
        active.append(acting.cpu())
    return BatchRecord(
        positions=torch.stack(positions, 1).numpy(),
        velocities=torch.stack(velocities, 1).numpy(),
        active=torch.stack(active, 1).numpy(),
        reached=reached.cpu().numpy(),
        exit_time=exit_time.cpu().numpy(),
        crashes=crashes.cpu().numpy(),
        speed_sum=speed_sum.sum(1).cpu().numpy(),
        speed_sq_sum=speed_sq_sum.sum(1).cpu().numpy(),
        speed_count=speed_count.sum(1).cpu().numpy(),
    )


# ---------------------------------------------------------------------- statistics
@dataclass
class ScalingStats:
    """Per-trial figures of one agent count, gathered batch after batch."""

    fails_pct: list[float] = field(default_factory=list)
    evacuation_times: list[float] = field(default_factory=list)
    door_flows: list[float] = field(default_factory=list)
    crashes_per_agent: list[float] = field(default_factory=list)
    stuck_pct: list[float] = field(default_factory=list)
    speed_sum: float = 0.0
    speed_sq_sum: float = 0.0
    speed_count: int = 0

    def add(self, record: BatchRecord, keep: int) -> None:
        """Add the first ``keep`` replicas of ``record``."""
        reached, exit_time = record.reached[:keep], record.exit_time[:keep]
        num_agents = reached.shape[1]
        self.fails_pct.extend((100.0 * (1.0 - reached.mean(axis=1))).tolist())
        self.crashes_per_agent.extend((record.crashes[:keep].sum(axis=1) / num_agents).tolist())
        self.stuck_pct.extend((100.0 * stuck_agents(record.positions[:keep], reached).mean(axis=1)).tolist())
        self.speed_sum += float(record.speed_sum[:keep].sum())
        self.speed_sq_sum += float(record.speed_sq_sum[:keep].sum())
        self.speed_count += int(record.speed_count[:keep].sum())
        for passed, times in zip(reached, exit_time, strict=True):
            times = times[passed]
            if passed.all():
                self.evacuation_times.append(float(times.max()))
            if times.size >= 2 and times.max() > times.min():
                self.door_flows.append(float((times.size - 1) / (times.max() - times.min())))

    def row(self, agents: int) -> dict[str, Any]:
        """The ``scaling.csv`` row (see the module docstring)."""
        fails = np.asarray(self.fails_pct)
        count = max(self.speed_count, 1)
        mean_speed = self.speed_sum / count
        variance = max(self.speed_sq_sum / count - mean_speed**2, 0.0)
        return {
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
            "trials": len(self.fails_pct),
        }


def stuck_agents(positions: np.ndarray, reached: np.ndarray) -> np.ndarray:
    """Agents still in the room at the end whose last ``STUCK_WINDOW`` decisions moved them less than ``STUCK_PATH``.

    Args:
        positions: ``(R, T, N, 2)`` centres (m), frame 0 the initial state; an agent that did not reach the door
            was in the room until the last frame (its trial was cut by the clock).
        reached: ``(R, N)`` bool, the agent passed the door.

    Returns:
        ``(R, N)`` bool.
    """
    window = positions[:, -(STUCK_WINDOW + 1) :]  # the last 20 decisions (all of them in shorter trials)
    path = np.linalg.norm(np.diff(window, axis=1), axis=-1).sum(axis=1)  # (R, N) m
    return ~reached & (path < STUCK_PATH)


# ---------------------------------------------------------------------- the evaluation
def evaluate(cfg: DictConfig, *, run_dir: str | Path | None = None) -> list[dict[str, Any]]:
    """Evaluate ``cfg.checkpoint`` at every agent count of ``cfg.agents``; returns the ``scaling.csv`` rows.

    Every output goes under ``run_dir`` (default: Hydra's output dir); see the module docstring.

    Raises:
        ValueError: one line, for an invalid config value (before any compute).
        CheckpointError: one line, for a checkpoint that cannot be used.
    """
    # ---- validation and setup: every check before any compute
    _validate(cfg)
    from pedrl.runtime import set_threads

    set_threads(cfg.get("threads"))
    run_dir = Path(run_dir) if run_dir is not None else hydra_output_dir()
    device = torch.device(cfg.device)
    policy = load_policy(
        cfg.checkpoint,
        controller=cfg.controller,
        epsilon=float(cfg.epsilon),
        device=device,
        max_decisions=cfg.max_decisions,
    )
    trials_per_batch = min(int(cfg.trials_per_batch), int(cfg.trials))
    envs = {
        int(agents): policy.env_factory(
            num_replicas=policy.processes * trials_per_batch, num_agents=int(agents), device=device
        )
        for agents in cfg.agents
    }
    first = next(iter(envs.values()))
    geometry = RoomGeometry(width=first.width, length=first.length, door_width=first.door_width)
    _check_against_room(cfg, geometry, envs)
    point = (geometry.width / 2, geometry.length - float(cfg.measurement.distance))
    label = f"{policy.algo} ({cfg.controller})"
    run_dir.mkdir(parents=True, exist_ok=True)
    logger = RunLogger(run_dir, tensorboard=cfg.tensorboard)
    logger.log_text("eval/config", "```\n" + OmegaConf.to_yaml(cfg) + "```")
    table = CsvWriter(run_dir / "scaling.csv", SCALING_COLUMNS)
    diagrams: dict[int, FundamentalDiagram] = {}
    rows: list[dict[str, Any]] = []
    print(
        f"pedrl-eval: {label}, {policy.processes} processes x {policy.tables} tables, agents {list(cfg.agents)}, "
        f"{cfg.trials} trials per process -> {run_dir}",
        flush=True,
    )

    # ---- one agent count after another
    try:
        for agents, env in envs.items():
            tic = time.perf_counter()
            env.generator.manual_seed(int(cfg.seed) * ENV_SEED_STRIDE + agents)
            if isinstance(policy.controller, LearnedController | GreedyDoorController):
                policy.controller.generator.manual_seed(int(cfg.seed) * CONTROLLER_SEED_STRIDE + agents)
            stats, diagram, density = _simulate_agent_count(env, policy, cfg, geometry, point, run_dir)
            row = stats.row(agents)
            rows.append(row)
            table.write(row)
            diagrams[agents] = diagram
            title = f"{label}: {agents} agents, {row['trials']} trials"
            figure = _write_density_map(run_dir, density, geometry, agents=agents, title=title)
            logger.log_figure(f"eval/density_map_{agents}", figure)
            logger.log_scalars(agents, {f"eval/{k}": v for k, v in row.items() if k != "agents"})
            print(
                f"  {agents:>4} agents: fails {row['fails_pct']:5.1f} ± {row['fails_std']:4.1f} %, "
                f"speed {row['mean_speed']:.2f} ± {row['speed_std']:.2f} m/s, stuck {row['stuck_pct']:.1f} %, "
                f"evacuated {row['evacuated_pct']:.0f} % of trials "
                f"({time.perf_counter() - tic:.1f} s)",
                flush=True,
            )
        figure = _write_fundamental_diagram(
            run_dir,
            diagrams,
            label=label,
            point=point,
            radius=float(cfg.measurement.radius),
            max_points=int(cfg.measurement.plot_points),
            seed=int(cfg.seed),
        )
        logger.log_figure("eval/fundamental_diagram", figure)
    finally:
        table.close()
        logger.close()
    # NaN (no trial evacuated, no flow measured) is not JSON: written as null
    clean = [{k: None if isinstance(v, float) and math.isnan(v) else v for k, v in row.items()} for row in rows]
    (run_dir / "scaling.json").write_text(json.dumps(clean, indent=2))
    return rows


def _simulate_agent_count(
    env: RoomEnv,
    policy: Policy,
    cfg: DictConfig,
    geometry: RoomGeometry,
    point: tuple[float, float],
    run_dir: Path,
) -> tuple[ScalingStats, FundamentalDiagram, DensityMap]:
    """``cfg.trials`` trials per process in batches: Table 4/5 figures, diagram samples, density map, exports."""
    stats = ScalingStats()
    diagrams: list[FundamentalDiagram] = []
    density: DensityMap | None = None
    runs_per_batch = env.num_replicas  # processes * trials_per_batch; replica i of batch b is run b * R + i
    total_runs = int(cfg.trials) * policy.processes
    to_export = min(int(cfg.export.trials), total_runs)
    folder = run_dir / "trajectories" / f"agents_{env.num_agents}"
    framerate = env.decisions_per_second
    for first_run in range(0, total_runs, runs_per_batch):
        record = record_batch(env, policy.controller)
        keep = min(runs_per_batch, total_runs - first_run)
        stats.add(record, keep)
        runs = [record.trajectories(i, geometry, framerate) for i in range(keep)]
        diagram = compute_fundamental_diagram(
            runs, point=point, radius=float(cfg.measurement.radius), min_density=float(cfg.measurement.min_density)
        )
        diagrams.append(_offset_trials(diagram, first_run))
        batch_map = compute_density_map(runs, tile_size=float(cfg.density_map.tile_size), geometry=geometry)
        density = batch_map if density is None else _add_maps(density, batch_map)
        if first_run == 0 and cfg.animation.enabled:
            animate_trial(
                runs[0],
                run_dir / f"animation_{env.num_agents}.gif",
                fps=float(cfg.animation.fps),
                max_frames=cfg.animation.max_frames,
                agent_radius=env.agent_radius,
                max_speed=env.max_speed,
            )
        for i in range(min(keep, to_export - first_run)):
            if first_run + i == 0:
                folder.mkdir(parents=True, exist_ok=True)
                write_geometry_wkt(run_dir / "trajectories" / "geometry.wkt", geometry)
            write_pedpy_trajectory(folder / f"trial_{first_run + i:03d}.txt", runs[i])
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


# ---------------------------------------------------------------------- figures and files
def _write_density_map(
    run_dir: Path, density: DensityMap, geometry: RoomGeometry, *, agents: int, title: str
) -> Figure:
    """``density_map_<agents>.npy`` (the counts) and ``density_map_<agents>.png``; returns the figure."""
    np.save(run_dir / f"density_map_{agents}.npy", density.counts)
    # a figure shaped like the room, so that the colour bar is as tall as the map
    plot_width = 4.0  # inches, besides ~2 for the axis labels and the colour bar
    plot_height = plot_width * geometry.length / geometry.width
    figure = Figure(figsize=(plot_width + 2.0, plot_height + 1.0), layout="constrained")
    axes = plot_density_map(density, geometry=geometry, axes=figure.add_subplot())
    _label_door(axes, geometry)
    axes.set_title(title, fontsize=10)
    figure.savefig(run_dir / f"density_map_{agents}.png", dpi=120)
    return figure


def _label_door(axes: Any, geometry: RoomGeometry) -> None:
    axes.annotate(
        "door",
        (geometry.width / 2, geometry.length),
        xytext=(0, 2),
        textcoords="offset points",
        ha="center",
        va="bottom",
        fontsize=8,
        color="tab:green",
    )


def _write_fundamental_diagram(
    run_dir: Path,
    diagrams: dict[int, FundamentalDiagram],
    *,
    label: str,
    point: tuple[float, float],
    radius: float,
    max_points: int,
    seed: int,
) -> Figure:
    """``fundamental_diagram.csv`` (every sample) and ``.png``; returns the figure.

    The figure shows at most ``max_points`` samples per agent count (a random subset: hundreds of thousands of
    points hide each other) and the least-squares fit of all samples, ``S(rho)`` linear and ``Q = rho S(rho)``.
    """
    with open(run_dir / "fundamental_diagram.csv", "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(FUNDAMENTAL_COLUMNS)
        for agents, diagram in diagrams.items():
            writer.writerows(
                zip(
                    [agents] * diagram.num_samples,
                    diagram.trial.tolist(),
                    diagram.frame.tolist(),
                    (f"{v:.6g}" for v in diagram.density),
                    (f"{v:.6g}" for v in diagram.speed),
                    (f"{v:.6g}" for v in diagram.flow),
                    strict=True,
                )
            )
    figure = Figure(figsize=(11.0, 4.8), layout="constrained")
    speed_axes, flow_axes = figure.subplots(1, 2)
    rng = np.random.default_rng(seed)
    largest = max((float(d.density.max()) for d in diagrams.values() if d.num_samples), default=1.0)
    grid = np.linspace(0.0, largest, 100)
    for index, (agents, diagram) in enumerate(diagrams.items()):
        color = f"C{index % 10}"
        if diagram.num_samples == 0:
            speed_axes.plot([], [], " ", label=f"{agents} agents: no sample")
            continue
        shown = diagram
        if diagram.num_samples > max_points:
            keep = np.sort(rng.choice(diagram.num_samples, size=max_points, replace=False))
            shown = replace(
                diagram,
                density=diagram.density[keep],
                speed=diagram.speed[keep],
                flow=diagram.flow[keep],
                trial=diagram.trial[keep],
                frame=diagram.frame[keep],
            )
        plot_fundamental_diagram(shown, axes=(speed_axes, flow_axes), fit=False, color=color)
        for collection in (*speed_axes.collections[-1:], *flow_axes.collections[-1:]):
            collection.set_sizes([4.0])
            collection.set_alpha(0.25)
        name = f"{agents} agents ({diagram.num_samples} samples)"
        if len(np.unique(diagram.density)) > SpeedDensityModel.LINEAR.value:
            fit = fit_speed_density(diagram, model=SpeedDensityModel.LINEAR)
            speed_axes.plot(grid, fit.speed(grid), color=color, linewidth=2.0, label=name)
            flow_axes.plot(grid, fit.flow(grid), color=color, linewidth=2.0, label=name)
        else:
            speed_axes.plot([], [], "o", color=color, label=name)
    if not any(d.num_samples for d in diagrams.values()):
        for axes in (speed_axes, flow_axes):
            axes.text(0.5, 0.5, "no frame above min_density", ha="center", va="center", transform=axes.transAxes)
    for axes in (speed_axes, flow_axes):
        axes.set_xlim(0.0, largest * 1.02)
        axes.set_ylim(bottom=0.0)
        if axes.get_legend_handles_labels()[0]:
            axes.legend(fontsize=8, title="lines: least-squares fit", title_fontsize=8, loc="upper right")
    speed_axes.set_title("speed-density", fontsize=10)
    flow_axes.set_title("flow-density", fontsize=10)
    figure.suptitle(
        f"Fundamental diagram, {label}: Gaussian R = {radius:g} m at ({point[0]:g}, {point[1]:g}) m, "
        f"at most {max_points} samples drawn per agent count",
        fontsize=11,
    )
    figure.savefig(run_dir / "fundamental_diagram.png", dpi=120)
    return figure


# ---------------------------------------------------------------------- validation
def _validate(cfg: DictConfig) -> None:
    """Raise a one-line ``ValueError`` naming the first invalid (or missing) value of the eval config."""
    from omegaconf.errors import OmegaConfBaseException

    try:
        _validate_values(cfg)
    except OmegaConfBaseException as err:  # e.g. a key deleted with ~key
        raise ValueError(f"the eval config is incomplete: {_first_line(err)}") from None


def _validate_values(cfg: DictConfig) -> None:
    checkpoint = cfg.get("checkpoint")
    if checkpoint in (None, "", "???"):
        raise ValueError("checkpoint is missing: pass checkpoint=<path of a .safetensors checkpoint>")
    agents = cfg.get("agents")
    if not isinstance(agents, ListConfig | list | tuple) or not agents:
        raise ValueError(f"agents={agents!r} is invalid: must be a non-empty list of integers >= 1, e.g. [20,40]")
    agents = list(agents)
    if any(isinstance(a, bool) or not isinstance(a, int) or a < 1 for a in agents):
        raise ValueError(f"agents={agents!r} is invalid: must be a non-empty list of integers >= 1, e.g. [20,40]")
    if len(set(agents)) != len(agents):
        raise ValueError(f"agents={agents!r} is invalid: every agent count must appear once")
    check_integer("trials", cfg.get("trials"), minimum=1)
    check_integer("trials_per_batch", cfg.get("trials_per_batch"), minimum=1)
    check_choice("controller", cfg.get("controller"), CONTROLLERS)
    check_number("epsilon", cfg.get("epsilon"), low=0.0, high=1.0)
    if cfg.get("max_decisions") is not None:
        check_integer("max_decisions", cfg.max_decisions, minimum=1)
    check_integer("seed", cfg.get("seed"), minimum=0, maximum=MAX_SEED)
    threads = cfg.get("threads")
    if threads is not None:
        check_integer("threads", threads, minimum=1)
    check_device(cfg.get("device"))
    check_number("measurement.radius", cfg.measurement.radius, low=0.0, low_open=True)
    check_number("measurement.distance", cfg.measurement.distance, low=0.0)
    check_number("measurement.min_density", cfg.measurement.min_density, low=0.0)
    check_integer("measurement.plot_points", cfg.measurement.plot_points, minimum=1)
    check_number("density_map.tile_size", cfg.density_map.tile_size, low=0.0, low_open=True)
    check_integer("export.trials", cfg.export.trials, minimum=0)
    check_bool("animation.enabled", cfg.animation.enabled)
    check_number("animation.fps", cfg.animation.fps, low=0.0, low_open=True)
    if cfg.animation.max_frames is not None:
        check_integer("animation.max_frames", cfg.animation.max_frames, minimum=1)
    check_bool("tensorboard", cfg.get("tensorboard"))


def _check_against_room(cfg: DictConfig, geometry: RoomGeometry, envs: dict[int, RoomEnv]) -> None:
    """The checks that need the checkpoint's room, before any compute: the measurement point lies inside it, and
    the recordings, density maps and room states fit in memory."""
    distance = float(cfg.measurement.distance)
    if distance >= geometry.length:
        raise ValueError(
            f"measurement.distance={cfg.measurement.distance!r} is invalid: the measurement point must be inside the "
            f"room, a distance in [0, {geometry.length:g}) m (the room's length) in front of the door"
        )
    tile_size = float(cfg.density_map.tile_size)
    tiles = math.ceil(geometry.width / tile_size) * math.ceil(geometry.length / tile_size)
    largest = max(envs.values(), key=lambda env: env.num_replicas * env.num_agents)
    frames = largest.num_replicas * (largest.max_decisions + 1) * largest.num_agents  # agent-frames of one batch
    check_memory(
        {
            f"density map (density_map.tile_size={cfg.density_map.tile_size!r}: {tiles:.3g} tiles)": (
                DENSITY_MAP_BYTES_PER_TILE * tiles
            ),
            "recorded trials": RECORD_BYTES_PER_AGENT_FRAME * frames,
            "room": max(env.step_memory() for env in envs.values()),
        },
        device=largest.device,
        advice="raise density_map.tile_size, or lower trials_per_batch, the agents or max_decisions",
    )


def _first_line(err: BaseException) -> str:
    return (str(err).strip().splitlines() or [type(err).__name__])[0]


# ---------------------------------------------------------------------- console
def print_table(rows: list[dict[str, Any]], label: str) -> None:
    """Tables 4/5 (and the extra columns) on the console."""
    header = (
        f"{'agents':>6} | {'fails % (std)':>14} | {'speed m/s (std)':>15} | {'evacuation s (trials)':>21} | "
        f"{'stuck %':>7} | {'door flow 1/s':>13} | {'crashes/agent':>13}"
    )
    print(f"\n  {label}\n  {header}\n  {'-' * len(header)}")
    for r in rows:
        evacuation = f"{r['evacuation_time_s']:.1f} ({r['evacuated_trials']}/{r['trials']})"
        print(
            f"  {r['agents']:>6} | {r['fails_pct']:6.2f} ({r['fails_std']:5.2f}) | "
            f"{r['mean_speed']:7.2f} ({r['speed_std']:4.2f}) | {evacuation:>21} | {r['stuck_pct']:7.1f} | "
            f"{r['door_flow']:13.3f} | "
            f"{r['crashes_per_agent']:13.2f}"
        )


@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="eval")
def main(cfg: DictConfig) -> None:
    """Evaluate a checkpoint at scale and print Tables 4/5; a bad value or file exits with code 2 and one line."""
    rows = run_reporting_errors("pedrl-eval", lambda: evaluate(cfg))
    print_table(rows, f"{cfg.controller} controller, {cfg.checkpoint}")


if __name__ == "__main__":
    main()

"""``pedrl-eval``: reload a checkpoint and simulate it with more agents (paper section 6, Tables 4 and 5).

``main`` is a thin ``@hydra.main`` wrapper around the importable ``evaluate(cfg)``.

For every agent count it runs ``trials`` trials in every learning process stored in the checkpoint and writes:
``scaling.csv`` (Tables 4/5 and more), ``fundamental_diagram.csv`` and ``.png`` (equations 2-5),
``density_map_<agents>.npy`` and ``.png``, PedPy trajectories under ``trajectories/``, ``animation_<agents>.gif``,
and TensorBoard scalars and figures under ``tb/``.
"""

from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Final

import hydra
import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from pedrl.algos.controllers import Controller, GreedyDoorController, LearnedController
from pedrl.analysis import (
    DensityMap,
    FundamentalDiagram,
    RoomGeometry,
    Trajectories,
    animate_trial,
    compute_density_map,
    compute_fundamental_diagram,
    plot_density_map,
    plot_fundamental_diagram,
    write_geometry_wkt,
    write_pedpy_trajectory,
)
from pedrl.io import CheckpointError, CsvWriter, RunLogger, load_checkpoint
from pedrl.sim import RoomEnv

CONFIG_DIR = str(Path(__file__).resolve().parent.parent / "conf")
SCALING_COLUMNS: Final = (
    "agents",
    "fails_pct",
    "fails_std",
    "mean_speed",
    "speed_std",
    "evacuation_time_s",
    "evacuated_trials",
    "door_flow",
    "crashes_per_agent",
    "trials",
)
CONTROLLERS: Final = ("learned", "greedy")


@dataclass
class ScalingAccumulator:
    """Running sums for one agent count."""

    fails_pct: list[float] = field(default_factory=list)
    evacuation_times: list[float] = field(default_factory=list)
    door_flows: list[float] = field(default_factory=list)
    crashes_per_agent: list[float] = field(default_factory=list)
    speed_sum: float = 0.0
    speed_sq_sum: float = 0.0
    speed_count: int = 0

    def row(self, agents: int) -> dict[str, Any]:
        fails = np.asarray(self.fails_pct)
        mean_speed = self.speed_sum / max(self.speed_count, 1)
        variance = max(self.speed_sq_sum / max(self.speed_count, 1) - mean_speed**2, 0.0)
        return {
            "agents": agents,
            "fails_pct": float(fails.mean()),
            "fails_std": float(fails.std()),
            "mean_speed": mean_speed,
            "speed_std": math.sqrt(variance),
            "evacuation_time_s": float(np.mean(self.evacuation_times)) if self.evacuation_times else float("nan"),
            "evacuated_trials": len(self.evacuation_times),
            "door_flow": float(np.mean(self.door_flows)) if self.door_flows else float("nan"),
            "crashes_per_agent": float(np.mean(self.crashes_per_agent)),
            "trials": len(self.fails_pct),
        }


def evaluate(cfg: DictConfig, *, run_dir: str | Path | None = None) -> list[dict[str, Any]]:
    """Evaluate ``cfg.checkpoint`` at every agent count of ``cfg.agents``; returns the scaling table rows."""
    _validate(cfg)
    run_dir = Path(run_dir) if run_dir is not None else _hydra_output_dir()
    run_dir.mkdir(parents=True, exist_ok=True)
    device = torch.device(cfg.device)
    checkpoint = load_checkpoint(cfg.checkpoint, device=device)
    controller, env_factory, processes = _controller_from_checkpoint(checkpoint, cfg)
    logger = RunLogger(run_dir, tensorboard=cfg.tensorboard)
    table = CsvWriter(run_dir / "scaling.csv", SCALING_COLUMNS)
    fd_rows: list[dict[str, Any]] = []
    diagrams: dict[int, FundamentalDiagram] = {}
    rows = []
    try:
        for agents in cfg.agents:
            tic = time.perf_counter()
            env = env_factory(num_replicas=processes * cfg.trials_per_batch, num_agents=int(agents), device=device)
            env.reset(seed=int(cfg.seed) * 1009 + int(agents))
            if isinstance(controller, LearnedController):
                controller.trainer.generator.manual_seed(int(cfg.seed) * 1013 + int(agents))
            geometry = RoomGeometry(width=env.width, length=env.length, door_width=env.door_width)
            stats, diagram, density = _simulate(env, controller, cfg, geometry, processes, run_dir)
            row = stats.row(int(agents))
            rows.append(row)
            table.write(row)
            diagrams[int(agents)] = diagram
            for sample in diagram.to_rows():
                fd_rows.append({"agents": int(agents), **sample})
            np.save(run_dir / f"density_map_{agents}.npy", density.counts)
            axes = plot_density_map(density, geometry=geometry)
            axes.set_title(f"{cfg.controller}: {agents} agents, {row['trials']} trials")
            axes.figure.savefig(run_dir / f"density_map_{agents}.png", dpi=120)
            logger.log_figure(f"eval/density_map_{agents}", axes.figure)
            logger.log_scalars(int(agents), {f"eval/{k}": v for k, v in row.items() if k != "agents"})
            print(
                f"  {agents:>4} agents: fails {row['fails_pct']:5.1f} ± {row['fails_std']:4.1f} %, "
                f"speed {row['mean_speed']:.2f} ± {row['speed_std']:.2f} m/s "
                f"({time.perf_counter() - tic:.1f} s)",
                flush=True,
            )
        _write_fundamental_diagram(run_dir, fd_rows, diagrams, cfg.controller, logger)
    finally:
        table.close()
        logger.close()
    (run_dir / "scaling.json").write_text(json.dumps(rows, indent=2))
    return rows


def _simulate(
    env: RoomEnv,
    controller: Controller,
    cfg: DictConfig,
    geometry: RoomGeometry,
    processes: int,
    run_dir: Path,
):
    """Run ``cfg.trials`` trials per process in batches; accumulate Table 4/5 figures, diagram samples and maps."""
    stats = ScalingAccumulator()
    diagrams: list[FundamentalDiagram] = []
    density: DensityMap | None = None
    exported = 0
    batches = math.ceil(cfg.trials / cfg.trials_per_batch)
    framerate = env.decisions_per_second
    for batch in range(batches):
        trajectories, reached, exit_time, crashes, speed_samples = _run_batch(env, controller)
        keep = min(cfg.trials_per_batch, cfg.trials - batch * cfg.trials_per_batch) * processes
        trajectories, reached, exit_time, crashes = (
            trajectories[:keep],
            reached[:keep],
            exit_time[:keep],
            crashes[:keep],
        )
        speeds = speed_samples[:, :keep]
        stats.speed_sum += float(speeds[~np.isnan(speeds)].sum())
        stats.speed_sq_sum += float((speeds[~np.isnan(speeds)] ** 2).sum())
        stats.speed_count += int((~np.isnan(speeds)).sum())
        num_agents = reached.shape[1]
        stats.fails_pct.extend((100.0 * (1.0 - reached.mean(axis=1))).tolist())
        stats.crashes_per_agent.extend((crashes.sum(axis=1) / num_agents).tolist())
        for i in range(keep):
            times = exit_time[i][reached[i]]
            if reached[i].all():
                stats.evacuation_times.append(float(times.max()))
            if times.size >= 2 and times.max() > times.min():
                stats.door_flows.append(float((times.size - 1) / (times.max() - times.min())))
        runs = [
            Trajectories(
                positions=t["positions"],
                velocities=t["velocities"],
                active=t["active"],
                framerate=framerate,
                geometry=geometry,
            )
            for t in trajectories
        ]
        diagrams.append(
            compute_fundamental_diagram(
                runs,
                radius=cfg.measurement.radius,
                point=_measurement_point(geometry, cfg),
                min_density=cfg.measurement.min_density,
            )
        )
        batch_map = compute_density_map(runs, tile_size=cfg.density_map.tile_size, geometry=geometry)
        density = (
            batch_map
            if density is None
            else replace(
                density,
                counts=density.counts + batch_map.counts,
                num_frames=density.num_frames + batch_map.num_frames,
            )
        )
        folder = run_dir / "trajectories" / f"agents_{env.num_agents}"
        while exported < min(cfg.export.trials, len(runs)):
            if exported == 0:
                folder.mkdir(parents=True, exist_ok=True)
                write_geometry_wkt(run_dir / "trajectories" / "geometry.wkt", geometry)
                if cfg.animation.enabled:
                    animate_trial(
                        runs[0],
                        run_dir / f"animation_{env.num_agents}.gif",
                        fps=cfg.animation.fps,
                        max_frames=cfg.animation.max_frames,
                        agent_radius=env.agent_radius,
                        max_speed=env.max_speed,
                    )
            write_pedpy_trajectory(folder / f"trial_{exported:03d}.txt", runs[exported])
            exported += 1
    return stats, _merge_diagrams(diagrams), density


def _merge_diagrams(diagrams: list[FundamentalDiagram]) -> FundamentalDiagram:
    """One diagram from per-batch diagrams, trial indices made unique."""
    offsets = np.cumsum([0] + [int(d.trial.max()) + 1 if d.num_samples else 0 for d in diagrams[:-1]])
    return replace(
        diagrams[0],
        density=np.concatenate([d.density for d in diagrams]),
        speed=np.concatenate([d.speed for d in diagrams]),
        flow=np.concatenate([d.flow for d in diagrams]),
        trial=np.concatenate([d.trial + o for d, o in zip(diagrams, offsets, strict=True)]),
        frame=np.concatenate([d.frame for d in diagrams]),
    )


def _measurement_point(geometry: RoomGeometry, cfg: DictConfig) -> tuple[float, float]:
    """The point ``measurement.distance`` metres inside the room in front of the door centre."""
    return (geometry.width / 2, geometry.length - float(cfg.measurement.distance))


def _write_fundamental_diagram(
    run_dir: Path, rows, diagrams: dict[int, FundamentalDiagram], controller: str, logger: RunLogger
) -> None:
    columns = ["agents", *(diagrams[next(iter(diagrams))].columns() if diagrams else [])]
    writer = CsvWriter(run_dir / "fundamental_diagram.csv", columns)
    for row in rows:
        writer.write(row)
    writer.close()
    speed_axes = flow_axes = None
    for agents, diagram in diagrams.items():
        if diagram.num_samples < 3:
            continue
        speed_axes, flow_axes = plot_fundamental_diagram(
            diagram,
            axes=None if speed_axes is None else (speed_axes, flow_axes),
            label=f"{controller}, {agents} agents",
        )
    if speed_axes is not None:
        speed_axes.figure.savefig(run_dir / "fundamental_diagram.png", dpi=120)
        logger.log_figure("eval/fundamental_diagram", speed_axes.figure)


def _controller_from_checkpoint(checkpoint, cfg: DictConfig):
    """The controller to evaluate, the room factory of the checkpoint's config, and the process count."""
    from hydra.utils import instantiate

    from pedrl.train import build_trainer

    saved = checkpoint.metadata.get("config")
    if not saved or "env" not in saved or "algo" not in saved:
        raise CheckpointError(f"checkpoint {str(checkpoint.path)!r} holds no training config to rebuild the room")
    saved = OmegaConf.create(saved)
    saved.device = cfg.device
    if cfg.max_decisions is not None:
        saved.env.max_decisions = cfg.max_decisions
    env_factory = instantiate(saved.env, _partial_=True, _convert_="all")
    q_values = checkpoint.tensors["q_values"]
    processes = int(q_values.shape[0])
    if cfg.controller == "greedy":
        return GreedyDoorController(), env_factory, processes
    trainer = build_trainer(saved, run_dir=".")
    quantizer = trainer.quantizer_from_state_dict(checkpoint.tensors_with_prefix("quantizer"))
    controller = LearnedController(trainer=trainer, quantizer=quantizer, q_values=q_values, epsilon=cfg.epsilon)
    return controller, env_factory, processes


def _validate(cfg: DictConfig) -> None:
    if cfg.get("checkpoint") in (None, "", "???"):
        raise ValueError("checkpoint is missing: pass checkpoint=<path to a .safetensors checkpoint>")
    agents = list(cfg.agents)
    if not agents or any(isinstance(a, bool) or not isinstance(a, int) or a < 1 for a in agents):
        raise ValueError(f"agents={agents!r} is invalid: must be a list of integers >= 1")
    for key in ("trials", "trials_per_batch"):
        value = cfg.get(key)
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{key}={value!r} is invalid: must be an integer >= 1")
    if cfg.controller not in CONTROLLERS:
        raise ValueError(f"controller={cfg.controller!r} is invalid: must be one of {', '.join(CONTROLLERS)}")
    epsilon = cfg.epsilon
    if isinstance(epsilon, bool) or not isinstance(epsilon, int | float) or not 0.0 <= epsilon <= 1.0:
        raise ValueError(f"epsilon={epsilon!r} is invalid: must be a number in [0, 1]")
    if cfg.device != "cpu" and not str(cfg.device).startswith("cuda"):
        raise ValueError(f"device={cfg.device!r} is invalid: must be 'cpu' or 'cuda[:index]'")
    if str(cfg.device).startswith("cuda") and not torch.cuda.is_available():
        raise ValueError(f"device={cfg.device!r} is invalid here: no CUDA GPU is available (use device=cpu)")


def _hydra_output_dir() -> Path:
    from hydra.core.hydra_config import HydraConfig

    return Path(HydraConfig.get().runtime.output_dir)


def print_table(rows: list[dict[str, Any]], controller: str) -> None:
    """Tables 4/5 on the console."""
    print(f"\n  {controller}: agents | fails % (std) | speed m/s (std) | evacuation s | door flow 1/s | crashes/agent")
    for r in rows:
        print(
            f"  {r['agents']:>6} | {r['fails_pct']:6.2f} ({r['fails_std']:5.2f}) | {r['mean_speed']:5.2f} "
            f"({r['speed_std']:4.2f}) | {r['evacuation_time_s']:12.1f} | {r['door_flow']:13.3f} | "
            f"{r['crashes_per_agent']:.2f}"
        )


@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="eval")
def main(cfg: DictConfig) -> None:
    """Evaluate a checkpoint at scale and print Tables 4/5."""
    from hydra.errors import InstantiationException

    try:
        rows = evaluate(cfg)
    except (ValueError, CheckpointError) as err:
        print(f"pedrl-eval: error: {err}", file=sys.stderr)
        sys.exit(2)
    except InstantiationException as err:
        cause = err.__cause__ or err
        print(f"pedrl-eval: error: {str(cause).splitlines()[0]}", file=sys.stderr)
        sys.exit(2)
    print_table(rows, cfg.controller)


if __name__ == "__main__":
    main()


def _run_batch(env: RoomEnv, controller: Controller):
    """One trial in every replica, recording trajectories (frame t = state after decision t)."""
    obs, info = env.reset()
    positions = [env.positions.cpu()]
    velocities = [env.velocities.cpu()]
    active = [env.active.cpu()]
    reached = torch.zeros_like(env.active)
    exit_time = torch.full(env.active.shape, float("nan"), device=env.positions.device)
    crashes = torch.zeros(env.active.shape, device=env.positions.device)
    speeds = []
    decision = 0
    while bool(env.active.any()):
        valid = env.active.clone()
        actions = controller.act(env, obs, info)
        obs, _, _, _, info = env.step(actions)
        decision += 1
        reached |= info["reached"]
        exit_time = torch.where(info["reached"], decision * env.decision_length, exit_time)
        crashes += (info["crashed_agent"] | info["crashed_wall"]).float()
        speeds.append(torch.where(valid, info["speed"], float("nan")).cpu())
        positions.append(env.positions.cpu())
        velocities.append(env.velocities.cpu())
        # an agent is kept in the frame where it passes the door, so exports show it leaving
        active.append((env.active | info["reached"]).cpu())
    pos = torch.stack(positions, 1).numpy()
    vel = torch.stack(velocities, 1).numpy()
    act = torch.stack(active, 1).numpy()
    trajectories = [{"positions": pos[i], "velocities": vel[i], "active": act[i]} for i in range(pos.shape[0])]
    return (
        trajectories,
        reached.cpu().numpy(),
        exit_time.cpu().numpy(),
        crashes.cpu().numpy(),
        torch.stack(speeds).numpy() if speeds else np.zeros((0, *env.active.shape)),
    )

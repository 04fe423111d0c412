"""``pedrl-train``: the Hydra entry point that trains VQQL, IT-VQQL or IN-VQQL.

``main`` is a thin ``@hydra.main`` wrapper; ``train(cfg)`` does the work and is importable by tests.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import hydra
import torch
from omegaconf import DictConfig, OmegaConf

from pedrl.algos import Trainer, TrainResult
from pedrl.cli import hydra_output_dir, run_reporting_errors
from pedrl.io import CheckpointError
from pedrl.sim.validation import MAX_SEED, check_integer

CONFIG_DIR = str(Path(__file__).resolve().parent.parent / "conf")


def build_trainer(cfg: DictConfig, run_dir: str | Path) -> Trainer:
    """Instantiate the trainer of ``cfg.algo`` with the room of ``cfg.env``; validates every value first."""
    from hydra.utils import instantiate

    _check_top_level(cfg)
    env = instantiate(cfg.env, _partial_=True, _convert_="all")
    config = OmegaConf.to_container(cfg, resolve=True)
    return instantiate(
        cfg.algo,
        _convert_="all",
        _recursive_=False,
        env=env,
        vq=OmegaConf.to_container(cfg.vq, resolve=True),
        processes=cfg.processes,
        rooms_per_process=cfg.rooms_per_process,
        checkpoint_every=cfg.checkpoint_every,
        device=cfg.device,
        seed=cfg.seed,
        run_dir=str(run_dir),
        tensorboard=cfg.logger.tensorboard,
        progress=cfg.progress,
        run_config=config,
    )


def train(cfg: DictConfig, *, run_dir: str | Path | None = None) -> TrainResult:
    """Train as configured and write every output under ``run_dir`` (default: Hydra's output dir).

    Outputs: ``learning_curve.csv``, ``learning_curve.png``, ``summary.json``, ``tb/`` (TensorBoard events) and
    ``checkpoints/iter_XXXX.safetensors`` + ``checkpoints/last.safetensors``.
    """
    run_dir = Path(run_dir) if run_dir is not None else hydra_output_dir()
    resume_from = _resume_path(cfg.get("resume"), run_dir)
    if resume_from is not None and cfg.get("resume") is not True:
        run_dir = resume_from.parent.parent  # continue writing into the run that holds the checkpoint
    trainer = build_trainer(cfg, run_dir)
    set_threads(cfg.get("threads"))
    torch.manual_seed(int(cfg.seed))
    result = trainer.fit(resume_from=resume_from)
    _write_outputs(result, trainer)
    return result


def _write_outputs(result: TrainResult, trainer: Trainer) -> None:
    from pedrl.plot import plot_learning_curve_file

    figure_path = result.run_dir / "learning_curve.png"
    plot_learning_curve_file(result.run_dir / "learning_curve.csv", figure_path, label=trainer.name)
    summary = {
        "algo": trainer.name,
        "final": result.final,
        "wall_time_s": result.wall_time_s,
        "phases": result.phases,
        "checkpoint": str(result.checkpoint),
    }
    (result.run_dir / "summary.json").write_text(json.dumps(summary, indent=2))


def print_summary(result: TrainResult, name: str) -> None:
    """The closing console table."""
    f = result.final
    rows = [
        ("algorithm", name),
        (
            "final success rate",
            f"{f.get('success_rate_mean', float('nan')):.3f} ± {f.get('success_rate_std', 0):.3f}",
        ),
        ("crashes with agents / agent", f"{f.get('crashes_agent_mean', float('nan')):.2f}"),
        ("crashes with walls / agent", f"{f.get('crashes_wall_mean', float('nan')):.2f}"),
        ("mean speed (m/s)", f"{f.get('mean_speed_mean', float('nan')):.2f}"),
        ("wall time (s)", f"{result.wall_time_s:.1f}"),
        ("outputs", str(result.run_dir)),
        ("checkpoint", str(result.checkpoint)),
        ("monitor", f"tensorboard --logdir {result.run_dir / 'tb'}"),
    ]
    width = max(len(k) for k, _ in rows)
    print("\n" + "\n".join(f"  {k:<{width}}  {v}" for k, v in rows))


def set_threads(threads: int | None) -> None:
    """Set torch's CPU thread count (None: leave torch's default); validated by :func:`build_trainer`."""
    if threads is not None and torch.get_num_threads() != threads:
        torch.set_num_threads(threads)


def _check_top_level(cfg: DictConfig) -> None:
    if cfg.get("threads") is not None:
        check_integer("threads", cfg.get("threads"), minimum=1)
    for key, minimum in (("processes", 1), ("rooms_per_process", 1), ("checkpoint_every", 0)):
        check_integer(key, cfg.get(key), minimum=minimum)
    check_integer("seed", cfg.get("seed"), minimum=0, maximum=MAX_SEED)


def _resume_path(resume: Any, run_dir: Path) -> Path | None:
    if resume is None or resume is False:
        return None
    if resume is True:
        path = run_dir / "checkpoints" / "last.safetensors"
        if not path.is_file():
            raise CheckpointError(
                f"resume=true but {str(path)!r} does not exist: pass hydra.run.dir=<the run to continue> "
                "or resume=<path to a checkpoint>"
            )
        return path
    if isinstance(resume, str):
        return Path(resume)
    raise ValueError(f"resume={resume!r} is invalid: must be null, true, or the path of a checkpoint")


@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="train")
def main(cfg: DictConfig) -> float:
    """Train; print a closing summary; return the final success rate (for sweepers)."""
    result = run_reporting_errors("pedrl-train", lambda: train(cfg))
    print_summary(result, cfg.algo._target_.rsplit(".", 1)[-1])
    return result.final.get("success_rate_mean", 0.0)


if __name__ == "__main__":
    main()

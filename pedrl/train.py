"""``pedrl-train``: the Hydra entry point that trains VQQL, IT-VQQL or IN-VQQL.

``main`` is a thin ``@hydra.main`` wrapper; ``train(cfg)`` does the work and is importable by tests.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import hydra
import torch
from omegaconf import DictConfig, OmegaConf

from pedrl.algos import Trainer, TrainResult
from pedrl.algos.registry import check_names_no_code, env_factory, trainer_class, vq_settings
from pedrl.cli import hydra_output_dir, run_reporting_errors
from pedrl.io import CheckpointError
from pedrl.io.files import replace_atomically
from pedrl.sim.validation import MAX_SEED, check_integer

CONFIG_DIR = str(Path(__file__).resolve().parent.parent / "conf")


def build_trainer(cfg: DictConfig, run_dir: str | Path) -> Trainer:
    """Build the trainer of ``cfg.algo`` with the room of ``cfg.env``; validates every value first.

    Only the known room and trainer classes are built (:mod:`pedrl.algos.registry`): a config names no code, so
    a ``_target_`` other than theirs, anywhere, is refused, and nothing is instantiated from a config node.
    """
    _check_top_level(cfg)
    config = OmegaConf.to_container(cfg, resolve=True)
    check_names_no_code(config)
    trainer, settings = trainer_class(config["algo"])
    return trainer(
        **settings,
        env=env_factory(config["env"], config.get("scenario")),
        vq=vq_settings(config["vq"]),
        processes=config["processes"],
        rooms_per_process=config["rooms_per_process"],
        checkpoint_every=config["checkpoint_every"],
        device=config["device"],
        seed=config["seed"],
        run_dir=str(run_dir),
        tensorboard=config["logger"]["tensorboard"],
        progress=config["progress"],
        run_config=config,
    )


def train(cfg: DictConfig, *, run_dir: str | Path | None = None) -> TrainResult:
    """Train as configured and write every output under ``run_dir`` (default: Hydra's output dir).

    Outputs: ``learning_curve.csv``, ``learning_curve.png``, ``summary.json``, ``tb/`` (TensorBoard events) and
    ``checkpoints/iter_XXXX.safetensors`` + ``checkpoints/last.safetensors``.
    """
    run_dir = Path(run_dir) if run_dir is not None else hydra_output_dir()
    resume_from = _resume_path(cfg.get("resume"), run_dir)
    if resume_from is not None and resume_from.parent.name == "checkpoints":
        run_dir = resume_from.parent.parent  # continue writing into the run that holds the checkpoint
    trainer = build_trainer(cfg, run_dir)
    set_threads(cfg.get("threads") if cfg.get("threads") is not None else launcher_threads())
    torch.manual_seed(int(cfg.seed))
    result = trainer.fit(resume_from=resume_from)
    summary_path = result.run_dir / "summary.json"
    if result.finished_before and summary_path.is_file():
        # a finished run: its summary and figures stay as they are
        result.final = result.final or _stored_final(summary_path)
        print(f"pedrl-train: {str(result.run_dir)!r} had already finished; its outputs are kept", flush=True)
        return result
    _write_outputs(result, trainer)
    return result


def _write_outputs(result: TrainResult, trainer: Trainer) -> None:
    from pedrl.plot import plot_learning_curve_file

    curve_path = result.run_dir / "learning_curve.csv"
    if curve_path.is_file():  # a finished run resumed from a copied checkpoint has no curve of its own
        plot_learning_curve_file(curve_path, result.run_dir / "learning_curve.png", label=trainer.name)
    summary = {
        "algo": trainer.name,
        "final": result.final,
        "wall_time_s": result.wall_time_s,
        "phases": result.phases,
        "checkpoint": str(result.checkpoint),
    }
    text = json.dumps(summary, indent=2)
    replace_atomically(result.run_dir / "summary.json", lambda temporary: temporary.write_text(text))


def _stored_final(summary_path: Path) -> dict[str, float]:
    """The final figures of a finished run's ``summary.json`` (empty if it cannot be read)."""
    try:
        final = json.loads(summary_path.read_text()).get("final", {})
    except (OSError, ValueError, AttributeError):
        return {}
    return final if isinstance(final, dict) else {}


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


def launcher_threads() -> int | None:
    """This job's share of the cores when it runs under ``hydra/launcher=parallel``: ``cores // n_jobs`` (at least 1),
    so that the jobs running side by side do not each spin one OpenMP thread per core against each other; None
    otherwise (a single run, or another launcher: torch's default)."""
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return None
    launcher = HydraConfig.get().get("launcher") or {}
    if "joblib" not in str(launcher.get("_target_", "")).lower():
        return None
    return share_of_cores(launcher.get("n_jobs"), available_cores())


def available_cores() -> int:
    """CPU cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def share_of_cores(n_jobs: Any, cores: int) -> int:
    """Threads per job when ``n_jobs`` jobs share ``cores`` cores: ``cores // jobs``, at least 1.

    ``n_jobs`` follows joblib: a positive count, ``-1`` one job per core, ``-2`` all cores but one, and so on;
    None counts as one job.
    """
    jobs = 1 if n_jobs is None else int(n_jobs)
    if jobs < 0:
        jobs = max(1, cores + 1 + jobs)
    return max(1, cores // max(1, jobs))


def _check_top_level(cfg: DictConfig) -> None:
    if cfg.get("threads") is not None:
        check_integer("threads", cfg.get("threads"), minimum=1)
    for key, minimum in (("processes", 1), ("rooms_per_process", 1), ("checkpoint_every", 0)):
        check_integer(key, cfg.get(key), minimum=minimum)
    check_integer("seed", cfg.get("seed"), minimum=0, maximum=MAX_SEED)


def _resume_path(resume: Any, run_dir: Path) -> Path | None:
    """The checkpoint to continue from: ``resume=true`` is the run directory's ``checkpoints/last.safetensors``;
    ``resume=<a run directory>`` that directory's; ``resume=<a file>`` that checkpoint."""
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
    if isinstance(resume, str) and resume:
        path = Path(resume)
        if path.is_dir():
            last = path / "checkpoints" / "last.safetensors"
            if not last.is_file():
                raise CheckpointError(
                    f"resume={resume!r} is a directory without checkpoints/last.safetensors: pass a run directory "
                    "that holds one, or the path of a .safetensors checkpoint"
                )
            return last
        return path
    raise ValueError(f"resume={resume!r} is invalid: must be null, true, a run directory or the path of a checkpoint")


@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="train")
def main(cfg: DictConfig) -> float:
    """Train; print a closing summary; return the final success rate (for sweepers)."""
    result = run_reporting_errors("pedrl-train", lambda: train(cfg))
    print_summary(result, cfg.algo._target_.rsplit(".", 1)[-1])
    return result.final.get("success_rate_mean", 0.0)


if __name__ == "__main__":
    main()

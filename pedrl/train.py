"""``pedrl-train``: the Hydra entry point that trains VQQL, IT-VQQL or IN-VQQL.

``main`` is a thin ``@hydra.main`` wrapper; ``train(cfg)`` does the work and is importable by tests.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import hydra
import torch
from omegaconf import DictConfig

from pedrl.algos import Trainer, TrainResult
from pedrl.algos.registry import build_trainer
from pedrl.cli import (
    CONFIG_DIR,
    OutputDirCheck,
    checked_groups,
    describe_os_error,
    fail,
    hydra_output_dir,
    run_reporting_errors,
)
from pedrl.io import CheckpointError
from pedrl.io.files import check_outputs, replace_atomically
from pedrl.io.lock import RunFolderInUseError, run_folder_lock
from pedrl.runtime import launcher_threads, set_threads


def train(cfg: DictConfig, *, run_dir: str | Path | None = None) -> TrainResult:
    """Train as configured and write every output under ``run_dir`` (default: Hydra's output dir).

    Outputs: ``learning_curve.csv``, ``learning_curve.png``, ``summary.json``, ``tb/`` (TensorBoard events) and
    ``checkpoints/iter_XXXX.safetensors`` + ``checkpoints/last.safetensors``. The run holds the folder's lock
    (:mod:`pedrl.io.lock`) from before its first computation to its last output: while it runs, a second ``train``
    into the same folder (or a resume of it) raises :class:`pedrl.io.lock.RunFolderInUseError`.
    """
    run_dir = Path(run_dir) if run_dir is not None else hydra_output_dir()
    resume_from = _resume_path(cfg.get("resume"), run_dir)
    if resume_from is not None and resume_from.parent.name == "checkpoints":
        run_dir = resume_from.parent.parent  # continue writing into the run that holds the checkpoint
    trainer = build_trainer(cfg, run_dir)
    check_outputs(*output_paths(run_dir, tensorboard=bool(cfg.logger.get("tensorboard", False))))
    set_threads(cfg.get("threads") if cfg.get("threads") is not None else launcher_threads())
    torch.manual_seed(int(cfg.seed))
    with run_folder_lock(run_dir):  # one run per folder: a second one (or a resume) is refused in one line
        result = trainer.fit(resume_from=resume_from)
        summary_path = result.run_dir / "summary.json"
        if result.finished_before and summary_path.is_file():
            # a finished run: its summary and figures stay as they are
            result.final = result.final or _stored_final(summary_path)
            print(f"pedrl-train: {str(result.run_dir)!r} had already finished; its outputs are kept", flush=True)
            return result
        _write_outputs(result, trainer)
    return result


def output_paths(run_dir: Path, *, tensorboard: bool) -> tuple[list[Path], list[Path]]:
    """The folders and files a run writes under ``run_dir``, checked before any compute
    (:func:`pedrl.io.files.check_outputs`)."""
    folders = [run_dir, run_dir / "checkpoints", *([run_dir / "tb"] if tensorboard else [])]
    files = [run_dir / name for name in ("learning_curve.csv", "learning_curve.png", "summary.json")]
    return folders, [*files, run_dir / "checkpoints" / "last.safetensors"]


def _write_outputs(result: TrainResult, trainer: Trainer) -> None:
    from pedrl.learning_curves import plot_learning_curve_file

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
    final = {k: None if isinstance(v, float) and math.isnan(v) else v for k, v in (result.final or {}).items()}
    text = json.dumps(summary | {"final": final}, indent=2)  # NaN (no door flow measured) is not JSON: null
    replace_atomically(result.run_dir / "summary.json", lambda temporary: temporary.write_text(text))


def _stored_final(summary_path: Path) -> dict[str, float]:
    """The final figures of a finished run's ``summary.json`` (empty if it cannot be read)."""
    try:
        final = json.loads(summary_path.read_text()).get("final", {})
    except (OSError, ValueError, AttributeError):
        return {}
    return final if isinstance(final, dict) else {}


def _figure(final: dict[str, Any], key: str) -> float:
    """A final figure, NaN when absent or null (a summary.json of an older run, no door flow measured)."""
    value = final.get(key)
    return float("nan") if value is None else float(value)


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
        ("evacuation time (s)", f"{_figure(f, 'evacuation_time_mean'):.1f}"),
        ("door flow (persons/s)", f"{_figure(f, 'door_flow_mean'):.2f}"),
        ("wall time (s)", f"{result.wall_time_s:.1f}"),
        ("outputs", str(result.run_dir)),
        ("checkpoint", str(result.checkpoint)),
        ("monitor", f"tensorboard --logdir {result.run_dir / 'tb'}"),
    ]
    width = max(len(k) for k, _ in rows)
    print("\n" + "\n".join(f"  {k:<{width}}  {v}" for k, v in rows))


def _resume_path(resume: Any, run_dir: Path) -> Path | None:
    """The checkpoint to continue from: ``resume=true`` is the run directory's ``checkpoints/last.safetensors``;
    ``resume=<a run directory>`` that directory's; ``resume=<a file>`` that checkpoint."""
    if resume is None or resume is False:
        return None
    if resume is True:
        path = run_dir / "checkpoints" / "last.safetensors"
        if not path.is_file():
            raise CheckpointError(
                f"resume=true but {str(path)!r} does not exist: "
                + _iteration_offer(
                    path.parent, "pass hydra.run.dir=<the run to continue> or resume=<path to a checkpoint>"
                )
            )
        return path
    if isinstance(resume, str) and resume:
        path = Path(resume)
        if path.is_dir():
            last = path / "checkpoints" / "last.safetensors"
            if not last.is_file():
                raise CheckpointError(
                    f"resume={resume!r} is a directory without checkpoints/last.safetensors: "
                    + _iteration_offer(
                        last.parent, "pass a run directory that holds one, or the path of a .safetensors checkpoint"
                    )
                )
            return last
        return path
    raise ValueError(f"resume={resume!r} is invalid: must be null, true, a run directory or the path of a checkpoint")


def _iteration_offer(folder: Path, otherwise: str) -> str:
    """What to do when ``folder`` (a run's ``checkpoints/``) lacks ``last.safetensors`` (a full disk or a kill while
    it was written): resume from its newest intact ``iter_XXXX`` checkpoint, which the message names, or
    ``otherwise``."""
    iterations = sorted(folder.glob("iter_[0-9][0-9][0-9][0-9].safetensors")) if folder.is_dir() else []
    if not iterations:
        return otherwise
    return (
        f"its newest iteration checkpoint is there: pass resume={str(iterations[-1])!r} to continue from it "
        "(the trials after it are learned again)"
    )


class RunFolderCheck(OutputDirCheck):
    """Hydra callback of ``pedrl-train`` (``conf/train.yaml``): before Hydra writes into the run folder (``.hydra/``,
    the job log), refuse in one line (exit code 2) a folder that cannot hold a run (:class:`~pedrl.cli.OutputDirCheck`)
    or whose lock another run holds, so that a second run does not overwrite what the first one recorded. It only
    tries the lock: :func:`train` holds it for the run."""

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        super().on_run_start(config, **kwargs)  # hydra.run.dir resolved and writable, else one line
        directory = OutputDirCheck.folder
        try:
            with run_folder_lock(directory):
                pass
        except RunFolderInUseError as err:
            fail("pedrl-train", str(err))
        except OSError as err:
            fail("pedrl-train", describe_os_error(err))


@checked_groups("pedrl-train", CONFIG_DIR)
@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="train")
def main(cfg: DictConfig) -> float:
    """Train; print a closing summary; return the final success rate (for sweepers)."""
    result = run_reporting_errors("pedrl-train", lambda: train(cfg))
    print_summary(result, cfg.algo._target_.rsplit(".", 1)[-1])
    return result.final.get("success_rate_mean", 0.0)


if __name__ == "__main__":
    main()

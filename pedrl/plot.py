"""``pedrl-plot``: learning curves of one or more runs together, in the style of the paper's Figures 5 and 7.

``pedrl-plot runs=[outputs/A,outputs/B,outputs/C]`` reads each run's ``learning_curve.csv`` and draws the success
rate (mean over learning processes, with a ±std band) against the trial number, with the iteration or stage
boundaries of every run dashed. ``main`` is a thin Hydra wrapper around :func:`plot_runs`.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import hydra
import numpy as np
from omegaconf import DictConfig

from pedrl.analysis import plot_learning_curves
from pedrl.cli import run_reporting_errors
from pedrl.io import read_csv

CONFIG_DIR = str(Path(__file__).resolve().parent.parent / "conf")


def read_learning_curve(path: str | Path, *, metric: str = "success_rate", smooth: int = 1):
    """Read ``learning_curve.csv``.

    Args:
        path: the CSV, or the run directory holding it.
        metric: one of the curve metrics (``success_rate``, ``episodic_return``, ...).
        smooth: moving-average window in trials (1: raw).

    Returns:
        ``(global_trial (T,), mean (T,), std (T,), boundaries)`` where boundaries are the trial numbers at which a
        new phase (iteration or stage) starts.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "learning_curve.csv"
    if not path.is_file():
        raise ValueError(f"no learning curve at {str(path)!r}: expected a run directory of pedrl-train")
    rows = read_csv(path)
    if not rows:
        raise ValueError(f"learning curve {str(path)!r} has no rows yet")
    if f"{metric}_mean" not in rows[0]:
        raise ValueError(f"metric={metric!r} is not in {str(path)!r}")
    trials = np.array([int(r["global_trial"]) for r in rows], dtype=float)
    mean = np.array([float(r[f"{metric}_mean"]) for r in rows])
    std = np.array([float(r[f"{metric}_std"]) for r in rows])
    phases = np.array([int(r["phase"]) for r in rows])
    boundaries = trials[1:][np.diff(phases) != 0].tolist()
    if smooth > 1:
        mean, std = _moving_average(mean, phases, smooth), _moving_average(std, phases, smooth)
    return trials, mean, std, boundaries


def _moving_average(values: np.ndarray, phases: np.ndarray, window: int) -> np.ndarray:
    """Trailing moving average that restarts at every phase boundary (phases learn from scratch)."""
    out = np.empty_like(values)
    for phase in np.unique(phases):
        idx = np.flatnonzero(phases == phase)
        cumulative = np.cumsum(np.insert(values[idx], 0, 0.0))
        ends = np.arange(1, idx.size + 1)
        starts = np.maximum(ends - window, 0)
        out[idx] = (cumulative[ends] - cumulative[starts]) / (ends - starts)
    return out


def plot_runs(
    runs: Sequence[str | Path],
    output: str | Path,
    *,
    labels: Sequence[str] | None = None,
    metric: str = "success_rate",
    smooth: int = 1,
) -> Path:
    """Draw the learning curves of ``runs`` in one figure saved at ``output``; returns ``output``."""
    labels = list(labels) if labels else [Path(r).name for r in runs]
    if len(labels) != len(runs):
        raise ValueError(f"labels={list(labels)!r} is invalid: must give one label per run ({len(runs)})")
    curves, boundaries = {}, []
    for run, label in zip(runs, labels, strict=True):
        trials, mean, std, bounds = read_learning_curve(run, metric=metric, smooth=smooth)
        curves[label] = (trials, mean, std)
        boundaries.extend(bounds)
    ylabel = "success rate (fraction of agents reaching the door)" if metric == "success_rate" else metric
    axes = plot_learning_curves(curves, boundaries=sorted(set(boundaries)), ylabel=ylabel)
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    axes.figure.tight_layout()
    axes.figure.savefig(output, dpi=120)
    return output


def plot_learning_curve_file(csv_path: str | Path, output: str | Path, *, label: str, smooth: int = 1) -> Path:
    """``learning_curve.png`` of one run."""
    return plot_runs([Path(csv_path).parent], output, labels=[label], smooth=smooth)


@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="plot")
def main(cfg: DictConfig) -> None:
    """Plot the runs of ``cfg.runs`` together."""

    def plot() -> Path:
        runs = list(cfg.runs)
        if not runs:
            raise ValueError("runs=[] is invalid: give one or more run directories, e.g. runs=[outputs/a,outputs/b]")
        return plot_runs(runs, cfg.output, labels=cfg.labels, metric=cfg.metric, smooth=int(cfg.smooth))

    path = run_reporting_errors("pedrl-plot", plot)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()

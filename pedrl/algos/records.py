"""What a run writes under its folder: ``learning_curve.csv``, TensorBoard events and checkpoints (:class:`RunRecord`),
and the figures they hold."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Final

from pedrl.algos.phase import Phase
from pedrl.io import CsvWriter, RunLogger, save_checkpoint
from pedrl.trial.rollout import Gathered, TrialStats
from pedrl.trial.walking import SCALARS as WALKING_SCALARS

CURVE_METRICS: Final = (
    "success_rate",
    "episodic_return",
    "crashes_agent",
    "crashes_wall",
    "mean_speed",
    "td_error",
    "evacuation_time",
    "door_flow",
)
CURVE_COLUMNS: Final = (
    "phase",
    "agents",
    "trial",
    "global_trial",
    "epsilon",
    *(f"{m}_{s}" for m in CURVE_METRICS for s in ("mean", "std")),
    "decisions_per_s",
    "room",
    *(f"walking_{name}" for name in WALKING_SCALARS),
)


class RunRecord:
    """The files of one run under ``run_dir``, and its wall time over every segment.

    Args:
        run_dir: the run's folder.
        tensorboard: write TensorBoard events (``tb/``).
        config: the resolved run config (TensorBoard's text tab, and every checkpoint).
        wall_time_before: wall time (s) of the segments before the checkpoint resumed from.
    """

    def __init__(self, run_dir: Path, *, tensorboard: bool, config: Mapping[str, Any], wall_time_before: float = 0.0):
        self.run_dir, self.tensorboard, self.config = run_dir, tensorboard, config
        self._start, self._before = time.perf_counter(), wall_time_before
        self.logger: RunLogger | None = None
        self.curve: CsvWriter | None = None

    @property
    def checkpoint_path(self) -> Path:
        """``checkpoints/last.safetensors``: the latest checkpoint, rewritten at every save."""
        return self.run_dir / "checkpoints" / "last.safetensors"

    def wall_time(self) -> float:
        """Wall time of the run so far (s): this segment plus the segments before the checkpoint resumed from."""
        return self._before + time.perf_counter() - self._start

    def open(self, global_trial: int, *, resumed: bool) -> None:
        """Open TensorBoard and ``learning_curve.csv``; a resumed run drops what was logged from ``global_trial`` on."""
        self.logger = RunLogger(
            self.run_dir, tensorboard=self.tensorboard, purge_step=global_trial if resumed else None
        )
        if not resumed:
            self.logger.log_text("config", markdown_table(self.config))
        keep = rows_before(global_trial) if resumed else None
        self.curve = CsvWriter(self.run_dir / "learning_curve.csv", CURVE_COLUMNS, keep_rows=keep)

    def close(self) -> None:
        for writer in (self.curve, self.logger):
            if writer is not None:
                writer.close()

    def log_trial(
        self,
        phase: Phase,
        trial: int,
        global_trial: int,
        epsilon: float,
        stats: TrialStats,
        rate: float,
        *,
        room: str = "",
        agents: int | None = None,
        per_room: bool = False,
        walking: Mapping[str, float] | None = None,
    ) -> None:
        """Write one trial's row of ``learning_curve.csv`` and its TensorBoard scalars (mean and spread over the
        processes); the row names the ``room`` it was played in and its ``agents`` (None: the phase's), and
        ``per_room`` (training across scenarios) also logs the room's own curves, ``rooms/<room>/<metric>``.
        ``walking``: the free-walking probe's figures after this trial (:class:`pedrl.trial.walking.WalkingLog`),
        ``walking/<name>`` and the ``walking_<name>`` columns (empty in the rows of the trials not probed)."""
        row: dict[str, Any] = {
            "phase": phase.index,
            "agents": phase.num_agents if agents is None else agents,
            "trial": trial,
            "global_trial": global_trial,
            "epsilon": epsilon,
            "decisions_per_s": rate,
            "room": room,
            **final_figures(stats),
            **{f"walking_{name}": value for name, value in (walking or {}).items()},
        }
        for metric in CURVE_METRICS:
            tag = "losses/td_error" if metric == "td_error" else f"charts/{metric}"
            self.logger.log_spread(global_trial, tag, getattr(stats, metric).double())
        self.logger.log_scalars(
            global_trial,
            {"charts/decisions_per_s": rate, "charts/epsilon": epsilon, "charts/phase": phase.index},
        )
        if per_room:
            means = {f"rooms/{room}/{metric}": float(getattr(stats, metric).mean()) for metric in CURVE_METRICS}
            self.logger.log_scalars(global_trial, means)
        if walking:
            self.logger.log_scalars(global_trial, {f"walking/{name}": value for name, value in walking.items()})
        self.curve.write(row)

    def log_phase(
        self, phase: Phase, global_trial: int, gathered: Gathered, prototypes: int, distortion: float, q_values
    ) -> dict[str, Any]:
        """Log a new phase's quantizer to TensorBoard (``vq/*`` at its first global trial); returns its summary."""
        summary = {
            "phase": phase.index,
            "agents": phase.num_agents,
            "gathered_states": int(gathered.states.shape[0]),
            "gather_success_rate": gathered.success_rate,
            "prototypes": int(prototypes),
            "distortion": distortion,
            "q_table_mib": q_values.numel() * q_values.element_size() / 2**20,
        }
        scalars = ("distortion", "prototypes", "gather_success_rate", "q_table_mib")
        self.logger.log_scalars(global_trial, {f"vq/{key}": summary[key] for key in scalars})
        return summary

    def save(self, tensors: dict[str, Any], metadata: dict[str, Any], phase: Phase, *, iteration: bool) -> None:
        """Write ``last.safetensors`` (and ``iter_XXXX.safetensors`` at the end of a phase) atomically, with the run
        config and wall time added to ``metadata``."""
        metadata = {**metadata, "config": self.config, "wall_time_s": self.wall_time()}
        if iteration:
            path = self.run_dir / "checkpoints" / f"iter_{phase.index:04d}.safetensors"
            save_checkpoint(path, tensors=tensors, metadata=metadata)
        save_checkpoint(self.checkpoint_path, tensors=tensors, metadata=metadata)


def report_phase(description: str, trials: int, tic: float, stats: TrialStats | None) -> None:
    """One line per phase instead of a progress bar when the console is not a terminal (a log file)."""
    success = f", success {float(stats.success_rate.mean()):.2f}" if stats is not None else ""
    print(f"{description}: {trials} trials in {time.perf_counter() - tic:.1f} s{success}", flush=True)


def final_figures(stats: TrialStats) -> dict[str, float]:
    """Mean and spread over the processes of every curve metric of a trial: ``{metric}_mean``, ``{metric}_std``
    (over the processes where it was measured; NaN where none was)."""
    figures = {}
    for metric in CURVE_METRICS:
        values = getattr(stats, metric).double()
        values = values[~values.isnan()]  # door_flow: processes with no flow measured
        figures[f"{metric}_mean"] = float(values.mean()) if values.numel() else float("nan")
        figures[f"{metric}_std"] = float(values.std(unbiased=False)) if values.numel() else float("nan")
    return figures


def markdown_table(config: Mapping[str, Any]) -> str:
    """The run config as a two-column markdown table of dotted keys (TensorBoard's text tab)."""
    rows = ["|parameter|value|", "|-|-|"]

    def walk(node: Mapping[str, Any], prefix: str) -> None:
        for key, value in node.items():
            if isinstance(value, Mapping):
                walk(value, f"{prefix}{key}.")
            else:
                rows.append(f"|{prefix}{key}|{value}|")

    walk(config, "")
    return "\n".join(rows)


def rows_before(global_trial: int) -> Callable[[Mapping[str, str]], bool]:
    """Keeps the learning-curve rows of the trials before ``global_trial`` (those a resumed run does not redo)."""

    def keep(row: Mapping[str, str]) -> bool:
        value = row.get("global_trial") or ""
        return value.isdigit() and int(value) < global_trial

    return keep


def interactive() -> bool:
    """True when stderr is a terminal, where a progress bar redraws in place (in a log file it would not)."""
    return sys.stderr.isatty()

"""Run logging: TensorBoard scalars and figures, and the per-trial ``learning_curve.csv``.

Metric name spaces (documented in the README):
    charts/   what the agents achieve (success_rate, episodic_return, crashes_agent, crashes_wall, mean_speed,
              decisions_per_s, epsilon)
    vq/       the quantizer (distortion, prototypes)
    losses/   the learning signal (td_error)
    eval/     scaled evaluation
Each scalar is logged as the mean over learning processes under its own tag, with the standard deviation under
``spread/<name>_std`` and a TensorBoard "margin" chart (mean, mean - std, mean + std) in the Custom Scalars tab.
"""

from __future__ import annotations

import csv
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import torch

# TensorBoard is imported lazily: it is slow to import and runs that disable it never pay for it.


class RunLogger:
    """Writes TensorBoard events under ``<run_dir>/tb`` and CSV rows under ``<run_dir>``.

    Args:
        run_dir: the run directory (Hydra's output dir).
        tensorboard: write TensorBoard events.
        purge_step: on resume, the first global step to rewrite; TensorBoard drops events at or after it.
        flush_secs: how often TensorBoard flushes to disk.
    """

    def __init__(
        self,
        run_dir: str | os.PathLike,
        *,
        tensorboard: bool = True,
        purge_step: int | None = None,
        flush_secs: int = 30,
    ) -> None:
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self._writer = None
        self._margin_tags: dict[str, list[str]] = {}
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            self._writer = SummaryWriter(log_dir=str(self.run_dir / "tb"), purge_step=purge_step, flush_secs=flush_secs)

    @property
    def tensorboard_dir(self) -> Path | None:
        return self.run_dir / "tb" if self._writer is not None else None

    def log_scalars(self, step: int, values: Mapping[str, float]) -> None:
        """Log plain scalars (``tag -> value``) at ``step``."""
        if self._writer is None:
            return
        for tag, value in values.items():
            self._writer.add_scalar(tag, float(value), step)

    def log_spread(self, step: int, tag: str, per_process: torch.Tensor) -> None:
        """Log the mean of ``per_process (R,)`` under ``tag`` and its std under ``spread/<name>_std``."""
        if self._writer is None:
            return
        values = per_process.detach().double().cpu()
        mean = float(values.mean())
        std = float(values.std(unbiased=False)) if values.numel() > 1 else 0.0
        name = tag.split("/")[-1]
        self._writer.add_scalar(tag, mean, step)
        self._writer.add_scalar(f"spread/{name}_std", std, step)
        self._writer.add_scalar(f"spread/{name}_lower", mean - std, step)
        self._writer.add_scalar(f"spread/{name}_upper", mean + std, step)
        self._margin_tags.setdefault(tag, [tag, f"spread/{name}_lower", f"spread/{name}_upper"])

    def log_text(self, tag: str, text: str) -> None:
        if self._writer is not None:
            self._writer.add_text(tag, text, 0)

    def log_figure(self, tag: str, figure: Any, step: int = 0) -> None:
        """Log a matplotlib figure as an image."""
        if self._writer is not None:
            self._writer.add_figure(tag, figure, step, close=False)

    def flush(self) -> None:
        if self._writer is None:
            return
        if self._margin_tags:
            layout: dict[str, dict[str, list[Any]]] = {"mean ± std over processes": {}}
            for tag, tags in self._margin_tags.items():
                layout["mean ± std over processes"][tag] = ["Margin", tags]
            self._writer.add_custom_scalars(layout)
        self._writer.flush()

    def close(self) -> None:
        if self._writer is not None:
            self.flush()
            self._writer.close()
            self._writer = None


class CsvWriter:
    """Appends rows to a CSV file with a fixed header, flushing after every row.

    Args:
        path: the file.
        columns: the header.
        keep_rows: on resume, keep only the existing rows for which this predicate is true (the rest are dropped,
            so a resumed run rewrites exactly the rows an uninterrupted one would have written).
    """

    def __init__(self, path: str | os.PathLike, columns: Sequence[str], *, keep_rows=None) -> None:
        self.path = Path(path)
        self.columns = list(columns)
        kept: list[dict[str, str]] = []
        if keep_rows is not None and self.path.exists():
            with open(self.path, newline="") as handle:
                kept = [row for row in csv.DictReader(handle) if keep_rows(row)]
        self._handle = open(self.path, "w", newline="")  # noqa: SIM115 - closed in close()
        self._writer = csv.DictWriter(self._handle, fieldnames=self.columns)
        self._writer.writeheader()
        for row in kept:
            self._writer.writerow({c: row.get(c, "") for c in self.columns})
        self._handle.flush()

    def write(self, row: Mapping[str, Any]) -> None:
        self._writer.writerow({c: _format(row.get(c, "")) for c in self.columns})
        self._handle.flush()

    def close(self) -> None:
        if not self._handle.closed:
            self._handle.close()


def _format(value: Any) -> Any:
    if isinstance(value, float):
        return f"{value:.6g}"
    return value


def read_csv(path: str | os.PathLike) -> list[dict[str, str]]:
    """Read a CSV written by :class:`CsvWriter` into a list of row dictionaries."""
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))

"""Run logging: TensorBoard scalars and figures, and the per-trial ``learning_curve.csv``.

Metric name spaces (documented in docs/outputs.md):
    charts/   what the agents achieve (success_rate, episodic_return, crashes_agent, crashes_wall, mean_speed,
              evacuation_time, door_flow, decisions_per_s, epsilon)
    vq/       the quantizer (distortion, prototypes)
    losses/   the learning signal (td_error)
    eval/     scaled evaluation
Each scalar is logged as the mean over learning processes under its own tag, with the standard deviation under
``spread/<name>_std`` and a TensorBoard "margin" chart (mean, mean - std, mean + std) in the Custom Scalars tab.
"""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import torch

from pedrl.io.files import named, replace_atomically

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
        """Log the mean of ``per_process (R,)`` under ``tag`` and its std under ``spread/<name>_std``, over the
        values that are not NaN (nothing when none is)."""
        if self._writer is None:
            return
        values = per_process.detach().double().cpu()
        values = values[~values.isnan()]  # a figure some processes did not measure (a door flow)
        if values.numel() == 0:
            return
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

    The file is first replaced atomically (temporary sibling, fsync, ``os.replace``) by the header and the rows
    kept, so that a process killed while it is rewritten leaves the old file whole, never a truncated one.

    Args:
        path: the file.
        columns: the header.
        keep_rows: on resume, keep only the existing rows for which this predicate is true (the rest are dropped,
            so a resumed run rewrites exactly the rows an uninterrupted one would have written). A last line cut
            short by a kill is never kept.
    """

    def __init__(self, path: str | os.PathLike, columns: Sequence[str], *, keep_rows=None) -> None:
        self.path = Path(path)
        self.columns = list(columns)
        kept = _complete_rows(self.path, keep_rows) if keep_rows is not None and self.path.exists() else []
        replace_atomically(self.path, lambda temporary: self._write_start(temporary, kept))
        self._handle = open(self.path, "a", newline="")  # noqa: SIM115 - closed in close()
        self._writer = csv.DictWriter(self._handle, fieldnames=self.columns)

    def _write_start(self, temporary: Path, kept: list[dict[str, str]]) -> None:
        with open(temporary, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=self.columns)
            writer.writeheader()
            for row in kept:
                writer.writerow({c: row.get(c, "") for c in self.columns})

    def write(self, row: Mapping[str, Any]) -> None:
        try:
            self._writer.writerow({c: _format(row.get(c, "")) for c in self.columns})
            self._handle.flush()
        except OSError as err:  # a full disk names no file: name the table
            raise named(err, self.path) from err

    def close(self) -> None:
        if not self._handle.closed:
            try:
                self._handle.close()
            except OSError as err:
                raise named(err, self.path) from err


def _complete_rows(path: Path, keep_rows) -> list[dict[str, str]]:
    """The rows of ``path`` that ``keep_rows`` accepts, without a last line left unfinished by a kill."""
    with open(path, newline="") as handle:
        text = handle.read()
    if not text.endswith("\n"):
        text = text[: text.rfind("\n") + 1]
    return [row for row in csv.DictReader(io.StringIO(text)) if None not in row.values() and keep_rows(row)]


def _format(value: Any) -> Any:
    if isinstance(value, float):
        return f"{value:.6g}"
    return value


def read_csv(path: str | os.PathLike) -> list[dict[str, str]]:
    """Read a CSV written by :class:`CsvWriter` into a list of row dictionaries."""
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))

"""Learning curves of runs: read a run's ``learning_curve.csv`` and draw one or more runs in one figure.

``pedrl-plot`` draws the runs it is given (paper Figures 5 and 7); ``pedrl-train`` draws each run's own
``learning_curve.png`` with :func:`plot_learning_curve_file`.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from pedrl.analysis import plot_learning_curves
from pedrl.io import read_csv


def read_learning_curve(path: str | Path, *, metric: str = "success_rate", smooth: int = 1, room: str | None = None):
    """Read ``learning_curve.csv``.

    Args:
        path: the CSV, or the run directory holding it.
        metric: one of the curve metrics (``success_rate``, ``episodic_return``, ...).
        smooth: moving-average window in trials (1: raw); the average is trailing and restarts at every phase.
        room: the rows of this room of a run trained across scenarios (its ``room`` column); None: the room of the
            last row, which is the run's own once a phase is complete (every row, for a run in one room).

    Returns:
        ``(global_trial (T,), mean (T,), std (T,), boundaries)`` where boundaries are the trial numbers at which a
        new phase (iteration or stage) starts.

    Raises:
        ValueError: no such file, no rows, an unknown metric, a bad ``smooth`` or a malformed row.
    """
    if isinstance(smooth, bool) or not isinstance(smooth, int) or smooth < 1:
        raise ValueError(f"smooth={smooth!r} is invalid: must be an integer >= 1 (trials in the moving average)")
    path = Path(path)
    if path.is_dir():
        path = path / "learning_curve.csv"
    if not path.is_file():
        raise ValueError(f"no learning curve at {str(path)!r}: expected a run directory of pedrl-train")
    try:
        rows = read_csv(path)
    except (UnicodeDecodeError, csv.Error) as err:  # a binary or garbled file
        reason = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise ValueError(f"learning curve {str(path)!r} is not a CSV text file ({reason})") from None
    if not rows:
        raise ValueError(f"learning curve {str(path)!r} has no rows yet")
    rooms = curve_rooms(rows)
    if room is not None and room not in rooms:
        raise ValueError(f"room={room!r} is not in {str(path)!r}: one of {', '.join(rooms) or 'none (no room column)'}")
    rows = room_rows(rows, room)
    if f"{metric}_mean" not in rows[0]:
        known = sorted(k[: -len("_mean")] for k in rows[0] if k.endswith("_mean"))
        raise ValueError(f"metric={metric!r} is not in {str(path)!r}: one of {', '.join(known)}")
    try:
        trials = np.array([int(r["global_trial"]) for r in rows], dtype=float)
        mean = np.array([float(r[f"{metric}_mean"]) for r in rows])
        std = np.array([float(r[f"{metric}_std"]) for r in rows])
        phases = np.array([int(r["phase"]) for r in rows])
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"learning curve {str(path)!r} is malformed: {err!r}") from None
    boundaries = trials[1:][np.diff(phases) != 0].tolist()
    if smooth > 1:
        mean, std = _moving_average(mean, phases, smooth), _moving_average(std, phases, smooth)
    return trials, mean, std, boundaries


def room_rows(rows: Sequence[dict[str, str]], room: str | None = None) -> list[dict[str, str]]:
    """The rows of a learning curve played in ``room``; None: in the room of the last row, the run's own once a phase
    is complete. Every row for a run in one room (or written before rooms were logged)."""
    if len(curve_rooms(rows)) <= 1:
        return list(rows)
    room = room if room is not None else rows[-1]["room"]
    return [r for r in rows if r["room"] == room]


def curve_rooms(rows: Sequence[dict[str, str]]) -> list[str]:
    """The rooms of a learning curve's ``rows``, in the order they first play (none before rooms were logged)."""
    return list(dict.fromkeys(r["room"] for r in rows if r.get("room")))


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


def draw_runs(
    runs: Sequence[str | Path],
    *,
    labels: Sequence[str] | None = None,
    metric: str = "success_rate",
    smooth: int = 1,
    axes: Axes | None = None,
) -> Axes:
    """Draw the learning curves of ``runs`` (run directories or CSVs) into ``axes``; returns the axes.

    Every run's phase boundaries are dashed vertical lines in the colour of its curve, so that runs with different
    phases (a VQQL block, an IT-VQQL iteration, an IN-VQQL stage) stay apart. Default labels are the run
    directories' names, made unique with their parents' names where two runs share a name.
    """
    runs = [Path(r) for r in runs]
    if not runs:
        raise ValueError("runs=[] is invalid: give one or more run directories, e.g. runs=[outputs/a,outputs/b]")
    labels = [str(label) for label in labels] if labels else _default_labels(runs)
    if len(labels) != len(runs):
        raise ValueError(f"labels={labels!r} is invalid: must give one label per run ({len(runs)})")
    if len(set(labels)) != len(labels):
        raise ValueError(f"labels={labels!r} is invalid: every run needs its own label")
    curves, boundaries = {}, {}
    for run, label in zip(runs, labels, strict=True):
        trials, mean, std, bounds = read_learning_curve(run, metric=metric, smooth=smooth)
        curves[label] = (trials, mean, std)
        boundaries[label] = bounds
    ylabel = "success rate (fraction of agents reaching the door)" if metric == "success_rate" else metric
    axes = plot_learning_curves(curves, axes=axes, ylabel=ylabel)
    colours = {line.get_label(): line.get_color() for line in axes.get_lines()}
    for label, bounds in boundaries.items():
        for boundary in bounds:
            axes.axvline(boundary, color=colours[label], linestyle="--", linewidth=0.8, alpha=0.8)
    return axes


def plot_runs(
    runs: Sequence[str | Path],
    output: str | Path,
    *,
    labels: Sequence[str] | None = None,
    metric: str = "success_rate",
    smooth: int = 1,
    marks: Sequence[Sequence[Any]] = (),
) -> Path:
    """Draw the learning curves of ``runs`` in one figure saved at ``output``; returns ``output``. ``marks``:
    ``(trials, value, text)`` points a reference states (a paper figure's end point), drawn as stars with their
    text."""
    checked = check_marks(marks)
    axes = draw_runs(runs, labels=labels, metric=metric, smooth=smooth)
    draw_marks(axes, checked)
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    axes.figure.savefig(output, dpi=120)  # the figure's constrained layout already fits the labels
    return output


def check_marks(marks: Sequence[Sequence[Any]] | None) -> list[tuple[float, float, str]]:
    """``marks`` as ``(trials, value, text)`` triples; a one-line ``ValueError`` naming the first that is not a
    finite trial count >= 0, a finite value and a text."""
    checked = []
    for mark in marks or ():
        items = list(mark) if isinstance(mark, Sequence) and not isinstance(mark, str) else None
        good = items is not None and len(items) == 3 and isinstance(items[2], str)
        good = good and all(isinstance(v, int | float) and not isinstance(v, bool) for v in items[:2])
        if not good or not (math.isfinite(items[0]) and items[0] >= 0 and math.isfinite(items[1])):
            raise ValueError(f"marks entry {mark!r} is invalid: must be [trials >= 0, value, 'text'] (finite numbers)")
        checked.append((float(items[0]), float(items[1]), items[2]))
    return checked


def draw_marks(axes: Axes, marks: Sequence[tuple[float, float, str]]) -> Axes:
    """Each of the checked ``marks`` (:func:`check_marks`) as a black star with its text, into ``axes``."""
    for trials, value, text in marks:
        axes.plot([trials], [value], marker="*", markersize=12, color="black", linestyle="none")
        axes.annotate(text, (trials, value), textcoords="offset points", xytext=(-8, 8), ha="right")
    return axes


def _default_labels(runs: Sequence[Path]) -> list[str]:
    """The shortest trailing parts of the run paths that tell every run apart (``0`` and ``0`` of two sweeps)."""
    parts = [(r.parent if r.suffix == ".csv" else r).resolve().parts for r in runs]
    depth = 1
    while depth < max(len(p) for p in parts):
        labels = ["/".join(p[-depth:]) for p in parts]
        if len(set(labels)) == len(labels):
            return labels
        depth += 1
    return ["/".join(p) for p in parts]


CROWD_PANELS: Final = (
    ("success_rate", "success rate (fraction of agents out)"),
    ("evacuation_time", "evacuation time (s, last agent out)"),
    ("crashes_agent", "contacts per agent and trial"),
    ("door_flow", "door flow (persons/s)"),
)
"""The panels of a run's ``learning_curve.png``: what a crowd does, trial after trial (metric, axis label)."""


def plot_learning_curve_file(csv_path: str | Path, output: str | Path, *, label: str, smooth: int = 1) -> Path:
    """``learning_curve.png`` of one run: a panel per figure of :data:`CROWD_PANELS` that the CSV holds (an older
    run's holds only the first ones), one curve per room for a run trained across scenarios."""
    rows = read_csv(csv_path)
    rooms = curve_rooms(rows) or [None]
    panels = [(metric, ylabel) for metric, ylabel in CROWD_PANELS if f"{metric}_mean" in rows[0]]
    figure = Figure(figsize=(12.0, 7.5) if len(panels) > 1 else (8.0, 4.5), layout="constrained")
    grid = figure.subplots(2, 2).ravel() if len(panels) > 1 else [figure.add_subplot()]
    for axes, (metric, ylabel) in zip(grid, panels, strict=False):
        curves, boundaries = {}, []
        for room in rooms:
            trials, mean, std, boundaries = read_learning_curve(csv_path, metric=metric, smooth=smooth, room=room)
            curves[label if room is None or len(rooms) == 1 else f"{label}: {room}"] = (trials, mean, std)
        plot_learning_curves(curves, axes=axes, boundaries=boundaries, ylabel=ylabel)
    for axes in list(grid)[len(panels) :]:
        axes.set_visible(False)
    figure.savefig(output, dpi=120)
    return Path(output)

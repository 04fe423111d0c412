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
from matplotlib import colormaps
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from pedrl.analysis import plot_learning_curves
from pedrl.common.checks import shown
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
    columns = _read_columns(path, metric, smooth, room)
    trials, mean, std, phases = (columns[k] for k in ("global_trial", "mean", "std", "phase"))
    boundaries = trials[1:][np.diff(phases) != 0].tolist()
    return trials, mean, std, boundaries


def read_phases(path: str | Path, *, metric: str = "success_rate", smooth: int = 1, room: str | None = None):
    """The phases (IT-VQQL iterations, IN-VQQL stages, VQQL blocks) of ``learning_curve.csv`` one by one, each
    against its own trials from 0 (the paper's Figures 4 and 6).

    Arguments and errors as :func:`read_learning_curve`. Returns a list of ``(phase, agents, trials (T,), mean (T,),
    std (T,))`` in the order the phases ran, ``agents`` the learning agents of the phase's first row.
    """
    columns = _read_columns(path, metric, smooth, room)
    phases = columns["phase"]
    starts = np.flatnonzero(np.r_[True, np.diff(phases) != 0])
    ends = np.r_[starts[1:], phases.size]
    return [
        (
            int(phases[a]),
            int(columns["agents"][a]),
            columns["global_trial"][a:b] - columns["global_trial"][a],
            columns["mean"][a:b],
            columns["std"][a:b],
        )
        for a, b in zip(starts, ends, strict=True)
    ]


def _read_columns(path: str | Path, metric: str, smooth: int, room: str | None) -> dict[str, np.ndarray]:
    """The columns of a learning curve the plots draw (``global_trial``, ``phase``, ``agents``, ``mean``, ``std`` of
    ``metric``, smoothed per phase), checked as :func:`read_learning_curve` states."""
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
        agents = np.array([int(r.get("agents") or 0) for r in rows])
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"learning curve {str(path)!r} is malformed: {err!r}") from None
    if smooth > 1:
        mean, std = _moving_average(mean, phases, smooth), _moving_average(std, phases, smooth)
    return {"global_trial": trials, "phase": phases, "agents": agents, "mean": mean, "std": std}


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
    runs, labels = _runs_and_labels(runs, labels)
    curves, boundaries = {}, {}
    for run, label in zip(runs, labels, strict=True):
        trials, mean, std, bounds = read_learning_curve(run, metric=metric, smooth=smooth)
        curves[label] = (trials, mean, std)
        boundaries[label] = bounds
    axes = plot_learning_curves(curves, axes=axes, ylabel=_ylabel(metric))
    colours = {line.get_label(): line.get_color() for line in axes.get_lines()}
    for label, bounds in boundaries.items():
        for boundary in bounds:
            axes.axvline(boundary, color=colours[label], linestyle="--", linewidth=0.8, alpha=0.8)
    return axes


def draw_phases(
    runs: Sequence[str | Path],
    *,
    labels: Sequence[str] | None = None,
    metric: str = "success_rate",
    smooth: int = 1,
    axes: Axes | None = None,
) -> Axes:
    """Draw every phase of ``runs`` against its own trials, one curve each (the paper's Figures 4 and 6), into
    ``axes``; returns the axes.

    A run of one phase (VQQL's) is a dashed reference curve labelled with the run (black if it is the only one); a
    run of several phases gets a colour per phase, from the first phase (dark) to the last (light), labelled
    ``<run> k``, with ``(n agents)`` where its phases differ in learning agents (IN-VQQL's stages); the runs after
    the first with several phases are told apart by their line style. More than six curves put the legend beside
    the axes.
    """
    runs, labels = _runs_and_labels(runs, labels)
    read = [read_phases(run, metric=metric, smooth=smooth) for run in runs]
    references = sum(len(phases) == 1 for phases in read)
    phased = 0
    curves, styles = {}, {}
    for label, phases in zip(labels, read, strict=True):
        if len(phases) == 1:  # black when it is the only reference, else the colour cycle's
            curves[label] = phases[0][2:]
            styles[label] = {"linestyle": "--"} | ({"color": "black"} if references == 1 else {})
            continue
        linestyle = PHASE_LINESTYLES[phased % len(PHASE_LINESTYLES)]
        phased += 1
        counts = len({agents for _, agents, *_ in phases}) > 1  # IN's stages: say how many learn in each
        for index, (phase, agents, *curve) in enumerate(phases):
            name = f"{label} {phase}" + (f" ({agents} agent{'' if agents == 1 else 's'})" if counts else "")
            curves[name] = tuple(curve)
            styles[name] = {
                "linestyle": linestyle,
                "color": colormaps["viridis"](index / max(len(phases) - 1, 1) * 0.9),
            }
    axes = plot_learning_curves(curves, axes=axes, styles=styles, ylabel=_ylabel(metric))
    axes.set_xlabel("trials within the phase")
    if len(curves) > 6:  # beside the axes, where it hides no curve or mark
        axes.legend(fontsize="x-small", loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return axes


PHASE_LINESTYLES: Final = ("-", ":", "-.")
"""Line styles of the runs with several phases in :func:`draw_phases`, in turn."""

LAYOUTS: Final = {"whole": draw_runs, "phases": draw_phases}
"""``pedrl-plot layout=``: the runs one after another (Figures 5 and 7) or each phase from its own start (4 and 6)."""


def plot_runs(
    runs: Sequence[str | Path],
    output: str | Path,
    *,
    labels: Sequence[str] | None = None,
    metric: str = "success_rate",
    smooth: int = 1,
    marks: Any = (),
    layout: str = "whole",
) -> Path:
    """Draw the learning curves of ``runs`` in one figure saved at ``output``; returns ``output``. ``marks``:
    ``(trials, value, text)`` points a reference states (a paper figure's end point), drawn as stars with their
    text, or ``(trials, None, text)``: a bound on the trials, drawn as a dotted vertical line. ``layout``: a key of
    :data:`LAYOUTS`."""
    if layout not in LAYOUTS:
        raise ValueError(f"layout={layout!r} is invalid: one of {', '.join(LAYOUTS)}")
    checked = check_marks(marks)
    axes = LAYOUTS[layout](runs, labels=labels, metric=metric, smooth=smooth)
    draw_marks(axes, checked)
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    axes.figure.savefig(output, dpi=120)  # the figure's constrained layout already fits the labels
    return output


MAX_MARK_TRIALS: Final = 1e9
"""Largest trial count of a mark (the most trials of one learning phase, ``MAX_TRIALS``): a mark beyond it squeezes
every curve against the axis."""
MAX_MARK_VALUE: Final = 1e9
"""Largest magnitude of a mark's value: a mark at 1e300 leaves the curves a flat line."""
MAX_MARK_TEXT: Final = 200
"""Most characters of a mark's text: a longer one runs off the figure."""
MARKS_ALLOWED: Final = "a list of [trials, value or null, 'text'], e.g. \"marks=[[150000,0.4,'Figure 4']]\""


def check_marks(marks: Any) -> list[tuple[float, float | None, str]]:
    """``marks`` as ``(trials, value, text)`` triples: trials a number in ``[0, MAX_MARK_TRIALS]``, value a number of
    magnitude at most :data:`MAX_MARK_VALUE` or None (a bound on the trials), text a string of at most
    :data:`MAX_MARK_TEXT` characters; else a one-line ``ValueError`` naming ``marks`` or the first bad ``marks[i]``
    and what is allowed."""
    if marks is None:
        return []
    if isinstance(marks, str | bytes) or not isinstance(marks, Sequence):
        raise ValueError(f"marks={shown(marks)} is invalid: must be {MARKS_ALLOWED}")
    checked = []
    for index, mark in enumerate(marks):
        where = f"marks[{index}]={shown(mark)} is invalid"
        items = list(mark) if isinstance(mark, Sequence) and not isinstance(mark, str | bytes) else None
        if items is None or len(items) != 3:
            raise ValueError(f"{where}: must be [trials, value or null, 'text'], e.g. [150000, 0.4, 'Figure 4']")
        trials, value, text = items
        if not (_is_number(trials) and 0 <= trials <= MAX_MARK_TRIALS):
            raise ValueError(f"{where}: its trials {shown(trials)} must be a number in [0, {MAX_MARK_TRIALS:.0e}]")
        if value is not None and not (_is_number(value) and abs(value) <= MAX_MARK_VALUE):
            raise ValueError(
                f"{where}: its value {shown(value)} must be null (a bound on the trials) or a number in"
                f" [{-MAX_MARK_VALUE:.0e}, {MAX_MARK_VALUE:.0e}]"
            )
        if not isinstance(text, str) or len(text) > MAX_MARK_TEXT:
            got = f"{len(text):,} characters" if isinstance(text, str) else shown(text)
            raise ValueError(f"{where}: its text must be a string of at most {MAX_MARK_TEXT} characters, got {got}")
        checked.append((float(trials), None if value is None else float(value), text))
    return checked


def _is_number(value: Any) -> bool:
    """A finite int or float (not a bool)."""
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def draw_marks(axes: Axes, marks: Sequence[tuple[float, float | None, str]]) -> Axes:
    """Each of the checked ``marks`` (:func:`check_marks`) into ``axes``: a point as a black star with its text, a
    bound on the trials (value None) as a dotted black vertical line with its text along it."""
    for trials, value, text in marks:
        if value is None:
            axes.axvline(trials, color="black", linestyle=":", linewidth=1.2)
            axes.annotate(
                text, (trials, 0.02), xycoords=("data", "axes fraction"), rotation=90, ha="right", va="bottom"
            )
            continue
        axes.plot([trials], [value], marker="*", markersize=12, color="black", linestyle="none")
        axes.annotate(text, (trials, value), textcoords="offset points", xytext=(-8, 8), ha="right")
    return axes


def _runs_and_labels(runs: Sequence[str | Path], labels: Sequence[str] | None) -> tuple[list[Path], list[str]]:
    """``runs`` as paths and their labels (default: :func:`_default_labels`); a one-line ``ValueError`` for no run,
    a label count that is not the runs' or two runs with one label."""
    runs = [Path(r) for r in runs]
    if not runs:
        raise ValueError("runs=[] is invalid: give one or more run directories, e.g. runs=[outputs/a,outputs/b]")
    labels = [str(label) for label in labels] if labels else _default_labels(runs)
    if len(labels) != len(runs):
        raise ValueError(f"labels={labels!r} is invalid: must give one label per run ({len(runs)})")
    if len(set(labels)) != len(labels):
        raise ValueError(f"labels={labels!r} is invalid: every run needs its own label")
    return runs, labels


def _ylabel(metric: str) -> str:
    return "success rate (fraction of agents reaching the door)" if metric == "success_rate" else metric


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

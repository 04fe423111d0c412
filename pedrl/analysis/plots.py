"""Figures of the paper's analysis: the room, fundamental diagrams, density maps, learning curves, animations.

Every ``plot_*`` function draws into the given ``axes`` and returns them. With ``axes=None`` it makes a new
:class:`matplotlib.figure.Figure` (not a pyplot figure): no backend is selected, nothing is shown, nothing is
kept alive by pyplot, so the functions run headless and in loops without ``matplotlib.use("Agg")``. Save the
result with ``axes.figure.savefig(path)``. In a notebook, pass axes from ``plt.subplots()`` to show them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Final

import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import EllipseCollection, LineCollection
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from numpy.typing import ArrayLike

from pedrl.analysis.density_map import DensityMap
from pedrl.analysis.fundamental import FundamentalDiagram, SpeedDensityModel, fit_speed_density
from pedrl.analysis.trajectories import Geometry, Trajectories

X_LABEL: Final = "x (m)"
Y_LABEL: Final = "y (m)"
DENSITY_LABEL: Final = "local density ρ (1/m²)"
SPEED_LABEL: Final = "local speed |S| (m/s)"
FLOW_LABEL: Final = "flow ρ|S| (1/(m·s))"
TRIALS_LABEL: Final = "trials"
PERFORMANCE_LABEL: Final = "performance (fraction of agents reaching the door)"

DEFAULT_AGENT_RADIUS: Final = 0.4
"""Body radius (m) drawn by :func:`animate_trial`; the simulator's default ``agent_radius``."""


def _new_axes(*, ncols: int = 1, figsize: tuple[float, float] = (6.0, 4.5)) -> Any:
    figure = Figure(figsize=figsize, layout="constrained")
    axes = figure.subplots(1, ncols, squeeze=True)
    return axes


def plot_room(
    geometry: Geometry,
    *,
    axes: Axes | None = None,
    wall_color: str = "black",
    door_color: str = "tab:green",
) -> Axes:
    """Draw the walls (solid) and the door, the first exit (dashed), with equal aspect and axes in metres.

    Returns:
        The axes drawn into.
    """
    if axes is None:
        axes = _new_axes(figsize=(4.5, 6.5))
    axes.add_collection(LineCollection(geometry.walls, colors=wall_color, linewidths=2.0, zorder=3))
    door = geometry.door
    axes.plot(door[:, 0], door[:, 1], linestyle="--", color=door_color, linewidth=2.0, label="door", zorder=3)
    margin = 0.05 * max(geometry.width, geometry.length)
    axes.set_xlim(geometry.x_min - margin, geometry.x_min + geometry.width + margin)
    axes.set_ylim(geometry.y_min - margin, geometry.y_min + geometry.length + margin)
    axes.set_aspect("equal")
    axes.set_xlabel(X_LABEL)
    axes.set_ylabel(Y_LABEL)
    return axes


def plot_fundamental_diagram(
    fundamental_diagram: FundamentalDiagram,
    *,
    axes: Sequence[Axes] | None = None,
    label: str | None = None,
    fit: bool | SpeedDensityModel = True,
    color: str | None = None,
) -> tuple[Axes, Axes]:
    """Speed-density (left) and flow-density (right) scatter, as in the paper's Figure 8.

    Args:
        fundamental_diagram: the samples.
        axes: two axes ``(speed_axes, flow_axes)``; None makes a new 1 x 2 figure.
        label: legend entry for this data set (e.g. "IN-VQQL"); call again on the same axes to compare.
        fit: draw the least-squares curves ``S(rho)`` and ``rho S(rho)`` (True: a linear model; or the model
            to fit; False: none). Skipped when there are too few samples to fit.
        color: colour of the points and curves (default: the next in the axes' cycle).

    Returns:
        ``(speed_axes, flow_axes)``.
    """
    speed_axes, flow_axes = _new_axes(ncols=2, figsize=(10.0, 4.5)) if axes is None else axes
    density = fundamental_diagram.density
    points = speed_axes.scatter(density, fundamental_diagram.speed, s=8, alpha=0.5, color=color, label=label)
    color = tuple(points.get_facecolor()[0][:3]) if color is None else color  # opaque, for the fit
    flow_axes.scatter(density, fundamental_diagram.flow, s=8, alpha=0.5, color=color, label=label)
    model = SpeedDensityModel.LINEAR if fit is True else (fit or None)
    if model is not None and len(np.unique(density)) > model.value:
        curve = fit_speed_density(fundamental_diagram, model=model)
        grid = np.linspace(0.0, float(density.max()), 100)
        fit_label = None if label is None else f"{label} fit"
        speed_axes.plot(grid, curve.speed(grid), color=color, linewidth=2.0, label=fit_label)
        flow_axes.plot(grid, curve.flow(grid), color=color, linewidth=2.0, label=fit_label)
    speed_axes.set_xlabel(DENSITY_LABEL)
    speed_axes.set_ylabel(SPEED_LABEL)
    flow_axes.set_xlabel(DENSITY_LABEL)
    flow_axes.set_ylabel(FLOW_LABEL)
    for ax in (speed_axes, flow_axes):
        ax.set_xlim(left=0.0)
        ax.set_ylim(bottom=0.0)
        if label is not None:
            ax.legend()
    return speed_axes, flow_axes


def plot_density_map(
    density_map: DensityMap,
    *,
    geometry: Geometry,
    axes: Axes | None = None,
    cmap: str = "Greys",
    colorbar: bool = True,
) -> Axes:
    """Draw the tile counts as a grey scale (Figures 9-10) with the room's walls and door on top.

    Returns:
        The axes drawn into.
    """
    if axes is None:
        axes = _new_axes(figsize=(5.0, 6.5))
    mesh = axes.pcolormesh(density_map.x_edges, density_map.y_edges, density_map.counts.T, cmap=cmap)
    if colorbar:
        bar = axes.figure.colorbar(mesh, ax=axes)
        bar.set_label(f"agent-frames per {density_map.tile_size:g} m × {density_map.tile_size:g} m tile")
    plot_room(geometry, axes=axes)
    return axes


def plot_learning_curves(
    curves: Mapping[str, tuple[ArrayLike, ArrayLike, ArrayLike]],
    *,
    axes: Axes | None = None,
    boundaries: Sequence[float] | None = None,
    styles: Mapping[str, Mapping[str, Any]] | None = None,
    xlabel: str = TRIALS_LABEL,
    ylabel: str = PERFORMANCE_LABEL,
) -> Axes:
    """Mean learning curves with a ±1 standard deviation band (Figures 4-7).

    Args:
        curves: label -> ``(trials (T,), mean (T,), std (T,))``, e.g. the fraction of agents reaching the door
            averaged over the learning processes.
        axes: where to draw; None makes a new figure.
        boundaries: x positions (trials) of iteration or stage boundaries, drawn as vertical dashed lines.
        styles: label -> extra ``Axes.plot`` keywords (e.g. ``{"VQQL": {"linestyle": "--"}}``).
        xlabel, ylabel: axis labels.

    Returns:
        The axes drawn into.
    """
    if axes is None:
        axes = _new_axes(figsize=(8.0, 4.5))
    styles = styles or {}
    for label, (trials, mean, std) in curves.items():
        trials, mean, std = (np.asarray(a, dtype=np.float64) for a in (trials, mean, std))
        if not trials.shape == mean.shape == std.shape:
            raise ValueError(
                f"curve {label!r}: trials, mean, std shapes differ: {trials.shape}, {mean.shape}, {std.shape}"
            )
        (line,) = axes.plot(trials, mean, label=label, **dict(styles.get(label, {})))
        axes.fill_between(trials, mean - std, mean + std, color=line.get_color(), alpha=0.2, linewidth=0)
    for boundary in boundaries or ():
        axes.axvline(boundary, color="grey", linestyle="--", linewidth=0.8)
    axes.set_xlabel(xlabel)
    axes.set_ylabel(ylabel)
    if curves:
        axes.legend()
    return axes


def animate_trial(
    trajectories: Trajectories,
    path: str | Path,
    *,
    fps: float = 10.0,
    max_frames: int | None = None,
    agent_radius: float = DEFAULT_AGENT_RADIUS,
    max_speed: float | None = None,
    dpi: int = 80,
    cmap: str = "viridis",
) -> Path:
    """Write a GIF of one trial: the room, the door and the active agents as circles coloured by speed.

    Inactive agents are not drawn. Frame ``t`` of the GIF is frame ``t`` of the trial, titled with its time.

    Args:
        trajectories: the trial.
        path: output ``.gif`` file.
        fps: GIF frames per second (playback speed; the trial's own rate is ``trajectories.framerate``).
        max_frames: write only the first ``max_frames`` frames (default: all).
        agent_radius: drawn body radius (m).
        max_speed: top of the colour scale (m/s); default the largest speed of an active agent.
        dpi: resolution of the frames.
        cmap: colour map of the speed.

    Returns:
        The path written.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # imported here: only this function needs them
    from PIL import Image

    path = Path(path)
    num_frames = trajectories.num_frames if max_frames is None else min(max_frames, trajectories.num_frames)
    speeds = trajectories.speeds
    if max_speed is None:
        active_speeds = speeds[trajectories.active]
        max_speed = float(active_speeds.max()) if active_speeds.size else 1.0
    norm = Normalize(vmin=0.0, vmax=max(max_speed, 1e-6))

    axes = plot_room(trajectories.geometry, axes=_new_axes(figsize=(4.5, 6.5)))
    figure = axes.figure
    bodies = EllipseCollection(
        widths=2 * agent_radius,
        heights=2 * agent_radius,
        angles=0.0,
        units="xy",
        offsets=np.empty((0, 2)),
        offset_transform=axes.transData,
        cmap=cmap,
        norm=norm,
        edgecolors="black",
        linewidths=0.3,
        zorder=4,
    )
    bodies.set_array(np.empty(0))
    axes.add_collection(bodies)
    figure.colorbar(bodies, ax=axes).set_label("speed (m/s)")

    # the room, walls and colour bar are drawn once; each frame redraws only the bodies and the title (blitting)
    figure.set_dpi(dpi)
    canvas = FigureCanvasAgg(figure)
    title = axes.set_title(f"t = {(num_frames - 1) / trajectories.framerate:g} s (frame {num_frames - 1}), 0 agents")
    canvas.draw()  # lays the figure out once, with the longest title
    figure.set_layout_engine("none")
    bodies.set_animated(True)
    title.set_animated(True)
    canvas.draw()
    background = canvas.copy_from_bbox(figure.bbox)
    frames = []
    for t in range(num_frames):
        active = trajectories.active[t]
        bodies.set_offsets(trajectories.positions[t, active])
        bodies.set_array(speeds[t, active])
        title.set_text(f"t = {t / trajectories.framerate:g} s (frame {t}), {int(active.sum())} agents")
        canvas.restore_region(background)
        axes.draw_artist(bodies)
        axes.draw_artist(title)
        frames.append(Image.frombuffer("RGBA", canvas.get_width_height(), canvas.buffer_rgba()).convert("RGB"))
    frames[0].save(path, save_all=True, append_images=frames[1:], duration=round(1000 / fps), loop=0)
    return path

"""The figures and files of an evaluation, and its console table.

:func:`pedrl.evaluation.engine.evaluate_policy` writes them; the outputs are listed in the :mod:`pedrl.evaluation`
docstring.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Any, Final

import numpy as np
from matplotlib.figure import Figure

from pedrl.analysis import (
    DensityMap,
    FundamentalDiagram,
    Geometry,
    SpeedDensityModel,
    fit_speed_density,
    plot_density_map,
    plot_fundamental_diagram,
)

FUNDAMENTAL_COLUMNS: Final = ("agents", "trial", "frame", "density", "speed", "flow")


# ---------------------------------------------------------------------- figures and files
def write_density_map(run_dir: Path, density: DensityMap, geometry: Geometry, *, agents: int, title: str) -> Figure:
    """``density_map_<agents>.npy`` (the counts) and ``density_map_<agents>.png``; returns the figure."""
    np.save(run_dir / f"density_map_{agents}.npy", density.counts)
    # a figure shaped like the room, so that the colour bar is as tall as the map
    plot_width = 4.0  # inches, besides ~2 for the axis labels and the colour bar
    plot_height = plot_width * geometry.length / geometry.width
    figure = Figure(figsize=(plot_width + 2.0, plot_height + 1.0), layout="constrained")
    axes = plot_density_map(density, geometry=geometry, axes=figure.add_subplot())
    _label_door(axes, geometry)
    axes.set_title(title, fontsize=10)
    figure.savefig(run_dir / f"density_map_{agents}.png", dpi=120)
    return figure


def _label_door(axes: Any, geometry: Geometry) -> None:
    axes.annotate(
        "door",
        tuple(float(v) for v in geometry.door_center),
        xytext=(0, 2),
        textcoords="offset points",
        ha="center",
        va="bottom",
        fontsize=8,
        color="tab:green",
    )


def write_fundamental_diagram(
    run_dir: Path,
    diagrams: dict[int, FundamentalDiagram],
    *,
    label: str,
    point: tuple[float, float],
    radius: float,
    max_points: int,
    seed: int,
) -> Figure:
    """``fundamental_diagram.csv`` (every sample) and ``.png``; returns the figure.

    The figure shows at most ``max_points`` samples per agent count (a random subset: hundreds of thousands of
    points hide each other) and the least-squares fit of all samples, ``S(rho)`` linear and ``Q = rho S(rho)``.
    """
    _write_fundamental_csv(run_dir, diagrams)
    figure = Figure(figsize=(11.0, 4.8), layout="constrained")
    speed_axes, flow_axes = figure.subplots(1, 2)
    rng = np.random.default_rng(seed)
    largest = max((float(d.density.max()) for d in diagrams.values() if d.num_samples), default=1.0)
    grid = np.linspace(0.0, largest, 100)
    for index, (agents, diagram) in enumerate(diagrams.items()):
        color = f"C{index % 10}"
        if diagram.num_samples == 0:
            speed_axes.plot([], [], " ", label=f"{agents} agents: no sample")
            continue
        shown = diagram
        if diagram.num_samples > max_points:
            keep = np.sort(rng.choice(diagram.num_samples, size=max_points, replace=False))
            shown = replace(
                diagram,
                density=diagram.density[keep],
                speed=diagram.speed[keep],
                flow=diagram.flow[keep],
                trial=diagram.trial[keep],
                frame=diagram.frame[keep],
            )
        plot_fundamental_diagram(shown, axes=(speed_axes, flow_axes), fit=False, color=color)
        for collection in (*speed_axes.collections[-1:], *flow_axes.collections[-1:]):
            collection.set_sizes([4.0])
            collection.set_alpha(0.25)
        name = f"{agents} agents ({diagram.num_samples} samples)"
        if len(np.unique(diagram.density)) > SpeedDensityModel.LINEAR.value:
            fit = fit_speed_density(diagram, model=SpeedDensityModel.LINEAR)
            speed_axes.plot(grid, fit.speed(grid), color=color, linewidth=2.0, label=name)
            flow_axes.plot(grid, fit.flow(grid), color=color, linewidth=2.0, label=name)
        else:
            speed_axes.plot([], [], "o", color=color, label=name)
    if not any(d.num_samples for d in diagrams.values()):
        for axes in (speed_axes, flow_axes):
            axes.text(0.5, 0.5, "no frame above min_density", ha="center", va="center", transform=axes.transAxes)
    for axes in (speed_axes, flow_axes):
        axes.set_xlim(0.0, largest * 1.02)
        axes.set_ylim(bottom=0.0)
        if axes.get_legend_handles_labels()[0]:
            axes.legend(fontsize=8, title="lines: least-squares fit", title_fontsize=8, loc="upper right")
    speed_axes.set_title("speed-density", fontsize=10)
    flow_axes.set_title("flow-density", fontsize=10)
    figure.suptitle(
        f"Fundamental diagram, {label}: Gaussian R = {radius:g} m at ({point[0]:g}, {point[1]:g}) m, "
        f"at most {max_points} samples drawn per agent count",
        fontsize=11,
    )
    figure.savefig(run_dir / "fundamental_diagram.png", dpi=120)
    return figure


def _write_fundamental_csv(run_dir: Path, diagrams: dict[int, FundamentalDiagram]) -> None:
    """``fundamental_diagram.csv``: every sample of every agent count, one row each (:data:`FUNDAMENTAL_COLUMNS`)."""
    with open(run_dir / "fundamental_diagram.csv", "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(FUNDAMENTAL_COLUMNS)
        for agents, diagram in diagrams.items():
            writer.writerows(
                zip(
                    [agents] * diagram.num_samples,
                    diagram.trial.tolist(),
                    diagram.frame.tolist(),
                    (f"{v:.6g}" for v in diagram.density),
                    (f"{v:.6g}" for v in diagram.speed),
                    (f"{v:.6g}" for v in diagram.flow),
                    strict=True,
                )
            )


def write_scaling_json(run_dir: Path, rows: list[dict[str, Any]]) -> None:
    """``scaling.json``: the ``scaling.csv`` rows."""
    # NaN (no trial evacuated, no flow measured) is not JSON: written as null
    clean = [{k: None if isinstance(v, float) and math.isnan(v) else v for k, v in row.items()} for row in rows]
    (run_dir / "scaling.json").write_text(json.dumps(clean, indent=2))


# ---------------------------------------------------------------------- console
def print_table(rows: list[dict[str, Any]], label: str) -> None:
    """Tables 4/5 (and the extra columns) on the console: one row per agent count and controller, the controllers
    of an agent count side by side, in the order of ``rows``."""
    header = (
        f"{'agents':>6} | {'controller':>10} | {'fails % (std)':>14} | {'speed m/s (std)':>15} | "
        f"{'evacuation s (trials)':>21} | {'stuck %':>7} | {'door flow 1/s':>13} | {'contacts/agent':>14} | "
        f"{'wall contacts':>13}"
    )
    print(f"\n  {label}\n  {header}\n  {'-' * len(header)}")
    counts = list(dict.fromkeys(r["agents"] for r in rows))
    for r in sorted(rows, key=lambda r: counts.index(r["agents"])):  # stable: the controllers keep their order
        evacuation = f"{r['evacuation_time_s']:.1f} ({r['evacuated_trials']}/{r['trials']})"
        print(
            f"  {r['agents']:>6} | {r.get('controller', ''):>10} | {r['fails_pct']:6.2f} ({r['fails_std']:5.2f}) | "
            f"{r['mean_speed']:7.2f} ({r['speed_std']:4.2f}) | {evacuation:>21} | {r['stuck_pct']:7.1f} | "
            f"{_number(r['door_flow'], '13.3f')} | "
            f"{_number(r['crashes_per_agent'], '14.2f')} | {_number(r['wall_crashes_per_agent'], '13.2f')}"
        )
    if any(math.isnan(r["crashes_per_agent"]) for r in rows):
        print("  contacts n/a: a contact is a move the room's contact rule cut; JuPedSim has no such event")
    for line in ranking_lines(rows):
        print(f"  {line}")


RANKING_ERRORS: Final = 2.0
"""Two controllers' fails are ranked where their means differ by more than this many standard errors of the
difference (about a 95 % interval); within it the scenes are too few to tell them apart."""


def ranking_lines(rows: list[dict[str, Any]]) -> list[str]:
    """One line per agent count and reference: whether the scenes tell the first controller's fails from the
    reference's, their difference beside two standard errors of it (``sqrt(std_a^2 / n_a + std_b^2 / n_b)``, the
    scenes taken as independent).

    ``pedrl-eval ... trials=10`` on one process is 10 scenes: at 100 agents a spread of 20 to 30 points per scene
    leaves about 20 points of doubt, and a 10-point gap there says nothing; these lines say so under the table.
    """
    lines = []
    counts = list(dict.fromkeys(r["agents"] for r in rows))
    for agents in counts:
        first, *references = [r for r in rows if r["agents"] == agents]
        for other in references:
            a, b = first.get("controller", "first"), other.get("controller", "reference")
            difference = first["fails_pct"] - other["fails_pct"]
            error = math.sqrt(
                first["fails_std"] ** 2 / max(first["trials"], 1) + other["fails_std"] ** 2 / max(other["trials"], 1)
            )
            scenes = f"{first['trials']} and {other['trials']} scenes"
            if error == 0.0 and difference == 0.0:
                verdict = "the same fails on every scene"
            elif abs(difference) > RANKING_ERRORS * error:
                verdict = f"{a} fails {'less' if difference < 0 else 'more'} than {b}"
            else:
                verdict = (
                    f"too few scenes to rank {a} and {b} on fails (the gap is within {RANKING_ERRORS:g} standard"
                    " errors; more trials narrow them)"
                )
            lines.append(
                f"{agents} agents: fails {a} - {b} = {difference:+.2f} ± {RANKING_ERRORS * error:.2f} points"
                f" ({RANKING_ERRORS:g} standard errors over {scenes}): {verdict}"
            )
    return lines


def _number(value: float, spec: str) -> str:
    """``value`` formatted with ``spec``, or ``n/a`` (as wide) for NaN: nothing measured."""
    width = int(spec.split(".")[0])
    return f"{'n/a':>{width}}" if math.isnan(value) else f"{value:{spec}}"

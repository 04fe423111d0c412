"""The validation suite: RiMEA tests 1, 4, 6 and 9 (numbered and named as the RiMEA guideline 4.1.1 of 2025 does),
Liddle's bottleneck flows and Feliciani and Nishinari's lanes (neither a RiMEA test), and the physical invariants.

Each test has two halves: a run, which simulates its scenario with a :class:`~pedrl.validation.crowds.Crowd` at the
test's published size, and a verdict (``judge_*``), a plain function of what was measured. The tests of the package
feed the verdicts hand-built crowds that must pass and crowds that must fail, so no verdict can pass vacuously. Where
a source gives no numeric pass rule (RiMEA 4 and 9), the rule is ours, and the report's reference column says so.

Every test runs at the crowd's own body radius. A test whose crowd does not fit at that radius (the bodies would
cover more than :data:`~pedrl.sim.env.MAX_DENSITY` of their start area) is "not applicable at radius r": it is never
shrunk to fit. docs/validation-suite.md gives each test's definition, its pass rule and the sizes it needs.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, Final

import numpy as np
from matplotlib.figure import Figure
from shapely.geometry import LineString, box

from pedrl.integrations.jupedsim import JuPedSimRunError
from pedrl.scenarios import LIDDLE_FLOWS, LIDDLE_WIDTHS, Scenario, Spawn, build_scenario
from pedrl.scenarios.builders import straight_corridor
from pedrl.validation.crowds import Crowd
from pedrl.validation.framework import (
    Budget,
    Context,
    NotApplicableError,
    TestResult,
    invariants_row,
    not_applicable,
    stopped,
    verdict,
)
from pedrl.validation.lanes import LANES_NAME, lanes
from pedrl.validation.measures import (
    WEIDMANN,
    Recording,
    crossing_times,
    density_scale,
    hex_packing,
    steady_flow,
    voronoi_samples,
    weidmann_speed,
)

RIMEA_SOURCE: Final = "RiMEA guideline 4.1.1 (2025)"
"""RiMEA e.V., Richtlinie fuer Mikroskopische Entfluchtungsanalysen / Guideline for Microscopic Evacuation Analysis,
version 4.1.1 of 11 September 2025 (rimea.de, CC BY-ND 4.0), annex 1: tests 1, 4 and 6 in A 2 (components), test 9
in A 4 (qualitative). Its numbering of these four is RiMEA 3.0's."""
RIMEA_NAMES: Final = {
    1: "Maintaining the specified walking speed in a corridor",
    4: "Measurement of the fundamental diagram",
    6: "Movement around a corner",
    9: "Crowd of people leaving a large public space",
}
"""The English headings of the tests in RiMEA 4.1.1 (docs/validation-suite.md says how they were confirmed)."""
WEIDMANN_SOURCE: Final = (
    RIMEA_SOURCE + ", test 4 (sets no numeric rule); curve: Weidmann (1993), v0 = 1.34 m/s, gamma = 1.913,"
    " rho_max = 5.4 /m^2"
)
LIDDLE_SOURCE: Final = (
    "Liddle et al. (2011), arXiv:1105.1532, bottlenecks 0.9-2.5 m wide, 4 m long (widths and flows as JuPedSim's"
    " bottleneck test reads them); not a RiMEA test"
)

RIMEA_1_SPEED: Final = 1.33
"""RiMEA test 1's walking speed (m/s): 40 m in 26 to 34 s."""
RIMEA_1_WINDOW: Final = (26.0, 34.0)
RIMEA_9_RATIO: Final = (1.6, 2.4)
"""Ours (JuPedSim's RiMEA 9 test uses it too): accepted ratio of RiMEA 9's evacuation times, two exits over four.
RiMEA expects "approximately twice as long" and, in a footnote, not to treat the test as an exclusion criterion."""
RIMEA_9_MIN_FLOW: Final = 0.5
"""Ours: RiMEA 9's least mean flow (persons/s) through each open 1 m exit over a whole run, persons over evacuation
time over open exits: a quarter of Liddle et al.'s 2.02 /s through a 1.0 m bottleneck. A crowd that mills for most of
a run and then leaves stays below it whatever the ratio of its times."""
RIMEA_9_EXITS: Final = (4, 2)
"""Open exits of RiMEA 9's two runs."""
WEIDMANN_SPAN: Final = (1.0, 3.0)
"""RiMEA 4's measured densities (Weidmann's scale, 1/m^2) must reach below the first and at or above the second."""
WEIDMANN_TOLERANCE: Final = 0.25
"""Ours: RiMEA 4 passes with an RMS distance of the binned speeds to Weidmann's curve of at most this share of v0."""
WEIDMANN_FREE_SHARE: Final = 0.75
"""Ours: the mean speed of RiMEA 4's lowest-density bin (below 1 /m^2) is at least this share of v0 (Weidmann's curve
is at 79 % of v0 at 1 /m^2 and higher below); a crowd that walks slowly when free, or stands, fails."""
WEIDMANN_FALL: Final = 0.5
"""Ours: the mean speed of RiMEA 4's bins at or above 3 /m^2 is at most this share of the lowest bin's (Weidmann's
curve: 25 % of v0 at 3 /m^2, against 79-100 % below 1 /m^2); a crowd that keeps its speed as density grows fails."""
WEIDMANN_BIN: Final = 0.5
MIN_BIN_SAMPLES: Final = 5
LIDDLE_TOLERANCE: Final = 0.25
"""Ours: the bottleneck passes when the flow at every width is within this relative error of Liddle's."""
MIN_CROSSINGS: Final = 50
"""Fewest crossings of a run for its flow to count."""


RIMEA_6_AGENTS: Final = 20
BOTTLENECK_AGENTS: Final = 100
BOTTLENECK_NAME: Final = "bottleneck flow against width (Liddle et al.)"


def rimea_name(number: int) -> str:
    """The report's name of RiMEA test ``number``: ``RiMEA n: <its heading in RiMEA 4.1.1>``."""
    return f"RiMEA {number}: {RIMEA_NAMES[number]}"


# ---------------------------------------------------------------------------------------------- RiMEA 1


def rimea_1(context: Context) -> TestResult:
    """RiMEA test 1: one person walks a 2 m x 40 m corridor at 1.33 m/s (the top speed is set to it for the test),
    starting with its back to the closed end, facing the exit. Passed when every run's travel time is in [26, 34] s."""
    scenario = straight_corridor()
    runs = context.budget.rimea_1_runs
    start = np.tile([[[context.crowd.radius + 0.01, 1.0]]], (runs, 1, 1))
    recording = context.run(
        scenario,
        num_agents=1,
        replicas=runs,
        max_time=60.0,
        seed=1,
        max_speed=RIMEA_1_SPEED,
        positions=start,
        headings=np.zeros((runs, 1)),
    )
    return judge_rimea_1(recording.exit_time[:, 0])


def judge_rimea_1(times: np.ndarray) -> TestResult:
    """RiMEA 1's verdict on the travel times (s) of the runs (NaN: never arrived)."""
    arrived = times[np.isfinite(times)]
    travel = float(arrived.mean()) if arrived.size else None
    low, high = RIMEA_1_WINDOW
    outside = arrived[(arrived < low) | (arrived > high)]
    worst = float(outside[np.argmax(np.abs(outside - (low + high) / 2))]) if outside.size else None
    passed, failed = verdict(
        [
            (arrived.size == times.size, f"{times.size - arrived.size} of {times.size} runs never arrived"),
            (
                worst is None,
                f"travel time {worst or 0:.1f} s not in [{low:g}, {high:g}] s ({outside.size} of {times.size} runs)",
            ),
        ]
    )
    return TestResult(
        rimea_name(1),
        passed,
        travel,
        "s",
        f"in [{low:g}, {high:g}] s (40 m at {RIMEA_1_SPEED} m/s)",
        RIMEA_SOURCE + ", test 1 (A 2); the rule is RiMEA's",
        {"arrived": int(arrived.size), "runs": int(times.size), "times_s": np.round(times, 2).tolist()},
        failed=failed,
    )


# ---------------------------------------------------------------------------------------------- RiMEA 4

RIMEA_4_FILL: Final = (0.0, 40.0)
"""Part of the corridor (x, m) filled at the start."""
RIMEA_4_AREA: Final = (24.0, 28.0)
"""The measurement area (x, m), across the corridor's whole width."""
RIMEA_4_WIDTH: Final = 4.0
RIMEA_4_START: Final = 10.0
"""Measurements start this long (s) after the start, as RiMEA prescribes."""


def lattice(density: float, *, radius: float, x_range: tuple[float, float], width: float, seed: int) -> np.ndarray:
    """Centres ``(N, 2)`` (m) of a hexagonal lattice of ``density`` (1/m^2) filling ``x_range x [0, width]`` clear of
    the walls, each jittered by up to a quarter of the free gap (seeded); the spacing is at least ``2.02 r``."""
    spacing = max(math.sqrt(2.0 / (math.sqrt(3.0) * density)), 2.02 * radius)
    jitter = 0.25 * (spacing - 2.02 * radius)
    margin = radius + 0.01 + jitter  # jittered centres stay clear of the walls
    ys = np.arange(margin, width - margin + 1e-9, spacing * math.sqrt(3.0) / 2.0)
    points = [
        (x, y)
        for index, y in enumerate(ys)
        for x in np.arange(x_range[0] + margin + (index % 2) * spacing / 2, x_range[1] - margin, spacing)
    ]
    centres = np.array(points, dtype=np.float64)
    return centres + np.random.default_rng(seed).uniform(-jitter, jitter, centres.shape)


def rimea_4_corridor(length: float = 150.0) -> Scenario:
    """RiMEA 4's corridor, ``length x 4 m``, open at its far end; long, so that the room's placement check (which
    counts the whole corridor as the start area) admits the densest lattice."""
    walkable = box(0.0, 0.0, length, RIMEA_4_WIDTH)
    exit_ = LineString([(length, 0.0), (length, RIMEA_4_WIDTH)])
    return Scenario("rimea_4", walkable, (exit_,), (Spawn(walkable, exit=0),))


def rimea_4(context: Context) -> tuple[TestResult, Figure]:
    """RiMEA test 4, the fundamental diagram: speed against density. A 4 m wide corridor is filled over its first
    40 m at RiMEA's densities 0.5 to 6 /m^2 (Weidmann's scale) with agents at rest; free speed 1.34 m/s (set for the
    test). PedPy measures Voronoi density and speed in a 4 m x 4 m area, 24 to 28 m along, from 10 s on (before the
    crowd's tail passes it).

    For bodies larger than Weidmann's (radius above 0.231 m, whose densest packing is his 5.4 /m^2), densities are
    divided by :func:`~pedrl.validation.measures.density_scale`: the curve's shape is kept, its jam density moved to
    the bodies' densest packing. Verdict: :func:`judge_rimea_4`."""
    radius, scale = context.crowd.radius, density_scale(context.crowd.radius)
    scenario = rimea_4_corridor()
    walkable = scenario.walkable
    area = box(RIMEA_4_AREA[0], 0.0, RIMEA_4_AREA[1], RIMEA_4_WIDTH)
    densities, speeds = [], []
    for index, target in enumerate(context.budget.rimea_4_densities):
        start = lattice(target * scale, radius=radius, x_range=RIMEA_4_FILL, width=RIMEA_4_WIDTH, seed=40 + index)
        start = start[None]  # one run per density: the lattice holds up to about a thousand agents
        recording = context.run(
            scenario,
            num_agents=start.shape[1],
            replicas=1,
            max_time=3 * RIMEA_4_START,
            seed=40 + index,
            max_speed=WEIDMANN["v0"],
            positions=start,
            headings=np.zeros(start.shape[:2]),
        )
        density, speed = voronoi_samples(recording, walkable, area, start=RIMEA_4_START)
        densities.append(density)
        speeds.append(speed)
    density, speed = np.concatenate(densities), np.concatenate(speeds)
    result = judge_rimea_4(density, speed, radius=radius)
    return result, weidmann_figure(density / scale, speed, result)


def judge_rimea_4(density: np.ndarray, speed: np.ndarray, *, radius: float) -> TestResult:
    """RiMEA 4's verdict on per-frame Voronoi ``density`` (1/m^2) and ``speed`` (m/s) samples of bodies of ``radius``.

    Densities are rescaled to Weidmann's scale and binned by 0.5 /m^2 (bins of at least 5 samples count). RiMEA sets
    no numeric rule; ours passes when the bins span [1, 3] /m^2 or wider (a bin below 1, a bin at or above 3), the RMS
    distance of the bins' mean speeds to Weidmann's curve (at each bin's mean density) is at most 25 % of
    v0 = 1.34 m/s, the lowest-density bin walks at least 75 % of v0 (free speed), the bins at or above 3 /m^2 walk at
    most half as fast as it (the speed falls over the span), and the bin means fall with density (negative slope).
    """
    scale = density_scale(radius)
    scaled = np.asarray(density, dtype=np.float64) / scale
    speed = np.asarray(speed, dtype=np.float64)
    index = np.floor(scaled / WEIDMANN_BIN).astype(int)
    kept = [b for b in np.unique(index) if np.sum(index == b) >= MIN_BIN_SAMPLES]
    rho = np.array([scaled[index == b].mean() for b in kept])
    mean = np.array([speed[index == b].mean() for b in kept])
    low_edge = np.array([b * WEIDMANN_BIN for b in kept])
    spans = rho.size > 0 and bool(low_edge.min() < WEIDMANN_SPAN[0] and low_edge.max() >= WEIDMANN_SPAN[1])
    rms = float(np.sqrt(np.mean((mean - weidmann_speed(rho, **WEIDMANN)) ** 2))) if rho.size else None
    slope = float(np.polyfit(rho, mean, 1)[0]) if rho.size >= 2 else None
    v0 = WEIDMANN["v0"]
    free = float(mean[0]) if spans else None  # the lowest-density bin, below 1 /m^2 when the span holds
    dense = float(mean[low_edge >= WEIDMANN_SPAN[1]].mean()) if spans else None
    fall = dense / free if free else None
    tolerance = WEIDMANN_TOLERANCE * v0
    span = f"{low_edge.min():.1f}-{low_edge.max() + WEIDMANN_BIN:.1f}" if rho.size else "none"
    criteria = [(spans, f"densities span {span} /m^2, not {WEIDMANN_SPAN[0]:g}-{WEIDMANN_SPAN[1]:g}")]
    if spans:  # then the bins, the free speed and the fall are measured
        criteria += [
            (rms <= tolerance, f"RMS distance {rms:.3g} m/s > {tolerance:.3g} m/s"),
            (free >= WEIDMANN_FREE_SHARE * v0, f"free speed {free:.3g} m/s < {WEIDMANN_FREE_SHARE * v0:.3g} m/s"),
            (
                fall is not None and fall <= WEIDMANN_FALL,
                f"dense bins at {fall or 0:.0%} of the free speed > {WEIDMANN_FALL:.0%}",
            ),
            (
                slope is not None and slope < 0,
                f"speed does not fall with density (slope {slope or 0:.3g} m/s per 1/m^2)",
            ),
        ]
    passed, failed = verdict(criteria)
    return TestResult(
        rimea_name(4),
        passed,
        rms,
        "m/s (RMS distance to Weidmann)",
        f"ours: <= {tolerance:.3g} m/s ({WEIDMANN_TOLERANCE:.0%} of v0), densities spanning {WEIDMANN_SPAN[0]:g}-"
        f"{WEIDMANN_SPAN[1]:g} /m^2, free speed (lowest bin) >= {WEIDMANN_FREE_SHARE:.0%} of v0, bins >="
        f" {WEIDMANN_SPAN[1]:g} /m^2 at <= {WEIDMANN_FALL:.0%} of it, speed falling with density",
        WEIDMANN_SOURCE + ("" if scale == 1.0 else f"; densities scaled by 1/{scale:.3g} for {radius:g} m bodies"),
        {
            "density_span_per_m2": span,
            "spans_range": spans,
            "density_scale": round(scale, 4),
            "jam_density_model_per_m2": round(min(WEIDMANN["rho_max"], hex_packing(radius)), 3),
            "free_speed_share_of_v0": None if free is None else round(free / v0, 3),
            "dense_over_free": None if fall is None else round(fall, 3),
            "slope_m_s_per_density": slope,
            "bin_density_per_m2": rho.round(3).tolist(),
            "bin_speed_m_s": mean.round(3).tolist(),
            "samples": int(scaled.size),
        },
        failed=failed,
    )


def weidmann_figure(scaled_density: np.ndarray, speed: np.ndarray, result: TestResult) -> Figure:
    """The samples and bin means of RiMEA 4 (Weidmann's density scale) against Weidmann's curve."""
    figure = Figure(figsize=(6.0, 4.0))
    axes = figure.add_subplot()
    axes.scatter(scaled_density, speed, s=6, alpha=0.3, label="frames (PedPy Voronoi)")
    axes.plot(result.details["bin_density_per_m2"], result.details["bin_speed_m_s"], "o-", color="C1", label="bins")
    rho = np.linspace(0.1, WEIDMANN["rho_max"], 200)
    axes.plot(rho, weidmann_speed(rho, **WEIDMANN), "k--", label="Weidmann")
    axes.set(xlabel="density, Weidmann's scale (1/m^2)", ylabel="speed (m/s)", title="RiMEA 4: the fundamental diagram")
    axes.legend(fontsize=8)
    return figure


# ---------------------------------------------------------------------------------------------- RiMEA 6


def rimea_6(context: Context) -> TestResult:
    """RiMEA test 6: 20 persons walk around a left corner (the ``corner`` scenario: 2 m wide legs of 12 m, the
    persons start in the first 6 m, as RiMEA places them). Verdict: :func:`judge_rimea_6`."""
    scenario = build_scenario({"name": "corner", "spawn_length": 6.0})
    recording = context.run(
        scenario, num_agents=RIMEA_6_AGENTS, replicas=context.budget.replicas, max_time=120.0, seed=6
    )
    return judge_rimea_6(recording, scenario)


def judge_rimea_6(recording: Recording, scenario: Scenario) -> TestResult:
    """RiMEA 6's verdict: failed if any trajectory point of an agent in the room lies in the wall (outside the
    walkable area, by more than 1e-4 m), or if anyone has not arrived."""
    import shapely

    points = shapely.points(recording.positions[recording.in_room].astype(np.float64))
    inside = shapely.contains(scenario.walkable.buffer(1e-4), points)
    in_wall = int((~inside).sum())
    passed, failed = verdict(
        [
            (recording.evacuated == 1.0, f"{recording.evacuated:.0%} arrived, not everyone"),
            (in_wall == 0, f"{in_wall} trajectory points in the wall"),
        ]
    )
    return TestResult(
        rimea_name(6),
        passed,
        recording.evacuated,
        "share arrived",
        "1.0, and no trajectory point in the wall",
        RIMEA_SOURCE + f", test 6 (A 2, {RIMEA_6_AGENTS} persons); the rule is RiMEA's",
        {"points_in_wall": in_wall, "runs": int(recording.exit_time.shape[0])},
        failed=failed,
    )


# ---------------------------------------------------------------------------------------------- RiMEA 9


def rimea_9(context: Context) -> tuple[TestResult, Figure]:
    """RiMEA test 9: 1000 persons, at least 2 m from the walls, leave a 30 m x 20 m room by four 1 m exits (two in
    each long side, 4 m from the short sides), then by the two bottom ones (the top two closed). Verdict:
    :func:`judge_rimea_9`."""
    figure = Figure(figsize=(6.0, 4.0))
    axes = figure.add_subplot()
    times: dict[str, np.ndarray] = {}
    for label, closed in (("four open", []), ("two closed", [2, 3])):
        scenario = build_scenario({"name": "four_exits", "closed_exits": closed, "margin": 4.0, "spawn_margin": 2.0})
        recording = context.run(
            scenario,
            num_agents=context.budget.rimea_9_agents,
            replicas=1,
            max_time=context.budget.rimea_9_time,
            seed=9,
        )
        times[label] = recording.exit_time
        steps = np.arange(recording.in_room.shape[1]) / recording.frame_rate
        axes.plot(steps, 1.0 - recording.in_room.mean(axis=(0, 2)), label=label)
    axes.set(xlabel="time (s)", ylabel="share evacuated", title="RiMEA 9: four exits, then two")
    axes.legend()
    return judge_rimea_9(times["four open"], times["two closed"]), figure


def judge_rimea_9(four_open: np.ndarray, two_closed: np.ndarray) -> TestResult:
    """RiMEA 9's verdict on the exit times (s, NaN: never out) of every person of both runs. RiMEA expects the
    evacuation with two exits to take "approximately twice as long" and sets no bound; ours passes when everyone left
    in both runs, the evacuation time (the last person out) with two exits is 1.6 to 2.4 times that with four, and in
    each run the mean flow through each open exit (persons over evacuation time over open exits) is at least
    0.5 /s: a crowd that mills for most of both runs cannot pass by the ratio of its times alone."""
    runs = {"four": four_open, "two": two_closed}
    evacuated = {label: float(np.isfinite(times).mean()) for label, times in runs.items()}
    everyone = all(share == 1.0 for share in evacuated.values())
    last = {label: float(np.max(runs[label])) if evacuated[label] == 1.0 else None for label in runs}  # if all left
    flows = {
        label: None if last[label] is None else runs[label].size / last[label] / exits
        for label, exits in zip(runs, RIMEA_9_EXITS, strict=True)
    }
    ratio = last["two"] / last["four"] if everyone and last["four"] and last["two"] else None
    low, high = RIMEA_9_RATIO
    shares = ", ".join(f"{share:.0%} with {label} exits" for label, share in evacuated.items())
    criteria = [(everyone, f"not everyone left ({shares})")]
    if everyone:  # then both evacuation times and flows are measured
        criteria.append(
            (ratio is not None and low <= ratio <= high, f"ratio {ratio or 0:.2f} not in [{low:g}, {high:g}]")
        )
        criteria += [
            (flow >= RIMEA_9_MIN_FLOW, f"flow {flow:.2f} /s per exit with {label} exits < {RIMEA_9_MIN_FLOW:g} /s")
            for label, flow in flows.items()
        ]
    passed, failed = verdict(criteria)
    return TestResult(
        rimea_name(9),
        passed,
        ratio,
        "ratio of evacuation times, two exits over four",
        f"ours: in [{low:g}, {high:g}] (RiMEA: about twice as long, not a pass rule), everyone out in both runs,"
        f" mean flow >= {RIMEA_9_MIN_FLOW:g} /s through each open exit",
        RIMEA_SOURCE + ", test 9 (A 4)",
        {
            "evacuation_time_four_s": last["four"],
            "evacuation_time_two_s": last["two"],
            "evacuated": evacuated,
            "flow_per_exit_per_s": {label: None if flow is None else round(flow, 3) for label, flow in flows.items()},
        },
        failed=failed,
    )


# ---------------------------------------------------------------------------------------------- bottleneck


def liddle_bottleneck(width: float) -> Scenario:
    """Liddle's bottleneck: a 4 m long corridor of ``width`` fed by a 10 m x 18 m waiting area, which holds 100
    bodies of up to 0.4 m radius (the ``bottleneck`` scenario, lengthened). Agents head straight for the corridor's
    far end: the scenario's route, which lines them up with the opening's centre one by one, would cap the flow."""
    scenario = build_scenario({"name": "bottleneck", "opening": width, "room_length": 18.0, "spawn_length": 17.2})
    return replace(scenario, spawns=tuple(replace(spawn, waypoints=()) for spawn in scenario.spawns))


def bottleneck(context: Context) -> tuple[TestResult, Figure]:
    """Flow through a bottleneck of Liddle's widths, 100 agents per width, measured by PedPy's N-t across its
    entrance. Verdict: :func:`judge_bottleneck`."""
    crossings = []
    for index, width in enumerate(context.budget.widths):
        scenario = liddle_bottleneck(width)
        recording = context.run(
            scenario, num_agents=BOTTLENECK_AGENTS, replicas=context.budget.replicas, max_time=200.0, seed=70 + index
        )
        crossings.append(crossing_times(recording, scenario.lines["opening"]))
    result = judge_bottleneck(context.budget.widths, crossings)
    figure = Figure(figsize=(6.0, 4.0))
    axes = figure.add_subplot()
    axes.plot(LIDDLE_WIDTHS, LIDDLE_FLOWS, "ks--", label="Liddle et al.")
    axes.plot(context.budget.widths, result.details["flows_per_s"], "o-", label="simulated (PedPy N-t)")
    axes.set(xlabel="bottleneck width (m)", ylabel="flow (1/s)", title="Flow through a bottleneck")
    axes.legend()
    return result, figure


def judge_bottleneck(widths: Sequence[float], crossings: Sequence[Sequence[np.ndarray]]) -> TestResult:
    """The bottleneck's verdict on the crossing times (s) of each run at each width.

    A run's flow is its steady N-t slope (:func:`~pedrl.validation.measures.steady_flow`) and counts only with at
    least 50 crossings; a width's flow is the mean over its counted runs. Passed when every width has a flow within
    25 % of Liddle's. The relative rule weighs narrow and wide openings alike, and 25 % covers the spread between
    repeated bottleneck experiments at one width (Liddle's, Seyfried's and Kretz's flows differ by 10-25 %); the
    distance JuPedSim's verification used, ``sqrt(sum (J - J_Liddle)^2)`` with a limit of 0.5 /s, is reported.
    """
    flows, errors, counts = [], [], []
    for width, runs in zip(widths, crossings, strict=True):
        counted = [steady_flow(times) for times in runs if len(times) >= MIN_CROSSINGS]
        counts.append([len(times) for times in runs])
        flow = float(np.nanmean(counted)) if counted and np.isfinite(counted).any() else math.nan
        flows.append(flow)
        errors.append(abs(flow - liddle_flow(width)) / liddle_flow(width))
    measured = np.isfinite(flows).all()
    distance = float(np.sqrt(np.nansum([(f - liddle_flow(w)) ** 2 for f, w in zip(flows, widths, strict=True)])))
    worst = float(np.max(errors)) if measured else None
    unmeasured = ", ".join(f"{w:g}" for w, f in zip(widths, flows, strict=True) if not math.isfinite(f))
    criteria = [(measured, f"no flow at {unmeasured} m (runs of < {MIN_CROSSINGS} crossings)")]
    if measured:
        criteria += [
            (
                error <= LIDDLE_TOLERANCE,
                f"flow {f:.2f} /s at {w:g} m is {error:.0%} off Liddle's {liddle_flow(w):.2f} /s"
                f" (> {LIDDLE_TOLERANCE:.0%})",
            )
            for w, f, error in zip(widths, flows, errors, strict=True)
        ]
    passed, failed = verdict(criteria)
    return TestResult(
        BOTTLENECK_NAME,
        passed,
        worst,
        "largest relative error",
        f"ours: <= {LIDDLE_TOLERANCE:g} at every width, each flow over >= {MIN_CROSSINGS} crossings",
        LIDDLE_SOURCE,
        {
            "widths_m": list(widths),
            "flows_per_s": [None if not math.isfinite(f) else round(f, 3) for f in flows],
            "liddle_per_s": [liddle_flow(w) for w in widths],
            "relative_error": [None if not math.isfinite(e) else round(e, 3) for e in errors],
            "crossings_per_run": counts,
            "jupedsim_distance_per_s": round(distance, 3) if measured else None,
        },
        failed=failed,
    )


def liddle_flow(width: float) -> float:
    """Liddle's measured flow (1/s) at one of :data:`~pedrl.scenarios.LIDDLE_WIDTHS`."""
    return LIDDLE_FLOWS[LIDDLE_WIDTHS.index(width)]


# ---------------------------------------------------------------------------------------------- the suite


TESTS: Final[dict[str, tuple[str, Callable[[Context], Any]]]] = {
    "rimea_1": (rimea_name(1), rimea_1),
    "rimea_4": (rimea_name(4), rimea_4),
    "rimea_6": (rimea_name(6), rimea_6),
    "rimea_9": (rimea_name(9), rimea_9),
    "bottleneck": (BOTTLENECK_NAME, bottleneck),
    "lanes": (LANES_NAME, lanes),
}
"""The tests of the suite, in report order: key -> (row name, run)."""
TEST_NAMES: Final[tuple[str, ...]] = (*TESTS, "invariants")
"""Values of ``tests``: every test, and the invariants row (which needs at least one other test to have frames)."""


def run_suite(
    crowd: Crowd,
    *,
    budget: Budget,
    only: Sequence[str] | None = None,
    progress: Callable[[str], None] | None = None,
    trajectories: Path | None = None,
) -> tuple[list[TestResult], dict[str, Figure]]:
    """Run the suite (or the tests named in ``only``) with one crowd; return its rows and figures. The invariants
    row closes the list whenever any test ran. With ``trajectories`` (a folder), the first run of every simulation
    goes there as a JuPedSim SQLite trajectory file (:class:`~pedrl.validation.framework.Context`)."""
    context = Context(crowd, budget, trajectories=trajectories)
    results: list[TestResult] = []
    figures: dict[str, Figure] = {}
    for key, (name, test) in TESTS.items():
        if only is not None and key not in only:
            continue
        if progress is not None:
            progress(key)
        context.test = key
        try:
            outcome = test(context)
        except NotApplicableError as err:
            results.append(not_applicable(name, crowd.radius, str(err)))
            continue
        except JuPedSimRunError as err:  # a reference model that breaks down fails the test, the others still run
            results.append(stopped(name, str(err)))
            continue
        if isinstance(outcome, tuple):
            outcome, figures[key] = outcome
        results.append(outcome)
    if results:  # with nothing simulated (every test not applicable), the row fails: it checked nothing
        results.append(invariants_row(context.invariants))
    return results, figures

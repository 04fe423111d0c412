"""The validation suite: RiMEA tests 1, 4, 6 and 9, Liddle's bottleneck flows, lanes, and the physical invariants.

Each test has two halves: a run, which simulates its scenario with a :class:`~pedrl.validation.crowds.Crowd` at the
test's published size, and a verdict (``judge_*``), a plain function of what was measured. The tests of the package
feed the verdicts hand-built crowds that must pass and crowds that must fail, so no verdict can pass vacuously.

Every test runs at the crowd's own body radius. A test whose crowd does not fit at that radius (the bodies would
cover more than :data:`~pedrl.sim.env.MAX_DENSITY` of their start area) is "not applicable at radius r": it is never
shrunk to fit. docs/validation-suite.md gives each test's definition, its pass rule and the sizes it needs.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any, Final

import numpy as np
from matplotlib.figure import Figure
from shapely.geometry import LineString, box

from pedrl.scenarios import LIDDLE_FLOWS, LIDDLE_WIDTHS, Scenario, Spawn, build_scenario
from pedrl.validation.crowds import Crowd
from pedrl.validation.framework import (
    Budget,
    Context,
    NotApplicableError,
    TestResult,
    invariants_row,
    not_applicable,
)
from pedrl.validation.measures import (
    WEIDMANN,
    Recording,
    crossing_times,
    density_scale,
    hex_packing,
    lane_order_values,
    steady_flow,
    voronoi_samples,
    weidmann_speed,
)

RIMEA_SOURCE: Final = "RiMEA guideline 3.0"
WEIDMANN_SOURCE: Final = "Weidmann (1993), RiMEA test 4: v0 = 1.34 m/s, gamma = 1.913, rho_max = 5.4 /m^2"
LIDDLE_SOURCE: Final = "Liddle et al. (2011), 0.9-2.5 m wide bottlenecks"
LANES_SOURCE: Final = "Rex and Löwen (2007); Feliciani and Nishinari (2016)"

RIMEA_1_SPEED: Final = 1.33
"""RiMEA test 1's walking speed (m/s): 40 m in 26 to 34 s."""
RIMEA_1_WINDOW: Final = (26.0, 34.0)
RIMEA_9_RATIO: Final = (1.6, 2.4)
"""Accepted ratio of RiMEA 9's evacuation times, two exits over four."""
WEIDMANN_SPAN: Final = (1.0, 3.0)
"""RiMEA 4's measured densities (Weidmann's scale, 1/m^2) must reach below the first and at or above the second."""
WEIDMANN_TOLERANCE: Final = 0.25
"""RiMEA 4 passes with an RMS distance of the binned speeds to Weidmann's curve of at most this share of v0."""
WEIDMANN_BIN: Final = 0.5
MIN_BIN_SAMPLES: Final = 5
LIDDLE_TOLERANCE: Final = 0.25
"""The bottleneck passes when the flow at every width is within this relative error of Liddle's."""
MIN_CROSSINGS: Final = 50
"""Fewest crossings of a run for its flow to count."""
LANE_ORDER_PASS: Final = 0.5
LANES_MIN_AGENTS: Final = 10
"""Fewest agents in the lanes window for a frame to count."""
LANES_MIN_FRAMES: Final = 300
"""Fewest counted agent-frames for a lanes verdict."""


RIMEA_6_AGENTS: Final = 20
BOTTLENECK_AGENTS: Final = 100
LANES_AGENTS: Final = 54


# ---------------------------------------------------------------------------------------------- RiMEA 1


def straight_corridor(length: float = 40.0, width: float = 2.0) -> Scenario:
    """RiMEA test 1's corridor, ``length x width``, its exit the far end."""
    walkable = box(0.0, 0.0, length, width)
    exit_ = LineString([(length, 0.0), (length, width)])
    return Scenario("rimea_1", walkable, (exit_,), (Spawn(box(0.0, 0.0, 2.0, width), exit=0),))


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
    passed = arrived.size == times.size and bool(((arrived >= low) & (arrived <= high)).all())
    return TestResult(
        "RiMEA 1: travel time in a 40 m corridor",
        passed,
        travel,
        "s",
        f"in [{low:g}, {high:g}] s (40 m at {RIMEA_1_SPEED} m/s)",
        RIMEA_SOURCE + ", test 1",
        {"arrived": int(arrived.size), "runs": int(times.size), "times_s": np.round(times, 2).tolist()},
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
    """RiMEA test 4: speed against density. A 4 m wide corridor is filled over its first 40 m at densities 0.5 to
    4 /m^2 (Weidmann's scale) with agents at rest; free speed 1.34 m/s (set for the test). PedPy measures Voronoi
    density and speed in a 4 m x 4 m area, 24 to 28 m along, from 10 s on (before the crowd's tail passes it).

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

    Densities are rescaled to Weidmann's scale and binned by 0.5 /m^2 (bins of at least 5 samples count). Passed
    when the bins span [1, 3] /m^2 or wider (a bin at or below 1, a bin at or above 3), the RMS distance of the bins'
    mean speeds to Weidmann's curve (at each bin's mean density) is at most 25 % of v0 = 1.34 m/s, and the mean
    speed falls with density (negative slope of the bin means).
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
    tolerance = WEIDMANN_TOLERANCE * WEIDMANN["v0"]
    passed = spans and rms is not None and rms <= tolerance and slope is not None and slope < 0
    span = f"{low_edge.min():.1f}-{low_edge.max() + WEIDMANN_BIN:.1f}" if rho.size else "none"
    return TestResult(
        "RiMEA 4: speed against density (Weidmann)",
        passed,
        rms,
        "m/s (RMS distance to Weidmann)",
        f"<= {tolerance:.3g} m/s (25 % of v0), densities spanning {WEIDMANN_SPAN[0]:g}-{WEIDMANN_SPAN[1]:g} /m^2,"
        " speed falling with density",
        WEIDMANN_SOURCE + ("" if scale == 1.0 else f"; densities scaled by 1/{scale:.3g} for {radius:g} m bodies"),
        {
            "density_span_per_m2": span,
            "spans_range": spans,
            "density_scale": round(scale, 4),
            "jam_density_model_per_m2": round(min(WEIDMANN["rho_max"], hex_packing(radius)), 3),
            "slope_m_s_per_density": slope,
            "bin_density_per_m2": rho.round(3).tolist(),
            "bin_speed_m_s": mean.round(3).tolist(),
            "samples": int(scaled.size),
        },
    )


def weidmann_figure(scaled_density: np.ndarray, speed: np.ndarray, result: TestResult) -> Figure:
    """The samples and bin means of RiMEA 4 (Weidmann's density scale) against Weidmann's curve."""
    figure = Figure(figsize=(6.0, 4.0))
    axes = figure.add_subplot()
    axes.scatter(scaled_density, speed, s=6, alpha=0.3, label="frames (PedPy Voronoi)")
    axes.plot(result.details["bin_density_per_m2"], result.details["bin_speed_m_s"], "o-", color="C1", label="bins")
    rho = np.linspace(0.1, WEIDMANN["rho_max"], 200)
    axes.plot(rho, weidmann_speed(rho, **WEIDMANN), "k--", label="Weidmann")
    axes.set(xlabel="density, Weidmann's scale (1/m^2)", ylabel="speed (m/s)", title="RiMEA 4: speed against density")
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
    passed = recording.evacuated == 1.0 and in_wall == 0
    return TestResult(
        "RiMEA 6: around a corner",
        passed,
        recording.evacuated,
        "share arrived",
        "1.0, and no trajectory point in the wall",
        RIMEA_SOURCE + f", test 6 ({RIMEA_6_AGENTS} persons)",
        {"points_in_wall": in_wall, "runs": int(recording.exit_time.shape[0])},
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
    """RiMEA 9's verdict on the exit times (s, NaN: never out) of every person of both runs: passed when everyone
    left in both and the evacuation time (the last person out) with two exits is 1.6 to 2.4 times that with four."""
    evacuated = {label: float(np.isfinite(t).mean()) for label, t in (("four", four_open), ("two", two_closed))}
    everyone = all(share == 1.0 for share in evacuated.values())
    t_four = float(np.max(four_open)) if evacuated["four"] == 1.0 else None  # the last person out, if all left
    t_two = float(np.max(two_closed)) if evacuated["two"] == 1.0 else None
    ratio = t_two / t_four if everyone and t_four and t_two else None
    low, high = RIMEA_9_RATIO
    return TestResult(
        "RiMEA 9: two of four exits closed",
        ratio is not None and low <= ratio <= high,
        ratio,
        "ratio of evacuation times, two exits over four",
        f"in [{low:g}, {high:g}], everyone out in both runs",
        RIMEA_SOURCE + ", test 9",
        {"evacuation_time_four_s": t_four, "evacuation_time_two_s": t_two, "evacuated": evacuated},
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
    return TestResult(
        "bottleneck flow against width",
        measured and worst <= LIDDLE_TOLERANCE,
        worst,
        "largest relative error",
        f"<= {LIDDLE_TOLERANCE:g} at every width, each flow over >= {MIN_CROSSINGS} crossings",
        LIDDLE_SOURCE,
        {
            "widths_m": list(widths),
            "flows_per_s": [None if not math.isfinite(f) else round(f, 3) for f in flows],
            "liddle_per_s": [liddle_flow(w) for w in widths],
            "relative_error": [None if not math.isfinite(e) else round(e, 3) for e in errors],
            "crossings_per_run": counts,
            "jupedsim_distance_per_s": round(distance, 3) if measured else None,
        },
    )


def liddle_flow(width: float) -> float:
    """Liddle's measured flow (1/s) at one of :data:`~pedrl.scenarios.LIDDLE_WIDTHS`."""
    return LIDDLE_FLOWS[LIDDLE_WIDTHS.index(width)]


# ---------------------------------------------------------------------------------------------- lanes

LANES_WINDOW: Final = (14.0, 24.0)
"""Feliciani and Nishinari's measurement area (x, m) in their 38 m x 3 m corridor."""
LANES_REACH: Final = 5.0
LANE_WIDTH: Final = 0.8
"""Width (m) of a lane: two bodies of a pedestrian's 0.2 m radius side by side would be two lanes."""


def lanes(context: Context) -> TestResult:
    """Lanes in Feliciani and Nishinari's bidirectional corridor (38 m x 3 m; 27 persons start in each 12 m end and
    walk to the other). Verdict: :func:`judge_lanes`."""
    scenario = build_scenario({"name": "corridor", "length": 38.0, "width": 3.0, "spawn_length": 12.0})
    recording = context.run(scenario, num_agents=LANES_AGENTS, replicas=context.budget.replicas, max_time=120.0, seed=5)
    direction = np.where(np.arange(LANES_AGENTS) < LANES_AGENTS // 2, 1, -1)  # group 0 walks to +x
    return judge_lanes(recording, direction)


def judge_lanes(recording: Recording, direction: np.ndarray) -> TestResult:
    """The lanes verdict: the mean lane order (:func:`~pedrl.validation.measures.lane_order_values`, lanes 0.8 m
    wide, 5 m reach) over the agent-frames in the 10 m measurement area while it holds at least 10 agents, some of
    each direction. Passed at 0.5 or more over at least 300 such agent-frames. The time to walk through the area is
    reported beside it."""
    values = lane_order_values(
        recording.positions,
        recording.in_room,
        direction,
        lane_width=LANE_WIDTH,
        window=LANES_WINDOW,
        reach=LANES_REACH,
        min_agents=LANES_MIN_AGENTS,
    )
    order = float(values.mean()) if values.size else None
    crossing = window_crossing_times(recording, LANES_WINDOW)
    passed = values.size >= LANES_MIN_FRAMES and order is not None and order >= LANE_ORDER_PASS
    return TestResult(
        "lanes in a bidirectional corridor",
        passed,
        order,
        "lane order parameter",
        f">= {LANE_ORDER_PASS:g} over >= {LANES_MIN_FRAMES} agent-frames of >= {LANES_MIN_AGENTS} agents",
        LANES_SOURCE,
        {
            "agent_frames": int(values.size),
            "evacuated": recording.evacuated,
            "time_to_cross_10m_s": None if not crossing.size else round(float(crossing.mean()), 2),
            "crossed": int(crossing.size),
        },
    )


def window_crossing_times(recording: Recording, window: tuple[float, float]) -> np.ndarray:
    """Times (s) agents spent walking through ``window`` (x, m) from one end to the other: the frames between their
    first and last frame in it, for agents whose first and last positions there lie within one frame's step of
    opposite ends."""
    x = np.where(recording.in_room, recording.positions[..., 0], np.nan)
    inside = (x >= window[0]) & (x <= window[1])
    step = recording.max_speed / recording.frame_rate
    times = []
    for replica, agent in zip(*np.nonzero(inside.any(axis=1)), strict=True):
        frames = np.nonzero(inside[replica, :, agent])[0]
        ends = x[replica, [frames[0], frames[-1]], agent]
        if min(ends) - window[0] <= step and window[1] - max(ends) <= step:
            times.append((frames[-1] - frames[0]) / recording.frame_rate)
    return np.array(times)


# ---------------------------------------------------------------------------------------------- the suite


TESTS: Final[dict[str, tuple[str, Callable[[Context], Any]]]] = {
    "rimea_1": ("RiMEA 1: travel time in a 40 m corridor", rimea_1),
    "rimea_4": ("RiMEA 4: speed against density (Weidmann)", rimea_4),
    "rimea_6": ("RiMEA 6: around a corner", rimea_6),
    "rimea_9": ("RiMEA 9: two of four exits closed", rimea_9),
    "bottleneck": ("bottleneck flow against width", bottleneck),
    "lanes": ("lanes in a bidirectional corridor", lanes),
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
) -> tuple[list[TestResult], dict[str, Figure]]:
    """Run the suite (or the tests named in ``only``) with one crowd; return its rows and figures. The invariants
    row closes the list whenever any test ran."""
    context = Context(crowd, budget)
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
        if isinstance(outcome, tuple):
            outcome, figures[key] = outcome
        results.append(outcome)
    if results:  # with nothing simulated (every test not applicable), the row fails: it checked nothing
        results.append(invariants_row(context.invariants))
    return results, figures

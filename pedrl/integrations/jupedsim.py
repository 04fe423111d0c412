"""JuPedSim, the field's reference simulator, on a pedrl scenario: the same area, agents and start positions.

Usage::

    from pedrl.integrations.jupedsim import JuPedSimModel, simulate
    from pedrl.scenarios import build_scenario

    scenario = build_scenario({"name": "corner"})
    run = simulate(
        scenario,
        positions=[[1.0, 1.0], [3.0, 1.0]],  # (N, 2) m
        exit_index=[0, 0],  # (N,)
        waypoints=[[(11.0, 1.0)], [(11.0, 1.0)]],  # per agent, may be empty
        model=JuPedSimModel(desired_speed=1.33),
        max_time=60.0,
        frame_rate=1.0,
    )
    run.positions  # (T + 1, N, 2) m, frame 0 the start

How the scenario maps onto JuPedSim:

- Area: JuPedSim removes an agent once its centre is inside an exit stage, a polygon. Each of our exits (a segment
  on the boundary) gets an apron outside it, :data:`EXIT_APRON_DEPTH` m deep (deeper for the generalized
  centrifugal force model, whose walls repel further: :func:`apron_depth`) and as wide as the exit; the walkable area
  grows by the aprons, and the aprons are the exit stages. So an agent leaves when its centre crosses its exit's
  segment, as in our simulation (:func:`walkable_with_aprons`).
- Routes: each agent walks to its exit (``exit_index``) through its waypoints first: JuPedSim waypoint stages that
  count as reached within the scenario's ``waypoint_radius``, joined by fixed transitions into one journey per
  distinct route. JuPedSim finds the way to each stage through the area itself (its routing engine). Unlike our
  simulation, where an agent leaves through any exit it passes, a JuPedSim agent leaves through its own exit only.
- Models: any of JuPedSim's operational models (:data:`MODELS`: the collision-free speed model of Tordeux, Chraibi
  and Seyfried 2016 and its V2 and V3, the anticipation velocity model, the generalized centrifugal force model, the
  social force model of Helbing, Farkas and Vicsek 2000, WarpDriver), with JuPedSim's own defaults except the values
  of :class:`JuPedSimModel`; :func:`check_model` has JuPedSim itself check them before a run.

JuPedSim is optional (``pip install 'pedrl[jupedsim]'``): it is imported when :func:`simulate` runs, so importing
this module needs only shapely and numpy.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import shapely
from numpy.typing import ArrayLike
from shapely.geometry import Polygon

from pedrl.common.checks import check_real, first_line
from pedrl.integrations.jupedsim_data import (
    EXIT_APRON_DEPTH,
    GCFM_WALL_REACH,
    MODELS,
    JuPedSimModel,
    JuPedSimRun,
    Scene,
    apron_depth,
    model_from_settings,
    pad_frames,
    room_scene,
)
from pedrl.scenarios import Scenario
from pedrl.sim import RoomEnv

__all__ = [
    "EXIT_APRON_DEPTH",
    "GCFM_WALL_REACH",
    "INSTALL_HINT",
    "MODELS",
    "JuPedSimModel",
    "JuPedSimRun",
    "JuPedSimRunError",
    "Scene",
    "apron_depth",
    "build_simulation",
    "check_model",
    "installed",
    "model_from_settings",
    "pad_frames",
    "room_scene",
    "simulate",
    "simulate_room",
    "walkable_with_aprons",
]

INSTALL_HINT: Final = "jupedsim is not installed: pip install 'pedrl[jupedsim]'"
ROUTE_CHECK_PERIOD: Final = 0.1
"""Simulated time (s) between two checks of the agents past their waypoint (``pass_waypoints``): 0.12 m of walking at
JuPedSim's default speed, and a tenth of the Python work of a check after every step."""
STEP_TOLERANCE: Final = 1e-6
"""Relative tolerance of ``1 / (frame_rate * dt)`` being a whole number of JuPedSim steps per frame."""


class JuPedSimRunError(ValueError):
    """JuPedSim stopped a run it had accepted (one line: the model, the simulated time and JuPedSim's reason)."""


# ---------------------------------------------------------------------- geometry
def walkable_with_aprons(scenario: Scenario, *, depth: float = EXIT_APRON_DEPTH) -> tuple[Polygon, tuple[Polygon, ...]]:
    """The walkable area grown by an apron outside every exit, and the aprons (one per exit, in order).

    An apron is the rectangle of the exit's segment and ``depth`` m outwards; it must not overlap the walkable area.

    Raises:
        ValueError: one line, for an exit without ``depth`` m of free space outside it.
    """
    depth = check_real("depth", depth, unit="m", positive=True)
    walkable = scenario.walkable
    aprons = []
    for index, exit_ in enumerate(scenario.exits):
        (x1, y1), (x2, y2) = list(exit_.coords)[:2]
        length = math.hypot(x2 - x1, y2 - y1)
        normal = np.array([y2 - y1, x1 - x2]) / length * depth
        candidates = [
            Polygon(
                [
                    (x1, y1),
                    (x2, y2),
                    (x2 + sign * normal[0], y2 + sign * normal[1]),
                    (x1 + sign * normal[0], y1 + sign * normal[1]),
                ]
            )
            for sign in (1.0, -1.0)
        ]
        apron = min(candidates, key=lambda polygon: polygon.intersection(walkable).area)
        if apron.intersection(walkable).area > 1e-9 * apron.area:
            raise ValueError(
                f"exit {index} of scenario {scenario.name!r} is invalid for JuPedSim: it needs {depth:g} m of free"
                " space outside it for its exit apron"
            )
        aprons.append(apron)
    area = shapely.union_all([walkable, *aprons])
    if not isinstance(area, Polygon):
        raise ValueError(
            f"scenario {scenario.name!r} is invalid for JuPedSim: its area and exit aprons do not form one polygon"
        )
    return area, tuple(aprons)


# ---------------------------------------------------------------------- the simulation
def simulate(
    scenario: Scenario,
    *,
    positions: ArrayLike,
    exit_index: ArrayLike,
    waypoints: Sequence[Sequence[tuple[float, float]]],
    model: JuPedSimModel | None = None,
    max_time: float,
    frame_rate: float,
    pass_waypoints: bool = True,
) -> JuPedSimRun:
    """Run JuPedSim in ``scenario`` from the given start until every agent left or ``max_time`` passed.

    Args:
        scenario: the area and its exits (its spawn areas are not used: ``positions`` place the agents).
        positions: ``(N, 2)`` start centres (m), inside the walkable area.
        exit_index: ``(N,)`` int, the exit of ``scenario.exits`` each agent walks to.
        waypoints: per agent, the points ``(x, y)`` (m) it passes first, in order (may be empty); reached within
            ``scenario.waypoint_radius``.
        model: the JuPedSim model and parameters (default :class:`JuPedSimModel`'s).
        max_time: simulated time (s) after which the run stops.
        frame_rate: frames per second of simulated time (1/s); ``1 / (frame_rate * model.dt)`` must be a whole number.
        pass_waypoints: also count a waypoint as reached once the agent is past it, as our simulation does: beyond
            the line through it across the direction to the next point of its route, less than ``waypoint_radius``
            to the side (checked every :data:`ROUTE_CHECK_PERIOD` s). False: JuPedSim's waypoint stages alone,
            reached within ``waypoint_radius`` only; in a crowd, agents pushed past a waypoint then turn back to it
            and jam.

    Returns:
        The trajectories, ``T = floor(max_time * frame_rate)`` frames after the start, fewer when everyone left.

    Raises:
        ModuleNotFoundError: jupedsim is not installed.
        ValueError: one line, for a bad value (before any step is simulated).
    """
    jps = _import_jupedsim()
    model = model if model is not None else JuPedSimModel()
    start = _checked_start(
        scenario,
        model=model,
        positions=positions,
        exit_index=exit_index,
        waypoints=waypoints,
        max_time=max_time,
        frame_rate=frame_rate,
    )
    simulation, agents = _jupedsim_scene(jps, scenario, model, start)
    return _run_frames(simulation, agents, scenario, model, start, pass_waypoints=pass_waypoints)


def build_simulation(
    scenario: Scenario,
    *,
    positions: ArrayLike,
    exit_index: ArrayLike,
    waypoints: Sequence[Sequence[tuple[float, float]]],
    model: JuPedSimModel | None = None,
) -> Any:
    """JuPedSim's ``Simulation`` of the start :func:`simulate` takes (the same arguments, checked alike), its agents
    added and no step taken, for a caller that steps it itself (``python -m pedrl.bench --only walk`` times its
    ``iterate``); it records nothing and passes no waypoint by the line past it.

    Raises:
        ModuleNotFoundError: jupedsim is not installed.
        ValueError: one line, for a bad value.
    """
    jps = _import_jupedsim()
    model = model if model is not None else JuPedSimModel()
    checked = {"positions": positions, "exit_index": exit_index, "waypoints": waypoints}
    start = _checked_start(scenario, model=model, **checked, max_time=model.dt, frame_rate=1.0 / model.dt)
    return _jupedsim_scene(jps, scenario, model, start)[0]


@dataclass(frozen=True)
class _Start:
    """The checked input of :func:`simulate`: the agents' start, their routes and exits, and the frames to record.

    Attributes:
        starts: ``(N, 2)`` float64 start centres (m).
        exits: ``(N,)`` int64, each agent's exit.
        routes: per agent, its waypoints ``(x, y)`` (m), in order (may be empty).
        frame_rate: frames per second of simulated time (1/s).
        steps_per_frame: JuPedSim steps per frame.
        num_frames: T, the frames to record after the start at most.
        area: the walkable area grown by the exit aprons.
        aprons: the exit aprons, one per exit.
    """

    starts: np.ndarray
    exits: np.ndarray
    routes: list[tuple[tuple[float, float], ...]]
    frame_rate: float
    steps_per_frame: int
    num_frames: int
    area: Polygon
    aprons: tuple[Polygon, ...]


def _checked_start(
    scenario: Scenario,
    *,
    model: object,
    positions: ArrayLike,
    exit_index: ArrayLike,
    waypoints: Sequence[Sequence[tuple[float, float]]],
    max_time: float,
    frame_rate: float,
) -> _Start:
    """The arguments of :func:`simulate` checked, every check before any compute (a one-line ValueError)."""
    if not isinstance(model, JuPedSimModel):
        raise ValueError(f"model={model!r} is invalid: must be a JuPedSimModel")
    starts = _points("positions", positions)
    count = starts.shape[0]
    exits = _exit_indices(exit_index, count, len(scenario.exits))
    if not hasattr(waypoints, "__len__") or len(waypoints) != count:
        given = f"{len(waypoints)} routes" if hasattr(waypoints, "__len__") else repr(waypoints)[:60]
        raise ValueError(f"waypoints holds {given}: must hold one route (a list of points) per agent, {count}")
    routes = [
        tuple(map(tuple, _points(f"waypoints[{i}]", route, empty=True).tolist())) for i, route in enumerate(waypoints)
    ]
    max_time = check_real("max_time", max_time, unit="s", positive=True)
    frame_rate = check_real("frame_rate", frame_rate, unit="1/s", positive=True)
    steps_per_frame = _steps_per_frame(frame_rate, model.dt)
    area, aprons = walkable_with_aprons(scenario, depth=apron_depth(model))
    _check_inside("positions", starts, scenario.walkable)
    for index, route in enumerate(routes):
        _check_inside(f"waypoints[{index}]", np.asarray(route).reshape(-1, 2), scenario.walkable)
    num_frames = int(math.floor(max_time * frame_rate * (1.0 + STEP_TOLERANCE)))
    if num_frames < 1:
        raise ValueError(
            f"max_time={max_time!r} is invalid: shorter than one frame (1 / frame_rate = {1 / frame_rate:g} s)"
        )
    return _Start(
        starts=starts,
        exits=exits,
        routes=routes,
        frame_rate=frame_rate,
        steps_per_frame=steps_per_frame,
        num_frames=num_frames,
        area=area,
        aprons=aprons,
    )


def _jupedsim_scene(
    jps: Any, scenario: Scenario, model: JuPedSimModel, start: _Start
) -> tuple[Any, dict[int, tuple[int, _Journey]]]:
    """The JuPedSim simulation of the area, its exit stages, one journey per distinct route, and the agents; and
    each agent's JuPedSim id -> (agent index, its journey)."""
    operational = _operational_model(jps, model)
    try:
        simulation = jps.Simulation(model=operational, geometry=start.area, dt=model.dt)
        exit_stages = [simulation.add_exit_stage(apron) for apron in start.aprons]
    except RuntimeError as err:
        raise ValueError(f"scenario {scenario.name!r} is invalid for JuPedSim: {first_line(err)}") from None
    waypoint_stages: dict[tuple[float, float], int] = {}
    journeys: dict[tuple[tuple[tuple[float, float], ...], int], _Journey] = {}
    agents: dict[int, tuple[int, _Journey]] = {}  # JuPedSim id -> (agent index, its journey)
    starts, routes, exits = start.starts, start.routes, start.exits
    for index in range(starts.shape[0]):
        key = (routes[index], int(exits[index]))
        if key not in journeys:
            journeys[key] = _add_journey(jps, simulation, scenario, key, exit_stages, waypoint_stages)
        journey = journeys[key]
        parameters = _agent_parameters(jps, model, starts[index], journey.id, journey.stages[0])
        try:
            agents[simulation.add_agent(parameters)] = (index, journey)
        except RuntimeError as err:  # e.g. too close to a wall or another agent for the model
            raise ValueError(
                f"positions[{index}]={starts[index].tolist()} is invalid: JuPedSim refuses it ({first_line(err)})"
            ) from None
    return simulation, agents


def _run_frames(
    simulation: Any,
    agents: dict[int, tuple[int, _Journey]],
    scenario: Scenario,
    model: JuPedSimModel,
    start: _Start,
    *,
    pass_waypoints: bool,
) -> JuPedSimRun:
    """The run, frame by frame, until every agent left or ``start.num_frames`` frames passed."""
    starts, num_frames, steps_per_frame = start.starts, start.num_frames, start.steps_per_frame
    count = starts.shape[0]
    route_check_steps = max(1, round(ROUTE_CHECK_PERIOD / model.dt))
    routing = {agent_id: journey for agent_id, (_, journey) in agents.items() if journey.lines}
    frames = np.empty((num_frames + 1, count, 2))
    frames[0] = starts
    current = starts.copy()
    left_at = np.full(count, -1, dtype=np.int64)
    exit_time = np.full(count, math.nan)

    def collect_departures(frame: int) -> None:
        """Agents out after the step just simulated, in frame ``frame``. JuPedSim tests its exit stages with the
        positions of the step before: an agent listed now (still readable, gone at the next step) was first past its
        exit after the previous step."""
        for agent_id in simulation.removed_agents():
            index = agents[agent_id][0]
            step = simulation.iteration_count() - 1
            left_at[index] = -(-step // steps_per_frame)  # the frame whose interval holds that step
            if left_at[index] < frame:  # that step ended the previous frame, which holds the point where it left
                current[index] = frames[left_at[index], index]
                exit_time[index] = step * model.dt
            else:  # one step further, still in the apron
                current[index] = simulation.agent(agent_id).position
                exit_time[index] = (step + 1) * model.dt

    recorded = num_frames
    for frame in range(1, num_frames + 1):
        for _ in range(steps_per_frame):
            try:
                simulation.iterate()
            except RuntimeError as err:  # the model put an agent where the area does not reach, for example
                time = simulation.iteration_count() * model.dt
                raise JuPedSimRunError(
                    f"JuPedSim's {model.model} model stopped after {time:.2f} s in scenario {scenario.name!r}:"
                    f" {first_line(err)}"
                ) from None
            collect_departures(frame)
            if pass_waypoints and routing and simulation.iteration_count() % route_check_steps == 0:
                _pass_waypoints(simulation, routing, scenario.waypoint_radius)
        for agent in simulation.agents():
            index = agents[agent.id][0]
            if left_at[index] < 0:
                current[index] = agent.position
        frames[frame] = current
        if bool((left_at >= 0).all()):
            recorded = int(left_at.max())
            break
    else:  # one more step tells who was out after the last one
        simulation.iterate()
        collect_departures(num_frames + 1)
    frames = frames[: recorded + 1]
    steps = np.arange(recorded + 1)[:, None]
    active = (left_at < 0)[None, :] | (steps < left_at[None, :])
    return JuPedSimRun(
        positions=frames, active=active, left_at=left_at, exit_time=exit_time, frame_rate=start.frame_rate
    )


# ---------------------------------------------------------------------- journeys
@dataclass(frozen=True)
class _Journey:
    """A JuPedSim journey: its id, its stages (waypoints, then the exit) and, for each waypoint stage, the line
    past which it counts as reached: the waypoint ``(x, y)`` and the unit direction ``(dx, dy)`` from it to the next
    point of the route (the exit's centre after the last waypoint), as plain floats."""

    id: int
    stages: tuple[int, ...]
    lines: tuple[tuple[float, float, float, float], ...]

    def next_stage(self, stage: int, position: tuple[float, float], radius: float) -> int | None:
        """The stage after ``stage`` if ``position`` is past the waypoint of ``stage`` (beyond its line, less than
        ``radius`` to the side), else None."""
        step = self.stages.index(stage)
        if step >= len(self.lines):
            return None
        x, y, dx, dy = self.lines[step]
        ahead = (position[0] - x) * dx + (position[1] - y) * dy
        side = (position[0] - x) * dy - (position[1] - y) * dx
        return self.stages[step + 1] if ahead >= 0.0 and abs(side) < radius else None


def _add_journey(
    jps: Any,
    simulation: Any,
    scenario: Scenario,
    route: tuple[tuple[tuple[float, float], ...], int],
    exit_stages: list[int],
    waypoint_stages: dict[tuple[float, float], int],
) -> _Journey:
    """The journey of the route ``(waypoints, exit)``: waypoint stages joined by fixed transitions to the exit."""
    points, exit_ = route
    for point in points:
        if point not in waypoint_stages:
            waypoint_stages[point] = simulation.add_waypoint_stage(point, scenario.waypoint_radius)
    stages = [waypoint_stages[point] for point in points] + [exit_stages[exit_]]
    description = jps.JourneyDescription(stages)
    for stage, following in zip(stages[:-1], stages[1:], strict=True):
        description.set_transition_for_stage(stage, jps.Transition.create_fixed_transition(following))
    centre = tuple(scenario.exits[exit_].interpolate(0.5, normalized=True).coords[0])
    lines = []
    for (x, y), (x_next, y_next) in zip(points, (*points, centre)[1:], strict=True):
        length = max(math.hypot(x_next - x, y_next - y), 1e-9)
        lines.append((x, y, (x_next - x) / length, (y_next - y) / length))
    return _Journey(id=simulation.add_journey(description), stages=tuple(stages), lines=tuple(lines))


def _pass_waypoints(simulation: Any, routing: dict[int, _Journey], radius: float) -> None:
    """Send every agent of ``routing`` that is past its waypoint on to the next stage, as our simulation does
    (``RoomEnv._advance_routes``); agents that aim at their exit leave ``routing``."""
    for agent_id, journey in list(routing.items()):
        agent = simulation.agent(agent_id)
        stage = agent.stage_id
        following = journey.next_stage(stage, agent.position, radius)
        if following is not None:
            simulation.switch_agent_journey(agent_id, journey.id, following)
            stage = following
        if stage == journey.stages[-1]:
            del routing[agent_id]


# ---------------------------------------------------------------------- helpers
def simulate_room(
    scenario: Scenario, room: RoomEnv, *, model: JuPedSimModel, max_time: float, frame_rate: float
) -> list[JuPedSimRun]:
    """:func:`simulate` from the scene of every replica of ``room`` as it stands (after ``room.reset(...)``), one
    replica after another (``scenario``: the one the room was built in)."""
    runs = []
    for replica in range(room.num_replicas):
        scene = room_scene(room, replica=replica)
        runs.append(
            simulate(
                scenario,
                positions=scene.positions,
                exit_index=scene.exit_index,
                waypoints=scene.waypoints,
                model=model,
                max_time=max_time,
                frame_rate=frame_rate,
            )
        )
    return runs


def installed() -> bool:
    """Whether JuPedSim can be imported (checked without importing it)."""
    import importlib.util

    return importlib.util.find_spec("jupedsim") is not None


def _import_jupedsim() -> Any:
    try:
        import jupedsim
    except ImportError as error:
        raise ModuleNotFoundError(INSTALL_HINT, name="jupedsim") from error
    return jupedsim


def _operational_model(jps: Any, model: JuPedSimModel) -> Any:
    """JuPedSim's model object of ``model.model``, at its defaults (the anticipation model's random seed fixed)."""
    builders = {
        "collision_free_speed": jps.CollisionFreeSpeedModel,
        "collision_free_speed_v2": jps.CollisionFreeSpeedModelV2,
        "collision_free_speed_v3": jps.CollisionFreeSpeedModelV3,
        "anticipation_velocity": lambda: jps.AnticipationVelocityModel(rng_seed=0),
        "generalized_centrifugal_force": jps.GeneralizedCentrifugalForceModel,
        "social_force": jps.SocialForceModel,
        "warp_driver": jps.WarpDriverModel,
    }
    return builders[model.model]()


def _agent_parameters(jps: Any, model: JuPedSimModel, position: np.ndarray, journey: int, stage: int) -> Any:
    common = {
        "position": (float(position[0]), float(position[1])),
        "desired_speed": model.desired_speed,
        "journey_id": journey,
        "stage_id": stage,
    }
    body = {"radius": model.radius}
    timed = {"time_gap": model.time_gap, **body}
    classes = {
        "collision_free_speed": (jps.CollisionFreeSpeedModelAgentParameters, timed),
        "collision_free_speed_v2": (jps.CollisionFreeSpeedModelV2AgentParameters, timed),
        "collision_free_speed_v3": (jps.CollisionFreeSpeedModelV3AgentParameters, timed),
        "anticipation_velocity": (jps.AnticipationVelocityModelAgentParameters, timed),
        "generalized_centrifugal_force": (
            jps.GeneralizedCentrifugalForceModelAgentParameters,
            {"a_min": model.radius, "b_min": model.radius, "b_max": 2.0 * model.radius},
        ),
        "social_force": (jps.SocialForceModelAgentParameters, body),
        "warp_driver": (jps.WarpDriverModelAgentParameters, {"orientation": (1.0, 0.0), **body}),
    }
    parameters, specific = classes[model.model]
    return parameters(**common, **specific)


def check_model(model: JuPedSimModel) -> None:
    """Have JuPedSim check ``model``'s parameters (its own ``CheckModelConstraint``) on one agent in a 10 m square,
    before any run: one-line ``ValueError`` naming the model when JuPedSim refuses them.

    Raises:
        ModuleNotFoundError: jupedsim is not installed.
        ValueError: one line, JuPedSim's reason.
    """
    jps = _import_jupedsim()
    square = Polygon([(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0)])
    try:
        simulation = jps.Simulation(model=_operational_model(jps, model), geometry=square, dt=model.dt)
        exit_stage = simulation.add_exit_stage(Polygon([(9.0, 4.0), (10.0, 4.0), (10.0, 6.0), (9.0, 6.0)]))
        journey = simulation.add_journey(jps.JourneyDescription([exit_stage]))
        simulation.add_agent(_agent_parameters(jps, model, np.array([5.0, 5.0]), journey, exit_stage))
    except RuntimeError as err:
        raise ValueError(f"jupedsim.model={model.model} refuses its parameters: {first_line(err)}") from None


def _points(name: str, value: Any, *, empty: bool = False) -> np.ndarray:
    """``value`` as finite ``(M, 2)`` float64 coordinates (M >= 1 unless ``empty``), else a one-line error."""
    try:
        points = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        points = np.zeros((0, 3))
    if empty and points.size == 0:
        return points.reshape(0, 2)
    if points.ndim != 2 or points.shape[0] < 1 or points.shape[1] != 2 or not np.isfinite(points).all():
        shape = "(M, 2)" if empty else "(N, 2) with N >= 1"
        raise ValueError(f"{name} is invalid: must be finite coordinates (m) of shape {shape}, got {_describe(value)}")
    return points


def _exit_indices(value: Any, count: int, num_exits: int) -> np.ndarray:
    indices = np.asarray(value)
    if indices.shape != (count,) or not np.issubdtype(indices.dtype, np.integer):
        raise ValueError(f"exit_index is invalid: must be {count} integers (one per agent), got {_describe(value)}")
    if ((indices < 0) | (indices >= num_exits)).any():
        bad = int(indices[(indices < 0) | (indices >= num_exits)][0])
        raise ValueError(f"exit_index holds {bad}: every index must be in [0, {num_exits}) (the scenario's exits)")
    return indices.astype(np.int64)


def _steps_per_frame(frame_rate: float, dt: float) -> int:
    steps = 1.0 / (frame_rate * dt)
    whole = round(steps)
    if whole < 1 or abs(steps - whole) > STEP_TOLERANCE * steps:
        raise ValueError(
            f"frame_rate={frame_rate!r} is invalid: 1 / (frame_rate * dt) must be a whole number of JuPedSim steps"
            f" of dt={dt!r} s, got {steps:g}"
        )
    return whole


def _check_inside(name: str, points: np.ndarray, walkable: Polygon) -> None:
    if points.size == 0:
        return
    inside = shapely.contains_xy(walkable, points[:, 0], points[:, 1])
    if not inside.all():
        index = int(np.flatnonzero(~inside)[0])
        x_min, y_min, x_max, y_max = walkable.bounds
        raise ValueError(
            f"{name}[{index}]={points[index].tolist()} is invalid: it must lie inside the walkable area"
            f" [{x_min:g}, {y_min:g}] x [{x_max:g}, {y_max:g}]"
        )


def _describe(value: Any) -> str:
    shape = getattr(value, "shape", None)
    return f"shape {tuple(shape)}" if shape is not None else repr(value)[:60]

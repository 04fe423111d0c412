"""Routes through any walkable area (:mod:`pedrl.scenarios.routes`, :mod:`pedrl.sim.routing`): a room whose exit
may be out of sight gets a route graph, built automatically for every scenario and WKT room, and each walker the
corners of its own shortest path round the walls."""

from dataclasses import replace

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf
from shapely.geometry import LineString, Point

from pedrl.cli import CONFIG_DIR
from pedrl.scenarios import SCENARIOS, Scenario, build_scenario, custom
from pedrl.scenarios.builders import BUILDERS
from pedrl.scenarios.routes import CLEARANCE, CLEARANCES, WAYPOINT_RADIUS, with_routes
from pedrl.sim.controllers import GreedyDoorController
from pedrl.sim.motion import Continuous, Yield

GOAL = {
    "action_frame": "goal",
    "speed_ratios": [0.0, 0.2, 0.4, 0.6, 0.7, 0.8, 0.9, 0.95, 1.0],
    "turn_ratios": [-0.5, -0.25, -0.1, -0.05, 0.0, 0.05, 0.1, 0.25, 0.5],
}


def config(name: str) -> dict:
    return OmegaConf.to_container(OmegaConf.load(f"{CONFIG_DIR}/scenario/{name}.yaml"), resolve=True)


def unrouted(name: str):
    """The held-out room without its routes (the control): its walkers aim straight at the exit."""
    return replace(build_scenario(config(name)), routes=None, waypoint_radius=Scenario.waypoint_radius)


def routes_of(scenario, agents: int = 40, seed: int = 1) -> list[list[tuple[float, float]]]:
    """The waypoints each of ``agents`` walkers placed with ``seed`` gets (replica 0)."""
    env = scenario.room(num_replicas=1, num_agents=agents, device="cpu", agent_radius=0.2)
    env.reset(seed=seed)
    return [
        [tuple(point) for point in route[:length]]
        for route, length in zip(env.spawns.waypoints[0].tolist(), env.spawns.route_length[0].tolist(), strict=True)
    ]


def greedy_out(scenario, motion: str = "continuous") -> tuple[float, float]:
    """Share of 40 greedy walkers (in 2 rooms, epsilon 0) out within 150 s, and wall contacts per agent."""
    walking = (
        Continuous(contact="yield", time_gap=0.4, order="door_first")
        if motion == "continuous"
        else Yield(time_gap=0.4, order="door_first")
    )
    env = scenario.room(
        num_replicas=2, num_agents=40, device="cpu", max_decisions=150, agent_radius=0.2, max_speed=1.34,
        motion=walking, **GOAL,
    )  # fmt: skip
    controller = GreedyDoorController(epsilon=0.0, generator=torch.Generator().manual_seed(0))
    obs, info = env.reset(seed=1)
    reached = torch.zeros(env.num_replicas, env.num_agents, dtype=torch.bool)
    walls = 0
    while bool(env.active.any()):
        obs, _, _, _, info = env.step(controller.act(env, obs, info))
        reached |= info["reached"]
        walls += int(info["crashed_wall"].sum())
    return float(reached.float().mean()), walls / reached.numel()


@pytest.mark.parametrize("name", ["partition_room", "corridor_room"])
def test_the_exit_is_out_of_sight_from_every_start(name):
    """The held-out rooms of the new kind: from 200 random starts, the line to the exit's middle leaves the area."""
    scenario = build_scenario(config(name))
    (x0, y0, x1, y1) = scenario.spawns[0].area.bounds
    generator = np.random.default_rng(0)
    middle = scenario.exits[0].interpolate(0.5, normalized=True)
    for x, y in zip(generator.uniform(x0, x1, 200), generator.uniform(y0, y1, 200), strict=True):
        assert not scenario.walkable.covers(LineString([(x, y), (middle.x, middle.y)]))


@pytest.mark.parametrize("name", ["partition_room", "corridor_room"])
def test_greedy_walkers_leave_round_the_walls_that_hide_the_exit(name):
    """With the route every walker leaves, touching a wall about once; without it (the builder's room, the control)
    they walk into the wall that hides the exit: none leaves the partition room, and in the corridor room, which the
    walls themselves funnel, fewer leave with four times the wall contacts."""
    out, walls = greedy_out(build_scenario(config(name)))
    assert out >= 0.98 and walls <= 1.5
    out_without, walls_without = greedy_out(unrouted(name))
    assert out_without < out and walls_without >= 3 * walls


def test_every_walker_turns_round_the_partition_clear_of_its_end():
    """Each walker's own route passes over the partition's end (9 m), the wide clearance off it, in one or two
    corners (one where the walker already sees the far corner)."""
    scenario = build_scenario(config("partition_room"))
    partition = LineString([(10.0, 0.0), (10.0, 9.0)]).buffer(0.1)
    for corners in routes_of(scenario):
        assert 1 <= len(corners) <= 2 and all(y > 9.0 for _, y in corners)
        assert all(Point(corner).distance(partition) >= CLEARANCES[0] - 1e-5 for corner in corners)  # the wider one
    assert scenario.waypoint_radius == pytest.approx(WAYPOINT_RADIUS)


def test_an_opening_narrower_than_the_wide_clearance_is_routed_with_the_narrow_one():
    """A 0.8 m gap closes at 0.5 m of clearance (1 m needed) and stays open at 0.25 m: the route goes through it."""
    settings = {
        "name": "custom",
        "geometry": "POLYGON ((0 0, 9.9 0, 9.9 11.2, 10.1 11.2, 10.1 0, 20 0, 20 12, 0 12, 0 0))",
        "exits": [[20.0, 1.0, 20.0, 2.6]],
        "spawn": [[0.5, 0.5, 9.4, 8.0]],
    }
    for corners in routes_of(build_scenario(settings), agents=10):
        assert corners and all(11.2 < y < 12.0 - CLEARANCE + 1e-5 for _, y in corners)


def test_a_start_area_that_reaches_no_exit_is_refused_naming_it():
    """A partition whose gap (0.4 m) is narrower than a body with the least clearance (0.5 m): the left half reaches
    no exit."""
    settings = {
        "name": "custom",
        "geometry": "POLYGON ((0 0, 9.9 0, 9.9 11.6, 10.1 11.6, 10.1 0, 20 0, 20 12, 0 12, 0 0))",
        "exits": [[20.0, 1.0, 20.0, 2.6]],
        "spawn": [[15.0, 0.5, 19.5, 8.0], [0.5, 0.5, 9.4, 8.0]],
    }
    with pytest.raises(ValueError) as error:
        build_scenario(settings)
    message = str(error.value)
    assert "\n" not in message and "spawn area 1 (bounds 0.5, 0.5, 9.4, 8)" in message and "reaches no exit" in message


def test_a_room_built_from_python_is_routed_as_one_from_a_config():
    settings = {key: value for key, value in config("partition_room").items() if key != "name"}
    assert custom(**settings) == build_scenario(config("partition_room"))
    assert custom(**settings).routes is not None


@pytest.mark.parametrize("name", [name for name in SCENARIOS if name != "custom"])
def test_built_in_scenarios_keep_their_routes(name):
    """Every built-in room is convex or has hand-made routes: the routes leave them as they were."""
    scenario = BUILDERS[name]()
    assert with_routes(scenario) == scenario

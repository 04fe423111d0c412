"""Routes through any walkable area (:mod:`pedrl.scenarios.routes`): a spawn area that cannot see its exit gets the
corners of the shortest path round the walls, built automatically for every scenario and WKT room."""

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

GOAL = {
    "action_frame": "goal",
    "collision_order": "door_first",
    "speed_ratios": [0.0, 0.2, 0.4, 0.6, 0.7, 0.8, 0.9, 0.95, 1.0],
    "turn_ratios": [-0.5, -0.25, -0.1, -0.05, 0.0, 0.05, 0.1, 0.25, 0.5],
}


def config(name: str) -> dict:
    return OmegaConf.to_container(OmegaConf.load(f"{CONFIG_DIR}/scenario/{name}.yaml"), resolve=True)


def unrouted(name: str):
    """The held-out room without its route (the control): its start areas aim straight at the exit."""
    scenario = build_scenario(config(name))
    spawns = tuple(replace(spawn, waypoints=()) for spawn in scenario.spawns)
    return replace(scenario, spawns=spawns, waypoint_radius=Scenario.waypoint_radius)


def greedy_out(scenario, motion: str = "continuous") -> tuple[float, float]:
    """Share of 40 greedy walkers (in 2 rooms, epsilon 0) out within 150 s, and wall contacts per agent."""
    env = scenario.room(
        num_replicas=2, num_agents=40, device="cpu", max_decisions=150, contact="yield", agent_radius=0.2,
        max_speed=1.34, motion=motion, time_gap=0.4, **GOAL,
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


def test_the_route_turns_round_the_partition_clear_of_its_end():
    scenario = build_scenario(config("partition_room"))
    corners = scenario.spawns[0].waypoints
    assert len(corners) == 2 and all(y > 9.0 for _, y in corners)  # over the partition's end (9 m)
    partition = LineString([(10.0, 0.0), (10.0, 9.0)]).buffer(0.1)
    assert all(Point(corner).distance(partition) >= CLEARANCES[0] - 1e-6 for corner in corners)  # the wider one
    assert scenario.waypoint_radius == pytest.approx(WAYPOINT_RADIUS)


def test_an_opening_narrower_than_the_wide_clearance_is_routed_with_the_narrow_one():
    """A 0.8 m gap closes at 0.5 m of clearance (1 m needed) and stays open at 0.25 m: the route goes through it."""
    settings = {
        "name": "custom",
        "geometry": "POLYGON ((0 0, 9.9 0, 9.9 11.2, 10.1 11.2, 10.1 0, 20 0, 20 12, 0 12, 0 0))",
        "exits": [[20.0, 1.0, 20.0, 2.6]],
        "spawn": [[0.5, 0.5, 9.4, 8.0]],
    }
    corners = build_scenario(settings).spawns[0].waypoints
    assert corners and all(11.2 < y < 12.0 - CLEARANCE + 1e-6 for _, y in corners)


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
    assert custom(**settings).spawns[0].waypoints


@pytest.mark.parametrize("name", [name for name in SCENARIOS if name != "custom"])
def test_built_in_scenarios_keep_their_routes(name):
    """Every built-in start area sees its exit or has its hand-made route: the routes leave them as they were."""
    scenario = BUILDERS[name]()
    assert with_routes(scenario) == scenario

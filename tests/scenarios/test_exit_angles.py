"""Exits at any angle: an exit in a wall that is not axis-aligned is cut out of the walls and lets walkers out, under
every contact rule and both motions, on the kernels and on the torch references alike."""

import math

import pytest
import torch
from shapely.geometry import LineString, Point, Polygon

from pedrl.scenarios import build_scenario
from pedrl.scenarios.model import walls_without_exits
from pedrl.sim import RoomEnv, RoomParams
from pedrl.sim.controllers import GreedyDoorController
from pedrl.sim.motion import MOTION_MODELS, Continuous
from tests.sim.test_contact import kernels_on

GOAL = {
    "action_frame": "goal",
    "speed_ratios": [0.0, 0.2, 0.4, 0.6, 0.7, 0.8, 0.9, 0.95, 1.0],
    "turn_ratios": [-0.5, -0.25, -0.1, -0.05, 0.0, 0.05, 0.1, 0.25, 0.5],
}


def turned_room(angle: float) -> tuple[str, list[float]]:
    """A 16 m square turned by ``angle`` degrees about (20, 20), and a 1.6 m exit in the middle of one side."""
    c, s = math.cos(math.radians(angle)), math.sin(math.radians(angle))
    corners = [(20 + x * c - y * s, 20 + x * s + y * c) for x, y in ((-8, -8), (8, -8), (8, 8), (-8, 8))]
    (px, py), (qx, qy) = corners[2], corners[3]
    mx, my, ux, uy = (px + qx) / 2, (py + qy) / 2, (qx - px) / 16, (qy - py) / 16
    return Polygon(corners).wkt, [mx - 0.8 * ux, my - 0.8 * uy, mx + 0.8 * ux, my + 0.8 * uy]


def greedy_out(angle: float, contact: str, motion: str = "step", decisions: int = 60) -> tuple[int, int]:
    """Greedy walkers (10 in each of 2 rooms, epsilon 0) in :func:`turned_room`: how many left, out of 20, and the
    decisions it took."""
    wkt, exit_ = turned_room(angle)
    geometry = build_scenario({"name": "custom", "geometry": wkt, "exits": [exit_]}).geometry()
    walking = (
        Continuous(contact=contact, order="door_first")
        if motion == "continuous"
        else MOTION_MODELS[contact](order="door_first")
    )
    params = RoomParams(agent_radius=0.2, max_speed=1.34, motion=walking, max_decisions=decisions, **GOAL)
    env = RoomEnv(geometry, params, num_agents=10, num_replicas=2)
    obs, info = env.reset(seed=0)
    controller = GreedyDoorController(epsilon=0.0, generator=torch.Generator().manual_seed(0))
    out = 0
    while env.active.any():
        obs, _, terminated, _, info = env.step(controller.act(env, obs, info))
        out += int(terminated.sum())
    return out, env.decision


@pytest.mark.parametrize("angle", [30, 45, 60])
def test_the_exit_is_cut_out_of_a_wall_at_any_angle(angle):
    wkt, exit_ = turned_room(angle)
    scenario = build_scenario({"name": "custom", "geometry": wkt, "exits": [exit_]})
    walls = walls_without_exits(scenario.walkable, scenario.exits)
    middle = Point((exit_[0] + exit_[2]) / 2, (exit_[1] + exit_[3]) / 2)
    assert walls.distance(middle) == pytest.approx(0.8, abs=1e-6)  # no wall across the exit
    assert walls.length == pytest.approx(4 * 16 - 1.6, abs=1e-6)  # the rest of the boundary stays a wall


def test_an_exit_in_a_holes_boundary_is_cut_out_of_it():
    """A courtyard (a hole) left through a 1 m gap in its diagonal side."""
    hole = [(8.0, 4.0), (12.0, 8.0), (8.0, 12.0), (4.0, 8.0)]
    walkable = Polygon([(0, 0), (16, 0), (16, 16), (0, 16)], [hole])
    unit = 1 / math.sqrt(2)
    exit_ = LineString([(10.0 - 0.5 * unit, 6.0 - 0.5 * unit), (10.0 + 0.5 * unit, 6.0 + 0.5 * unit)])
    walls = walls_without_exits(walkable, (exit_,))
    assert walls.distance(Point(10.0, 6.0)) == pytest.approx(0.5, abs=1e-6)
    assert walls.length == pytest.approx(64 + 4 * 4 * math.sqrt(2) - 1.0, abs=1e-6)


@pytest.mark.parametrize("contact", ["slide", "yield"])
@pytest.mark.parametrize("angle", [0, 30, 45, 60])
def test_greedy_walkers_leave_through_an_exit_at_any_angle(angle, contact):
    """Every walker out in under 20 s (13 s through the straight wall's exit); before the fix none left at 30, 45 or
    60 degrees."""
    out, decisions = greedy_out(angle, contact)
    assert out == 20 and decisions <= 20


@pytest.mark.parametrize("contact", ["stop", "headway"])
@pytest.mark.parametrize("angle", [30, 45, 60])
def test_rules_that_jam_a_greedy_crowd_let_as_many_out_at_any_angle(angle, contact):
    """Under stop and headway a greedy crowd at epsilon 0 locks at any exit, the straight wall's too (12 and 13 of 20
    out before it does, then none in another 60 s): at any angle at least half leave, where none did before the fix."""
    assert greedy_out(angle, contact)[0] >= 10


@pytest.mark.parametrize("angle", [30, 45])
def test_the_continuous_motion_and_the_torch_reference_leave_too(angle):
    assert greedy_out(angle, "yield", motion="continuous")[0] == 20
    with kernels_on(False):
        assert greedy_out(angle, "yield", decisions=20)[0] == 20

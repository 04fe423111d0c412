"""Scenarios from polygons: each built-in one, custom WKT input, the bad inputs, and physical invariants in each."""

import ast
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from shapely.geometry import box

from pedrl.algos.registry import env_factory
from pedrl.analysis import AreaGeometry, RoomGeometry
from pedrl.scenarios import SCENARIOS, PaperRoom, Scenario, Spawn, build_scenario
from pedrl.sim import NOOP_ACTION, RoomEnv
from pedrl.sim.controllers import GreedyDoorController
from pedrl.sim.geometry import distances_to_segments

BUILT_IN = [name for name in SCENARIOS if name != "custom"]
AGENTS = {"paper_room": 20, "bottleneck": 30, "corridor": 30, "corner": 7, "four_exits": 40, "hall": 60}
ENV = {"_target_": "pedrl.sim.RoomEnv", "max_decisions": 60}


@pytest.mark.parametrize("name", BUILT_IN)
def test_each_scenario_keeps_bodies_apart_inside_and_off_the_walls(name):
    """Greedy walkers with noise for 60 decisions: no overlap, nobody through a wall, nobody above top speed, and
    every agent still in the area is inside the walkable polygon."""
    env = env_factory(ENV, {"name": name})(num_replicas=2, num_agents=AGENTS[name])
    controller = GreedyDoorController(epsilon=0.2, generator=torch.Generator().manual_seed(1))
    obs, info = env.reset(seed=3)
    walls = env.geometry.walls[: env.geometry.num_walls].double()
    left = torch.zeros(env.num_replicas, env.num_agents, dtype=torch.bool)
    for _ in range(60):
        before = env.positions.clone()
        obs, _, terminated, _, info = env.step(controller.act(env, obs, info))
        left |= terminated
        inside = env.active
        positions = env.positions.double()
        assert env.geometry.inside(env.positions)[inside].all()
        assert (distances_to_segments(positions, walls).amin(-1)[inside] >= env.params.agent_radius - 1e-5).all()
        gaps = torch.cdist(positions, positions) + torch.eye(env.num_agents, dtype=torch.float64) * 1e9
        both = inside.unsqueeze(-1) & inside.unsqueeze(-2)
        assert (gaps[both] >= 2 * env.params.agent_radius - 1e-5).all()
        moved = (env.positions - before).norm(dim=-1)
        assert (moved <= env.params.max_speed / env.params.decisions_per_second + 1e-4).all()
    assert left.any() or name == "corridor"  # someone found an exit (the greedy crowds of the corridor deadlock)


def test_paper_room_scenario_uses_the_env_size_and_one_door():
    scenario = build_scenario({"name": "paper_room"}, room={"width": 20.0, "length": 30.0, "door_width": 3.0})
    geometry = scenario.geometry(goal_depth=1.0)
    assert geometry.bounds == (0.0, 0.0, 20.0, 30.0) and geometry.num_walls == 5
    assert geometry.exit_goals.tolist() == [[10.0, 31.0]]


def test_corridor_groups_head_for_opposite_ends_and_four_exits_take_the_nearest():
    env = env_factory(ENV, {"name": "corridor"})(num_replicas=1, num_agents=10)
    env.reset(seed=0)
    assert env.exit_index[0].tolist() == [0] * 5 + [1] * 5
    assert (env.positions[0, :5, 0] <= 12.0).all() and (env.positions[0, 5:, 0] >= 28.0).all()
    # the groups' shares: 5:1 of 54 (the lanes test's counterflow) puts 45 at the west end walking east
    env = env_factory(
        {**ENV, "agent_radius": 0.2}, {"name": "corridor", "width": 3.0, "length": 38.0, "ratio": [5, 1]}
    )(num_replicas=1, num_agents=54)
    env.reset(seed=0)
    assert env.exit_index[0].tolist() == [0] * 45 + [1] * 9
    env = env_factory(ENV, {"name": "four_exits"})(num_replicas=1, num_agents=40)
    env.reset(seed=0)
    goals = env.geometry.exit_goals
    distance = torch.cdist(env.positions[0], goals)
    assert torch.equal(env.exit_index[0], distance.argmin(-1))
    assert len(set(env.exit_index[0].tolist())) == 4


def test_the_hall_has_its_exits_on_every_side_and_each_walker_takes_the_nearest():
    env = env_factory(ENV | {"agent_radius": 0.2}, {"name": "hall", "exits_per_side": 2})(
        num_replicas=1, num_agents=400
    )
    env.reset(seed=0)
    geometry = env.geometry
    assert geometry.num_exits == 8
    assert torch.equal(geometry.exit_spans.sqrt(), torch.full((8,), 3.0))
    normals = {tuple(round(v) for v in normal) for normal in geometry.exit_normals.tolist()}
    assert normals == {(0, -1), (1, 0), (0, 1), (-1, 0)}  # out of every side
    distance = torch.cdist(env.positions[0], geometry.exit_goals)
    assert torch.equal(env.exit_index[0], distance.argmin(-1))
    assert len(set(env.exit_index[0].tolist())) == 8


def test_closed_exits_become_walls():
    open_all = build_scenario({"name": "four_exits"}).geometry()
    two_closed = build_scenario({"name": "four_exits", "closed_exits": [2, 3]}).geometry()
    assert open_all.num_exits == 4 and two_closed.num_exits == 2
    assert (two_closed.exit_normals[:, 1] < 0).all()  # the bottom exits stay open
    top = torch.tensor([[1.5, 19.9], [28.5, 19.9]])
    assert two_closed.touches_walls(top, radius=0.4).all() and not open_all.touches_walls(top, radius=0.4).any()


def test_corner_route_aims_at_the_turn_then_at_the_exit():
    env = env_factory(ENV, {"name": "corner"})(num_replicas=1, num_agents=1)
    env.reset(options={"positions": [[(2.0, 1.0)]], "headings": [[0.0]], "speeds": [[0.0]]})
    torch.testing.assert_close(env.targets()[0, 0], torch.tensor([11.0, 1.0]))
    env.reset(options={"positions": [[(10.8, 1.2)]], "headings": [[0.0]], "speeds": [[0.0]]})
    torch.testing.assert_close(env.targets()[0, 0], torch.tensor([11.0, 12.0]))
    # the reference line: the door distance is the distance to the target
    obs, _ = env.reset(options={"positions": [[(2.0, 1.0)]], "headings": [[0.0]], "speeds": [[0.0]]})
    assert obs[0, 0, 2].item() == pytest.approx(9.0)


def test_custom_geometry_from_wkt_with_a_hole(tmp_path):
    path = tmp_path / "room.wkt"
    path.write_text("POLYGON ((0 0, 12 0, 12 10, 0 10, 0 0), (5 4, 7 4, 7 6, 5 6, 5 4))")
    scenario = build_scenario(
        {"name": "paper_room", "geometry": str(path), "exits": [[12, 4, 12, 6]], "spawn": [[0, 0, 4, 10]]}
    )
    assert scenario.name == "custom"
    geometry = scenario.geometry()
    assert geometry.num_walls == 5 + 4  # the outer ring, split by the exit, and the pillar
    assert geometry.exit_normals.tolist() == [[1.0, 0.0]]
    env = RoomEnv(geometry, num_replicas=2, num_agents=10)
    env.reset(seed=0)
    assert (env.positions[..., 0] <= 4.0).all()
    assert not env.geometry.inside(torch.tensor([[6.0, 5.0]])).any()  # the pillar is not walkable


BAD = [
    ({"name": "mall"}, "scenario.name='mall' is invalid: must be one of paper_room"),
    ({"name": "bottleneck", "opening": -1.0}, "scenario.opening=-1.0 is invalid"),
    ({"name": "bottleneck", "wdith": 2.0}, "scenario.wdith is not a setting of scenario 'bottleneck'"),
    ({"name": "four_exits", "closed_exits": [0, 1, 2, 3]}, "at least one exit must stay open"),
    ({"name": "four_exits", "closed_exits": [7]}, "scenario.closed_exits holds 7"),
    ({"name": "corridor", "exits": [[0, 0, 1, 1]]}, "scenario.exits is set without scenario.geometry"),
    ({"name": "hall", "exits_per_side": 0}, "scenario.exits_per_side=0 is invalid: must be an integer in [1, 100]"),
    ({"name": "hall", "exits_per_side": 40}, "scenario.exit_width=3.0 is invalid: 40 exits of it must take less"),
    ({"name": "hall", "spawn_margin": 60.0}, "scenario.spawn_margin=60.0 is invalid: must be in [0, 50) m"),
    ({"name": "corridor", "ratio": [1, -1]}, "scenario.ratio=[1, -1] is invalid: must be two shares in [0, 1e+06]"),
    ({"name": "corridor", "ratio": [1e308, 1e308]}, "scenario.ratio=[1e+308, 1e+308] is invalid"),
    ({"name": "corridor", "ratio": [0, 0]}, "scenario.ratio=[0, 0] is invalid"),
    ({"name": "corridor", "ratio": [3, 3, 3]}, "scenario.ratio=[3, 3, 3] is invalid"),
]


@pytest.mark.parametrize(("config", "message"), BAD)
def test_bad_scenarios_give_one_line_errors(config, message):
    with pytest.raises(ValueError, match=None) as err:
        build_scenario(config)
    assert message in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize(
    ("wkt", "exits", "spawn", "message"),
    [
        ("POLYGON ((0 0, 10 10, 10 0, 0 10, 0 0))", [[10, 0, 10, 10]], None, "Self-intersection"),
        ("POLYGON ((0 0, 10 0, 10 10, 0 10, 0 0))", [[5, 5, 6, 5]], None, "must be a segment on the boundary"),
        ("POLYGON ((0 0, 10 0, 10 10, 0 10, 0 0))", [[10, 2, 10, 4]], [[8, 8, 12, 12]], "must lie inside the walkable"),
        ("POINT (1 2)", [[10, 2, 10, 4]], None, "must hold exactly one POLYGON"),
        ("POLYGON ((0 0, 10 0", [[10, 2, 10, 4]], None, "not WKT"),
        ("POLYGON ((0 0, 10 0, 10 10, 0 10, 0 0))", [[10, 2, 10]], None, "must be 4 finite numbers"),
    ],
)
def test_bad_custom_geometry_gives_one_line_errors(tmp_path, wkt, exits, spawn, message):
    path = tmp_path / "room.wkt"
    path.write_text(wkt)
    with pytest.raises(ValueError) as err:
        build_scenario({"name": "custom", "geometry": str(path), "exits": exits, "spawn": spawn})
    assert message in str(err.value) and "\n" not in str(err.value), str(err.value)


def test_missing_wkt_file_names_the_path(tmp_path):
    with pytest.raises(ValueError, match="cannot read it"):
        build_scenario({"name": "custom", "geometry": str(tmp_path / "nope.wkt"), "exits": [[0, 0, 1, 0]]})


def test_more_agents_than_fit_in_the_spawn_area_is_refused_before_any_room_is_built():
    factory = env_factory(ENV, {"name": "corner"})
    with pytest.raises(ValueError, match=r"num_agents=20 is invalid: 20 bodies .* cannot be placed in spawn area 0"):
        factory(num_replicas=1, num_agents=20)


def test_spawn_areas_are_split_by_weight_and_checked():
    room = box(0, 0, 20, 10)
    scenario = Scenario(
        "two",
        room,
        (build_scenario({"name": "paper_room"}, room={"width": 20.0, "length": 10.0}).exits[0],),
        (Spawn(box(0, 0, 5, 10), weight=3.0), Spawn(box(15, 0, 20, 10), weight=1.0)),
    )
    env = RoomEnv(scenario.geometry(), num_replicas=1, num_agents=8)
    env.reset(seed=1)
    assert env.spawn_counts == (6, 2)
    assert (env.positions[0, :6, 0] <= 5).all() and (env.positions[0, 6:, 0] >= 15).all()
    assert math.isclose(scenario.geometry().spawns[0].area, 50.0)


@pytest.mark.parametrize("name", BUILT_IN)
def test_the_analysis_view_is_the_simulated_geometry(name):
    """A scenario builds the simulation's geometry and the analysis' plain view of it: the same walls, exits, normals
    and bounds (the paper's room in closed form, a :class:`RoomGeometry`)."""
    scenario = build_scenario({"name": name}, room={"width": 20.0, "length": 30.0, "door_width": 3.0})
    geometry = scenario.geometry()
    view = scenario.analysis_geometry(geometry)
    assert isinstance(view, AreaGeometry) and isinstance(view, RoomGeometry) == (name == "paper_room")
    assert view.bounds == geometry.bounds
    walls = geometry.walls[: geometry.num_walls].double().numpy()
    assert sorted(map(repr, view.walls.tolist())) == sorted(map(repr, walls.tolist()))  # the paper's room: its order
    assert np.array_equal(np.sort(view.exits, axis=1), np.sort(geometry.exits.double().numpy(), axis=1))
    assert np.array_equal(view.exit_normals, geometry.exit_normals.double().numpy())
    assert view.contains(geometry.exit_goals.double().numpy() - 0.1 * view.exit_normals).all()
    assert not view.contains(geometry.exit_goals.double().numpy() + 0.1 * view.exit_normals).any()


def test_the_paper_room_view_is_the_general_view_in_closed_form():
    """The paper's room answers what the general view of its polygon answers (:class:`RoomGeometry` only writes its
    door apron and its door centre in closed form)."""
    scenario = build_scenario({"name": "paper_room"}, room={"width": 20.0, "length": 30.0, "door_width": 3.0})
    assert isinstance(scenario, PaperRoom) and (scenario.width, scenario.length, scenario.door_width) == (20, 30, 3)
    room, general = scenario.analysis_geometry(), Scenario.analysis_geometry(scenario)
    assert type(general) is AreaGeometry
    assert room.bounds == general.bounds and (room.width, room.length) == (general.width, general.length)
    assert np.array_equal(room.door_center, general.door_center)
    assert np.array_equal(room.door_normal, general.door_normal)
    points = np.random.default_rng(0).uniform([-1.0, -1.0], [21.0, 33.0], (2000, 2))
    assert np.array_equal(room.contains(points), general.contains(points))
    assert room.to_wkt(exit_depth=0.0) != general.to_wkt(exit_depth=0.0)  # the same polygon, written otherwise
    assert AreaGeometry(room.to_wkt(exit_depth=0.0), room.walls, room.exits, room.exit_normals).bounds == room.bounds


def test_nothing_outside_the_scenarios_compares_a_scenario_name():
    """The objects are asked (``Scenario.analysis_geometry``), not their names: no comparison with a built-in
    scenario's name anywhere in pedrl but where ``build_scenario`` reads a config."""
    package = Path(__file__).resolve().parents[2] / "pedrl"
    found = []
    for path in sorted(package.rglob("*.py")):
        if path == package / "scenarios" / "builders.py":  # where build_scenario reads a config
            continue
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Compare):
                names = [part for part in (node.left, *node.comparators) if isinstance(part, ast.Constant)]
                found += [f"{path.name}:{node.lineno}" for part in names if part.value in SCENARIOS]
    assert not found, f"comparisons with a scenario's name: {found}"


def test_only_its_own_exit_reaches_the_goal():
    """The corridor's groups head for opposite ends. A walker stepping back out of the end it started at leaves the
    room (terminated) but reaches no goal: no goal reward, not counted as reached. The other group's walker leaving
    by that same end reaches its goal (the control), and in four exits (no assigned exit) any exit is a goal."""
    env = env_factory({**ENV, "max_speed": 1.0}, {"name": "corridor", "length": 20.0, "spawn_length": 5.0})(
        num_replicas=1, num_agents=2
    )
    assert env.exit_index.shape == (1, 2)
    # agent 0's group heads for exit 0 (x = 20), agent 1's for exit 1 (x = 0)
    env.reset(
        options={"positions": [[(0.5, 2.5), (3.0, 1.0)]], "headings": [[math.pi, math.pi]], "speeds": [[1.0, 1.0]]}
    )
    assert env.exit_index.tolist() == [[0, 1]] and env.geometry.exit_goals[0, 0] >= 20.0
    _, reward, terminated, _, info = env.step(torch.full((1, 2), NOOP_ACTION))
    assert terminated[0, 0] and not info["reached"][0, 0]  # out through the wrong end: no goal
    assert reward[0, 0] < env.params.rewards.goal / 2
    env.reset(options={"positions": [[(17.0, 1.0), (0.5, 2.5)]], "headings": [[0.0, math.pi]], "speeds": [[1.0, 1.0]]})
    _, reward, terminated, _, info = env.step(torch.full((1, 2), NOOP_ACTION))
    assert terminated[0, 1] and info["reached"][0, 1] and reward[0, 1] >= env.params.rewards.goal / 2  # its own end

    rooms = env_factory(ENV, {"name": "four_exits"})(num_replicas=1, num_agents=1)
    rooms.reset(options={"positions": [[(2.0, 0.6)]], "headings": [[-math.pi / 2]], "speeds": [[1.0]]})
    _, _, terminated, _, info = rooms.step(torch.full((1, 1), NOOP_ACTION))
    assert not rooms.spawns.checks_exits and terminated[0, 0] == info["reached"][0, 0]

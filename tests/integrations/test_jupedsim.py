"""JuPedSim on pedrl scenarios: RiMEA 1's travel time, agents stay in the area, waypoints, the room's scenes, errors."""

import math
import sys
from dataclasses import replace

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString, box

pytest.importorskip("jupedsim")

from pedrl.integrations.jupedsim import (  # noqa: E402
    EXIT_APRON_DEPTH,
    GCFM_WALL_REACH,
    INSTALL_HINT,
    MODELS,
    JuPedSimModel,
    apron_depth,
    check_model,
    model_from_settings,
    room_scene,
    simulate,
    walkable_with_aprons,
)
from pedrl.integrations.jupedsim_data import MIN_DT  # noqa: E402
from pedrl.scenarios import Scenario, Spawn, build_scenario  # noqa: E402

CORRIDOR = Scenario(
    "rimea_1", box(0.0, 0.0, 40.0, 2.0), (LineString([(40.0, 0.0), (40.0, 2.0)]),), (Spawn(box(0, 0, 2, 2)),)
)
"""RiMEA test 1: a 40 m x 2 m corridor, its exit the far end x = 40."""


def one_agent(scenario=CORRIDOR, **overrides):
    arguments = {
        "positions": [[0.5, 1.0]],
        "exit_index": [0],
        "waypoints": [[]],
        "model": JuPedSimModel(desired_speed=1.33),
        "max_time": 60.0,
        "frame_rate": 1.0,
    }
    return simulate(scenario, **(arguments | overrides))


@pytest.mark.parametrize("model", MODELS)
def test_one_agent_walks_the_rimea_1_corridor_in_about_30_s(model):
    run = one_agent(model=JuPedSimModel(model=model, desired_speed=1.33))
    # 39.5 m at 1.33 m/s: 29.7 s; the social force model first accelerates (reaction time 0.5 s), and so does the
    # generalized centrifugal force model (tau 0.5 s), whose 1 m exit apron used to slow it at the end (33.6 s)
    assert 29.0 <= run.exit_time[0] <= 31.0
    assert run.left_at[0] == math.ceil(run.exit_time[0] - 1e-9)
    assert run.positions.shape == (run.left_at[0] + 1, 1, 2)  # stops once everyone left
    assert run.active[: run.left_at[0], 0].all() and not run.active[run.left_at[0], 0]
    assert run.positions[-1, 0, 0] >= 40.0  # the point where it left: past the exit line, in the apron
    assert np.allclose(run.positions[0], [[0.5, 1.0]])
    speeds = np.linalg.norm(run.velocities()[:, 0], axis=-1)
    assert speeds[0] == 0.0 and speeds[10:-1] == pytest.approx(1.33, abs=0.01)
    assert speeds[-1] == pytest.approx(1.33, abs=0.05)  # over the part of the last interval before it left


def test_the_generalized_centrifugal_force_model_gets_jupedsims_defaults_and_the_bodys_ellipse():
    """Every parameter pedrl passes the model and its agents: JuPedSim's own defaults (checked against JuPedSim's
    classes, so that a change of theirs shows), the ellipse scaled to the body radius, JuPedSim's time step."""
    import jupedsim as jps

    from pedrl.integrations.jupedsim import _agent_parameters, _operational_model

    gcfm = JuPedSimModel(model="generalized_centrifugal_force")
    assert (gcfm.desired_speed, gcfm.dt) == (1.2, 0.01)
    forces = _operational_model(jps, gcfm)
    expected_forces = {
        "strength_neighbor_repulsion": 0.3,
        "strength_geometry_repulsion": 0.2,
        "max_neighbor_interaction_distance": 2.0,
        "max_geometry_interaction_distance": GCFM_WALL_REACH,
        "max_neighbor_interpolation_distance": 0.1,
        "max_geometry_interpolation_distance": 0.1,
        "max_neighbor_repulsion_force": 9.0,
        "max_geometry_repulsion_force": 3.0,
    }
    assert {key: getattr(forces, key) for key in expected_forces} == expected_forces
    assert forces == jps.GeneralizedCentrifugalForceModel()
    defaults = jps.GeneralizedCentrifugalForceModelAgentParameters()
    fields = ("speed", "orientation", "mass", "tau", "desired_speed", "a_v", "a_min", "b_min", "b_max")
    for radius, ellipse in ((0.2, (0.2, 0.2, 0.4)), (0.4, (0.4, 0.4, 0.8))):
        agent = _agent_parameters(jps, replace(gcfm, radius=radius), np.array([1.0, 2.0]), 3, 4)
        passed = {key: getattr(agent, key) for key in fields}
        assert passed == {
            "speed": 0.0, "orientation": (1.0, 0.0), "mass": 1.0, "tau": 0.5, "desired_speed": 1.2, "a_v": 1.0,
            "a_min": ellipse[0], "b_min": ellipse[1], "b_max": ellipse[2],
        }  # fmt: skip
        assert (agent.position, agent.journey_id, agent.stage_id) == ((1.0, 2.0), 3, 4)
    assert {key: getattr(defaults, key) for key in fields} == {
        key: getattr(_agent_parameters(jps, gcfm, np.array([1.0, 2.0]), 3, 4), key) for key in fields
    }  # at 0.2 m, JuPedSim's defaults exactly


def test_the_generalized_centrifugal_force_models_exit_aprons_are_out_of_its_walls_reach():
    # its walls repel from GCFM_WALL_REACH beyond the ellipse, whose semi-axis along the walk is radius + 1 s x v0
    assert apron_depth(JuPedSimModel(model="generalized_centrifugal_force", radius=0.4)) == pytest.approx(3.6)
    assert apron_depth(JuPedSimModel(model="generalized_centrifugal_force", radius=0.2, desired_speed=1.34)) == (
        pytest.approx(3.54)
    )
    assert all(apron_depth(JuPedSimModel(model=name)) == EXIT_APRON_DEPTH for name in MODELS[:4] + MODELS[5:])
    # one body of 0.4 m walks 9 m to a 3 m door at its desired speed: behind a 1 m apron the apron's far end held
    # it 0.2 m short of the exit line, where it crept over at 0.01 m/s (36.4 s)
    room = build_scenario(None, room={"width": 10.0, "length": 10.0, "door_width": 3.0})
    model = JuPedSimModel(model="generalized_centrifugal_force", radius=0.4)
    run = simulate(room, positions=[[5.0, 1.0]], exit_index=[0], waypoints=[[]], model=model, max_time=60.0,
                   frame_rate=1.0)  # fmt: skip
    assert 7.5 <= run.exit_time[0] <= 9.0


def test_a_small_generalized_centrifugal_force_crowd_walks_out():
    # 20 bodies of 0.4 m in a 10 m room with a 3 m door: everyone out in about 30 s (3 of them behind a 1 m apron)
    room = build_scenario(None, room={"width": 10.0, "length": 10.0, "door_width": 3.0})
    positions = [[1.5 + 1.75 * i, 1.5 + 1.75 * j] for i in range(5) for j in range(4)]
    model = JuPedSimModel(model="generalized_centrifugal_force", radius=0.4)
    run = simulate(room, positions=positions, exit_index=[0] * 20, waypoints=[[]] * 20, model=model, max_time=60.0,
                   frame_rate=1.0)  # fmt: skip
    assert run.left.all() and np.nanmax(run.exit_time) <= 45.0


def test_the_anticipation_model_repeats_a_run():
    # its random seed is fixed, so two runs of a crowd give the same trajectories
    model = JuPedSimModel(model="anticipation_velocity")
    positions = [[0.5 + 0.6 * i, 0.5 + 0.5 * (i % 3)] for i in range(8)]
    runs = [one_agent(positions=positions, exit_index=[0] * 8, waypoints=[[]] * 8, model=model) for _ in range(2)]
    assert np.array_equal(runs[0].positions, runs[1].positions)


@pytest.mark.parametrize(
    ("model", "message"),
    [
        (
            JuPedSimModel(model="generalized_centrifugal_force", radius=1.9),
            "jupedsim.model=generalized_centrifugal_force refuses its parameters: Model constraint violation: AMin 1.9",
        ),
    ],
)
def test_jupedsim_checks_a_models_parameters_before_a_run_in_one_line(model, message):
    with pytest.raises(ValueError) as error:
        check_model(model)
    assert message in str(error.value) and "\n" not in str(error.value)
    for name in MODELS:
        check_model(JuPedSimModel(model=name))  # every model's defaults pass


def test_a_run_stops_at_max_time_with_everyone_still_inside():
    run = one_agent(max_time=10.0, frame_rate=2.0)
    assert run.positions.shape == (21, 1, 2) and run.active.all()
    assert run.left_at.tolist() == [-1] and np.isnan(run.exit_time).all()
    assert run.positions[-1, 0, 0] == pytest.approx(0.5 + 1.33 * 10.0, abs=0.02)


def test_nobody_is_ever_outside_the_walkable_area():
    scenario = build_scenario({"name": "four_exits", "width": 12.0, "length": 8.0})
    room = scenario.room(num_agents=60, agent_radius=0.2, max_decisions=60)
    room.reset(seed=3)
    scene = room_scene(room)
    run = simulate(
        scenario,
        positions=scene.positions,
        exit_index=scene.exit_index,
        waypoints=scene.waypoints,
        model=JuPedSimModel(radius=0.2),
        max_time=60.0,
        frame_rate=10.0,
    )
    assert run.left.all()  # everyone out through one of the four exits
    inside = shapely.contains_xy(scenario.walkable.buffer(1e-9), run.positions[..., 0], run.positions[..., 1])
    assert inside[run.active].all()
    area, aprons = walkable_with_aprons(scenario)
    for agent in range(run.num_agents):  # each left where its centre crossed its own exit
        point = run.positions[-1, agent]
        assert aprons[scene.exit_index[agent]].buffer(1e-9).covers(shapely.Point(point))
    assert area.area == pytest.approx(scenario.walkable.area + 4 * 1.0 * EXIT_APRON_DEPTH)  # four 1 m exits


def test_agents_routed_through_a_waypoint_pass_near_it():
    detour = replace(build_scenario({"name": "corner"}), waypoint_radius=0.3)  # RiMEA 6's corridor turning left
    starts = [[1.0, 0.5], [3.0, 0.5], [5.0, 0.5]]
    waypoint = (8.0, 0.4)  # off the agents' shortest way, from y = 0.5 to the inner corner (10, 2)
    kwargs = {"positions": starts, "exit_index": [0, 0, 0], "max_time": 60.0, "frame_rate": 10.0}
    routed = simulate(detour, waypoints=[[waypoint]] * 3, **kwargs)
    direct = simulate(detour, waypoints=[[]] * 3, **kwargs)
    for run in (routed, direct):
        assert run.left.all() and (run.positions[-1, :, 1] >= 12.0).all()  # out at the top of the second leg
    nearest = np.linalg.norm(routed.positions - np.array(waypoint), axis=-1).min(axis=0)  # (N,) m
    assert (nearest < 0.3 + 0.2).all()  # within the radius, give or take one frame's walk
    assert (np.linalg.norm(direct.positions - np.array(waypoint), axis=-1).min(axis=0) > 0.8).all()


def test_the_room_scene_is_the_rooms_start():
    scenario = build_scenario({"name": "bottleneck"})
    room = scenario.room(num_agents=6, agent_radius=0.2, num_replicas=2, max_decisions=10)
    room.reset(seed=0)
    scene = room_scene(room, replica=1)
    assert np.array_equal(scene.positions, room.positions[1].double().numpy())
    assert scene.exit_index.tolist() == [0] * 6
    assert all(len(route) == 2 for route in scene.waypoints)  # the bottleneck's two waypoints, none reached yet
    run = simulate(
        scenario,
        positions=scene.positions,
        exit_index=scene.exit_index,
        waypoints=scene.waypoints,
        max_time=40.0,
        frame_rate=1.0,
    )
    assert run.left.all()


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"positions": [[-1.0, 1.0]]}, "positions[0]=[-1.0, 1.0] is invalid: it must lie inside the walkable area"),
        ({"positions": [[0.5, 0.1]]}, "positions[0]=[0.5, 0.1] is invalid: JuPedSim refuses it"),  # on the wall
        ({"positions": [[1.0, 2.0, 3.0]]}, "positions is invalid: must be finite coordinates"),
        ({"exit_index": [1]}, "exit_index holds 1: every index must be in [0, 1)"),
        ({"exit_index": [0.0]}, "exit_index is invalid"),
        ({"waypoints": []}, "waypoints holds 0 routes: must hold one route (a list of points) per agent, 1"),
        ({"waypoints": None}, "waypoints holds None"),
        ({"max_time": 0.5}, "max_time=0.5 is invalid: shorter than one frame"),
        ({"waypoints": [[(50.0, 1.0)]]}, "waypoints[0][0]=[50.0, 1.0] is invalid"),
        ({"max_time": 0.0}, "max_time=0.0 is invalid"),
        ({"frame_rate": 3.0}, "frame_rate=3.0 is invalid: 1 / (frame_rate * dt) must be a whole number"),
        ({"model": "jupedsim"}, "model='jupedsim' is invalid: must be a JuPedSimModel"),
    ],
)
def test_bad_input_fails_with_one_line(overrides, message):
    with pytest.raises(ValueError) as error:
        one_agent(**overrides)
    assert message in str(error.value) and "\n" not in str(error.value)


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        (
            {"model": "magic"},
            "jupedsim.model='magic' is invalid: must be one of collision_free_speed, collision_free_speed_v2",
        ),
        ({"desired_speed": 0}, "jupedsim.desired_speed=0 is invalid"),
        ({"dt": -0.01}, "jupedsim.dt=-0.01 is invalid"),
        (
            {"dt": 1e-9},
            "jupedsim.dt=1e-09 is invalid: must be >= 0.001 s (JuPedSim's default 0.01 s; 1e-09 s would"
            " take 1,000,000,000 JuPedSim steps per simulated second, at most 1,000)",
        ),
        ({"dt": 0.0009}, "jupedsim.dt=0.0009 is invalid: must be >= 0.001 s"),
        ({"speed": 1.0}, "jupedsim.speed is not a setting of the JuPedSim model"),
    ],
)
def test_bad_model_settings_fail_with_one_line(settings, message):
    with pytest.raises(ValueError) as error:
        model_from_settings(settings)
    assert message in str(error.value) and "\n" not in str(error.value)
    assert model_from_settings({"desired_speed": 1.34}) == JuPedSimModel(desired_speed=1.34)
    assert model_from_settings({"dt": MIN_DT}).dt == MIN_DT  # the control: the bound itself is taken


def test_without_jupedsim_the_error_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "jupedsim", None)  # import jupedsim now fails
    with pytest.raises(ModuleNotFoundError) as error:
        one_agent()
    assert str(error.value) == INSTALL_HINT == "jupedsim is not installed: pip install 'pedrl[jupedsim]'"


def test_a_run_jupedsim_stops_is_one_line_naming_the_model_and_the_time(monkeypatch):
    import jupedsim

    from pedrl.integrations.jupedsim import JuPedSimRunError

    def broken(self):
        raise RuntimeError("Point (19.0, -0.0003) is outside of accessible area\nmore")

    monkeypatch.setattr(jupedsim.Simulation, "iterate", broken)
    with pytest.raises(JuPedSimRunError) as error:
        one_agent(model=JuPedSimModel(model="warp_driver"))
    message = str(error.value)
    assert message.startswith("JuPedSim's warp_driver model stopped after 0.00 s in scenario 'rimea_1': Point (19.0")
    assert "\n" not in message

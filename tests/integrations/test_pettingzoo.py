"""PedestrianParallelEnv: PettingZoo's API and seed tests, equality with RoomEnv, ends of trials, spaces, errors."""

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

pettingzoo = pytest.importorskip("pettingzoo")
from pettingzoo.test import parallel_api_test, parallel_seed_test  # noqa: E402

from pedrl.integrations.pettingzoo import PedestrianParallelEnv, parallel_env  # noqa: E402
from pedrl.scenarios import paper_room  # noqa: E402
from pedrl.sim import NOOP_ACTION  # noqa: E402

SIZES = {"width": 6.0, "length": 8.0, "door_width": 1.5}
SMALL = {**SIZES, "num_agents": 5, "max_decisions": 30}
"""A small room that random walkers can leave within the trial."""
UP = math.pi / 2
PLACED = [[3.0, 7.4], [1.0, 1.0], [5.0, 1.0], [1.0, 3.0], [5.0, 3.0]]
"""Agent 0 just before the door (the room's length is 8 m), the others at the far end."""
ROOT = Path(__file__).resolve().parents[2]


def _agents(count: int) -> list[str]:
    return [f"pedestrian_{index}" for index in range(count)]


def _rollout_actions(env: PedestrianParallelEnv, rng: np.random.Generator, *, skip: str = "") -> dict[str, int]:
    """Random actions for the agents still in the trial, none for ``skip`` (it takes the no-op)."""
    return {agent: int(rng.integers(env.env.num_actions)) for agent in env.agents if agent != skip}


# ---------------------------------------------------------------- PettingZoo's own tests


@pytest.mark.filterwarnings("ignore:PedestrianParallelEnv.reset ignores the options:UserWarning")
@pytest.mark.parametrize(
    ("room", "num_cycles"),
    [(SMALL, 40), ({"num_agents": 3, "max_decisions": 200}, 60)],
    ids=["small-room", "paper-room"],
)
def test_parallel_api_test_passes(room, num_cycles):
    env = parallel_env(**room)
    parallel_api_test(env, num_cycles=num_cycles)
    assert env.possible_agents == _agents(room["num_agents"])
    assert env.action_space("pedestrian_0").n == 81


def test_parallel_seed_test_passes():
    parallel_seed_test(lambda: parallel_env(**SMALL), num_cycles=30)


# ---------------------------------------------------------------- the adapter adds nothing


def test_seeded_rollouts_repeat_and_equal_room_env_stepped_directly():
    """Same seed and actions: the same observations twice, and those of RoomEnv for the same actions.

    ``pedestrian_0`` starts at the door heading to it and never gets an action: the adapter gives it the no-op,
    which RoomEnv is given explicitly, and it leaves; the others walk at random until the clock stops them.
    """
    first, second = parallel_env(**SMALL), parallel_env(**SMALL)
    room = paper_room(**SIZES).room(num_replicas=1, num_agents=5, max_decisions=30)
    options = {"positions": PLACED, "headings": [UP, 0.0, 1.0, 2.0, 3.0], "speeds": [room.params.max_speed] + [0.0] * 4}
    obs_first, _ = first.reset(seed=7, options=options)
    obs_second, _ = second.reset(seed=7, options=options)
    room_obs, _ = room.reset(seed=7, options={key: [value] for key, value in options.items()})
    for agent, index in zip(first.possible_agents, range(room.num_agents), strict=True):
        np.testing.assert_array_equal(obs_first[agent], room_obs[0, index].numpy())
        np.testing.assert_array_equal(obs_first[agent], obs_second[agent])
    rng = np.random.default_rng(0)
    steps, ended = 0, {"terminated": 0, "truncated": 0}
    while first.agents:
        active_before = list(first.agents)
        actions = _rollout_actions(first, rng, skip="pedestrian_0")
        obs_first, rewards, terminations, truncations, infos = first.step(actions)
        obs_second, *_ = second.step(dict(actions))
        room_actions = torch.full((1, room.num_agents), NOOP_ACTION, dtype=torch.int64)
        for agent, action in actions.items():
            room_actions[0, first.possible_agents.index(agent)] = action
        room_obs, room_reward, room_terminated, room_truncated, room_info = room.step(room_actions)
        steps += 1
        ended["terminated"] += sum(terminations.values())
        ended["truncated"] += sum(truncations.values())

        assert set(obs_first) == set(rewards) == set(terminations) == set(truncations) == set(infos)
        assert set(obs_first) == set(active_before)
        for agent in active_before:
            index = first.possible_agents.index(agent)
            assert obs_first[agent].dtype == np.float32
            assert obs_first[agent].shape == (room.num_features,)
            np.testing.assert_array_equal(obs_first[agent], obs_second[agent])
            np.testing.assert_array_equal(obs_first[agent], room_obs[0, index].numpy())
            assert type(rewards[agent]) is float and rewards[agent] == float(room_reward[0, index])
            assert terminations[agent] is bool(room_terminated[0, index])
            assert truncations[agent] is bool(room_truncated[0, index])
            velocity = infos[agent].pop("neighbour_velocity")  # an ONNX model's third input, where it reads one
            np.testing.assert_array_equal(velocity, room_info["neighbour_velocity"][0, index].numpy())
            assert velocity.dtype == np.float32 and velocity.shape == (room.params.num_neighbours, 2)
            assert infos[agent] == {
                "crashed_agent": bool(room_info["crashed_agent"][0, index]),
                "crashed_wall": bool(room_info["crashed_wall"][0, index]),
                "reached": bool(room_info["reached"][0, index]),
                "speed": float(room_info["speed"][0, index]),
                "num_sensed": int(room_info["num_sensed"][0, index]),  # an ONNX model's second input
            }
        active = room.active[0].tolist()
        assert first.agents == [agent for agent, alive in zip(first.possible_agents, active, strict=True) if alive]
        assert second.agents == first.agents
    assert steps <= SMALL["max_decisions"]
    assert ended["terminated"] >= 1 and ended["terminated"] + ended["truncated"] == SMALL["num_agents"]
    np.testing.assert_array_equal(room.positions.numpy(), first.env.positions.numpy())


# ---------------------------------------------------------------- ends of trials


def _placed(**room) -> PedestrianParallelEnv:
    """Agent 0 just before the door, heading to it at top speed; the others standing still at the far end."""
    env = parallel_env(**{**SMALL, "reward_progress": 0.0, **room})
    env.reset(
        seed=0,
        options={
            "positions": PLACED,
            "headings": [UP, 0.0, 0.0, 0.0, 0.0],
            "speeds": [env.env.params.max_speed, 0.0, 0.0, 0.0, 0.0],
        },
    )
    return env


def test_agent_at_the_door_with_the_noop_terminates_and_leaves_agents():
    env = _placed()
    obs, rewards, terminations, truncations, infos = env.step({})  # everyone takes the no-op
    assert terminations == {"pedestrian_0": True, **dict.fromkeys(_agents(5)[1:], False)}
    assert not any(truncations.values())
    assert rewards["pedestrian_0"] == env.env.params.rewards.goal
    assert infos["pedestrian_0"]["reached"]
    np.testing.assert_array_equal(obs["pedestrian_0"], 0.0)  # RoomEnv: reached agents observe 0
    assert env.agents == _agents(5)[1:]
    assert env.state()[:2].tolist() == [0.0, 0.0]  # gone from the state too
    # later steps: it is no longer reported, and an action for it is ignored
    obs, rewards, *_ = env.step({"pedestrian_0": 0, "pedestrian_1": NOOP_ACTION})
    assert set(obs) == set(rewards) == set(_agents(5)[1:])


def test_truncation_at_max_decisions_removes_everyone():
    env = _placed(max_decisions=3)
    env.step({})  # agent 0 leaves through the door
    env.step({})
    assert env.agents == _agents(5)[1:]
    _, _, terminations, truncations, _ = env.step({})
    assert truncations == dict.fromkeys(_agents(5)[1:], True)
    assert terminations == dict.fromkeys(_agents(5)[1:], False)
    assert env.agents == []
    assert env.step({}) == ({}, {}, {}, {}, {})  # nothing left: the room is not stepped
    assert env.env.decision == 3
    obs, _ = env.reset(seed=1)  # a new trial brings everyone back
    assert env.agents == _agents(5) and set(obs) == set(_agents(5))


# ---------------------------------------------------------------- spaces


def test_observations_and_states_stay_in_their_spaces_in_a_random_crowd():
    env = parallel_env(num_agents=12, width=6.0, length=8.0, door_width=1.5, max_decisions=25, goal_depth=1.0)
    rng = np.random.default_rng(3)
    obs, _ = env.reset(seed=3)
    for _ in range(25):
        for agent, features in obs.items():
            assert env.observation_space(agent).contains(features), (agent, features)
        assert env.state_space.contains(env.state())
        if not env.agents:
            break
        obs, *_ = env.step(_rollout_actions(env, rng))
    space = env.observation_space("pedestrian_0")
    names = env.env.feature_names
    assert space.high[names.index("speed")] == np.float32(env.env.params.max_speed)
    assert space.low[names.index("velocity_angle")] == np.float32(-math.pi)


def test_head_on_neighbours_at_top_speed_are_inside_the_bounds():
    """The relative speed's extreme, -2 max_speed, lies inside the space."""
    env = parallel_env(**{**SMALL, "num_agents": 2})
    speed = env.env.params.max_speed
    head_on = {"positions": [[2.0, 4.0], [4.0, 4.0]], "headings": [0.0, math.pi], "speeds": [speed] * 2}
    obs, _ = env.reset(options=head_on)
    rel_speed = env.env.feature_names.index("neighbour0_rel_speed")
    assert obs["pedestrian_0"][rel_speed] == pytest.approx(-2.0 * speed)
    assert env.observation_space("pedestrian_0").contains(obs["pedestrian_0"])
    assert env.state_space.contains(env.state())


def test_spaces_are_the_same_objects_per_agent_and_distinct_between_agents():
    env = parallel_env(**SMALL)
    assert env.observation_space("pedestrian_2") is env.observation_space("pedestrian_2")
    assert env.action_space("pedestrian_2") is env.action_space("pedestrian_2")
    assert env.action_space("pedestrian_2") is not env.action_space("pedestrian_3")
    assert env.state_space.shape == (4 * SMALL["num_agents"],)


# ---------------------------------------------------------------- errors


def test_more_than_one_replica_is_a_value_error():
    with pytest.raises(ValueError, match=r"^env\.num_replicas=2 is invalid"):
        PedestrianParallelEnv(paper_room(**SIZES).room(num_replicas=2, num_agents=5, max_decisions=30))
    with pytest.raises(ValueError, match=r"num_replicas=2"):
        parallel_env(num_replicas=2, **SMALL)
    with pytest.raises(ValueError, match=r"render_mode='human'"):
        parallel_env(render_mode="human", **SMALL)


def test_bad_actions_and_steps_before_reset_are_refused():
    env = parallel_env(**SMALL)
    with pytest.raises(RuntimeError, match=r"before reset"):
        env.step({})
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"actions key 'pedestrian_9' is invalid"):
        env.step({"pedestrian_9": 0})
    with pytest.raises(ValueError, match=r"actions\['pedestrian_0'\]=81 is invalid"):
        env.step({"pedestrian_0": 81})
    with pytest.raises(ValueError, match=r"is invalid: must be an integer"):
        env.step({"pedestrian_0": 1.5})
    for flag in (True, False, np.True_, torch.tensor(True)):  # no action: True was taken as action 1
        with pytest.raises(ValueError, match=r"actions\['pedestrian_0'\]=.* is invalid: must be an integer in \[0, "):
            env.step({"pedestrian_0": flag})
    env.step({"pedestrian_0": np.int64(1), "pedestrian_1": torch.tensor(2)})  # the control: integers of any kind
    with pytest.warns(UserWarning, match=r"ignores the options 'replicas'"):
        env.reset(options={"replicas": [True]})


def test_import_pedrl_needs_no_pettingzoo_and_the_adapter_says_how_to_install_it():
    code = (
        "import sys\n"
        "sys.modules['pettingzoo'] = None\n"
        "import pedrl, pedrl.sim, pedrl.integrations\n"
        "try:\n"
        "    import pedrl.integrations.pettingzoo\n"
        "except ImportError as error:\n"
        "    print(error)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    assert done.stdout.count("\n") == 1
    assert "pip install pedrl[pettingzoo]" in done.stdout


@pytest.mark.parametrize("scenario", ["corridor", "corner", "four_exits", "bottleneck"])
def test_parallel_api_in_every_scenario(scenario):
    """The adapter drives any scenario's room (one replica), under PettingZoo's own API test."""
    agents = 7 if scenario == "corner" else 10
    env = parallel_env(scenario=scenario, num_agents=agents, max_decisions=20)
    assert env.env.geometry.name == scenario
    parallel_api_test(env, num_cycles=25)


# ---------------------------------------------------------------- PettingZoo's registry


@pytest.mark.filterwarnings("ignore:PedestrianParallelEnv.reset ignores the options:UserWarning")
def test_importing_the_adapter_registers_the_room_in_pettingzoos_registry():
    if not hasattr(pettingzoo, "register"):
        pytest.skip("a PettingZoo without a registry (before 1.27)")
    from pedrl.integrations.pettingzoo import REGISTRY_ID, register

    assert register()  # again: no second entry, no override warning
    env = pettingzoo.make("parallel", REGISTRY_ID, **SMALL)
    assert isinstance(env, PedestrianParallelEnv)
    assert env.possible_agents == _agents(5) and env.env.params.max_decisions == 30
    assert pettingzoo.spec("parallel", "pedrl/room-v0").id == "pedrl/room-v0"  # PettingZoo's spelling of the id
    cycles = pettingzoo.make("parallel", REGISTRY_ID, max_cycles=12, num_agents=3)  # PettingZoo's episode length
    assert cycles.env.params.max_decisions == 12
    parallel_api_test(pettingzoo.make("parallel", REGISTRY_ID, **SMALL), num_cycles=10)


def test_max_cycles_and_max_decisions_that_disagree_are_refused_in_one_line():
    from pedrl.integrations.pettingzoo import make_env

    with pytest.raises(ValueError) as error:
        make_env(max_cycles=12, max_decisions=30, num_agents=3)
    assert str(error.value).startswith("max_cycles=12 and max_decisions=30 disagree") and "\n" not in str(error.value)
    assert make_env(max_cycles=30, max_decisions=30, num_agents=3).env.params.max_decisions == 30


def test_registering_twice_warns_nothing(recwarn):
    if not hasattr(pettingzoo, "register"):
        pytest.skip("a PettingZoo without a registry (before 1.27)")
    from pedrl.integrations.pettingzoo import register

    register()
    register()
    assert not [w for w in recwarn if "Overriding" in str(w.message)]

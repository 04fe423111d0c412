"""RoomEnv: analytic scenes, episodes, seeding, replicas, resets, validation."""

import math
import shutil

import pytest
import torch

import pedrl.sim.env as env_module
from pedrl.scenarios import paper_room
from pedrl.sim import NOOP_ACTION, PlacementError, RoomEnv
from pedrl.sim.actions import NUM_ACTIONS
from pedrl.sim.motion import Simultaneous, Stop

UP, DOWN, RIGHT, LEFT = math.pi / 2, -math.pi / 2, 0.0, math.pi
TABLE_2 = {"reward_progress": 0.0, "reward_default": 0.0}
"""The paper's rewards alone (no progress reward, no time cost), for the analytic scenes."""


def _noop(env: RoomEnv) -> torch.Tensor:
    return torch.full((env.num_replicas, env.num_agents), NOOP_ACTION)


def _place(env: RoomEnv, positions, headings, speeds):
    return env.reset(options={"positions": [positions], "headings": [headings], "speeds": [speeds]})


# ---------------------------------------------------------------- analytic scenes


@pytest.mark.parametrize(("distance", "decisions_per_second"), [(10.3, 1.0), (3.0, 2.0), (0.9, 1.0), (26.1, 0.5)])
def test_agent_heading_at_the_door_reaches_it_in_the_expected_decisions(distance, decisions_per_second):
    env = paper_room().room(**TABLE_2, num_agents=1, decisions_per_second=decisions_per_second)
    _place(env, [(30.0, 100.0 - distance)], [UP], [env.params.max_speed])
    per_decision = env.params.max_speed / decisions_per_second  # m, straight up at full speed
    expected = math.ceil(distance / per_decision)
    for decision in range(1, expected + 1):
        obs, reward, terminated, truncated, info = env.step(_noop(env))
        arrived = decision == expected
        assert reward.tolist() == [[100.0 if arrived else 0.0]]
        assert terminated.tolist() == [[arrived]] and truncated.tolist() == [[False]]
        assert info["reached"].tolist() == [[arrived]] and info["decision"] == decision
    assert not env.active.any()
    substep = per_decision / env.num_substeps
    assert 100.0 <= env.positions[0, 0, 1].item() < 100.0 + substep + 1e-4
    assert env.positions[0, 0, 0].item() == pytest.approx(30.0)
    assert torch.equal(obs, torch.zeros_like(obs))
    # once out, it stays out: no reward, no event, its actions are ignored
    obs, reward, terminated, truncated, _ = env.step(torch.zeros(1, 1, dtype=torch.int64))
    assert reward.item() == 0.0 and not terminated.any() and not truncated.any()
    assert torch.equal(obs, torch.zeros_like(obs)) and not env.active.any()


def test_head_on_agents_both_stop_and_both_get_the_agent_penalty():
    """Under the simultaneous rule both stop at the same sub-step (the sequential rule: test_dynamics)."""
    env = paper_room().room(**TABLE_2, num_agents=2, motion=Simultaneous())
    gap = 5.0
    _place(env, [(20.0, 50.0), (20.0 + gap, 50.0)], [RIGHT, LEFT], [env.params.max_speed] * 2)
    _, reward, terminated, _, info = env.step(_noop(env))
    substep = env.params.max_speed / env.num_substeps
    closing = 2 * substep
    moved = max(k for k in range(env.num_substeps + 1) if gap - k * closing >= 2 * env.params.agent_radius)
    assert moved < env.num_substeps  # they do collide within the decision
    assert reward.tolist() == [[-4.0, -4.0]]
    assert info["crashed_agent"].tolist() == [[True, True]] and info["crashed_wall"].tolist() == [[False, False]]
    assert env.speeds.tolist() == [[0.0, 0.0]] and info["speed"].tolist() == [[0.0, 0.0]]
    assert not terminated.any()
    torch.testing.assert_close(
        env.positions[0], torch.tensor([[20.0 + moved * substep, 50.0], [20.0 + gap - moved * substep, 50.0]])
    )
    assert (env.positions[0, 1] - env.positions[0, 0]).norm() >= 2 * env.params.agent_radius


def test_agent_driven_into_a_wall_stops_inside_the_room():
    env = paper_room().room(**TABLE_2, num_agents=1)
    start = 2.0
    _place(env, [(30.0, start)], [DOWN], [env.params.max_speed])
    _, reward, _, _, info = env.step(_noop(env))
    substep = env.params.max_speed / env.num_substeps
    moved = max(k for k in range(env.num_substeps + 1) if start - k * substep >= env.params.agent_radius)
    assert reward.tolist() == [[-15.0]]
    assert info["crashed_wall"].tolist() == [[True]] and info["crashed_agent"].tolist() == [[False]]
    assert env.speeds.item() == 0.0
    assert env.positions[0, 0, 1].item() == pytest.approx(start - moved * substep)
    assert env.positions[0, 0, 1].item() >= env.params.agent_radius
    assert env.active.all()


def test_agent_driven_into_a_door_post_stops_below_it():
    env = paper_room().room(**TABLE_2, num_agents=1)
    _place(env, [(29.0, 98.0)], [UP], [env.params.max_speed])  # straight at the left door post (29, 100)
    _, reward, terminated, _, info = env.step(_noop(env))
    assert reward.tolist() == [[-15.0]] and not terminated.any() and info["crashed_wall"].all()
    assert 100.0 - env.positions[0, 0, 1].item() >= env.params.agent_radius
    assert env.active.all()


def test_walking_into_a_standing_agent_penalises_only_the_mover():
    env = paper_room().room(**TABLE_2, num_agents=2)
    _place(env, [(10.0, 50.0), (12.0, 50.0)], [RIGHT, LEFT], [env.params.max_speed, 0.0])
    _, reward, _, _, info = env.step(_noop(env))
    assert reward.tolist() == [[-4.0, 0.0]]
    assert info["crashed_agent"].tolist() == [[True, False]]
    assert env.positions[0, 1].tolist() == [12.0, 50.0]


def test_actions_change_speed_and_heading_before_moving():
    env = paper_room().room(**TABLE_2, num_agents=1)
    _place(env, [(30.0, 50.0)], [RIGHT], [0.0])
    full_speed_left_turn = 8 * 9 + 7  # +1.0 max_speed, +0.25 pi
    env.step(torch.tensor([[full_speed_left_turn]]))
    diagonal = 2.5 * math.sqrt(0.5)
    assert env.speeds.item() == pytest.approx(env.params.max_speed) and env.headings.item() == pytest.approx(UP / 2)
    torch.testing.assert_close(env.positions[0, 0], torch.tensor([30.0 + diagonal, 50.0 + diagonal]))
    torch.testing.assert_close(env.velocities[0, 0], torch.tensor([diagonal, diagonal]), atol=1e-5, rtol=0)


# ---------------------------------------------------------------- episodes


def test_truncation_at_max_decisions():
    env = paper_room().room(**TABLE_2, num_replicas=2, num_agents=3, max_decisions=4)
    env.reset(seed=0)
    for decision in range(1, 5):
        obs, reward, terminated, truncated, info = env.step(_noop(env))
        assert info["decision"] == decision
        assert truncated.all() == (decision == 4) and not terminated.any()
    assert not env.active.any() and env.decisions.tolist() == [4, 4]
    # the truncation step still carries the final observation; after that, zeros
    assert obs[..., 2].gt(0).all()
    obs, reward, terminated, truncated, _ = env.step(_noop(env))
    assert not truncated.any() and torch.equal(obs, torch.zeros_like(obs)) and not reward.any()


def test_arrival_on_the_last_decision_is_terminated_not_truncated():
    env = paper_room().room(**TABLE_2, num_agents=2, max_decisions=2)
    _place(env, [(30.0, 96.0), (10.0, 10.0)], [UP, UP], [env.params.max_speed, 0.0])
    env.step(_noop(env))
    _, reward, terminated, truncated, _ = env.step(_noop(env))
    assert terminated.tolist() == [[True, False]] and truncated.tolist() == [[False, True]]
    assert reward.tolist() == [[100.0, 0.0]]


def test_info_keys_shapes_and_dtypes():
    env = paper_room().room(num_replicas=3, num_agents=4)
    obs, info = env.reset(seed=1)
    obs, reward, terminated, truncated, info = env.step(torch.randint(0, NUM_ACTIONS, (3, 4)))
    assert set(info) == {
        "crashed_agent",
        "crashed_wall",
        "reached",
        "num_sensed",
        "neighbour_mask",
        "neighbour_velocity",
        "speed",
        "decision",
    }
    assert obs.shape == (3, 4, env.num_features) and obs.dtype == torch.float32
    assert reward.shape == (3, 4) and reward.dtype == torch.float32
    assert terminated.dtype == truncated.dtype == torch.bool
    for key in ("crashed_agent", "crashed_wall", "reached"):
        assert info[key].shape == (3, 4) and info[key].dtype == torch.bool
    assert info["num_sensed"].dtype == torch.int64 and info["num_sensed"].tolist() == [[3] * 4] * 3
    assert info["neighbour_mask"].shape == (3, 4, 7) and info["speed"].dtype == torch.float32
    velocity = info["neighbour_velocity"]
    assert velocity.shape == (3, 4, 7, 2) and velocity.dtype == torch.float32
    assert bool((velocity[:, :, 3:] == 0).all())  # three others: the slots past them are empty
    assert isinstance(info["decision"], int) and info["decision"] == 1
    assert env.num_actions == 81 and env.num_features == 28
    assert env.geometry.bounds == (0.0, 0.0, 60.0, 100.0) and env.geometry.num_walls == 5


def test_reset_places_agents_apart_clear_of_walls_standing():
    env = paper_room(width=20.0, length=25.0, door_width=2.0).room(num_replicas=5, num_agents=60)
    _, info = env.reset(seed=2)
    gaps = torch.cdist(env.positions, env.positions) + torch.eye(60) * 1e3
    assert gaps.min() >= 2 * env.params.agent_radius
    x, y = env.positions[..., 0], env.positions[..., 1]
    r = env.params.agent_radius
    assert (x >= r).all() and (x <= 20.0 - r).all() and (y >= r).all() and (y <= 25.0 - r).all()
    assert (env.speeds == 0).all() and env.active.all() and info["decision"] == 0
    assert (env.headings > -math.pi).all() and (env.headings <= math.pi).all()
    assert env.headings.std() > 1.0  # uniform headings, not a constant


# ---------------------------------------------------------------- seeding, replicas, resets


def _rollout(env: RoomEnv, seed: int, steps: int, action_seed: int = 0, change=None):
    obs, _ = env.reset(seed=seed)
    generator = torch.Generator().manual_seed(action_seed)
    history = [(obs, env.positions)]
    for step in range(steps):
        actions = torch.randint(0, NUM_ACTIONS, (env.num_replicas, env.num_agents), generator=generator)
        if change is not None:
            actions = change(step, actions)
        obs, reward, *_ = env.step(actions)
        history.append((obs, env.positions, reward))
    return history


def test_same_seed_same_trajectories():
    first = _rollout(paper_room().room(num_replicas=2, num_agents=10), seed=7, steps=40)
    second = _rollout(paper_room().room(num_replicas=2, num_agents=10), seed=7, steps=40)
    for a, b in zip(first, second, strict=True):
        assert all(torch.equal(x, y) for x, y in zip(a, b, strict=True))
    other = _rollout(paper_room().room(num_replicas=2, num_agents=10), seed=8, steps=1)
    assert not torch.equal(first[0][1], other[0][1])


def test_reset_with_seed_reseeds_the_same_env():
    env = paper_room().room(num_agents=10)
    env.reset(seed=3)
    start = env.positions
    env.step(torch.randint(0, NUM_ACTIONS, (1, 10)))
    env.reset()
    assert not torch.equal(env.positions, start)
    env.reset(seed=3)
    assert torch.equal(env.positions, start)


def test_replicas_are_independent():
    def replica_zero_turns(step, actions):
        actions = actions.clone()
        actions[0] = (actions[0] + 17) % NUM_ACTIONS
        return actions

    base = _rollout(paper_room().room(num_replicas=3, num_agents=15), seed=11, steps=30)
    changed = _rollout(paper_room().room(num_replicas=3, num_agents=15), seed=11, steps=30, change=replica_zero_turns)
    assert not torch.equal(base[-1][1][0], changed[-1][1][0])
    for a, b in zip(base, changed, strict=True):
        for x, y in zip(a, b, strict=True):
            assert torch.equal(x[1:], y[1:])


def test_partial_reset_only_touches_the_chosen_replicas():
    env = paper_room().room(num_replicas=3, num_agents=6, max_decisions=50)
    env.reset(seed=4)
    generator = torch.Generator().manual_seed(4)
    for _ in range(5):
        env.step(torch.randint(0, NUM_ACTIONS, (3, 6), generator=generator))
    before = {name: getattr(env, name).clone() for name in ("positions", "headings", "speeds", "active")}
    obs, info = env.reset(options={"replicas": torch.tensor([False, True, False])})
    for name, value in before.items():
        current = getattr(env, name)
        assert torch.equal(current[0], value[0]) and torch.equal(current[2], value[2]), name
    assert not torch.equal(env.positions[1], before["positions"][1])
    assert (env.speeds[1] == 0).all() and env.active[1].all()
    assert env.decisions.tolist() == [5, 0, 5] and info["decision"] == 5
    env.step(_noop(env))
    assert env.decisions.tolist() == [6, 1, 6]
    env.reset(options={"replicas": [True, False, True]})
    assert env.decision == 1


def test_hand_placed_scene_with_partial_reset_ignores_other_replicas_rows():
    env = paper_room().room(num_replicas=2, num_agents=2)
    env.reset(seed=0)
    kept = env.positions[1].clone()
    positions = torch.tensor([[[5.0, 5.0], [7.0, 5.0]], [[-1.0, -1.0], [-1.0, -1.0]]])  # row 1 invalid but unused
    env.reset(options={"positions": positions, "replicas": [True, False]})
    assert env.positions[0].tolist() == [[5.0, 5.0], [7.0, 5.0]] and torch.equal(env.positions[1], kept)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA is not available")
def test_runs_on_cuda_like_on_cpu():
    cpu = _rollout(paper_room().room(num_replicas=2, num_agents=8), seed=5, steps=10)
    env = paper_room().room(num_replicas=2, num_agents=8, device="cuda")
    obs, _ = env.reset(seed=5)
    assert obs.device.type == "cuda" and env.positions.device.type == "cuda"
    for _ in range(10):
        obs, reward, terminated, truncated, info = env.step(torch.randint(0, NUM_ACTIONS, (2, 8), device="cuda"))
    assert reward.device.type == "cuda" and info["num_sensed"].device.type == "cuda"
    assert obs.shape == cpu[-1][0].shape


# ---------------------------------------------------------------- validation


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        ({"num_replicas": 0}, "num_replicas=0"),
        ({"num_agents": -3}, "num_agents=-3"),
        ({"num_agents": 2.5}, "num_agents=2.5"),
        ({"num_agents": True}, "num_agents=True"),
        ({"device": "gpu7"}, "device='gpu7'"),
        ({"width": -1.0}, "width=-1.0"),
        ({"length": float("inf")}, "length=inf"),
        ({"width": float("nan")}, "width=nan"),
        ({"door_width": 61.0}, "door_width=61.0"),
        ({"door_width": 0.0}, "door_width=0.0"),
        ({"agent_radius": 1.5}, "agent_radius=1.5"),
        ({"agent_radius": 0.0}, "agent_radius=0.0"),
        ({"agent_radius": 0.9, "door_width": 2.0, "width": 1.5, "length": 100.0}, "door_width=2.0"),
        ({"agent_radius": 2.0, "door_width": 4.0, "width": 5.0, "length": 3.5}, "agent_radius=2.0"),
        ({"max_speed": 0.0}, "max_speed=0.0"),
        ({"decisions_per_second": -1.0}, "decisions_per_second=-1.0"),
        ({"max_decisions": 0}, "max_decisions=0"),
        ({"num_neighbours": -1}, "num_neighbours=-1"),
        ({"num_walls": 6}, "num_walls=6"),
        ({"num_walls": -1}, "num_walls=-1"),
        ({"speed_ratios": (0.0,) * 8}, "speed_ratios has 8 values"),
        ({"turn_ratios": (0.0,) * 10}, "turn_ratios has 10 values"),
        ({"speed_ratios": (-1.0, -0.5, -0.25, -0.1, 0.1, 0.1, 0.25, 0.5, 1.0)}, "speed_ratios[4]=0.1"),
        ({"turn_ratios": (0.0, 0.0, 0.0, float("nan"), 0.0, 0.0, 0.0, 0.0, 0.0)}, "turn_ratios[3]=nan"),
        ({"speed_ratios": "fast"}, "speed_ratios"),
        # bounds of the action set, and degenerate ones
        (
            {"turn_ratios": (-0.75, -0.25, -0.08, -0.025, 0.0, 0.025, 0.08, 0.25, 1e30)},
            "turn_ratios[8]=1e+30 is invalid: each is a turn in [-1, 1]",
        ),
        (
            {
                "action_frame": "goal",
                "speed_ratios": (1.0,) * 9,
                "turn_ratios": (-4.0, -0.25, -0.1, -0.05, 0.0, 0.05, 0.1, 0.25, 0.5),
            },
            "turn_ratios[0]=-4.0 is invalid",
        ),
        (
            {"speed_ratios": (-1.0, -0.5, -0.25, -0.1, 0.0, 0.1, 0.25, 0.5, 3.0)},
            "speed_ratios[8]=3.0 is invalid: each is a speed change in [-1, 1]",
        ),
        (
            {"speed_ratios": (0.0,) * 9},
            "speed_ratios=[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0] is invalid: at least one must be above 0",
        ),
        ({"speed_ratios": (-1.0, -0.5, -0.25, -0.1, 0.0, -0.1, -0.25, -0.5, -1.0)}, "at least one must be above 0"),
        (
            {"action_frame": "goal", "speed_ratios": (0.0,) * 9, "turn_ratios": (0.0,) * 9},
            "at least one must be above 0",
        ),
        (
            {"turn_ratios": (0.0,) * 9},
            "turn_ratios=[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0] is invalid: all alike",
        ),
        ({"action_frame": "goal", "speed_ratios": (1.0,) * 9, "turn_ratios": (0.1,) * 9}, "turn_ratios=[0.1, 0.1, 0.1"),
        ({"reward_goal": float("nan")}, "reward_goal=nan"),
        ({"reward_crash_wall": "a lot"}, "reward_crash_wall='a lot'"),
        ({"substep_length": 0.5}, "substep_length=0.5"),
        ({"substep_length": -0.1}, "substep_length=-0.1"),
        ({"num_agents": 10000}, "num_agents=10000"),
    ],
)
def test_invalid_configuration_raises_one_line_value_error(kwargs, fragment):
    sizes = {key: kwargs.pop(key) for key in ("width", "length", "door_width") if key in kwargs}
    with pytest.raises(ValueError) as error:
        paper_room(**sizes).room(**kwargs)
    message = str(error.value)
    assert fragment in message and "\n" not in message


def test_the_widest_action_sets_are_kept():
    """Turns of a half turn either way and speed changes of the whole top speed are the bounds, and allowed."""
    env = paper_room().room(
        speed_ratios=(-1.0, -1.0, -0.5, -0.1, 0.0, 0.1, 0.5, 1.0, 1.0),
        turn_ratios=(-1.0, -0.5, 0, 0, 0, 0, 0, 0.5, 1.0),
    )
    assert env.params.turn_ratios[0] == -1.0 and env.params.speed_ratios[-1] == 1.0


def test_too_many_agents_message_names_n_and_the_room():
    with pytest.raises(ValueError, match=r"num_agents=10000 .*60\.0 m x 100\.0 m room"):
        paper_room().room(num_agents=10000)


def test_failed_placement_names_n_and_the_room(monkeypatch):
    monkeypatch.setattr(env_module, "MAX_PLACEMENT_ROUNDS", 1)
    env = paper_room(width=5.0, length=6.0, door_width=1.0).room(num_agents=15)
    with pytest.raises(PlacementError, match=r"num_agents=15 .*5\.0 m x 6\.0 m room") as error:
        env.reset(seed=0)
    assert isinstance(error.value, ValueError) and "\n" not in str(error.value)


def test_dense_but_allowed_rooms_are_placed():
    env = paper_room(width=5.0, length=6.0, door_width=1.0).room(num_replicas=3, num_agents=15)
    env.reset(seed=0)
    gaps = torch.cdist(env.positions, env.positions) + torch.eye(15) * 1e3
    assert gaps.min() >= 2 * env.params.agent_radius


@pytest.mark.parametrize(
    ("options", "fragment"),
    [
        ({"positions": [[(5.0, 5.0), (5.5, 5.0)]]}, "overlap"),
        ({"positions": [[(0.2, 5.0), (10.0, 5.0)]]}, "agent 0 of replica 0"),
        ({"positions": [[(30.0, 100.5), (10.0, 5.0)]]}, "outside the room"),
        ({"positions": [[(5.0, 5.0)]]}, "options['positions'] has shape (1, 1, 2)"),
        ({"positions": [[(5.0, 5.0), (float("nan"), 5.0)]]}, "finite"),
        ({"speeds": [[1.0, 3.0]]}, "options['speeds']"),
        ({"headings": [[0.0]]}, "options['headings'] has shape"),
        ({"replicas": [True, False]}, "options['replicas'] has shape"),
        ({"velocity": 1.0}, "options key 'velocity'"),
    ],
)
def test_invalid_reset_options(options, fragment):
    env = paper_room().room(num_agents=2)
    with pytest.raises(ValueError) as error:
        env.reset(options=options)
    assert fragment in str(error.value) and "\n" not in str(error.value)


def test_step_checks_its_input():
    env = paper_room().room(num_replicas=2, num_agents=3)
    with pytest.raises(RuntimeError, match="before reset"):
        env.step(torch.zeros(2, 3, dtype=torch.int64))
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"actions.shape=\(3, 2\)"):
        env.step(torch.zeros(3, 2, dtype=torch.int64))
    with pytest.raises(ValueError, match="actions.dtype"):
        env.step(torch.zeros(2, 3))
    env.step(torch.zeros(2, 3, dtype=torch.int32))  # any integer dtype is accepted


@pytest.mark.parametrize("order", ["random", "door_first"])
def test_a_queue_to_the_door_moves_up_together_when_the_front_acts_first(order):
    """Leader and follower 0.85 m apart walk to the door at the same speed: the follower only stalls (and is
    penalised) when it acts before its leader, which door_first never lets happen."""
    env = paper_room().room(num_replicas=8, num_agents=2, motion=Stop(order=order))
    positions = [[(30.0, 60.0), (30.0, 59.15)]] * 8
    env.reset(seed=0, options={"positions": positions, "headings": [[UP, UP]] * 8, "speeds": [[2.0, 2.0]] * 8})
    crashes = 0
    for _ in range(10):
        _, reward, _, _, info = env.step(_noop(env))
        crashes += int(info["crashed_agent"].sum())
        assert not info["crashed_agent"][:, 0].any()  # the leader is never stopped by its follower
    assert (crashes == 0) == (order == "door_first")


def test_progress_reward_and_time_cost_by_default():
    """One decision straight at the door at full speed: -1 (time cost) + 2.5 (metres of approach)."""
    env = paper_room().room(num_agents=1)
    _place(env, [(30.0, 50.0)], [UP], [env.params.max_speed])
    _, reward, _, _, _ = env.step(_noop(env))
    assert reward.item() == pytest.approx(-1.0 + env.params.max_speed)
    _place(env, [(30.0, 50.0)], [DOWN], [0.0])  # standing still: the time cost alone
    _, reward, _, _, _ = env.step(_noop(env))
    assert reward.item() == pytest.approx(-1.0)


# ---------------------------------------------------------------- compiled sensing (opt-in)


@pytest.mark.skipif(not (shutil.which("g++") or shutil.which("c++")), reason="inductor needs a C++ compiler")
def test_compiled_sensing_is_not_recompiled_per_trial_and_matches_eager_sensing():
    from torch._dynamo.utils import counters

    kwargs = dict(num_replicas=2, num_agents=5)
    room = paper_room(width=8.0, length=10.0, door_width=1.5)
    compiled, eager = room.room(**kwargs, compile_sensing=True), room.room(**kwargs)
    generator = torch.Generator().manual_seed(0)

    def run_trial(seed: int) -> None:
        obs, _ = compiled.reset(seed=seed)
        reference, _ = eager.reset(seed=seed)
        torch.testing.assert_close(obs, reference, rtol=1e-5, atol=1e-5)
        for _ in range(6):
            actions = torch.randint(0, compiled.num_actions, (2, 5), generator=generator)
            obs = compiled.step(actions)[0]
            reference = eager.step(actions)[0]
            torch.testing.assert_close(obs, reference, rtol=1e-4, atol=1e-4)  # the same moves: sensing differs in ulps

    run_trial(0)
    graphs = counters["stats"]["unique_graphs"]
    assert graphs >= 1
    for seed in (1, 2, 3):
        run_trial(seed)
    compiled.reset(seed=4, options={"replicas": torch.tensor([True, False])})  # a partial reset: same shapes
    assert counters["stats"]["unique_graphs"] == graphs


@pytest.mark.parametrize("seed", [1.5, 2**70, True, -1, "3", 2**64])
def test_room_reset_refuses_a_seed_that_is_not_an_integer_in_range(seed):
    """``reset(seed=1.5)`` truncated to 1 and ``reset(seed=2**70)`` overflowed with a traceback."""
    env = paper_room(width=10.0, length=10.0).room(num_replicas=1, num_agents=2)
    with pytest.raises(ValueError, match=r"^seed=.* is invalid: must be an integer in \[0, 18446744073709551615\]"):
        env.reset(seed=seed)
    env.reset(seed=2**64 - 1)  # the widest a torch generator takes: derived seeds (seed * 10007 + phase) fit

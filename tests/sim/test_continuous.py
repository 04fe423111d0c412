"""``motion=continuous``: the decision sets the desired direction and speed, and the collision-free speed model with
its direction rule (Tordeux, Chraibi & Seyfried 2016) walks every body at time steps of at most 0.05 s. Its kernel
against its torch specification, to the bit: ``tests/sim/test_contact.py``."""

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from pedrl._numba import numba_available
from pedrl.scenarios import paper_room
from pedrl.sim import RoomEnv
from pedrl.sim.actions import NUM_ACTIONS
from pedrl.sim.motion import Continuous, Steering, Yield, motion_from_config
from pedrl.sim.motion.sliding import steer
from tests.sim.test_contact import check_bodies, kernels_on

GOAL = {
    "action_frame": "goal",
    "speed_ratios": [0.0, 0.2, 0.4, 0.6, 0.7, 0.8, 0.9, 0.95, 1.0],
    "turn_ratios": [-0.5, -0.25, -0.1, -0.05, 0.0, 0.05, 0.1, 0.25, 0.5],
}
WALKING = Continuous(contact="yield", order="door_first")
"""The walking layer by the yield rule, nearest the door first."""
WALK = 8 * 9 + 4  # full speed, straight at the goal
STAND = 4  # speed 0

needs_numba = pytest.mark.skipif(not numba_available(), reason="numba is off (PEDRL_NO_NUMBA)")


def continuous(**kwargs) -> RoomEnv:
    """A room of the paper's shape (``width``, ``length`` and ``door_width`` among ``kwargs``) on the walking layer."""
    sizes = {key: kwargs.pop(key) for key in ("width", "length", "door_width") if key in kwargs}
    settings = {"motion": WALKING, "agent_radius": 0.2, "max_speed": 1.34} | GOAL | kwargs
    return paper_room(**sizes).room(**settings)


@pytest.mark.parametrize(
    ("build", "fragments"),
    [
        (
            lambda: motion_from_config({"name": "smooth"}),
            ("env.motion.name='smooth'", "stop, simultaneous", "continuous"),
        ),
        (lambda: Continuous(contact="stop"), ("env.motion.contact='stop'", "headway, yield")),
        (lambda: Continuous(contact="slide"), ("env.motion.contact='slide'", "headway, yield")),
        (lambda: Continuous(time_step=0.1), ("env.motion.time_step=0.1", "0.05")),
        (lambda: Continuous(time_step=0.0), ("env.motion.time_step=0.0",)),
        (lambda: Steering(neighbour_strength=-1.0), ("env.motion.steering.neighbour_strength=-1.0",)),
        (lambda: Steering(wall_range=0.0), ("env.motion.steering.wall_range=0.0",)),
        (lambda: Continuous(steering="5,0.02"), ("env.motion.steering='5,0.02'",)),
        (
            lambda: continuous(num_agents=2, motion=Continuous(time_step=1e-6), decisions_per_second=0.5),
            ("env.motion.time_step=1e-06", "at most"),
        ),
    ],
)
def test_bad_motion_settings_give_one_line_errors(build, fragments):
    with pytest.raises(ValueError) as error:
        build()
    message = str(error.value)
    assert "\n" not in message
    for fragment in fragments:
        assert fragment in message


@pytest.mark.parametrize("decisions_per_second", [1.0, 2.0, 3.0, 4.0])
def test_the_time_step_is_at_most_0_05_s(decisions_per_second):
    env = continuous(num_agents=2, decisions_per_second=decisions_per_second)
    assert env.params.decision_length / env.num_substeps <= 0.05 + 1e-12
    assert env.motion.steering == Steering()  # JuPedSim's defaults
    assert paper_room().room(num_agents=2, motion=Yield()).motion.steering is None  # the step model keeps its own


def test_the_direction_rule_turns_away_from_a_body_ahead_and_a_wall():
    """Analytic cases of Tordeux et al.'s eq. 4: a body 0.5 m ahead and 0.1 m to the left pushes the walker right
    with weight a exp((2 r - d) / D); a wall 0.25 m to the left with b exp((r - d) / B)."""
    env = continuous(num_agents=2, width=6.0, length=8.0)
    walls = sliding_walls(env)
    positions = torch.tensor([[[3.0, 2.0], [2.9, 2.5]]])
    commanded = torch.tensor([[[0.0, 1.0], [0.0, 0.0]]])
    wanted = steer(
        positions=positions, commanded=commanded, present=torch.tensor([[True, True]]), agent_radius=0.2,
        steering=Steering(), walls=walls,
    )  # fmt: skip
    distance = math.hypot(0.1, 0.5)
    weight = 8.0 * math.exp((0.4 - distance) / 0.1)
    expected = torch.tensor([0.1 / distance * weight, 1.0 - 0.5 / distance * weight])
    expected = expected / expected.norm()
    torch.testing.assert_close(wanted[0, 0], expected, atol=1e-5, rtol=0)
    assert torch.equal(wanted[0, 1], torch.zeros(2))  # speed 0: no velocity
    near_wall = steer(
        positions=torch.tensor([[[0.25, 2.0]]]), commanded=torch.tensor([[[0.0, 1.0]]]),
        present=torch.tensor([[True]]), agent_radius=0.2, steering=Steering(), walls=walls,
    )  # fmt: skip
    push = 5.0 * math.exp((0.2 - 0.25) / 0.02)
    torch.testing.assert_close(near_wall[0, 0], torch.tensor([push, 1.0]) / math.hypot(push, 1.0), atol=1e-5, rtol=0)


def sliding_walls(env: RoomEnv):
    return env.geometry.wall_segments()


@settings(max_examples=6, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    num_agents=st.integers(1, 60),
    decisions_per_second=st.sampled_from([1.0, 2.0, 4.0]),
    compiled=st.booleans() if numba_available() else st.just(False),
)
def test_invariants_hold_after_every_decision(seed, num_agents, decisions_per_second, compiled):
    """Random actions, mostly at full speed: bodies apart, off the walls, inside, at most max_speed."""
    num_agents = min(num_agents, 60 if compiled else 15)
    env = continuous(
        num_replicas=2, num_agents=num_agents, width=8.0, length=10.0, door_width=1.0,
        decisions_per_second=decisions_per_second, max_decisions=40,
    )  # fmt: skip
    generator = torch.Generator().manual_seed(seed)
    env.reset(seed=seed)
    with kernels_on(compiled):
        for _ in range(40 if compiled else 8):
            start, acting = env.positions.clone(), env.active.clone()
            actions = torch.randint(0, NUM_ACTIONS, env.active.shape, generator=generator)
            actions = torch.where(torch.rand(env.active.shape, generator=generator) < 0.7, 72 + actions % 9, actions)
            _, _, terminated, _, info = env.step(actions)
            check_bodies(env, start, acting & ~terminated)
            assert not (info["crashed_agent"] & info["crashed_wall"]).any()
            if not env.active.any():
                break


def walk_past_a_standing_body(motion: str) -> tuple[bool, int]:
    """A walker 4 m from the door of a 6 m x 8 m room, and a body standing on its line to the door 1.5 m ahead (5 cm
    to the side): whether the walker gets out within 20 s, and its contacts."""
    settings = {} if motion == "continuous" else {"motion": Yield(order="door_first"), "max_speed": 1.34}
    env = continuous(num_agents=2, width=6.0, length=8.0, door_width=1.2, max_decisions=40, **settings)
    env.reset(seed=0, options={"positions": [[[3.0, 4.0], [3.05, 5.5]]]})
    contacts = 0
    for _ in range(20 * int(env.params.decisions_per_second)):
        _, _, terminated, _, info = env.step(torch.tensor([[WALK, STAND]]))
        contacts += int(info["crashed_agent"][0, 0]) + int(info["crashed_wall"][0, 0])
        assert (env.positions[0, 0] - env.positions[0, 1]).norm() >= 0.4 - 1e-4  # no overlap
        if bool(terminated[0, 0]):
            return True, contacts
    return False, contacts


def test_continuous_steers_round_a_standing_body_where_the_step_model_waits_behind_it():
    assert walk_past_a_standing_body("continuous") == (True, 0)
    out, _ = walk_past_a_standing_body("step")
    assert not out  # the control: the headway rule alone keeps it behind the body


def test_a_lone_walker_keeps_its_speed_along_a_corridor():
    """RiMEA's test 1 in miniature: a lone walker commanded at full speed walks 8 m straight in 8 / 1.34 s."""
    env = continuous(num_agents=1, width=2.0, length=9.0, door_width=2.0, decisions_per_second=4.0)
    env.reset(seed=0, options={"positions": [[[1.0, 1.0]]], "headings": [[0.3]]})
    decisions = 0
    while env.active[0, 0] and decisions < 40:
        env.step(torch.tensor([[WALK]]))
        decisions += 1
    assert decisions / 4.0 == pytest.approx(8.0 / 1.34, abs=0.25)
    assert env.speeds[0, 0] == pytest.approx(1.34, abs=1e-3)

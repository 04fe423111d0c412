"""The sliding motion models of the room (``env.motion``): slide, headway and yield, their CPU kernel against the torch
reference, their invariants on random scenes and in every scenario, and the behaviour each adds over ``stop``."""

import contextlib
import math
from unittest import mock

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from pedrl._numba import numba_available
from pedrl.algos.registry import env_factory
from pedrl.scenarios import SCENARIOS, paper_room
from pedrl.sim import RoomEnv
from pedrl.sim.actions import NUM_ACTIONS, NUM_TURNS, velocities_from
from pedrl.sim.controllers import GreedyDoorController
from pedrl.sim.geometry import distances_to_segments
from pedrl.sim.motion import (
    MOTION_MODELS,
    Headway,
    Slide,
    SlidingMotion,
    Steering,
    Stop,
    Yield,
    motion_from_config,
    move_agents_sliding,
    move_agents_sliding_torch,
)
from pedrl.sim.motion import sequential as sequential_motion
from pedrl.sim.motion import sliding as sliding_motion

TOLERANCE = 1e-4  # m, as tests/sim/test_properties.py (docs/design.md invariants)
RULES = ("slide", "headway", "yield")
ACCELERATE = 8 * NUM_TURNS + 4  # full speed up, no turn
NOOP = 4 * NUM_TURNS + 4
BUILT_IN = [name for name in SCENARIOS if name != "custom"]
AGENTS = {"paper_room": 20, "bottleneck": 30, "corridor": 30, "corner": 7, "four_exits": 40, "hall": 100}

needs_numba = pytest.mark.skipif(not numba_available(), reason="numba is off (PEDRL_NO_NUMBA)")


def check_bodies(env: RoomEnv, start: torch.Tensor, acting: torch.Tensor) -> None:
    """No overlap, nobody on or through a wall or outside the area, nobody faster than ``max_speed``."""
    r = env.params.agent_radius
    inside = env.active
    positions = env.positions.double()
    walls = env.geometry.walls[: env.geometry.num_walls].double()
    assert env.geometry.inside(env.positions)[inside].all()
    assert (distances_to_segments(positions, walls).amin(-1)[inside] >= r - TOLERANCE).all()
    gaps = torch.cdist(positions, positions) + torch.eye(env.num_agents, dtype=torch.float64) * 1e9
    both = inside.unsqueeze(-1) & inside.unsqueeze(-2)
    assert (gaps[both] >= 2 * r - TOLERANCE).all()
    assert ((env.speeds >= 0) & (env.speeds <= env.params.max_speed)).all()
    moved = (env.positions - start).norm(dim=-1)
    assert (moved <= env.params.max_speed / env.params.decisions_per_second + TOLERANCE).all()
    # the speed is the distance walked per second (its own heading kept)
    walked = moved * env.params.decisions_per_second
    torch.testing.assert_close(env.speeds[acting], walked[acting].clamp(max=env.params.max_speed), atol=1e-4, rtol=0)


# ---------------------------------------------------------------- configuration


def test_stop_is_the_default_contact_model():
    env = paper_room().room(num_agents=2)
    assert env.motion == Stop() and env.motion.order == "random" and env.motion.time_gap is None


@pytest.mark.parametrize(
    ("build", "fragments"),
    [
        (lambda: motion_from_config({"name": "bounce"}), ("env.motion.name='bounce'", "stop, simultaneous, slide")),
        (lambda: motion_from_config({"name": None}), ("env.motion.name=None", "headway, yield, continuous")),
        (lambda: Headway(time_gap=0.0), ("env.motion.time_gap=0.0", "> 0")),
        (lambda: Yield(time_gap=-1.0), ("env.motion.time_gap=-1.0", "> 0")),
        (lambda: Headway(time_gap=math.nan), ("env.motion.time_gap=nan",)),
        (lambda: Yield(time_gap="1"), ("env.motion.time_gap='1'",)),
        (lambda: Slide(order="last"), ("env.motion.order='last'", "random, door_first")),
        (
            lambda: motion_from_config({"name": "slide", "time_gap": 1.0}),
            ("env.motion.time_gap is not a setting of motion 'slide'", "its settings are order"),
        ),
        (lambda: paper_room().room(num_agents=2, motion="slide"), ("motion='slide' is invalid", "Stop, Simultaneous")),
    ],
)
def test_bad_contact_settings_give_one_line_errors(build, fragments):
    with pytest.raises(ValueError) as error:
        build()
    message = str(error.value)
    assert "\n" not in message
    for fragment in fragments:
        assert fragment in message


def random_scene(seed: int, num_agents: int, room: tuple[float, float, float], speed_scale: float):
    """Placed bodies (no overlaps) with random velocities up to ``max_speed`` and a few inactive agents."""
    width, length, door_width = room
    env = paper_room(width=width, length=length, door_width=door_width).room(num_replicas=2, num_agents=num_agents)
    env.reset(seed=seed)
    generator = torch.Generator().manual_seed(seed)
    shape = (2, num_agents)
    speeds = env.params.max_speed * speed_scale * torch.rand(shape, generator=generator)
    headings = math.pi - 2 * math.pi * torch.rand(shape, generator=generator)
    active = torch.rand(shape, generator=generator) < 0.9
    priority = torch.rand(shape, generator=generator)
    velocities = velocities_from(speeds=speeds, headings=headings)
    return env, velocities, active, priority


@needs_numba
@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    num_agents=st.integers(1, 40),
    room=st.sampled_from([(12.0, 15.0, 1.5), (6.0, 8.0, 1.0), (4.0, 4.0, 1.2)]),
    speed_scale=st.sampled_from([0.3, 1.0]),
    rule=st.sampled_from((*RULES, "continuous")),
)
def test_kernel_equals_the_torch_reference_to_the_bit(seed, num_agents, room, speed_scale, rule):
    """Every sliding rule, and motion=continuous (yield with the direction rule at 0.05 s steps)."""
    width, length, _ = room
    num_agents = min(num_agents, int(0.3 * (width - 0.8) * (length - 0.8) / (math.pi * 0.16)))
    env, velocities, active, priority = random_scene(seed, num_agents, room, speed_scale)
    kwargs = dict(
        positions=env.positions,
        velocities=velocities,
        active=active,
        motion=SlidingMotion(
            env.geometry, env.params.agent_radius, env.params.decision_length,
            20 if rule == "continuous" else env.num_substeps, None if rule == "slide" else 1.0,
            rule in ("yield", "continuous"), Steering() if rule == "continuous" else None,
        ),
        priority=priority,
    )  # fmt: skip
    compiled = move_agents_sliding(**kwargs, compiled=True)
    reference = move_agents_sliding_torch(**kwargs)  # the kernel's specification
    assert torch.equal(compiled.positions, reference.positions)  # same float32 operations in the same order
    for flag in ("blocked", "crashed_wall", "crashed_agent", "reached"):
        assert torch.equal(getattr(compiled, flag), getattr(reference, flag)), flag


# ---------------------------------------------------------------- invariants


@settings(max_examples=8, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    num_agents=st.integers(1, 60),
    room=st.sampled_from([(60.0, 100.0, 2.0), (12.0, 15.0, 1.5), (6.0, 8.0, 1.0)]),
    rule=st.sampled_from(RULES),
    compiled=st.booleans() if numba_available() else st.just(False),
)
def test_invariants_hold_after_every_step(seed, num_agents, room, rule, compiled):
    """Random, mostly accelerating actions: bodies apart, off the walls, inside, speeds in range and equal to the
    distance walked; a contact is flagged as wall or body, never both, and pays its reward."""
    width, length, door_width = room
    capacity = int(0.3 * (width - 0.8) * (length - 0.8) / (math.pi * 0.16))
    num_agents = min(num_agents, capacity, 60 if compiled else 20)
    env = paper_room(width=width, length=length, door_width=door_width).room(
        num_replicas=2, num_agents=num_agents, max_decisions=30, motion=MOTION_MODELS[rule](), reward_progress=0.0
    )
    shape = (2, num_agents)
    generator = torch.Generator().manual_seed(seed)
    env.reset(seed=seed)
    with kernels_on(compiled):
        for _ in range(60 if compiled else 20):
            if env.decision >= env.params.max_decisions or not env.active.any():
                env.reset()
            start, acting = env.positions.clone(), env.active.clone()
            actions = torch.randint(0, NUM_ACTIONS, shape, generator=generator)
            actions = torch.where(torch.rand(shape, generator=generator) < 0.7, 8 * 9 + actions % 9, actions)
            _, reward, terminated, _, info = env.step(actions)
            check_bodies(env, start, acting & ~terminated)
            assert not (info["crashed_agent"] & info["crashed_wall"]).any()
            event = torch.where(info["crashed_agent"], -4.0, -1.0)
            event = torch.where(info["crashed_wall"], -15.0, event)
            event = torch.where(terminated, 100.0, event)
            assert torch.equal(reward, torch.where(acting, event, 0.0))


def kernels_on(compiled: bool):
    """Force the kernels of every contact model on or off."""
    switch = lambda device, compiled_=None: compiled  # noqa: E731
    patches = [mock.patch.object(module, "use_kernels", switch) for module in (sequential_motion, sliding_motion)]
    stack = contextlib.ExitStack()
    for patch in patches:
        stack.enter_context(patch)
    return stack


def walk_scenario(name: str, rule: str, *, compiled: bool, decisions: int) -> torch.Tensor:
    """Greedy walkers with noise in a scenario, checking the invariants after every step: the final positions."""
    settings = {"_target_": "pedrl.sim.RoomEnv", "max_decisions": 60, "motion": {"name": rule}}
    env = env_factory(settings, {"name": name})(num_replicas=2, num_agents=AGENTS[name])
    controller = GreedyDoorController(epsilon=0.2, generator=torch.Generator().manual_seed(1))
    obs, info = env.reset(seed=3)
    with kernels_on(compiled):
        for _ in range(decisions):
            start, acting = env.positions.clone(), env.active.clone()
            obs, _, terminated, _, info = env.step(controller.act(env, obs, info))
            check_bodies(env, start, acting & ~terminated)
    return env.positions


@pytest.mark.parametrize("rule", RULES)
@pytest.mark.parametrize("name", BUILT_IN)
def test_every_scenario_keeps_its_invariants(name, rule):
    """The compiled kernel for 40 decisions; the torch reference for 8, to the bit the same as the kernel's."""
    reference = walk_scenario(name, rule, compiled=False, decisions=8)
    if numba_available():
        walk_scenario(name, rule, compiled=True, decisions=40)
        assert torch.equal(walk_scenario(name, rule, compiled=True, decisions=8), reference)


# ---------------------------------------------------------------- behaviour


def door_post_run(contact: str) -> tuple[bool, int]:
    """A lone agent aimed 30 degrees off straight at a 1.2 m door, so that it meets the left post.

    Returns:
        Whether it got out, and its wall contacts.
    """
    env = paper_room(width=6.0, length=8.0, door_width=1.2).room(
        num_agents=1, max_decisions=15, motion=MOTION_MODELS[contact]()
    )
    heading = math.radians(90.0 - 30.0)
    env.reset(seed=0, options={"positions": [[[1.6, 6.4]]], "headings": [[heading]], "speeds": [[1.0]]})
    contacts = 0
    for _ in range(15):
        _, _, terminated, truncated, info = env.step(torch.tensor([[ACCELERATE]]))
        contacts += int(info["crashed_wall"].sum())
        if bool(terminated.any()):
            return True, contacts
        if bool(truncated.any()):
            break
    return False, contacts


def test_stop_pins_a_body_against_a_door_post():
    got_out, contacts = door_post_run("stop")
    assert not got_out and contacts > 10


@pytest.mark.parametrize("rule", RULES)
def test_every_sliding_rule_gets_a_body_past_a_door_post(rule):
    got_out, contacts = door_post_run(rule)
    assert got_out and contacts >= 1


def follow_run(contact: str, order: str = "random") -> tuple[list[float], int]:
    """A leader walking at 1 m/s and a follower 3 m behind it that always wants full speed: (gaps, body contacts)."""
    env = paper_room(width=6.0, length=60.0, door_width=2.0).room(
        num_agents=2, max_decisions=40, motion=MOTION_MODELS[contact](order=order)
    )
    up = math.pi / 2
    env.reset(seed=0, options={"positions": [[[3.0, 5.0], [3.0, 2.0]]], "headings": [[up, up]], "speeds": [[1.0, 2.5]]})
    gaps, contacts = [], 0
    for _ in range(30):
        _, _, _, _, info = env.step(torch.tensor([[NOOP, ACCELERATE]]))
        contacts += int(info["crashed_agent"].sum())
        gaps.append(float((env.positions[0, 0] - env.positions[0, 1]).norm()) - 2 * env.params.agent_radius)
    return gaps, contacts


def test_stop_lets_a_follower_bump_into_a_slower_leader():
    _, contacts = follow_run("stop")
    assert contacts > 5


@pytest.mark.parametrize(("rule", "order"), [("headway", "random"), ("yield", "door_first")])
def test_headway_keeps_a_follower_about_v_times_t_behind_a_slower_leader(rule, order):
    gaps, contacts = follow_run(rule, order)
    assert contacts == 0 and min(gaps) > 0.5
    assert all(abs(gap - 1.0 * 1.0) < 0.2 for gap in gaps[10:]), gaps  # v T = 1 m/s * 1 s


def test_yield_follows_the_order_of_action():
    """With the order reversed (the one farther from the door acts first), the follower acts before the leader:
    under yield it owes the leader no gap, and bumps into it."""
    with mock.patch.object(RoomEnv, "_goal_distance", lambda self, positions, targets: positions[..., 1]):
        _, reversed_contacts = follow_run("yield", "door_first")
    assert reversed_contacts > 5


def greedy_crowd_run(rule: str) -> tuple[float, float]:
    """100 greedy walkers (10 % random actions) in the paper's room: (share out in 200 decisions, contacts per
    agent)."""
    env = paper_room().room(num_replicas=4, num_agents=100, motion=MOTION_MODELS[rule](order="door_first"))
    controller = GreedyDoorController(epsilon=0.1, generator=torch.Generator().manual_seed(0))
    obs, info = env.reset(seed=3)
    out = torch.zeros(env.num_replicas, env.num_agents, dtype=torch.bool)
    contacts = 0.0
    for _ in range(env.params.max_decisions):
        obs, _, terminated, _, info = env.step(controller.act(env, obs, info))
        out |= terminated
        contacts += info["crashed_agent"].float().mean().item()
    return out.float().mean().item(), contacts


@needs_numba
def test_yield_lets_a_greedy_crowd_through_a_door_where_headway_jams():
    """Walkers converging on a door each stand in the other's corridor: under headway (as JuPedSim's rule, without
    its steering away from neighbours) they hold each other up; with the right of way of yield the crowd leaves, and
    with far fewer contacts than under slide."""
    jammed, _ = greedy_crowd_run("headway")
    flowing, yield_contacts = greedy_crowd_run("yield")
    _, slide_contacts = greedy_crowd_run("slide")
    assert jammed < 0.5 and flowing >= 0.99, (jammed, flowing)
    assert yield_contacts < 2 and slide_contacts > 10 * yield_contacts, (yield_contacts, slide_contacts)

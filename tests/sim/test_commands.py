"""Continuous commands (the speed ratio and the heading offset from the goal bearing) in the room: a ``goal``-frame
action and the command it is walk the same, in the torch step and in the compiled kernels; bad commands get one line.
"""

import math

import pytest
import torch

from pedrl._numba import numba_available
from pedrl.scenarios import paper_room
from pedrl.sim import RoomEnv, commands_of
from pedrl.sim.actions import NUM_ACTIONS
from pedrl.sim.controllers import GreedyDoorController
from pedrl.trial.stepped import CompiledRoom
from tests.sim.test_contact import check_bodies
from tests.sim.test_continuous import continuous

needs_numba = pytest.mark.skipif(not numba_available(), reason="numba is off (PEDRL_NO_NUMBA)")


def room() -> RoomEnv:
    return continuous(num_replicas=3, num_agents=12, max_decisions=40)


def as_commands(env: RoomEnv, actions: torch.Tensor) -> torch.Tensor:
    return commands_of(actions, speed_changes=env.speed_changes, turn_changes=env.turn_changes,
                       max_speed=env.params.max_speed)  # fmt: skip


def walk(env, decide, *, seed: int = 5, steps: int = 15) -> list[torch.Tensor]:
    """Positions after each of ``steps`` decisions, ``decide(env, step)`` giving what the room is stepped with."""
    env.reset(seed=seed)
    trace = []
    for step in range(steps):
        env.step(decide(env, step))
        trace.append(env.positions.clone())
    return trace


def random_actions(env: RoomEnv, step: int) -> torch.Tensor:
    generator = torch.Generator().manual_seed(100 + step)
    return torch.randint(0, NUM_ACTIONS, (env.num_replicas, env.num_agents), generator=generator)


@pytest.mark.parametrize("stepped", [False, pytest.param(True, marks=needs_numba)])
def test_a_goal_frame_action_and_its_command_walk_the_same(stepped):
    """The command that :func:`commands_of` writes for each of 15 decisions of random actions moves every body where
    the action moves it (float32: within 1e-5 m), through the torch step and through the compiled kernels."""
    wrap = CompiledRoom if stepped else (lambda env: env)
    by_action = walk(wrap(room()), random_actions)
    by_command = walk(wrap(room()), lambda env, step: as_commands(env, random_actions(env, step)))
    moved = (by_action[-1] - by_action[0]).norm(dim=-1)
    assert float(moved.max()) > 1.0  # the bodies walked
    for a, c in zip(by_action, by_command, strict=True):
        torch.testing.assert_close(c, a, atol=1e-5, rtol=0)


def test_commands_are_clipped_to_the_top_speed_and_wrapped():
    """A ratio above 1 walks at the top speed, a negative one stands; an offset of 2 pi heads at the goal."""
    env = room()
    env.reset(seed=1)
    commands = torch.zeros(env.num_replicas, env.num_agents, 2)
    commands[..., 0] = torch.tensor([1.7, -0.4, 0.5] * 4)
    commands[..., 1] = torch.tensor([2 * math.pi, 0.0, math.pi / 4] * 4)
    speeds, headings = env.decide(commands)
    bearing_speeds, bearings = env.decide(as_commands(env, torch.full_like(commands[..., 0], 8 * 9 + 4).long()))
    top = env.params.max_speed
    torch.testing.assert_close(speeds[..., 0::3], torch.full_like(speeds[..., 0::3], top))
    assert bool((speeds[..., 1::3] == 0).all())
    torch.testing.assert_close(speeds[..., 2::3], torch.full_like(speeds[..., 2::3], 0.5 * top))
    torch.testing.assert_close(headings[..., 0::3], bearings[..., 0::3], atol=1e-5, rtol=0)
    turned = torch.remainder(headings[..., 2::3] - bearings[..., 2::3], 2 * math.pi)
    torch.testing.assert_close(turned, torch.full_like(turned, math.pi / 4), atol=1e-5, rtol=0)


@needs_numba
def test_commanded_walkers_keep_the_physical_invariants():
    """The greedy walker's commands with noise, some asking for more than the top speed, in the compiled room: after
    every decision no overlap, nobody on or through a wall, nobody faster than the top speed
    (:func:`tests.sim.test_contact.check_bodies`), and the crowd empties the room."""
    env = CompiledRoom(continuous(num_replicas=2, num_agents=20, max_decisions=200))
    obs, info = env.reset(seed=2)
    greedy = GreedyDoorController(epsilon=0.0)
    generator = torch.Generator().manual_seed(0)
    for _ in range(200):
        if not bool(env.active.any()):
            break
        commands = as_commands(env, greedy.act(env, obs, info))
        commands = commands + 0.05 * torch.randn(commands.shape, generator=generator)
        start, acting = env.positions.clone(), env.active.clone()
        obs, _, _, _, info = env.step(commands)
        check_bodies(env.env, start, acting)
    assert not bool(env.active.any())


@pytest.mark.parametrize(
    ("make", "fragment"),
    [
        (lambda env: torch.zeros(env.num_replicas, env.num_agents, 3), "must be (2, 4, 2)"),
        (lambda env: torch.zeros(env.num_replicas, env.num_agents), "must be (2, 4, 2)"),
        (lambda env: torch.full((env.num_replicas, env.num_agents, 2), math.nan), "finite"),
    ],
)
def test_bad_commands_get_one_line(make, fragment):
    env = continuous(num_replicas=2, num_agents=4)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="actions") as error:
        env.step(make(env))
    assert fragment in str(error.value) and "\n" not in str(error.value)


def test_commands_need_the_goal_frame():
    env = paper_room().room(num_agents=4)  # the paper's heading frame
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action_frame=goal"):
        env.step(torch.zeros(1, 4, 2))

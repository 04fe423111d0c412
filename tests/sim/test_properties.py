"""Invariants of RoomEnv under random actions (hypothesis): bodies, walls, speeds, episode flags."""

import math

import torch
from hypothesis import example, given, settings
from hypothesis import strategies as st

from pedrl.scenarios import paper_room
from pedrl.sim import RoomEnv
from pedrl.sim.actions import NUM_ACTIONS
from pedrl.sim.geometry import distances_to_segments

TOLERANCE = 1e-4  # m, docs/design.md invariants


def _capacity(width: float, length: float, radius: float = 0.4) -> int:
    return int(0.35 * (width - 2 * radius) * (length - 2 * radius) / (math.pi * radius**2))


def check_state(env: RoomEnv) -> None:
    """Bodies apart, clear of walls and inside the room; speeds in range."""
    r = env.params.agent_radius
    active = env.active
    x, y = env.positions[..., 0].double(), env.positions[..., 1].double()
    assert ((env.speeds >= 0) & (env.speeds <= env.params.max_speed)).all()
    assert torch.isfinite(env.positions).all()
    x_min, y_min, x_max, y_max = env.geometry.bounds
    inside = (x > x_min) & (x < x_max) & (y > y_min) & (y < y_max)
    assert (inside | ~active).all()
    wall_distance = distances_to_segments(env.positions.double(), env.geometry.walls.double()).amin(-1)
    assert ((wall_distance >= r - TOLERANCE) | ~active).all()
    gap_x = x.unsqueeze(2) - x.unsqueeze(1)
    gap_y = y.unsqueeze(2) - y.unsqueeze(1)
    both = active.unsqueeze(2) & active.unsqueeze(1) & ~torch.eye(env.num_agents, dtype=torch.bool)
    gap_sq = torch.where(both, gap_x * gap_x + gap_y * gap_y, torch.inf)
    assert (gap_sq >= (2 * r - TOLERANCE) ** 2).all()


@settings(max_examples=16, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    num_replicas=st.integers(1, 3),
    num_agents=st.integers(1, 100),
    room=st.sampled_from([(60.0, 100.0, 2.0), (12.0, 15.0, 1.5), (6.0, 8.0, 1.0)]),
    bias=st.sampled_from(["uniform", "fast"]),
)
@example(seed=1, num_replicas=2, num_agents=100, room=(60.0, 100.0, 2.0), bias="uniform")
@example(seed=2, num_replicas=2, num_agents=60, room=(12.0, 15.0, 1.5), bias="fast")
@example(seed=3, num_replicas=2, num_agents=20, room=(6.0, 8.0, 1.0), bias="fast")
def test_invariants_hold_after_every_step(seed, num_replicas, num_agents, room, bias):
    width, length, door_width = room
    # dense rooms hold at most 60 agents: keeps every tensor small enough for one intra-op thread
    num_agents = min(num_agents, _capacity(width, length), 100 if width >= 60.0 else 60)
    env = paper_room(width=width, length=length, door_width=door_width).room(
        num_replicas=num_replicas, num_agents=num_agents, max_decisions=70
    )
    shape = (num_replicas, num_agents)
    env.reset(seed=seed)
    check_state(env)
    generator = torch.Generator().manual_seed(seed)
    events = 0
    for _ in range(200):
        if env.decision >= env.params.max_decisions or not env.active.any():
            env.reset()
        before = env.active.clone()
        start = env.positions.clone()
        actions = torch.randint(0, NUM_ACTIONS, shape, generator=generator)
        if bias == "fast":  # mostly accelerate, so bodies meet walls, each other and the door
            actions = torch.where(torch.rand(shape, generator=generator) < 0.7, 8 * 9 + actions % 9, actions)
        obs, reward, terminated, truncated, info = env.step(actions)
        check_state(env)

        ended = terminated | truncated
        assert not (terminated & truncated).any()
        assert torch.equal(ended, before & ~env.active)  # trials end exactly once, inactive stays inactive
        assert not (env.active & ~before).any()
        assert torch.equal(terminated, info["reached"])
        assert (env.positions[..., 1][terminated] >= env.geometry.bounds[3]).all()  # through the door, then inactive
        velocities = env.speeds.unsqueeze(-1) * torch.stack((env.headings.cos(), env.headings.sin()), dim=-1)
        torch.testing.assert_close(env.velocities[env.active], velocities[env.active], atol=1e-5, rtol=1e-5)
        if truncated.any():
            assert info["decision"] == env.params.max_decisions
        assert not reward[~before].any() and torch.equal(obs[~before], torch.zeros_like(obs[~before]))
        assert torch.equal(obs[terminated], torch.zeros_like(obs[terminated]))
        # Table 2 events (the default time cost -1 otherwise), plus 1 per metre of approach to the door centre
        event = torch.where(info["crashed_agent"], -4.0, -1.0)
        event = torch.where(info["crashed_wall"], -15.0, event)
        event = torch.where(terminated, 100.0, event)
        goal = env.geometry.exit_goals[0]
        approach = (start - goal).norm(dim=-1) - (env.positions - goal).norm(dim=-1)
        expected = torch.where(before, event + env.params.reward_progress * approach, 0.0)
        torch.testing.assert_close(reward, expected, atol=1e-4, rtol=1e-5)
        crashed = info["crashed_agent"] | info["crashed_wall"]
        assert not (info["crashed_agent"] & info["crashed_wall"]).any()
        assert (env.speeds[crashed] == 0).all() and not crashed[~before].any()
        in_room = before & ~terminated
        others = in_room.sum(-1, keepdim=True) - 1
        expected_sensed = torch.where(in_room, others.clamp(max=env.params.num_neighbours), 0)
        assert torch.equal(info["num_sensed"], expected_sensed)
        assert torch.equal(info["neighbour_mask"].sum(-1), expected_sensed)
        assert torch.isfinite(obs).all()
        events += int(crashed.sum())
    assert events > 0 or num_agents == 1 or bias == "uniform"

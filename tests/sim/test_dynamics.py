"""Actions, speed and heading updates, and the collision rules against their literal specifications
(`pedrl.sim.reference`)."""

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from pedrl.scenarios import paper_room
from pedrl.sim import RoomEnv
from pedrl.sim.actions import (
    DEFAULT_SPEED_RATIOS,
    DEFAULT_TURN_RATIOS,
    GOAL_SPEED_RATIOS,
    GOAL_TURN_RATIOS,
    NOOP_ACTION,
    NUM_ACTIONS,
    apply_actions,
    count_substeps,
    decode_actions,
    encode_actions,
    velocities_from,
)
from pedrl.sim.geometry import distances_to_segments
from pedrl.sim.motion import Motion, Yield, move_agents, move_agents_sequential
from pedrl.sim.reference import move_agents_literal, move_agents_sequential_literal


def motion(env: RoomEnv, velocities: torch.Tensor) -> dict:
    """The arguments of ``move_agents`` for the room's current state and ``velocities``."""
    return dict(
        positions=env.positions,
        velocities=velocities,
        active=env.active,
        motion=Motion(env.geometry, env.params.agent_radius, env.params.decision_length, env.num_substeps),
    )


# ---------------------------------------------------------------- actions


def test_action_encoding_round_trips_and_noop_is_40():
    actions = torch.arange(NUM_ACTIONS).view(9, 9)
    speed_index, turn_index = decode_actions(actions)
    assert torch.equal(speed_index, torch.arange(9).view(9, 1).expand(9, 9))
    assert torch.equal(turn_index, torch.arange(9).view(1, 9).expand(9, 9))
    assert torch.equal(encode_actions(speed_index=speed_index, turn_index=turn_index), actions)
    assert NOOP_ACTION == 40 and decode_actions(torch.tensor(40)) == (4, 4)


def test_apply_actions_changes_speed_and_heading_as_documented():
    max_speed = 2.5
    speed_changes = torch.tensor(DEFAULT_SPEED_RATIOS) * max_speed
    turn_changes = torch.tensor(DEFAULT_TURN_RATIOS) * math.pi
    speeds = torch.tensor([[0.0, 0.0, 2.0, 1.0, 2.5]])
    headings = torch.tensor([[0.0, 3.0, 0.0, -3.0, 1.0]])
    actions = torch.tensor([[8 * 9 + 4, 7 * 9 + 8, 8 * 9 + 4, 0 * 9 + 0, NOOP_ACTION]])
    active = torch.tensor([[True, True, True, True, False]])
    new_speeds, new_headings = apply_actions(
        speeds=speeds,
        headings=headings,
        actions=actions,
        speed_changes=speed_changes,
        turn_changes=turn_changes,
        max_speed=max_speed,
        active=active,
    )
    # standing to full speed in one decision (+1.0), +0.5 is half of it, clipped to [0, max_speed];
    # the inactive agent (last) ignores its action
    torch.testing.assert_close(new_speeds, torch.tensor([[2.5, 1.25, 2.5, 0.0, 2.5]]))
    expected_headings = [0.0, 3.0 + 0.75 * math.pi - 2 * math.pi, 0.0, -3.0 - 0.75 * math.pi + 2 * math.pi, 1.0]
    torch.testing.assert_close(new_headings, torch.tensor([expected_headings]), atol=1e-5, rtol=0)
    assert (new_headings > -math.pi).all() and (new_headings <= math.pi).all()


def test_goal_frame_actions_set_the_speed_and_the_heading_from_the_bearing_of_the_goal():
    """In the goal frame an action means the same whatever the speed and heading before it: the speed index sets
    the speed, the turn index the heading relative to the line to the goal."""
    max_speed = 2.5
    bearings = torch.tensor([[math.pi / 2, math.pi / 2, 3.0, 0.0]])
    speeds, headings = apply_actions(
        speeds=torch.tensor([[2.5, 0.0, 1.0, 1.0]]),
        headings=torch.tensor([[-2.0, 1.0, 0.0, 0.0]]),
        actions=torch.tensor([[8 * 9 + 4, 0 * 9 + 5, 5 * 9 + 8, 2 * 9 + 4]]),
        speed_changes=torch.tensor(GOAL_SPEED_RATIOS) * max_speed,
        turn_changes=torch.tensor(GOAL_TURN_RATIOS) * math.pi,
        max_speed=max_speed,
        active=torch.tensor([[True, True, True, False]]),
        bearings=bearings,
    )
    torch.testing.assert_close(speeds, torch.tensor([[2.5, 0.0, 2.0, 1.0]]))  # the inactive one keeps its own
    expected = [math.pi / 2, math.pi / 2 + 0.05 * math.pi, 3.0 + 0.5 * math.pi - 2 * math.pi, 0.0]
    torch.testing.assert_close(headings, torch.tensor([expected]), atol=1e-5, rtol=0)


def test_goal_frame_walkers_go_straight_out_and_bad_ratios_are_refused():
    """Full speed at offset 0 takes every walker of an open room out by the shortest line; a speed ratio outside
    [0, 1] is refused in one line (in the heading frame it is a change, -1 allowed)."""
    env = paper_room(width=10.0, length=10.0, door_width=3.0).room(
        num_replicas=2,
        num_agents=8,
        max_decisions=20,
        action_frame="goal",
        speed_ratios=GOAL_SPEED_RATIOS,
        turn_ratios=GOAL_TURN_RATIOS,
        motion=Yield(order="door_first"),
    )
    env.reset(seed=3)
    straight = torch.full((2, 8), 8 * 9 + 4)
    start = env.positions.clone()
    to_door = torch.linalg.vector_norm(env.targets() - start, dim=-1)
    for _ in range(20):
        _, _, terminated, _, info = env.step(straight)
        if not env.active.any():
            break
    assert not env.active.any()
    # nobody needs more decisions than the straight line at full speed allows, plus the queue at the door
    assert env.decisions.max() <= math.ceil(float(to_door.max()) / 2.5) + 8
    with pytest.raises(ValueError, match=r"^speed_ratios\[0\]=-1.0 is invalid: with action_frame=goal"):
        paper_room().room(action_frame="goal")
    with pytest.raises(ValueError, match=r"^action_frame='door' is invalid: must be one of heading, goal$"):
        paper_room().room(action_frame="door")


def test_half_turn_takes_two_decisions():
    turn_changes = torch.tensor(DEFAULT_TURN_RATIOS) * math.pi
    heading = torch.zeros(1, 1)
    for turn in (8, 7):  # +0.75 pi, then +0.25 pi
        _, heading = apply_actions(
            speeds=torch.zeros(1, 1),
            headings=heading,
            actions=torch.tensor([[4 * 9 + turn]]),
            speed_changes=torch.zeros(9),
            turn_changes=turn_changes,
            max_speed=2.5,
            active=torch.ones(1, 1, dtype=torch.bool),
        )
    assert heading.item() == pytest.approx(math.pi, abs=1e-6)


def test_velocities_point_along_the_heading():
    velocities = velocities_from(speeds=torch.tensor([[2.0, 1.0]]), headings=torch.tensor([[0.0, math.pi / 2]]))
    torch.testing.assert_close(velocities, torch.tensor([[[2.0, 0.0], [0.0, 1.0]]]), atol=1e-6, rtol=0)


@pytest.mark.parametrize(
    ("max_speed", "decision_length", "substep_length", "expected"),
    [(2.5, 1.0, 0.4, 7), (2.5, 1.0, 0.5, 5), (2.5, 0.5, 0.4, 4), (1.0, 1.0, 2.0, 1)],
)
def test_count_substeps(max_speed, decision_length, substep_length, expected):
    substeps = count_substeps(max_speed=max_speed, decision_length=decision_length, substep_length=substep_length)
    assert substeps == expected
    assert max_speed * decision_length / substeps <= substep_length + 1e-12


# ---------------------------------------------------------------- geometry used by the mover


def test_touches_walls_equals_segment_distance_test():
    geometry = paper_room(width=6.0, length=8.0, door_width=1.2).geometry()
    generator = torch.Generator().manual_seed(0)
    radius = 0.4
    points = torch.rand(20000, 2, generator=generator) * torch.tensor([6.0 + 4 * radius, 8.0 + 4 * radius])
    points -= 2 * radius
    distance = distances_to_segments(points.double(), geometry.walls[: geometry.num_walls].double())
    nearest = distance.amin(-1)
    decided = (nearest - radius).abs() > 1e-4  # away from float ties
    touches = geometry.touches_walls(points, radius=radius)
    assert decided.sum() > 19000
    assert torch.equal(touches[decided], (nearest < radius)[decided])


# ---------------------------------------------------------------- the collision rule


def _cap(width: float, length: float, radius: float = 0.4) -> int:
    """Most agents RoomEnv accepts in a room (35 % of the free area)."""
    return int(0.35 * (width - 2 * radius) * (length - 2 * radius) / (math.pi * radius**2))


@settings(max_examples=100, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    num_replicas=st.integers(1, 4),
    num_agents=st.integers(1, 40),
    room=st.sampled_from([(4.0, 5.0, 0.9), (8.0, 10.0, 1.5), (60.0, 100.0, 2.0)]),
    decisions_per_second=st.sampled_from([1.0, 2.0]),
)
def test_move_agents_equals_the_literal_substep_rule(seed, num_replicas, num_agents, room, decisions_per_second):
    width, length, door_width = room
    num_agents = min(num_agents, _cap(width, length))
    env = paper_room(width=width, length=length, door_width=door_width).room(
        num_replicas=num_replicas, num_agents=num_agents, decisions_per_second=decisions_per_second
    )
    env.reset(seed=seed)
    generator = torch.Generator().manual_seed(seed)
    shape = (num_replicas, num_agents)
    for _ in range(12):
        speeds = torch.rand(shape, generator=generator) * env.params.max_speed
        speeds = torch.where(torch.rand(shape, generator=generator) < 0.3, env.params.max_speed, speeds)
        speeds = torch.where(torch.rand(shape, generator=generator) < 0.2, 0.0, speeds)
        headings = math.pi - 2 * math.pi * torch.rand(shape, generator=generator)
        # aim a third of the agents at the door, so the door and its posts are exercised
        goal_x, goal_y = env.geometry.exit_goals[0].tolist()
        to_door = torch.atan2(goal_y - env.positions[..., 1], goal_x - env.positions[..., 0])
        headings = torch.where(torch.rand(shape, generator=generator) < 0.3, to_door, headings)
        kwargs = motion(env, velocities_from(speeds=speeds, headings=headings))
        fast = move_agents(**kwargs)
        slow = move_agents_literal(**kwargs)
        assert torch.equal(fast.positions, slow.positions)
        assert torch.equal(fast.crashed_wall, slow.crashed_wall)
        assert torch.equal(fast.crashed_agent, slow.crashed_agent & ~slow.crashed_wall)
        assert torch.equal(fast.reached, slow.reached)
        assert torch.equal(fast.blocked, slow.blocked)
        env.step(torch.randint(0, NUM_ACTIONS, shape, generator=generator))


def test_standing_agent_that_is_walked_into_is_not_penalised():
    geometry = paper_room().geometry()
    # the mover's first sub-step (2.5 / 7 = 0.357 m) would bring the centres to 0.843 m apart, the second to
    # 0.486 m: it is blocked in sub-step 2 and stays after sub-step 1
    positions = torch.tensor([[[10.0, 50.0], [11.2, 50.0]]])
    velocities = torch.tensor([[[2.5, 0.0], [0.0, 0.0]]])
    movement = move_agents(
        positions=positions,
        velocities=velocities,
        active=torch.ones(1, 2, dtype=torch.bool),
        motion=Motion(geometry, 0.4, 1.0, 7),
    )
    assert movement.crashed_agent.tolist() == [[True, False]]
    assert movement.blocked.tolist() == [[True, False]]
    assert movement.crashed_wall.tolist() == [[False, False]]
    torch.testing.assert_close(movement.positions, torch.tensor([[[10.0 + 2.5 / 7, 50.0], [11.2, 50.0]]]))


def test_dense_rooms_match_the_reference_and_exercise_every_event():
    """A crowded small room, many decisions: agent crashes, wall crashes and arrivals all happen."""
    env = paper_room(width=5.0, length=6.0, door_width=1.0).room(num_replicas=3, num_agents=12)
    env.reset(seed=3)
    generator = torch.Generator().manual_seed(3)
    counts = {"crashed_agent": 0, "crashed_wall": 0, "reached": 0}
    for _ in range(60):
        if not env.active.any():
            env.reset()
        speeds = torch.full((3, 12), env.params.max_speed)
        goal_x, goal_y = env.geometry.exit_goals[0].tolist()
        headings = torch.atan2(goal_y - env.positions[..., 1], goal_x - env.positions[..., 0])
        headings = headings + 0.6 * torch.randn(3, 12, generator=generator)
        kwargs = motion(env, velocities_from(speeds=speeds, headings=headings))
        fast = move_agents(**kwargs)
        slow = move_agents_literal(**kwargs)
        assert torch.equal(fast.positions, slow.positions)
        assert torch.equal(fast.crashed_wall, slow.crashed_wall)
        assert torch.equal(fast.reached, slow.reached)
        assert torch.equal(fast.blocked, slow.blocked)
        counts["crashed_agent"] += int(fast.crashed_agent.sum())
        counts["crashed_wall"] += int(fast.crashed_wall.sum())
        counts["reached"] += int(fast.reached.sum())
        env.positions, env.active = fast.positions, env.active & ~fast.reached
    assert counts["crashed_agent"] > 20 and counts["crashed_wall"] > 20 and counts["reached"] > 5


# ---------------------------------------------------------------- the sequential rule (the paper's reading)


def _sequential(positions, velocities, priority=None, geometry=None):
    positions, velocities = torch.tensor([positions]), torch.tensor([velocities])
    num_agents = positions.shape[1]
    return move_agents_sequential(
        positions=positions,
        velocities=velocities,
        active=torch.ones(1, num_agents, dtype=torch.bool),
        motion=Motion(geometry or paper_room().geometry(), 0.4, 1.0, 7),
        priority=torch.tensor([priority if priority is not None else list(range(num_agents))], dtype=torch.float32),
    )


@pytest.mark.parametrize("priority", [[0, 1], [1, 0]])
def test_a_leader_caught_by_a_faster_follower_keeps_walking(priority):
    """The follower's move would enter the leader's body: only the follower stops, whatever the order."""
    movement = _sequential([[10.0, 50.0], [10.0, 49.0]], [[0.0, 1.0], [0.0, 2.5]], priority)
    assert movement.blocked.tolist() == [[False, True]]
    assert movement.crashed_agent.tolist() == [[False, True]]
    torch.testing.assert_close(movement.positions[0, 0], torch.tensor([10.0, 51.0]))
    assert (movement.positions[0, 0] - movement.positions[0, 1]).norm() >= 0.8


@pytest.mark.parametrize("rule", ["sequential", "simultaneous"])
def test_two_agents_below_the_door_heading_for_its_centre(rule):
    """Simultaneously both stop at every decision and stay frozen for ever; sequentially both leave."""
    geometry = paper_room().geometry()
    positions = torch.tensor([[[29.5, 97.0], [30.5, 97.0]]])
    active = torch.ones(1, 2, dtype=torch.bool)
    reached = torch.zeros_like(active)
    generator = torch.Generator().manual_seed(0)
    for _ in range(10):
        to_door = geometry.exit_goals[0] - positions
        velocities = 2.5 * to_door / to_door.norm(dim=-1, keepdim=True)
        kwargs = dict(
            positions=positions,
            velocities=velocities,
            active=active,
            motion=Motion(geometry, 0.4, 1.0, 7),
        )
        if rule == "sequential":
            movement = move_agents_sequential(**kwargs, priority=torch.rand(1, 2, generator=generator))
        else:
            movement = move_agents(**kwargs)
        positions, reached, active = movement.positions, reached | movement.reached, active & ~movement.reached
    assert reached.tolist() == ([[True, True]] if rule == "sequential" else [[False, False]])


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    num_replicas=st.integers(1, 3),
    num_agents=st.integers(1, 30),
    room=st.sampled_from([(4.0, 5.0, 0.9), (8.0, 10.0, 1.5), (60.0, 100.0, 2.0)]),
)
def test_move_agents_sequential_equals_the_literal_agent_by_agent_loop(seed, num_replicas, num_agents, room):
    width, length, door_width = room
    num_agents = min(num_agents, _cap(width, length))
    env = paper_room(width=width, length=length, door_width=door_width).room(
        num_replicas=num_replicas, num_agents=num_agents
    )
    env.reset(seed=seed)
    generator = torch.Generator().manual_seed(seed)
    shape = (num_replicas, num_agents)
    for _ in range(8):
        speeds = torch.where(torch.rand(shape, generator=generator) < 0.2, 0.0, env.params.max_speed)
        goal_x, goal_y = env.geometry.exit_goals[0].tolist()
        to_door = torch.atan2(goal_y - env.positions[..., 1], goal_x - env.positions[..., 0])
        headings = to_door + 0.8 * torch.randn(shape, generator=generator)
        kwargs = motion(env, velocities_from(speeds=speeds, headings=headings))
        kwargs["priority"] = torch.rand(shape, generator=generator)
        fast = move_agents_sequential(**kwargs, compiled=False)
        slow = move_agents_sequential_literal(**kwargs)
        bounded = move_agents_sequential(**kwargs, sync_free=True)  # the CUDA path: fixed rounds, no host reads
        compiled = move_agents_sequential(**kwargs, compiled=True)  # the CPU default: the numba kernel
        for field in ("positions", "blocked", "crashed_wall", "crashed_agent", "reached"):
            assert torch.equal(getattr(fast, field), getattr(slow, field)), field
            assert torch.equal(getattr(bounded, field), getattr(slow, field)), field
            assert torch.equal(getattr(compiled, field), getattr(slow, field)), field
        # no two bodies in the room overlap afterwards
        inside = env.active & ~fast.reached
        gaps = fast.positions.unsqueeze(2) - fast.positions.unsqueeze(1)
        close = (gaps * gaps).sum(-1) < (2 * env.params.agent_radius) ** 2 - 1e-4
        close &= inside.unsqueeze(1) & inside.unsqueeze(2) & ~torch.eye(num_agents, dtype=torch.bool)
        assert not close.any()
        env.positions, env.active = fast.positions, env.active & ~fast.reached


@pytest.mark.parametrize("seed", range(3))
def test_compiled_rule_equals_the_torch_rule_with_slanted_walls_and_two_exits(seed, tmp_path):
    """A hexagonal room (slanted walls: the kernel takes torch's wall tests) with two exits and a crowd heading
    for them: the compiled kernel and the torch code give the same movement to the bit, decision after decision."""
    from pedrl.scenarios import custom

    wkt = tmp_path / "hexagon.wkt"
    wkt.write_text("POLYGON ((4 0, 12 0, 16 6, 12 12, 4 12, 0 6, 4 0))")
    scenario = custom(geometry=wkt, exits=[[6, 12, 9, 12], [6, 0, 9, 0]])
    env = scenario.room(num_replicas=3, num_agents=25)
    env.reset(seed=seed)
    assert not env.geometry.axis_aligned
    generator = torch.Generator().manual_seed(seed)
    shape = (3, 25)
    compared = events = 0
    for _ in range(12):
        targets = env.targets()
        to_exit = torch.atan2(targets[..., 1] - env.positions[..., 1], targets[..., 0] - env.positions[..., 0])
        headings = to_exit + 0.6 * torch.randn(shape, generator=generator)
        kwargs = motion(env, velocities_from(speeds=torch.full(shape, env.params.max_speed), headings=headings))
        kwargs["priority"] = torch.rand(shape, generator=generator)
        eager = move_agents_sequential(**kwargs, compiled=False)
        compiled = move_agents_sequential(**kwargs, compiled=True)
        for field in ("positions", "blocked", "crashed_wall", "crashed_agent", "reached"):
            assert torch.equal(getattr(eager, field), getattr(compiled, field)), field
        compared += 1
        events += int(eager.crashed_wall.sum() + eager.crashed_agent.sum() + eager.reached.sum())
        env.positions, env.active = eager.positions, env.active & ~eager.reached
    assert compared == 12 and events > 0


def test_the_literal_rules_use_the_room_exits_beyond_the_paper_room(tmp_path):
    """A hexagon with an exit in its top and one in its bottom wall: the literal specifications take the room's own
    exit test (not the paper room's ``y >= length``), so both rules equal them to the bit, and crowds leave through
    both exits."""
    from pedrl.scenarios import custom

    wkt = tmp_path / "hexagon.wkt"
    wkt.write_text("POLYGON ((4 0, 12 0, 16 6, 12 12, 4 12, 0 6, 4 0))")
    env = custom(geometry=wkt, exits=[[6, 12, 9, 12], [6, 0, 9, 0]]).room(num_replicas=2, num_agents=16)
    env.reset(seed=5)
    generator = torch.Generator().manual_seed(5)
    shape = (2, 16)
    out_top = out_bottom = 0
    for _ in range(10):
        targets = env.targets()
        to_exit = torch.atan2(targets[..., 1] - env.positions[..., 1], targets[..., 0] - env.positions[..., 0])
        headings = to_exit + 0.3 * torch.randn(shape, generator=generator)
        kwargs = motion(env, velocities_from(speeds=torch.full(shape, env.params.max_speed), headings=headings))
        fast, slow = move_agents(**kwargs), move_agents_literal(**kwargs)
        for field in ("positions", "blocked", "crashed_wall", "reached"):
            assert torch.equal(getattr(fast, field), getattr(slow, field)), field
        kwargs["priority"] = torch.rand(shape, generator=generator)
        sequential = move_agents_sequential(**kwargs, compiled=False)
        literal = move_agents_sequential_literal(**kwargs)
        for field in ("positions", "blocked", "crashed_wall", "crashed_agent", "reached"):
            assert torch.equal(getattr(sequential, field), getattr(literal, field)), field
        out_top += int((sequential.reached & (sequential.positions[..., 1] >= 12.0)).sum())
        out_bottom += int((sequential.reached & (sequential.positions[..., 1] <= 0.0)).sum())
        env.positions, env.active = sequential.positions, env.active & ~sequential.reached
    assert out_top > 0 and out_bottom > 0, (out_top, out_bottom)

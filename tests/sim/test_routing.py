"""Exit choice and each walker's own route (:mod:`pedrl.sim.routing`): the nearest exit by route length, not by the
straight line, and, with ``queue_weight``, the exit of least time with the queue weighed."""

import math

import pytest
import torch

from pedrl.scenarios import custom
from pedrl.sim.controllers import GreedyDoorController
from pedrl.sim.motion import Yield
from pedrl.sim.routing import SPECIFIC_FLOW, choose_exits, sight

# A 20 m x 12 m room split by a partition from the bottom wall up to 11 m at x = 10. Exit 0 (right of the
# partition, at its foot) is the nearest in a straight line from the start area (left of the partition, low); exit 1
# (top of the left wall) is in sight and nearer by the route: 8 m against about 25 m round the partition's end.
BEHIND_PARTITION = {
    "geometry": "POLYGON ((0 0, 9.9 0, 9.9 11, 10.1 11, 10.1 0, 20 0, 20 12, 0 12, 0 0))",
    "exits": [[10.1, 0.0, 12.1, 0.0], [0.0, 10.0, 0.0, 11.6]],
    "spawn": [[6.0, 0.5, 9.4, 3.0]],
}
# A 20 m x 8 m hall with a 1 m exit at each end: every start (the left quarter) is nearest to the left one.
TWO_ENDS = {
    "geometry": "POLYGON ((0 0, 20 0, 20 8, 0 8, 0 0))",
    "exits": [[0.0, 3.5, 0.0, 4.5], [20.0, 3.5, 20.0, 4.5]],
    "spawn": [[0.5, 0.5, 5.0, 7.5]],
}
PEDESTRIAN = {"agent_radius": 0.2, "max_speed": 1.34, "motion": Yield(order="door_first")}
GOAL = {
    "action_frame": "goal",
    "speed_ratios": [0.0, 0.2, 0.4, 0.6, 0.7, 0.8, 0.9, 0.95, 1.0],
    "turn_ratios": [-0.5, -0.25, -0.1, -0.05, 0.0, 0.05, 0.1, 0.25, 0.5],
}


def room(settings, *, agents, replicas=1, **kwargs):
    env = custom(**settings).room(num_replicas=replicas, num_agents=agents, device="cpu", **PEDESTRIAN | kwargs)
    env.reset(seed=3)
    return env


def test_the_nearest_exit_is_the_nearest_by_route_not_by_the_straight_line():
    env = room(BEHIND_PARTITION, agents=12)
    straight = env.geometry.nearest_exits(env.positions)
    assert bool((straight == 0).all())  # the control: the straight line picks the exit behind the partition
    assert bool((env.exit_index == 1).all()) and bool((env.spawns.route_length == 0).all())  # in sight: no corner


def test_without_routes_every_walker_takes_the_straight_line_nearest_exit():
    env = room(TWO_ENDS, agents=30, replicas=2)
    assert env.geometry.routes is None
    assert torch.equal(env.exit_index, env.geometry.nearest_exits(env.positions))


def test_weighing_the_queue_sends_the_walkers_furthest_back_to_the_far_exit():
    """Without the queue all 60 walkers crowd the left exit; with it, those whose wait behind the others would exceed
    the walk to the right exit (about 15 m, 11 s, at 1.3 /s through 1 m: 15 walkers) take the right one, and they are
    the ones nearest to it."""
    plain = room(TWO_ENDS, agents=60)
    assert bool((plain.exit_index == 0).all())
    weighed = room(TWO_ENDS, agents=60, queue_weight=1.0)
    right = weighed.exit_index[0] == 1
    assert 0.1 <= float(right.float().mean()) <= 0.5
    x = weighed.positions[0, :, 0]
    assert float(x[right].min()) > float(x[~right].median())  # the far ones go right


def test_the_queue_leaves_assigned_exits_alone_and_is_settled_to_a_best_answer():
    """Agents with an assigned exit keep it; every free agent's exit is its least time given the others' final
    choices, up to the one-walker granularity of the queue (fictitious play settles, it does not cycle)."""
    generator = torch.Generator().manual_seed(0)
    lengths = torch.rand(2, 50, 3, generator=generator) * 20.0
    assigned = torch.full((2, 50), -1)
    assigned[:, :10] = 2
    widths = torch.tensor([1.0, 1.0, 2.0])
    exits = choose_exits(lengths, assigned, widths, max_speed=1.0, queue_weight=1.0)
    assert bool((exits[:, :10] == 2).all())
    index = torch.arange(50)
    earlier = index[None, :] < index[:, None]
    chosen = torch.nn.functional.one_hot(exits, 3).float()  # (R, N, E)
    mine, theirs = lengths.unsqueeze(2), lengths.unsqueeze(1)
    ahead = ((theirs < mine) | ((theirs == mine) & earlier[None, :, :, None])).float()
    times = lengths + torch.einsum("rije,rje->rie", ahead, chosen) / (SPECIFIC_FLOW * widths)
    own = times.gather(-1, exits.unsqueeze(-1)).squeeze(-1)
    slack = 1.0 / (SPECIFIC_FLOW * widths.min())  # one walker more or less in a queue
    assert bool((own[:, 10:] <= times[:, 10:].min(-1).values + slack).all())
    assert torch.equal(exits, choose_exits(lengths, assigned, widths, max_speed=1.0, queue_weight=1.0))


def test_weighing_the_queue_empties_the_hall_sooner():
    """Greedy walkers (epsilon 0) leave the two-ended hall sooner when they weigh the queue: measured, 34 s without
    and 27 s with queue_weight 0.5 (this walker drains a 1 m exit at about 1.8 /s, more than the 1.3 /s the queue is
    reckoned at, so 0.5 weighs it about right; at 1.0 too many walk to the far exit, 32 s)."""
    times = {}
    for weight in (0.0, 0.5):
        env = room(TWO_ENDS, agents=60, queue_weight=weight, max_decisions=200, **GOAL)
        controller = GreedyDoorController(epsilon=0.0, generator=torch.Generator().manual_seed(0))
        obs, info = env.reset(seed=3)
        steps = 0
        while bool(env.active.any()):
            obs, _, _, _, info = env.step(controller.act(env, obs, info))
            steps += 1
        times[weight] = steps
    assert times[0.5] < 0.85 * times[0.0]


def test_a_line_of_sight_is_blocked_by_a_wall_and_by_a_corner_it_grazes():
    walls = torch.tensor([[[5.0, 0.0], [5.0, 5.0]]])
    corners = torch.tensor([[5.0, 5.0]])
    points = torch.tensor([[[0.0, 1.0], [0.0, 5.1], [0.0, 6.0]]])
    target = torch.tensor([[10.0, 1.0]]), torch.tensor([[10.0, 5.1]]), torch.tensor([[10.0, 6.0]])
    seen = [bool(sight(points[:, k : k + 1], target[k], walls, corners)) for k in range(3)]
    assert seen == [False, False, True]  # through the wall; 0.1 m past its end; 1 m past it
    assert bool(sight(points[:, 1:2], target[1], walls, None))  # without the corner test, 0.1 m past the end is seen


@pytest.mark.parametrize("value", [-1.0, math.nan, math.inf, 1e9, "heavy"])
def test_a_bad_queue_weight_is_refused_in_one_line(value):
    with pytest.raises((ValueError, TypeError)) as error:
        room(TWO_ENDS, agents=4, queue_weight=value)
    assert "queue_weight" in str(error.value) and "\n" not in str(error.value)

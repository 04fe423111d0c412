"""The policy files shipped with pedrl (``pedrl.pretrained``): they load, act in their own rooms, and walk a crowd out
far faster than the same files with their tables zeroed (the control)."""

import pytest
import torch

import pedrl
from pedrl.policy_files import PRETRAINED
from pedrl.trial.crowd import run_crowd


@pytest.mark.parametrize("name", sorted(PRETRAINED))
def test_a_shipped_policy_is_small_loads_and_walks_a_crowd_out(name):
    path = pedrl.pretrained(name)
    assert path.is_file() and path.stat().st_size < 3 * 2**20, path
    policy = pedrl.load_policy(path)
    assert policy.num_processes == 1 and policy.metadata["config"]["seed"] == 0
    room = pedrl.room_factory(policy)(num_replicas=4, num_agents=20)
    room.reset(seed=100)
    learned = run_crowd(room, policy.controller(generator=torch.Generator().manual_seed(0)), fused=None).stats
    zeroed = pedrl.TabularPolicy(policy.encoder, torch.zeros_like(policy.q_values), metadata=policy.metadata)
    room.reset(seed=100)
    control = run_crowd(room, zeroed.controller(generator=torch.Generator().manual_seed(0)), fused=None).stats
    assert float(learned.success_rate.mean()) >= 0.9
    # zeroed tables pick among tied actions at random: the goal frame still drifts them out, twice as slowly
    assert float(learned.evacuation_time.mean()) < 0.7 * float(control.evacuation_time.mean())


def test_an_unknown_shipped_policy_is_refused_in_one_line():
    with pytest.raises(ValueError, match="name='mian' is invalid: must be one of main, pedestrian_walk"):
        pedrl.pretrained("mian")

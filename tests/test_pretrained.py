"""The policy files shipped with pedrl (``pedrl.pretrained``): they load, act in their own rooms, and walk a crowd out
far faster than the same files with their tables zeroed (the control)."""

import pytest
import torch

import pedrl
from pedrl.policy_files import PRETRAINED
from pedrl.trial.crowd import run_crowd


def blank(policy):
    """The control: the same policy with its values zeroed (a table's rows, a network's last layer)."""
    if isinstance(policy, pedrl.TabularPolicy):
        return pedrl.TabularPolicy(policy.encoder, torch.zeros_like(policy.q_values), metadata=policy.metadata)
    network = policy.network.twin()
    network.load_state_dict(policy.network.state_dict())
    with torch.no_grad():
        network.weights[-1].zero_()
        network.biases[-1].zero_()
    return pedrl.NeuralPolicy(policy.encoder, network, policy.mean, policy.std, metadata=policy.metadata)


@pytest.mark.parametrize("name", sorted(PRETRAINED))
def test_a_shipped_policy_is_small_loads_and_walks_a_crowd_out(name):
    path = pedrl.pretrained(name)
    assert path.is_file() and path.stat().st_size < 3 * 2**20, path
    policy = pedrl.load_policy(path)
    assert policy.num_processes == 1 and policy.metadata["config"]["seed"] == 0
    room = pedrl.room_factory(policy)(num_replicas=4, num_agents=20)
    room.reset(seed=100)
    learned = run_crowd(room, policy.controller(generator=torch.Generator().manual_seed(0)), fused=None).stats
    zeroed = blank(policy)
    room.reset(seed=100)
    control = run_crowd(room, zeroed.controller(generator=torch.Generator().manual_seed(0)), fused=None).stats
    assert float(learned.success_rate.mean()) >= 0.9
    # zeroed tables pick among tied actions at random: the goal frame still drifts them out, twice as slowly (a
    # zeroed network takes action 0 and stands)
    assert float(learned.evacuation_time.mean()) < 0.7 * float(control.evacuation_time.mean())


def test_an_unknown_shipped_policy_is_refused_in_one_line():
    with pytest.raises(ValueError, match="name='mian' is invalid: must be one of main, pedestrian_walk, pedestrian_f"):
        pedrl.pretrained("mian")


def test_the_shipped_network_has_its_onnx_model_and_contract_beside_it():
    onnxruntime = pytest.importorskip("onnxruntime")
    path = pedrl.pretrained("pedestrian_free")
    model, contract = path.with_suffix(".onnx"), path.with_suffix(".onnx.json")
    assert model.is_file() and contract.is_file()
    policy = pedrl.load_policy(path)
    room = pedrl.room_factory(policy)(num_replicas=2, num_agents=20)
    obs, info = room.reset(seed=3)
    flat, sensed = obs.reshape(-1, obs.shape[-1]), info["num_sensed"].reshape(-1)
    q_values, action = onnxruntime.InferenceSession(str(model)).run(
        None, {"obs": flat.numpy(), "num_sensed": sensed.numpy()}
    )
    expected = policy.values(policy.inputs(flat, sensed, 0), torch.zeros(flat.shape[0], dtype=torch.int64))
    torch.testing.assert_close(torch.from_numpy(q_values), expected, atol=1e-4, rtol=1e-4)
    assert bool((torch.from_numpy(action) == expected.argmax(1)).all())

"""The policy files shipped with pedrl (``pedrl.pretrained``): they load, act in their own rooms, and walk a crowd out
far faster than the same files with their tables zeroed (the control)."""

import pytest
import torch
from omegaconf import OmegaConf

import pedrl
from pedrl.configs import HISTORICAL_VALUES
from pedrl.io import load_checkpoint
from pedrl.policy_files import PRETRAINED
from pedrl.rl import ContinuousPolicy
from pedrl.trial.crowd import run_crowd
from tests.conftest import compose_config


def blank(policy):
    """The control: the same policy with its values zeroed (a table's rows, a network's last layer; a continuous
    network's last layer set to command standing)."""
    if isinstance(policy, pedrl.TabularPolicy):
        return pedrl.TabularPolicy(policy.encoder, torch.zeros_like(policy.q_values), metadata=policy.metadata)
    network = policy.network.twin()
    network.load_state_dict(policy.network.state_dict())
    with torch.no_grad():
        network.weights[-1].zero_()
        network.biases[-1].zero_()
        if isinstance(policy, ContinuousPolicy):
            network.biases[-1][..., 0] = -3.0  # a speed ratio below 0: standing, as a zeroed Q-network's action 0
    return type(policy)(policy.encoder, network, policy.mean, policy.std, metadata=policy.metadata,
                        neighbour_velocity=policy.neighbour_velocity)  # fmt: skip


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


@pytest.mark.parametrize("name", ["pedestrian_free", "main_ppo", "pedestrian_walk_ppo"])
def test_a_shipped_network_has_its_onnx_model_and_contract_beside_it(name):
    onnxruntime = pytest.importorskip("onnxruntime")
    path = pedrl.pretrained(name)
    model, contract = path.with_suffix(".onnx"), path.with_suffix(".onnx.json")
    assert model.is_file() and contract.is_file()
    policy = pedrl.load_policy(path)
    room = pedrl.room_factory(policy)(num_replicas=2, num_agents=20)
    obs, info = room.reset(seed=3)
    flat, sensed = obs.reshape(-1, obs.shape[-1]), info["num_sensed"].reshape(-1)
    feeds = {"obs": flat.numpy(), "num_sensed": sensed.numpy()}
    if policy.neighbour_velocity:
        feeds["neighbour_velocity"] = info["neighbour_velocity"].reshape(flat.shape[0], -1, 2).numpy()
    values, chosen = onnxruntime.InferenceSession(str(model)).run(None, feeds)
    expected = policy.values(policy.info_inputs(obs, info), torch.zeros(flat.shape[0], dtype=torch.int64))
    torch.testing.assert_close(torch.from_numpy(values), expected, atol=1e-4, rtol=1e-4)
    acted = policy.act(obs, info).reshape(flat.shape[0], -1).squeeze(1)  # actions (B,), or commands (B, 2)
    torch.testing.assert_close(torch.from_numpy(chosen), acted, atol=1e-4, rtol=0)


def _leaves(config: dict, prefix: str = "") -> set[str]:
    """The dotted keys of ``config``'s env, algo and vq settings (a room's own description left whole)."""
    keys = set()
    for key, value in config.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict) and prefix.count(".") < 2:
            keys |= _leaves(value, f"{name}.")
        elif name.split(".")[0] in ("env", "algo", "vq"):
            keys.add(name)
    return keys


@pytest.mark.parametrize("name", sorted(PRETRAINED))
def test_every_key_added_since_a_shipped_policy_was_trained_has_the_value_of_its_time(name):
    """A key of today's config that a shipped file's stored config lacks must be in HISTORICAL_VALUES: else resuming
    or comparing such a file reads the key as absent (resume refuses it) or as today's default. The control: a key
    added after a shipped file (env.reward_deviation, taken out of its stored config) is found."""
    stored = load_checkpoint(pedrl.pretrained(name)).metadata["config"]
    algo = {"DQN": "dqn", "PPO": "ppo"}.get(stored["algo"]["_target_"].rsplit(".", 1)[-1], "it_vqql")
    today = _leaves(OmegaConf.to_container(compose_config("train", [f"algo={algo}"]), resolve=True))

    def added(config: dict) -> set[str]:
        return {key for key in today - _leaves(config) if not key.startswith("env.motion.")}

    assert added(stored) <= set(HISTORICAL_VALUES), sorted(added(stored) - set(HISTORICAL_VALUES))
    # the control: a key the file's config lacks is found (a file trained before env.reward_deviation lacks it)
    older = {**stored, "env": {key: value for key, value in stored["env"].items() if key != "reward_deviation"}}
    assert "env.reward_deviation" in added(older)

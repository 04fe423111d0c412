"""pedrl-export out=<name>.onnx: a network of algo=dqn that onnxruntime runs as pedrl does, with its contract."""

import json

import pytest
import torch

from pedrl.export import export
from pedrl.policy_files import load_policy, room_factory
from pedrl.rl.neural import squash
from pedrl.train import train
from tests.conftest import compose_config

onnxruntime = pytest.importorskip("onnxruntime")

PPO_GOAL = ("env.action_frame=goal", "env.speed_ratios=[0.0,0.2,0.4,0.6,0.7,0.8,0.9,0.95,1.0]",
            "env.turn_ratios=[-0.5,-0.25,-0.1,-0.05,0.0,0.05,0.1,0.25,0.5]")  # fmt: skip


def train_dqn(tmp_path_factory, *overrides: str, algo: str = "dqn"):
    run = tmp_path_factory.mktemp(algo)
    cfg = compose_config("train", ["debug=default", f"algo={algo}", "algo.trials=4", "algo.iterations=1", "logger=none",
                                   "threads=1", "progress=false", *overrides])  # fmt: skip
    train(cfg, run_dir=run)
    return run / "checkpoints" / "last.safetensors"


@pytest.fixture(scope="module")
def dqn_checkpoint(tmp_path_factory):
    return train_dqn(tmp_path_factory)


@pytest.fixture(scope="module")
def branching_checkpoint(tmp_path_factory):
    return train_dqn(tmp_path_factory, "algo.head=branching")


def _export(checkpoint, out, *overrides):
    return export(compose_config("export", [f"checkpoint={checkpoint}", f"out={out}", *overrides]))


@pytest.fixture(scope="module")
def velocity_checkpoint(tmp_path_factory):
    return train_dqn(tmp_path_factory, "algo.neighbour_velocity=true")


@pytest.fixture(scope="module")
def ppo_checkpoint(tmp_path_factory):
    return train_dqn(tmp_path_factory, algo="ppo")


@pytest.mark.parametrize("head", ["dqn_checkpoint", "branching_checkpoint", "velocity_checkpoint", "ppo_checkpoint"])
def test_onnx_round_trip_gives_pedrls_values_and_actions(head, request, tmp_path):
    dqn_checkpoint = request.getfixturevalue(head)
    path = _export(dqn_checkpoint, tmp_path / "policy.onnx", "process=1")
    policy = load_policy(dqn_checkpoint)
    room = room_factory(policy)(num_replicas=3, num_agents=20)
    obs, info = room.reset(seed=4)
    for _ in range(3):  # a crowd in motion, some slots empty
        obs, _, _, _, info = room.step(policy.act(obs, info, generator=torch.Generator().manual_seed(0)))
    flat, sensed = obs.reshape(-1, obs.shape[-1]), info["num_sensed"].reshape(-1)
    session = onnxruntime.InferenceSession(str(path))
    feeds = {"obs": flat.numpy(), "num_sensed": sensed.numpy()}
    if policy.neighbour_velocity:
        feeds["neighbour_velocity"] = info["neighbour_velocity"].reshape(flat.shape[0], -1, 2).numpy()
    assert [i.name for i in session.get_inputs()] == list(feeds)
    q_values, action = session.run(None, feeds)
    expected = policy.values(policy.info_inputs(obs, info), torch.ones(flat.shape[0], dtype=torch.int64))
    inside = room.active.reshape(-1)
    torch.testing.assert_close(torch.from_numpy(q_values)[inside], expected[inside], atol=1e-4, rtol=1e-4)
    assert (torch.from_numpy(action)[inside] == expected[inside].argmax(1)).float().mean() > 0.99
    assert sorted(p.name for p in tmp_path.iterdir()) == ["policy.onnx", "policy.onnx.json"]  # the weights inside
    contract = json.loads((tmp_path / "policy.onnx.json").read_text())
    assert contract["inputs"]["obs"]["shape"] == ["batch", room.num_features] and contract["process"] == 1
    assert list(contract["inputs"]) == list(feeds)
    assert contract["observation"]["features"][0] == room.feature_names[0]
    assert len(contract["actions"]["speed"]) * len(contract["actions"]["turn"]) == contract["actions"]["count"] == 81
    meaning = "the actor's logits" if head == "ppo_checkpoint" else "Q-values"
    assert contract["outputs"]["q_values"]["meaning"] == meaning and contract["algo"] == policy.metadata["algo"]


@pytest.fixture(scope="module")
def continuous_checkpoint(tmp_path_factory):
    return train_dqn(tmp_path_factory, *PPO_GOAL, "algo.actions=continuous", algo="ppo")


@pytest.fixture(scope="module")
def company_checkpoint(tmp_path_factory):
    return train_dqn(tmp_path_factory, *PPO_GOAL, "algo.actions=continuous", "algo.company_heading=added", algo="ppo")


@pytest.mark.parametrize("head", ["continuous_checkpoint", "company_checkpoint"])
def test_onnx_round_trip_of_a_continuous_policy_gives_its_means_and_commands(head, request, tmp_path):
    """PPO's continuous head: the model's means are the actor's and its commands what the policy commands (1e-4)."""
    continuous_checkpoint = request.getfixturevalue(head)
    path = _export(continuous_checkpoint, tmp_path / "policy.onnx")
    policy = load_policy(continuous_checkpoint)
    room = room_factory(policy)(num_replicas=3, num_agents=20)
    obs, info = room.reset(seed=4)
    for _ in range(3):
        obs, _, _, _, info = room.step(policy.act(obs, info))
    flat, sensed = obs.reshape(-1, obs.shape[-1]), info["num_sensed"].reshape(-1)
    session = onnxruntime.InferenceSession(str(path))
    assert [o.name for o in session.get_outputs()] == ["means", "command"]
    means, command = session.run(None, {"obs": flat.numpy(), "num_sensed": sensed.numpy()})
    expected = policy.values(policy.info_inputs(obs, info), torch.zeros(flat.shape[0], dtype=torch.int64))
    inside = room.active.reshape(-1)
    assert int(inside.sum()) > 20
    torch.testing.assert_close(torch.from_numpy(means)[inside], expected[inside], atol=1e-4, rtol=1e-4)
    acted = policy.act(obs, info)[0]  # replica 0 acts with process 0's network, the exported one
    torch.testing.assert_close(torch.from_numpy(command)[: room.num_agents], acted, atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(torch.from_numpy(command)[inside], squash(expected)[inside], atol=1e-4, rtol=1e-4)
    contract = json.loads((tmp_path / "policy.onnx.json").read_text())
    assert list(contract["outputs"]) == ["means", "command"] and contract["actions"]["kind"] == "continuous"
    assert contract["actions"]["frame"] == "goal" and contract["algo"] == "ppo"


def test_onnx_of_a_company_heading_drops_its_term_where_nobody_is_sensed(company_checkpoint, tmp_path):
    """The model's means are the policy's, read in company and as lone walkers (no neighbour sensed): the network's
    three outputs give the speed, and the heading alone plus the company term only where someone is sensed."""
    path = _export(company_checkpoint, tmp_path / "policy.onnx")
    policy = load_policy(company_checkpoint)
    room = room_factory(policy)(num_replicas=1, num_agents=20)
    obs, info = room.reset(seed=4)
    flat = obs.reshape(-1, obs.shape[-1])
    session = onnxruntime.InferenceSession(str(path))
    for sensed in (info["num_sensed"].reshape(-1), torch.zeros(20, dtype=torch.int64)):
        means, _ = session.run(None, {"obs": flat.numpy(), "num_sensed": sensed.numpy()})
        inputs = policy.inputs(flat, sensed, 0)
        expected = policy.values(inputs, torch.zeros(20, dtype=torch.int64))
        torch.testing.assert_close(torch.from_numpy(means), expected, atol=1e-4, rtol=1e-4)
        with torch.no_grad():
            raw = policy.network(inputs.expand(policy.num_processes, -1, -1))[0]  # process 0's (20, 3)
        company = (sensed > 0).float()
        assert bool(sensed.max() == 0) or bool(company.all())
        torch.testing.assert_close(expected, torch.stack((raw[:, 0], raw[:, 1] + company * raw[:, 2]), 1))
        assert bool(raw[:, 2].abs().min() > 1e-6)  # a term that acts where it is read


def test_a_model_of_one_process_of_several_says_whose_replicas_it_agrees_with(dqn_checkpoint, tmp_path):
    # pedrl's crowd acts with network i mod P in replica i; a model of process 0 disagrees with the others' replicas
    from pedrl.export import written

    processes = load_policy(dqn_checkpoint).num_processes
    assert processes == 2  # debug=default
    path = _export(dqn_checkpoint, tmp_path / "p.onnx")
    lines = written(path, str(dqn_checkpoint))
    assert lines[0].startswith(f"pedrl-export: wrote {path} (")
    assert lines[1] == (
        "pedrl-export: p.onnx holds the network of process 0 of 2: pedrl's crowd acts with network i mod 2 in replica"
        " i, so this model agrees with the replicas of process 0 only (process=<index> writes another)"
    )
    assert json.loads((tmp_path / "p.onnx.json").read_text())["processes"] == processes
    policy_file = _export(dqn_checkpoint, tmp_path / "p.safetensors")
    assert len(written(policy_file, str(dqn_checkpoint))) == 1  # a policy file holds every process: nothing to say


def test_a_tables_checkpoint_is_refused_for_onnx_in_one_line(tmp_path):
    cfg = compose_config("train", ["debug=default", "algo=vqql", "algo.trials=2", "algo.iterations=1",
                                   "logger=none", "threads=1", "progress=false"])  # fmt: skip
    train(cfg, run_dir=tmp_path)
    with pytest.raises(ValueError, match="ONNX export writes a network \\(algo=dqn\\)") as err:
        _export(tmp_path / "checkpoints" / "last.safetensors", tmp_path / "p.onnx")
    assert "\n" not in str(err.value) and not (tmp_path / "p.onnx").exists()


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["process=5"], "process=5 is invalid: must be an integer in \\[0, 1\\]"),
        (["processes=1"], "processes=1 is invalid with out=<name>.onnx: pass process=<index>"),
    ],
)
def test_bad_onnx_settings_are_one_line_and_write_nothing(dqn_checkpoint, tmp_path, overrides, message):
    with pytest.raises(ValueError, match=message):
        _export(dqn_checkpoint, tmp_path / "p.onnx", *overrides)
    assert not (tmp_path / "p.onnx").exists()


def test_a_network_exports_to_a_policy_file_that_acts_as_the_checkpoint(dqn_checkpoint, tmp_path):
    path = _export(dqn_checkpoint, tmp_path / "policy.safetensors", "processes=1")
    exported, original = load_policy(path), load_policy(dqn_checkpoint)
    assert exported.num_processes == 1 and exported.metadata["algo"] == "dqn"
    room = room_factory(exported)(num_replicas=1, num_agents=10)
    obs, info = room.reset(seed=1)
    assert torch.equal(exported.act(obs, info), original.act(obs, info))  # replica 0 acts with process 0 in both

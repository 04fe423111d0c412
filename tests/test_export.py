"""pedrl-export and pedrl.load_policy: an exported policy acts as the checkpoint it came from, in pedrl-eval
``policy=`` and in the PettingZoo adapter, and bad input is refused in one line."""

import csv
import dataclasses
import subprocess
import sys
import warnings

import pytest
import torch
from hydra import compose, initialize_config_dir

import pedrl
import pedrl.evaluate
import pedrl.export
from pedrl.cli import CONFIG_DIR
from pedrl.configs import env_factory
from pedrl.configs.motion import FLAT_DEFAULTS
from pedrl.evaluation import evaluate, load_controller
from pedrl.io import CheckpointError
from pedrl.policy_files import room_factory, room_settings
from pedrl.sim.motion import Continuous, Simultaneous, Slide, Steering, Stop, Yield
from tests.refusals import EVAL_BASE, assert_refused, run_hydra_main, train_checkpoint

TINY_IT = (
    "debug=default",
    "algo=it_vqql",  # random void filling: the generator drives exploration, ties and void draws alike
    "algo.num_agents=3",
    "algo.iterations=2",
    "algo.trials=2",
    "vq.num_prototypes=8",
    "env.max_decisions=10",
    "logger=none",
)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A seconds-long IT-VQQL checkpoint (2 processes, one quantizer per process) and its exported policy."""
    checkpoint = train_checkpoint(tmp_path_factory, TINY_IT)
    exported = pedrl.export_policy(checkpoint, checkpoint.parent.parent / "policy.safetensors")
    return checkpoint, exported


def test_the_exported_policy_is_the_checkpoints_encoder_and_tables(trained):
    checkpoint, exported = trained
    original, carried = pedrl.load_policy(checkpoint), pedrl.load_policy(exported)
    assert exported.stat().st_size < checkpoint.stat().st_size  # no generator states
    assert torch.equal(original.q_values, carried.q_values)
    assert carried.encoder.settings == original.encoder.settings
    assert carried.encoder.settings.void_features == "random"
    assert carried.metadata["algo"] == "it_vqql" and carried.metadata["config"] == original.metadata["config"]
    assert isinstance(pedrl.TabularPolicy.load(exported), pedrl.TabularPolicy)
    room = room_factory(carried)(num_replicas=4, num_agents=5)  # more agents and replicas than were learned
    obs, info = room.reset(seed=2)
    for _ in range(5):
        want = original.act(obs, info, epsilon=0.2, generator=torch.Generator().manual_seed(9))
        got = carried.act(obs, info, epsilon=0.2, generator=torch.Generator().manual_seed(9))
        assert torch.equal(want, got)
        obs, *_, info = room.step(want)


def test_pedrl_eval_gives_the_same_numbers_from_the_policy_file(trained, tmp_path):
    checkpoint, exported = trained
    rows = {}
    for key, path in (("checkpoint", checkpoint), ("policy", exported)):
        with initialize_config_dir(version_base="1.3", config_dir=CONFIG_DIR):
            cfg = compose("eval", [*EVAL_BASE, f"{key}={path}", "export.trials=0", "seed=4"])
        evaluate(cfg, run_dir=tmp_path / key)
        with open(tmp_path / key / "scaling.csv") as file:
            rows[key] = list(csv.DictReader(file))
    assert rows["checkpoint"] == rows["policy"] and len(rows["policy"]) == 4  # 2 counts, learned and greedy


def test_a_user_learner_trains_among_the_learned_crowd(trained):
    from pedrl.integrations.pettingzoo import PedestrianParallelEnv

    _, exported = trained
    crowd = pedrl.load_policy(exported)
    factory = room_factory(crowd)
    env = PedestrianParallelEnv(factory(num_replicas=1, num_agents=4), crowd=crowd, learners=1, crowd_epsilon=0.1)
    assert env.possible_agents == ["pedestrian_0"]
    observations, _ = env.reset(seed=5)
    reference = factory(num_replicas=1, num_agents=4)  # the same room, every crowd action by hand
    obs, info = reference.reset(seed=5)
    generator = torch.Generator().manual_seed(5)
    for _ in range(6):
        if not env.agents:
            break
        assert torch.equal(torch.as_tensor(observations["pedestrian_0"]), obs[0, 0])
        actions = crowd.act(obs, info, epsilon=0.1, generator=generator)
        actions[0, 0] = 40  # the user's learner: the no-op
        observations, *_ = env.step({"pedestrian_0": 40})
        obs, *_, info = reference.step(actions)
        assert torch.equal(env.env.positions, reference.positions)  # the crowd walked as the policy acts
    with pytest.raises(ValueError, match="learners=5 is invalid"):
        PedestrianParallelEnv(factory(num_replicas=1, num_agents=4), crowd=crowd, learners=5)


def test_a_training_checkpoint_is_not_a_policy_file_and_back(trained):
    checkpoint, exported = trained
    with pytest.raises(CheckpointError, match="is not an exported policy"):
        pedrl.TabularPolicy.load(checkpoint)
    with pytest.raises(CheckpointError, match="is an exported policy, not a training checkpoint"):
        pedrl.load_policy(exported, kind="checkpoint")


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"device": "banana"}, r"^device='banana' is invalid: must be cpu or cuda"),
        ({"kind": "bogus"}, r"^kind='bogus' is invalid: must be None, 'checkpoint' or 'policy'$"),
    ],
)
def test_load_policy_blames_its_argument_not_the_file(trained, kwargs, message):
    """The Python API speaks as the command lines do: a bad argument is named in one line before the file is read,
    not blamed on the file (device) or raised as a bare KeyError (kind)."""
    with pytest.raises(ValueError, match=message) as refused:
        pedrl.load_policy(trained[1], **kwargs)
    assert "\n" not in str(refused.value) and "policy.safetensors" not in str(refused.value)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: pedrl.load_policy(123), r"^path=123 is invalid: must be a str or os.PathLike naming a \.safetensors"),
        (
            lambda: pedrl.room_factory("nope"),
            r"^policy='nope' is invalid: must be a TabularPolicy or NeuralPolicy, as pedrl.load_policy",
        ),
        (lambda: pedrl.room_factory(None), r"^policy=None is invalid: must be a TabularPolicy"),
    ],
)
def test_the_python_api_refuses_an_argument_of_the_wrong_type_in_one_line(call, message):
    """Not an AttributeError from deep inside (``'str' object has no attribute 'metadata'``) nor os's own message."""
    with pytest.raises(TypeError, match=message) as refused:
        call()
    assert "\n" not in str(refused.value)


@pytest.mark.parametrize(
    ("args", "fragments"),
    [
        (["out=policy.txt"], ("policy.txt' is invalid", ".safetensors")),
        (["out=CHECKPOINT"], ("it is the checkpoint itself",)),
        (["checkpoint=missing.safetensors", "out=p.safetensors"], ("missing.safetensors",)),
        (["checkpoint=POLICY", "out=again.safetensors"], ("is an exported policy, not a training checkpoint",)),
        (["out=p.safetensors", "device=gpu"], ("device='gpu' is invalid",)),
        (["out=p.safetensors", "oot=q.safetensors"], ("oot is not a key of the config",)),
        ([], ("out is missing: pass out=",)),
        (["out=DIR/folder.safetensors"], ("output file", "folder.safetensors' is invalid: it is a folder")),
        (["out=DIR/a_file/p.safetensors"], ("output file", "a_file' is a file, not a folder")),
    ],
)
def test_pedrl_export_refuses_bad_input_in_one_line(args, fragments, trained, tmp_path, capsys):
    checkpoint, exported = trained
    args = [a.replace("CHECKPOINT", str(checkpoint)).replace("POLICY", str(exported)) for a in args]
    if not any(a.startswith("checkpoint=") for a in args):
        args.append(f"checkpoint={checkpoint}")
    args = [a if not a.startswith("out=") or "/" in a else f"out={tmp_path / a[4:]}" for a in args]
    args = [a.replace("DIR", str(tmp_path)) for a in args]
    (tmp_path / "folder.safetensors").mkdir()
    (tmp_path / "a_file").write_text("keep me")
    outcome = run_hydra_main(pedrl.export, args, capsys)
    assert_refused(outcome, "pedrl-export", fragments)
    assert not [path for path in tmp_path.glob("*.safetensors") if path.is_file()], "nothing is written"


def test_a_full_disk_names_the_file_being_written(trained, tmp_path, monkeypatch, capsys):
    """ENOSPC at a write that names no file (as a full disk fails at ``fsync`` or ``close``): the line names the
    file, where it said "cannot use '?'"; the old file is kept whole and no temporary is left."""
    import errno

    import pedrl.io.files

    checkpoint, _ = trained
    out = tmp_path / "policy.safetensors"
    out.write_bytes(b"the old file")

    def full(fd: int) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(pedrl.io.files.os, "fsync", full)
    outcome = run_hydra_main(pedrl.export, [f"checkpoint={checkpoint}", f"out={out}"], capsys)
    assert outcome.lines == [f"pedrl-export: error: cannot write checkpoint {str(out)!r}: No space left on device"]
    assert out.read_bytes() == b"the old file" and sorted(tmp_path.iterdir()) == [out]


def test_a_write_error_naming_no_file_and_no_run_folder_names_the_working_folder(tmp_path, monkeypatch):
    import errno

    from pedrl.cli import OutputDirCheck, describe_os_error

    monkeypatch.setattr(OutputDirCheck, "folder", None)
    monkeypatch.chdir(tmp_path)
    message = describe_os_error(OSError(errno.ENOSPC, "No space left on device"))
    assert message == f"cannot write in {str(tmp_path)!r}: No space left on device"


def test_pedrl_export_and_eval_policy_as_console_scripts(trained, tmp_path):
    checkpoint, _ = trained
    out = tmp_path / "policy.safetensors"
    done = subprocess.run(
        [sys.executable, "-m", "pedrl.export", f"checkpoint={checkpoint}", f"out={out}"],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr
    assert out.is_file() and "pedrl-export: wrote" in done.stdout
    assert sorted(p.name for p in tmp_path.iterdir()) == ["policy.safetensors"], "it writes nothing else"
    refused = subprocess.run(
        [sys.executable, "-m", "pedrl.evaluate", f"checkpoint={out}", f"hydra.run.dir={tmp_path / 'eval'}"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    lines = refused.stderr.strip().splitlines()
    assert refused.returncode == 2 and len(lines) == 1 and "pass it as policy=" in lines[0], refused.stderr


def _rewritten(path, tmp_path, change):
    """A copy of the file at ``path`` with ``change(tensors, metadata)`` applied."""
    import json

    from safetensors import safe_open
    from safetensors.torch import load_file, save_file

    from pedrl.io.checkpoint import METADATA_KEY

    tensors = load_file(str(path))
    with safe_open(str(path), framework="pt") as handle:
        metadata = json.loads(handle.metadata()[METADATA_KEY])
    change(tensors, metadata)
    out = tmp_path / f"changed_{path.name}"
    save_file(tensors, str(out), metadata={METADATA_KEY: json.dumps(metadata)})
    return out


@pytest.mark.parametrize(
    ("which", "change", "message"),
    [
        ("policy", lambda t, m: m.update(policy_version=2), "policy_version=2 is unknown"),
        ("policy", lambda t, m: t.update(evil=torch.zeros(1)), "tensor evil is unknown"),
        ("policy", lambda t, m: m.pop("encoder"), "metadata encoder is missing"),
        ("policy", lambda t, m: m["config"].pop("vq"), "disagrees with its config"),  # no vq: raw distances then
        ("policy", lambda t, m: m["config"].update(vq=None), "vq=None is invalid"),
        ("policy", lambda t, m: m["config"]["algo"].pop("_target_"), "algo._target_=None is invalid"),
        ("checkpoint", lambda t, m: m["config"]["algo"].pop("_target_"), "algo._target_=None is invalid"),
        ("checkpoint", lambda t, m: m["encoder"].update(num_walls=1), "disagrees with its config"),
        # a stored config that contradicts the tensors (it loaded and acted): its K against the quantizer's
        ("policy", lambda t, m: m["config"]["vq"].update(num_prototypes=2), "vq.num_prototypes=2 disagrees with its"),
        ("checkpoint", lambda t, m: m["config"]["vq"].update(num_prototypes=2), "must hold at most 2"),
        ("policy", lambda t, m: m["config"]["vq"].update(factors={"own": {"num_prototypes": 4}}), "vq.factors"),
    ],
)
def test_both_kinds_of_file_are_checked_alike_in_one_line(trained, tmp_path, which, change, message):
    path = _rewritten(dict(zip(("checkpoint", "policy"), trained, strict=True))[which], tmp_path, change)
    with pytest.raises(CheckpointError, match=message) as error:
        pedrl.load_policy(path)
    assert "\n" not in str(error.value) and str(path) in str(error.value)


def test_a_config_that_allows_more_prototypes_than_the_file_holds_loads(trained, tmp_path):
    """The control of the size checks: k-means may keep fewer prototypes than vq.num_prototypes, and a file whose
    config allows more loads."""
    path = _rewritten(trained[1], tmp_path, lambda t, m: m["config"]["vq"].update(num_prototypes=64))
    assert pedrl.load_policy(path).encoder.quantizer.num_prototypes <= 8


def test_a_checkpoint_older_than_its_keys_gets_the_values_of_its_time(trained, tmp_path):
    """Keys added after a checkpoint was written take the values runs had then (pedrl.configs.HISTORICAL_VALUES):
    void fillings drawn at every encode and raw distances, here; the encoder follows them."""

    def older(tensors, metadata):
        metadata.pop("encoder")
        metadata["config"]["algo"].pop("void_draws")
        metadata["config"]["vq"].pop("distance_transform")

    settings = pedrl.load_policy(_rewritten(trained[0], tmp_path, older)).encoder.settings
    assert (settings.void_draws, settings.distance_transform) == ("decision", "none")


def _flat(env: dict, **flat) -> None:
    """``env`` as a config written before ``env.motion`` named a model: the flat keys ``flat`` instead."""
    env.pop("motion")
    env.update(flat)


@pytest.mark.parametrize("which", ["checkpoint", "policy"])
def test_an_older_room_is_built_as_trained_whatever_the_rooms_defaults_now(trained, tmp_path, monkeypatch, which):
    """A file whose stored env config describes the motion model by the flat keys of its time and lacks contact,
    time_gap and motion (written before those keys) rebuilds the room of its time (pedrl.configs.HISTORICAL_VALUES:
    stop, 1 s, the step model) in load_policy, room_factory, room_settings (pedrl-validate) and pedrl-eval's
    load_controller, not the room that the flat keys' defaults would give now."""

    def older(tensors, metadata):
        _flat(metadata["config"]["env"], collision_rule="sequential", collision_order="random")

    path = _rewritten(dict(zip(("checkpoint", "policy"), trained, strict=True))[which], tmp_path, older)
    monkeypatch.setitem(FLAT_DEFAULTS, "contact", "slide")  # defaults changed since
    monkeypatch.setitem(FLAT_DEFAULTS, "time_gap", 2.0)
    policy = pedrl.load_policy(path)
    assert "contact" not in policy.metadata["config"]["env"]  # the stored config is kept as it was written
    assert room_settings(policy)["motion"] == {"name": "stop", "order": "random"}
    loaded = load_controller(
        path, controller="greedy", epsilon=0.0, device=torch.device("cpu"), max_decisions=5, kind=which
    )
    factories = (room_factory(policy), room_factory(policy, max_decisions=5), loaded.env_factory)
    for factory in factories:
        room = factory(num_replicas=1, num_agents=3)
        assert room.motion == Stop()


@pytest.mark.parametrize(
    ("flat", "model"),
    [
        ({"contact": "yield", "collision_order": "door_first", "time_gap": 0.4}, Yield(0.4, "door_first")),
        ({"contact": "stop", "collision_rule": "simultaneous", "collision_order": "door_first"}, Simultaneous()),
        ({"contact": "slide", "time_gap": 3.0}, Slide()),
        (
            {"contact": "headway", "motion": "continuous", "time_step": 0.02, "neighbour_repulsion": [6.0, 0.2]},
            Continuous(time_step=0.02, steering=Steering(neighbour_strength=6.0, neighbour_range=0.2)),
        ),
    ],
)
def test_an_older_files_flat_keys_give_the_model_and_the_room_they_gave(trained, tmp_path, flat, model):
    """The flat keys of a file written before env.motion (env.contact, env.collision_rule, env.collision_order,
    env.time_gap, env.motion: step|continuous, env.time_step, env.neighbour_repulsion, env.wall_repulsion) become the
    motion model they gave, keys that model never read dropped; the room is the one today's config of that model
    builds, every setting equal."""
    path = _rewritten(trained[0], tmp_path, lambda tensors, metadata: _flat(metadata["config"]["env"], **flat))
    policy = pedrl.load_policy(path)
    room = room_factory(policy)(num_replicas=1, num_agents=3)
    assert room.motion == model
    config = dict(policy.metadata["config"], env={**policy.metadata["config"]["env"]})
    config["env"] = {key: value for key, value in config["env"].items() if key not in flat} | {
        "motion": model.to_config()
    }
    today = env_factory(config["env"], config.get("scenario"), files=False)(num_replicas=1, num_agents=3)
    assert today.params == room.params


def test_act_without_a_generator_draws_on_from_the_policys_own(trained):
    policy = pedrl.load_policy(trained[1])
    room = room_factory(policy)(num_replicas=2, num_agents=5)
    obs, info = room.reset(seed=0)
    first, second = (policy.act(obs, info, epsilon=1.0) for _ in range(2))
    assert not torch.equal(first, second)  # a new default generator per call would repeat the same draws


def test_the_adapter_refuses_a_crowd_it_cannot_run(trained):
    from pedrl.integrations.pettingzoo import parallel_env

    with pytest.raises(ValueError, match="crowd of type str is invalid: must be a pedrl.TabularPolicy"):
        parallel_env(num_agents=3, width=8.0, length=8.0, crowd=str(trained[1]))


def test_the_adapter_puts_a_crowd_in_its_own_room_and_warns_of_another(trained):
    """``parallel_env(crowd=policy)`` with no room keywords builds the policy's training room (not the paper's
    default room), silently; a room given that differs gets one warning line naming what differs."""
    from pedrl.integrations.pettingzoo import parallel_env

    crowd = pedrl.load_policy(trained[1])
    own = room_factory(crowd)(num_replicas=1, num_agents=4)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # its own room: no warning
        room = parallel_env(crowd=crowd, num_agents=4, max_decisions=30).env
    assert room.params == dataclasses.replace(own.params, max_decisions=30)
    assert torch.equal(room.geometry.walls, own.geometry.walls) and torch.equal(room.geometry.exits, own.geometry.exits)
    with pytest.warns(UserWarning) as caught:
        parallel_env(crowd=crowd, num_agents=3, width=8.0, length=8.0, max_speed=0.9)
    (message,) = (str(item.message) for item in caught)
    assert message.startswith("crowd was trained in another room: the walkable area, ") and "\n" not in message
    assert "max_speed" in message and "pedrl.room_factory(crowd)" in message


@pytest.mark.parametrize("which", [0, 1])
def test_a_file_of_an_unknown_kind_is_named_as_such(trained, tmp_path, which):
    """A checkpoint or policy whose metadata ``kind`` is neither is refused as a file of an unknown kind, not called a
    training checkpoint with the advice for one."""
    crafted = _rewritten(trained[which], tmp_path, lambda tensors, metadata: metadata.update(kind="bogus"))
    with pytest.raises(CheckpointError, match=r"has metadata kind='bogus', which is unknown") as refused:
        pedrl.load_policy(crafted)
    assert "training checkpoint has no kind" in str(refused.value) and "\n" not in str(refused.value)


def test_an_export_of_fewer_processes_is_smaller_and_acts_as_those_processes(trained, tmp_path):
    checkpoint, _ = trained
    full = pedrl.load_policy(checkpoint)
    assert full.num_processes == 2
    small = pedrl.load_policy(pedrl.export_policy(checkpoint, tmp_path / "one.safetensors", processes=1))
    assert small.num_processes == 1 and torch.equal(small.q_values, full.q_values[:1])
    room = room_factory(small)(num_replicas=1, num_agents=3)  # replica 0 acts with process 0 in both
    obs, info = room.reset(seed=3)
    want = full.act(obs, info, epsilon=0.0, generator=torch.Generator().manual_seed(1))
    assert torch.equal(small.act(obs, info, epsilon=0.0, generator=torch.Generator().manual_seed(1)), want)
    with pytest.raises(ValueError, match=r"processes=3 is invalid: must be an integer in \[1, 2\]"):
        pedrl.export_policy(checkpoint, tmp_path / "three.safetensors", processes=3)
    assert not (tmp_path / "three.safetensors").exists()

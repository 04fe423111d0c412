"""Training across scenarios (``mix``): rooms of other geometries take turns with each phase's own room."""

import json

import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from pedrl.algos.mix import room_of_trial
from pedrl.algos.registry import build_trainer
from pedrl.configs import mix_rooms
from pedrl.io import load_checkpoint, read_csv
from pedrl.learning_curves import read_learning_curve
from pedrl.train import train
from tests.algos.resuming import assert_resume_equals_uninterrupted

MIX = "mix=[{name: corridor, length: 12.0, width: 3.0, spawn_length: 4.0, agents: 4}, {name: corner, agents: 3}]"
"""Two small rooms besides the debug room (10 m x 10 m, 20 agents)."""


@pytest.mark.parametrize("rooms", [1, 2, 3, 8])
@pytest.mark.parametrize("trials", [1, 7, 24])
def test_rooms_take_turns_and_the_own_room_plays_the_last_trial(rooms, trials):
    turns = [room_of_trial(trial, trials, rooms) for trial in range(trials)]
    assert turns[-1] == 0
    assert all((b - a - 1) % rooms == 0 for a, b in zip(turns, turns[1:], strict=False))  # each room in its turn
    counts = [turns.count(room) for room in range(rooms)]
    assert max(counts) - min(counts) <= 1 if trials >= rooms else max(counts) == 1


def test_a_mixed_run_learns_in_every_room_and_logs_each(train_config, tmp_path):
    result = train(train_config("algo=it_vqql", MIX), run_dir=tmp_path)
    rows = read_csv(tmp_path / "learning_curve.csv")
    labels = ["paper_room", "corridor_4", "corner_3"]
    assert len(rows) == 20
    for phase in ("1", "2"):
        phase_rows = [r for r in rows if r["phase"] == phase]
        assert [r["room"] for r in phase_rows] == [labels[room_of_trial(t, 10, 3)] for t in range(10)]
        assert phase_rows[-1]["room"] == "paper_room"  # the phase's final figures are its own room's
    agents = {r["room"]: r["agents"] for r in rows}
    assert agents == {"corridor_4": "4", "corner_3": "3", "paper_room": "20"}
    assert result.final["success_rate_mean"] == pytest.approx(float(rows[-1]["success_rate_mean"]), abs=1e-5)

    events = EventAccumulator(str(tmp_path / "tb")).Reload()
    tags = set(events.Tags()["scalars"])
    for label in labels:
        assert f"rooms/{label}/success_rate" in tags and f"rooms/{label}/crashes_agent" in tags
    corner = [e.step for e in events.Scalars("rooms/corner_3/success_rate")]
    assert corner == [int(r["global_trial"]) for r in rows if r["room"] == "corner_3"]

    trials, _, _, _ = read_learning_curve(tmp_path)  # the run's own room by default
    assert trials.tolist() == [float(r["global_trial"]) for r in rows if r["room"] == "paper_room"]
    trials, _, _, _ = read_learning_curve(tmp_path, room="corner_3")
    assert trials.tolist() == [float(r["global_trial"]) for r in rows if r["room"] == "corner_3"]
    with pytest.raises(ValueError, match=r"room='hall' is not in .*: one of paper_room, corridor_4, corner_3$"):
        read_learning_curve(tmp_path, room="hall")
    assert (tmp_path / "learning_curve.png").stat().st_size > 0

    checkpoint = load_checkpoint(tmp_path / "checkpoints" / "last.safetensors")
    stored = checkpoint.metadata["config"]["mix"]
    assert [entry["name"] for entry in stored] == ["corridor", "corner"] and stored[1]["agents"] == 3


def test_states_are_gathered_in_every_room(train_config, tmp_path):
    """The quantizer sees every room: the mixed run gathers more states, and its void fillings span the largest."""
    train(train_config("algo=it_vqql", "algo.iterations=1", "algo.trials=3"), run_dir=tmp_path / "one")
    train(train_config("algo=it_vqql", "algo.iterations=1", "algo.trials=3", MIX), run_dir=tmp_path / "mix")
    gathered = {
        run: json.loads((tmp_path / run / "summary.json").read_text())["phases"][0]["gathered_states"]
        for run in ("one", "mix")
    }
    assert gathered["mix"] > gathered["one"]
    trainer = build_trainer(train_config("algo=it_vqql", MIX), tmp_path / "built")
    longest = max(room.max_distance for _, room in trainer.rooms(trainer.env_for(20)))
    assert trainer.encoder_settings.max_distance == longest > trainer.env_for(20).max_distance  # the corridor's


def test_a_mixed_run_resumed_mid_phase_equals_an_uninterrupted_one(train_config, tmp_path, monkeypatch):
    """One generator drives every room, and a checkpoint holds it: resuming continues the same trials."""
    overrides = ("algo=it_vqql", "checkpoint_every=4", "logger=none", MIX)
    # 15 trials: the second phase, after its first mid-phase checkpoint (trial 4)
    assert_resume_equals_uninterrupted(train_config, overrides, tmp_path, monkeypatch, stop_after=15)


def test_a_resume_with_another_mix_is_refused(train_config, tmp_path):
    train(train_config("algo=vqql", "algo.iterations=1", "algo.trials=2", "logger=none", MIX), run_dir=tmp_path)
    cfg = train_config("algo=vqql", "algo.iterations=1", "algo.trials=2", "logger=none", "resume=true")
    from pedrl.io import CheckpointError

    with pytest.raises(CheckpointError, match="mix was"):
        train(cfg, run_dir=tmp_path)


ENV = {"_target_": "pedrl.sim.RoomEnv"}


@pytest.mark.parametrize(
    ("mix", "message"),
    [
        ("corridor", r"mix='corridor' is invalid: must be a list of scenarios"),
        ([{"agents": 4}], r"mix\[0\]=.* is invalid: must be a scenario config with a name and agents"),
        ([{"name": "corridor"}], r"mix\[0\]\.agents=None is invalid: must be an integer in \[1, 10000\]"),
        ([{"name": "corridor", "agents": 0}], r"mix\[0\]\.agents=0 is invalid"),
        ([{"name": "corridor", "agents": True}], r"mix\[0\]\.agents=True is invalid"),
        ([{"name": "mall", "agents": 4}], r"mix\[0\]: scenario\.name='mall' is invalid: must be one of"),
        ([{"name": "corridor", "opening": 1.0, "agents": 4}], r"mix\[0\]: scenario\.opening is not a setting"),
        ([{"name": "corridor", "agents": 4}] * 17, r"mix holds 17 rooms: at most 16"),
    ],
)
def test_a_bad_mix_is_refused_in_one_line(mix, message):
    with pytest.raises(ValueError, match=message) as info:
        mix_rooms(ENV, mix)
    assert "\n" not in str(info.value)


def test_labels_tell_rooms_apart():
    rooms = mix_rooms(
        ENV, [{"name": "corner", "agents": 4}, {"name": "corner", "width": 3.0, "agents": 4}], home="corner"
    )
    assert [room.label for room in rooms] == ["corner_4", "corner_4_1"]
    assert mix_rooms(ENV, None) == [] and mix_rooms(ENV, []) == []


def test_a_bad_mix_stops_pedrl_train_before_any_compute(train_config, tmp_path):
    cfg = train_config("algo=vqql", "mix=[{name: corridor, agents: -1}]")
    with pytest.raises(ValueError, match=r"mix\[0\]\.agents=-1 is invalid"):
        train(cfg, run_dir=tmp_path)
    assert not (tmp_path / "checkpoints").exists()


def test_a_mixed_checkpoint_loads_as_a_policy_and_acts_as_trained(train_config, tmp_path):
    """The corridor is longer than the debug room: its encoder's longest distance is the corridor's, and loading
    the checkpoint (evaluation, export) derives the same from the stored mix."""
    import pedrl

    train(train_config("algo=vqql", "algo.iterations=1", "algo.trials=2", "logger=none", MIX), run_dir=tmp_path)
    path = tmp_path / "checkpoints" / "last.safetensors"
    stored = load_checkpoint(path).metadata["encoder"]["max_distance"]
    policy = pedrl.load_policy(path)
    assert (
        policy.encoder.settings.max_distance
        == stored
        > pedrl.room_factory(policy)(num_replicas=1, num_agents=1).max_distance
    )
    exported = pedrl.export_policy(path, tmp_path / "policy.safetensors")
    assert pedrl.load_policy(exported).encoder.settings == policy.encoder.settings


def test_a_mix_room_too_small_for_its_agents_is_named():
    with pytest.raises(ValueError, match=r"^mix\[1\]: num_agents=500 is invalid: 500 bodies") as info:
        mix_rooms(ENV, [{"name": "corner", "agents": 3}, {"name": "corner", "agents": 500}])
    assert "\n" not in str(info.value)


def test_mix_null_is_an_empty_mix(train_config, tmp_path):
    trainer = build_trainer(train_config("algo=vqql", "mix=null"), tmp_path)
    assert trainer.mix == [] and trainer.config["mix"] == []


def test_a_stored_config_with_too_many_mix_rooms_is_refused(train_config, tmp_path):
    from pedrl.configs import checked_config
    from pedrl.io import CheckpointError

    config = build_trainer(train_config("algo=vqql"), tmp_path).config
    with pytest.raises(CheckpointError, match=r"mix holds 17 rooms: at most 16"):
        checked_config({**config, "mix": [{"name": "corner", "agents": 1}] * 17}, "checkpoint 'x'")
    long_text = "x" * 5000
    with pytest.raises(CheckpointError, match=r"mix\[0\]\.exits\.geometry=.* at most 4096 characters"):
        checked_config({**config, "mix": [{"name": "corner", "agents": 1, "exits": {"geometry": long_text}}]}, "c")

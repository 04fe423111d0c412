"""End-to-end training through the real entry point, with tiny budgets."""

import json
import math
import subprocess
import sys

import pytest
import torch

from pedrl.algos.registry import build_trainer
from pedrl.io import CheckpointError, load_checkpoint, read_csv
from pedrl.train import train
from pedrl.vq.encoder import StateEncoder, quantizer_from_state_dict
from tests.algos.resuming import assert_resume_equals_uninterrupted

ALGOS = ("vqql", "it_vqql", "in_vqql")


@pytest.mark.parametrize("algo", ALGOS)
@pytest.mark.parametrize("logger", ["tensorboard", "none"])
def test_every_group_composes_and_builds(algo, logger, tmp_path, compose):
    cfg = compose("train", [f"algo={algo}", f"logger={logger}", "debug=default"])
    trainer = build_trainer(cfg, tmp_path)
    assert trainer.name == algo
    assert trainer.phases(), "an algorithm has at least one phase"


def test_paper_defaults_compose(compose):
    cfg = compose("train", ["algo=in_vqql"])
    assert list(cfg.algo.stages) == [1, 2, 3, 4, 5, 6, 7, 8, 10, 20]
    assert cfg.algo.gamma == 0.91 and cfg.algo.alpha == 0.35 and cfg.algo.epsilon_start == 0.4
    assert compose("train", ["algo=vqql"]).algo.alpha == 0.25


def test_vqql_debug_run_writes_every_output(train_config, tmp_path):
    result = train(train_config("algo=vqql"), run_dir=tmp_path)
    for name in ("learning_curve.csv", "learning_curve.png", "summary.json"):
        assert (tmp_path / name).is_file(), name
    assert sorted(p.name for p in (tmp_path / "checkpoints").iterdir()) == [
        "iter_0001.safetensors",
        "iter_0002.safetensors",
        "last.safetensors",
    ]
    rows = read_csv(tmp_path / "learning_curve.csv")
    assert len(rows) == 20 and [int(r["global_trial"]) for r in rows] == list(range(20))
    assert result.final["success_rate_mean"] == pytest.approx(float(rows[-1]["success_rate_mean"]), abs=1e-5)
    # the crowd's figures per trial: within the trial's clock (debug: 30 decisions of 1 s)
    for row in rows:
        assert 0.0 < float(row["evacuation_time_mean"]) <= 30.0
        flow = float(row["door_flow_mean"])
        assert math.isnan(flow) or flow > 0.0
    checkpoint = load_checkpoint(tmp_path / "checkpoints" / "iter_0001.safetensors")
    assert checkpoint.tensors["q_values"].shape == (2, 1, 32, 81)  # algo.tables=process: one table per process
    assert checkpoint.metadata["config"]["algo"]["_target_"] == "pedrl.algos.VQQL"


def test_vqql_learns_measurably_better_than_a_random_walk(compose, tmp_path):
    """The main job's experiment, shrunk: success late in training beats the random walk the data came from."""
    cfg = compose(
        "train", ["experiment=quick_vqql", "processes=2", "algo.trials=40", "algo.iterations=1", "logger=none"]
    )
    cfg.progress = False
    train(cfg, run_dir=tmp_path)
    rows = read_csv(tmp_path / "learning_curve.csv")
    summary = json.loads((tmp_path / "summary.json").read_text())
    random_walk = summary["phases"][0]["gather_success_rate"]
    late = sum(float(r["success_rate_mean"]) for r in rows[-8:]) / 8
    assert late > 2 * random_walk + 0.1, (late, random_walk)


def test_tensorboard_events_hold_the_documented_tags(train_config, tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    train(train_config("algo=vqql", "algo.iterations=1", "algo.trials=3"), run_dir=tmp_path)
    events = EventAccumulator(str(tmp_path / "tb"))
    events.Reload()
    tags = set(events.Tags()["scalars"])
    for tag in (
        "charts/success_rate",
        "charts/episodic_return",
        "charts/crashes_agent",
        "charts/crashes_wall",
        "charts/mean_speed",
        "charts/evacuation_time",
        "charts/decisions_per_s",
        "vq/distortion",
        "losses/td_error",
        "spread/success_rate_std",
    ):
        assert tag in tags, tag
    assert len(events.Scalars("charts/success_rate")) == 3


def test_seeded_runs_are_reproducible(train_config, tmp_path):
    cfg = train_config("algo=vqql", "algo.iterations=1", "algo.trials=4", "logger=none")
    train(cfg, run_dir=tmp_path / "a")
    train(cfg, run_dir=tmp_path / "b")
    a = load_checkpoint(tmp_path / "a" / "checkpoints" / "last.safetensors")
    b = load_checkpoint(tmp_path / "b" / "checkpoints" / "last.safetensors")
    assert torch.equal(a.tensors["q_values"], b.tensors["q_values"])
    quantizer_a, quantizer_b = a.tensors_with_prefix("quantizer"), b.tensors_with_prefix("quantizer")
    assert quantizer_a.keys() == quantizer_b.keys()
    assert all(torch.equal(quantizer_a[key], quantizer_b[key]) for key in quantizer_a)


@pytest.mark.parametrize("algo", ALGOS)
def test_resumed_run_equals_uninterrupted_run(train_config, tmp_path, monkeypatch, algo):
    overrides = (f"algo={algo}", "checkpoint_every=3", "logger=none")
    # 14 trials: inside the second phase, after a mid-phase checkpoint
    assert_resume_equals_uninterrupted(train_config, overrides, tmp_path, monkeypatch, stop_after=14)


def test_resume_from_foreign_config_is_refused(train_config, tmp_path):
    train(train_config("algo=vqql", "algo.iterations=1", "algo.trials=2", "logger=none"), run_dir=tmp_path)
    cfg = train_config(
        "algo=vqql", "algo.iterations=1", "algo.trials=2", "logger=none", "algo.gamma=0.5", "resume=true"
    )
    with pytest.raises(CheckpointError, match="algo.gamma"):
        train(cfg, run_dir=tmp_path)
    bad = tmp_path / "checkpoints" / "last.safetensors"
    bad.write_bytes(bad.read_bytes()[:100])
    cfg = train_config("algo=vqql", "algo.iterations=1", "algo.trials=2", "logger=none", "resume=true")
    with pytest.raises(CheckpointError, match="corrupt or truncated"):
        train(cfg, run_dir=tmp_path)


def test_a_resume_on_another_walking_layer_is_refused(train_config, tmp_path):
    run = ("algo=vqql", "algo.iterations=1", "algo.trials=2", "logger=none")
    train(train_config(*run, "motion=yield"), run_dir=tmp_path)
    with pytest.raises(CheckpointError, match='env.motion.contact was "<absent>" there and is "yield" here'):
        train(train_config(*run, "motion=continuous", "env.motion.contact=yield", "resume=true"), run_dir=tmp_path)


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("processes=0", "processes=0 is invalid"),
        ("algo.alpha=2.0", "alpha=2.0 is invalid"),
        ("algo.trials=abc", "trials='abc' is invalid"),
        ("env.door_width=100", "door_width"),
        ("vq.num_prototypes=1", "num_prototypes=1 is invalid"),
        ("vq.weight_neighbours=[1,2]", "weight_neighbours=\\[1, 2\\] is invalid: must be a number > 0 or a list of 7"),
        ("vq.weight_neighbours=-1", "weight_neighbours=-1 is invalid"),
        ("vq.weight_own=0", "weight_own=0 is invalid"),
        ("vq.distance_transform=sqrt", "distance_transform='sqrt' is invalid"),
        ("vq.per_process=maybe", "per_process='maybe' is invalid"),
        ("algo.tables=room", "tables='room' is invalid"),
        ("algo.void_draws=never", "void_draws='never' is invalid"),
        ("env.motion.order=last", "env.motion.order='last' is invalid"),
        ("env.reward_progress=-1", "reward_progress=-1 is invalid"),
        ("env.goal_depth=-1", "goal_depth=-1 is invalid"),
    ],
)
def test_bad_values_fail_before_compute(train_config, tmp_path, override, message):
    with pytest.raises(Exception, match=message):
        build_trainer(train_config(override), tmp_path)
    assert not (tmp_path / "learning_curve.csv").exists()


def test_cli_reports_user_errors_in_one_line(tmp_path):
    command = [sys.executable, "-m", "pedrl.train", "debug=default", "processes=-2", f"hydra.run.dir={tmp_path}"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert lines == ["pedrl-train: error: processes=-2 is invalid: must be an integer >= 1"]


def test_cli_rejects_unknown_keys(tmp_path):
    command = [sys.executable, "-m", "pedrl.train", "debug=default", "algo.no_such_key=1", f"hydra.run.dir={tmp_path}"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert done.returncode != 0
    assert "no_such_key" in done.stderr


@pytest.mark.parametrize("void_draws", ["trial", "decision"])
def test_void_filling_is_drawn_once_per_agent_and_trial(void_draws, train_config, tmp_path):
    """IT-VQQL fills empty neighbour slots at random: by default once per trial, so a state keeps its filling."""
    trainer = build_trainer(
        train_config(
            "algo=it_vqql", "algo.num_agents=3", f"algo.void_draws={void_draws}", "vq.distance_transform=none"
        ),
        tmp_path,
    )
    env = trainer.env_for(3)
    obs, info = env.reset(seed=0)
    flat, sensed = obs.reshape(-1, env.num_features), info["num_sensed"].reshape(-1)
    assert (sensed < env.params.num_neighbours).all()  # 3 agents: 2 neighbours sensed, 5 void slots
    encoder = StateEncoder(trainer.encoder_settings)
    first = encoder.prepare(flat, sensed, 0, trainer.generator)
    later = encoder.prepare(flat, sensed, 5, trainer.generator)  # the same state later in the trial
    next_trial = encoder.prepare(flat, sensed, 0, trainer.generator)  # a new trial draws again
    assert torch.equal(first[:, :9], flat[:, :9])  # own features and both sensed neighbours kept
    assert torch.equal(first, later) == (void_draws == "trial")
    assert not torch.equal(first, next_trial)


@pytest.mark.parametrize("algo", ALGOS)
def test_each_learning_process_fits_its_own_quantizer(algo, train_config, tmp_path):
    cfg = train_config(f"algo={algo}", "logger=none")
    trainer = build_trainer(cfg, tmp_path)
    train(cfg, run_dir=tmp_path)
    checkpoint = load_checkpoint(tmp_path / "checkpoints" / "last.safetensors")
    quantizer = quantizer_from_state_dict(checkpoint.tensors_with_prefix("quantizer"))
    assert trainer.vq.per_process
    assert quantizer.num_processes == cfg.processes == checkpoint.tensors["q_values"].shape[0]
    first, second = (part.state_dict() for part in quantizer.parts[:2])
    assert first.keys() == second.keys()
    assert any(not torch.equal(first[key], second[key]) for key in first if key.endswith("prototypes"))


def test_a_shared_quantizer_stays_selectable(train_config, tmp_path):
    cfg = train_config("algo=vqql", "logger=none", "vq.per_process=false")
    train(cfg, run_dir=tmp_path)
    tensors = load_checkpoint(tmp_path / "checkpoints" / "last.safetensors").tensors_with_prefix("quantizer")
    assert sorted(tensors) == ["mean", "prototypes", "std"]


def test_one_table_per_process_is_shared_by_its_agents(train_config, tmp_path):
    cfg = train_config("algo=vqql", "algo.num_agents=3", "logger=none", "algo.tables=process")
    train(cfg, run_dir=tmp_path)
    q_values = load_checkpoint(tmp_path / "checkpoints" / "last.safetensors").tensors["q_values"]
    assert q_values.shape[:2] == (cfg.processes, 1)  # A = 1: every agent of a process learns into one table
    assert q_values.abs().sum() > 0


def test_log_distance_transform_changes_only_distances(train_config, tmp_path):
    plain = build_trainer(train_config("algo=vqql", "vq.distance_transform=none"), tmp_path)
    logged = build_trainer(train_config("algo=vqql", "vq.distance_transform=log"), tmp_path)
    env = plain.env_for(plain.phases()[0].num_agents)
    obs, info = env.reset(seed=0)
    flat, sensed = obs.reshape(-1, env.num_features), info["num_sensed"].reshape(-1)
    prepare = [StateEncoder(t.encoder_settings).prepare(flat, sensed, 0, t.generator) for t in (plain, logged)]
    before, after = prepare
    names = env.feature_names
    distance = torch.tensor(["distance" in name for name in names])
    assert torch.equal(before[:, ~distance], after[:, ~distance])
    torch.testing.assert_close(after[:, distance], before[:, distance].log1p())
    assert distance.sum() == 1 + env.params.num_neighbours + env.params.num_walls


def test_it_vqql_iterations_can_learn_in_a_larger_crowd(train_config, tmp_path):
    cfg = train_config("algo=it_vqql", "algo.iterations=2", "algo.num_agents=[2,5]", "algo.tables=agent", "logger=none")
    train(cfg, run_dir=tmp_path)
    rows = read_csv(tmp_path / "learning_curve.csv")
    assert {(row["phase"], row["agents"]) for row in rows} == {("1", "2"), ("2", "5")}
    q_values = load_checkpoint(tmp_path / "checkpoints" / "last.safetensors").tensors["q_values"]
    assert q_values.shape[1] == 5  # the last iteration's tables, one per agent of the larger crowd
    with pytest.raises(ValueError, match=r"num_agents=\[2\] is invalid: must be an integer >= 1 or a list of 2"):
        build_trainer(train_config("algo=it_vqql", "algo.iterations=2", "algo.num_agents=[2]"), tmp_path)

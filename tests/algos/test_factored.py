"""A factored table (``vq.factors``) through every surface: VQQL and IT-VQQL train it on both trial paths, a killed run
resumes to the same numbers, its checkpoint and exported file act alike in pedrl-eval, pedrl-validate and the
PettingZoo adapter, and bad factors are refused in one line before any compute."""

import csv

import pytest
import torch
from hydra import compose, initialize_config_dir

import pedrl
import pedrl.train
from pedrl.cli import CONFIG_DIR
from pedrl.evaluation import evaluate
from pedrl.io import load_checkpoint, read_csv
from pedrl.policy_files import room_factory
from pedrl.train import train
from pedrl.vq import FactoredQuantizer
from tests.algos.resuming import assert_resume_equals_uninterrupted
from tests.refusals import EVAL_BASE, assert_nothing_computed, assert_refused, run_hydra_main, train_checkpoint

FACTORS = (
    "vq.factors={own: {num_prototypes: 24}, neighbour: {num_prototypes: 16, weights: {distance: 2}},"
    " wall: {num_prototypes: 8}}"
)
TINY_FACTORED = (
    "debug=default",
    "algo=it_vqql",
    "algo.num_agents=4",
    "algo.iterations=2",
    "algo.trials=6",
    "algo.value_transfer=true",
    "vq.per_process=false",
    FACTORS,
    "env.max_decisions=15",
    "logger=none",
)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A seconds-long IT-VQQL run of a factored table (value transfer between its two iterations) and its export."""
    checkpoint = train_checkpoint(tmp_path_factory, TINY_FACTORED)
    exported = pedrl.export_policy(checkpoint, checkpoint.parent.parent / "policy.safetensors")
    return checkpoint, exported


def test_the_checkpoint_holds_a_factored_table_that_learned(trained):
    checkpoint, exported = trained
    policy = pedrl.load_policy(checkpoint)
    quantizer = policy.encoder.quantizer
    assert isinstance(quantizer, FactoredQuantizer)
    assert set(quantizer.parts) == {"own", "neighbour", "wall"} and quantizer.num_slots == 1 + 7 + 2
    assert policy.q_values.shape[2] == quantizer.num_prototypes <= 24 + 16 + 8
    own, neighbour, wall = (policy.q_values[0, 0, first:last] for first, last in ((0, 24), (24, 40), (40, 48)))
    assert bool((own != 0).any() and (neighbour != 0).any() and (wall != 0).any())  # every factor learned
    carried = pedrl.load_policy(exported)
    room = room_factory(carried)(num_replicas=3, num_agents=6)
    obs, info = room.reset(seed=2)
    for _ in range(4):
        want = policy.act(obs, info, epsilon=0.2, generator=torch.Generator().manual_seed(9))
        assert torch.equal(want, carried.act(obs, info, epsilon=0.2, generator=torch.Generator().manual_seed(9)))
        obs, *_, info = room.step(want)


@pytest.mark.parametrize("fused", ["true", "false"])
def test_pedrl_eval_runs_the_checkpoint_and_the_file_alike(trained, tmp_path, fused):
    checkpoint, exported = trained
    rows = {}
    for key, path in (("checkpoint", checkpoint), ("policy", exported)):
        with initialize_config_dir(version_base="1.3", config_dir=CONFIG_DIR):
            cfg = compose("eval", [*EVAL_BASE, f"{key}={path}", "export.trials=0", "seed=4", f"fused={fused}"])
        evaluate(cfg, run_dir=tmp_path / key)
        with open(tmp_path / key / "scaling.csv") as file:
            rows[key] = list(csv.DictReader(file))
    assert rows["checkpoint"] == rows["policy"] and len(rows["policy"]) == 4  # 2 counts, learned and greedy


def test_pedrl_validate_runs_a_factored_policy(trained, tmp_path, capsys):
    import pedrl.validate

    checkpoint, _ = trained
    args = [f"checkpoint={checkpoint}", "tests=[rimea_6]", "controller=learned", "quick=true",
            f"hydra.run.dir={tmp_path}"]  # fmt: skip
    outcome = run_hydra_main(pedrl.validate, args, capsys)
    assert outcome.code == 0, outcome.stderr
    assert "learned" in (tmp_path / "validation.md").read_text()


def test_the_pettingzoo_adapter_walks_a_factored_crowd(trained):
    from pedrl.integrations.pettingzoo import PedestrianParallelEnv

    _, exported = trained
    crowd = pedrl.load_policy(exported)
    factory = room_factory(crowd)
    env = PedestrianParallelEnv(factory(num_replicas=1, num_agents=4), crowd=crowd, learners=1, crowd_epsilon=0.1)
    env.reset(seed=5)
    reference = factory(num_replicas=1, num_agents=4)
    obs, info = reference.reset(seed=5)
    generator = torch.Generator().manual_seed(5)
    for _ in range(5):
        if not env.agents:
            break
        actions = crowd.act(obs, info, epsilon=0.1, generator=generator)
        actions[0, 0] = 40
        env.step({"pedestrian_0": 40})
        obs, *_, info = reference.step(actions)
        assert torch.equal(env.env.positions, reference.positions)


@pytest.mark.parametrize("algo", ["vqql", "it_vqql"])
def test_a_killed_factored_run_resumes_to_the_same_numbers(train_config, tmp_path, monkeypatch, algo):
    overrides = ("debug=default", f"algo={algo}", "algo.trials=8", "checkpoint_every=3", "logger=none",
                 "vq.per_process=false", FACTORS)  # fmt: skip
    assert_resume_equals_uninterrupted(train_config, overrides, tmp_path, monkeypatch, stop_after=5)


def test_a_seed_gives_the_same_factored_run(train_config, tmp_path):
    overrides = ("debug=default", "algo=vqql", "algo.trials=6", "logger=none", "vq.per_process=false", FACTORS)
    for run in ("a", "b"):
        train(train_config(*overrides), run_dir=tmp_path / run)
    a, b = (load_checkpoint(tmp_path / run / "checkpoints" / "last.safetensors") for run in ("a", "b"))
    assert torch.equal(a.tensors["q_values"], b.tensors["q_values"])
    strip = lambda rows: [{k: v for k, v in r.items() if k != "decisions_per_s"} for r in rows]  # noqa: E731
    assert strip(read_csv(tmp_path / "a" / "learning_curve.csv")) == strip(
        read_csv(tmp_path / "b" / "learning_curve.csv")
    )


@pytest.mark.parametrize(
    ("overrides", "fragments"),
    [
        (["vq.factors={door: {num_prototypes: 4}}"], ("vq.factors.door is not a factor", "own, neighbour, wall")),
        (["vq.factors={own: {num_prototypes: 0}}"], ("vq.factors.own.num_prototypes=0", "integer >= 1")),
        (["vq.factors={own: {num_prototypes: 4, weights: {speed: nan}}}"], ("weights.speed=nan", "finite")),
        (["vq.factors={own: {num_prototypes: 4, weights: {pace: 1}}}"], ("weights.pace names no feature", "speed")),
        (["vq.per_process=true", "vq.factors={own: {num_prototypes: 4}}"], ("vq.per_process=true is invalid",)),
        (["algo=in_vqql", "vq.factors={own: {num_prototypes: 4}}"], ("vq.factors is invalid with algo=in_vqql",)),
        # a factor of a kind the room senses no slot of: nothing to fit it on (it crashed after the first phase)
        (
            ["experiment=main_factored", "env.num_neighbours=0"],
            ("vq.factors.neighbour is invalid with env.num_neighbours=0", "~vq.factors.neighbour"),
        ),
        (["experiment=main_factored", "env.num_walls=0"], ("vq.factors.wall is invalid with env.num_walls=0",)),
    ],
)
def test_bad_factors_are_refused_in_one_line_before_any_compute(overrides, fragments, tmp_path, capsys):
    run_dir = tmp_path / "run"
    base = ["debug=default", "vq.per_process=false", f"hydra.run.dir={run_dir}"]
    outcome = run_hydra_main(pedrl.train, [*base, *overrides], capsys)
    assert_refused(outcome, "pedrl-train", fragments)
    assert_nothing_computed(run_dir)


@pytest.mark.parametrize(
    ("slots", "factors"),
    [
        ("env.num_neighbours=0", "vq.factors={own: {num_prototypes: 8}, wall: {num_prototypes: 4}}"),
        ("env.num_walls=0", "vq.factors={own: {num_prototypes: 8}, neighbour: {num_prototypes: 4}}"),
    ],
)
def test_a_room_without_neighbour_or_wall_slots_trains_the_factors_it_has(slots, factors, train_config, tmp_path):
    """The way out the refusal names: the table without the empty factor trains (the state split of a room of 0 slots
    of a kind was numpy-ambiguous and crashed)."""
    overrides = ("debug=default", "algo=vqql", "algo.num_agents=3", "algo.trials=2", "env.max_decisions=10",
                 "logger=none", "vq.per_process=false", slots, factors)  # fmt: skip
    train(train_config(*overrides), run_dir=tmp_path)
    checkpoint = load_checkpoint(tmp_path / "checkpoints" / "last.safetensors")
    assert checkpoint.tensors["q_values"].abs().sum() > 0
    assert len(read_csv(tmp_path / "learning_curve.csv")) == 2


def test_the_neighbours_tool_refuses_a_factored_table_in_one_line(trained, capsys):
    """It printed the factors' summed K and "sees neighbours: no" (it read the first id of a set); the plain
    checkpoint's rows are tests/evaluation/test_neighbours.py's control."""
    from pedrl.evaluation import neighbours

    checkpoint, exported = trained
    for path in (checkpoint, exported):
        with pytest.raises(SystemExit) as exit_:
            neighbours.main([str(path), "--places", "2", "--samples", "4", "--crowds", "2"])
        assert exit_.value.code == 2
        captured = capsys.readouterr()
        lines = [line for line in captured.err.splitlines() if line.strip()]
        assert len(lines) == 1 and "is a factored table (vq.factors): this tool counts" in lines[0], captured.err
        assert captured.out == ""


def test_a_factored_file_whose_config_names_other_factors_is_refused(trained, tmp_path):
    """A stored vq.factors without the wall factor, or with a smaller K than the table holds, loaded and acted."""
    import pedrl
    from pedrl.io import CheckpointError
    from tests.test_export import _rewritten

    def smaller(tensors, metadata):
        metadata["config"]["vq"]["factors"]["own"]["num_prototypes"] = 1

    for path in trained:
        for change in (lambda t, m: m["config"]["vq"]["factors"].pop("wall"), smaller):
            with pytest.raises(CheckpointError, match=r"its config's vq.factors \(K .*\) disagree with its factored"):
                pedrl.load_policy(_rewritten(path, tmp_path, change))

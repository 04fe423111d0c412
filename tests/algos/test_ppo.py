"""algo=ppo, shared-parameter PPO on the learning run every learner shares: it learns, it is reproducible, it
resumes exactly, its checkpoints are read as networks by every tool, and bad settings are refused in one line."""

import math

import pytest
import torch

from pedrl.algos.registry import build_trainer
from pedrl.io import load_checkpoint, read_csv
from pedrl.policy_files import load_policy, room_factory
from pedrl.rl.network import QNetwork
from pedrl.rl.neural import ContinuousPolicy, NeuralPolicy
from pedrl.train import train
from pedrl.trial.crowd import run_crowd
from tests.algos.resuming import assert_resume_equals_uninterrupted

# a 10 m room, 4 agents for 40 decisions, actions in the goal frame (the presets'), small networks at a larger step, two
# iterations (two checkpoints)
PPO = ("algo=ppo", "algo.num_agents=4", "env.max_decisions=40", "threads=1", "logger=none", "env.action_frame=goal",
       "algo.hidden=[32,32]", "algo.minibatches=2", "algo.learning_rate=0.002", "algo.iterations=2",
       "env.speed_ratios=[0.0,0.2,0.4,0.6,0.7,0.8,0.9,0.95,1.0]",
       "env.turn_ratios=[-0.5,-0.25,-0.1,-0.05,0.0,0.05,0.1,0.25,0.5]")  # fmt: skip


def _greedy_return(policy: NeuralPolicy, factory, seed: int = 11) -> float:
    """The mean return of ``policy`` acting on its most probable actions over 16 scenes of ``seed``."""
    room = factory(num_replicas=16, num_agents=4)
    room.reset(seed=seed)
    return float(run_crowd(room, policy.controller(0.0, torch.Generator().manual_seed(0)), fused=None).stats
                 .episodic_return.mean())  # fmt: skip


def test_ppo_learns_to_walk_better_than_its_untrained_actor(train_config, tmp_path):
    train(train_config(*PPO, "algo.trials=60", "algo.epochs=10"), run_dir=tmp_path)
    learned = load_policy(tmp_path / "checkpoints" / "last.safetensors")
    assert isinstance(learned, NeuralPolicy) and learned.metadata["algo"] == "ppo"
    factory = room_factory(learned)
    untrained = NeuralPolicy(learned.encoder, QNetwork(1, learned.num_inputs, [32, 32], 81,
                             generator=torch.Generator().manual_seed(0)), learned.mean, learned.std)  # fmt: skip
    before, after = _greedy_return(untrained, factory), _greedy_return(learned, factory)
    assert after > before + 50.0, (before, after)


def test_ppo_logs_its_update_and_writes_a_checkpoint_per_iteration(train_config, tmp_path):
    train(train_config(*PPO, "algo.trials=6", "logger=tensorboard"), run_dir=tmp_path)
    names = sorted(path.name for path in (tmp_path / "checkpoints").iterdir())
    assert names == ["iter_0001.safetensors", "iter_0002.safetensors", "last.safetensors"]
    meta = load_checkpoint(tmp_path / "checkpoints" / "last.safetensors").metadata
    assert (
        meta["algo"] == "ppo" and meta["learner"] == "neural" and meta["updates"] == 6 * 4 * 2
    )  # epochs x minibatches
    rows = read_csv(tmp_path / "learning_curve.csv")
    assert len(rows) == 6 and all(float(row["epsilon"]) == 0.0 for row in rows)  # it explores by sampling
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(tmp_path / "tb")).Reload()
    tags = set(events.Tags()["scalars"])
    assert {"ppo/policy_loss", "ppo/value_loss", "ppo/entropy", "ppo/approx_kl",
            "ppo/clip_fraction", "ppo/gradient_steps"} <= tags, sorted(tags)  # fmt: skip


def test_ppo_same_seed_same_numbers_other_seed_other_numbers(train_config, tmp_path):
    for run, seed in (("a", 0), ("b", 0), ("c", 1)):
        train(train_config(*PPO, "algo.trials=4", "algo.iterations=1", f"seed={seed}"), run_dir=tmp_path / run)
    a, b, c = (load_checkpoint(tmp_path / run / "checkpoints" / "last.safetensors").tensors for run in "abc")
    assert a.keys() == b.keys() and all(torch.equal(a[name], b[name]) for name in a)
    assert not torch.equal(a["network/w0"], c["network/w0"])


@pytest.mark.parametrize(
    ("stop_after", "head"),
    [(4, "discrete"), (7, "discrete"), (7, "continuous")],
    ids=["first_iteration", "second_iteration", "continuous"],
)
def test_ppo_killed_mid_run_resumes_to_the_same_networks_and_curve(
    stop_after, head, train_config, tmp_path, monkeypatch
):
    overrides = (*PPO, "checkpoint_every=2", "algo.trials=10", f"algo.actions={head}")
    assert_resume_equals_uninterrupted(
        train_config, overrides, tmp_path, monkeypatch, stop_after=stop_after, tensors="all"
    )


def test_ppo_resume_refuses_another_network(train_config, tmp_path):
    train(train_config(*PPO, "algo.trials=2", "algo.iterations=1"), run_dir=tmp_path)
    with pytest.raises(Exception, match="algo.hidden was"):
        train(train_config(*PPO, "algo.trials=2", "algo.iterations=1", "algo.hidden=[16]", "resume=true"),
              run_dir=tmp_path)  # fmt: skip


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("algo.epochs=0", "epochs=0 is invalid: must be an integer in [1, 1000]"),
        ("algo.minibatches=0", "minibatches=0 is invalid"),
        ("algo.clip_coef=0", "clip_coef=0 is invalid"),
        ("algo.gae_lambda=1.5", "gae_lambda=1.5 is invalid"),
        ("algo.entropy_coef=-1", "entropy_coef=-1 is invalid"),
        ("algo.learning_rate=nan", "learning_rate=nan is invalid"),
        ("algo.hidden=[0]", "hidden=[0] is invalid"),
        ("algo.hidden=[65536,65536]", "this run needs about .* GiB of memory .networks and Adam"),
        ("algo.normalize_advantages=3", "normalize_advantages=3 is invalid: must be true or false"),
        ("+algo.batch_size=4", "algo.batch_size is not a setting of pedrl.algos.PPO"),
        ("vq.per_process=false vq.factors={own:{num_prototypes:8}}", "vq.factors is invalid with algo=ppo"),
        ("algo.actions=beta", "actions='beta' is invalid"),
        ("algo.init_std=0", "init_std=0 is invalid"),
        ("algo.heading_prior=-1", "heading_prior=-1 is invalid"),
        ("algo.heading_prior=1", "algo.heading_prior=1 is invalid with algo.actions=discrete"),
        ("algo.company_heading=routed", "algo.company_heading=routed is invalid with algo.actions=discrete"),
        ("algo.company_heading=true", "company_heading=True is invalid: must be one of none, added, routed"),
        (
            "algo.actions=continuous env.action_frame=heading env.speed_ratios=[-1,-0.5,-0.25,-0.1,0,0.1,0.25,0.5,1]",
            "algo.actions=continuous is invalid with env.action_frame",
        ),
    ],
)
def test_ppo_bad_settings_are_one_line_before_any_compute(train_config, tmp_path, override, message):
    cfg = train_config(*PPO, *override.split())
    with pytest.raises(ValueError, match=message.replace("[", r"\[").replace("]", r"\]")) as err:
        build_trainer(cfg, tmp_path)
    assert "\n" not in str(err.value)
    assert not (tmp_path / "checkpoints").exists()


def _eval_checkpoint_and_export(checkpoint, tmp_path):
    """``pedrl-eval`` of ``checkpoint`` and of its exported policy file on the same scenes: the file and the rows of
    each (by controller)."""
    import csv

    from pedrl.evaluation import evaluate
    from pedrl.policy_files import export_policy
    from tests.conftest import compose_config

    exported = export_policy(checkpoint, tmp_path / "policy.safetensors")
    rows = {}
    for name, source in (("checkpoint", f"checkpoint={checkpoint}"), ("file", f"policy={exported}")):
        eval_cfg = compose_config("eval", [source, "agents=[4]", "trials=8", "trials_per_batch=8", "seed=3",
                                           "animation.enabled=false", "export.trials=0"])  # fmt: skip
        evaluate(eval_cfg, run_dir=tmp_path / name)
        with open(tmp_path / name / "scaling.csv") as file:
            rows[name] = {row["controller"]: row for row in csv.DictReader(file)}
    return exported, rows


def test_pedrl_eval_runs_a_ppo_checkpoint_and_its_exported_file(tmp_path):
    """The actor is a network of the DQN's kind: pedrl-eval reads the checkpoint and its exported file alike."""
    from tests.conftest import compose_config

    cfg = compose_config("train", ["debug=default", *PPO, "algo.trials=4", "algo.iterations=1", "progress=false"])
    train(cfg, run_dir=tmp_path / "run")
    exported, rows = _eval_checkpoint_and_export(tmp_path / "run" / "checkpoints" / "last.safetensors", tmp_path)
    assert isinstance(NeuralPolicy.load(exported), NeuralPolicy)
    assert rows["checkpoint"] == rows["file"] and set(rows["file"]) == {"learned", "greedy"}


# ---------------------------------------------------------------------- the continuous head
@pytest.fixture(scope="module")
def continuous_run(tmp_path_factory):
    """A continuous PPO run of 40 trials of one process of 8 rooms (about 5 s): its folder."""
    from tests.conftest import compose_config

    run = tmp_path_factory.mktemp("continuous")
    cfg = compose_config("train", [*PPO, "algo.trials=40", "algo.epochs=10", "algo.actions=continuous",
                                   "processes=1", "rooms_per_process=8", "progress=false"])  # fmt: skip
    train(cfg, run_dir=run)
    return run


def test_continuous_ppo_learns_to_walk_better_than_its_untrained_actor(continuous_run):
    """The untrained actor walks at half the top speed straight at the goal (its outputs near 0); the learned one
    earns far more (measured 126 against 43; the greedy walker 91)."""
    learned = load_policy(continuous_run / "checkpoints" / "last.safetensors")
    assert isinstance(learned, ContinuousPolicy) and learned.metadata["algo"] == "ppo"
    untrained = ContinuousPolicy(learned.encoder, QNetwork(1, learned.num_inputs, [32, 32], 2,
                                 generator=torch.Generator().manual_seed(0)), learned.mean, learned.std)  # fmt: skip
    factory = room_factory(learned)
    before, after = _greedy_return(untrained, factory), _greedy_return(learned, factory)
    assert after > before + 50.0, (before, after)


def test_a_continuous_checkpoint_holds_its_spread_and_acts_by_commands(continuous_run):
    checkpoint = load_checkpoint(continuous_run / "checkpoints" / "last.safetensors")
    assert checkpoint.metadata["learner"] == "continuous"
    policy = load_policy(continuous_run / "checkpoints" / "last.safetensors")
    log_std = checkpoint.tensors["actor/log_std"]
    assert log_std.shape == (policy.num_processes, 2) and bool(torch.isfinite(log_std).all())
    assert not torch.equal(log_std, torch.zeros_like(log_std))  # learned from init_std=1
    room = room_factory(policy)(num_replicas=2, num_agents=4)
    obs, info = room.reset(seed=0)
    commands = policy.act(obs, info)
    assert commands.shape == (2, 4, 2) and commands.dtype == torch.float32
    assert bool((commands[..., 0] >= -0.05).all() and (commands[..., 0] <= 1.05).all())
    assert bool((commands[..., 1].abs() <= math.pi / 2 + 1e-6).all())
    explored = policy.act(obs, info, epsilon=1.0, generator=torch.Generator().manual_seed(0))
    assert not torch.equal(explored, commands) and bool((explored[..., 0] >= 0).all())


def test_a_continuous_crowd_drives_the_pettingzoo_room(continuous_run):
    """The crowd's commands and the user's discrete action (as its command) step the room as by hand."""
    from pedrl.integrations.pettingzoo import PedestrianParallelEnv
    from pedrl.sim import commands_of

    crowd = load_policy(continuous_run / "checkpoints" / "last.safetensors")
    factory = room_factory(crowd)
    env = PedestrianParallelEnv(factory(num_replicas=1, num_agents=4), crowd=crowd, learners=1)
    env.reset(seed=5)
    reference = factory(num_replicas=1, num_agents=4)
    obs, info = reference.reset(seed=5)
    walk = 8 * 9 + 4  # top speed straight at the goal
    for _ in range(6):
        if not env.agents:
            break
        commands = crowd.act(obs, info, generator=torch.Generator())
        changes = dict(speed_changes=reference.speed_changes, turn_changes=reference.turn_changes)
        commands[0, 0] = commands_of(torch.tensor(walk), **changes, max_speed=reference.params.max_speed)
        env.step({"pedestrian_0": walk})
        obs, *_, info = reference.step(commands)
        assert torch.equal(env.env.positions, reference.positions)
    from pedrl.scenarios import paper_room

    with pytest.raises(ValueError, match="continuous policy and the room's env.action_frame='heading'"):
        PedestrianParallelEnv(paper_room().room(num_agents=4), crowd=crowd, learners=1)  # the paper's frame


def test_pedrl_eval_runs_a_continuous_checkpoint_and_its_exported_file(continuous_run, tmp_path):
    checkpoint = continuous_run / "checkpoints" / "last.safetensors"
    exported, rows = _eval_checkpoint_and_export(checkpoint, tmp_path)
    assert isinstance(ContinuousPolicy.load(exported), ContinuousPolicy)
    assert rows["checkpoint"] == rows["file"] and float(rows["file"]["learned"]["fails_pct"]) < 50

"""The experiment configs: every one composes and builds; the paper ones hold Table 3; IT and IN behave as described.

The fast tests here take well under a minute together; the full quick_it / quick_in runs are marked slow.
"""

import json
import re
from pathlib import Path

import pytest
import torch
from hydra import compose as hydra_compose
from hydra import initialize_config_dir
from omegaconf import OmegaConf

from pedrl.algos.base import Trainer
from pedrl.algos.registry import build_trainer
from pedrl.cli import CONFIG_DIR
from pedrl.io import load_checkpoint, read_csv
from pedrl.train import train

EXPERIMENTS = sorted(p.stem for p in (Path(CONFIG_DIR) / "experiment").glob("*.yaml"))
PAPER = {"paper_vqql": ("VQQL", 0.25), "paper_it": ("ITVQQL", 0.35), "paper_in": ("INVQQL", 0.35)}
NAMES = {"pedrl.algos.VQQL": "vqql", "pedrl.algos.ITVQQL": "it_vqql", "pedrl.algos.INVQQL": "in_vqql"}
NAMES |= {"pedrl.algos.DQN": "dqn", "pedrl.algos.PPO": "ppo"}
K_VALUES = [512, 1024, 2048, 4096, 8192, 16384]
REWARDS = {"paper_vqql": "paper", "paper_it": "paper", "paper_in": "paper", "main": "crowd", "tuned_it": "tuned"}
REWARDS |= {"main_heading": "tuned"}
REWARDS |= {"tuned_in": "tuned", "pedestrian": "tuned", "pedestrian_mix": "tuned", "pedestrian_walk": "tuned"}
REWARDS |= {"pedestrian_lanes": "tuned", "main_factored": "crowd", "pedestrian_walk_factored": "tuned"}
REWARDS |= {"paper_it_full": "paper", "paper_in_full": "paper", "main_dqn": "crowd", "pedestrian_walk_dqn": "tuned"}
REWARDS |= {"pedestrian_free_dqn": "walk", "main_ppo": "crowd", "pedestrian_walk_ppo": "speed"}
# the paper_faithful presets and the literal ones they build on
FAITHFUL = {
    "paper_faithful_vqql": "paper_vqql",
    "paper_faithful_it": "paper_it_full",
    "paper_faithful_in": "paper_in_full",
}
REWARDS |= dict.fromkeys(FAITHFUL, "paper")
WEIGHTED = {f"paper_weighted_{method}": f"paper_faithful_{method}" for method in ("vqql", "it", "in")}
"""The paper with one change: each paper_faithful preset with the feature weights."""
REWARDS |= dict.fromkeys(WEIGHTED, "paper")
RESULTS = Path(CONFIG_DIR).parent / "docs" / "results.md"
HISTORY = Path(CONFIG_DIR).parent / "docs" / "history.md"
README = Path(CONFIG_DIR).parent / "README.md"
CONFIGURATION = Path(CONFIG_DIR).parent / "docs" / "configuration.md"
FORMER_COMMENTS = "### Measured figures formerly in the config comments"
SUPERSEDED_IN_CONF = re.compile(r"^# Superseded by experiment=(\w+): ", re.MULTILINE)
SUPERSEDED_IN_TABLE = re.compile(r"^superseded by `(\w+)`")


def quiet(cfg):
    cfg.progress = False
    cfg.logger.tensorboard = False
    return cfg


def test_the_expected_experiments_exist():
    expected = {"main", "quick_vqql", "quick_it", "quick_in", "paper_vqql", "paper_it", "paper_in", "tuned_it"}
    assert expected | {"tuned_in", "k_sweep"} <= set(EXPERIMENTS)


@pytest.mark.parametrize("name", EXPERIMENTS)
def test_every_experiment_composes_and_builds_a_trainer(name, compose, tmp_path):
    text = (Path(CONFIG_DIR) / "experiment" / f"{name}.yaml").read_text()
    assert text.startswith("# @package _global_\n"), "experiment files are global packages"
    assert "  - override /algo: " in text, "experiment files pick their algorithm with `override /algo: ...`"
    cfg = compose("train", [f"experiment={name}"])
    trainer = build_trainer(cfg, tmp_path)
    assert trainer.phases()
    assert trainer.name == NAMES[cfg.algo._target_]


def experiment_file(name):
    """An experiment file's body (plain containers) and its group choices, as overrides (``algo=it_vqql``); an
    experiment it builds on (a plain name in its defaults) is ``experiment=<name>``."""
    body = OmegaConf.to_container(OmegaConf.load(Path(CONFIG_DIR) / "experiment" / f"{name}.yaml"))
    choices = [
        f"experiment={entry}" if isinstance(entry, str) else f"{key.removeprefix('override /')}={value}"
        for entry in body.pop("defaults")
        for key, value in ([(None, entry)] if isinstance(entry, str) else entry.items())
    ]
    body.pop("hydra", None)
    return body, choices


def leaves(node, prefix=""):
    for key, value in node.items():
        if isinstance(value, dict):
            yield from leaves(value, f"{prefix}{key}.")
        else:
            yield f"{prefix}{key}", value


@pytest.mark.parametrize("name", EXPERIMENTS)
def test_experiment_files_change_only_what_differs(name, compose):
    """Every key an experiment sets differs from what its groups (algo, rewards) and the defaults give without it."""
    body, choices = experiment_file(name)
    base = OmegaConf.to_container(compose("train", choices), resolve=True)
    for key, value in leaves(body):
        default = base
        for part in key.split("."):  # a key under a default of null (vq.factors) is new: it differs
            default = default.get(part) if isinstance(default, dict) else None
        assert (type(default), default) != (type(value), value), f"experiment/{name}.yaml restates {key}={value!r}"


@pytest.mark.parametrize("name", EXPERIMENTS)
def test_experiments_take_their_rewards_from_the_rewards_group(name, compose):
    body, choices = experiment_file(name)
    assert not [key for key in body.get("env", {}) if key.startswith("reward_")], "rewards come from conf/rewards/"
    expected = REWARDS.get(name)
    rewards, pending = [], list(choices)
    while pending:  # the file's own choices, then those of the experiments it builds on, and theirs
        choice = pending.pop(0)
        rewards += [choice] if choice.startswith("rewards=") else []
        pending += experiment_file(choice.removeprefix("experiment="))[1] if choice.startswith("experiment=") else []
    # the first choice is the one that applies (the file's own, over those of the experiments it builds on)
    assert rewards[:1] == ([f"rewards={expected}"] if expected else [])
    env = compose("train", [f"experiment={name}"]).env
    rewards = OmegaConf.load(Path(CONFIG_DIR) / "rewards" / f"{expected or 'default'}.yaml")
    assert {key: env[key] for key in rewards} == OmegaConf.to_container(rewards)


def test_a_rewards_choice_on_the_command_line_wins_over_the_experiments(compose):
    paper = OmegaConf.load(Path(CONFIG_DIR) / "rewards" / "paper.yaml")
    env = compose("train", ["experiment=main", "rewards=paper"]).env
    assert {key: env[key] for key in paper} == OmegaConf.to_container(paper)
    room = OmegaConf.load(Path(CONFIG_DIR) / "env" / "room.yaml")
    env = compose("train", ["experiment=paper_it", "rewards=default"]).env
    assert all(env[key] == room[key] for key in room if key.startswith("reward_"))


@pytest.mark.parametrize("name", EXPERIMENTS)
def test_measured_figures_are_in_the_docs_not_the_config(name):
    """An experiment's header points to the docs for its measured figures; the figures its header once stated, where
    it points to them, are in docs/history.md under the experiment's name."""
    text = (Path(CONFIG_DIR) / "experiment" / f"{name}.yaml").read_text()
    assert "Measured here" not in text
    assert "docs/results.md" in text or "docs/history.md" in text, "the header says where its figures are"
    history = HISTORY.read_text()
    assert FORMER_COMMENTS in history
    if "history.md#measured-figures-formerly-in-the-config-comments" in text:
        section = history.split(FORMER_COMMENTS, 1)[1].split("\n## ", 1)[0]
        assert f"`{name}" in section or f"{name}`" in section, name


def experiment_tables():
    """The experiment tables of the README and of docs/configuration.md: for each page, ``{preset: what}`` from the
    rows whose first cell lists presets in backticks."""
    tables = {}
    for page in (README, CONFIGURATION):
        rows = {}
        table = page.read_text().split("| experiment | what |", 1)[1].split("\n\n", 1)[0]
        for line in table.splitlines()[2:]:
            first, what = line.split("|")[1:3]
            rows |= dict.fromkeys(re.findall(r"`(\w+)`", first), what.strip())
        tables[page.name] = rows
    return tables


def superseded_in_conf():
    """``{preset: successor}`` of every experiment whose header labels it superseded."""
    labels = {}
    for name in EXPERIMENTS:
        found = SUPERSEDED_IN_CONF.findall((Path(CONFIG_DIR) / "experiment" / f"{name}.yaml").read_text())
        assert len(found) <= 1, f"experiment/{name}.yaml: one label at most"
        if found:
            labels[name] = found[0]
    return labels


def label_mismatches(tables, in_conf):
    """What differs between the labels in conf/experiment/ and in each page's experiment table, as lines."""
    problems = []
    for page, rows in tables.items():
        if set(rows) != set(EXPERIMENTS):
            problems.append(f"{page}: rows {sorted(set(rows) ^ set(EXPERIMENTS))} differ from conf/experiment/")
        in_table = {name: m.group(1) for name, what in rows.items() if (m := SUPERSEDED_IN_TABLE.match(what))}
        if in_table != in_conf:
            problems.append(f"{page} labels {in_table} superseded, conf/experiment/ labels {in_conf}")
    return problems


def test_presets_a_user_should_not_pick_are_labelled_alike_in_conf_and_the_docs():
    """A preset labelled superseded in its header (``# Superseded by experiment=X: why``) is labelled so, with the same
    successor, in the README's experiment table and in docs/configuration.md's ("superseded by `X`: why"), and no
    other preset is; every preset has its row in both tables, and a successor is a preset that is not superseded."""
    in_conf = superseded_in_conf()
    assert {"main_heading", "pedestrian", "pedestrian_mix"} <= set(in_conf)
    assert not label_mismatches(experiment_tables(), in_conf)
    assert all(successor in EXPERIMENTS and successor not in in_conf for successor in in_conf.values())


def test_a_superseded_label_missing_from_one_side_is_found():
    """The controls: a label dropped from the README's table, and one added there that conf lacks."""
    in_conf = superseded_in_conf()
    dropped = experiment_tables()
    dropped["README.md"]["pedestrian"] = "the main job with pedestrian bodies"
    assert [line.split(" labels")[0] for line in label_mismatches(dropped, in_conf)] == ["README.md"]
    added = experiment_tables()
    added["configuration.md"]["tuned_it"] = "superseded by `main`: a label conf does not have"
    assert [line.split(" labels")[0] for line in label_mismatches(added, in_conf)] == ["configuration.md"]
    assert not label_mismatches(experiment_tables(), in_conf)


# ---------------------------------------------------------------------- the paper, literally
@pytest.mark.parametrize("name", sorted(PAPER))
def test_paper_experiments_are_the_paper_literally(name, compose, tmp_path):
    """Tables 2 and 3, the stop rule, plain standardisation of raw distances, 20 independent processes of one room
    and one table per learning agent: only the trial budget may differ from the paper."""
    cfg = compose("train", [f"experiment={name}"])
    target, alpha = PAPER[name]
    assert cfg.algo._target_ == f"pedrl.algos.{target}"
    # Table 3 (VQQL: alpha = 0.25, section 5.1)
    assert (cfg.algo.gamma, cfg.algo.epsilon_start, cfg.algo.alpha) == (0.91, 0.4, alpha)
    assert cfg.env.decisions_per_second == 1.0
    # sections 2 and 5: the room, the body, the senses, the trial length
    assert (cfg.env.width, cfg.env.length, cfg.env.door_width, cfg.env.max_decisions) == (60.0, 100.0, 2.0, 200)
    assert (cfg.env.agent_radius, cfg.env.num_neighbours, cfg.env.num_walls) == (0.4, 7, 2)
    assert cfg.env.action_frame == "heading"  # section 2: actions change the speed and the heading
    # Table 2, and nothing else paid: no progress reward, no time cost
    rewards = (cfg.env.reward_goal, cfg.env.reward_crash_wall, cfg.env.reward_crash_agent, cfg.env.reward_default)
    assert rewards == (100.0, -15.0, -4.0, 0.0)
    assert cfg.env.reward_progress == 0.0
    # a body that would enter another stops; movers in a random order
    assert dict(cfg.env.motion) == {"name": "stop", "order": "random"}
    # plain standardisation of the raw features (section 5.1), K = 4096 per learning process
    assert (cfg.vq.distance_transform, cfg.vq.weight_own, cfg.vq.weight_neighbours, cfg.vq.weight_walls) == (
        "none",
        1.0,
        1.0,
        1.0,
    )
    assert (cfg.vq.num_prototypes, cfg.vq.per_process) == (4096, True)
    # 20 independent learning processes of one room, one table per learning agent
    assert (cfg.processes, cfg.rooms_per_process, cfg.algo.tables) == (20, 1, "agent")
    phases = build_trainer(cfg, tmp_path).phases()
    assert phases[0].gather_epsilon == 1.0  # the first phase gathers from a random walk
    if name == "paper_vqql":
        assert [p.num_agents for p in phases] == [20] * len(phases)
        assert sum(p.trials for p in phases) == cfg.algo.trials
    if name == "paper_it":
        assert [p.num_agents for p in phases] == [20] * len(phases) and len(phases) >= 2
        assert [p.gather_epsilon for p in phases[1:]] == [0.07] * (len(phases) - 1)
        assert cfg.algo.void_features == "random"  # section 5.1
    if name == "paper_in":
        assert [p.num_agents for p in phases] == [1, 2, 3, 4, 5, 6, 7, 8, 10, 20]
        assert [p.gather_epsilon for p in phases[1:]] == [0.07] * 9
        budgets = [p.trials for p in phases]
        assert budgets == sorted(budgets)  # trials grow with the number of agents


@pytest.mark.parametrize(("name", "trials"), [("paper_vqql", 90), ("paper_it", 90), ("paper_in", 70)])
def test_paper_experiments_state_their_budget(name, trials, compose, tmp_path):
    """Each file states its trial budget and as many trials as it runs; how long the paper's would take,
    extrapolated from a measured partial run, is in docs/results.md."""
    text = (Path(CONFIG_DIR) / "experiment" / f"{name}.yaml").read_text()
    assert "Budget:" in text and "extrapolated from a measured partial run" in text
    assert "docs/history.md#the-papers-budgets-fused" in text.replace("\n# ", " ")
    assert f"{trials} trials" in text
    extrapolated = HISTORY.read_text().split("\n### The paper's budgets, fused\n", 1)[1].split("\n### ", 1)[0]
    assert re.search(rf"^- `{name}`: .* hours", extrapolated, re.MULTILINE), name
    phases = build_trainer(compose("train", [f"experiment={name}"]), tmp_path).phases()
    assert sum(p.trials for p in phases) == trials


def test_paper_in_full_stages_follow_figure_6s_caption(compose, tmp_path):
    """Figure 6: the curves of 1 to 8 agents end below 1.5 x 10^5 trials, those of 10 and 20 agents beyond
    1.2 x 10^5; the trials grow with the learning agents (section 5.2)."""
    phases = build_trainer(compose("train", ["experiment=paper_in_full"]), tmp_path).phases()
    budgets = {p.num_agents: p.trials for p in phases}
    assert list(budgets) == [1, 2, 3, 4, 5, 6, 7, 8, 10, 20]
    assert all(budgets[m] < 150_000 for m in range(1, 9))
    assert budgets[10] > 120_000 and budgets[20] > 120_000
    assert list(budgets.values()) == sorted(budgets.values())


@pytest.mark.parametrize("name", sorted(FAITHFUL))
def test_paper_faithful_presets_keep_every_stated_choice(name, compose, tmp_path):
    """A paper_faithful preset differs from its literal preset only in what the paper leaves open (the room's unit,
    the door's width) and, for VQQL, in the budget of the paper's reference curve; its budget is the paper's."""

    def flat(experiment):
        return dict(leaves(OmegaConf.to_container(compose("train", [f"experiment={experiment}"]), resolve=True)))

    faithful, literal = flat(name), flat(FAITHFUL[name])
    open_choices = {"env.width": 30.0, "env.length": 50.0, "env.door_width": 4.0}
    budget = {"algo.trials", "algo.iterations", "checkpoint_every"} if name == "paper_faithful_vqql" else set()
    differ = {key for key in faithful.keys() | literal.keys() if faithful.get(key) != literal.get(key)}
    assert differ == set(open_choices) | budget
    assert {key: faithful[key] for key in open_choices} == open_choices
    phases = build_trainer(compose("train", [f"experiment={name}"]), tmp_path).phases()
    papers = {"paper_faithful_vqql": 109_686, "paper_faithful_it": 109_686, "paper_faithful_in": 990_000}
    assert sum(p.trials for p in phases) == papers[name]


@pytest.mark.parametrize("name", sorted(WEIGHTED))
def test_paper_weighted_presets_differ_from_the_faithful_ones_only_in_the_feature_weights(name, compose):
    def flat(experiment):
        return dict(leaves(OmegaConf.to_container(compose("train", [f"experiment={experiment}"]), resolve=True)))

    weighted, faithful = flat(name), flat(WEIGHTED[name])
    differ = {key for key in weighted.keys() | faithful.keys() if weighted.get(key) != faithful.get(key)}
    assert differ == {"vq.weight_own", "vq.weight_neighbours", "vq.weight_walls"}
    assert (weighted["vq.weight_own"], weighted["vq.weight_neighbours"], weighted["vq.weight_walls"]) == (4.0, 0.2, 0.5)


@pytest.mark.parametrize("name", ["tuned_it", "tuned_in"])
def test_tuned_experiments_keep_the_papers_room_and_table_3(name, compose):
    cfg = compose("train", [f"experiment={name}"])
    assert (cfg.env.width, cfg.env.length, cfg.env.door_width, cfg.env.max_decisions) == (60.0, 100.0, 2.0, 200)
    assert (cfg.algo.gamma, cfg.algo.epsilon_start, cfg.algo.alpha) == (0.91, 0.4, 0.35)
    assert (cfg.vq.num_prototypes, cfg.vq.per_process) == (4096, True)
    # the project's choices, as the main job's before the goal action frame
    main = compose("train", ["experiment=main_heading"]).env
    for key in ("motion", "reward_progress", "reward_default", "reward_crash_agent"):
        assert cfg.env[key] == main[key], key


@pytest.mark.parametrize("name", EXPERIMENTS)
def test_no_preset_pays_a_contact_better_than_a_free_step(name, compose):
    """Table 2's priority, "the prevention of collisions is the main task": a decision in which another body or a
    wall cut the agent's move pays less than a free decision with the same progress (the progress reward is paid
    on both alike)."""
    env = compose("train", [f"experiment={name}"]).env
    assert env.reward_crash_agent < env.reward_default, (env.reward_crash_agent, env.reward_default)
    assert env.reward_crash_wall < env.reward_default, (env.reward_crash_wall, env.reward_default)
    assert env.reward_goal > env.reward_default


def test_k_sweep_is_a_multirun_over_the_papers_k_values():
    with initialize_config_dir(version_base="1.3", config_dir=CONFIG_DIR):
        cfg = hydra_compose("train", ["experiment=k_sweep"], return_hydra_config=True)
    assert str(cfg.hydra.mode) in ("MULTIRUN", "RunMode.MULTIRUN")
    swept = cfg.hydra.sweeper.params["vq.num_prototypes"]
    assert [int(k) for k in str(swept).split(",")] == K_VALUES
    assert cfg.algo._target_ == "pedrl.algos.VQQL"


# ---------------------------------------------------------------------- IT-VQQL: data from the previous policy
def test_it_vqql_gathers_iteration_2_from_iteration_1s_greedy_policy(compose, tmp_path, monkeypatch):
    """Iteration 2's dataset comes from iteration 1's tables, epsilon-greedy with 0.07, not from a random walk:
    the agents reach the door far more often while it is gathered than in iteration 1's random walk."""
    gathered = []
    original = Trainer.gather

    def spy(self, phase, env, previous):
        tables = None if previous is None else previous[1].clone()
        gathered.append((phase.index, phase.gather_epsilon, tables))
        return original(self, phase, env, previous)

    monkeypatch.setattr(Trainer, "gather", spy)
    overrides = ["experiment=quick_it", "processes=2", "algo.iterations=2", "algo.trials=[40,1]"]
    cfg = quiet(compose("train", overrides))
    train(cfg, run_dir=tmp_path)

    (first, first_epsilon, first_tables), (second, second_epsilon, second_tables) = gathered
    assert (first, first_epsilon, first_tables) == (1, 1.0, None)  # a random walk
    assert (second, second_epsilon) == (2, 0.07)
    iteration_1 = load_checkpoint(tmp_path / "checkpoints" / "iter_0001.safetensors").tensors["q_values"]
    assert torch.equal(second_tables, iteration_1)  # followed the tables iteration 1 learned
    phases = json.loads((tmp_path / "summary.json").read_text())["phases"]
    random_walk, greedy = phases[0]["gather_success_rate"], phases[1]["gather_success_rate"]
    assert greedy > 2 * random_walk and greedy > random_walk + 0.1, (random_walk, greedy)


# ---------------------------------------------------------------------- IN-VQQL: stages, checkpoints, learning
def test_in_vqql_tiny_run_checkpoints_every_stage_and_learns(compose, tmp_path):
    overrides = [
        "experiment=quick_in",
        "processes=2",
        "algo.stages=[1,2,4]",
        "algo.trials=[30,10,30]",
        "vq.num_prototypes=128",
    ]
    train(quiet(compose("train", overrides)), run_dir=tmp_path)
    names = sorted(p.name for p in (tmp_path / "checkpoints").iterdir())
    assert names == ["iter_0001.safetensors", "iter_0002.safetensors", "iter_0003.safetensors", "last.safetensors"]
    for stage, agents in enumerate((1, 2, 4), start=1):
        checkpoint = load_checkpoint(tmp_path / "checkpoints" / f"iter_{stage:04d}.safetensors")
        assert checkpoint.metadata["agents"] == agents
        # the union quantizer grows by K prototypes per stage; one table per process (algo.tables=process)
        assert checkpoint.tensors["q_values"].shape == (2, 1, 128 * stage, 81)
    summary = json.loads((tmp_path / "summary.json").read_text())
    random_walk = summary["phases"][0]["gather_success_rate"]
    last_stage = [float(r["success_rate_mean"]) for r in read_csv(tmp_path / "learning_curve.csv") if r["phase"] == "3"]
    late = sum(last_stage[-10:]) / 10
    assert late > 2 * random_walk and late > random_walk + 0.2, (late, random_walk)


# ---------------------------------------------------------------------- the quick experiments in full
@pytest.mark.slow
@pytest.mark.parametrize(("name", "minimum"), [("quick_it", 0.45), ("quick_in", 0.3)])
def test_quick_experiments_learn(name, minimum, compose, tmp_path):
    """The full quick_it / quick_in runs (about a minute each here): 20 agents learn to leave the room."""
    result = train(quiet(compose("train", [f"experiment={name}"])), run_dir=tmp_path)
    phases = result.phases
    assert result.final["success_rate_mean"] > minimum
    assert result.final["success_rate_mean"] > 3 * phases[0]["gather_success_rate"]
    assert phases[-1]["gather_success_rate"] > phases[0]["gather_success_rate"]


def debug_jobs(name):
    """The overrides of every job ``pedrl-train experiment=<name> debug=default`` runs: one, or one per value of its
    sweep (``hydra.sweeper.params``)."""
    base = [f"experiment={name}", "debug=default"]
    with initialize_config_dir(version_base="1.3", config_dir=CONFIG_DIR):
        params = hydra_compose("train", base, return_hydra_config=True).hydra.sweeper.params or {}
    jobs = [base]
    for key, values in params.items():
        jobs = [[*job, f"{key}={value}"] for job in jobs for value in str(values).split(",")]
    return jobs


@pytest.mark.parametrize("name", EXPERIMENTS)
def test_every_preset_composes_with_debug_and_passes_the_checks(name, compose, tmp_path):
    """Any preset can be smoke-tested with debug=default: every job it runs (each K of k_sweep's sweep) composes and
    passes every check made before compute (main's 80 bodies did not fit the debug room; k_sweep's K above 1200 did
    not fit its gather)."""
    for overrides in debug_jobs(name):
        cfg = compose("train", overrides)
        assert cfg.env.max_decisions <= 30 and cfg.vq.max_iterations <= 10, "debug shrinks every budget"
        trainer = build_trainer(cfg, tmp_path / "_".join(overrides).replace("=", "-"))
        assert trainer.phases()


def test_the_main_jobs_debug_run_trains_end_to_end(tmp_path, capsys):
    """``pedrl-train experiment=main debug=default``, the main job's smoke run, as a user runs it."""
    import pedrl.train
    from tests.refusals import run_hydra_main

    run_dir = tmp_path / "main"
    outcome = run_hydra_main(pedrl.train, ["experiment=main", "debug=default", f"hydra.run.dir={run_dir}"], capsys)
    assert outcome.code in (0, None), outcome.stderr
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["algo"] == "it_vqql" and 0.0 <= summary["final"]["success_rate_mean"] <= 1.0
    assert (run_dir / "checkpoints" / "last.safetensors").is_file()
    assert load_checkpoint(run_dir / "checkpoints" / "last.safetensors").metadata["config"]["algo"]["num_agents"] == 20

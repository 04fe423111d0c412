"""The bad-input catalogue: every entry point refuses a bad value, path or file before any compute.

Each case runs a real entry point (``pedrl-train``, ``pedrl-eval``, ``pedrl-plot`` as Hydra applications with
``sys.argv`` set, ``pedrl-sweep`` with its argv) in this process, and asserts what a user sees: exit code 2, exactly
one line on stderr, ``<program>: error: ...`` naming the bad value and what is allowed, no traceback, and a run
folder holding nothing beyond Hydra's own ``.hydra/`` and log file. In-process calls keep the catalogue fast (a
subprocess costs seconds of imports); :func:`test_real_entry_points_behave_the_same` runs one case of every command
as a real subprocess.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from omegaconf import OmegaConf, open_dict

import pedrl.evaluate
import pedrl.plot
import pedrl.sweep
import pedrl.train
import pedrl.validate
from pedrl.algos.base import CURVE_COLUMNS
from pedrl.train import CONFIG_DIR, train

HYDRA_OWN = {".hydra", "train.log", "evaluate.log", "plot.log", "validate.log"}
"""What Hydra writes into a run folder before the job starts: nothing else may be there after a refusal."""


# ---------------------------------------------------------------------- running an entry point in this process
@dataclass(frozen=True)
class Outcome:
    """What a user saw: the exit code and the non-empty lines of stderr."""

    code: int | str | None
    lines: list[str]
    stderr: str


def run_hydra_main(module, args: list[str], capsys) -> Outcome:
    """Call ``module.main()`` (a ``@hydra.main`` entry point) as the console script would, with ``args``."""
    capsys.readouterr()
    saved = sys.argv
    sys.argv = [f"{module.__name__}.py", *args]
    code: int | str | None = 0
    try:
        module.main()
    except SystemExit as exit_:
        code = exit_.code
    finally:
        sys.argv = saved
        GlobalHydra.instance().clear()
    err = capsys.readouterr().err
    return Outcome(code, [line for line in err.splitlines() if line.strip()], err)


def run_sweep_main(args: list[str], capsys) -> Outcome:
    capsys.readouterr()
    code: int | str | None = 0
    try:
        pedrl.sweep.main(args)
    except SystemExit as exit_:
        code = exit_.code
    err = capsys.readouterr().err
    return Outcome(code, [line for line in err.splitlines() if line.strip()], err)


def assert_refused(outcome: Outcome, program: str, fragments: tuple[str, ...]) -> None:
    """Exit code 2 and one line ``<program>: error: ...`` holding every fragment (the value, what is allowed)."""
    assert "Traceback" not in outcome.stderr, outcome.stderr
    assert outcome.code == 2, outcome.stderr
    assert len(outcome.lines) == 1, outcome.stderr
    line = outcome.lines[0]
    assert line.startswith(f"{program}: error: "), line
    for fragment in fragments:
        assert fragment in line, f"{fragment!r} not in {line!r}"


def catalogue(cases: list[tuple], fast: set[str], *, named: bool = False) -> list:
    """``cases`` as pytest params with their first item as id (and, if ``named``, only as id); those not in ``fast``
    are marked ``slow``: ``make test`` runs a sample (every item of issue 11, a case or more per group),
    ``make test-all`` all of them."""
    unknown = fast - {str(case[0]) for case in cases}
    assert not unknown, f"fast sample names unknown cases: {unknown}"
    return [
        pytest.param(*(case[1:] if named else case), id=str(case[0]), marks=() if case[0] in fast else pytest.mark.slow)
        for case in cases
    ]


def assert_nothing_computed(run_dir: Path) -> None:
    if run_dir.is_dir():
        assert set(os.listdir(run_dir)) <= HYDRA_OWN, sorted(os.listdir(run_dir))


# ---------------------------------------------------------------------- fixtures: what the cases refer to
@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    """``last.safetensors`` of a seconds-long VQQL run (2 processes, 2 agents, a 10 m x 10 m room)."""
    with initialize_config_dir(version_base="1.3", config_dir=CONFIG_DIR):
        cfg = compose(
            "train",
            [
                "debug=default",
                "algo=vqql",
                "algo.num_agents=2",
                "algo.trials=2",
                "vq.num_prototypes=8",
                "env.max_decisions=10",
                "logger=none",
            ],
        )
    with open_dict(cfg):
        cfg.progress = False
    run_dir = tmp_path_factory.mktemp("trained")
    threads = torch.get_num_threads()
    try:
        train(cfg, run_dir=run_dir)
    finally:
        torch.set_num_threads(threads)
    return run_dir / "checkpoints" / "last.safetensors"


@pytest.fixture
def read_only_dir(tmp_path) -> Path:
    """A folder nobody may write in: a mode-0555 folder, or for root (who ignores modes) read-only ``/sys``."""
    folder = tmp_path / "read_only"
    folder.mkdir()
    folder.chmod(0o555)
    candidates = [folder, Path("/sys")]
    for candidate in candidates:
        try:
            (candidate / "probe").mkdir()
        except OSError:
            yield candidate
            break
        (candidate / "probe").rmdir()
    else:
        pytest.skip("no read-only folder on this machine")
    folder.chmod(0o755)


def write_curve(path: Path, rows: int = 4) -> Path:
    """A learning_curve.csv as pedrl-train writes it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=CURVE_COLUMNS)
        writer.writeheader()
        for trial in range(rows):
            row = {column: 0.0 for column in CURVE_COLUMNS}
            row.update(phase=1, agents=2, trial=trial, global_trial=trial)
            writer.writerow(row)
    return path


def make_job(sweep_dir: Path, name: str = "0") -> Path:
    """A finished job of a ``pedrl-train --multirun`` sweep: summary.json and .hydra/{overrides,config}.yaml."""
    job = sweep_dir / name
    (job / ".hydra").mkdir(parents=True)
    OmegaConf.save(OmegaConf.create(["vq.num_prototypes=512"]), job / ".hydra" / "overrides.yaml")
    OmegaConf.save(OmegaConf.create({"vq": {"num_prototypes": 512}}), job / ".hydra" / "config.yaml")
    final = {f"{m}_{s}": 0.5 for m in pedrl.sweep.FINAL_METRICS for s in ("mean", "std")}
    (job / "summary.json").write_text(json.dumps({"algo": "vqql", "final": final, "wall_time_s": 1.0}))
    return job


# ---------------------------------------------------------------------- pedrl-train
TRAIN_BASE = ["debug=default", "logger=none"]
"""Every train case adds its overrides to a debug-sized run: with a good value it would run in seconds."""

TRAIN_CASES: list[tuple[str, tuple[str, ...]]] = [
    # ---- top level (conf/train.yaml)
    ("processes=0", ("processes=0 is invalid", "integer >= 1")),
    ("processes=-2", ("processes=-2", "integer >= 1")),
    ("processes=abc", ("processes='abc'", "integer >= 1")),
    ("processes=1.5", ("processes=1.5", "integer >= 1")),
    ("processes=1e9", ("processes=1000000000.0", "digits only", "write 1000000000")),
    ("processes=1000000000", ("needs about", "GiB", "available", "processes")),
    ("processes=100000", ("needs about", "gathered states", "processes")),
    ("rooms_per_process=0", ("rooms_per_process=0", "integer >= 1")),
    ("rooms_per_process=10000000", ("needs about", "GiB", "rooms_per_process")),
    ("checkpoint_every=-1", ("checkpoint_every=-1", "integer >= 0")),
    ("checkpoint_every=often", ("checkpoint_every='often'", "integer >= 0")),
    ("seed=-1", ("seed=-1", "integer in [0, 4294967295]")),
    ("seed=1e18", ("seed=1e+18", "integer in [0, 4294967295]")),
    ("seed=10000000000000", ("seed=10000000000000", "integer in [0, 4294967295]")),
    ("seed=abc", ("seed='abc'", "integer in")),
    ("threads=0", ("threads=0", "integer >= 1")),
    ("threads=two", ("threads='two'", "integer >= 1")),
    ("device=meta", ("device='meta'", "cpu or cuda")),
    ("device=tpu", ("device='tpu'", "cpu or cuda")),
    ("device=cuda:99", ("device='cuda:99'", "cpu or cuda")),
    ("progress=maybe", ("progress='maybe'", "true or false")),
    ("progress=2", ("progress=2", "true or false")),
    ("logger.tensorboard=maybe", ("logger.tensorboard='maybe'", "true or false")),
    ("resume=5", ("resume=5", "null, true, a run directory or the path")),
    ("resume=true", ("resume=true", "does not exist")),
    # ---- the room (conf/env/room.yaml)
    ("env.width=0", ("width=0", "> 0")),
    ("env.width=-5", ("width=-5", "> 0")),
    ("env.width=inf", ("width=inf", "finite")),
    ("env.width=wide", ("width='wide'", "finite number")),
    ("env.length=0", ("length=0", "> 0")),
    ("env.door_width=100", ("door_width=100", "at most width")),
    ("env.door_width=0", ("door_width=0", "> 0")),
    ("env.agent_radius=5", ("agent_radius=5", "at most")),
    ("env.agent_radius=0", ("agent_radius=0", "> 0")),
    ("env.max_speed=0", ("max_speed=0", "> 0")),
    ("env.max_speed=1e5", ("max_speed=100000.0", "2.5e+05 sub-steps", "at most 1000")),
    ("env.max_speed=1e9", ("max_speed=1000000000.0", "sub-steps", "at most 1000")),
    ("env.decisions_per_second=0", ("decisions_per_second=0", "> 0")),
    ("env.decisions_per_second=1e-9", ("decisions_per_second=1e-09", "sub-steps", "at most 1000")),
    ("env.max_decisions=0", ("max_decisions=0", "integer >= 1")),
    ("env.max_decisions=1.5", ("max_decisions=1.5", "integer >= 1")),
    ("env.max_decisions=1000000000", ("needs about", "gathered states", "env.max_decisions")),
    ("env.num_neighbours=-1", ("num_neighbours=-1", "integer >= 0")),
    ("env.num_walls=6", ("num_walls=6", "integer in [0, 5]")),
    ("env.speed_ratios=[1,2]", ("speed_ratios has 2 values", "9 finite numbers")),
    ("env.speed_ratios=fast", ("speed_ratios", "9 finite numbers")),
    ("env.speed_ratios=[-1,-0.5,-0.25,-0.1,0.5,0.1,0.25,0.5,1]", ("speed_ratios[4]=0.5", "must be 0.0")),
    ("env.turn_ratios=[0,0,0,0,0,0,0,0,nan]", ("turn_ratios[8]=nan", "finite number")),
    ("env.reward_goal=1e38", ("reward_goal=1e+38", "[-1e+06, 1e+06]")),
    ("env.reward_crash_wall=-1e38", ("reward_crash_wall=-1e+38", "[-1e+06, 1e+06]")),
    ("env.reward_crash_agent=nan", ("reward_crash_agent=nan", "[-1e+06, 1e+06]")),
    ("env.reward_default=abc", ("reward_default='abc'", "[-1e+06, 1e+06]")),
    ("env.reward_progress=-1", ("reward_progress=-1", "[0, 1e+06]")),
    ("env.reward_progress=1e7", ("reward_progress=10000000.0", "[0, 1e+06]")),
    ("env.substep_length=1", ("substep_length=1", "agent_radius")),
    ("env.substep_length=0", ("substep_length=0", "> 0")),
    ("env.substep_length=1e-9", ("substep_length=1e-09", "sub-steps", "at most 1000")),
    ("env.collision_rule=both", ("collision_rule='both'", "sequential, simultaneous")),
    ("env.collision_order=last", ("collision_order='last'", "random, door_first")),
    ("env.contact=bounce", ("contact='bounce'", "stop, slide, headway, yield")),
    ("env.time_gap=0", ("time_gap=0", "> 0")),
    ("env.contact=headway env.collision_rule=simultaneous", ("collision_rule='simultaneous'", "contact='headway'")),
    ("env.goal_depth=-1", ("goal_depth=-1", ">= 0")),
    ("algo.num_agents=100000", ("num_agents=100000", "cannot be placed")),
    # ---- the scenario (conf/scenario/*.yaml)
    ("scenario=mall", ("scenario='mall' is invalid", "must be one of bottleneck, corner")),
    ("scenario.name=mall", ("scenario.name='mall' is invalid", "paper_room, bottleneck")),
    ("scenario=corner algo.num_agents=20", ("num_agents=20", "cannot be placed in spawn area 0")),
    ("scenario=bottleneck scenario.opening=-1", ("scenario.opening=-1", "> 0")),
    ("scenario=bottleneck scenario.opening=20", ("scenario.opening=20", "at most room_width")),
    ("scenario=four_exits scenario.closed_exits=[0,1,2,3]", ("closed_exits", "at least one exit must stay open")),
    ("scenario=corridor scenario.exits=[[0,0,1,1]]", ("scenario.exits is set without scenario.geometry",)),
    ("+scenario.doors=2", ("scenario.doors is not a setting of scenario 'paper_room'", "allowed: width")),
    ("scenario=custom scenario.geometry={tmp}/none.wkt scenario.exits=[[0,0,1,0]]", ("none.wkt", "cannot read it")),
    ("scenario=custom scenario.geometry={tmp}/bowtie.wkt scenario.exits=[[10,0,10,10]]", ("Self-intersection",)),
    ("scenario=custom scenario.geometry={tmp}/square.wkt scenario.exits=[[5,5,6,5]]", ("on the boundary",)),
    (
        "scenario=custom scenario.geometry={tmp}/square.wkt scenario.exits=[[10,2,10,4]] scenario.spawn=[[8,8,12,12]]",
        ("spawn area 0", "inside the walkable area"),
    ),
    # ---- the quantizer (conf/vq/default.yaml)
    ("vq.num_prototypes=1", ("vq.num_prototypes=1", "integer >= 2")),
    ("vq.num_prototypes=many", ("vq.num_prototypes='many'", "integer >= 2")),
    ("vq.num_prototypes=100000000", ("vq.max_states=200000", "at least vq.num_prototypes=100000000")),
    ("vq.max_iterations=0", ("vq.max_iterations=0", "integer >= 1")),
    ("vq.max_iterations=-3", ("vq.max_iterations=-3", "integer >= 1")),
    ("vq.tolerance=-1", ("vq.tolerance=-1", ">= 0")),
    ("vq.tolerance=nan", ("vq.tolerance=nan", ">= 0")),
    ("vq.tolerance=small", ("vq.tolerance='small'", ">= 0")),
    ("vq.max_states=0", ("vq.max_states=0", "integer >= 1")),
    ("vq.max_states=10", ("vq.max_states=10", "at least vq.num_prototypes=32")),
    ("vq.num_prototypes=4096", ("vq.num_prototypes=4096", "gathers at most 1200 states per process", "gather_trials")),
    ("vq.init=foo", ("vq.init='foo'", "kmeans++, random")),
    ("vq.init=3", ("vq.init=3", "kmeans++, random")),
    ("vq.chunk_size=-5", ("vq.chunk_size=-5 is invalid: must be an integer >= 1",)),
    ("vq.chunk_size=0", ("vq.chunk_size=0", "integer >= 1")),
    ("vq.chunk_size=1.5", ("vq.chunk_size=1.5", "integer >= 1")),
    ("vq.weight_own=-2", ("vq.weight_own=-2", "> 0")),
    ("vq.weight_own=0", ("vq.weight_own=0", "> 0")),
    ("vq.weight_walls=-1", ("vq.weight_walls=-1", "> 0")),
    ("vq.weight_neighbours=[1,2]", ("vq.weight_neighbours=[1, 2]", "list of 7 numbers")),
    ("vq.weight_neighbours=-1", ("vq.weight_neighbours=-1", "a number > 0")),
    ("vq.per_process=maybe", ("vq.per_process='maybe'", "true or false")),
    ("vq.distance_transform=sqrt", ("vq.distance_transform='sqrt'", "none, log")),
    ("+vq.foo=1", ("vq.foo is not a quantizer setting", "num_prototypes")),
    # ---- VQQL (conf/algo/vqql.yaml)
    ("algo.trials=0", ("trials=0", "integer in [2, 1000000000]")),
    ("algo.trials=abc", ("trials='abc'", "integer in")),
    ("algo.trials=10000000000", ("trials=10000000000", "integer in [2, 1000000000]")),
    ("algo.iterations=0", ("iterations=0", "integer in [1, 1000000000]")),
    ("algo.iterations=5 algo.trials=2", ("trials=2", "integer in [5, 1000000000]")),
    ("algo.alpha=2.0", ("alpha=2.0", "(0, 1]")),
    ("algo.alpha=0", ("alpha=0", "(0, 1]")),
    ("algo.gamma=1.5", ("gamma=1.5", "[0, 1]")),
    ("algo.epsilon_start=-0.1", ("epsilon_start=-0.1", "[0, 1]")),
    ("algo.epsilon_end=2", ("epsilon_end=2", "[0, 1]")),
    ("algo.epsilon_decay_fraction=0", ("epsilon_decay_fraction=0", "(0, 1]")),
    ("algo.gather_trials=0", ("gather_trials=0", "integer >= 1")),
    ("algo.gather_trials=100000000", ("needs about", "gathered states", "algo.gather_trials")),
    ("algo.num_agents=0", ("num_agents=0", "integer >= 1")),
    ("algo.void_features=maybe", ("void_features='maybe'", "zero, random")),
    ("algo.void_draws=never", ("void_draws='never'", "trial, decision")),
    ("algo.tables=room", ("tables='room'", "agent, process")),
    # ---- IT-VQQL (conf/algo/it_vqql.yaml)
    ("algo=it_vqql algo.iterations=0", ("iterations=0", "integer in [1, 1000000000]")),
    ("algo=it_vqql algo.trials_growth=1e300", ("trials_growth=1e+300", "phase 2 would learn", "at most 1e+09")),
    ("algo=it_vqql algo.iterations=15 algo.trials_growth=10", ("trials_growth=10", "would learn", "at most 1e+09")),
    ("algo=it_vqql algo.trials_growth=0", ("trials_growth=0", "> 0")),
    ("algo=it_vqql algo.trials_growth=-1", ("trials_growth=-1", "> 0")),
    ("algo=it_vqql algo.trials=[1,2,3]", ("trials=[1, 2, 3]", "list of 2 of them")),
    ("algo=it_vqql algo.iterations=2 algo.trials=[1,2.5]", ("trials[1]=2.5", "integer in")),
    ("algo=it_vqql algo.gather_epsilon=2", ("gather_epsilon=2", "[0, 1]")),
    # ---- IN-VQQL (conf/algo/in_vqql.yaml)
    ("algo=in_vqql algo.stages=[1,2.7,4]", ("stages=[1, 2.7, 4]", "increasing integer agent counts")),
    ("algo=in_vqql algo.stages=5", ("stages=5", "must be a list of increasing integer")),
    ("algo=in_vqql algo.stages=[]", ("stages=[]", "increasing integer")),
    ("algo=in_vqql algo.stages=[2,1]", ("stages=[2, 1]", "increasing integer")),
    ("algo=in_vqql algo.stages=[0,1]", ("stages=[0, 1]", "agent counts >= 1")),
    ("algo=in_vqql algo.stages=[1,1]", ("stages=[1, 1]", "increasing")),
    ("algo=in_vqql algo.trials_growth=1e300", ("trials_growth=1e+300", "at most 1e+09")),
    ("algo=in_vqql algo.trials=[1]", ("trials=[1]", "list of 3 of them")),
    (
        "algo=in_vqql algo.stages=[1,2] algo.tables=agent vq.num_prototypes=10000000 vq.max_states=10000000",
        ("needs about", "Q tables", "vq.num_prototypes"),
    ),
]


TRAIN_FAST = {
    "processes=0",
    "processes=1e9",
    "processes=1000000000",
    "seed=1e18",
    "device=meta",
    "progress=maybe",
    "logger.tensorboard=maybe",
    "env.max_speed=1e5",
    "env.max_speed=1e9",
    "env.decisions_per_second=1e-9",
    "env.max_decisions=1000000000",
    "env.reward_goal=1e38",
    "env.reward_crash_wall=-1e38",
    "vq.chunk_size=-5",
    "vq.chunk_size=0",
    "vq.weight_own=-2",
    "vq.init=foo",
    "vq.max_iterations=0",
    "vq.tolerance=-1",
    "algo=it_vqql algo.trials_growth=1e300",
    "algo=in_vqql algo.stages=[1,2.7,4]",
    "algo=in_vqql algo.stages=5",
    "scenario=mall",
    "scenario=corner algo.num_agents=20",
    "scenario=custom scenario.geometry={tmp}/bowtie.wkt scenario.exits=[[10,0,10,10]]",
    "scenario=custom scenario.geometry={tmp}/square.wkt scenario.exits=[[5,5,6,5]]",
}


@pytest.mark.parametrize(("overrides", "fragments"), catalogue(TRAIN_CASES, TRAIN_FAST))
def test_train_refuses(overrides, fragments, tmp_path, capsys):
    run_dir = tmp_path / "run"
    (tmp_path / "bowtie.wkt").write_text("POLYGON ((0 0, 10 10, 10 0, 0 10, 0 0))")  # self-intersecting
    (tmp_path / "square.wkt").write_text("POLYGON ((0 0, 10 0, 10 10, 0 10, 0 0))")
    args = [*TRAIN_BASE, *overrides.format(tmp=tmp_path).split(), f"hydra.run.dir={run_dir}"]
    outcome = run_hydra_main(pedrl.train, args, capsys)
    assert_refused(outcome, "pedrl-train", fragments)
    assert_nothing_computed(run_dir)


# ---------------------------------------------------------------------- pedrl-eval
EVAL_BASE = ["agents=[2,3]", "trials=1", "trials_per_batch=1", "animation.enabled=false", "tensorboard=false"]
"""Every eval case adds its overrides to a seconds-long evaluation of the trained checkpoint (a 10 m x 10 m room)."""

EVAL_CASES: list[tuple[str, tuple[str, ...]]] = [
    ("checkpoint=???", ("checkpoint is missing", "checkpoint=<path")),
    ("checkpoint={tmp}/absent.safetensors", ("checkpoint", "absent.safetensors")),
    ("checkpoint={tmp}/notes.safetensors", ("checkpoint", "notes.safetensors")),
    ("agents=[0]", ("agents=[0]", "integers >= 1")),
    ("scenario=nowhere", ("scenario='nowhere' is invalid", "must be one of")),
    ("scenario=corner agents=[20]", ("num_agents=20", "cannot be placed in spawn area 0")),
    ("scenario=bottleneck scenario.opening=0", ("scenario.opening=0", "> 0")),
    ("agents=[]", ("agents=[]", "non-empty list")),
    ("agents=5", ("agents=5", "non-empty list")),
    ("agents=[2,2]", ("agents=[2, 2]", "appear once")),
    ("agents=[2.5]", ("agents=[2.5]", "integers >= 1")),
    ("agents=[1000000]", ("num_agents=1000000", "cannot be placed")),
    ("trials=0", ("trials=0", "integer >= 1")),
    ("trials=1.5", ("trials=1.5", "integer >= 1")),
    ("trials_per_batch=0", ("trials_per_batch=0", "integer >= 1")),
    ("trials=1000000000 trials_per_batch=1000000000", ("needs about", "GiB", "trials_per_batch")),
    ("controller=foo", ("controller='foo'", "learned, greedy")),
    ("epsilon=2", ("epsilon=2", "[0, 1]")),
    ("epsilon=-0.1", ("epsilon=-0.1", "[0, 1]")),
    ("max_decisions=0", ("max_decisions=0", "integer >= 1")),
    ("seed=-1", ("seed=-1", "integer in [0, 4294967295]")),
    ("seed=1e18", ("seed=1e+18", "integer in [0, 4294967295]")),
    ("threads=0", ("threads=0", "integer >= 1")),
    ("device=meta", ("device='meta'", "cpu or cuda")),
    ("device=gpu", ("device='gpu'", "cpu or cuda")),
    ("measurement.radius=0", ("measurement.radius=0", "> 0")),
    ("measurement.distance=1000", ("measurement.distance=1000", "inside the room", "[0, 10)")),
    ("measurement.distance=10", ("measurement.distance=10", "inside the room", "[0, 10)")),
    ("measurement.distance=-1", ("measurement.distance=-1", ">= 0")),
    ("measurement.min_density=-1", ("measurement.min_density=-1", ">= 0")),
    ("measurement.plot_points=0", ("measurement.plot_points=0", "integer >= 1")),
    ("density_map.tile_size=0", ("density_map.tile_size=0", "> 0")),
    ("density_map.tile_size=1e-6", ("density_map.tile_size=1e-06", "tiles", "needs about", "GiB")),
    ("export.trials=-1", ("export.trials=-1", "integer >= 0")),
    ("animation.enabled=maybe", ("animation.enabled='maybe'", "true or false")),
    ("animation.fps=0", ("animation.fps=0", "> 0")),
    ("animation.max_frames=0", ("animation.max_frames=0", "integer >= 1")),
    ("tensorboard=maybe", ("tensorboard='maybe'", "true or false")),
]


EVAL_FAST = {
    "agents=[0]",
    "device=meta",
    "measurement.distance=1000",
    "density_map.tile_size=1e-6",
    "scenario=nowhere",
    "scenario=corner agents=[20]",
}


@pytest.mark.parametrize(("overrides", "fragments"), catalogue(EVAL_CASES, EVAL_FAST))
def test_eval_refuses(overrides, fragments, checkpoint, tmp_path, capsys):
    (tmp_path / "notes.safetensors").write_text("these are not tensors\n")
    run_dir = tmp_path / "run"
    args = [f"checkpoint={checkpoint}", *EVAL_BASE, *overrides.format(tmp=tmp_path).split()]
    outcome = run_hydra_main(pedrl.evaluate, [*args, f"hydra.run.dir={run_dir}"], capsys)
    assert_refused(outcome, "pedrl-eval", fragments)
    assert_nothing_computed(run_dir)


# ---------------------------------------------------------------------- pedrl-plot
def _binary_curve(run: Path) -> None:
    (run / "learning_curve.csv").write_bytes(bytes(range(256)) * 4)


def _foreign_csv(run: Path) -> None:
    (run / "learning_curve.csv").write_text("phase,global_trial,speed_mean\n1,2,3\n")


def _header_only(run: Path) -> None:
    (run / "learning_curve.csv").write_text(",".join(CURVE_COLUMNS) + "\n")


def _malformed_row(run: Path) -> None:
    path = run / "learning_curve.csv"
    path.write_text(path.read_text() + "x" * 5 + "\n")


PLOT_CASES: list[tuple[str, str, Callable[[Path], None] | None, tuple[str, ...]]] = [
    ("no_runs", "runs=[]", None, ("runs=[]", "one or more run directories")),
    ("absent_run", "runs=[{tmp}/absent]", None, ("absent", "expected a run directory")),
    ("smooth_0", "smooth=0", None, ("smooth=0", "integer >= 1")),
    ("smooth_abc", "smooth=abc", None, ("smooth='abc'", "integer >= 1")),
    ("metric_foo", "metric=foo", None, ("metric='foo'", "one of", "success_rate")),
    ("two_labels", "labels=[a,b]", None, ("labels=", "one label per run")),
    ("same_labels", "runs=[{run},{run}] labels=[a,a]", None, ("labels=['a', 'a']", "its own label")),
    ("binary_csv", "", _binary_curve, ("learning_curve.csv", "not a CSV text file")),
    ("foreign_csv", "", _foreign_csv, ("metric='success_rate' is not in", "learning_curve.csv", "one of speed")),
    ("header_only", "", _header_only, ("learning_curve.csv", "has no rows")),
    ("malformed_row", "", _malformed_row, ("learning_curve.csv", "malformed")),
    (
        "output_under_a_file",
        "output={tmp}/figure.png/inside.png",
        lambda run: (run.parent / "figure.png").write_text(""),
        ("figure.png",),
    ),
]


@pytest.mark.parametrize(
    ("overrides", "damage", "fragments"), catalogue(PLOT_CASES, {"no_runs", "binary_csv"}, named=True)
)
def test_plot_refuses(overrides, damage, fragments, tmp_path, capsys):
    run = tmp_path / "a_run"
    write_curve(run / "learning_curve.csv")
    if damage is not None:
        damage(run)
    run_dir = tmp_path / "plots"
    args = [f"runs=[{run}]", *overrides.format(tmp=tmp_path, run=run).split(), f"hydra.run.dir={run_dir}"]
    outcome = run_hydra_main(pedrl.plot, args, capsys)
    assert_refused(outcome, "pedrl-plot", fragments)
    assert_nothing_computed(run_dir)


# ---------------------------------------------------------------------- pedrl-sweep
def _no_parameter(sweep: Path) -> list[str]:
    make_job(sweep)
    return [str(sweep), "--parameter", "algo.alpha"]


def _broken_summary(sweep: Path) -> list[str]:
    (make_job(sweep) / "summary.json").write_text("{not json")
    return [str(sweep)]


def _binary_summary(sweep: Path) -> list[str]:
    (make_job(sweep) / "summary.json").write_bytes(bytes(range(256)))
    return [str(sweep)]


def _broken_overrides(sweep: Path) -> list[str]:
    (make_job(sweep) / ".hydra" / "overrides.yaml").write_text("[unclosed")
    return [str(sweep)]


def _sweep_is_a_file(sweep: Path) -> list[str]:
    (sweep / "sweep.txt").write_text("")
    return [str(sweep / "sweep.txt")]


SWEEP_CASES: list[tuple[Callable[[Path], list[str]], tuple[str, ...]]] = [
    (lambda sweep: [str(sweep / "absent")], ("absent", "does not exist")),
    (lambda sweep: [str(sweep)], ("no finished job", "summary.json")),
    (_sweep_is_a_file, ("sweep.txt", "is a file")),
    (_no_parameter, ("parameter='algo.alpha'", "no value")),
    (_broken_summary, ("summary.json", "not a summary written by pedrl-train")),
    (_binary_summary, ("summary.json", "not a summary written by pedrl-train")),
    (_broken_overrides, ("overrides.yaml", "not a config written by Hydra")),
]


@pytest.mark.parametrize(("make", "fragments"), SWEEP_CASES, ids=[f"case{i}" for i in range(len(SWEEP_CASES))])
def test_sweep_refuses(make, fragments, tmp_path, capsys):
    outcome = run_sweep_main(make(tmp_path), capsys)
    assert_refused(outcome, "pedrl-sweep", fragments)
    assert not (tmp_path / pedrl.sweep.SUMMARY_CSV).exists()


# ---------------------------------------------------------------------- unusable output folders
PROGRAMS = {"pedrl-train": pedrl.train, "pedrl-eval": pedrl.evaluate, "pedrl-plot": pedrl.plot}


def _program_args(program: str, tmp_path: Path, checkpoint: Path) -> list[str]:
    if program == "pedrl-plot":
        return [f"runs=[{write_curve(tmp_path / 'a_run' / 'learning_curve.csv').parent}]"]
    if program == "pedrl-eval":
        return [f"checkpoint={checkpoint}", *EVAL_BASE]
    return list(TRAIN_BASE)


@pytest.mark.parametrize("program", list(PROGRAMS))
@pytest.mark.parametrize(
    "where", ["file", "read_only", pytest.param("inside_file", marks=pytest.mark.slow), "inside_read_only"]
)
def test_unusable_run_directory_is_refused(program, where, tmp_path, read_only_dir, checkpoint, capsys):
    (tmp_path / "a_file").write_text("keep me")
    run_dir = {
        "file": tmp_path / "a_file",
        "inside_file": tmp_path / "a_file" / "run",
        "read_only": read_only_dir,
        "inside_read_only": read_only_dir / "run",
    }[where]
    args = [*_program_args(program, tmp_path, checkpoint), f"hydra.run.dir={run_dir}"]
    before = os.listdir(read_only_dir)
    outcome = run_hydra_main(PROGRAMS[program], args, capsys)
    assert_refused(outcome, program, (f"output folder {str(run_dir)!r} is invalid", "must be a folder"))
    assert (tmp_path / "a_file").read_text() == "keep me"
    assert os.listdir(read_only_dir) == before


def test_plot_into_a_read_only_folder_names_the_path(tmp_path, read_only_dir, capsys):
    run = write_curve(tmp_path / "a_run" / "learning_curve.csv").parent
    output = read_only_dir / "sub" / "curves.png"
    args = [f"runs=[{run}]", f"output={output}", f"hydra.run.dir={tmp_path / 'plots'}"]
    outcome = run_hydra_main(pedrl.plot, args, capsys)
    assert_refused(outcome, "pedrl-plot", (str(read_only_dir / "sub"),))


def test_sweep_into_a_read_only_folder_names_the_path(tmp_path, capsys, monkeypatch):
    make_job(tmp_path)

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied", str(tmp_path / pedrl.sweep.SUMMARY_CSV))

    monkeypatch.setattr(pedrl.sweep, "_write_csv", refuse)
    outcome = run_sweep_main([str(tmp_path)], capsys)
    assert_refused(outcome, "pedrl-sweep", (str(tmp_path / pedrl.sweep.SUMMARY_CSV), "Permission denied"))


# ---------------------------------------------------------------------- the real console entry points
# ---------------------------------------------------------------------- pedrl-validate
VALIDATE_CASES: list[tuple[str, tuple[str, ...]]] = [
    ("controller=both", ("checkpoint is missing", "controller=references")),
    ("controller=smart", ("controller='smart' is invalid", "all, both, references, learned, greedy, jupedsim")),
    ("controller=greedy epsilon=-1", ("epsilon=-1", "[0, 1]")),
    ("controller=greedy tests=[lanes,queues]", ("tests='queues' is invalid", "rimea_1")),
    ("controller=greedy tests=lanes", ("tests='lanes' is invalid", "non-empty list")),
    ("controller=greedy seed=-1", ("seed=-1", "integer in")),
    ("checkpoint={tmp}/absent.safetensors", ("absent.safetensors",)),
]


@pytest.mark.parametrize(("overrides", "fragments"), catalogue(VALIDATE_CASES, {"controller=both"}))
def test_validate_refuses(overrides, fragments, tmp_path, capsys):
    run_dir = tmp_path / "run"
    args = [*overrides.format(tmp=tmp_path).split(), "quick=true", f"hydra.run.dir={run_dir}"]
    outcome = run_hydra_main(pedrl.validate, args, capsys)
    assert_refused(outcome, "pedrl-validate", fragments)
    assert_nothing_computed(run_dir)


def test_real_entry_points_behave_the_same(checkpoint, tmp_path):
    """One case of every command as a subprocess (``python -m``, as the console scripts run them)."""
    run = write_curve(tmp_path / "a_run" / "learning_curve.csv").parent
    _binary_curve(run)
    (tmp_path / "sweep.txt").write_text("")
    commands = {
        "pedrl-train": ["pedrl.train", *TRAIN_BASE, "vq.chunk_size=-5", f"hydra.run.dir={tmp_path / 'train'}"],
        "pedrl-eval": [
            "pedrl.evaluate",
            f"checkpoint={checkpoint}",
            "agents=[2]",
            "density_map.tile_size=1e-6",
            f"hydra.run.dir={tmp_path / 'eval'}",
        ],
        "pedrl-plot": ["pedrl.plot", f"runs=[{run}]", f"hydra.run.dir={tmp_path / 'plot'}"],
        "pedrl-sweep": ["pedrl.sweep", str(tmp_path / "sweep.txt")],
        "pedrl-validate": ["pedrl.validate", "scenario=corner", f"hydra.run.dir={tmp_path / 'validate'}"],
    }
    expected = {
        "pedrl-train": ("vq.chunk_size=-5 is invalid: must be an integer >= 1",),
        "pedrl-eval": ("density_map.tile_size=1e-06",),
        "pedrl-plot": ("learning_curve.csv", "not a CSV text file"),
        "pedrl-sweep": ("sweep.txt", "is a file"),
        "pedrl-validate": ("scenario='corner' is invalid", "has no scenario group"),
    }
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    for program, command in commands.items():
        done = subprocess.run(
            [sys.executable, "-m", *command], capture_output=True, text=True, timeout=300, env=env, check=False
        )
        lines = [line for line in done.stderr.splitlines() if line.strip()]
        assert_refused(Outcome(done.returncode, lines, done.stderr), program, expected[program])
    for folder in ("train", "eval", "plot"):
        assert_nothing_computed(tmp_path / folder)


# ---------------------------------------------------------------------- issue 20: Hydra's own failures, sweeps, seeds
ALL_PROGRAMS = {**PROGRAMS, "pedrl-validate": pedrl.validate}


def _any_program_args(program: str, tmp_path: Path, checkpoint: Path) -> list[str]:
    """A command line of ``program`` that would run (in seconds) if nothing else were wrong."""
    if program == "pedrl-validate":
        return ["controller=greedy", "quick=true"]
    return _program_args(program, tmp_path, checkpoint)


UNKNOWN_KEY_CASES: list[tuple[str, str, tuple[str, ...]]] = [
    ("pedrl-train", "env.widht=5", ("env.widht is not a key of the config", "did you mean env.width?", "+env.widht=")),
    ("pedrl-train", "foo=1", ("foo is not a key of the config", "top-level keys are", "seed", "+foo=")),
    ("pedrl-train", "num_prototypes=64", ("num_prototypes is not a key", "did you mean vq.num_prototypes?")),
    ("pedrl-train", "envv.width=5", ("envv is not a key of the config", "did you mean env?", "+envv.width=")),
    ("pedrl-train", "seed.x=1", ("seed.x is not a key of the config", "seed is a value")),
    ("pedrl-train", "env.speed_ratios.x=1", ("'env.speed_ratios.x=1' cannot be applied",)),
    ("pedrl-train", "foo=[1,", ("'foo=[1,' is not a valid override", "key=value")),
    ("pedrl-train", "hydra.run.dirr=x", ("hydra.run.dirr is not a key", "did you mean hydra.run.dir?")),
    ("pedrl-eval", "trails=3", ("trails is not a key of the config", "did you mean trials?", "+trails=")),
    ("pedrl-plot", "ouptut=x.png", ("ouptut is not a key of the config", "did you mean output?")),
    ("pedrl-validate", "seeed=1", ("seeed is not a key of the config", "did you mean seed?")),
]


@pytest.mark.parametrize(("program", "override", "fragments"), UNKNOWN_KEY_CASES, ids=lambda case: str(case))
def test_unknown_key_is_one_line(program, override, fragments, tmp_path, checkpoint, capsys):
    """Hydra printed six lines and exited with 1; now one line naming the key and the nearest one, exit 2."""
    run_dir = tmp_path / "run"
    args = [*_any_program_args(program, tmp_path, checkpoint), override, f"hydra.run.dir={run_dir}"]
    hydra_full_error = os.environ.get("HYDRA_FULL_ERROR")
    outcome = run_hydra_main(ALL_PROGRAMS[program], args, capsys)
    assert_refused(outcome, program, fragments)
    assert not run_dir.exists()
    assert os.environ.get("HYDRA_FULL_ERROR") == hydra_full_error  # the entry point's setting does not leak


def test_unknown_key_in_a_sweep_is_one_line(tmp_path, capsys):
    sweep_dir = tmp_path / "sweep"
    args = ["--multirun", *TRAIN_BASE, "seed=0,1", "env.widht=3,4", f"hydra.sweep.dir={sweep_dir}"]
    outcome = run_hydra_main(pedrl.train, args, capsys)
    assert_refused(outcome, "pedrl-train", ("env.widht is not a key", "did you mean env.width?"))


def test_new_keys_and_hydra_keys_still_work(tmp_path, capsys):
    """``+key=value`` adds a key and a valid ``hydra.*`` override is Hydra's: the check refuses neither."""
    args = ["--cfg", "job", *TRAIN_BASE, "+note=hello", "hydra.job.chdir=false", f"hydra.run.dir={tmp_path / 'r'}"]
    capsys.readouterr()
    saved = sys.argv
    sys.argv = ["pedrl.train.py", *args]
    try:
        pedrl.train.main()
    finally:
        sys.argv = saved
        GlobalHydra.instance().clear()
    captured = capsys.readouterr()
    assert "note: hello" in captured.out, captured.err
    assert "error" not in captured.err


def _full_disk(run_dir: Path, tmp_path: Path, read_only_dir: Path) -> tuple[list[str], tuple[str, ...]]:
    """``.hydra/config.yaml`` is a link to ``/dev/full``: every write to it fails with ENOSPC, as on a full disk."""
    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full on this machine")
    (run_dir / ".hydra").mkdir(parents=True)
    (run_dir / ".hydra" / "config.yaml").symlink_to("/dev/full")
    return [], (f"cannot write in {str(run_dir)!r}", "No space left on device")


def _read_only_hydra_folder(run_dir: Path, tmp_path: Path, read_only_dir: Path) -> tuple[list[str], tuple[str, ...]]:
    """Hydra's files go to a folder nobody may write in (EACCES, or EPERM under /sys for root)."""
    target = read_only_dir / "hydra_files"
    return [f"hydra.output_subdir={target}"], (f"cannot use {str(target)!r}",)


def _hydra_folder_below_a_file(run_dir: Path, tmp_path: Path, read_only_dir: Path) -> tuple[list[str], tuple[str, ...]]:
    (tmp_path / "a_file").write_text("keep me")
    target = tmp_path / "a_file" / "hydra_files"
    return [f"hydra.output_subdir={target}"], (f"cannot use {str(target)!r}", "Not a directory")


@pytest.mark.parametrize("program", list(ALL_PROGRAMS))
@pytest.mark.parametrize("damage", [_full_disk, _read_only_hydra_folder, _hydra_folder_below_a_file])
def test_hydra_files_that_cannot_be_written_are_one_line(program, damage, tmp_path, read_only_dir, checkpoint, capsys):
    """Hydra writes ``.hydra/*.yaml`` before the job starts: a full disk or an unwritable folder there gave its
    traceback; now one line naming the path, exit 2, and the job does not start."""
    run_dir = tmp_path / "run"
    extra, fragments = damage(run_dir, tmp_path, read_only_dir)
    args = [*_any_program_args(program, tmp_path, checkpoint), *extra, f"hydra.run.dir={run_dir}"]
    before = os.listdir(read_only_dir)
    outcome = run_hydra_main(ALL_PROGRAMS[program], args, capsys)
    assert_refused(outcome, program, fragments)
    assert_nothing_computed(run_dir)
    assert os.listdir(read_only_dir) == before


def test_full_disk_in_a_real_subprocess(tmp_path):
    """The console script as a user runs it: an unknown key and a full disk, one line each."""
    run_dir = tmp_path / "run"
    _full_disk(run_dir, tmp_path, tmp_path)
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    commands = [
        ("env.widht=5", ("env.widht is not a key of the config", "did you mean env.width?")),
        ("seed=0", (f"cannot write in {str(run_dir)!r}", "No space left on device")),
    ]
    for override, fragments in commands:
        done = subprocess.run(
            [sys.executable, "-m", "pedrl.train", *TRAIN_BASE, override, f"hydra.run.dir={run_dir}"],
            capture_output=True,
            text=True,
            timeout=300,
            env=env,
            check=False,
        )
        lines = [line for line in done.stderr.splitlines() if line.strip()]
        assert_refused(Outcome(done.returncode, lines, done.stderr), "pedrl-train", fragments)


def test_sweep_of_jobs_with_different_override_keys_names_the_key(tmp_path, capsys):
    """Jobs of two sweeps in one folder (``algo`` overridden in one, not in the other) gave a KeyError blamed on a
    summary.json; now one line naming the key and the jobs that lack it."""
    make_job(tmp_path, "0")
    make_job(tmp_path, "1")
    make_job(tmp_path, "2")
    for name in ("0", "2"):
        OmegaConf.save(
            OmegaConf.create(["vq.num_prototypes=512", "algo=it_vqql"]), tmp_path / name / ".hydra" / "overrides.yaml"
        )
    for args in ([str(tmp_path)], [str(tmp_path), "--parameter", "vq.num_prototypes"]):
        outcome = run_sweep_main(args, capsys)
        assert_refused(outcome, "pedrl-sweep", ("override 'algo'", "set in jobs 0, 2", "not in job 1"))
        assert not (tmp_path / pedrl.sweep.SUMMARY_CSV).exists()


@pytest.mark.parametrize("seed", [1.5, 2**70, True, -1, "3", 2**64])
def test_room_reset_refuses_a_seed_that_is_not_an_integer_in_range(seed):
    """``reset(seed=1.5)`` truncated to 1 and ``reset(seed=2**70)`` overflowed with a traceback."""
    from pedrl.sim import RoomEnv

    env = RoomEnv(num_replicas=1, num_agents=2, width=10.0, length=10.0)
    with pytest.raises(ValueError, match=r"^seed=.* is invalid: must be an integer in \[0, 18446744073709551615\]"):
        env.reset(seed=seed)
    env.reset(seed=2**64 - 1)  # the widest a torch generator takes: derived seeds (seed * 10007 + phase) fit


SEED_CASES: list[tuple[str, str, tuple[str, ...]]] = [
    ("pedrl-train", "seed=1.5", ("seed=1.5 is invalid", "integer in [0, 4294967295]")),
    ("pedrl-train", "seed=true", ("seed=True is invalid", "integer in [0, 4294967295]")),
    ("pedrl-train", "seed=1180591620717411303424", ("seed=1180591620717411303424", "integer in [0, 4294967295]")),
    ("pedrl-eval", "seed=1.5", ("seed=1.5 is invalid", "integer in [0, 4294967295]")),
    ("pedrl-eval", "seed=true", ("seed=True is invalid", "integer in [0, 4294967295]")),
    ("pedrl-validate", "seed=1.5", ("seed=1.5 is invalid", "integer in [0, 4294967295]")),
    ("pedrl-validate", "seed=4294967296", ("seed=4294967296 is invalid", "integer in [0, 4294967295]")),
]


@pytest.mark.parametrize(("program", "override", "fragments"), SEED_CASES, ids=lambda case: str(case))
def test_every_command_checks_its_seed(program, override, fragments, tmp_path, checkpoint, capsys):
    run_dir = tmp_path / "run"
    args = [*_any_program_args(program, tmp_path, checkpoint), override, f"hydra.run.dir={run_dir}"]
    outcome = run_hydra_main(ALL_PROGRAMS[program], args, capsys)
    assert_refused(outcome, program, fragments)
    assert_nothing_computed(run_dir)


@pytest.mark.parametrize("program", ["pedrl-train", "pedrl-eval", "pedrl-plot", "pedrl-validate"])
def test_run_folder_that_cannot_be_resolved_is_one_line(program, tmp_path, checkpoint, capsys):
    """``hydra.run.dir=${oops}``: Hydra turned the callback's error into a five-line warning, then a traceback."""
    args = [*_any_program_args(program, tmp_path, checkpoint), "hydra.run.dir=" + str(tmp_path) + "/${oops}"]
    outcome = run_hydra_main(ALL_PROGRAMS[program], args, capsys)
    assert_refused(outcome, program, ("hydra.run.dir is invalid", "Interpolation key 'oops' not found"))

"""``pedrl-eval`` (``pedrl/evaluate.py``) refuses a bad value, path or checkpoint before any compute: the eval part
of the bad-input catalogue, and a bad checkpoint on the real command line.

How a catalogue case runs and what it asserts: :mod:`tests.refusals`. The evaluation itself (:mod:`pedrl.evaluation`)
is tested in ``tests/evaluation/``.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

import pedrl.evaluate
from tests.refusals import (
    EVAL_BASE,
    HYDRA_OWN,
    assert_nothing_computed,
    assert_refused,
    catalogue,
    read_only_folder,
    run_hydra_main,
    train_checkpoint,
)


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    return train_checkpoint(tmp_path_factory)


@pytest.mark.parametrize("case", ["missing", "not_a_checkpoint"])
def test_bad_checkpoint_fails_with_one_line_on_the_command_line(case, tmp_path):
    path = tmp_path / "nothing.safetensors"
    if case == "not_a_checkpoint":
        path = tmp_path / "notes.safetensors"
        path.write_text("these are not tensors\n")
    result = subprocess.run(
        [sys.executable, "-m", "pedrl.evaluate", f"checkpoint={path}", f"hydra.run.dir={tmp_path / 'run'}"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("pedrl-eval: error: checkpoint ") and str(path) in lines[0]


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
    ("trials=0", ("trials=0", "integer in [1, 1000000000]")),
    ("trials=1.5", ("trials=1.5", "integer in [1, 1000000000]")),
    # counts no machine could finish: one line naming the key (they ran silently for hours)
    ("trials=1000000000000", ("trials=1000000000000", "integer in [1, 1000000000]")),
    (
        "trials=1000000000 max_decisions=1000000",
        ("trials=1000000000 is invalid with agents=[2, 3] and max_decisions=1000000", "agent-decisions", "a year"),
    ),
    ("max_decisions=100000000", ("max_decisions=100000000", "integer in [1, 10000000]")),
    ("trials_per_batch=0", ("trials_per_batch=0", "integer >= 1")),
    ("trials=1000000000 trials_per_batch=1000000000", ("needs about", "GiB", "trials_per_batch")),
    ("controller=foo", ("controller='foo'", "learned, greedy")),
    ("controller=jupedsim jupedsim.dt=1e-9", ("jupedsim.dt=1e-09 is invalid", ">= 0.001 s")),
    ("epsilon=2", ("epsilon=2", "[0, 1]")),
    ("epsilon=-0.1", ("epsilon=-0.1", "[0, 1]")),
    ("max_decisions=0", ("max_decisions=0", "integer in [1, 10000000]")),
    ("seed=-1", ("seed=-1", "integer in [0, 4294967295]")),
    ("seed=1e18", ("seed=1e+18", "integer in [0, 4294967295]")),
    ("threads=0", ("threads=0", "integer >= 1")),
    ("device=meta", ("device='meta'", "cpu or cuda")),
    ("device=gpu", ("device='gpu'", "cpu or cuda", "(not a device name)")),
    ("device=mps", ("device='mps'", "cpu or cuda", "device type 'mps' is not supported")),
    ("queue_weight=-1", ("queue_weight=-1", "[0, 100]")),
    ("queue_weight=nan", ("queue_weight=nan", "[0, 100]")),
    ("measurement.radius=0", ("measurement.radius=0", "> 0")),
    ("measurement.distance=1000", ("measurement.distance=1000", "inside the room", "[0, 10)")),
    ("measurement.distance=10", ("measurement.distance=10", "inside the room", "[0, 10)")),
    ("measurement.distance=-1", ("measurement.distance=-1", ">= 0")),
    ("measurement.min_density=-1", ("measurement.min_density=-1", ">= 0")),
    ("measurement.plot_points=0", ("measurement.plot_points=0", "integer >= 1")),
    ("density_map.tile_size=0", ("density_map.tile_size=0", "> 0")),
    ("density_map.tile_size=1e-6", ("density_map.tile_size=1e-06", "tiles", "needs about", "GiB")),
    ("export.trials=-1", ("export.trials=-1", "integer >= 0")),
    ("export.fps=0", ("export.fps=0", "> 0")),
    ("export.fps=0.5", ("export.fps=0.5", "at least the room's 1 decisions per second")),
    # above the trajectory writer's bound: refused before the trials (they ran, then the writer refused)
    ("export.fps=1e6", ("export.fps=1000000.0", "frames per second in [1, 1e+06)")),
    ("export.fps=1e9", ("export.fps=1000000000.0", "frames per second in [1, 1e+06)")),
    ("export.fps=999999 max_decisions=1000", ("needs about", "an exported trial (export.fps=999999", "export.fps")),
    ("animation.enabled=maybe", ("animation.enabled='maybe'", "true or false")),
    ("animation.fps=0", ("animation.fps=0", "> 0")),
    ("animation.max_frames=0", ("animation.max_frames=0", "integer >= 1")),
    ("tensorboard=maybe", ("tensorboard='maybe'", "true or false")),
]


EVAL_FAST = {
    "agents=[0]",
    "trials=1000000000000",
    "trials=1000000000 max_decisions=1000000",
    "max_decisions=100000000",
    "export.fps=1e6",
    "export.fps=999999 max_decisions=1000",
    "device=meta",
    "measurement.distance=1000",
    "density_map.tile_size=1e-6",
    "export.fps=0.5",
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


def _read_only_trajectories(run_dir: Path, read_only: Path) -> None:
    (run_dir / "trajectories").symlink_to(read_only, target_is_directory=True)


OUTPUT_CASES: list[tuple[str, object, tuple[str, ...]]] = [
    (
        "trajectories_a_file",
        lambda run, _: (run / "trajectories").write_text(""),
        ("/trajectories'", "it is a file", "must be a folder"),
    ),
    ("trajectories_read_only", _read_only_trajectories, ("trajectories", "cannot be written in")),
    (
        "sqlite_a_folder",
        lambda run, _: (run / "trajectories" / "agents_2" / "trial_000.sqlite").mkdir(parents=True),
        ("agents_2/trial_000.sqlite'", "it is a folder", "must be a file"),
    ),
    (
        "txt_a_folder",
        lambda run, _: (run / "trajectories" / "agents_3" / "trial_001.txt").mkdir(parents=True),
        ("agents_3/trial_001.txt'", "it is a folder"),
    ),
    (
        "wkt_a_folder",
        lambda run, _: (run / "trajectories" / "geometry.wkt").mkdir(parents=True),
        ("trajectories/geometry.wkt'", "it is a folder"),
    ),
    (
        "reference_table_a_folder",
        lambda run, _: (run / "greedy" / "scaling.csv").mkdir(parents=True),
        ("greedy/scaling.csv'", "it is a folder"),
    ),
]


@pytest.fixture
def read_only_dir(tmp_path):
    yield from read_only_folder(tmp_path)


@pytest.mark.parametrize(("make", "fragments"), catalogue(OUTPUT_CASES, {case[0] for case in OUTPUT_CASES}, named=True))
def test_eval_checks_every_output_before_compute(make, fragments, checkpoint, read_only_dir, tmp_path, capsys):
    """An output path that cannot be written is refused before the first trial, so no table is left half-written."""
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    make(run_dir, read_only_dir)
    before = _names(run_dir)
    args = [f"checkpoint={checkpoint}", *EVAL_BASE, "export.trials=2", f"hydra.run.dir={run_dir}"]
    outcome = run_hydra_main(pedrl.evaluate, args, capsys)
    assert_refused(outcome, "pedrl-eval", ("output", str(run_dir), *fragments))
    assert _names(run_dir) - HYDRA_OWN == before  # no scaling.csv, no trajectory


def _names(folder: Path) -> set[str]:
    """The names of everything under ``folder`` (links not followed), Hydra's ``.hydra/`` left out."""
    names: set[str] = set()
    for _, dirs, files in os.walk(folder):
        if ".hydra" in dirs:
            dirs.remove(".hydra")
        names.update(dirs, files)
    return names


@pytest.mark.parametrize("long", [False, True], ids=["control", "long"])
def test_a_long_evaluation_prints_its_estimate_and_shows_every_batch(long, checkpoint, tmp_path, capsys, monkeypatch):
    """A run whose worst case passes LARGE_RUN_S at the fastest rate says so before its first row (time, memory) and
    shows a progress bar for every batch; at export.fps, trajectory files past LARGE_EXPORT_BYTES state their size.
    The thresholds are lowered here (a seconds-long run); the control keeps them and prints neither."""
    import pedrl.evaluation.config as config
    from pedrl.evaluation import evaluate
    from tests.conftest import compose_config

    if long:
        monkeypatch.setattr(config, "LARGE_RUN_S", 0.0)
        monkeypatch.setattr(config, "LARGE_EXPORT_BYTES", 0)
    cfg = compose_config("eval", [f"checkpoint={checkpoint}", *EVAL_BASE, "references=[]", "export.fps=4"])
    capsys.readouterr()
    evaluate(cfg, run_dir=tmp_path)
    captured = capsys.readouterr()
    lines = captured.out.splitlines()
    estimate = [line for line in lines if line.startswith("pedrl-eval: a long run: up to ")]
    export = [line for line in lines if line.startswith("pedrl-eval: export.fps=4 writes up to ")]
    assert len(estimate) == len(export) == int(long), captured.out
    assert ("2 agents, runs 1-2" in captured.err) == long, captured.err  # the batch's bar
    if long:
        first_row = next(i for i, line in enumerate(lines) if "agents: fails" in line)
        assert lines.index(estimate[0]) < first_row
        assert "agent-decisions (trials x processes x agents x max_decisions" in estimate[0]
        assert "GiB of memory" in estimate[0] and "GiB of trajectory files" in export[0]

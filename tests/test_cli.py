"""What every entry point shares through :mod:`pedrl.cli`: a run folder that cannot be used, an unknown key, Hydra's
own files that cannot be written, a seed out of range, all end in one line and exit code 2 before any compute; and
the real console scripts (subprocesses) behave as the in-process calls of the bad-input catalogue.

How a case runs and what it asserts: :mod:`tests.refusals`; each entry point's own cases are in the test file of its
module (``tests/test_train.py``, ``test_evaluate.py``, ``test_validate.py``, ``test_plot.py``, ``test_sweep.py``).
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from hydra.core.global_hydra import GlobalHydra

import pedrl.evaluate
import pedrl.export
import pedrl.plot
import pedrl.train
import pedrl.validate
from tests.refusals import (
    EVAL_BASE,
    TRAIN_BASE,
    Outcome,
    assert_nothing_computed,
    assert_refused,
    binary_curve,
    read_only_folder,
    run_hydra_main,
    train_checkpoint,
    write_small_curve,
)


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    return train_checkpoint(tmp_path_factory)


@pytest.fixture
def read_only_dir(tmp_path) -> Iterator[Path]:
    yield from read_only_folder(tmp_path)


# ---------------------------------------------------------------------- unusable output folders
PROGRAMS = {"pedrl-train": pedrl.train, "pedrl-eval": pedrl.evaluate, "pedrl-plot": pedrl.plot}


def _program_args(program: str, tmp_path: Path, checkpoint: Path) -> list[str]:
    if program == "pedrl-plot":
        return [f"runs=[{write_small_curve(tmp_path / 'a_run' / 'learning_curve.csv').parent}]"]
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


# ---------------------------------------------------------------------- the real console entry points
def test_real_entry_points_behave_the_same(checkpoint, tmp_path):
    """One case of every command as a subprocess (``python -m``, as the console scripts run them)."""
    run = write_small_curve(tmp_path / "a_run" / "learning_curve.csv").parent
    binary_curve(run)
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


# ---------------------------------------------------------------------- issue 20: Hydra's own failures, seeds
ALL_PROGRAMS = {**PROGRAMS, "pedrl-validate": pedrl.validate}


def _any_program_args(program: str, tmp_path: Path, checkpoint: Path) -> list[str]:
    """A command line of ``program`` that would run (in seconds) if nothing else were wrong."""
    if program == "pedrl-validate":
        return ["controller=greedy", "quick=true"]
    return _program_args(program, tmp_path, checkpoint)


UNKNOWN_KEY_CASES: list[tuple[str, str, tuple[str, ...]]] = [
    ("pedrl-train", "env.widht=5", ("env.widht is not a key of the config", "did you mean env.width?")),
    ("pedrl-train", "foo=1", ("foo is not a key of the config", "top-level keys are", "seed")),
    ("pedrl-train", "num_prototypes=64", ("num_prototypes is not a key", "did you mean vq.num_prototypes?")),
    ("pedrl-train", "envv.width=5", ("envv is not a key of the config", "did you mean env?")),
    ("pedrl-train", "seed.x=1", ("seed.x is not a key of the config", "seed is a value")),
    ("pedrl-train", "env.speed_ratios.x=1", ("'env.speed_ratios.x=1' cannot be applied",)),
    ("pedrl-train", "foo=[1,", ("'foo=[1,' is not a valid override", "key=value")),
    ("pedrl-train", "hydra.run.dirr=x", ("hydra.run.dirr is not a key", "did you mean hydra.run.dir?")),
    ("pedrl-eval", "trails=3", ("trails is not a key of the config", "did you mean trials?")),
    ("pedrl-plot", "ouptut=x.png", ("ouptut is not a key of the config", "did you mean output?")),
    ("pedrl-validate", "seeed=1", ("seeed is not a key of the config", "did you mean seed?")),
    ("pedrl-validate", "lanes.ratio=5", ("lanes is not a key of the config", "top-level keys are", "quick")),
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


def test_hydra_keys_and_existing_keys_with_plus_still_work(tmp_path, capsys):
    """A valid ``hydra.*`` override is Hydra's, and ``++key=value`` of a key the config has sets it: the checks
    refuse neither."""
    args = ["--cfg", "job", *TRAIN_BASE, "++seed=7", "hydra.job.chdir=false", f"hydra.run.dir={tmp_path / 'r'}"]
    capsys.readouterr()
    saved = sys.argv
    sys.argv = ["pedrl.train.py", *args]
    try:
        pedrl.train.main()
    finally:
        sys.argv = saved
        GlobalHydra.instance().clear()
    captured = capsys.readouterr()
    assert "seed: 7" in captured.out, captured.err
    assert "error" not in captured.err


ADDED_KEY_CASES = [
    ("pedrl-validate", "+lanes_ratio=[5,1]", ("+lanes_ratio=[5,1] is invalid", "lanes_ratio is not a setting")),
    ("pedrl-train", "+note=hello", ("+note=hello is invalid", "nothing reads an added key", "seed")),
    ("pedrl-train", "+vq.foo=1", ("+vq.foo=1 is invalid", "the keys of vq", "num_prototypes")),
    ("pedrl-eval", "++trails=3", ("++trails=3 is invalid", "did you mean trials")),
    ("pedrl-plot", "+ouptut=x.png", ("+ouptut=x.png is invalid", "did you mean output")),
    ("pedrl-export", "+oot=p.safetensors", ("+oot=p.safetensors is invalid", "did you mean out")),
]


@pytest.mark.parametrize(("program", "override", "fragments"), ADDED_KEY_CASES, ids=lambda case: str(case))
def test_an_added_key_that_nothing_reads_is_refused_by_every_entry_point(
    program, override, fragments, tmp_path, checkpoint, capsys
):
    """``+key=value`` of a key the config lacks was accepted and ignored (exit 0): nothing reads it. Now one line
    naming it, before Hydra writes anything."""
    run_dir = tmp_path / "run"
    if program == "pedrl-export":
        args = [f"checkpoint={checkpoint}", f"out={tmp_path / 'p.safetensors'}"]
    else:
        args = [*_any_program_args(program, tmp_path, checkpoint), f"hydra.run.dir={run_dir}"]
    module = pedrl.export if program == "pedrl-export" else ALL_PROGRAMS[program]
    outcome = run_hydra_main(module, [*args, override], capsys)
    assert_refused(outcome, program, fragments)
    assert not run_dir.exists() and not (tmp_path / "p.safetensors").exists()


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


def test_a_full_disk_during_a_run_names_the_run_folder(tmp_path, monkeypatch, capsys):
    """A write that fails with ENOSPC and names no file (a checkpoint or curve flushed at close) blames the run's
    folder, where it said "cannot use '?'"."""
    import errno

    from pedrl.cli import OutputDirCheck, run_reporting_errors

    monkeypatch.setattr(OutputDirCheck, "folder", tmp_path / "run")

    def full() -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(SystemExit) as exit_info:
        run_reporting_errors("pedrl-train", full)
    assert exit_info.value.code == 2
    error = capsys.readouterr().err.strip()
    assert error == f"pedrl-train: error: cannot write in {str(tmp_path / 'run')!r}: No space left on device"


OUTPUT_CASES = [
    ("pedrl-train", "checkpoints", "file", ("output folder", "/checkpoints' is invalid: it is a file")),
    ("pedrl-train", "summary.json", "folder", ("output file", "/summary.json' is invalid: it is a folder")),
    ("pedrl-validate", "trajectories", "file", ("output folder", "/trajectories' is invalid: it is a file")),
    ("pedrl-validate", "trajectories/greedy", "file", ("trajectories/greedy' is invalid: it is a file",)),
    ("pedrl-validate", "validation.md", "folder", ("output file", "/validation.md' is invalid: it is a folder")),
]


@pytest.mark.parametrize(("program", "name", "kind", "fragments"), OUTPUT_CASES, ids=lambda case: str(case))
def test_an_output_that_cannot_be_written_is_refused_before_any_compute(
    program, name, kind, fragments, tmp_path, checkpoint, capsys
):
    """A file where a folder goes (or the reverse) in the run folder was found only when the run wrote there, after
    its compute; now one line naming it, before the first trial, and nothing is written."""
    run_dir = tmp_path / "run"
    path = run_dir / name
    path.parent.mkdir(parents=True)
    if kind == "file":
        path.write_text("keep me")
    else:
        path.mkdir()
    args = [*_any_program_args(program, tmp_path, checkpoint), f"hydra.run.dir={run_dir}"]
    outcome = run_hydra_main(ALL_PROGRAMS[program], args, capsys)
    assert_refused(outcome, program, (str(run_dir), *fragments))
    written = {str(p.relative_to(run_dir)) for p in run_dir.rglob("*") if ".hydra" not in p.parts}
    assert written - {"train.log", "validate.log", ".hydra"} == {name, *map(str, Path(name).parents)} - {"."}
    assert kind == "folder" or path.read_text() == "keep me"


@pytest.mark.parametrize(
    ("args", "fragments"),
    [
        (
            ["debug_experiment=default_main_dqn"],
            ("debug_experiment='default_main_dqn' is invalid", "run experiment=main_dqn debug=default"),
        ),
        (["debug_algo=default_dqn"], ("debug_algo='default_dqn' is invalid", "run algo=dqn debug=default")),
        (["+debug_experiment=default_main"], ("debug_experiment='default_main'", "run experiment=main debug=default")),
    ],
)
def test_a_debug_patch_given_alone_is_refused_before_the_full_run(args, fragments, tmp_path, capsys):
    # debug_experiment=default_main_dqn alone patched the full default training, which then ran for ten minutes
    outcome = run_hydra_main(pedrl.train, [*args, f"hydra.run.dir={tmp_path / 'run'}"], capsys)
    assert_refused(outcome, "pedrl-train", fragments)
    assert not (tmp_path / "run").exists()

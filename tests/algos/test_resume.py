"""Resuming: a run killed anywhere continues to the same numbers, and resume never loses or wipes outputs."""

import json
import os
import signal
import time

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import open_dict

from pedrl._numba import numba_available
from pedrl.algos.registry import build_trainer
from pedrl.cli import CONFIG_DIR, run_reporting_errors
from pedrl.io import CheckpointError, load_checkpoint, read_csv
from pedrl.train import train

# Two VQQL blocks of 10 trials in a 10 m room, mid-phase checkpoints every 3 trials: a whole run takes seconds.
TINY = ("algo=vqql", "checkpoint_every=3", "logger=none", "algo.trials=20", "vq.num_prototypes=16", "threads=1")


def tiny_config(*overrides: str):
    """The debug config with ``overrides``, progress bars off (usable from module-scoped fixtures)."""
    with initialize_config_dir(version_base="1.3", config_dir=CONFIG_DIR):
        cfg = compose(config_name="train", overrides=["debug=default", *overrides])
    with open_dict(cfg):
        cfg.progress = False
    return cfg


def _strip_clock(rows):
    return [{k: v for k, v in row.items() if k != "decisions_per_s"} for row in rows]


def _interrupt_after(monkeypatch, trials: int, *, slow_s: float = 0.0) -> None:
    """Make training stop (KeyboardInterrupt) after ``trials`` logged trials, each taking at least ``slow_s``."""
    from pedrl.algos.records import RunRecord

    original = RunRecord.log_trial
    calls = {"n": 0}

    def interrupted(self, *args, **kwargs):
        time.sleep(slow_s)
        original(self, *args, **kwargs)
        calls["n"] += 1
        if calls["n"] == trials:
            raise KeyboardInterrupt

    monkeypatch.setattr(RunRecord, "log_trial", interrupted)


# ---------------------------------------------------------------------- a finished run
def test_resuming_a_finished_run_keeps_its_summary_and_figures(tmp_path):
    cfg = tiny_config(*TINY)
    first = train(cfg, run_dir=tmp_path)
    kept = {
        name: (tmp_path / name).read_bytes() for name in ("summary.json", "learning_curve.png", "learning_curve.csv")
    }
    again = train(tiny_config(*TINY, "resume=true"), run_dir=tmp_path)
    assert again.finished_before
    for name, content in kept.items():
        assert (tmp_path / name).read_bytes() == content, name
    assert json.loads(kept["summary.json"])["final"] == first.final != {}
    assert again.final == pytest.approx(first.final)


# ---------------------------------------------------------------------- wall time, threads, run directories
def test_wall_time_counts_every_segment(tmp_path, monkeypatch):
    _interrupt_after(monkeypatch, 14, slow_s=0.1)  # 1.4 s or more before the kill
    with pytest.raises(KeyboardInterrupt):
        train(tiny_config(*TINY), run_dir=tmp_path)
    monkeypatch.undo()
    before = load_checkpoint(tmp_path / "checkpoints" / "last.safetensors").metadata["wall_time_s"]
    assert before >= 1.2  # 12 trials (the checkpoint) of at least 0.1 s
    start = time.perf_counter()
    result = train(tiny_config(*TINY, "resume=true"), run_dir=tmp_path)
    segment = time.perf_counter() - start
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["wall_time_s"] == pytest.approx(result.wall_time_s)
    assert before < result.wall_time_s <= before + segment  # the segment before the kill counts too


def test_resume_accepts_other_threads_and_a_run_directory(tmp_path, monkeypatch):
    _interrupt_after(monkeypatch, 14)
    with pytest.raises(KeyboardInterrupt):
        train(tiny_config(*TINY, "threads=1"), run_dir=tmp_path / "run")
    monkeypatch.undo()
    train(tiny_config(*TINY, "threads=2", f"resume={tmp_path / 'run'}"), run_dir=tmp_path / "elsewhere")
    assert not (tmp_path / "elsewhere").exists()  # the outputs went on in the run that was resumed
    assert len(read_csv(tmp_path / "run" / "learning_curve.csv")) == 20


def test_resume_of_a_directory_without_checkpoint_says_so(tmp_path):
    with pytest.raises(CheckpointError, match="is a directory without checkpoints/last.safetensors"):
        train(tiny_config(*TINY, f"resume={tmp_path}"), run_dir=tmp_path / "run")


def test_resume_without_last_offers_the_newest_iteration_checkpoint_which_resumes(tmp_path):
    """After a full disk (or a kill while last.safetensors was written) the run keeps its iter_XXXX checkpoints:
    resume=true and resume=<the run> name the newest, and resuming from it finishes the run; the control, a run
    without any checkpoint, keeps the plain refusal."""
    train(tiny_config(*TINY, "algo.iterations=2"), run_dir=tmp_path)
    folder = tmp_path / "checkpoints"
    for lost in ("last", "iter_0002"):  # the disk filled up in the second iteration
        (folder / f"{lost}.safetensors").unlink()
    newest = str(folder / "iter_0001.safetensors")
    for resume in ("resume=true", f"resume={tmp_path}"):
        with pytest.raises(CheckpointError) as error:
            train(tiny_config(*TINY, "algo.iterations=2", resume), run_dir=tmp_path)
        assert f"its newest iteration checkpoint is there: pass resume={newest!r} to continue" in str(error.value)
        assert "\n" not in str(error.value)
    train(tiny_config(*TINY, "algo.iterations=2", f"resume={newest}"), run_dir=tmp_path)
    assert (folder / "last.safetensors").is_file() and (folder / "iter_0002.safetensors").is_file()
    with pytest.raises(CheckpointError, match="does not exist: pass hydra.run.dir=") as error:
        train(tiny_config(*TINY, "resume=true"), run_dir=tmp_path / "empty")
    assert "iteration checkpoint" not in str(error.value)


def test_a_checkpoint_outside_a_run_continues_in_the_new_run_directory(tmp_path, monkeypatch):
    _interrupt_after(monkeypatch, 14)
    with pytest.raises(KeyboardInterrupt):
        train(tiny_config(*TINY), run_dir=tmp_path / "run")
    monkeypatch.undo()
    copied = tmp_path / "shared.safetensors"
    copied.write_bytes((tmp_path / "run" / "checkpoints" / "last.safetensors").read_bytes())
    train(tiny_config(*TINY, f"resume={copied}"), run_dir=tmp_path / "new")
    # killed at global trial 14: the checkpoint is at trial 3 of phase 2 (global 13)
    assert [int(r["global_trial"]) for r in read_csv(tmp_path / "new" / "learning_curve.csv")] == list(range(13, 20))
    assert sorted(os.listdir(tmp_path)) == ["new", "run", "shared.safetensors"]  # nothing written beside the copy


# ---------------------------------------------------------------------- bad generator state, named code
def test_a_broken_generator_state_is_refused_mid_phase(tmp_path, monkeypatch):
    from safetensors import safe_open
    from safetensors.torch import load_file, save_file

    _interrupt_after(monkeypatch, 14)
    with pytest.raises(KeyboardInterrupt):
        train(tiny_config(*TINY), run_dir=tmp_path)
    monkeypatch.undo()
    path = tmp_path / "checkpoints" / "last.safetensors"
    with safe_open(str(path), framework="pt") as handle:
        metadata = handle.metadata()
    tensors = load_file(str(path))
    tensors["rng/trainer"] = torch.zeros_like(tensors["rng/trainer"])  # the right size, not an mt19937 state
    save_file(tensors, str(path), metadata=metadata)
    with pytest.raises(CheckpointError, match="rng/trainer is not a cpu generator state: must be uint8 \\(5056,\\)"):
        train(tiny_config(*TINY, "resume=true"), run_dir=tmp_path)


@pytest.mark.parametrize("target", ["builtins.print", "os.getcwd", "pedrl.algos.base.Trainer"])
def test_a_typed_config_names_no_code_either(tmp_path, target):
    with pytest.raises(ValueError, match=f"algo._target_='{target}' is invalid: must be one of pedrl.algos.VQQL"):
        build_trainer(tiny_config("algo=vqql", f"algo._target_={target}"), tmp_path)
    with pytest.raises(ValueError, match="extra._target_ is not allowed"):
        build_trainer(tiny_config("algo=vqql", "+extra={_target_: builtins.list}"), tmp_path)


# ---------------------------------------------------------------------- file-system errors
def test_a_full_disk_gives_one_line_naming_the_checkpoint(tmp_path, monkeypatch, capsys):
    from safetensors import SafetensorError

    import pedrl.io.checkpoint as checkpoint_module

    def full_disk(tensors, filename, metadata=None):
        raise SafetensorError("Error while serializing: IoError(Os { code: 28, kind: StorageFull })")

    monkeypatch.setattr(checkpoint_module, "save_file", full_disk)
    with pytest.raises(SystemExit) as info:
        run_reporting_errors("pedrl-train", lambda: train(tiny_config(*TINY), run_dir=tmp_path))
    assert info.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    path = tmp_path / "checkpoints" / "last.safetensors"
    assert len(lines) == 1 and lines[0].startswith(f"pedrl-train: error: cannot write checkpoint {str(path)!r}: ")
    assert "StorageFull" in lines[0]
    assert os.listdir(tmp_path / "checkpoints") == []  # no temporary left behind


def test_an_os_error_gives_one_line_naming_the_path(capsys):
    def fails():
        raise OSError(28, "No space left on device", "/runs/a/learning_curve.csv")

    with pytest.raises(SystemExit) as info:
        run_reporting_errors("pedrl-train", fails)
    assert info.value.code == 2
    assert (
        capsys.readouterr().err
        == "pedrl-train: error: cannot use '/runs/a/learning_curve.csv': No space left on device\n"
    )


# ---------------------------------------------------------------------- kill anywhere
def _killed_at(point: str, nth: int):
    """Patches that SIGKILL this process at the ``nth`` passage through ``point`` (no cleanup code runs)."""
    import csv

    import pedrl.io.checkpoint as checkpoint_module
    from pedrl.algos.records import RunRecord
    from pedrl.io import metrics

    calls = {"n": 0}

    def count() -> bool:
        calls["n"] += 1
        return calls["n"] == nth

    def die() -> None:
        os.kill(os.getpid(), signal.SIGKILL)

    if point == "phase":  # after a trial's row was written, between checkpoints
        original_log = RunRecord.log_trial

        def log(self, *args, **kwargs):
            original_log(self, *args, **kwargs)
            if count():
                die()

        RunRecord.log_trial = log
    elif point == "checkpoint_half_written":  # safetensors had written half the temporary file
        original_save = checkpoint_module.save_file

        def save(tensors, filename, metadata=None):
            original_save(tensors, filename, metadata=metadata)
            if count():
                with open(filename, "rb+") as handle:
                    handle.truncate(os.path.getsize(filename) // 2)
                die()

        checkpoint_module.save_file = save
    elif point == "checkpoint_before_rename":  # the temporary is complete and synced, not yet renamed
        original_replace = os.replace

        def replace(source, destination):
            if str(destination).endswith(".safetensors") and count():
                die()
            original_replace(source, destination)

        os.replace = replace
    elif point == "csv_rewrite":  # while the resumed run rewrites the rows it keeps
        original_init, original_row = metrics.CsvWriter.__init__, csv.DictWriter.writerow
        rewriting = {"on": False}

        def init(self, *args, **kwargs):
            rewriting["on"] = True
            try:
                original_init(self, *args, **kwargs)
            finally:
                rewriting["on"] = False

        def writerow(self, row):
            if rewriting["on"] and count():
                die()
            return original_row(self, row)

        metrics.CsvWriter.__init__ = init
        csv.DictWriter.writerow = writerow
    else:
        raise AssertionError(point)


def _run_until_killed(cfg, run_dir, point: str, nth: int) -> None:
    """Train in a forked child that is SIGKILLed at ``point``; fail if it ends any other way."""
    pid = os.fork()
    if pid == 0:  # the child: it never returns to pytest
        try:
            torch.set_num_threads(1)
            _killed_at(point, nth)
            train(cfg, run_dir=run_dir)
        finally:
            os._exit(3)  # the kill point was never reached
    deadline = time.monotonic() + 120
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            break
        if time.monotonic() > deadline:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            pytest.fail(f"the child killed at {point} hung")
        time.sleep(0.05)
    assert os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL, f"not killed at {point}: {status}"


def _assert_same_run(reference, resumed) -> None:
    for name in ("last.safetensors", "iter_0001.safetensors", "iter_0002.safetensors"):
        a = load_checkpoint(reference / "checkpoints" / name)
        b = load_checkpoint(resumed / "checkpoints" / name)
        assert a.tensors.keys() == b.tensors.keys(), name
        for key in a.tensors:
            assert torch.equal(a.tensors[key], b.tensors[key]), f"{name}: {key}"
            assert a.tensors[key].dtype == b.tensors[key].dtype
    assert _strip_clock(read_csv(reference / "learning_curve.csv")) == _strip_clock(
        read_csv(resumed / "learning_curve.csv")
    )
    assert sorted(os.listdir(resumed / "checkpoints")) == sorted(os.listdir(reference / "checkpoints"))
    assert not [p for p in resumed.rglob("*.tmp")], "temporaries left behind"
    assert json.loads((resumed / "summary.json").read_text())["final"] == pytest.approx(
        json.loads((reference / "summary.json").read_text())["final"]
    )


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """An uninterrupted run of the tiny config."""
    run_dir = tmp_path_factory.mktemp("reference")
    train(tiny_config(*TINY), run_dir=run_dir)
    return run_dir


KILLS = [
    # (kill point, passage, killed again while the resumed run rewrites the CSV)
    ("phase", 14, False),  # phase 2, two trials after the checkpoint at its trial 3
    ("checkpoint_half_written", 3, False),  # the 3rd write: the mid-phase last.safetensors of phase 1 (trial 9)
    ("checkpoint_before_rename", 5, False),  # the 5th write: last.safetensors at the end of phase 1, after iter_0001
    ("phase", 5, True),
]
SLOW_KILLS = {1, 2}  # the fast sample: a kill in a phase, then a kill in the CSV rewrite of the resume


@pytest.mark.parametrize(
    ("point", "nth", "kill_rewrite"),
    [pytest.param(*kill, marks=pytest.mark.slow) if i in SLOW_KILLS else kill for i, kill in enumerate(KILLS)],
)
def test_a_run_killed_anywhere_resumes_to_the_same_numbers(reference, tmp_path, point, nth, kill_rewrite):
    _run_until_killed(tiny_config(*TINY), tmp_path, point, nth)
    if point.startswith("checkpoint_"):
        assert list((tmp_path / "checkpoints").glob(".*.tmp")), "the kill left a temporary, as a real one would"
    if kill_rewrite:
        rows_before = read_csv(tmp_path / "learning_curve.csv")
        _run_until_killed(tiny_config(*TINY, "resume=true"), tmp_path, "csv_rewrite", 2)
        assert read_csv(tmp_path / "learning_curve.csv") == rows_before, "no row lost"
    train(tiny_config(*TINY, "resume=true"), run_dir=tmp_path)
    _assert_same_run(reference, tmp_path)


def test_checkpoints_written_before_compile_sensing_existed_still_resume():
    from pedrl.algos.restore import config_mismatch

    current = {"env": {"width": 60.0, "compile_sensing": False}, "seed": 0}
    older = {"env": {"width": 60.0}, "seed": 0}
    assert config_mismatch(older, current) == ""
    assert "env.compile_sensing" in config_mismatch(older, {**current, "env": {"width": 60.0, "compile_sensing": True}})


# ---------------------------------------------------------------------- the trial path
@pytest.mark.skipif(not numba_available(), reason="numba is off (PEDRL_NO_NUMBA)")
def test_a_resume_keeps_the_trial_path_the_run_started_on(tmp_path, monkeypatch):
    """A run started on the fused path (the CPU default) refuses, in one line, to go on in the torch loop (numba
    switched off, as ``PEDRL_NO_NUMBA=1`` does), whose numbers for a seed differ; resumed as it started, it goes on."""
    import pedrl.trial.crowd

    _interrupt_after(monkeypatch, 14)
    with pytest.raises(KeyboardInterrupt):
        train(tiny_config(*TINY), run_dir=tmp_path)
    monkeypatch.undo()
    assert load_checkpoint(tmp_path / "checkpoints" / "last.safetensors").metadata["trial_path"] == "fused"
    curve = (tmp_path / "learning_curve.csv").read_bytes()
    monkeypatch.setattr(pedrl.trial.crowd, "numba_available", lambda: False)
    with pytest.raises(CheckpointError) as refused:
        train(tiny_config(*TINY, "resume=true"), run_dir=tmp_path)
    message = str(refused.value)
    assert "ran its trials on the fused path and this resume would run them on the torch path" in message
    assert "without numba" in message and "\n" not in message
    assert (tmp_path / "learning_curve.csv").read_bytes() == curve  # nothing ran, nothing was lost
    monkeypatch.undo()
    train(tiny_config(*TINY, "resume=true"), run_dir=tmp_path)  # the control: as it started, it goes on
    assert len(read_csv(tmp_path / "learning_curve.csv")) == 20

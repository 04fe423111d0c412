"""The bad-input catalogue's helpers: every entry point refuses a bad value, path or file before any compute.

The catalogue is split by entry point, each part in the test file of its module: ``tests/test_train.py``
(``pedrl-train``), ``tests/test_evaluate.py`` (``pedrl-eval``), ``tests/test_validate.py`` (``pedrl-validate``),
``tests/test_plot.py`` (``pedrl-plot``), ``tests/test_sweep.py`` (``pedrl-sweep``); what every entry point shares
through :mod:`pedrl.cli` (unusable run folders, unknown keys, Hydra's own files, seeds, the real console scripts) is
in ``tests/test_cli.py``.

Each case runs a real entry point (the Hydra applications with ``sys.argv`` set, ``pedrl-sweep`` with its argv) in
this process, and asserts what a user sees: exit code 2, exactly one line on stderr, ``<program>: error: ...``
naming the bad value and what is allowed, no traceback, and a run folder holding nothing beyond Hydra's own
``.hydra/`` and log file. In-process calls keep the catalogue fast (a subprocess costs seconds of imports);
``tests/test_cli.py::test_real_entry_points_behave_the_same`` runs one case of every command as a real subprocess.

Not a test module (pytest collects ``test_*.py`` only): the test files import it as ``tests.refusals``.
"""

from __future__ import annotations

import csv
import json
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from omegaconf import OmegaConf, open_dict

import pedrl.sweep
from pedrl.algos.records import CURVE_COLUMNS
from pedrl.cli import CONFIG_DIR
from pedrl.train import train

HYDRA_OWN = {".hydra", "train.log", "evaluate.log", "plot.log", "validate.log"}
"""What Hydra writes into a run folder before the job starts: nothing else may be there after a refusal."""

TRAIN_BASE = ["debug=default", "logger=none"]
"""Every train case adds its overrides to a debug-sized run: with a good value it would run in seconds."""

EVAL_BASE = ["agents=[2,3]", "trials=1", "trials_per_batch=1", "animation.enabled=false", "tensorboard=false"]
"""Every eval case adds its overrides to a seconds-long evaluation of the trained checkpoint (a 10 m x 10 m room)."""


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


# ---------------------------------------------------------------------- what the cases refer to
TINY_VQQL = (
    "debug=default",
    "algo=vqql",
    "algo.num_agents=2",
    "algo.trials=2",
    "vq.num_prototypes=8",
    "env.max_decisions=10",
    "logger=none",
)
"""A seconds-long VQQL run: 2 processes, 2 agents, a 10 m x 10 m room."""


def train_checkpoint(tmp_path_factory, overrides: tuple[str, ...] = TINY_VQQL) -> Path:
    """``last.safetensors`` of a seconds-long run of the train config with ``overrides`` (default :data:`TINY_VQQL`),
    progress bars off and torch's thread count restored after it.

    Each test module that needs it wraps it in a module-scoped ``checkpoint`` fixture."""
    with initialize_config_dir(version_base="1.3", config_dir=CONFIG_DIR):
        cfg = compose("train", list(overrides))
    with open_dict(cfg):
        cfg.progress = False
    run_dir = tmp_path_factory.mktemp("trained")
    threads = torch.get_num_threads()
    try:
        train(cfg, run_dir=run_dir)
    finally:
        torch.set_num_threads(threads)
    return run_dir / "checkpoints" / "last.safetensors"


def read_only_folder(tmp_path: Path) -> Iterator[Path]:
    """A folder nobody may write in: a mode-0555 folder, or for root (who ignores modes) read-only ``/sys``.

    A generator for a ``read_only_dir`` fixture (``yield from read_only_folder(tmp_path)``)."""
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


def write_small_curve(path: Path, rows: int = 4) -> Path:
    """A learning_curve.csv as pedrl-train writes it: ``rows`` trials of phase 1, every metric 0."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=CURVE_COLUMNS)
        writer.writeheader()
        for trial in range(rows):
            row = {column: 0.0 for column in CURVE_COLUMNS}
            row.update(phase=1, agents=2, trial=trial, global_trial=trial)
            writer.writerow(row)
    return path


def binary_curve(run: Path) -> None:
    """Replace the learning_curve.csv of ``run`` with bytes that are no text."""
    (run / "learning_curve.csv").write_bytes(bytes(range(256)) * 4)


def make_plain_job(sweep_dir: Path, name: str = "0") -> Path:
    """A finished job of a ``pedrl-train --multirun`` sweep: summary.json and .hydra/{overrides,config}.yaml, with
    ``vq.num_prototypes=512`` and every final metric 0.5."""
    job = sweep_dir / name
    (job / ".hydra").mkdir(parents=True)
    OmegaConf.save(OmegaConf.create(["vq.num_prototypes=512"]), job / ".hydra" / "overrides.yaml")
    OmegaConf.save(OmegaConf.create({"vq": {"num_prototypes": 512}}), job / ".hydra" / "config.yaml")
    final = {f"{m}_{s}": 0.5 for m in pedrl.sweep.FINAL_METRICS for s in ("mean", "std")}
    (job / "summary.json").write_text(json.dumps({"algo": "vqql", "final": final, "wall_time_s": 1.0}))
    return job

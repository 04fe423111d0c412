"""``pedrl-validate`` refuses a bad value before any compute: the validate part of the bad-input catalogue.

How a case runs and what it asserts: :mod:`tests.refusals`. The suite itself is tested in ``tests/validation/``.
"""

import pytest

import pedrl.validate
from tests.refusals import assert_nothing_computed, assert_refused, catalogue, run_hydra_main

VALIDATE_CASES: list[tuple[str, tuple[str, ...]]] = [
    ("controller=both", ("checkpoint is missing", "controller=references")),
    ("controller=smart", ("controller='smart' is invalid", "all, both, references, learned, greedy, jupedsim")),
    ("controller=greedy epsilon=-1", ("epsilon=-1", "[0, 1]")),
    ("controller=greedy queue_weight=1e9", ("queue_weight=1000000000.0", "[0, 100]")),
    ("controller=greedy tests=[lanes,queues]", ("tests='queues' is invalid", "rimea_1")),
    ("controller=greedy tests=lanes", ("tests='lanes' is invalid", "non-empty list")),
    ("controller=greedy seed=-1", ("seed=-1", "integer in")),
    ("checkpoint={tmp}/absent.safetensors", ("absent.safetensors",)),
    # a value of a column this run does not use is checked all the same
    ("controller=greedy jupedsim.model=foo", ("jupedsim.model='foo' is invalid",)),
    ("controller=greedy jupedsim.dt=0", ("jupedsim.dt=0 is invalid",)),
    ("controller=jupedsim jupedsim.dt=1e-9", ("jupedsim.dt=1e-09 is invalid", ">= 0.001 s")),
]


@pytest.mark.parametrize(("overrides", "fragments"), catalogue(VALIDATE_CASES, {"controller=both"}))
def test_validate_refuses(overrides, fragments, tmp_path, capsys):
    run_dir = tmp_path / "run"
    args = [*overrides.format(tmp=tmp_path).split(), "quick=true", f"hydra.run.dir={run_dir}"]
    outcome = run_hydra_main(pedrl.validate, args, capsys)
    assert_refused(outcome, "pedrl-validate", fragments)
    assert_nothing_computed(run_dir)

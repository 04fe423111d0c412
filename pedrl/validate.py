"""``pedrl-validate``: the validation suite on a learned checkpoint and on the greedy reference.

``main`` is a thin ``@hydra.main`` wrapper: it checks the values, reloads the checkpoint with
:func:`pedrl.evaluation.load_policy` and runs :func:`pedrl.validation.runner.validate`, whose reports are described in
:mod:`pedrl.validation.report`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import hydra
from omegaconf import DictConfig, ListConfig

from pedrl.cli import checked_groups, hydra_output_dir, run_reporting_errors
from pedrl.runtime import set_threads
from pedrl.sim.validation import MAX_SEED, check_bool, check_choice, check_device, check_integer, check_number
from pedrl.validation.runner import CONTROLLERS, validate
from pedrl.validation.suite import TESTS

CONFIG_DIR = str(Path(__file__).resolve().parent.parent / "conf")


def run(cfg: DictConfig, *, run_dir: Path | None = None) -> dict[str, Any]:
    """Check ``cfg``, reload the checkpoint and run the suite; returns the rows per controller."""
    controller = check_choice("controller", cfg.get("controller"), CONTROLLERS)
    epsilon = check_number("epsilon", cfg.get("epsilon"), low=0.0, high=1.0)
    quick = check_bool("quick", cfg.get("quick"))
    seed = check_integer("seed", cfg.get("seed"), minimum=0, maximum=MAX_SEED)
    device = check_device(cfg.get("device"))
    tensorboard = check_bool("tensorboard", cfg.get("tensorboard"))
    if cfg.get("threads") is not None:
        check_integer("threads", cfg.get("threads"), minimum=1)
    tests = cfg.get("tests")
    if tests is not None:
        if not isinstance(tests, list | ListConfig) or not tests:
            raise ValueError(f"tests={tests!r} is invalid: must be null or a non-empty list of {', '.join(TESTS)}")
        for test in tests:
            check_choice("tests", test, TESTS)
        tests = list(tests)
    checkpoint = cfg.get("checkpoint")
    if checkpoint is None and controller != "greedy":
        raise ValueError(f"checkpoint is missing: controller={controller} needs one (or use controller=greedy)")
    set_threads(cfg.get("threads"))
    learned = None
    if checkpoint is not None:
        from pedrl.evaluation import load_policy

        policy = load_policy(checkpoint, controller="learned", epsilon=epsilon, device=device, max_decisions=None)
        learned = (policy.controller, policy.env_settings)
    return validate(
        run_dir=run_dir or hydra_output_dir(),
        learned=learned,
        controller=controller,
        epsilon=epsilon,
        quick=quick,
        tests=tests,
        seed=seed,
        device=device,
        tensorboard=tensorboard,
        meta={"checkpoint": None if checkpoint is None else str(checkpoint)},
        progress=lambda step: print(f"pedrl-validate: {step}", flush=True),
    )


@checked_groups("pedrl-validate", CONFIG_DIR, groups=())
@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="validate")
def main(cfg: DictConfig) -> None:
    """Run the suite and print the verdicts; a bad value or file exits with code 2 and one line."""
    results = run_reporting_errors("pedrl-validate", lambda: run(cfg))
    for controller, rows in results.items():
        passed = sum(row.passed for row in rows)
        print(f"{controller}: {passed}/{len(rows)} passed")
        for row in rows:
            value = "n/a" if row.value is None else f"{row.value:.3g}"
            print(f"  {'pass' if row.passed else 'FAIL'}  {row.test}: {value} {row.unit}")
    print(f"reports: {hydra_output_dir()}/validation.md, validation.json")


if __name__ == "__main__":
    main()

"""``pedrl-validate``: the validation suite on a learned checkpoint, the greedy reference and JuPedSim.

``main`` is a thin ``@hydra.main`` wrapper: it checks the values, reloads the checkpoint with
:func:`pedrl.load_policy` and runs :func:`pedrl.validation.runner.validate`, whose reports are described in
:mod:`pedrl.validation.report`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import hydra
import torch
from omegaconf import DictConfig, ListConfig

from pedrl.cli import CONFIG_DIR, checked_groups, hydra_output_dir, run_reporting_errors
from pedrl.common.checks import MAX_SEED, check_bool, check_choice, check_device, check_integer, check_number
from pedrl.io.files import check_outputs
from pedrl.runtime import set_threads
from pedrl.sim.routing import check_queue_weight
from pedrl.trial.crowd import choose_path
from pedrl.validation.report import pass_count
from pedrl.validation.runner import CHOICES, columns, validate
from pedrl.validation.suite import TEST_NAMES


def run(cfg: DictConfig, *, run_dir: Path | None = None) -> dict[str, Any]:
    """Check ``cfg``, reload the checkpoint and run the suite; returns the rows per controller."""
    controller = check_choice("controller", cfg.get("controller"), tuple(CHOICES))
    epsilon = check_number("epsilon", cfg.get("epsilon"), low=0.0, high=1.0)
    quick = check_bool("quick", cfg.get("quick"))
    seed = check_integer("seed", cfg.get("seed"), minimum=0, maximum=MAX_SEED)
    device = check_device(cfg.get("device"))
    tensorboard = check_bool("tensorboard", cfg.get("tensorboard"))
    if cfg.get("threads") is not None:
        check_integer("threads", cfg.get("threads"), minimum=1)
    fused = cfg.get("fused")
    choose_path([], None, fused)  # the value; the rooms are checked once built
    radius = cfg.get("radius")
    if radius is not None:
        radius = check_number("radius", radius, low=0.05, high=1.0)
    queue_weight = check_queue_weight(cfg.get("queue_weight"))
    tests = cfg.get("tests")
    if tests is not None:
        if not isinstance(tests, list | ListConfig) or not tests:
            raise ValueError(f"tests={tests!r} is invalid: must be null or a non-empty list of {', '.join(TEST_NAMES)}")
        for test in tests:
            check_choice("tests", test, TEST_NAMES)
        if set(tests) == {"invariants"}:
            raise ValueError("tests=[invariants] is invalid: the invariants row checks the runs of the other tests")
        tests = list(tests)
    checkpoint = cfg.get("checkpoint")
    if checkpoint is None and "learned" in columns(controller):
        raise ValueError(
            f"checkpoint is missing: controller={controller} needs one (or use controller=references, greedy or"
            " jupedsim)"
        )
    from pedrl.integrations.jupedsim import model_from_settings

    model_from_settings(cfg.get("jupedsim"))  # every value given is checked, whether or not this run uses it
    jupedsim = jupedsim_model(cfg.get("jupedsim")) if "jupedsim" in columns(controller) else None
    run_dir = run_dir or hydra_output_dir()
    folders = [
        run_dir,
        run_dir / "figures",
        run_dir / "trajectories",
        *(run_dir / "trajectories" / name for name in columns(controller)),
    ]
    if tensorboard:
        folders.append(run_dir / "tb")
    check_outputs(folders, [run_dir / "validation.json", run_dir / "validation.md"])  # before any compute
    set_threads(cfg.get("threads"))
    learned = None
    if checkpoint is not None:
        from pedrl.policy_files import load_policy, room_settings

        policy = load_policy(checkpoint, device=device)
        env_settings = room_settings(policy)
        learned = (policy.controller(epsilon, torch.Generator(device=device)), env_settings)  # seeded by the runner
        own = float(env_settings.get("agent_radius", 0.4))
        if radius is not None and radius != own:
            raise ValueError(
                f"radius={radius!r} is invalid with a checkpoint: every test runs at the checkpoint's own body radius,"
                f" {own:g} m (leave radius null)"
            )
    return validate(
        run_dir=run_dir,
        learned=learned,
        controller=controller,
        epsilon=epsilon,
        quick=quick,
        tests=tests,
        seed=seed,
        device=device,
        radius=radius,
        queue_weight=queue_weight,
        jupedsim=jupedsim,
        tensorboard=tensorboard,
        fused=fused,
        meta={"checkpoint": None if checkpoint is None else str(checkpoint)},
        progress=lambda step: print(f"pedrl-validate: {step}", flush=True),
    )


def jupedsim_model(settings: Any) -> Any:
    """The :class:`~pedrl.integrations.jupedsim.JuPedSimModel` of the ``jupedsim`` settings, after checking that
    JuPedSim is installed; one-line errors. The suite gives it the run's body radius."""
    from pedrl.integrations.jupedsim import INSTALL_HINT, installed, model_from_settings

    if not installed():
        raise ValueError(f"the jupedsim column is invalid here: {INSTALL_HINT} (or choose controller=both)")
    return model_from_settings(settings)


@checked_groups("pedrl-validate", CONFIG_DIR, groups=())
@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="validate")
def main(cfg: DictConfig) -> None:
    """Run the suite and print the verdicts; a bad value or file exits with code 2 and one line."""
    results = run_reporting_errors("pedrl-validate", lambda: run(cfg))
    if cfg.get("quick"):
        print("quick: not a verdict")
    for controller, rows in results.items():
        print(f"{controller}: {pass_count(rows)} passed")
        for row in rows:
            value = row.reference if not row.applicable else ("n/a" if row.value is None else f"{row.value:.3g}")
            print(f"  {row.status:4}  {row.test}: {value} {row.unit}")
    print(f"reports: {hydra_output_dir()}/validation.md, validation.json")


if __name__ == "__main__":
    main()

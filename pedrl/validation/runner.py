"""Run the validation suite for the controllers asked for and write its reports (plain arguments, no Hydra)."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Final

import torch

from pedrl.algos.controllers import GreedyDoorController
from pedrl.scenarios import Scenario
from pedrl.sim import RoomEnv
from pedrl.validation.report import write_reports
from pedrl.validation.suite import TESTS, Budget, TestResult, run_suite

CONTROLLERS: Final = ("both", "learned", "greedy")
"""Values of ``controller``: the learned checkpoint and the greedy reference side by side, or one of them."""


def room_maker(env_settings: Mapping[str, Any], *, device: torch.device) -> Callable[..., RoomEnv]:
    """``make(scenario, num_agents=, num_replicas=, max_decisions=)``: a room of the ``env`` settings (a checkpoint's,
    or the defaults) in ``scenario``, after checking that the agents fit in its spawn areas."""
    settings = {key: value for key, value in env_settings.items() if key not in ("_target_", "max_decisions")}

    def make(scenario: Scenario, *, num_agents: int, num_replicas: int, max_decisions: int) -> RoomEnv:
        return scenario.room(
            **settings, num_agents=num_agents, num_replicas=num_replicas, max_decisions=max_decisions, device=device
        )

    return make


def validate(
    *,
    run_dir: Path,
    learned: tuple[Any, Mapping[str, Any]] | None,
    controller: str,
    epsilon: float,
    quick: bool,
    tests: Sequence[str] | None,
    seed: int,
    device: torch.device,
    tensorboard: bool = True,
    meta: Mapping[str, Any] | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict[str, list[TestResult]]:
    """Run the suite with the learned controller (``learned``: the controller and its checkpoint's ``env``
    settings) and/or the greedy reference, and write ``validation.json``, ``validation.md`` and the figures.

    The greedy reference runs in the checkpoint's room settings when there is one (same bodies, speeds, sensing),
    else in the defaults of :class:`~pedrl.sim.RoomEnv`.
    """
    budget = Budget(quick=quick)
    chosen: dict[str, tuple[Any, Mapping[str, Any]]] = {}
    env_settings = learned[1] if learned is not None else {}
    if controller in ("both", "learned") and learned is not None:
        chosen["learned"] = learned
    if controller in ("both", "greedy"):
        generator = torch.Generator(device=device).manual_seed(seed)
        chosen["greedy"] = (GreedyDoorController(epsilon=epsilon, generator=generator), env_settings)
    results: dict[str, list[TestResult]] = {}
    figures: dict[str, dict[str, Any]] = {}
    started = time.perf_counter()
    for name, (policy, settings) in chosen.items():
        torch.manual_seed(seed)
        if hasattr(policy, "generator"):
            policy.generator.manual_seed(seed)
        report = None if progress is None else (lambda test, name=name: progress(f"{name}: {test}"))
        results[name], figures[name] = run_suite(
            room_maker(settings, device=device), policy, budget=budget, only=tests, progress=report
        )
    document = {
        **(meta or {}),
        "controllers": list(chosen),
        "quick": quick,
        "epsilon": epsilon,
        "seed": seed,
        "tests_run": list(tests or TESTS),
        "wall_time_s": round(time.perf_counter() - started, 1),
    }
    write_reports(run_dir, results, figures, meta=document, tensorboard=tensorboard)
    return results

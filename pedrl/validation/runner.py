"""Run the validation suite for the controllers asked for and write its reports (plain arguments, no Hydra)."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any, Final

import torch

from pedrl.integrations.jupedsim import check_model
from pedrl.sim.controllers import GreedyDoorController
from pedrl.validation.crowds import JuPedSimCrowd, PedrlCrowd
from pedrl.validation.report import write_reports
from pedrl.validation.suite import TEST_NAMES, Budget, TestResult, run_suite

CONTROLLERS: Final = ("learned", "greedy", "jupedsim")
"""The crowds a report can hold, in column order."""
CHOICES: Final = {
    "all": CONTROLLERS,
    "both": ("learned", "greedy"),
    "references": ("greedy", "jupedsim"),
    "learned": ("learned",),
    "greedy": ("greedy",),
    "jupedsim": ("jupedsim",),
}
"""Values of ``controller`` and the columns each runs."""
DEFAULT_RADIUS: Final = 0.2
"""Body radius (m) of a run without a checkpoint: JuPedSim's default, a pedestrian's shoulder radius."""


def columns(controller: str) -> tuple[str, ...]:
    """The controllers ``controller`` names (one of :data:`CHOICES`)."""
    return CHOICES[controller]


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
    radius: float | None = None,
    queue_weight: float | None = None,
    jupedsim: Any = None,
    tensorboard: bool = True,
    fused: bool | None = None,
    meta: Mapping[str, Any] | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict[str, list[TestResult]]:
    """Run the suite with the learned controller (``learned``: the controller and its checkpoint's ``env``
    settings), the greedy reference and JuPedSim (``jupedsim``: a :class:`~pedrl.integrations.jupedsim.JuPedSimModel`)
    as ``controller`` names them, and write ``validation.json``, ``validation.md`` and the figures.

    Every column runs at one body radius: the checkpoint's, else ``radius`` (default :data:`DEFAULT_RADIUS`). The
    greedy reference runs in the checkpoint's room settings when there is one (same bodies, speeds, sensing), else in
    the defaults of :class:`~pedrl.sim.RoomEnv`; JuPedSim starts from the positions the same rooms give. The learned
    and greedy crowds run through the fused trial's kernels where they can (``fused``: None), or the torch loop
    (False). ``queue_weight`` (None: the checkpoint's, else the room's default) sets how every column's walkers choose
    their exits (:mod:`pedrl.sim.routing`).
    """
    budget = Budget(quick=quick)
    env_settings = dict(learned[1]) if learned is not None else {}
    if learned is None:
        env_settings["agent_radius"] = radius if radius is not None else DEFAULT_RADIUS
    if queue_weight is not None:
        env_settings["queue_weight"] = queue_weight
    crowds: dict[str, Any] = {}
    for name in columns(controller):
        if name == "learned" and learned is not None:
            crowds[name] = PedrlCrowd(learned[0], env_settings, device, fused)
        elif name == "greedy":
            greedy = GreedyDoorController(epsilon=epsilon, generator=torch.Generator(device=device))  # seeded below
            crowds[name] = PedrlCrowd(greedy, env_settings, device, fused)
        elif name == "jupedsim":
            placement = PedrlCrowd(None, env_settings, device)
            model = replace(jupedsim, radius=placement.radius)
            check_model(model)  # JuPedSim's own parameter ranges, before any test runs
            crowds[name] = JuPedSimCrowd(model, placement)
    results: dict[str, list[TestResult]] = {}
    figures: dict[str, dict[str, Any]] = {}
    timings: dict[str, float] = {}
    for name, crowd in crowds.items():
        torch.manual_seed(seed)
        generator = getattr(crowd.controller, "generator", None) if isinstance(crowd, PedrlCrowd) else None
        if generator is not None:
            generator.manual_seed(seed)
        report = None if progress is None else (lambda test, name=name: progress(f"{name}: {test}"))
        started = time.perf_counter()
        results[name], figures[name] = run_suite(
            crowd, budget=budget, only=tests, progress=report, trajectories=run_dir / "trajectories" / name
        )
        timings[name] = round(time.perf_counter() - started, 1)
    document = {
        **(meta or {}),
        "verdict": not quick,
        "controllers": list(crowds),
        "radius_m": next(iter(crowds.values())).radius if crowds else None,
        "quick": quick,
        "epsilon": epsilon,
        "seed": seed,
        "tests_run": list(tests or TEST_NAMES),
        "wall_time_s": timings,
    }
    if "jupedsim" in crowds:
        document["jupedsim"] = asdict(crowds["jupedsim"].model)
    write_reports(run_dir, results, figures, meta=document, tensorboard=tensorboard)
    return results

"""Fit the time gap of a walking layer against Weidmann and Liddle with the greedy walker:
``python -m pedrl.validation.calibrate --experiment pedestrian_walk --time-gaps 0.35 0.4 0.45 0.5``.

For each time gap ``T`` the greedy walker (ε = 0) runs RiMEA 4 (speed against density, Weidmann 1993) and the
bottleneck flows (Liddle et al. 2011) in the experiment's room settings with ``env.motion.time_gap=T``. The fit is the
``T`` whose worse score is smallest, each score the measured error over its pass band: RiMEA 4's RMS distance over its
allowed distance, the largest bottleneck error over 0.25. It prints one row per ``T`` and the chosen one.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import torch

from pedrl.sim.controllers import GreedyDoorController
from pedrl.validation.crowds import PedrlCrowd
from pedrl.validation.framework import Budget
from pedrl.validation.suite import run_suite

BANDS = {"rimea_4": 0.335, "bottleneck": 0.25}
"""The pass band of each fitted test's value: RiMEA 4's RMS distance (m/s), the largest bottleneck error."""


def experiment_env(experiment: str) -> dict[str, Any]:
    """The ``env`` settings that ``pedrl-train experiment=<experiment>`` composes (bar the run-time sizes)."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from pedrl.common.commands import CONFIG_DIR

    with initialize_config_dir(config_dir=CONFIG_DIR, version_base=None):
        config = compose("train", [f"experiment={experiment}"])
    env = OmegaConf.to_container(config.env, resolve=True)
    return {key: value for key, value in env.items() if key != "_target_"}


def score(env: Mapping[str, Any], *, seed: int = 0) -> dict[str, float]:
    """The greedy walker's RiMEA 4 and bottleneck values in rooms of ``env``, and the fit's score (the worse of the
    two over its band; infinite where a test has no value)."""
    greedy = GreedyDoorController(epsilon=0.0, generator=torch.Generator().manual_seed(seed))
    torch.manual_seed(seed)
    results, _ = run_suite(PedrlCrowd(greedy, dict(env)), budget=Budget(quick=False), only=list(BANDS))
    row: dict[str, float] = {}
    for key, result in zip(BANDS, results, strict=False):
        row[key] = math.inf if result.value is None else float(result.value)
    row["score"] = max(row[key] / band for key, band in BANDS.items())
    return row


def fit(env: Mapping[str, Any], time_gaps: Sequence[float], *, seed: int = 0) -> tuple[float, list[dict[str, float]]]:
    """The time gap with the smallest score, and every row."""
    rows = []
    for gap in time_gaps:
        started = time.perf_counter()
        motion = {**env.get("motion", {}), "time_gap": gap}  # the motion model's T
        rows.append({"time_gap": gap, **score({**env, "motion": motion}, seed=seed)})
        rows[-1]["seconds"] = round(time.perf_counter() - started, 1)
    best = min(rows, key=lambda row: row["score"])
    return best["time_gap"], rows


def main(argv: Sequence[str] | None = None) -> None:
    from pedrl.common.checks import MAX_SEED
    from pedrl.common.commands import CONFIG_DIR, OneLineParser, integer_arg, number_arg

    presets = sorted(path.stem for path in (Path(CONFIG_DIR) / "experiment").glob("*.yaml"))
    parser = OneLineParser(prog="python -m pedrl.validation.calibrate", description=__doc__.split("\n")[0])
    parser.add_argument(
        "--experiment", default="pedestrian_walk", choices=presets, help="a conf/experiment preset (its env settings)"
    )
    parser.add_argument(
        "--time-gaps",
        type=number_arg(0.0, 10.0, low_open=True),
        nargs="+",
        default=[0.35, 0.4, 0.45, 0.5],
        help="T values (s)",
    )
    parser.add_argument("--seed", type=integer_arg(0, MAX_SEED), default=0)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    chosen, rows = fit(experiment_env(args.experiment), args.time_gaps, seed=args.seed)
    print("| time_gap (s) | RiMEA 4 RMS (m/s, band 0.335) | bottleneck largest error (band 0.25) | score | s |")
    print("|---|---|---|---|---|")
    for row in rows:
        print(
            f"| {row['time_gap']:g} | {row['rimea_4']:.3f} | {row['bottleneck']:.3f} | {row['score']:.2f} |"
            f" {row['seconds']:g} |"
        )
    print(f"fitted time_gap: {chosen:g} s")


if __name__ == "__main__":
    main()

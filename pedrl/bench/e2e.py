"""End-to-end benchmark: agent-decisions per second of the real VQQL learning loop.

Metrics (wall-clock, best trial of ``trials`` after one warm-up trial, at R = 20 processes, N = 20 agents each,
K = 4096 prototypes; keys of the returned dict):
    - ``e2e``: one row per E (rooms per process) with ``rooms_per_process``, ``agent_decisions_per_s``,
      ``seconds`` (of the best trial) and ``fraction_of_matmul_peak``: the rate as a fraction of the rate that the
      nearest-prototype search alone (``2 K F`` FLOP per decision, F = 28 features) would reach at the float32
      matrix-product peak measured in the same run (``matmul_peak_flop_per_s``).
    - ``e2e_contended`` (``--contention``): the same rows measured while a second torch process multiplies
      matrices on every core (the situation of ``hydra/launcher=parallel`` or of a shared machine).
    - ``e2e_baseline`` (``--baseline COMMIT``): the rows of the same measurement for the code of COMMIT, run from a
      temporary git worktree in a subprocess right before this code's, and ``e2e_speedup`` (this / that, per E).

This file is also the driver that the baseline subprocess runs (``python e2e.py --rooms ...`` with the other
tree's ``pedrl`` on ``PYTHONPATH``): everything below :func:`measure` uses only the API that commit e228a3c
already had (``VQQL``, ``gather``, ``fit_quantizer``, ``run_trial``, ``zeros_q_values``; its rooms came from
``_env``, which is now ``env_for``).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

import torch

PROCESSES, AGENTS, PROTOTYPES, FEATURES = 20, 20, 4096, 28
ROOMS = (1, 4, 16, 32)
"""E values of the default run (docs/performance.md's table); ``--rooms`` picks others."""
QUICK_ROOMS = (1, 2)
QUICK_PROTOTYPES = 512


def _sync(device: str) -> None:
    if str(device).startswith("cuda"):
        torch.cuda.synchronize()


def matmul_peak(device: str = "cpu", *, size: int | None = None, repeats: int = 5) -> float:
    """Float32 matrix-product rate (FLOP/s): best of ``repeats`` products of two ``(size, size)`` matrices."""
    size = size or (8192 if str(device).startswith("cuda") else 1024)
    generator = torch.Generator(device=device).manual_seed(0)
    left = torch.randn(size, size, device=device, generator=generator)
    right = torch.randn(size, size, device=device, generator=generator)
    left @ right  # warm-up
    _sync(device)
    best = float("inf")
    for _ in range(repeats):
        tic = time.perf_counter()
        left @ right
        _sync(device)
        best = min(best, time.perf_counter() - tic)
    return 2.0 * size**3 / best


def measure(*, rooms: Sequence[int], trials: int, quick: bool, device: str) -> list[dict]:
    """Agent-decisions per second of the VQQL loop (``run_trial``) at R = 20, N = 20, for each E in ``rooms``."""
    from pedrl.algos import VQQL
    from pedrl.rl import zeros_q_values
    from pedrl.scenarios import paper_room

    prototypes = QUICK_PROTOTYPES if quick else PROTOTYPES
    rows = []
    for rooms_per_process in rooms:
        trainer = VQQL(
            env=paper_room().room,
            vq={"num_prototypes": prototypes, "max_iterations": 3, "max_states": 100_000},
            num_agents=AGENTS,
            trials=1,
            gather_trials=2,  # 2 x 20 agents x 200 decisions: enough states per process for K = 4096
            processes=PROCESSES,
            rooms_per_process=rooms_per_process,
            device=device,
            progress=False,
            tensorboard=False,
        )
        env = (trainer.env_for if hasattr(trainer, "env_for") else trainer._env)(AGENTS)  # e228a3c: _env
        env.reset(seed=0)
        phase = trainer.phases()[0]
        states, num_sensed = trainer.gather(phase, env, None)[:2]
        quantizer, _ = trainer.fit_quantizer(phase, states, num_sensed, None)
        # the tables as the trainers allocate them (this code: in huge pages on the CPU)
        q_values = zeros_q_values(PROCESSES, AGENTS, quantizer.num_prototypes, env.num_actions, device=device)
        trainer.run_trial(env, quantizer, q_values, epsilon=0.4, learn=True)  # warm-up
        best_rate, best_seconds = 0.0, 0.0
        for _ in range(trials):
            _sync(device)
            tic = time.perf_counter()
            stats = trainer.run_trial(env, quantizer, q_values, epsilon=0.4, learn=True)
            _sync(device)
            seconds = time.perf_counter() - tic
            if stats.agent_decisions / seconds > best_rate:
                best_rate, best_seconds = stats.agent_decisions / seconds, seconds
        rows.append(
            {
                "processes": PROCESSES,
                "rooms_per_process": rooms_per_process,
                "agents": AGENTS,
                "prototypes": quantizer.num_prototypes,
                "seconds": best_seconds,
                "agent_decisions_per_s": best_rate,
            }
        )
        print(f"  e2e R={PROCESSES} E={rooms_per_process}: {best_rate:,.0f} agent-decisions/s", flush=True)
    return rows


def with_peak_fraction(rows: list[dict], peak: float) -> list[dict]:
    """``rows`` with ``fraction_of_matmul_peak``: the rate over ``peak / (2 K F)`` (the search alone at the peak)."""
    return [
        {**row, "fraction_of_matmul_peak": row["agent_decisions_per_s"] * 2.0 * row["prototypes"] * FEATURES / peak}
        for row in rows
    ]


@contextlib.contextmanager
def busy_process() -> Iterator[None]:
    """A second torch process multiplying matrices with torch's default threads, for the time of the block."""
    script = "import torch\na = torch.randn(1024, 1024)\nwhile True:\n    a @ a\n"
    env = {key: value for key, value in os.environ.items() if key != "OMP_NUM_THREADS"}
    process = subprocess.Popen([sys.executable, "-c", script], env=env)
    try:
        time.sleep(1.0)  # let it start
        yield
    finally:
        process.kill()
        process.wait()


def measure_commit(commit: str, *, rooms: Sequence[int], trials: int, quick: bool, device: str) -> list[dict]:
    """:func:`measure` for the code of ``commit``: a temporary git worktree, this file run there in a subprocess."""
    repository = Path(__file__).resolve().parents[2]
    with tempfile.TemporaryDirectory(prefix="pedrl-baseline-") as folder:
        tree = Path(folder) / "tree"
        subprocess.run(
            ["git", "-C", str(repository), "worktree", "add", "--detach", "--quiet", str(tree), commit], check=True
        )
        try:
            output = Path(folder) / "rows.json"
            driver = Path(folder) / "e2e_driver.py"  # run from outside any pedrl tree: the import is the worktree's
            shutil.copyfile(__file__, driver)
            command = [sys.executable, str(driver), "--rooms", ",".join(map(str, rooms)), "--trials", str(trials)]
            command += ["--device", device, "--output", str(output)] + (["--quick"] if quick else [])
            env = {**os.environ, "PYTHONPATH": str(tree)}
            subprocess.run(command, check=True, env=env, cwd=folder)
            return json.loads(output.read_text())
        finally:
            subprocess.run(["git", "-C", str(repository), "worktree", "remove", "--force", str(tree)], check=False)


def run(
    *,
    quick: bool = False,
    device: str = "cpu",
    rooms: Sequence[int] | None = None,
    trials: int | None = None,
    contention: bool = False,
    baseline: str | None = None,
) -> dict:
    """The e2e section of ``python -m pedrl.bench`` (see the module docstring for the keys)."""
    rooms = tuple(rooms or (QUICK_ROOMS if quick else ROOMS))
    trials = trials or (1 if quick else 3)
    report: dict = {}
    if baseline is not None:
        print(f"  baseline {baseline}:", flush=True)
        report["e2e_baseline_commit"] = baseline
        baseline_rows = measure_commit(baseline, rooms=rooms, trials=trials, quick=quick, device=device)
        print("  this code:", flush=True)
    rows = measure(rooms=rooms, trials=trials, quick=quick, device=device)
    peak = matmul_peak(device)
    report["matmul_peak_flop_per_s"] = peak
    report["e2e"] = with_peak_fraction(rows, peak)
    report["e2e_best_agent_decisions_per_s"] = max(row["agent_decisions_per_s"] for row in rows)
    for row in report["e2e"]:
        print(
            f"  e2e E={row['rooms_per_process']}: {row['agent_decisions_per_s']:,.0f} agent-decisions/s ="
            f" {row['fraction_of_matmul_peak']:.1%} of the matmul peak ({peak / 1e9:.0f} GFLOP/s)",
            flush=True,
        )
    if baseline is not None:
        report["e2e_baseline"] = with_peak_fraction(baseline_rows, peak)
        report["e2e_speedup"] = {
            str(new["rooms_per_process"]): new["agent_decisions_per_s"] / old["agent_decisions_per_s"]
            for new, old in zip(rows, baseline_rows, strict=True)
        }
        for key, value in report["e2e_speedup"].items():
            print(f"  e2e E={key}: {value:.2f}x the rate of {baseline}", flush=True)
    if contention:
        print("  with a second busy torch process:", flush=True)
        with busy_process():
            contended = measure(rooms=rooms, trials=trials, quick=quick, device=device)
        report["e2e_contended"] = with_peak_fraction(contended, peak)
    return report


def _driver(argv: list[str] | None = None) -> None:
    """What the baseline subprocess runs: :func:`measure`, rows written as JSON to ``--output``."""
    parser = argparse.ArgumentParser(description="pedrl e2e driver (run by --baseline)")
    parser.add_argument("--rooms", required=True)
    parser.add_argument("--trials", type=int, required=True)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--output", required=True)
    args = parser.parse_args(argv)
    rooms = [int(value) for value in args.rooms.split(",")]
    rows = measure(rooms=rooms, trials=args.trials, quick=args.quick, device=args.device)
    Path(args.output).write_text(json.dumps(rows))


if __name__ == "__main__":
    _driver()

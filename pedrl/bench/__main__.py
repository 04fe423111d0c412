"""``python -m pedrl.bench`` (``make bench``): speed figures written to ``outputs/bench/bench.json``.

Sections:
    sim       random-action stepping: env steps/s and agent-steps/s for (R, N) = (20, 20), (1000, 20), (20, 100)
    kmeans    Lloyd iteration time on 200k x 28 with K = 4096 against scikit-learn and faiss (same data and init),
              and encode throughput
    e2e       end-to-end training decisions/s at R = 20, A = 20, K = 4096 through the real trainer loop
              (simulation, sensing, encoding, epsilon-greedy and the TD update), for several E (rooms per process)
"""

from __future__ import annotations

import argparse
import functools
import json
import platform
import time
from pathlib import Path

import torch

SECTIONS = ("sim", "kmeans", "e2e")


def bench_end_to_end(*, quick: bool = False, device: str = "cpu") -> dict:
    """Agent-decisions per second of the VQQL learning loop at R = 20, A = 20, K = 4096."""
    from pedrl.algos import VQQL
    from pedrl.sim import RoomEnv

    processes, agents, prototypes = 20, 20, (512 if quick else 4096)
    results = []
    for rooms in (1, 4, 16, 32) if not quick else (1, 2):
        trainer = VQQL(
            env=functools.partial(RoomEnv),
            vq={"num_prototypes": prototypes, "max_iterations": 3, "max_states": 100_000},
            num_agents=agents,
            trials=1,
            gather_trials=1,
            processes=processes,
            rooms_per_process=rooms,
            device=device,
            progress=False,
            tensorboard=False,
        )
        env = trainer._env(agents)
        env.reset(seed=0)
        phase = trainer.phases()[0]
        states, num_sensed, _ = trainer.gather(phase, env, None)
        quantizer, _ = trainer.fit_quantizer(phase, states, num_sensed, None)
        q_values = torch.zeros((processes, agents, quantizer.num_prototypes, env.num_actions), device=device)
        trainer.run_trial(env, quantizer, q_values, epsilon=0.4, learn=True)  # warm-up
        decisions, elapsed, trials = 0, 0.0, (1 if quick else 3)
        for _ in range(trials):
            _sync(device)
            tic = time.perf_counter()
            stats = trainer.run_trial(env, quantizer, q_values, epsilon=0.4, learn=True)
            _sync(device)
            elapsed += time.perf_counter() - tic
            decisions += stats.agent_decisions
        results.append(
            {
                "processes": processes,
                "rooms_per_process": rooms,
                "agents": agents,
                "prototypes": quantizer.num_prototypes,
                "agent_decisions": decisions,
                "seconds": elapsed,
                "agent_decisions_per_s": decisions / elapsed,
            }
        )
        print(
            f"  e2e R={processes} E={rooms} A={agents} K={quantizer.num_prototypes}: "
            f"{decisions / elapsed:,.0f} agent-decisions/s",
            flush=True,
        )
    best = max(results, key=lambda r: r["agent_decisions_per_s"])
    return {
        "e2e": results,
        "e2e_best_agent_decisions_per_s": best["agent_decisions_per_s"],
        "e2e_target_agent_decisions_per_s": 500_000,
    }


def _sync(device: str) -> None:
    if str(device).startswith("cuda"):
        torch.cuda.synchronize()


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(prog="python -m pedrl.bench", description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes, for a smoke check")
    parser.add_argument("--device", default="cpu", help="cpu or cuda")
    parser.add_argument("--only", default=",".join(SECTIONS), help=f"comma-separated sections of {SECTIONS}")
    parser.add_argument("--output", default="outputs/bench/bench.json", help="where the JSON goes")
    args = parser.parse_args(argv)
    sections = [s for s in args.only.split(",") if s]
    unknown = sorted(set(sections) - set(SECTIONS))
    if unknown:
        parser.error(f"--only={args.only!r} names unknown sections {unknown}: allowed {', '.join(SECTIONS)}")
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        parser.error(f"--device={args.device!r} is invalid here: no CUDA GPU is available")
    report: dict = {
        "device": args.device,
        "device_name": torch.cuda.get_device_name() if args.device.startswith("cuda") else platform.processor(),
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "quick": args.quick,
    }
    if "sim" in sections:
        from pedrl.bench.sim import run as run_sim

        print("sim ...", flush=True)
        report.update(run_sim(quick=args.quick, device=args.device))
    if "kmeans" in sections:
        from pedrl.bench.kmeans import run as run_kmeans

        print("kmeans ...", flush=True)
        report.update(run_kmeans(quick=args.quick, device=args.device))
    if "e2e" in sections:
        print("end to end ...", flush=True)
        report.update(bench_end_to_end(quick=args.quick, device=args.device))
    output = Path(args.output)
    output.parent.mkdir(parents=True, exist_ok=True)
    previous = json.loads(output.read_text()) if output.exists() else {}
    previous.update(report)
    output.write_text(json.dumps(previous, indent=2))
    print(json.dumps(report, indent=2))
    print(f"wrote {output}")
    return report


if __name__ == "__main__":
    main()

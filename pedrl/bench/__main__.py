"""``python -m pedrl.bench`` (``make bench``): speed figures written to ``outputs/bench/bench.json``.

Sections:
    sim       random-action stepping: env steps/s and agent-steps/s for (R, N) = (20, 20), (1000, 20), (20, 100);
              and a reset of 8 x 40 walkers in the partition room with and without its routes
    kmeans    Lloyd iteration time on 200k x 28 with K = 4096 against scikit-learn and faiss (same data and init),
              and encode throughput
    e2e       end-to-end training decisions/s at R = 20, A = 20, K = 4096 through the real trainer loop
              (simulation, sensing, encoding, epsilon-greedy and the TD update), for several E (rooms per process),
              each also as a fraction of the float32 matmul peak measured in the same run; optionally with a
              second busy torch process (--contention) and beside the code of another commit (--baseline)
    factored  the fused learning trial of the main job's room (80 agents, 8 x 8 rooms) with one plain quantizer
              (K = 2048) and with experiment=main_factored's factored table: agent-decisions/s and their ratio
    dqn       beside the fused tabular trial of that room, a learning and an acting trial of experiment=main_dqn's
              network (one process of 8 rooms of 80 agents, the kernels stepping each decision): agent-decisions/s
    eval      pedrl-eval's recording of a batch (the greedy walker, 80 rooms of 100 and of 20 agents) through the fused
              trial's kernels against the torch loop, in agent-decisions/s and their ratio (target 3x at 100 agents)
    literal   the literal presets' nearest-prototype search at one thread, K = 4096: us/state of the scan against the
              batched search of pedrl.vq.pruned (the same ids), and the search's work per state
    walk      pedrl's continuous walking layer (the greedy walker through the fused trial, one room of N) against
              JuPedSim's collision-free speed model in the same hall at 0.4 persons/m^2, N = 100 to 100,000: wall time,
              agent-steps/s (per core), their ratio, peak memory and linearity, each run in its own one-thread
              process (--agents, --sim-time; --write-docs puts the table into docs/performance.md)
"""

from __future__ import annotations

import argparse
import json
import os
import platform
from pathlib import Path

import torch

SECTIONS = ("sim", "kmeans", "e2e", "eval", "literal", "walk", "factored", "dqn")
PERFORMANCE_PAGE = "docs/performance.md"


def _arguments(argv: list[str] | None) -> tuple[argparse.Namespace, list[int] | None, list[str]]:
    """The command line checked at the door (one line and exit code 2 for a mistake): the arguments, the e2e room
    counts and the sections to run; sets the thread count."""
    from pedrl.bench import walk
    from pedrl.common.commands import OneLineParser, integer_arg, number_arg
    from pedrl.io.files import output_problem

    parser = OneLineParser(prog="python -m pedrl.bench", description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes, for a smoke check")
    parser.add_argument("--device", default="cpu", help="cpu or cuda")
    parser.add_argument("--only", default=",".join(SECTIONS), help=f"comma-separated sections of {SECTIONS}")
    parser.add_argument("--output", default="outputs/bench/bench.json", help="where the JSON goes")
    parser.add_argument(
        "--threads", type=integer_arg(1, 4096), default=None, help="torch CPU threads (default: torch's, one per core)"
    )
    parser.add_argument("--rooms", default=None, help="e2e: comma-separated E values (default 1,4,16,32; quick 1,2)")
    parser.add_argument(
        "--trials", type=integer_arg(1, 1000), default=None, help="e2e: timed trials per E, the best kept (default 3)"
    )
    parser.add_argument("--contention", action="store_true", help="e2e: also measure beside a busy torch process")
    parser.add_argument(
        "--baseline", default=None, metavar="COMMIT", help="e2e: also measure COMMIT's tree alone, first"
    )
    parser.add_argument(
        "--agents",
        default=None,
        help="walk: comma-separated agent counts (default 100,1000,10000,100000; quick 100,1000)",
    )
    parser.add_argument(
        "--sim-time",
        type=number_arg(0.0, walk.MAX_SIM_TIME, low_open=True),
        default=None,
        help=f"walk: simulated seconds per run (default {walk.SIM_TIME:g}; quick {walk.QUICK_SIM_TIME:g})",
    )
    parser.add_argument(
        "--write-docs",
        nargs="?",
        const=PERFORMANCE_PAGE,
        default=None,
        metavar="PAGE",
        help=f"walk: write its table into PAGE between its marker comments (default {PERFORMANCE_PAGE})",
    )
    args = parser.parse_args(argv)
    try:
        args.agents = walk.parse_agents(args.agents) if args.agents is not None else None
        args.sim_time = walk.check_sim_time(args.sim_time) if args.sim_time is not None else None
    except ValueError as err:
        parser.error(str(err))
    rooms = _rooms(parser, args.rooms)
    if not (args.device == "cpu" or args.device == "cuda" or args.device.startswith("cuda:")):
        parser.error(f"--device={args.device!r} is invalid: must be cpu or cuda[:index]")
    for option, path in (("--output", args.output), ("--write-docs", args.write_docs)):
        problem = output_problem(path) if path is not None else None
        if problem is not None:
            parser.error(f"{option}: {problem}")
    if args.threads is not None:
        torch.set_num_threads(args.threads)
        os.environ["OMP_NUM_THREADS"] = str(args.threads)  # the same for the --baseline subprocess
    sections = [s for s in args.only.split(",") if s]
    unknown = sorted(set(sections) - set(SECTIONS))
    if unknown:
        parser.error(f"--only={args.only!r} names unknown sections {unknown}: allowed {', '.join(SECTIONS)}")
    if args.write_docs is not None and "walk" not in sections:
        parser.error(f"--write-docs is invalid with --only={args.only!r}: it writes the walk section's table")
    if args.write_docs is not None and (problem := walk.page_problem(args.write_docs)) is not None:
        parser.error(problem)
    if args.baseline is not None:
        from pedrl.bench.e2e import baseline_problem

        if "e2e" not in sections:
            parser.error(f"--baseline is invalid with --only={args.only!r}: it measures the e2e section")
        if (problem := baseline_problem(args.baseline)) is not None:
            parser.error(problem)
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        parser.error(f"--device={args.device!r} is invalid here: no CUDA GPU is available")
    return args, rooms, sections


def _rooms(parser: argparse.ArgumentParser, text: str | None) -> list[int] | None:
    """``--rooms`` as a list of room counts (None when not given); one line for a bad list."""
    if not text:
        return None
    try:
        rooms = [int(value) for value in text.split(",")]
    except ValueError:
        rooms = []
    if not rooms or min(rooms) < 1:
        parser.error(f"--rooms={text!r} is invalid: must be comma-separated integers >= 1, e.g. 1,4,16")
    return rooms


def main(argv: list[str] | None = None) -> dict:
    args, rooms, sections = _arguments(argv)
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
        from pedrl.bench.e2e import run as run_e2e

        print("end to end ...", flush=True)
        report.update(
            run_e2e(
                quick=args.quick,
                device=args.device,
                rooms=rooms,
                trials=args.trials,
                contention=args.contention,
                baseline=args.baseline,
            )
        )
    if "factored" in sections:
        from pedrl.bench.factored import run as run_factored

        print("factored table ...", flush=True)
        report.update(run_factored(quick=args.quick, trials=args.trials))
    if "dqn" in sections:
        from pedrl.bench.dqn import run as run_dqn

        print("neural learner ...", flush=True)
        report.update(run_dqn(quick=args.quick, trials=args.trials))
    if "eval" in sections:
        from pedrl.bench.evaluation import run as run_eval

        print("evaluation ...", flush=True)
        report.update(run_eval(quick=args.quick, device=args.device))
    if "literal" in sections:
        from pedrl.bench.literal import run as run_literal

        print("literal encoding ...", flush=True)
        report.update(run_literal(quick=args.quick))
    if "walk" in sections:
        from pedrl.bench.walk import run as run_walk

        print("walking layer against JuPedSim ...", flush=True)
        report.update(run_walk(quick=args.quick, sizes=args.agents, sim_time=args.sim_time, docs=args.write_docs))
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

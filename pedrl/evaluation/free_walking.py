"""The free-walking probe of learned policies (:mod:`pedrl.trial.walking`): how a walker walks alone.

``python -m pedrl.evaluation.free_walking CHECKPOINT [CHECKPOINT ...] [--places P] [--lateral L] [--seed S]`` loads
each file (a training checkpoint or an exported policy of any learner: tables, factored tables, networks), places
one walker alone in RiMEA 1's free 40 m x 2 m corridor (3 places across it, 6 start headings) and at ``P`` random
places of the policy's own room, lets it act at ``epsilon=0`` with every learning process, and prints one row per
file: the share of its decisions at top speed within one turn step of the goal bearing (overall, in the corridor, in
its room), the mean heading offset, the mean speed over v0, the decisions to walk the corridor beside the greedy
walker's, and the verdict (:meth:`pedrl.trial.walking.FreeWalking.passed`).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Any, Final

from pedrl.sim import RoomParams
from pedrl.trial.walking import MAX_DECISION_RATIO, MIN_STRAIGHT, FreeWalking, WalkingSettings, probe_learned


def probe_loaded(policy: Any, settings: WalkingSettings | None = None) -> FreeWalking:
    """The free-walking figures of a loaded policy (:func:`pedrl.load_policy`, any learner) at ``epsilon=0``, in the
    corridor with its room's settings and in its own room, every learning process acting."""
    from pedrl.configs import room_keywords
    from pedrl.policy_files import room_factory, room_settings

    params = RoomParams.from_settings(room_keywords(room_settings(policy)))
    return probe_learned(policy, params, home=room_factory(policy), settings=settings)


PROGRAM: Final = "python -m pedrl.evaluation.free_walking"


def _parser() -> argparse.ArgumentParser:
    from pedrl.common.commands import OneLineParser, integer_arg

    parser = OneLineParser(prog=PROGRAM, description="How a learned walker walks alone in a free corridor and room.")
    parser.add_argument("checkpoints", nargs="+", help="training checkpoints or exported policies (.safetensors)")
    parser.add_argument("--places", type=integer_arg(0, 10_000), default=8, help="random placements in its own room")
    parser.add_argument("--lateral", type=integer_arg(1, 100), default=3, help="start places across the corridor")
    parser.add_argument("--seed", type=integer_arg(0, 2**31 - 1), default=0, help="placements and random draws")
    return parser


def row(name: str, probe: FreeWalking) -> str:
    """One markdown row of the command's table."""
    room = f"{probe.room.straight:.0%}" if probe.room is not None else "-"
    corridor = probe.corridor
    decisions = (
        f"{corridor.decisions:.1f}"
        if corridor.arrived == 1.0
        else f"{corridor.decisions:.1f} ({corridor.arrived:.0%} out)"
    )
    return (
        f"| {name} | {probe.straight:.0%} | {corridor.straight:.0%} | {room} | {probe.heading_offset:.1f} | "
        f"{probe.speed_ratio:.2f} | {decisions} | {probe.greedy_corridor.decisions:.1f} | "
        f"{'pass' if probe.passed() else 'FAIL'} |"
    )


HEADER: Final = (
    "| checkpoint | straight at top speed | in the corridor | in its room | heading offset (deg) | speed / v0 "
    "| decisions for the corridor | greedy walker's | verdict |\n|---|---|---|---|---|---|---|---|---|"
)


def main(argv: Sequence[str] | None = None) -> int:
    from pedrl.common.commands import fail
    from pedrl.policy_files import load_policy

    args = _parser().parse_args(argv)
    try:  # every argument and every file checked before the first walk
        settings = WalkingSettings(places=args.places, lateral=args.lateral, seed=args.seed)
        policies = [load_policy(path) for path in args.checkpoints]
    except (ValueError, TypeError) as err:
        fail(PROGRAM, str(err))
    print(HEADER)
    for path, policy in zip(args.checkpoints, policies, strict=True):
        print(row(path, probe_loaded(policy, settings)), flush=True)
    print(
        f"pass: at least {MIN_STRAIGHT:.0%} of the decisions straight at top speed (within one turn step of the goal "
        f"bearing) and every corridor walker out within {MAX_DECISION_RATIO:.3f} times the greedy walker's decisions"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())

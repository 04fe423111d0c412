"""How finely a learned quantizer resolves the bearing of the door: the prototypes an agent passes through as it
turns on the spot.

A Q table can only steer an agent towards the door if turning changes the agent's state id: an agent whose every
heading falls on one prototype has one row of values for all of them, and no action can be better for one heading
than for another. :func:`heading_resolution` places an agent at ``positions`` random points of the policy's room
(alone, or among ``agents - 1`` others standing still), turns its heading through ``headings`` evenly spaced values of
a full circle at a fixed speed, and counts the distinct prototypes its states fall on, for every learning process.
Only the own heading feature (the angle of the velocity to the reference line) and the neighbours' relative speeds
change along a turn, so the count is the quantizer's resolution of the bearing, in prototypes per turn.

Random void fillings (``void_features="random"``) are drawn once per position and kept over the turn, as
``void_draws="trial"`` keeps them over a trial.

``python -m pedrl.evaluation.resolution CHECKPOINT [CHECKPOINT ...] [--agents N] [--positions P] [--headings H]
[--speed S] [--seed S]`` prints one row per file and agent count.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch

from pedrl.common.checks import MAX_SEED, check_integer, check_number
from pedrl.policy_files import load_policy, room_factory
from pedrl.rl.neural import NeuralPolicy
from pedrl.rl.policy import TabularPolicy
from pedrl.sim.sensing import observe
from pedrl.vq.encoder import StateEncoder

MAX_AGENTS = 1000
"""The most bodies in a resolution room (the room itself may hold fewer: its density check)."""


@dataclass(frozen=True)
class Resolution:
    """Prototypes passed through in one full turn.

    Attributes:
        distinct: ``(P, positions)`` int64, the distinct state ids of each process's turn at each position.
        changes: ``(P, positions)`` int64, the times the id changes between neighbouring headings round the circle.
        num_prototypes: K, the prototypes of a process.
    """

    distinct: torch.Tensor
    changes: torch.Tensor
    num_prototypes: int

    @property
    def mean(self) -> float:
        """Mean distinct prototypes per turn, over processes and positions."""
        return float(self.distinct.double().mean())

    @property
    def std(self) -> float:
        """Their standard deviation (population)."""
        return float(self.distinct.double().std(correction=0))

    @property
    def degrees_per_prototype(self) -> float:
        """360 degrees over the mean distinct prototypes: the coarseness of the bearing."""
        return 360.0 / self.mean


def turn_ids(
    encoder: StateEncoder,
    room,
    *,
    headings: int,
    speed: float,
    seed: int,
    processes: int = 1,
) -> torch.Tensor:
    """State ids ``(P, H, R)`` of agent 0 of each of ``room``'s ``R`` rooms (placed at random from ``seed``) turned to
    ``H`` evenly spaced headings at ``speed`` (m/s), the others standing still, for each of ``processes`` learning
    processes of ``encoder``."""
    room.reset(seed=seed)
    state = room.state
    replicas, agents = room.num_replicas, room.num_agents
    device = state.positions.device
    speeds = torch.zeros(replicas, agents, device=device)
    speeds[:, 0] = speed
    observers = torch.zeros(replicas, agents, dtype=torch.bool, device=device)
    observers[:, 0] = True
    sensed = torch.ones_like(observers)
    generator = torch.Generator(device=device).manual_seed(seed)
    prepared, sensed_counts = [], []
    for index in range(headings):
        angle = -math.pi + 2.0 * math.pi * index / headings
        heading = state.headings.clone()
        heading[:, 0] = angle
        velocities = torch.stack((speeds * torch.cos(heading), speeds * torch.sin(heading)), dim=-1)
        obs = observe(
            positions=state.positions,
            velocities=velocities,
            headings=heading,
            speeds=speeds,
            observers=observers,
            sensed=sensed,
            geometry=room.geometry,
            goals=room.targets(),
            num_neighbours=room.params.num_neighbours,
            num_walls=room.params.num_walls,
        )
        num_sensed = obs.num_sensed[:, 0]
        # decision 0 draws the random void fillings once per position; the later headings keep them
        prepared.append(encoder.prepare(obs.features[:, 0], num_sensed, index, generator))
        sensed_counts.append(num_sensed)
    rows = torch.cat(prepared)  # (H * R, F), heading-major
    return process_ids(encoder, rows, torch.cat(sensed_counts), processes).view(processes, headings, replicas)


def process_ids(
    encoder: StateEncoder, prepared: torch.Tensor, num_sensed: torch.Tensor, processes: int
) -> torch.Tensor:
    """State ids ``(P, B)`` of prepared rows ``(B, F)`` with ``num_sensed (B,)`` neighbours, as each of ``encoder``'s
    first ``processes`` learning processes encodes them. A factored table's states are sets of ids: each distinct set
    gets one number (the measures count distinct states and their changes)."""
    ids = torch.stack(
        [
            encoder.encode_prepared(prepared, num_sensed, torch.full_like(num_sensed, process))
            for process in range(processes)
        ]
    )
    if ids.ndim == 3:
        _, inverse = torch.unique(ids.flatten(0, 1), dim=0, return_inverse=True)
        ids = inverse.view(ids.shape[:2])
    return ids


def tables_only(policy: Any) -> TabularPolicy:
    """``policy``, a :class:`~pedrl.rl.TabularPolicy`; one line otherwise: a ``ValueError`` for a network of
    ``algo=dqn`` (these tools count the states of a quantizer, and a network has none), a ``TypeError`` for anything
    else (a trainer, a path)."""
    if isinstance(policy, NeuralPolicy):
        source = policy.metadata.get("source", "the policy")
        raise ValueError(
            f"{source} is a network (algo=dqn): this tool counts the states of a quantizer, which a network has none "
            "of; judge a network by pedrl-eval and pedrl-validate"
        )
    if not isinstance(policy, TabularPolicy):
        raise TypeError(f"policy is a {type(policy).__name__}: must be a TabularPolicy, as pedrl.load_policy returns")
    return policy


def policy_room(policy: TabularPolicy, *, num_replicas: int, num_agents: int):
    """A room of ``policy``'s training config (:func:`pedrl.room_factory`) on its device; a one-line ``TypeError`` for
    a ``policy`` that is not a :class:`~pedrl.rl.TabularPolicy` (a trainer, a path), a ``ValueError`` for a crowd the
    room refuses (its density, its memory)."""
    tables_only(policy)
    return room_factory(policy)(num_replicas=num_replicas, num_agents=num_agents, device=policy.device)


def heading_resolution(
    policy: TabularPolicy,
    *,
    agents: int = 1,
    positions: int = 25,
    headings: int = 360,
    speed_ratio: float = 0.5,
    seed: int = 0,
) -> Resolution:
    """The prototypes ``policy``'s quantizer gives an agent turning through a full circle (module docstring).

    Args:
        policy: a loaded policy (:func:`pedrl.load_policy`); its training config rebuilds the room.
        agents: bodies in the room, 1 for a lone agent; the others stand still where they were placed.
        positions: random placements (each its own room), from ``seed``.
        headings: evenly spaced headings of the turn.
        speed_ratio: the turning agent's speed, a fraction of the room's top speed.
        seed: placements and random void fillings.

    Raises:
        TypeError: one line, for a ``policy`` that is not a TabularPolicy.
        ValueError: one line, for a bad argument (before any compute).
    """
    check_integer("agents", agents, minimum=1, maximum=MAX_AGENTS)
    check_integer("positions", positions, minimum=1, maximum=10_000)
    check_integer("headings", headings, minimum=2, maximum=100_000)
    check_number("speed_ratio", speed_ratio, low=0.0, high=1.0)
    check_integer("seed", seed, minimum=0, maximum=MAX_SEED)
    room = policy_room(policy, num_replicas=positions, num_agents=agents)
    ids = turn_ids(
        policy.encoder,
        room,
        headings=headings,
        speed=speed_ratio * room.params.max_speed,
        seed=seed,
        processes=policy.num_processes,
    )
    return Resolution(
        distinct=distinct_counts(ids),
        changes=(ids != ids.roll(1, dims=1)).sum(1),
        num_prototypes=policy.encoder.num_states,
    )


def distinct_counts(ids: torch.Tensor) -> torch.Tensor:
    """Distinct values along dim 1 of ``ids (P, H, R)``: ``(P, R)``."""
    ordered = ids.sort(dim=1).values
    return 1 + (ordered[:, 1:] != ordered[:, :-1]).sum(1)


PROGRAM = "python -m pedrl.evaluation.resolution"


def _parser() -> argparse.ArgumentParser:
    from pedrl.common.commands import OneLineParser, integer_arg, number_arg

    parser = OneLineParser(
        prog=PROGRAM,
        description="Prototypes a learned quantizer gives an agent turning on the spot (the bearing's resolution).",
    )
    parser.add_argument("checkpoints", nargs="+", help="training checkpoints or exported policies (.safetensors)")
    parser.add_argument(
        "--agents", type=integer_arg(1, MAX_AGENTS), nargs="+", default=[1], help="bodies in the room (1: alone)"
    )
    parser.add_argument("--positions", type=integer_arg(1, 10_000), default=25, help="random placements")
    parser.add_argument("--headings", type=integer_arg(2, 100_000), default=360, help="headings of the turn")
    parser.add_argument(
        "--speed", type=number_arg(0.0, 1.0), default=0.5, help="the turning agent's speed, fraction of top speed"
    )
    parser.add_argument("--seed", type=integer_arg(0, MAX_SEED), default=0, help="placements and void fillings")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    from pedrl.common.commands import fail

    args = _parser().parse_args(argv)
    try:  # every argument and every room checked before the first turn
        policies = [tables_only(load_policy(path)) for path in args.checkpoints]
        for policy in policies:
            for agents in args.agents:  # the room's own checks: the bodies fit, the memory suffices
                policy_room(policy, num_replicas=args.positions, num_agents=agents)
    except ValueError as err:
        fail(PROGRAM, str(err))
    print("| checkpoint | agents | K | prototypes per turn | degrees per prototype | changes per turn |")
    print("|---|---|---|---|---|---|")
    for path, policy in zip(args.checkpoints, policies, strict=True):
        for agents in args.agents:
            result = heading_resolution(
                policy,
                agents=agents,
                positions=args.positions,
                headings=args.headings,
                speed_ratio=args.speed,
                seed=args.seed,
            )
            changes = float(result.changes.double().mean())
            print(
                f"| {path} | {agents} | {result.num_prototypes} | {result.mean:.1f} ± {result.std:.1f} "
                f"| {result.degrees_per_prototype:.1f} | {changes:.1f} |"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""What a learned quantizer sees of an agent's neighbours: the prototypes its state passes through as a neighbour moves.

A Q table can only yield, sidestep or keep to a lane if a body in the agent's way changes the agent's state id. This
module places an agent at ``places`` random points of the policy's room, walking towards its goal (the door or its
waypoint) at each of ``speed_ratios`` of its top speed, and moves one neighbour (or a crowd) round it, everything else
held fixed. For each scene it counts the distinct prototypes the agent's state falls on:

- ``circling``: one neighbour standing on a circle of ``circle_radius`` (1 m) round the agent, at ``samples`` evenly
  spaced bearings;
- ``head_on``: one neighbour straight ahead, walking towards the agent at the agent's own speed, at ``samples``
  distances from ``approach_from`` (5 m) down to ``approach_to`` (0.45 m, just over two body radii of 0.2 m);
- ``receding``: the same places, the neighbour walking away at the agent's speed;
- ``crowds``: ``crowds`` random crowds of ``crowd_size`` (7) neighbours standing uniformly within ``crowd_radius``
  (3 m), at least ``approach_to`` from the agent;
- ``turning``, the control: the agent alone, its own heading turned through a full circle (``samples`` headings):
  the resolution of the door's bearing (:mod:`pedrl.evaluation.resolution`).

A table that sees its neighbours passes through at least as many prototypes when a neighbour circles it or walks at it
as when it turns on the spot. A quantizer whose prototypes ignore the neighbour features gives 1 for every neighbour
measure, whatever its resolution of the bearing.

``python -m pedrl.evaluation.neighbours CHECKPOINT [CHECKPOINT ...] [--places P] [--speeds S ...] [--samples H]
[--crowds C] [--crowd-size N] [--seed S]`` prints one row per file and speed.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import torch

from pedrl.common.checks import check_integer, check_number
from pedrl.evaluation.resolution import distinct_counts, policy_room, process_ids, tables_only
from pedrl.policy_files import load_policy
from pedrl.rl.policy import TabularPolicy
from pedrl.sim.geometry import X, Y
from pedrl.sim.sensing import observe
from pedrl.vq.encoder import StateEncoder

MEASURES: Final = ("turning", "circling", "head_on", "receding", "crowds")
"""The measures of :class:`NeighbourSight`, the control first."""


@dataclass(frozen=True)
class Scenes:
    """Where the measures are taken: the observing agent of every place and speed.

    Attributes:
        positions: ``(S, 2)`` the agent's position (m), one row per scene (place-major, then speed).
        headings: ``(S,)`` its heading (rad): the bearing of its goal.
        speeds: ``(S,)`` its speed (m/s).
        goals: ``(S, 2)`` its goal (m), the other end of its reference line.
    """

    positions: torch.Tensor
    headings: torch.Tensor
    speeds: torch.Tensor
    goals: torch.Tensor


@dataclass(frozen=True)
class NeighbourSight:
    """Distinct prototypes per scene for each measure (module docstring).

    Attributes:
        counts: measure name -> ``(P, S)`` int64, the distinct state ids of each process in each scene.
        speed_ratios: the agent's speeds, fractions of the top speed; scene ``s`` walks at
            ``speed_ratios[s % len(speed_ratios)]``.
        num_prototypes: K, the prototypes of a process.
    """

    counts: dict[str, torch.Tensor]
    speed_ratios: tuple[float, ...]
    num_prototypes: int

    def mean(self, measure: str, speed_ratio: float | None = None) -> float:
        """Mean distinct prototypes of ``measure`` over processes and places (and speeds, when None)."""
        return float(self._select(measure, speed_ratio).double().mean())

    def std(self, measure: str, speed_ratio: float | None = None) -> float:
        """Their standard deviation (population)."""
        return float(self._select(measure, speed_ratio).double().std(correction=0))

    def sees_neighbours(self, speed_ratio: float | None = None) -> bool:
        """Whether a circling and a head-on neighbour each pass through at least as many prototypes, on the mean, as
        a full turn of the agent's own heading (the target of a table that sees its neighbours)."""
        control = self.mean("turning", speed_ratio)
        return self.mean("circling", speed_ratio) >= control and self.mean("head_on", speed_ratio) >= control

    def _select(self, measure: str, speed_ratio: float | None) -> torch.Tensor:
        counts = self.counts[measure]
        if speed_ratio is None:
            return counts
        index = self.speed_ratios.index(speed_ratio)
        return counts[:, index :: len(self.speed_ratios)]


def scenes_of(room, *, speed_ratios: Sequence[float], seed: int) -> Scenes:
    """Agent 0 of each of ``room``'s replicas, placed at random from ``seed``, heading for its goal at each speed."""
    room.reset(seed=seed)
    positions, goals = room.state.positions[:, 0], room.targets()[:, 0]
    bearings = torch.atan2(goals[:, Y] - positions[:, Y], goals[:, X] - positions[:, X])
    ratios = torch.tensor(speed_ratios, dtype=positions.dtype, device=positions.device)
    count = len(speed_ratios)
    return Scenes(
        positions=positions.repeat_interleave(count, 0),
        headings=bearings.repeat_interleave(count, 0),
        speeds=(ratios * room.params.max_speed).repeat(positions.shape[0]),
        goals=goals.repeat_interleave(count, 0),
    )


def sight_ids(
    encoder: StateEncoder,
    room,
    scenes: Scenes,
    offsets: torch.Tensor,
    velocities: torch.Tensor,
    *,
    own_headings: torch.Tensor | None = None,
    alone: bool = False,
    generator: torch.Generator,
    processes: int = 1,
) -> torch.Tensor:
    """State ids ``(P, S, C)`` of each scene's agent with ``C`` configurations of ``M`` neighbours round it.

    Args:
        encoder: the policy's state encoder.
        room: a room of the policy's settings (its geometry, sensing and speeds).
        scenes: ``S`` scenes (:func:`scenes_of`).
        offsets: ``(S, C, M, 2)`` each neighbour's position relative to the agent (m), in the agent's frame: x along
            its heading, y to its left.
        velocities: ``(S, C, M, 2)`` each neighbour's velocity (m/s) in the same frame.
        own_headings: ``(S, C)`` the agent's heading in each configuration (None: the scene's).
        alone: the neighbours are not sensed (the agent is alone).
        generator: random void fillings, drawn once per scene and kept over its configurations.
        processes: learning processes of ``encoder`` to encode with.
    """
    num_scenes, configurations, members, _ = offsets.shape
    headings = scenes.headings[:, None].expand(num_scenes, configurations) if own_headings is None else own_headings
    cos, sin = torch.cos(headings)[..., None], torch.sin(headings)[..., None]

    def to_world(vectors: torch.Tensor) -> torch.Tensor:
        x, y = vectors[..., X], vectors[..., Y]
        return torch.stack((cos * x - sin * y, sin * x + cos * y), dim=-1)

    speeds = scenes.speeds[:, None].expand(num_scenes, configurations)
    own_velocity = torch.stack((speeds * torch.cos(headings), speeds * torch.sin(headings)), dim=-1)
    positions = torch.cat((scenes.positions[:, None, None].expand(-1, configurations, 1, 2),
                           scenes.positions[:, None, None] + to_world(offsets)), dim=2)  # fmt: skip
    velocities = torch.cat((own_velocity[:, :, None], to_world(velocities)), dim=2)
    batch = num_scenes * configurations
    agents = members + 1
    positions, velocities = positions.reshape(batch, agents, 2), velocities.reshape(batch, agents, 2)
    world_headings = torch.atan2(velocities[..., Y], velocities[..., X])
    world_headings[:, 0] = headings.reshape(batch)
    observers = torch.zeros(batch, agents, dtype=torch.bool, device=positions.device)
    observers[:, 0] = True
    obs = observe(
        positions=positions,
        velocities=velocities,
        headings=world_headings,
        speeds=velocities.norm(dim=-1),
        observers=observers,
        sensed=observers if alone else torch.ones_like(observers),
        geometry=room.geometry,
        goals=scenes.goals[:, None, None].expand(num_scenes, configurations, agents, 2).reshape(batch, agents, 2),
        num_neighbours=room.params.num_neighbours,
        num_walls=room.params.num_walls,
    )
    features = obs.features[:, 0].view(num_scenes, configurations, -1)
    sensed_counts = obs.num_sensed[:, 0].view(num_scenes, configurations)
    # configuration by configuration, so that random void fillings are drawn once per scene (at the first) and kept
    prepared = torch.stack(
        [encoder.prepare(features[:, c], sensed_counts[:, c], c, generator) for c in range(configurations)], dim=1
    ).view(batch, -1)
    return process_ids(encoder, prepared, sensed_counts.reshape(batch), processes).view(
        processes, num_scenes, configurations
    )


@dataclass(frozen=True)
class SightSettings:
    """The scenes and samples of the measures (module docstring), checked when built: a bad value ends in a one-line
    ``ValueError`` before any compute.

    Attributes:
        places: random placements of the agent, from ``seed``.
        speed_ratios: the agent's speeds, fractions of the room's top speed, in (0, 1].
        samples: bearings of the circle, distances of the approach and headings of the control's turn.
        circle_radius: the circling neighbour's distance (m).
        approach_from: the head-on and receding neighbour's farthest distance (m).
        approach_to: their nearest distance (m), and the crowds' nearest.
        crowds: random crowds per scene.
        crowd_size: neighbours in a crowd.
        crowd_radius: the crowds' farthest distance (m).
        seed: placements, crowds and random void fillings.
    """

    places: int = 25
    speed_ratios: tuple[float, ...] = (0.5, 1.0)
    samples: int = 72
    circle_radius: float = 1.0
    approach_from: float = 5.0
    approach_to: float = 0.45
    crowds: int = 400
    crowd_size: int = 7
    crowd_radius: float = 3.0
    seed: int = 0

    def __post_init__(self) -> None:
        check_integer("places", self.places, minimum=1, maximum=10_000)
        if len(self.speed_ratios) == 0:
            raise ValueError("speed_ratios=[] is invalid: must name at least one fraction of the top speed in (0, 1]")
        for ratio in self.speed_ratios:
            check_number("speed_ratio", ratio, low=0.0, high=1.0)
            if ratio == 0:
                raise ValueError(
                    "speed_ratio=0.0 is invalid: must be in (0, 1] (an agent standing still has no heading)"
                )
        object.__setattr__(self, "speed_ratios", tuple(self.speed_ratios))
        check_integer("samples", self.samples, minimum=2, maximum=100_000)
        check_integer("crowds", self.crowds, minimum=1, maximum=100_000)
        check_integer("crowd_size", self.crowd_size, minimum=1, maximum=100)
        check_integer("seed", self.seed, minimum=0, maximum=2**31 - 1)
        sampled = max(self.samples, self.crowds)
        if self.places * len(self.speed_ratios) * sampled * (self.crowd_size + 1) > 50_000_000:
            raise ValueError(
                f"places={self.places} x {len(self.speed_ratios)} speeds x {sampled} samples or crowds x "
                f"{self.crowd_size + 1} bodies is too large: must be at most 50,000,000 bodies sensed at once"
            )
        check_number("circle_radius", self.circle_radius, low=0.0, high=100.0)
        check_number("approach_to", self.approach_to, low=0.0, high=100.0)
        check_number("approach_from", self.approach_from, low=self.approach_to, high=100.0)
        check_number("crowd_radius", self.crowd_radius, low=self.approach_to, high=100.0)


def neighbour_sight(policy: TabularPolicy, settings: SightSettings | None = None) -> NeighbourSight:
    """The prototypes ``policy``'s quantizer gives an agent as its neighbours move round it (module docstring), with
    ``settings`` (None: the defaults of :class:`SightSettings`); ``policy`` is a loaded policy
    (:func:`pedrl.load_policy`), whose training config rebuilds the room.

    Raises:
        TypeError: one line, for a ``policy`` that is not a TabularPolicy.
        ValueError: one line, for a factored table (:func:`plain_tables_only`).
    """
    plain_tables_only(policy)
    settings = settings if settings is not None else SightSettings()
    room = policy_room(policy, num_replicas=settings.places, num_agents=1)
    scenes = scenes_of(room, speed_ratios=settings.speed_ratios, seed=settings.seed)
    return sight_of(policy.encoder, room, scenes, settings, processes=policy.num_processes)


def plain_tables_only(policy: TabularPolicy) -> TabularPolicy:
    """``policy``, a table over one quantizer of the whole state; a one-line ``ValueError`` for a factored table
    (``vq.factors``), whose state is a set of ids (own, one per neighbour slot, one per wall): this tool counts the one
    id a plain quantizer gives a state, and summing the factors' K would read a set as one id."""
    tables_only(policy)
    if policy.encoder.num_slots is not None:
        source = policy.metadata.get("source", "the policy")
        raise ValueError(
            f"{source} is a factored table (vq.factors): this tool counts the one prototype a plain quantizer gives "
            "a state, and a factored table gives each sensed neighbour an id of its own neighbour factor (it sees "
            "every neighbour by construction); judge it by pedrl-eval and pedrl-validate"
        )
    return policy


def sight_of(
    encoder: StateEncoder, room, scenes: Scenes, settings: SightSettings, *, processes: int = 1
) -> NeighbourSight:
    """Every measure of :func:`neighbour_sight` for an ``encoder`` and given ``scenes`` (``settings.places`` unused)."""
    device = scenes.positions.device
    num_scenes = scenes.positions.shape[0]
    samples = settings.samples
    generator = torch.Generator(device=device).manual_seed(settings.seed)

    def ids(offsets, velocities, **kwargs) -> torch.Tensor:
        return sight_ids(encoder, room, scenes, offsets, velocities, generator=generator, processes=processes, **kwargs)

    zeros = torch.zeros(num_scenes, samples, 1, 2, device=device)
    speeds = scenes.speeds[:, None]
    # the control: the agent alone, its heading turned
    turn = scenes.headings[:, None] + torch.arange(samples, device=device) * (2.0 * math.pi / samples)
    bearings = torch.arange(samples, device=device) * (2.0 * math.pi / samples)
    circle = torch.stack((torch.cos(bearings), torch.sin(bearings)), dim=-1) * settings.circle_radius
    distances = torch.linspace(settings.approach_from, settings.approach_to, samples, device=device)
    ahead = torch.zeros(num_scenes, samples, 1, 2, device=device)
    ahead[..., X] = distances[None, :, None]
    walking = torch.zeros(num_scenes, samples, 1, 2, device=device)
    walking[..., X] = speeds[..., None]
    radii = (settings.approach_to, settings.crowd_radius)
    counts = {
        "turning": ids(zeros, zeros, own_headings=turn, alone=True),
        "circling": ids(circle[None, :, None].expand(num_scenes, samples, 1, 2), zeros),
        "head_on": ids(ahead, -walking),
        "receding": ids(ahead, walking),
        "crowds": crowd_ids(ids, num_scenes, settings.crowds, settings.crowd_size, radii, generator, device),
    }
    return NeighbourSight(
        counts={name: distinct_counts(value.transpose(1, 2)) for name, value in counts.items()},
        speed_ratios=settings.speed_ratios,
        num_prototypes=encoder.num_states,
    )


def crowd_ids(ids, num_scenes, crowds, crowd_size, radii, generator, device) -> torch.Tensor:
    """State ids of ``crowds`` random standing crowds per scene, uniform over the annulus ``radii`` (m)."""
    shape = (num_scenes, crowds, crowd_size)
    inner, outer = radii
    radius = torch.sqrt(inner**2 + (outer**2 - inner**2) * torch.rand(shape, generator=generator, device=device))
    angle = 2.0 * math.pi * torch.rand(shape, generator=generator, device=device)
    offsets = torch.stack((radius * torch.cos(angle), radius * torch.sin(angle)), dim=-1)
    return ids(offsets, torch.zeros_like(offsets))


PROGRAM: Final = "python -m pedrl.evaluation.neighbours"


def _parser() -> argparse.ArgumentParser:
    from pedrl.common.commands import OneLineParser, integer_arg, number_arg

    parser = OneLineParser(
        prog=PROGRAM, description="Prototypes a learned quantizer gives an agent as its neighbours move round it."
    )
    parser.add_argument("checkpoints", nargs="+", help="training checkpoints or exported policies (.safetensors)")
    parser.add_argument("--places", type=integer_arg(1, 10_000), default=25, help="random placements of the agent")
    parser.add_argument(
        "--speeds", type=number_arg(0.0, 1.0, low_open=True), nargs="+", default=[0.5, 1.0],
        help="its speeds, fractions of the top speed",
    )  # fmt: skip
    parser.add_argument("--samples", type=integer_arg(2, 100_000), default=72, help="bearings, distances, headings")
    parser.add_argument("--crowds", type=integer_arg(1, 100_000), default=400, help="random crowds per place, speed")
    parser.add_argument("--crowd-size", type=integer_arg(1, 100), default=7, help="neighbours in a crowd")
    parser.add_argument("--seed", type=integer_arg(0, 2**31 - 1), default=0, help="placements, crowds, fillings")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    from pedrl.common.commands import fail

    args = _parser().parse_args(argv)
    try:  # every argument and every file checked before the first measure
        settings = SightSettings(
            places=args.places,
            speed_ratios=tuple(args.speeds),
            samples=args.samples,
            crowds=args.crowds,
            crowd_size=args.crowd_size,
            seed=args.seed,
        )
        policies = [plain_tables_only(tables_only(load_policy(path))) for path in args.checkpoints]
    except (ValueError, TypeError) as err:
        fail(PROGRAM, str(err))
    print("| checkpoint | speed | K | " + " | ".join(MEASURES) + " | sees neighbours |")
    print("|---|---|---|" + "---|" * len(MEASURES) + "---|")
    for path, policy in zip(args.checkpoints, policies, strict=True):
        sight = neighbour_sight(policy, settings)
        for ratio in sight.speed_ratios:
            cells = " | ".join(f"{sight.mean(m, ratio):.1f} ± {sight.std(m, ratio):.1f}" for m in MEASURES)
            verdict = "yes" if sight.sees_neighbours(ratio) else "no"
            print(f"| {path} | {ratio:g} | {sight.num_prototypes} | {cells} | {verdict} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The factored quantizer: one small quantizer per kind of thing an agent senses, shared by every slot of that kind.

A plain quantizer maps the whole 28-feature state to one prototype, so a table row is "this door bearing *and*
this neighbour at slot 3": what it learns about a neighbour at slot 3 is lost at slot 1, and a row is learned from
few visits. The factored quantizer splits the state into its factors (the deictic state of Table 1 is made of them):

- ``own``: the agent's speed, velocity angle and goal distance (3 features), one prototype per state;
- ``neighbour``: one quantizer over a neighbour's 3 features (relative speed, distance, angle), applied to each
  *sensed* neighbour slot (void slots read nothing);
- ``wall``: one quantizer over a wall's 2 features (distance, angle), applied to each wall slot.

A state's code is then a set of ``M = 1 + k + w`` ids, one per slot, in the id space ``[0, K_own + K_nb + K_wall)``
(own ids first, then the neighbour's, then the wall's), with ``-1`` for a slot that reads nothing. A Q table over
these ids holds ``Q_own``, ``Q_nb`` and ``Q_wall`` in one ``(K, U)`` block, and the value of a state is the sum of
its slots' rows (:func:`pedrl.rl.factored_values`): ``Q(s, a) = Q_own(k_own(s), a) + sum_i Q_nb(k_nb(n_i), a) +
sum_j Q_wall(k_wall(w_j), a)``. Angles are relative to the line to the goal, as are the actions of
``env.action_frame=goal``, so a neighbour's row can say "turn away from a neighbour ahead on the left" wherever the
agent stands.

Each factor's features are standardised and weighted by their own weights (:class:`FactorSpec`), so a factor can
resolve, say, a neighbour's distance more finely than its relative speed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from numbers import Real
from typing import Any, Final

import torch

from pedrl.common.checks import check_integer
from pedrl.sim.sensing import FEATURES_PER_NEIGHBOUR, FEATURES_PER_WALL, NUM_OWN_FEATURES
from pedrl.vq.quantizer import Quantizer

__all__ = ["FACTORS", "FACTOR_FEATURES", "FactorSpec", "FactoredQuantizer", "check_factor_slots", "factor_specs"]

FACTOR_FEATURES: Final = {
    "own": ("speed", "velocity_angle", "door_distance"),
    "neighbour": ("rel_speed", "distance", "angle"),
    "wall": ("distance", "angle"),
}
"""The features each factor reads, in the state's order (:mod:`pedrl.sim.sensing`)."""
FACTORS: Final = tuple(FACTOR_FEATURES)
"""The factors, in the order of their ids: own, neighbour, wall."""
SLOTS_KEY: Final = "slots"
"""The state-dict entry ``(2,)`` int64: the neighbour and wall slots ``(k, w)`` the quantizer reads."""


@dataclass(frozen=True)
class FactorSpec:
    """How one factor is quantized (an entry of ``vq.factors``).

    Attributes:
        name: ``own``, ``neighbour`` or ``wall`` (:data:`FACTORS`).
        num_prototypes: its K.
        weights: one positive weight per feature of the factor (:data:`FACTOR_FEATURES`), multiplying the
            standardised feature before k-means and encoding.
    """

    name: str
    num_prototypes: int
    weights: tuple[float, ...]

    @classmethod
    def from_config(cls, name: str, values: Any) -> FactorSpec:
        """The factor ``name`` of ``vq.factors`` (``{num_prototypes: K, weights: {feature: weight}}``), checked:
        one line naming the bad key or value."""
        if name not in FACTOR_FEATURES:
            raise ValueError(f"vq.factors.{name} is not a factor: allowed: {', '.join(FACTORS)}")
        if not isinstance(values, Mapping):
            raise ValueError(
                f"vq.factors.{name}={values!r} is invalid: must be a mapping with num_prototypes (and weights)"
            )
        unknown = sorted(set(values) - {"num_prototypes", "weights"})
        if unknown:
            raise ValueError(f"vq.factors.{name}.{unknown[0]} is unknown: allowed: num_prototypes, weights")
        if "num_prototypes" not in values:
            raise ValueError(f"vq.factors.{name}.num_prototypes is missing: the factor's K, an integer >= 1")
        size = check_integer(f"vq.factors.{name}.num_prototypes", values["num_prototypes"], minimum=1)
        features = FACTOR_FEATURES[name]
        given = values.get("weights") or {}
        if not isinstance(given, Mapping):
            raise ValueError(
                f"vq.factors.{name}.weights={given!r} is invalid: must map features ({', '.join(features)}) to weights"
            )
        for feature, weight in given.items():
            if feature not in features:
                raise ValueError(
                    f"vq.factors.{name}.weights.{feature} names no feature of the factor: allowed: "
                    f"{', '.join(features)}"
                )
            if isinstance(weight, bool) or not isinstance(weight, Real) or not math.isfinite(weight) or weight <= 0:
                raise ValueError(
                    f"vq.factors.{name}.weights.{feature}={weight!r} is invalid: must be a finite number > 0"
                )
        return cls(name, size, tuple(float(given.get(feature, 1.0)) for feature in features))


def factor_specs(values: Any) -> tuple[FactorSpec, ...] | None:
    """The factors of ``vq.factors`` (None: one plain quantizer over the whole state), checked before any compute.
    The own factor is required; the neighbour and wall factors may be left out (the table then reads no neighbour,
    or no wall)."""
    if values is None:
        return None
    if not isinstance(values, Mapping) or not values:
        raise ValueError(
            f"vq.factors={values!r} is invalid: must be null or a mapping of factors ({', '.join(FACTORS)})"
        )
    specs = {name: FactorSpec.from_config(name, entry) for name, entry in values.items()}
    if "own" not in specs:
        raise ValueError("vq.factors.own is missing: a factored table needs the agent's own factor")
    return tuple(specs[name] for name in FACTORS if name in specs)


def split_state(
    states: torch.Tensor, num_neighbours: int, num_walls: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(own (B, 3), neighbours (B, k, 3), walls (B, w, 2))`` of states ``(B, F)`` of ``k`` neighbour and ``w`` wall
    slots (the layout of :mod:`pedrl.sim.sensing`)."""
    first_wall = NUM_OWN_FEATURES + FEATURES_PER_NEIGHBOUR * num_neighbours
    batch = states.shape[0]  # named, not -1: a room of no neighbour or no wall slot has 0 features of that kind
    own = states[:, :NUM_OWN_FEATURES]
    neighbours = states[:, NUM_OWN_FEATURES:first_wall].reshape(batch, num_neighbours, FEATURES_PER_NEIGHBOUR)
    walls = states[:, first_wall : first_wall + FEATURES_PER_WALL * num_walls]
    return own, neighbours, walls.reshape(batch, num_walls, FEATURES_PER_WALL)


def check_factor_slots(specs: tuple[FactorSpec, ...] | None, *, num_neighbours: int, num_walls: int) -> None:
    """Refuse, before any compute, a neighbour or wall factor of ``specs`` in a room whose state has no slot of that
    kind (``env.num_neighbours=0``, ``env.num_walls=0``): it would have nothing to be fitted on. The table without
    that factor reads the room as it is (one line naming the factor, the setting, and both ways out)."""
    slots = {"neighbour": ("env.num_neighbours", num_neighbours), "wall": ("env.num_walls", num_walls)}
    for spec in specs or ():
        if spec.name in slots and slots[spec.name][1] == 0:
            key = slots[spec.name][0]
            raise ValueError(
                f"vq.factors.{spec.name} is invalid with {key}=0: the state has no {spec.name} slot for it to read: "
                f"leave the factor out (~vq.factors.{spec.name}) or raise {key}"
            )


class FactoredQuantizer:
    """Quantizers of the own state, of one neighbour (shared by every neighbour slot) and of one wall (shared by
    every wall slot); module docstring.

    Args:
        own: the quantizer of the 3 own features.
        neighbour: the quantizer of one neighbour's 3 features (None: neighbours are not read).
        wall: the quantizer of one wall's 2 features (None: walls are not read).
        num_neighbours: k, the neighbour slots of the state.
        num_walls: w, its wall slots.
    """

    def __init__(
        self,
        *,
        own: Quantizer,
        neighbour: Quantizer | None,
        wall: Quantizer | None,
        num_neighbours: int,
        num_walls: int,
    ) -> None:
        for name, part, width in (
            ("own", own, NUM_OWN_FEATURES),
            ("neighbour", neighbour, FEATURES_PER_NEIGHBOUR),
            ("wall", wall, FEATURES_PER_WALL),
        ):
            if part is not None and part.dim != width:
                raise ValueError(f"the {name} quantizer reads {part.dim} features: must read {width}")
        self.own, self.neighbour, self.wall = own, neighbour, wall
        self.num_neighbours = check_integer("num_neighbours", num_neighbours, minimum=0)
        self.num_walls = check_integer("num_walls", num_walls, minimum=0)

    # ------------------------------------------------------------------ structure
    @property
    def parts(self) -> dict[str, Quantizer]:
        """The factors' quantizers present, in id order."""
        found = {"own": self.own, "neighbour": self.neighbour, "wall": self.wall}
        return {name: part for name, part in found.items() if part is not None}

    @property
    def offsets(self) -> dict[str, int]:
        """The first id of each factor present."""
        offsets, first = {}, 0
        for name, part in self.parts.items():
            offsets[name] = first
            first += part.num_prototypes
        return offsets

    @property
    def num_prototypes(self) -> int:
        """K, the ids of every factor together (the rows of a table)."""
        return sum(part.num_prototypes for part in self.parts.values())

    @property
    def num_slots(self) -> int:
        """M, the ids of one state: 1 own, k neighbour slots (if read), w wall slots (if read)."""
        return (
            1
            + (self.num_neighbours if self.neighbour is not None else 0)
            + (self.num_walls if self.wall is not None else 0)
        )

    @property
    def device(self) -> torch.device:
        return self.own.device

    # ------------------------------------------------------------------ encoding
    def split(self, states: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """:func:`split_state` of prepared states ``(B, F)`` with this quantizer's slots."""
        return split_state(states, self.num_neighbours, self.num_walls)

    def encode(self, states: torch.Tensor, num_sensed: torch.Tensor) -> torch.Tensor:
        """Ids ``(B, M)`` of prepared states ``(B, F)`` with ``num_sensed (B,)`` neighbours: the own id, then one id
        per neighbour slot (-1 beyond the sensed ones), then one per wall slot."""
        own, neighbours, walls = self.split(states)
        offsets = self.offsets
        ids = [self.own.encode(own)[:, None]]
        if self.neighbour is not None:
            found = self.neighbour.encode(neighbours) + offsets["neighbour"]
            slot = torch.arange(self.num_neighbours, device=states.device)
            ids.append(torch.where(slot[None, :] < num_sensed[:, None], found, -1))
        if self.wall is not None:
            ids.append(self.wall.encode(walls) + offsets["wall"])
        return torch.cat(ids, 1)

    @classmethod
    def fit(
        cls,
        states: torch.Tensor,
        num_sensed: torch.Tensor,
        specs: tuple[FactorSpec, ...],
        *,
        num_neighbours: int,
        num_walls: int,
        max_states: int,
        generator: torch.Generator,
        **kmeans: Any,
    ) -> tuple[FactoredQuantizer, float]:
        """Fit each factor's quantizer on its slots of the prepared ``states (S, F)``: the own features of every
        state, the features of every sensed neighbour, those of every wall, each capped at ``max_states`` rows (a
        uniform subset). ``kmeans`` goes to :meth:`pedrl.vq.Quantizer.fit` (iterations, tolerance, init, ...).
        Returns the quantizer and the mean of the factors' final distortions (standardised units)."""
        own, neighbours, walls = split_state(states, num_neighbours, num_walls)
        sensed = torch.arange(num_neighbours, device=states.device)[None, :] < num_sensed[:, None]
        rows = {"own": own, "neighbour": neighbours[sensed], "wall": walls.reshape(-1, FEATURES_PER_WALL)}
        parts: dict[str, Quantizer | None] = {"neighbour": None, "wall": None}
        distortions = []
        for spec in specs:
            data = rows[spec.name]
            if data.shape[0] == 0:
                raise ValueError(
                    f"vq.factors.{spec.name}: the gathered states hold no {spec.name} to fit it on (no neighbour "
                    "was ever sensed: leave the factor out, or gather with more agents)"
                )
            if data.shape[0] > max_states:
                keep = torch.randperm(data.shape[0], generator=generator, device=data.device)[:max_states]
                data = data.index_select(0, keep)
            size = min(spec.num_prototypes, data.shape[0])
            weights = torch.tensor(spec.weights, dtype=torch.float32, device=data.device)
            parts[spec.name], result = Quantizer.fit(
                data.contiguous(), size, generator=generator, feature_weights=weights, **kmeans
            )
            distortions.append(float(result.distortion[-1]))
        quantizer = cls(num_neighbours=num_neighbours, num_walls=num_walls, **parts)
        return quantizer, sum(distortions) / len(distortions)

    def nearest_in(self, old: FactoredQuantizer) -> torch.Tensor:
        """``(K,)`` int64: for each id of this quantizer, the id in ``old`` of the prototype of the same factor nearest
        to it in raw units (-1 where ``old`` lacks the factor): IT-VQQL's value transfer between iterations."""
        found = []
        old_parts, old_offsets = old.parts, old.offsets
        for name, part in self.parts.items():
            ids = torch.arange(part.num_prototypes, device=part.device)
            if name in old_parts:
                found.append(old_parts[name].encode(part.decode(ids)) + old_offsets[name])
            else:
                found.append(torch.full_like(ids, -1))
        return torch.cat(found)

    # ------------------------------------------------------------------ files
    def state_dict(self) -> dict[str, torch.Tensor]:
        """``own.mean``, ``own.std``, ``own.prototypes``, the same for ``neighbour`` and ``wall`` when present, and
        ``slots`` ``(k, w)``."""
        tensors = {
            f"{name}.{key}": value for name, part in self.parts.items() for key, value in part.state_dict().items()
        }
        tensors[SLOTS_KEY] = torch.tensor([self.num_neighbours, self.num_walls], dtype=torch.int64)
        return tensors

    @staticmethod
    def holds(tensors: Mapping[str, torch.Tensor]) -> bool:
        """Whether ``tensors`` were written by :meth:`state_dict`."""
        return SLOTS_KEY in tensors and "own.prototypes" in tensors

    @classmethod
    def from_state_dict(cls, tensors: Mapping[str, torch.Tensor]) -> FactoredQuantizer:
        """Inverse of :meth:`state_dict`; one line for a tensor that belongs to no factor."""
        for name in tensors:
            if name != SLOTS_KEY and name.split(".", 1)[0] not in FACTOR_FEATURES:
                raise ValueError(f"tensor {name} belongs to no factor: allowed: {', '.join(FACTORS)}, {SLOTS_KEY}")
        slots = tensors[SLOTS_KEY]
        if slots.shape != (2,):
            raise ValueError(f"tensor {SLOTS_KEY} is {tuple(slots.shape)}: must be (2,), the neighbour and wall slots")

        def part(name: str) -> Quantizer | None:
            keys = ("mean", "std", "prototypes")
            if f"{name}.prototypes" not in tensors:
                return None
            return Quantizer.from_state_dict({key: tensors[f"{name}.{key}"] for key in keys})

        k, w = (int(value) for value in slots.tolist())
        own = part("own")
        if own is None:
            raise ValueError("tensor own.prototypes is missing: a factored quantizer has an own factor")
        return cls(own=own, neighbour=part("neighbour"), wall=part("wall"), num_neighbours=k, num_walls=w)

    def __repr__(self) -> str:
        sizes = ", ".join(f"{name}={part.num_prototypes}" for name, part in self.parts.items())
        return f"FactoredQuantizer({sizes}, slots={self.num_slots})"

"""Everything between a room's observation and a state id: void filling, the distance transform, the quantizer.

A :class:`StateEncoder` is what a learned table is indexed by. Training builds one per phase (the trainer fits the
quantizer, the encoder applies it); evaluation, validation and the PettingZoo adapter rebuild it from a checkpoint or
an exported policy file through :class:`pedrl.rl.TabularPolicy`, without a trainer.

The quantizer is one of three kinds, and :meth:`StateEncoder.encode_prepared` dispatches on it:

- :class:`~pedrl.vq.Quantizer`: one quantizer over the full state (VQQL, IT-VQQL, shared by every process);
- :class:`~pedrl.vq.ProcessQuantizers`: one part per learning process (``vq.per_process``), each part encoding the
  states of the agents its process drives;
- :class:`~pedrl.vq.UnionQuantizer`: IN-VQQL's union, a part per number of sensed neighbours, each reading its
  projection of the state;
- :class:`~pedrl.vq.FactoredQuantizer`: a quantizer per factor (own, neighbour, wall), whose state ids are sets of
  ``M`` ids (``(B, M)``, -1 for a slot that reads nothing) of a factored table (``vq.factors``).

The feature weights are applied inside the quantizer (its prototypes are fitted in weighted, standardised
units), so they travel with it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from typing import Any, Final, NamedTuple

import numpy as np
import torch

from pedrl.common.checks import check_choice, check_integer, check_number
from pedrl.sim.sensing import (
    MIN_VOID_DISTANCE,
    distance_indices,
    feature_indices,
    fill_void_neighbours,
    num_features,
    void_draws,
)
from pedrl.vq.factored import FactoredQuantizer
from pedrl.vq.quantizer import ProcessQuantizers, Quantizer, UnionQuantizer

VOID_FEATURES: Final = ("zero", "random")
"""Values of ``void_features``: empty neighbour slots left at 0, or filled with random valid values (section 5.1)."""
VOID_DRAWS: Final = ("trial", "decision")
"""Values of ``void_draws``: the random filling drawn once per agent and trial, or anew at every encode."""
DISTANCE_TRANSFORMS: Final = ("none", "log")
"""Values of ``distance_transform``: raw distances (the paper) or ``log(1 + d)``."""
AnyQuantizer = Quantizer | ProcessQuantizers | UnionQuantizer | FactoredQuantizer


class KernelEncoding(NamedTuple):
    """:class:`EncoderSettings` as :func:`pedrl.vq.encode_kernel.encode_agent` reads them
    (:meth:`EncoderSettings.kernel`)."""

    num_neighbours: int
    max_distance: np.float32
    """The range of random void fillings (m)."""
    max_speed: np.float32
    """The range of random void fillings (m/s)."""
    min_void_distance: np.float32
    """The nearest a random void filling lies when no neighbour is sensed (m)."""
    random_void: bool
    log_distances: bool


@dataclass(frozen=True)
class EncoderSettings:
    """How observations are prepared before they are quantized.

    Attributes:
        num_neighbours: k, neighbour slots of the state.
        num_walls: w, sensed walls.
        max_distance: the longest distance of the room the encoder was trained in (m): the range of random void
            fillings.
        max_speed: the agents' top speed (m/s) in that room: the range of random void fillings.
        void_features: ``"zero"`` or ``"random"`` (:data:`VOID_FEATURES`).
        void_draws: ``"trial"`` or ``"decision"`` (:data:`VOID_DRAWS`).
        distance_transform: ``"none"`` or ``"log"`` (:data:`DISTANCE_TRANSFORMS`).
    """

    num_neighbours: int
    num_walls: int
    max_distance: float
    max_speed: float
    void_features: str = "zero"
    void_draws: str = "trial"
    distance_transform: str = "none"

    def __post_init__(self) -> None:
        check_integer("num_neighbours", self.num_neighbours, minimum=0)
        check_integer("num_walls", self.num_walls, minimum=0)
        check_number("max_distance", self.max_distance, low=0.0, low_open=True)
        check_number("max_speed", self.max_speed, low=0.0, low_open=True)
        check_choice("void_features", self.void_features, VOID_FEATURES)
        check_choice("void_draws", self.void_draws, VOID_DRAWS)
        check_choice("distance_transform", self.distance_transform, DISTANCE_TRANSFORMS)

    def kernel(self) -> KernelEncoding:
        """These settings as the encoding kernel reads them (:class:`KernelEncoding`)."""
        return KernelEncoding(
            self.num_neighbours,
            np.float32(self.max_distance),
            np.float32(self.max_speed),
            np.float32(MIN_VOID_DISTANCE),
            self.void_features == "random",
            self.distance_transform == "log",
        )

    @classmethod
    def for_room(cls, room: Any, **choices: Any) -> EncoderSettings:
        """The settings of observations of ``room`` (a :class:`pedrl.sim.RoomEnv`: its neighbour slots, walls, longest
        distance and top speed) with ``choices`` (``void_features``, ``void_draws``, ``distance_transform``)."""
        params = room.params
        sizes = dict(num_neighbours=params.num_neighbours, num_walls=params.num_walls, max_speed=params.max_speed)
        return cls(**sizes, max_distance=room.max_distance, **choices)

    def spanning(self, rooms: Sequence[Any]) -> EncoderSettings:
        """These settings over ``rooms`` too (anything with a ``max_distance``, e.g. the rooms of a run trained
        across scenarios): random void fillings span the longest distance of them all."""
        return replace(self, max_distance=max([self.max_distance, *(room.max_distance for room in rooms)]))

    @property
    def num_features(self) -> int:
        """F, the features of an observation: ``3 + 3 k + 2 w``."""
        return num_features(self.num_neighbours, self.num_walls)

    def to_metadata(self) -> dict[str, Any]:
        """The settings as plain JSON values."""
        return asdict(self)

    @classmethod
    def from_metadata(cls, values: Mapping[str, Any]) -> EncoderSettings:
        """Settings from :meth:`to_metadata`'s mapping; an unknown or missing key is a one-line ``ValueError``."""
        if not isinstance(values, Mapping):
            raise ValueError(f"encoder settings {values!r} are invalid: must be a mapping")
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"encoder setting {unknown[0]!r} is unknown: allowed: {', '.join(sorted(known))}")
        try:
            return cls(**values)
        except TypeError:
            missing = sorted(known - set(values))
            raise ValueError(f"encoder settings lack {', '.join(missing)}") from None


class StateEncoder:
    """Maps observations to state ids: void slots filled, distances transformed, then quantized.

    Args:
        settings: how observations are prepared.
        quantizer: the quantizer of the state ids (None until a trainer has fitted one).
    """

    def __init__(self, settings: EncoderSettings, quantizer: AnyQuantizer | None = None) -> None:
        self.settings = settings
        self.quantizer = quantizer
        self._distance_mask: torch.Tensor | None = None
        self._void_uniform: torch.Tensor | None = None

    @property
    def num_states(self) -> int:
        """K, the state ids ``0 .. K - 1`` (the prototypes of a process, or of the shared quantizer)."""
        if self.quantizer is None:
            raise ValueError("the encoder has no quantizer yet")
        return self.quantizer.num_prototypes

    @property
    def num_slots(self) -> int | None:
        """M, the ids of one state of a factored quantizer; None for the others (one id a state)."""
        return self.quantizer.num_slots if isinstance(self.quantizer, FactoredQuantizer) else None

    # ------------------------------------------------------------------ encoding
    def prepare(self, obs: torch.Tensor, num_sensed: torch.Tensor, decision: int, generator: torch.Generator):
        """Observations ``(B, F)`` as the quantizer sees them: void slots filled, distances transformed.

        ``distance_transform="log"`` replaces every distance feature ``d`` (door, neighbours, walls) by
        ``log(1 + d)`` (m -> log m), so that the quantizer resolves near things finely and far ones coarsely.

        ``void_features="random"`` fills void neighbour slots with random valid values (section 5.1), drawn from
        ``generator``; ``void_draws="trial"`` draws them once per agent at the first decision of a trial
        (``decision == 0``), so that within a trial the same state always gets the same filling and the same
        prototype; ``"decision"`` draws them anew at every call.
        """
        settings = self.settings
        if settings.void_features == "random":
            stale = self._void_uniform is None or self._void_uniform.shape[0] != obs.shape[0]
            if settings.void_draws == "decision" or decision == 0 or stale:
                self._void_uniform = void_draws(
                    (obs.shape[0],), num_neighbours=settings.num_neighbours, generator=generator, device=obs.device
                )
            obs = fill_void_neighbours(
                obs,
                num_sensed,
                num_neighbours=settings.num_neighbours,
                num_walls=settings.num_walls,
                max_distance=settings.max_distance,
                max_speed=settings.max_speed,
                uniform=self._void_uniform,
            )
        if settings.distance_transform == "log":
            if self._distance_mask is None or self._distance_mask.device != obs.device:
                mask = torch.zeros(settings.num_features, dtype=torch.bool, device=obs.device)
                mask[distance_indices(settings.num_neighbours, settings.num_walls, device=obs.device)] = True
                self._distance_mask = mask
            obs = torch.where(self._distance_mask, obs.log1p(), obs)  # other columns may be < -1: NaN, not taken
        return obs

    def encode_prepared(
        self, prepared: torch.Tensor, num_sensed: torch.Tensor, process: torch.Tensor | None = None
    ) -> torch.Tensor:
        """State ids ``(B,)`` of prepared observations ``(B, F)`` with ``num_sensed (B,)`` neighbours (``(B, M)`` id
        sets of a :class:`~pedrl.vq.FactoredQuantizer`).

        ``process (B,)`` names the learning process of every row, whose quantizer encodes it when there is one per
        process; None means the trainers' layout (``B / P`` consecutive rows per process).
        """
        quantizer = self.quantizer
        if isinstance(quantizer, ProcessQuantizers):
            return quantizer.encode(prepared, num_sensed, process=process)
        if isinstance(quantizer, UnionQuantizer | FactoredQuantizer):
            return quantizer.encode(prepared, num_sensed)
        if quantizer is None:
            raise ValueError("the encoder has no quantizer yet")
        return quantizer.encode(prepared)

    def encode(
        self,
        obs: torch.Tensor,
        info: Mapping[str, Any],
        generator: torch.Generator,
        process: torch.Tensor | None = None,
        *,
        rows_mask: torch.Tensor | None = None,
        process_of_rows: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """State ids ``(R * N,)`` of a room's observations ``(R, N, F)`` (``info`` as ``RoomEnv.step`` gives it).

        ``process (R * N,)``: the learning process of every agent (None: the trainers' layout, see
        :meth:`encode_prepared`). ``rows_mask (R * N,)`` bool: encode only these agents (those still in a room),
        whose processes ``process_of_rows (R * N,)`` then gives when ``process`` is None; the others get id 0 (an
        empty set, all -1, of a factored quantizer). With every agent masked in, or ``None``, all are encoded at once.
        """
        num_sensed = info["num_sensed"].reshape(-1)
        prepared = self.prepare(obs.reshape(-1, obs.shape[-1]), num_sensed, info["decision"], generator)
        if rows_mask is not None:
            selected = rows_mask.nonzero().squeeze(1)
            if selected.shape[0] < rows_mask.shape[0]:
                owner = process if process is not None else process_of_rows
                slots = self.num_slots
                shape = (rows_mask.shape[0],) if slots is None else (rows_mask.shape[0], slots)
                ids = torch.full(shape, 0 if slots is None else -1, dtype=torch.int64, device=obs.device)
                if selected.shape[0] > 0:
                    own = self.encode_prepared(
                        prepared.index_select(0, selected),
                        num_sensed.index_select(0, selected),
                        owner.index_select(0, selected) if owner is not None else None,
                    )
                    ids.index_copy_(0, selected, own)
                return ids
        return self.encode_prepared(prepared, num_sensed, process)

    # ------------------------------------------------------------------ files
    def state_dict(self) -> dict[str, torch.Tensor]:
        """The quantizer's tensors (the settings are metadata: :meth:`EncoderSettings.to_metadata`)."""
        if self.quantizer is None:
            raise ValueError("the encoder has no quantizer to save")
        return self.quantizer.state_dict()

    @classmethod
    def from_state_dict(cls, settings: EncoderSettings, tensors: dict[str, torch.Tensor]) -> StateEncoder:
        """Rebuild an encoder from its settings and its quantizer's tensors (the kind is read from the names)."""
        return cls(settings, quantizer_from_state_dict(tensors))

    def check(self) -> None:
        """One-line ``ValueError`` if the quantizer cannot encode this encoder's observations: a plain part must
        read all F features, and a union's part for ``n`` sensed neighbours exactly their projection."""
        quantizer, settings = self.quantizer, self.settings
        if isinstance(quantizer, FactoredQuantizer):
            slots = (quantizer.num_neighbours, quantizer.num_walls)
            if slots != (settings.num_neighbours, settings.num_walls):
                raise ValueError(
                    f"the factored quantizer reads {slots[0]} neighbour and {slots[1]} wall slots: the observations "
                    f"have {settings.num_neighbours} and {settings.num_walls}"
                )
            return
        parts = quantizer.parts if isinstance(quantizer, ProcessQuantizers) else [quantizer]
        for index, part in enumerate(parts):
            if isinstance(part, Quantizer):
                if part.dim != settings.num_features:
                    raise ValueError(
                        f"quantizer {index} reads {part.dim} features: the observations have {settings.num_features}"
                    )
            elif isinstance(part, UnionQuantizer):
                for n in part.num_sensed:
                    feature_index, sub = part.part(n)
                    wanted = feature_indices(n, settings.num_neighbours, settings.num_walls)
                    if n > settings.num_neighbours or not torch.equal(feature_index.cpu(), wanted):
                        raise ValueError(
                            f"quantizer {index}, part {n}: reads features {feature_index.tolist()}, must read "
                            f"{wanted.tolist()}"
                        )
                    if sub.dim != wanted.numel():
                        raise ValueError(
                            f"quantizer {index}, part {n}: reads {sub.dim} features, must read {wanted.numel()}"
                        )
            else:
                raise ValueError(f"quantizer {index} is a {type(part).__name__}: must be a Quantizer or UnionQuantizer")


def quantizer_from_state_dict(tensors: dict[str, torch.Tensor]) -> AnyQuantizer:
    """The quantizer saved as ``tensors``: one per process or one shared, each plain or a union, or a factored one
    (read from the tensor names)."""
    if FactoredQuantizer.holds(tensors):
        return FactoredQuantizer.from_state_dict(tensors)
    if ProcessQuantizers.holds(tensors):
        return ProcessQuantizers.from_state_dict(tensors, _part_from_state_dict)
    return _part_from_state_dict(tensors)


def _part_from_state_dict(tensors: dict[str, torch.Tensor]) -> Quantizer | UnionQuantizer:
    if "num_sensed" in tensors:
        return UnionQuantizer.from_state_dict(tensors)
    return Quantizer.from_state_dict(tensors)

"""How quantizers are fitted: the ``vq`` config group, checked before any compute."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from typing import Any, Final

from pedrl.common.checks import check_bool, check_choice, check_integer, check_number
from pedrl.vq.encoder import DISTANCE_TRANSFORMS
from pedrl.vq.factored import FactorSpec, factor_specs

KMEANS_INITS: Final = ("kmeans++", "random")
"""Values of ``vq.init``: k-means++ seeding or K random states (see :func:`pedrl.vq.kmeans`)."""


@dataclass(frozen=True)
class VQSettings:
    """How quantizers are fitted (the ``vq`` config group).

    Attributes:
        num_prototypes: K, the number of prototypes (the paper's best: 4096).
        max_iterations: Lloyd iteration cap.
        tolerance: stop when the relative decrease of distortion falls below it.
        max_states: cap on gathered states kept for k-means (a uniform random subset is kept).
        init: k-means initialisation (see :func:`pedrl.vq.kmeans`).
        chunk_size: rows per block in distance computations (bounds memory; None: the measured best).
        weight_own: weight of the agent's own features (speed, velocity angle, door distance) after
            standardisation; 1 is the paper's plain standardisation.
        weight_neighbours: weight of the neighbour features after standardisation: one number for every
            neighbour, or one per neighbour rank (nearest first, ``k`` numbers), so that the nearest neighbours
            are resolved more finely than the far ones.
        weight_walls: weight of every wall feature after standardisation.
        distance_transform: ``"none"`` (the paper's raw distances) or ``"log"`` (``log(1 + d)`` for every distance
            feature before standardisation: fine near the door and the neighbours, coarse far away).
        per_process: one quantizer per learning process, fitted on that process's own states (the paper's
            processes are independent); False: one quantizer fitted on all processes' states and shared.
        factors: None (one quantizer over the whole state), or a factored table (:mod:`pedrl.vq.factored`): a
            mapping of the factors ``own`` (required), ``neighbour`` and ``wall`` to ``{num_prototypes: K,
            weights: {feature: weight}}``; ``num_prototypes`` and the ``weight_*`` keys are then not read, and the
            quantizer is shared (``per_process=false``).
    """

    num_prototypes: int = 4096
    max_iterations: int = 50
    tolerance: float = 1e-4
    max_states: int = 200_000
    init: str = "kmeans++"
    chunk_size: int | None = None
    weight_own: float = 4.0
    weight_neighbours: float | Sequence[float] = 0.2
    weight_walls: float = 0.5
    per_process: bool = True
    distance_transform: str = "log"
    factors: Mapping[str, Any] | None = None

    def __post_init__(self) -> None:
        """Check every value (except the neighbour weights, which need the room) before any compute."""
        check_integer("vq.num_prototypes", self.num_prototypes, minimum=2)
        check_integer("vq.max_iterations", self.max_iterations, minimum=1)
        check_number("vq.tolerance", self.tolerance, low=0.0)
        check_integer("vq.max_states", self.max_states, minimum=1)
        if self.max_states < self.num_prototypes:
            raise ValueError(
                f"vq.max_states={self.max_states!r} is invalid: must be at least vq.num_prototypes="
                f"{self.num_prototypes} (k-means needs at least one state per prototype)"
            )
        check_choice("vq.init", self.init, KMEANS_INITS)
        if self.chunk_size is not None:
            check_integer("vq.chunk_size", self.chunk_size, minimum=1)
        check_number("vq.weight_own", self.weight_own, low=0.0, low_open=True)
        check_number("vq.weight_walls", self.weight_walls, low=0.0, low_open=True)
        check_bool("vq.per_process", self.per_process)
        check_choice("vq.distance_transform", self.distance_transform, DISTANCE_TRANSFORMS)
        if self.factor_specs is not None and self.per_process:
            raise ValueError(
                "vq.per_process=true is invalid with vq.factors: a factored table's quantizers are shared by the "
                "processes (set vq.per_process=false)"
            )

    def kmeans_arguments(self) -> dict[str, Any]:
        """The keyword arguments of :meth:`pedrl.vq.Quantizer.fit` these settings give: Lloyd's cap and stop, the
        seeding and the block size."""
        return {
            "max_iterations": self.max_iterations,
            "tolerance": self.tolerance,
            "init": self.init,
            "chunk_size": self.chunk_size,
        }

    @property
    def factor_specs(self) -> tuple[FactorSpec, ...] | None:
        """The factors of a factored table, checked (None: one plain quantizer)."""
        return factor_specs(self.factors)

    @property
    def table_states(self) -> int:
        """K of a phase's tables: ``num_prototypes``, or the factors' together."""
        specs = self.factor_specs
        return self.num_prototypes if specs is None else sum(spec.num_prototypes for spec in specs)

    @property
    def fit_states(self) -> int:
        """The distinct states one fit needs: ``num_prototypes``, or the own factor's K (every gathered state is an
        own state; neighbours and walls are more)."""
        specs = self.factor_specs
        return self.num_prototypes if specs is None else specs[0].num_prototypes

    @classmethod
    def from_config(cls, values: Mapping[str, Any]) -> VQSettings:
        """Settings from the ``vq`` config group; an unknown key is a one-line ``ValueError``."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"vq.{unknown[0]} is not a quantizer setting: allowed: {', '.join(sorted(known))}")
        return cls(**{key: _plain(value) if key == "factors" else value for key, value in values.items()})


def _plain(value: Any) -> Any:
    """``value`` with every mapping in it a dict (a DictConfig's entries are DictConfigs)."""
    return {key: _plain(entry) for key, entry in value.items()} if isinstance(value, Mapping) else value

"""State quantisers: `Quantizer` (VQQL, IT-VQQL) and `UnionQuantizer` (IN-VQQL).

A quantiser maps a continuous state to the id of its nearest prototype (paper section 3:
`V_Q(x) = argmin_{y in C} dist(x, y)`). The data are standardised first (section 5.1: "each feature has zero mean
and standard deviation equal to 1"), so prototypes live in standardised space and distances weigh every feature
equally.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import torch

from pedrl._numba import use_kernels
from pedrl.vq.kmeans import MIN_GROUP_SIZE, KMeansResult, Precision, PrototypeIndex, _block_argmin, kmeans

__all__ = ["ProcessQuantizers", "Quantizer", "UnionQuantizer"]

#: Features whose standard deviation is below this are only centred (their std is stored as 1).
MIN_STD = 1e-6
#: With `precision="auto"` on the CPU, quantisers of at least this many prototypes encode with the k-d tree.
TREE_MIN_PROTOTYPES = 256


def _uses_tree(prototypes: torch.Tensor, precision: Precision) -> bool:
    """Whether `encode` searches with a `pedrl.vq.tree.TreeIndex`: `"auto"`, on the CPU, with numba, K large."""
    return precision == "auto" and prototypes.shape[-2] >= TREE_MIN_PROTOTYPES and use_kernels(prototypes.device)


def _tree(prototypes: torch.Tensor) -> Any:
    """A `pedrl.vq.tree.TreeIndex` over `(K, d)` or `(T, K, d)` prototypes (the import loads numba)."""
    from pedrl.vq.tree import TreeIndex

    return TreeIndex(prototypes)


class Quantizer:
    """Standardise, then map to the nearest of `K` prototypes.

    `encode(x) = argmin_k || (x - mean) / std - prototypes[k] ||^2` (lowest id on ties).

    Attributes:
        mean: `(d,)` float32 feature means of the fitting data (units of the features).
        std: `(d,)` float32 feature standard deviations (population, `ddof = 0`); a feature whose std is below
            `MIN_STD` (constant in the data) gets std 1 so that it is centred but not blown up.
        prototypes: `(K, d)` float32 prototypes in standardised space.
    """

    def __init__(
        self,
        *,
        mean: torch.Tensor,
        std: torch.Tensor,
        prototypes: torch.Tensor,
        precision: Precision = "auto",
    ) -> None:
        """Builds a quantiser from its tensors (all on one device).

        Args:
            mean: `(d,)` feature means.
            std: `(d,)` feature standard deviations, all > 0.
            prototypes: `(K, d)` prototypes in standardised space.
            precision: nearest-prototype search method of `encode`, exact either way: `"auto"` is the k-d tree of
                `pedrl.vq.tree` on the CPU (from `TREE_MIN_PROTOTYPES` prototypes on, when numba imports), else
                the matrix search of `pedrl.vq.kmeans.PrototypeIndex` with its own `"auto"`; `"float32"` and
                `"bfloat16"` name the matrix search's method. Methods can break float32 ties differently.
        """
        if prototypes.ndim != 2 or mean.shape != (prototypes.shape[1],) or std.shape != mean.shape:
            raise ValueError(
                f"expected mean (d,), std (d,), prototypes (K, d); got {tuple(mean.shape)}, {tuple(std.shape)}, "
                f"{tuple(prototypes.shape)}"
            )
        if not bool((std > 0).all()):
            raise ValueError("std must be positive")
        self.mean = mean.to(torch.float32)
        self.std = std.to(torch.float32)
        self.prototypes = prototypes.to(torch.float32)
        self.precision = precision
        self._index = PrototypeIndex(self.prototypes, precision=precision)
        self._tree: Any = None  # built at the first encode that uses it

    @property
    def num_prototypes(self) -> int:
        """Number of prototypes `K` (ids are `0 .. K - 1`)."""
        return self.prototypes.shape[0]

    @property
    def dim(self) -> int:
        """Number of features `d`."""
        return self.prototypes.shape[1]

    @property
    def device(self) -> torch.device:
        """Device of the tensors."""
        return self.prototypes.device

    @classmethod
    def fit(
        cls,
        states: torch.Tensor,
        num_prototypes: int,
        *,
        generator: torch.Generator | None = None,
        max_iterations: int = 100,
        tolerance: float = 1e-4,
        init: Literal["kmeans++", "random"] | torch.Tensor = "kmeans++",
        chunk_size: int | None = None,
        init_sample_size: int | None = None,
        precision: Precision = "auto",
        feature_weights: torch.Tensor | None = None,
    ) -> tuple[Quantizer, KMeansResult]:
        """Standardises `states` and runs k-means on them (see `pedrl.vq.kmeans.kmeans`).

        Args:
            states: `(M, d)` float32 states (raw feature units).
            num_prototypes: `K`; reduced, with a warning, if the data has fewer distinct states.
            generator: random source on `states.device` (None: seeded with 0).
            max_iterations: cap on Lloyd iterations.
            tolerance: relative distortion decrease that stops the iterations.
            init: `"kmeans++"`, `"random"` or `(K, d)` initial prototypes in standardised space.
            chunk_size: rows per block of the nearest-prototype search.
            init_sample_size: points used by k-means++ seeding.
            precision: nearest-prototype search method, for fitting and for the returned quantizer.
            feature_weights: `(d,)` positive weights multiplying the standardised features (None: all 1, the
                paper's plain standardisation). They are folded into the stored scale, `std / weight`, so
                `encode` applies them too.

        Returns:
            `(quantizer, result)`; `result.distortion` is in standardised units.
        """
        if states.ndim != 2 or states.shape[0] == 0:
            raise ValueError(f"states must be (M, d) with M > 0, got {tuple(states.shape)}")
        states64 = states.to(torch.float64)
        mean = states64.mean(0)
        std = states64.std(0, correction=0)
        std = torch.where(std < MIN_STD, torch.ones_like(std), std)
        if feature_weights is not None:
            weights = torch.as_tensor(feature_weights, dtype=torch.float64, device=states.device)
            if weights.shape != std.shape or not bool((weights > 0).all()):
                raise ValueError(f"feature_weights must be ({states.shape[1]},) positive numbers")
            std = std / weights
        standardised = ((states64 - mean) / std).to(torch.float32)
        del states64
        result = kmeans(
            standardised,
            num_prototypes,
            max_iterations=max_iterations,
            tolerance=tolerance,
            generator=generator,
            init=init,
            chunk_size=chunk_size,
            init_sample_size=init_sample_size,
            precision=precision,
        )
        return cls(mean=mean, std=std, prototypes=result.prototypes, precision=precision), result

    def standardise(self, states: torch.Tensor) -> torch.Tensor:
        """`(states - mean) / std`, `(..., d) -> (..., d)`."""
        return (states - self.mean) / self.std

    def encode(self, states: torch.Tensor, *, chunk_size: int | None = None) -> torch.Tensor:
        """Ids of the nearest prototypes.

        Args:
            states: `(..., d)` raw states, any leading shape.
            chunk_size: rows per block of the search (None: per-device default).

        Returns:
            `(...)` int64 ids in `[0, K)`.
        """
        if states.shape[-1] != self.dim:
            raise ValueError(f"expected states (..., {self.dim}), got {tuple(states.shape)}")
        flat = self.standardise(states.reshape(-1, self.dim).to(torch.float32))
        if chunk_size is None and _uses_tree(self.prototypes, self.precision):
            if self._tree is None:
                self._tree = _tree(self.prototypes)
            return self._tree.search(flat)[0].view(states.shape[:-1])
        index = self._index
        if chunk_size is not None:
            index = PrototypeIndex(self.prototypes, precision=self.precision, chunk_size=chunk_size)
        ids, _ = index.search(flat)
        return ids.view(states.shape[:-1])

    def decode(self, ids: torch.Tensor) -> torch.Tensor:
        """Prototypes in raw feature units, `(...) -> (..., d)`."""
        return self.prototypes[ids] * self.std + self.mean

    def to(self, device: torch.device | str) -> Quantizer:
        """A copy on `device`."""
        return Quantizer(mean=self.mean.to(device), std=self.std.to(device), prototypes=self.prototypes.to(device))

    def state_dict(self) -> dict[str, torch.Tensor]:
        """`{"mean": (d,), "std": (d,), "prototypes": (K, d)}` (contiguous, safe for safetensors)."""
        return {
            "mean": self.mean.contiguous(),
            "std": self.std.contiguous(),
            "prototypes": self.prototypes.contiguous(),
        }

    @classmethod
    def from_state_dict(cls, state: dict[str, torch.Tensor]) -> Quantizer:
        """Inverse of `state_dict`."""
        return cls(mean=state["mean"], std=state["std"], prototypes=state["prototypes"])

    def __repr__(self) -> str:
        return f"Quantizer(num_prototypes={self.num_prototypes}, dim={self.dim}, device={self.device})"


@dataclass(frozen=True)
class _Part:
    num_sensed: int
    feature_index: torch.Tensor
    quantizer: Quantizer


class UnionQuantizer:
    """The union quantiser of IN-VQQL (paper Fig. 3, `V_Q^i = V_Q^i U V_Q^(i-1)`).

    One part per number of sensed neighbours `n`. Part `n` holds the projection `feature_index (d_n,)` (the
    features of a state with `n` neighbours, the paper's Gamma, from `pedrl.sim.sensing.feature_indices`) and a
    `Quantizer` over those `d_n` features.

    Ids are global: parts are ordered by increasing `n`, part `n` owns the id range
    `[offset_n, offset_n + K_n)` with `offset_n` the total size of the parts before it, and a state's id is
    `offset_n + local id`. Adding a part or growing one shifts the ids of the parts after it, so a Q table indexed
    by an older union is not valid for a newer one (IN-VQQL learns from scratch after each union anyway).

    Routing: a state with `n` sensed neighbours is encoded by part `n`. If there is no part `n`, it goes to the
    part of the largest `n' < n` (projecting away the extra neighbours, like the paper's projection Gamma), and if
    there is none, to the part with the smallest `n`.
    """

    def __init__(self, parts: list[_Part] | None = None) -> None:
        """Builds a union from parts (use `UnionQuantizer()` and `unite` instead).

        Args:
            parts: parts with distinct `num_sensed`, on one device.
        """
        self._parts = sorted(parts or [], key=lambda part: part.num_sensed)
        if len({part.num_sensed for part in self._parts}) != len(self._parts):
            raise ValueError("parts must have distinct num_sensed")
        sizes = [part.quantizer.num_prototypes for part in self._parts]
        self._offsets = [sum(sizes[:i]) for i in range(len(sizes))]
        self._route = self._routing_table()

    # ------------------------------------------------------------------ structure

    @property
    def num_sensed(self) -> list[int]:
        """The `n` of every part, increasing."""
        return [part.num_sensed for part in self._parts]

    @property
    def part_sizes(self) -> dict[int, int]:
        """`{n: K_n}` in increasing `n`."""
        return {part.num_sensed: part.quantizer.num_prototypes for part in self._parts}

    @property
    def offsets(self) -> dict[int, int]:
        """`{n: offset_n}`, the first global id of every part."""
        return {part.num_sensed: offset for part, offset in zip(self._parts, self._offsets, strict=True)}

    @property
    def num_prototypes(self) -> int:
        """Total number of prototypes (global ids are `0 .. num_prototypes - 1`)."""
        return sum(part.quantizer.num_prototypes for part in self._parts)

    @property
    def device(self) -> torch.device:
        """Device of the tensors (CPU when empty)."""
        return self._parts[0].quantizer.device if self._parts else torch.device("cpu")

    def part(self, num_sensed: int) -> tuple[torch.Tensor, Quantizer]:
        """`(feature_index (d_n,), quantizer)` of part `num_sensed` (KeyError if absent)."""
        for part in self._parts:
            if part.num_sensed == num_sensed:
                return part.feature_index, part.quantizer
        raise KeyError(num_sensed)

    def _routing_table(self) -> torch.Tensor:
        """`(n_max + 1,)` int64: part position used for each `n in [0, n_max]`."""
        if not self._parts:
            return torch.zeros(0, dtype=torch.int64, device=self.device)
        ns = self.num_sensed
        route = []
        for n in range(ns[-1] + 1):
            below = [i for i, m in enumerate(ns) if m <= n]
            route.append(below[-1] if below else 0)
        return torch.tensor(route, dtype=torch.int64, device=self.device)

    # ------------------------------------------------------------------ building

    def unite(self, num_sensed: int, feature_index: torch.Tensor, quantizer: Quantizer) -> UnionQuantizer:
        """A new union with `quantizer` added as (or merged into) part `num_sensed`.

        A new `n` adds a part. For an existing `n`, the part's quantizer becomes: the new `mean`/`std`, and the old
        prototypes re-expressed in that standardisation (`(old * old_std + old_mean - new_mean) / new_std`, so they
        are unchanged in raw units) followed by the new prototypes. Local ids of the old prototypes are kept; global
        ids of later parts shift.

        Args:
            num_sensed: `n >= 0`, the number of sensed neighbours this quantizer is for.
            feature_index: `(d_n,)` int64 indices of the features of the full state that `quantizer` reads.
            quantizer: a `Quantizer` over `d_n` features, on the union's device.

        Returns:
            The new `UnionQuantizer` (this one is unchanged).
        """
        feature_index = feature_index.to(device=quantizer.device, dtype=torch.int64)
        if feature_index.ndim != 1 or feature_index.shape[0] != quantizer.dim:
            raise ValueError(
                f"feature_index must be ({quantizer.dim},) to match the quantizer, got {tuple(feature_index.shape)}"
            )
        if self._parts and quantizer.device != self.device:
            raise ValueError(f"quantizer is on {quantizer.device}, the union on {self.device}")
        parts = [part for part in self._parts if part.num_sensed != num_sensed]
        if len(parts) < len(self._parts):
            old_index, old = self.part(num_sensed)
            if not torch.equal(old_index, feature_index):
                raise ValueError(f"part {num_sensed} already exists with different feature indices")
            raw = old.prototypes * old.std + old.mean
            old_prototypes = (raw - quantizer.mean) / quantizer.std
            quantizer = Quantizer(
                mean=quantizer.mean,
                std=quantizer.std,
                prototypes=torch.cat([old_prototypes, quantizer.prototypes]),
                precision=quantizer.precision,
            )
        parts.append(_Part(num_sensed=num_sensed, feature_index=feature_index, quantizer=quantizer))
        return UnionQuantizer(parts)

    # ------------------------------------------------------------------ encoding

    def part_of(self, num_sensed: torch.Tensor) -> torch.Tensor:
        """Position (in `self.num_sensed`) of the part that encodes states with `num_sensed` neighbours, `(...)`."""
        clamped = num_sensed.clamp(0, self._route.shape[0] - 1)
        return self._route[clamped]

    def encode(self, states: torch.Tensor, num_sensed: torch.Tensor, *, chunk_size: int | None = None) -> torch.Tensor:
        """Global ids of the states, each encoded by the part of its number of sensed neighbours.

        Args:
            states: `(..., F)` full states (`F` covers every `feature_index`).
            num_sensed: `(...)` int64 number of sensed neighbours of each state.
            chunk_size: rows per block of the search.

        Returns:
            `(...)` int64 global ids in `[0, num_prototypes)`.
        """
        if not self._parts:
            raise RuntimeError("UnionQuantizer has no parts")
        if num_sensed.shape != states.shape[:-1]:
            raise ValueError(f"num_sensed {tuple(num_sensed.shape)} must match states {tuple(states.shape[:-1])}")
        flat_states = states.reshape(-1, states.shape[-1])
        which = self.part_of(num_sensed.reshape(-1).to(torch.int64))
        ids = torch.empty(flat_states.shape[0], dtype=torch.int64, device=states.device)
        for position, (part, offset) in enumerate(zip(self._parts, self._offsets, strict=True)):
            rows = (which == position).nonzero().squeeze(1)
            if rows.numel() == 0:
                continue
            projected = flat_states[rows[:, None], part.feature_index[None, :]]
            ids[rows] = part.quantizer.encode(projected, chunk_size=chunk_size) + offset
        return ids.view(states.shape[:-1])

    # ------------------------------------------------------------------ devices and persistence

    def to(self, device: torch.device | str) -> UnionQuantizer:
        """A copy on `device`."""
        return UnionQuantizer(
            [_Part(part.num_sensed, part.feature_index.to(device), part.quantizer.to(device)) for part in self._parts]
        )

    def state_dict(self) -> dict[str, torch.Tensor]:
        """Flat `dict[str, Tensor]`: `"num_sensed" (P,)` and, per part `n`, `"part{n}.feature_index"`,
        `"part{n}.mean"`, `"part{n}.std"`, `"part{n}.prototypes"`."""
        state = {"num_sensed": torch.tensor(self.num_sensed, dtype=torch.int64, device=self.device)}
        for part in self._parts:
            state[f"part{part.num_sensed}.feature_index"] = part.feature_index.contiguous()
            for key, value in part.quantizer.state_dict().items():
                state[f"part{part.num_sensed}.{key}"] = value
        return state

    @classmethod
    def from_state_dict(cls, state: dict[str, torch.Tensor]) -> UnionQuantizer:
        """Inverse of `state_dict`."""
        parts = []
        for n in state["num_sensed"].tolist():
            prefix = f"part{n}."
            quantizer = Quantizer.from_state_dict({key: state[prefix + key] for key in ("mean", "std", "prototypes")})
            parts.append(_Part(n, state[prefix + "feature_index"].to(torch.int64), quantizer))
        return cls(parts)

    def __repr__(self) -> str:
        return f"UnionQuantizer(part_sizes={self.part_sizes}, device={self.device})"


def _first_argmin(scores: torch.Tensor) -> torch.Tensor:
    """`scores.argmin(-1)` (the first minimum), by the two-level minimum of `pedrl.vq.kmeans._block_argmin` when
    groups of `MIN_GROUP_SIZE` columns divide the last axis: on CPU a full `argmin` over 4096 columns costs several
    times the product that filled it."""
    width = scores.shape[-1]
    if scores.device.type != "cpu" or width % MIN_GROUP_SIZE:
        return scores.argmin(-1)
    flat = scores.reshape(-1, width)
    rows = torch.arange(flat.shape[0], device=scores.device)
    return _block_argmin(flat, rows, MIN_GROUP_SIZE)[1].view(scores.shape[:-1])


PROCESS_PREFIX = "process"
"""Key prefix of a part in `ProcessQuantizers.state_dict`: `process{p:03d}/<the part's key>`."""


class ProcessQuantizers:
    """One quantiser per learning process: the paper's 20 learning processes are independent, quantiser included.

    Part `p` (a `Quantizer` or a `UnionQuantizer`) is fitted on the states that process `p` visited and encodes
    that process's states only. Every part has the same number of prototypes, so the processes' Q tables stack
    into one `(P, A, K, U)` tensor.

    Args:
        parts: one quantiser per process, all with the same `num_prototypes`.
    """

    def __init__(self, parts: list[Quantizer | UnionQuantizer]) -> None:
        if not parts:
            raise ValueError("ProcessQuantizers needs at least one part")
        sizes = {part.num_prototypes for part in parts}
        if len(sizes) != 1:
            raise ValueError(f"every process's quantizer must have the same number of prototypes, got {sorted(sizes)}")
        self.parts = list(parts)
        self._stacked: tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor] | None = None
        self._tree: Any = None  # one k-d tree per process, built at the first encode that uses it
        if all(isinstance(part, Quantizer) for part in parts) and len({part.dim for part in parts}) == 1:
            mean = torch.stack([part.mean for part in parts])  # (P, d)
            std = torch.stack([part.std for part in parts])
            prototypes = torch.stack([part.prototypes for part in parts])  # (P, K, d)
            self._stacked = (mean, std, prototypes, (prototypes * prototypes).sum(-1).unsqueeze(1))  # (P, 1, K)
        self._use_tree = self._stacked is not None and all(_uses_tree(p.prototypes, p.precision) for p in parts)

    @property
    def num_processes(self) -> int:
        """P, the number of parts."""
        return len(self.parts)

    @property
    def num_prototypes(self) -> int:
        """K of every part (ids are `0 .. K - 1` within each process)."""
        return self.parts[0].num_prototypes

    @property
    def device(self) -> torch.device:
        """Device of the tensors."""
        return self.parts[0].device

    def encode(
        self,
        states: torch.Tensor,
        num_sensed: torch.Tensor | None = None,
        *,
        process: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Ids of the states, each encoded by the quantiser of its process.

        Args:
            states: `(B, F)` raw states.
            num_sensed: `(B,)` sensed neighbours (needed by `UnionQuantizer` parts; ignored otherwise).
            process: `(B,)` int64 process of every row; None means `B / P` consecutive rows per process, in order
                (the trainers' layout).

        Returns:
            `(B,)` int64 ids in `[0, K)`.
        """
        rows = states.shape[0]
        if process is None and rows % self.num_processes:
            raise ValueError(f"{rows} rows cannot be split into {self.num_processes} processes")
        if self._use_tree:
            return self._encode_tree(states, self._layout(rows, states.device) if process is None else process)
        if process is None:
            if self._stacked is not None:
                return self._encode_stacked(states.view(self.num_processes, -1, states.shape[-1])).reshape(-1)
            process = self._layout(rows, states.device)
        elif self._stacked is not None:
            return self._encode_grouped(states, process)
        ids = torch.empty(rows, dtype=torch.int64, device=states.device)
        for index, part in enumerate(self.parts):
            selected = (process == index).nonzero().squeeze(1)
            if selected.numel() == 0:
                continue
            own = states.index_select(0, selected)
            if isinstance(part, UnionQuantizer):
                if num_sensed is None:
                    raise ValueError("num_sensed is required to encode with UnionQuantizer parts")
                ids[selected] = part.encode(own, num_sensed.index_select(0, selected))
            else:
                ids[selected] = part.encode(own)
        return ids

    def _layout(self, rows: int, device: torch.device) -> torch.Tensor:
        """The trainers' layout: `rows / P` consecutive rows per process, `(rows,)` process ids."""
        return torch.arange(self.num_processes, device=device).repeat_interleave(rows // self.num_processes)

    def _encode_tree(self, states: torch.Tensor, process: torch.Tensor) -> torch.Tensor:
        """Ids of `(B, d)` states of processes `(B,)` by the k-d trees of those processes."""
        assert self._stacked is not None
        mean, std, prototypes, _ = self._stacked
        if self._tree is None:
            self._tree = _tree(prototypes)
        standardised = (states.to(torch.float32) - mean.index_select(0, process)) / std.index_select(0, process)
        return self._tree.search(standardised, process)[0]

    def _encode_stacked(self, states: torch.Tensor) -> torch.Tensor:
        """Nearest prototypes of `(P, B, d)` states, one batched matrix product for all processes: `(P, B)`."""
        assert self._stacked is not None
        mean, std, prototypes, squared_norms = self._stacked
        standardised = (states.to(torch.float32) - mean.unsqueeze(1)) / std.unsqueeze(1)
        # ||x - c||^2 = ||x||^2 - 2 x.c + ||c||^2; ||x||^2 is the same for every c of a row
        scores = torch.baddbmm(squared_norms, standardised, prototypes.transpose(1, 2), alpha=-2.0)
        return _first_argmin(scores)

    def _encode_grouped(self, states: torch.Tensor, process: torch.Tensor) -> torch.Tensor:
        """Ids of `(B, d)` states of any processes `(B,)`: the rows are grouped by process into a `(P, m, d)`
        batch (`m` the most rows of one process, the rest padded) for one batched product: `(B,)`."""
        order = torch.argsort(process, stable=True)  # (B,) rows grouped by process
        owner = process.index_select(0, order)
        counts = torch.bincount(process, minlength=self.num_processes)
        starts = torch.cumsum(counts, 0) - counts
        slot = torch.arange(order.shape[0], device=states.device) - starts.index_select(0, owner)
        padded = states.new_zeros(self.num_processes, int(counts.max()), states.shape[-1])
        padded[owner, slot] = states.index_select(0, order)
        ids = torch.empty(order.shape[0], dtype=torch.int64, device=states.device)
        ids[order] = self._encode_stacked(padded)[owner, slot]
        return ids

    def to(self, device: torch.device | str) -> ProcessQuantizers:
        """A copy on `device`."""
        return ProcessQuantizers([part.to(device) for part in self.parts])

    def state_dict(self) -> dict[str, torch.Tensor]:
        """Flat `dict[str, Tensor]`: the keys of part `p`'s own state dict under `process{p:03d}/`."""
        return {
            f"{PROCESS_PREFIX}{index:03d}/{key}": value
            for index, part in enumerate(self.parts)
            for key, value in part.state_dict().items()
        }

    @staticmethod
    def holds(state: dict[str, torch.Tensor]) -> bool:
        """Whether a state dict was written by `ProcessQuantizers.state_dict` (else by a single quantiser)."""
        return bool(state) and all(key.startswith(PROCESS_PREFIX) for key in state)

    @classmethod
    def from_state_dict(cls, state: dict[str, torch.Tensor], load_part: Any) -> ProcessQuantizers:
        """Inverse of `state_dict`; `load_part(part_state)` rebuilds one part (`Quantizer.from_state_dict`, ...)."""
        grouped: dict[int, dict[str, torch.Tensor]] = {}
        for key, value in state.items():
            head, _, rest = key.partition("/")
            index = head[len(PROCESS_PREFIX) :]
            if not index.isdigit() or not rest:
                raise ValueError(f"state key {key!r} is not of the form {PROCESS_PREFIX}NNN/<key>")
            grouped.setdefault(int(index), {})[rest] = value
        if sorted(grouped) != list(range(len(grouped))):
            raise ValueError(f"the processes of the state dict are not numbered 0..P-1: {sorted(grouped)}")
        return cls([load_part(grouped[index]) for index in range(len(grouped))])

    def __repr__(self) -> str:
        return f"ProcessQuantizers(processes={self.num_processes}, num_prototypes={self.num_prototypes})"

"""The replay memory of the neural learner: one ring of transitions per learning process, in preallocated tensors.

Each process keeps its own ``capacity`` latest transitions ``(input, action, reward, next input, terminated)`` of its
agents and samples its own batches, so that ``P`` processes stay ``P`` independent learning runs. Each transition also
keeps the index of the room it was played in (a ``mix`` run's rooms: 0 its own, ``i`` its ``i``-th mix room): a
balanced batch (``algo.replay_balance=room``) draws every room the ring holds equally often, whatever its share of
the ring (a lone walker's trial adds 30 transitions where a crowd's adds thousands).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Final, NamedTuple

import torch

REPLAY_PREFIX: Final = "replay"
FIELDS: Final = ("inputs", "actions", "rewards", "next_inputs", "terminated")


class Batch(NamedTuple):
    """A sampled batch of every process, ``(P, B, ...)``."""

    inputs: torch.Tensor
    actions: torch.Tensor
    rewards: torch.Tensor
    next_inputs: torch.Tensor
    terminated: torch.Tensor


class ReplayBuffer:
    """``P`` rings of ``capacity`` transitions of ``width``-wide inputs.

    Args:
        processes: P, independent rings.
        capacity: transitions per ring; the oldest are overwritten once it is full.
        width: D, the width of an input.
    """

    def __init__(self, processes: int, capacity: int, width: int, *, device: str | torch.device = "cpu") -> None:
        self.processes, self.capacity, self.width = processes, capacity, width
        shape = (processes, capacity)
        self.inputs = torch.zeros(*shape, width, device=device)
        self.actions = torch.zeros(shape, dtype=torch.int64, device=device)
        self.rewards = torch.zeros(shape, device=device)
        self.next_inputs = torch.zeros(*shape, width, device=device)
        self.terminated = torch.zeros(shape, dtype=torch.bool, device=device)
        self.rooms = torch.zeros(shape, dtype=torch.int64, device=device)
        self.sizes = torch.zeros(processes, dtype=torch.int64)
        self.heads = torch.zeros(processes, dtype=torch.int64)
        self._weights: list[torch.Tensor | None] = [None] * processes  # a balanced ring's weights, until it changes

    @staticmethod
    def bytes_needed(processes: int, capacity: int, width: int) -> int:
        """Bytes of the rings of :meth:`__init__`: two float32 inputs, an int64 action and room, a float32 reward, a
        flag."""
        return processes * capacity * (8 * width + 8 + 8 + 4 + 1)

    @property
    def size(self) -> int:
        """Transitions held by the smallest ring."""
        return int(self.sizes.min())

    def add(self, process: torch.Tensor, transitions: Batch, room: int = 0) -> None:
        """Append transitions ``(B, ...)`` (a :class:`Batch` without the process axis), row ``b`` to ring
        ``process[b]``, in order, each marked as played in ``room``."""
        counts = torch.bincount(process, minlength=self.processes)
        for p in torch.nonzero(counts).squeeze(1).tolist():
            rows = torch.nonzero(process == p).squeeze(1)
            if rows.shape[0] > self.capacity:  # only the newest fit
                rows = rows[-self.capacity :]
            count = rows.shape[0]
            slots = (self.heads[p] + torch.arange(count)) % self.capacity
            slots = slots.to(self.inputs.device)
            for name in FIELDS:
                getattr(self, name)[p].index_copy_(0, slots, getattr(transitions, name).index_select(0, rows))
            self.rooms[p].index_fill_(0, slots, room)
            self.heads[p] = (self.heads[p] + count) % self.capacity
            self.sizes[p] = min(self.capacity, int(self.sizes[p]) + count)
            self._weights[p] = None

    def sample(self, batch_size: int, generator: torch.Generator, *, balanced: bool = False) -> Batch:
        """``batch_size`` transitions of each ring, with replacement: uniform over what it holds, or (``balanced``)
        each room it holds drawn equally often, uniform within the room."""
        device = self.inputs.device
        if balanced:
            index = torch.stack([self._balanced(p, batch_size, generator) for p in range(self.processes)])
        else:
            uniform = torch.rand(self.processes, batch_size, generator=generator, device=device)
            index = (uniform * self.sizes.to(device)[:, None]).long().clamp_max(self.capacity - 1)
        process = torch.arange(self.processes, device=device)[:, None]
        return Batch(*(getattr(self, name)[process, index] for name in FIELDS))

    def _balanced(self, process: int, batch_size: int, generator: torch.Generator) -> torch.Tensor:
        """Slots ``(B,)`` of ring ``process``, each transition weighted by one over its room's count in the ring (the
        weights kept until the ring changes: the gradient steps of a decision draw from one set)."""
        weights = self._weights[process]
        if weights is None:
            rooms = self.rooms[process, : int(self.sizes[process])]
            weights = self._weights[process] = 1.0 / torch.bincount(rooms).double()[rooms]
        return torch.multinomial(weights, batch_size, replacement=True, generator=generator)

    def tensors(self) -> dict[str, torch.Tensor]:
        """The rings as named tensors (``replay/<field>``, ``replay/rooms``, ``replay/sizes``, ``replay/heads``), for
        an exact resume."""
        named = {f"{REPLAY_PREFIX}/{name}": getattr(self, name) for name in (*FIELDS, "rooms")}
        named[f"{REPLAY_PREFIX}/sizes"] = self.sizes
        named[f"{REPLAY_PREFIX}/heads"] = self.heads
        return named

    def load_tensors(self, tensors: Mapping[str, torch.Tensor]) -> None:
        """Take the rings of :meth:`tensors`; one line for a missing tensor or one of another shape or dtype (the rooms
        of a checkpoint written before they were kept are all 0: its run drew its batches uniformly)."""
        for name in (*FIELDS, "rooms", "sizes", "heads"):
            key = f"{REPLAY_PREFIX}/{name}"
            mine, theirs = getattr(self, name), tensors.get(key)
            if theirs is None and name == "rooms":
                mine.zero_()
                continue
            if theirs is None:
                raise ValueError(f"tensor {key} is missing")
            if theirs.dtype != mine.dtype or theirs.shape != mine.shape:
                raise ValueError(
                    f"tensor {key} is {theirs.dtype} {tuple(theirs.shape)}: must be {mine.dtype} {tuple(mine.shape)}"
                )
            mine.copy_(theirs)
        self._weights = [None] * self.processes
        if bool(
            ((self.sizes < 0) | (self.sizes > self.capacity) | (self.heads < 0) | (self.heads >= self.capacity)).any()
        ):
            raise ValueError(f"tensors replay/sizes and replay/heads must lie in [0, {self.capacity}]")

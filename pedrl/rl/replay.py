"""The replay memory of the neural learner: one ring of transitions per learning process, in preallocated tensors.

Each process keeps its own ``capacity`` latest transitions ``(input, action, reward, next input, terminated)`` of its
agents and samples its own batches, so that ``P`` processes stay ``P`` independent learning runs. Each transition also
keeps the index of the room it was played in (a ``mix`` run's rooms: 0 its own, ``i`` its ``i``-th mix room): a
balanced batch (``algo.replay_balance=room``) draws every room the ring holds equally often, whatever its share of
the ring (a lone walker's trial adds 30 transitions where a crowd's adds thousands).

With n-step returns (``algo.n_step`` > 1; Sutton & Barto 2018, section 7.1; Hessel et al. 2018) a transition holds the
discounted sum of up to ``n`` rewards and the input ``n`` decisions on, and the rings keep each transition's horizon
(fewer than ``n`` decisions where its walker's trial ended before): :class:`NStepWindow` folds a trial's decisions
into such transitions.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Final, NamedTuple

import torch

REPLAY_PREFIX: Final = "replay"
FIELDS: Final = ("inputs", "actions", "rewards", "next_inputs", "terminated")


class Batch(NamedTuple):
    """A sampled batch of every process, ``(P, B, ...)``: ``rewards`` the (discounted sum of) rewards up to
    ``next_inputs``, ``horizons`` the decisions between ``inputs`` and ``next_inputs`` (None: one each)."""

    inputs: torch.Tensor
    actions: torch.Tensor
    rewards: torch.Tensor
    next_inputs: torch.Tensor
    terminated: torch.Tensor
    horizons: torch.Tensor | None = None


class ReplayBuffer:
    """``P`` rings of ``capacity`` transitions of ``width``-wide inputs.

    Args:
        processes: P, independent rings.
        capacity: transitions per ring; the oldest are overwritten once it is full.
        width: D, the width of an input.
        horizons: keep each transition's horizon (n-step returns); without, every transition spans one decision.
    """

    def __init__(
        self, processes: int, capacity: int, width: int, *, horizons: bool = False, device: str | torch.device = "cpu"
    ) -> None:
        self.processes, self.capacity, self.width = processes, capacity, width
        self.fields = (*FIELDS, "horizons") if horizons else FIELDS
        shape = (processes, capacity)
        self.inputs = torch.zeros(*shape, width, device=device)
        self.actions = torch.zeros(shape, dtype=torch.int64, device=device)
        self.rewards = torch.zeros(shape, device=device)
        self.next_inputs = torch.zeros(*shape, width, device=device)
        self.terminated = torch.zeros(shape, dtype=torch.bool, device=device)
        self.rooms = torch.zeros(shape, dtype=torch.int64, device=device)
        self.horizons = torch.ones(shape, dtype=torch.uint8, device=device) if horizons else None
        self.sizes = torch.zeros(processes, dtype=torch.int64)
        self.heads = torch.zeros(processes, dtype=torch.int64)
        self._weights: list[torch.Tensor | None] = [None] * processes  # a balanced ring's weights, until it changes

    @staticmethod
    def bytes_needed(processes: int, capacity: int, width: int, *, horizons: bool = False) -> int:
        """Bytes of the rings of :meth:`__init__`: two float32 inputs, an int64 action and room, a float32 reward, a
        flag (and a byte of horizon)."""
        return processes * capacity * (8 * width + 8 + 8 + 4 + 1 + int(horizons))

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
            for name in self.fields:
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
        return Batch(*(getattr(self, name)[process, index] for name in self.fields))

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
        named = {f"{REPLAY_PREFIX}/{name}": getattr(self, name) for name in (*self.fields, "rooms")}
        named[f"{REPLAY_PREFIX}/sizes"] = self.sizes
        named[f"{REPLAY_PREFIX}/heads"] = self.heads
        return named

    def load_tensors(self, tensors: Mapping[str, torch.Tensor]) -> None:
        """Take the rings of :meth:`tensors`; one line for a missing tensor or one of another shape or dtype (the rooms
        of a checkpoint written before they were kept are all 0: its run drew its batches uniformly)."""
        for name in (*self.fields, "rooms", "sizes", "heads"):
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
        if self.horizons is not None and bool((self.horizons == 0).any()):
            raise ValueError("tensor replay/horizons must hold horizons of at least 1 decision")


class NStepWindow:
    """A trial's last ``steps`` decisions, folded into n-step transitions (module docstring).

    :meth:`fold` takes one decision of every row (an agent of a room) and returns the transitions it completes: for
    each row that acted, the one that began ``steps - 1`` decisions earlier, and, where the row's trial ends here
    (it reached its goal, or the clock cut it), every one still open, each with the discounted sum of its rewards
    and its horizon. A row's open transitions are dropped once it stops acting, so a transition is returned once.
    One window serves one trial.
    """

    def __init__(self, steps: int, gamma: float) -> None:
        self.steps, self.gamma = steps, gamma
        self._past: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]] = []

    def fold(
        self,
        taken: Batch,
        valid: torch.Tensor,
        ended: torch.Tensor,
    ) -> tuple[torch.Tensor, Batch]:
        """``taken``: the decision's ``(R N, ...)`` transitions of every row (one decision each); ``valid`` ``(R N,)``
        the rows that acted; ``ended`` the rows whose trial ends with this decision. Returns the rows ``(T,)`` of the
        completed transitions and the transitions (with their horizons)."""
        self._past.append((taken.inputs, taken.actions, taken.rewards, valid))
        window = self._past
        returns = [taken.rewards] * len(window)
        for j in range(len(window) - 2, -1, -1):
            returns[j] = window[j][2] + self.gamma * returns[j + 1]
        closing = valid & ended
        parts = []
        for j, (inputs, actions, _, acted) in enumerate(window):
            horizon = len(window) - j
            rows = torch.nonzero(acted & valid & (valid if horizon == self.steps else closing)).squeeze(1)
            if rows.shape[0]:
                horizons = torch.full_like(rows, horizon, dtype=torch.uint8)
                parts.append((rows, inputs[rows], actions[rows], returns[j][rows], horizons))
        if len(window) == self.steps:
            window.pop(0)
        if not parts:
            rows = torch.zeros(0, dtype=torch.int64, device=valid.device)
            return rows, Batch(*(t[rows] for t in taken[:5]), torch.zeros(0, dtype=torch.uint8, device=valid.device))
        rows = torch.cat([part[0] for part in parts])
        return rows, Batch(
            torch.cat([part[1] for part in parts]),
            torch.cat([part[2] for part in parts]),
            torch.cat([part[3] for part in parts]),
            taken.next_inputs[rows],
            taken.terminated[rows],
            torch.cat([part[4] for part in parts]),
        )

"""The state of a batch of rooms, :class:`RoomState`: what changes from decision to decision, in one record that the
torch step and the numba kernels both read and write (``RoomEnv.state``, ``RoomEnv.load_state``)."""

from __future__ import annotations

from collections import namedtuple
from dataclasses import dataclass, fields

import torch

__all__ = ["KernelState", "RoomState"]


@dataclass
class RoomState:
    """Every tensor of ``R`` rooms of ``N`` agents that a decision changes.

    Attributes:
        positions: Agent centres ``(R, N, 2)`` float32 (m).
        velocities: Velocities ``(R, N, 2)`` float32 (m/s).
        headings: Headings ``(R, N)`` float32 (rad, in ``(-pi, pi]``).
        speeds: Speeds ``(R, N)`` float32 (m/s).
        active: Agents still in their trial ``(R, N)`` bool.
        exit_index: The exit each agent heads for ``(R, N)`` int64.
        targets: The point each agent aims at ``(R, N, 2)`` float32 (m): its waypoint, else its exit's goal point.
        decisions: Each room's clock ``(R,)`` int64 (decisions since its reset).
        stage: The waypoint each agent aims at ``(R, N)`` int64.
    """

    positions: torch.Tensor
    velocities: torch.Tensor
    headings: torch.Tensor
    speeds: torch.Tensor
    active: torch.Tensor
    exit_index: torch.Tensor
    targets: torch.Tensor
    decisions: torch.Tensor
    stage: torch.Tensor

    def tensors(self) -> tuple[torch.Tensor, ...]:
        """The fields in declaration order."""
        return tuple(getattr(self, field.name) for field in fields(self))

    def arrays(self) -> KernelState:
        """The numba kernels' view of the state (:data:`KernelState`): a contiguous array of each field, named as the
        field; an array shares its tensor's memory where the tensor was contiguous already."""
        return KernelState(*(t.contiguous().numpy() for t in self.tensors()))

    @classmethod
    def from_arrays(cls, arrays: KernelState) -> RoomState:
        """The state held by a kernel's ``arrays`` (their memory, not copies)."""
        return cls(**{name: torch.from_numpy(getattr(arrays, name)) for name in KernelState._fields})

    def clone(self) -> RoomState:
        """A deep copy (contiguous)."""
        return RoomState(*(t.clone().contiguous() for t in self.tensors()))

    def check_like(self, other: RoomState) -> None:
        """Raise ``ValueError`` naming the first field whose shape, dtype or device differs from ``other``'s."""
        for field in fields(self):
            mine, theirs = getattr(self, field.name), getattr(other, field.name)
            if not isinstance(mine, torch.Tensor):
                raise ValueError(f"state.{field.name} is a {type(mine).__name__}: must be a tensor")
            if (mine.shape, mine.dtype, mine.device) != (theirs.shape, theirs.dtype, theirs.device):
                raise ValueError(
                    f"state.{field.name} is {tuple(mine.shape)} {mine.dtype} on {mine.device}: must be "
                    f"{tuple(theirs.shape)} {theirs.dtype} on {theirs.device}"
                )


KernelState = namedtuple("KernelState", [field.name for field in fields(RoomState)], module=__name__)
"""What the numba kernels read and write of the state: :class:`RoomState`'s fields as numpy arrays, by the same names
(built from the dataclass, so that a new field reaches the kernels by its name)."""

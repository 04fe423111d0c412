"""Close pairs of points in linear memory: the torch twin of the kernels' grids of cells (:mod:`pedrl.sim.grid_kernel`),
for the placement of a crowd and the check of hand-placed bodies. Its specification is the ``(R, N, N)`` table of
squared gaps below a limit, and it returns exactly that table's true entries (the same float32 squared gaps), in
memory that grows with the crowd, not with its square (``tests/sim/test_pairs.py``).

The points are binned into square cells of side at least the limit (larger where the area is sparse, at most
:data:`CELLS_PER_POINT` cells a point), sorted by cell; each point's candidates are the points of the 3 x 3 cells
round its own, gathered cell row by cell row into ``(R N, M)`` blocks, ``M`` the fullest cell's count.
"""

from __future__ import annotations

import math
from typing import Final

import torch

__all__ = ["CELLS_PER_POINT", "DENSE_AGENTS", "close_pairs", "overlaps_earlier"]

DENSE_AGENTS: Final = 512
"""Crowds of fewer agents take the ``(R, N, N)`` table itself (faster there, the same pairs)."""
CELLS_PER_POINT: Final = 4
"""A grid gets at most this many cells per point (plus 64)."""
CELL_SCALE = 1.0
"""Cells are at least this times the limit: at 1 the 3 x 3 block round a point's cell holds everything within the
limit (the tests' control shrinks it)."""


def close_pairs(points: torch.Tensor, limit: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The pairs ``(r, i, j)``, ``j < i``, of ``points`` ``(R, N, 2)`` whose squared gap
    ``((p_i - p_j) ** 2).sum()`` (float32, as the table computes it) is below ``limit ** 2``; NaN points have none.
    Three int64 tensors, in no particular order."""
    num_replicas, num_agents, _ = points.shape
    if num_agents < DENSE_AGENTS:
        offsets = points.unsqueeze(2) - points.unsqueeze(1)
        close = ((offsets * offsets).sum(-1) < limit * limit).tril_(-1)
        return close.nonzero(as_tuple=True)
    finite = torch.isfinite(points).all(-1)  # (R, N)
    flat = points.reshape(-1, 2)
    safe = torch.where(finite.reshape(-1, 1), flat, 0.0)
    low = safe.amin(0)
    extent = (safe.amax(0) - low).clamp_min(0.0)
    size = max(limit * CELL_SCALE, 1e-6)
    area = float(extent[0] + size) * float(extent[1] + size)
    size = max(size, math.sqrt(area / (CELLS_PER_POINT * num_agents + 64)))
    nx, ny = (int(value) + 1 for value in (extent / size).tolist())
    cell = ((safe - low) / size).floor().long()
    cx, cy = cell[:, 0].clamp(0, nx - 1), cell[:, 1].clamp(0, ny - 1)
    replica = torch.arange(num_replicas, device=points.device).repeat_interleave(num_agents)
    key = (replica * ny + cy) * nx + cx
    key = torch.where(finite.reshape(-1), key, num_replicas * nx * ny)  # NaN points: a bin of their own, never read
    order = torch.argsort(key, stable=True)
    counts = torch.bincount(key, minlength=num_replicas * nx * ny + 1)
    starts = torch.cumsum(counts, 0) - counts
    rows, others = [], []
    for dy in (-1, 0, 1):
        row = cy + dy
        inside = (row >= 0) & (row < ny) & finite.reshape(-1)
        first_x, last_x = (cx - 1).clamp_min(0), (cx + 1).clamp_max(nx - 1)  # the row's cells, contiguous in key
        base = (replica * ny + row.clamp(0, ny - 1)) * nx
        begin = starts[base + first_x]
        count = torch.where(inside, starts[base + last_x] + counts[base + last_x] - begin, 0)
        most = int(count.max()) if count.numel() else 0
        if most == 0:
            continue
        slot = torch.arange(most, device=points.device)
        valid = slot < count.unsqueeze(1)  # (R N, M)
        other = order[(begin.unsqueeze(1) + slot).clamp_max(order.numel() - 1)]
        mover = torch.arange(flat.shape[0], device=points.device).unsqueeze(1).expand_as(other)
        valid &= other % num_agents < mover % num_agents
        rows.append(mover[valid])
        others.append(other[valid])
    if not rows:
        empty = torch.zeros(0, dtype=torch.long, device=points.device)
        return empty, empty, empty
    mover, other = torch.cat(rows), torch.cat(others)
    offsets = flat[mover] - flat[other]
    close = (offsets * offsets).sum(-1) < limit * limit
    mover, other = mover[close], other[close]
    return mover // num_agents, mover % num_agents, other % num_agents


def overlaps_earlier(points: torch.Tensor, limit: float) -> torch.Tensor:
    """``(R, N)`` bool: the point has an earlier-indexed one of its replica within ``limit`` (squared gap below
    ``limit ** 2``)."""
    replica, agent, _ = close_pairs(points, limit)
    out = torch.zeros(points.shape[:2], dtype=torch.bool, device=points.device)
    out[replica, agent] = True
    return out

"""Uniform grids of cells for the neighbour searches of the numba kernels: linear time in the crowd where every pair
would be quadratic. Its specification is the all-pairs loop each search replaces; a kernel that uses a grid returns
the all-pairs loop's numbers to the bit (``tests/sim/test_grid.py``), because

- a grid query returns every point within its reach (the cells cover the square around the query point, and the
  reach is the model's cut-off plus a slack of :data:`SLACK` m and :data:`RELATIVE_SLACK` of it, so float32 rounding
  of the cell index can only add candidates, never drop one);
- a sum over neighbours is taken over the candidates sorted by index (the all-pairs loop's order), and a nearest one
  is chosen by ``(squared distance, index)`` (the all-pairs loop's first minimum).

A grid spans the box of the points it holds; points outside are clamped to its border cells (the clamp is monotone
and moves a cell index by at most the query's clamp, so nothing within reach is lost). Wall segments are listed in
every cell within their reach (:func:`bin_segments`), so a room with thousands of segments costs per query what the
few segments near it cost.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from pedrl._numba import cached_njit

__all__ = [
    "RELATIVE_SLACK",
    "SLACK",
    "Cells",
    "bin_points",
    "bin_segments",
    "cell_range",
    "make_cells",
]

SLACK = np.float32(1e-3)
"""Absolute slack (m) added to every reach."""
RELATIVE_SLACK = np.float32(1e-4)
"""Relative slack added to every reach (float32 rounding of distances near the cut-off)."""
_MAX_CELLS_PER_POINT = 4
"""A grid gets at most this many cells per point (plus 64): larger cells than the reach where the crowd is sparse."""


class Cells(NamedTuple):
    """A uniform grid: the items of cell ``c`` are ``items[start[c]:start[c + 1]]``, ascending. A cell's index is
    ``cy * nx + cx``."""

    box: np.ndarray
    """``(3,)`` float32: the origin ``x0, y0`` (m) and one over the cell size (1/m)."""
    shape: np.ndarray
    """``(2,)`` int64: ``nx, ny``."""
    start: np.ndarray
    """``(nx * ny + 1,)`` int64."""
    items: np.ndarray
    """int64, the items cell by cell."""
    fill: np.ndarray
    """``(nx * ny,)`` int64 scratch of the binning."""


@cached_njit(nogil=True)
def make_cells(low_x, low_y, high_x, high_y, size, capacity, max_points):
    """An empty grid over the box ``[low, high]`` with cells of ``size`` m (larger if the box would need more than
    :data:`_MAX_CELLS_PER_POINT` cells per point of ``max_points``), room for ``capacity`` items."""
    width = max(high_x - low_x, np.float32(0.0))
    height = max(high_y - low_y, np.float32(0.0))
    size = max(size, np.float32(1e-3))
    limit = _MAX_CELLS_PER_POINT * max_points + 64
    while (int(width / size) + 1) * (int(height / size) + 1) > limit:
        size = size * np.float32(1.25)
    nx = int(width / size) + 1
    ny = int(height / size) + 1
    box = np.empty(3, np.float32)
    box[0], box[1], box[2] = low_x, low_y, np.float32(1.0) / size
    shape = np.empty(2, np.int64)
    shape[0], shape[1] = nx, ny
    return Cells(box, shape, np.zeros(nx * ny + 1, np.int64), np.empty(capacity, np.int64), np.empty(nx * ny, np.int64))


@cached_njit(nogil=True, inline="always")
def _cell(value, origin, inverse, count):
    """The cell index along one axis of ``value``, clamped to ``[0, count)``."""
    index = int(max(np.float32((value - origin) * inverse), np.float32(-1.0)))
    return min(max(index, 0), count - 1)


@cached_njit(nogil=True, inline="always")
def cell_range(cells, x, y, reach):
    """``(x0, x1, y0, y1)``: the cells (inclusive) that hold every point within ``reach`` of ``(x, y)``."""
    box, nx, ny = cells.box, cells.shape[0], cells.shape[1]
    return (
        _cell(x - reach, box[0], box[2], nx),
        _cell(x + reach, box[0], box[2], nx),
        _cell(y - reach, box[1], box[2], ny),
        _cell(y + reach, box[1], box[2], ny),
    )


@cached_njit(nogil=True)
def bin_points(cells, points, use):
    """Put each point ``i`` with ``use[i]`` (``points`` ``(N, 2)``) into its cell, ascending within each cell (a
    counting sort)."""
    box, nx, ny, start, items, fill = cells.box, cells.shape[0], cells.shape[1], cells.start, cells.items, cells.fill
    start[:] = 0
    for i in range(points.shape[0]):
        if use[i]:
            c = _cell(points[i, 1], box[1], box[2], ny) * nx + _cell(points[i, 0], box[0], box[2], nx)
            start[c + 1] += 1
    for c in range(nx * ny):
        start[c + 1] += start[c]
        fill[c] = start[c]
    for i in range(points.shape[0]):
        if use[i]:
            c = _cell(points[i, 1], box[1], box[2], ny) * nx + _cell(points[i, 0], box[0], box[2], nx)
            items[fill[c]] = i
            fill[c] += 1


@cached_njit(nogil=True, inline="always")
def _segment_near(cells, s, cx, cy, starts, directions, inverse, reach):
    """Whether segment ``s`` may come within ``reach`` of a point of cell ``(cx, cy)`` (conservative: its distance to
    the cell's centre against ``reach`` plus half the cell's diagonal)."""
    size = np.float32(1.0) / cells.box[2]
    x = cells.box[0] + (np.float32(cx) + np.float32(0.5)) * size
    y = cells.box[1] + (np.float32(cy) + np.float32(0.5)) * size
    along = ((x - starts[s, 0]) * directions[s, 0] + (y - starts[s, 1]) * directions[s, 1]) * inverse[s]
    along = min(max(along, np.float32(0.0)), np.float32(1.0))
    gap_x = x - (starts[s, 0] + along * directions[s, 0])
    gap_y = y - (starts[s, 1] + along * directions[s, 1])
    limit = reach + size * np.float32(0.7072)
    return gap_x * gap_x + gap_y * gap_y <= limit * limit


@cached_njit(nogil=True)
def bin_segments(cells, starts, directions, inverse, reach):
    """A grid of the same cells listing, in each, every wall segment (ascending) that comes within ``reach`` of a point
    of that cell (and possibly a few more)."""
    nx, ny = cells.shape[0], cells.shape[1]
    walls = Cells(cells.box, cells.shape, np.zeros(nx * ny + 1, np.int64), np.empty(0, np.int64), cells.fill)
    for sweep in range(2):  # count, then fill
        if sweep == 1:
            for c in range(nx * ny):
                walls.start[c + 1] += walls.start[c]
                walls.fill[c] = walls.start[c]
            walls = Cells(cells.box, cells.shape, walls.start, np.empty(walls.start[nx * ny], np.int64), walls.fill)
        for s in range(starts.shape[0]):
            end_x = starts[s, 0] + directions[s, 0]
            end_y = starts[s, 1] + directions[s, 1]
            x0, _, y0, _ = cell_range(cells, min(starts[s, 0], end_x), min(starts[s, 1], end_y), reach)
            _, x1, _, y1 = cell_range(cells, max(starts[s, 0], end_x), max(starts[s, 1], end_y), reach)
            for cy in range(y0, y1 + 1):
                for cx in range(x0, x1 + 1):
                    if _segment_near(cells, s, cx, cy, starts, directions, inverse, reach):
                        c = cy * nx + cx
                        if sweep == 0:
                            walls.start[c + 1] += 1
                        else:
                            walls.items[walls.fill[c]] = s
                            walls.fill[c] += 1
    return walls

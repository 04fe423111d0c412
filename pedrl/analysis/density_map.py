"""Density maps (paper section 6, Figures 9-10): how many agent centres fell in each tile of the room.

The bounding box of the area (``[0, width] x [0, length]`` for the paper's room) is tiled with squares of side
``tile_size``; the last column and row are narrower when it is not a whole number of tiles. Every active
agent-frame whose centre is inside the area (``AreaGeometry.contains``: agents that have passed an exit are
outside) adds 1 to its tile, over all frames of all trials. A tile's count is thus in agent-frames: divide by the
total number of frames for the mean occupancy.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pedrl.analysis.trajectories import Geometry, Trajectories, X, Y


@dataclass(frozen=True, eq=False)
class DensityMap:
    """A histogram of agent centres over the tiles of the room.

    Attributes:
        counts: ``(nx, ny)`` int64 agent-frames per tile; ``counts[i, j]`` covers
            ``x_edges[i] <= x < x_edges[i + 1]`` and ``y_edges[j] <= y < y_edges[j + 1]`` (the last column
            also holds ``x = width``).
        x_edges: ``(nx + 1,)`` tile boundaries along x (m), from 0 to width.
        y_edges: ``(ny + 1,)`` tile boundaries along y (m), from 0 to length.
        tile_size: nominal tile side (m).
        num_frames: frames summed over all trials (for the mean occupancy ``counts / num_frames``).
    """

    counts: NDArray[np.int64]
    x_edges: NDArray[np.float64]
    y_edges: NDArray[np.float64]
    tile_size: float
    num_frames: int

    def __post_init__(self) -> None:
        expected = (len(self.x_edges) - 1, len(self.y_edges) - 1)
        if self.counts.shape != expected:
            raise ValueError(f"counts must have shape {expected} from the edges, got {self.counts.shape}")

    @property
    def total(self) -> int:
        """Number of agent-frames counted (the sum of ``counts``)."""
        return int(self.counts.sum())

    def save(self, path: str | Path) -> Path:
        """Write the map as a ``.npz`` archive (``np.load`` or :func:`load_density_map` reads it)."""
        path = Path(path)
        with path.open("wb") as file:
            np.savez(
                file,
                counts=self.counts,
                x_edges=self.x_edges,
                y_edges=self.y_edges,
                tile_size=self.tile_size,
                num_frames=self.num_frames,
            )
        return path


def load_density_map(path: str | Path) -> DensityMap:
    """Read a map written by :meth:`DensityMap.save`."""
    with np.load(Path(path)) as archive:
        return DensityMap(
            counts=archive["counts"].astype(np.int64),
            x_edges=archive["x_edges"],
            y_edges=archive["y_edges"],
            tile_size=float(archive["tile_size"]),
            num_frames=int(archive["num_frames"]),
        )


def compute_tile_edges(extent: float, tile_size: float) -> NDArray[np.float64]:
    """Tile boundaries ``0, s, 2s, ..., extent`` (m); the last tile is narrower if ``s`` does not divide."""
    # The tolerance keeps 1.0 / 0.1 = 10.000000000000002 at 10 tiles.
    num_tiles = max(1, int(np.ceil(extent / tile_size - 1e-9)))
    return np.minimum(np.arange(num_tiles + 1) * tile_size, extent)


def compute_density_map(
    trajectories_list: Sequence[Trajectories] | Trajectories, *, tile_size: float, geometry: Geometry
) -> DensityMap:
    """Count the active agent centres inside the room per tile, over all frames and trials.

    Args:
        trajectories_list: the trials (or a single trial).
        tile_size: tile side (m), > 0.
        geometry: the room that is tiled.

    Returns:
        The density map; ``counts.sum()`` equals the number of active agent-frames inside the room.
    """
    if not tile_size > 0:
        raise ValueError(f"tile_size must be positive, got {tile_size}")
    if isinstance(trajectories_list, Trajectories):
        trajectories_list = [trajectories_list]
    x_edges = geometry.x_min + compute_tile_edges(geometry.width, tile_size)
    y_edges = geometry.y_min + compute_tile_edges(geometry.length, tile_size)
    counts = np.zeros((len(x_edges) - 1, len(y_edges) - 1), dtype=np.int64)
    num_frames = 0
    for trajectories in trajectories_list:
        centres = trajectories.positions[trajectories.active]
        centres = centres[geometry.contains(centres)]
        tile_counts, _, _ = np.histogram2d(centres[:, X], centres[:, Y], bins=(x_edges, y_edges))
        counts += tile_counts.astype(np.int64)
        num_frames += trajectories.num_frames
    return DensityMap(
        counts=counts, x_edges=x_edges, y_edges=y_edges, tile_size=float(tile_size), num_frames=num_frames
    )

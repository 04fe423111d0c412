"""Room geometry and recorded trajectories: the only input of :mod:`pedrl.analysis`.

The analysis never imports :mod:`pedrl.sim`. It takes a plain view of the area a trial ran in, an
:class:`AreaGeometry` (numpy arrays and WKT text), which the side that built the simulation's geometry builds from
it (:meth:`pedrl.scenarios.Scenario.analysis_geometry`), and the recorded states as :class:`Trajectories` (numpy
arrays, float32 or 64), one run of a :class:`~pedrl.common.recording.Recording` each.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from numbers import Integral
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pedrl.common.recording import Recording

X: Final = 0
Y: Final = 1

DEFAULT_EXIT_DEPTH: Final = 2.5
"""Depth (m) of the apron beyond each exit that :meth:`AreaGeometry.to_wkt` adds to the walkable area.

An agent is terminated on the decision its centre passes an exit; with the default speed limit (2.5 m/s) and
decision length (1 s) its last position lies at most 2.5 m beyond the exit line.
"""


@dataclass(frozen=True, eq=False)
class AreaGeometry:
    """A plain view of a walkable area, what every analysis takes: its polygon, its walls and its exits (m).

    Built from the simulation's geometry by the scenario that built it
    (:meth:`pedrl.scenarios.Scenario.analysis_geometry`); :class:`RoomGeometry` is the paper's rectangle, built from
    its three sizes. The "door" of the paper's analyses (density map, measurement point) is the first exit.

    Attributes:
        wkt: The walkable polygon as WKT (holes allowed), without aprons.
        walls: ``(S, 2, 2)`` wall segments (m), float64.
        exits: ``(E, 2, 2)`` exit segments (m), float64.
        exit_normals: ``(E, 2)`` unit vectors out of the area through each exit.
        name: The scenario's name (a label).
        bounds: ``(x_min, y_min, x_max, y_max)`` of the walkable polygon (m), derived from ``wkt``.
    """

    wkt: str
    walls: NDArray[np.float64]
    exits: NDArray[np.float64]
    exit_normals: NDArray[np.float64]
    name: str = "custom"
    bounds: tuple[float, float, float, float] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        import shapely

        polygon = shapely.from_wkt(self.wkt)
        object.__setattr__(self, "_polygon", polygon)
        object.__setattr__(self, "bounds", tuple(float(v) for v in polygon.bounds))
        self._set_segments(self.walls, self.exits, self.exit_normals)

    def _set_segments(self, walls: ArrayLike, exits: ArrayLike, exit_normals: ArrayLike) -> None:
        object.__setattr__(self, "walls", np.asarray(walls, dtype=np.float64).reshape(-1, 2, 2))
        object.__setattr__(self, "exits", np.asarray(exits, dtype=np.float64).reshape(-1, 2, 2))
        object.__setattr__(self, "exit_normals", np.asarray(exit_normals, dtype=np.float64).reshape(-1, 2))

    @property
    def x_min(self) -> float:
        """Left edge of the area (m)."""
        return self.bounds[0]

    @property
    def y_min(self) -> float:
        """Bottom edge of the area (m)."""
        return self.bounds[1]

    @property
    def width(self) -> float:
        """Extent along x (m)."""
        return self.bounds[2] - self.bounds[0]

    @property
    def length(self) -> float:
        """Extent along y (m)."""
        return self.bounds[3] - self.bounds[1]

    @property
    def door(self) -> NDArray[np.float64]:
        """The first exit ``(2, 2)`` (m)."""
        return self.exits[0]

    @property
    def door_center(self) -> NDArray[np.float64]:
        """Centre of the first exit ``(2,)`` (m)."""
        return self.exits[0].mean(axis=0)

    @property
    def door_normal(self) -> NDArray[np.float64]:
        """Unit vector out of the area through the first exit ``(2,)``."""
        return self.exit_normals[0]

    def describe(self) -> str:
        """One line naming the area, for file headers."""
        x_min, y_min, x_max, y_max = self.bounds
        return f"area: {self.name}, bounds [{x_min:g}, {y_min:g}] x [{x_max:g}, {y_max:g}], {len(self.exits)} exits"

    def contains(self, points: ArrayLike) -> NDArray[np.bool_]:
        """Which points lie in the walkable area (agents past an exit are outside), ``(...)`` bool."""
        import shapely

        p = np.asarray(points, dtype=np.float64)
        return shapely.contains_xy(self._polygon, p[..., X], p[..., Y])

    def to_wkt(self, *, exit_depth: float = DEFAULT_EXIT_DEPTH) -> str:
        """The walkable area with an apron of ``exit_depth`` beyond each exit (the last positions of agents that just
        left), as WKT for ``pedpy.WalkableArea``."""
        import shapely
        from shapely.geometry import Polygon

        if exit_depth < 0:
            raise ValueError(f"exit_depth must be >= 0, got {exit_depth}")
        if exit_depth == 0:
            return self._polygon.wkt
        aprons = [
            Polygon([a, b, b + exit_depth * n, a + exit_depth * n])
            for (a, b), n in zip(self.exits, self.exit_normals, strict=True)
        ]
        return shapely.union_all([self._polygon, *aprons]).wkt


@dataclass(frozen=True, eq=False)
class RoomGeometry(AreaGeometry):
    """The paper's rectangle ``[0, width] x [0, length]`` with one door (docs/design.md, "The room"): an
    :class:`AreaGeometry` built from three sizes, without shapely.

    The door is a gap of ``door_width`` centred on the short side ``y = length``. Its walls, door and bounds are
    the :class:`AreaGeometry` attributes; it answers in closed form where a formula is exact (the door centre
    ``width / 2``), and writes its polygon with a door apron that flares at 45 degrees (:meth:`walkable_polygon`).

    Attributes:
        width: extent along x (m).
        length: extent along y (m).
        door_width: width of the gap in the wall ``y = length`` (m).
    """

    wkt: str = field(init=False, repr=False)
    walls: NDArray[np.float64] = field(init=False, repr=False)
    exits: NDArray[np.float64] = field(init=False, repr=False)
    exit_normals: NDArray[np.float64] = field(init=False, repr=False)
    name: str = field(default="paper_room", init=False, repr=False)
    width: float = 60.0
    length: float = 100.0
    door_width: float = 2.0

    def __post_init__(self) -> None:
        if not (self.width > 0 and self.length > 0):
            raise ValueError(f"room width and length must be positive, got {self.width} x {self.length}")
        if not 0 < self.door_width < self.width:
            raise ValueError(f"door_width must be in (0, width={self.width}), got {self.door_width}")
        w, l = self.width, self.length
        walls = [
            [[0.0, 0.0], [w, 0.0]],
            [[w, 0.0], [w, l]],
            [[w, l], [self.door_right, l]],
            [[self.door_left, l], [0.0, l]],
            [[0.0, l], [0.0, 0.0]],
        ]
        self._set_segments(walls, [[self.door_left, l], [self.door_right, l]], [[0.0, 1.0]])
        object.__setattr__(self, "bounds", (0.0, 0.0, w, l))
        object.__setattr__(self, "wkt", self.to_wkt(exit_depth=0.0))

    @property
    def door_left(self) -> float:
        """x of the left door post (m)."""
        return self.width / 2 - self.door_width / 2

    @property
    def door_right(self) -> float:
        """x of the right door post (m)."""
        return self.width / 2 + self.door_width / 2

    @property
    def door_center(self) -> NDArray[np.float64]:
        """The goal point ``(width / 2, length)`` (m), shape ``(2,)``."""
        return np.array([self.width / 2, self.length])

    def describe(self) -> str:
        """One line naming the room, for file headers."""
        return f"room: width {self.width!r}, length {self.length!r}, door_width {self.door_width!r}"

    def contains(self, points: ArrayLike) -> NDArray[np.bool_]:
        """Which points lie in the room: ``0 <= x <= width`` and ``0 <= y < length``.

        A centre at ``y >= length`` has passed the door (docs/design.md) and is outside.

        Args:
            points: ``(..., 2)`` positions (m).

        Returns:
            ``(...)`` bool.
        """
        p = np.asarray(points)
        x, y = p[..., X], p[..., Y]
        return (x >= 0) & (x <= self.width) & (y >= 0) & (y < self.length)

    def walkable_polygon(self, *, exit_depth: float = DEFAULT_EXIT_DEPTH) -> NDArray[np.float64]:
        """Outline of the walkable area, counter-clockwise and closed (first vertex repeated), ``(V, 2)``, m.

        The room rectangle is opened at the door onto an apron outside it: a trapezoid of depth
        ``exit_depth`` whose sides flare at 45 degrees from the door posts, so that the last position of an
        agent that has just walked through the door is still inside the walkable area. ``exit_depth = 0``
        gives the bare rectangle.
        """
        if exit_depth < 0:
            raise ValueError(f"exit_depth must be >= 0, got {exit_depth}")
        w, l, e = self.width, self.length, exit_depth
        outline = [(0.0, 0.0), (w, 0.0), (w, l)]
        if e > 0:
            outline += [(self.door_right, l), (self.door_right + e, l + e)]
            outline += [(self.door_left - e, l + e), (self.door_left, l)]
        outline += [(0.0, l), (0.0, 0.0)]
        return np.array(outline)

    def to_wkt(self, *, exit_depth: float = DEFAULT_EXIT_DEPTH) -> str:
        """The walkable area as a WKT ``POLYGON`` that ``pedpy.WalkableArea`` accepts (coordinates in m).

        See :meth:`walkable_polygon` for the shape (room plus an apron of ``exit_depth`` outside the door).
        """
        coords = ", ".join(f"{x!r} {y!r}" for x, y in self.walkable_polygon(exit_depth=exit_depth).tolist())
        return f"POLYGON (({coords}))"


Geometry = AreaGeometry
"""What the analysis functions take: any walkable area (the paper's room is a :class:`RoomGeometry`)."""


@dataclass(frozen=True)
class Trajectories:
    """The recorded states of one trial: one run of a :class:`~pedrl.common.recording.Recording` in the area it ran
    in (:meth:`of_run`), the measures' input.

    Frame ``t`` is the state after decision ``t`` (frame 0 is the initial state), so frames are
    ``1 / framerate`` seconds apart. ``active[t, n]`` says whether agent ``n`` is in the scene at frame ``t``;
    positions and velocities of inactive agent-frames are ignored by every analysis. A recorder should keep an
    agent active in the frame where it passes the door (its last position, ``y >= length``) so that door
    crossings appear in the exported data; :meth:`AreaGeometry.to_wkt` includes an apron beyond each exit for
    these positions.

    Attributes:
        positions: ``(T, N, 2)`` agent centres (m).
        velocities: ``(T, N, 2)`` agent velocities (m/s).
        active: ``(T, N)`` bool.
        framerate: frames per second (1/s); ``decisions_per_second`` of the simulation.
        geometry: the room the trial ran in.
    """

    positions: NDArray[np.floating]
    velocities: NDArray[np.floating]
    active: NDArray[np.bool_]
    framerate: float
    geometry: Geometry

    def __post_init__(self) -> None:
        positions = np.asarray(self.positions)
        velocities = np.asarray(self.velocities)
        active = np.asarray(self.active)
        if positions.ndim != 3 or positions.shape[-1] != 2:
            raise ValueError(f"positions must have shape (T, N, 2), got {positions.shape}")
        if not np.issubdtype(positions.dtype, np.floating):
            raise ValueError(f"positions must be floating point, got {positions.dtype}")
        if velocities.shape != positions.shape:
            raise ValueError(f"velocities must have the shape of positions {positions.shape}, got {velocities.shape}")
        if not np.issubdtype(velocities.dtype, np.floating):
            raise ValueError(f"velocities must be floating point, got {velocities.dtype}")
        if active.shape != positions.shape[:2]:
            raise ValueError(f"active must have shape (T, N) = {positions.shape[:2]}, got {active.shape}")
        if active.dtype != np.bool_:
            raise ValueError(f"active must be bool, got {active.dtype}")
        if not self.framerate > 0:
            raise ValueError(f"framerate must be positive, got {self.framerate}")
        if not isinstance(self.geometry, AreaGeometry):
            raise TypeError(f"geometry must be an AreaGeometry (or RoomGeometry), got {type(self.geometry).__name__}")
        if not (np.isfinite(positions[active]).all() and np.isfinite(velocities[active]).all()):
            raise ValueError("positions and velocities of active agents must be finite")
        object.__setattr__(self, "positions", positions)
        object.__setattr__(self, "velocities", velocities)
        object.__setattr__(self, "active", active)
        object.__setattr__(self, "framerate", float(self.framerate))

    @classmethod
    def of_run(cls, recording: Recording, index: int, geometry: Geometry) -> Trajectories:
        """Run ``index`` of ``recording`` in ``geometry``, its agents of each frame those of
        :meth:`~pedrl.common.recording.Recording.acted` (velocities 0 where the recording has none).

        Raises:
            ValueError: one line, for an ``index`` that names no run of ``recording`` (a negative one included: it
                would count from the end).
        """
        runs = recording.positions.shape[0]
        if isinstance(index, bool) or not isinstance(index, Integral) or not 0 <= index < runs:
            allowed = f"an integer in [0, {runs - 1}]" if runs else "none (the recording holds no run)"
            raise ValueError(
                f"index={index!r} is invalid: must be {allowed} (the recording holds {runs} run{'s' * (runs != 1)})"
            )
        velocities = recording.velocities if recording.velocities is not None else np.zeros_like(recording.positions)
        return cls(
            positions=recording.positions[index],
            velocities=velocities[index],
            active=recording.acted()[index],
            framerate=recording.frame_rate,
            geometry=geometry,
        )

    @property
    def num_frames(self) -> int:
        """T, the number of frames (decisions + 1 for the initial state)."""
        return self.positions.shape[0]

    @property
    def num_agents(self) -> int:
        """N, the number of agents."""
        return self.positions.shape[1]

    @property
    def speeds(self) -> NDArray[np.floating]:
        """``(T, N)`` speed ``|v|`` (m/s); also defined for inactive agent-frames."""
        return np.linalg.norm(self.velocities, axis=-1)

    @property
    def times(self) -> NDArray[np.float64]:
        """``(T,)`` time of each frame, ``t / framerate`` (s)."""
        return np.arange(self.num_frames) / self.framerate

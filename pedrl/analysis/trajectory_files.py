"""Export trajectories in the text format that PedPy reads (``pedpy.load_trajectory_from_txt``), and as JuPedSim's
SQLite trajectory files (:func:`write_jupedsim_sqlite`), which PedPy reads with their walkable area.

The format (PedPy's ``pedpy/io/ped_data_archive_loader.py``): ``#`` comment lines first, then one row per
agent and frame with whitespace-separated columns ``id frame x y``. PedPy takes the frame rate from the first
number on a comment line containing ``framerate``, and the unit from a comment line containing ``x/m``
(metres) or ``x/cm``. We write::

    # pedrl trajectories, one trial (PedPy text format)
    # framerate: 1.0
    # room: width 60.0, length 100.0, door_width 2.0
    # id frame x/m y/m
    0 0 12.5 3.25
    ...

Rows are sorted by frame, then id, and only active agent-frames are written: the writers write a trial as they are
given it. :func:`trajectories_for_export` makes a recorded trial what ``pedrl-eval`` and ``pedrl-validate`` write: a
walker that left stays :data:`FRAMES_PAST_EXIT` frames past its exit (PedPy counts a walker over a line only from a
movement into a frame that is not the walker's last), at a frame rate of choice (positions interpolated linearly
between the recorded frames). One file holds one trial: PedPy
treats a file as one experiment with one clock, and trials of ``pedrl`` all start at frame 0; use
:func:`write_pedpy_trajectories` to write a list of trials, one file each. Coordinates are written with enough
significant digits to read back bit-exactly in the dtype of the positions (9 for float32, 17 for float64).
"""

from __future__ import annotations

import hashlib
import sqlite3
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Final

import numpy as np
import shapely
from numpy.typing import NDArray

from pedrl.analysis.trajectories import DEFAULT_EXIT_DEPTH, Geometry, Trajectories, X, Y

ID_COL: Final = "id"
FRAME_COL: Final = "frame"
X_COL: Final = "x"
Y_COL: Final = "y"
FRAMERATE_KEY: Final = "framerate"

_SIGNIFICANT_DIGITS: Final = {np.dtype(np.float32): 9, np.dtype(np.float64): 17}

MAX_FRAMERATE: Final = 1e6
"""The export's frame rates lie below this (frames per second): a microsecond between frames, far finer than any
walker's motion, and a second of a trial at 100 walkers is then 100 million rows already."""
FRAMES_PAST_EXIT: Final = 2
"""Frames an exported walker that left is kept past its last recorded frame, held where it left (inside the exit's
apron of the written walkable area, at speed 0).

PedPy's crossing count (``pedpy.compute_n_t``, ``compute_crossing_frames``) reads a walker's movement into each frame
from the frame before, except into its last frame, where its adaptive border leaves a movement of length 0: a walker
whose rows end at the first frame past the exit line is never counted over it. One frame more is enough; the second
gives PedPy's speeds (a window of a frame each side) a frame past the line too."""


def trajectories_for_export(
    trajectories: Trajectories, *, framerate: float | None = None, frames_past_exit: int = FRAMES_PAST_EXIT
) -> Trajectories:
    """A recorded trial as the trajectory files hold it: resampled to ``framerate``, each walker that left kept
    ``frames_past_exit`` frames past its last frame.

    Export frame ``j`` is the state at ``j / framerate`` s: between two recorded frames (one per decision, or one every
    few decisions for a large crowd) a position is interpolated linearly and the velocity is the one of the recorded
    frame that ends the interval; a walker is in an export frame when it is in the recorded frames on both sides.
    The recorded frames themselves are kept exactly. A walker left when its last position lies outside the area
    (past an exit); it then stays ``frames_past_exit`` more export frames where it left, with velocity 0, and the trial
    grows by up to ``frames_past_exit`` frames at its end for a walker that left in its last frame. A walker still in
    the area at its last frame (the trial ended) is not extended.

    Args:
        trajectories: the recorded trial, ``(T, N, 2)`` positions.
        framerate: frames per second of the export (1/s), at least the trial's; None: the trial's own.
        frames_past_exit: frames a walker that left is kept past its last one (0: none).

    Returns:
        The trial to write, ``(T', N, 2)``, positions and velocities in their recorded dtype.

    Raises:
        ValueError: one line naming the bad argument.
    """
    if not isinstance(trajectories, Trajectories):
        raise TypeError(f"trajectories is a {type(trajectories).__name__}: must be pedrl.analysis.Trajectories")
    recorded = trajectories.framerate
    if framerate is None:
        framerate = recorded
    ok = not isinstance(framerate, bool) and isinstance(framerate, int | float)
    if not (ok and recorded <= framerate < MAX_FRAMERATE):
        raise ValueError(
            f"framerate={framerate!r} is invalid: must be a number of frames per second in [{recorded:g}, "
            f"{MAX_FRAMERATE:g}), at least the trial's {recorded:g} (fewer frames would skip recorded ones)"
        )
    if isinstance(frames_past_exit, bool) or not isinstance(frames_past_exit, int | np.integer):
        raise ValueError(f"frames_past_exit={frames_past_exit!r} is invalid: must be an integer >= 0")
    if frames_past_exit < 0:
        raise ValueError(f"frames_past_exit={frames_past_exit!r} is invalid: must be an integer >= 0")
    positions, velocities, active = trajectories.positions, trajectories.velocities, trajectories.active
    num_frames = trajectories.num_frames
    # Recorded frame of export frame j: j * recorded / framerate, split into a frame and a weight towards the next.
    ratio = float(framerate) / recorded
    count = int(np.floor((num_frames - 1) * ratio + 1e-9)) + 1
    where = np.arange(count) / ratio
    before = np.minimum(np.floor(where + 1e-9).astype(np.int64), num_frames - 1)
    weight = np.clip(where - before, 0.0, 1.0)
    weight[weight < 1e-9] = 0.0
    after = np.minimum(before + 1, num_frames - 1)
    between = weight > 0
    blend = weight[:, None, None]
    interpolated = (1.0 - blend) * positions[before] + blend * positions[after]
    out_positions = np.where(between[:, None, None], interpolated, positions[before]).astype(positions.dtype)
    out_velocities = np.where(between[:, None, None], velocities[after], velocities[before]).astype(velocities.dtype)
    out_active = active[before] & (~between[:, None] | active[after])
    # Walkers that left: their last position lies outside the area; they stay there frames_past_exit frames more.
    present = out_active.any(axis=0)
    last = count - 1 - np.argmax(out_active[::-1], axis=0)
    agents = np.flatnonzero(present)
    left = agents[~trajectories.geometry.contains(out_positions[last[agents], agents])]
    if frames_past_exit and left.size:
        extra = max(0, int(last[left].max()) + frames_past_exit + 1 - count)
        if extra:
            out_positions = np.concatenate([out_positions, np.repeat(out_positions[-1:], extra, axis=0)])
            out_velocities = np.concatenate([out_velocities, np.zeros_like(out_velocities[:extra])])
            out_active = np.concatenate([out_active, np.zeros((extra, trajectories.num_agents), dtype=bool)])
        for step in range(1, frames_past_exit + 1):
            frames = last[left] + step
            out_positions[frames, left] = out_positions[last[left], left]
            out_velocities[frames, left] = 0.0
            out_active[frames, left] = True
    return Trajectories(
        positions=out_positions,
        velocities=out_velocities,
        active=out_active,
        framerate=float(framerate),
        geometry=trajectories.geometry,
    )


def write_pedpy_trajectory(path: str | Path, trajectories: Trajectories, *, first_id: int = 0) -> Path:
    """Write one trial as a PedPy text trajectory file.

    Args:
        path: output file (its parent must exist).
        trajectories: the trial; agent ``n`` gets id ``first_id + n``, frame ``t`` is written as frame ``t``.
        first_id: id of agent 0.

    Returns:
        The path written.

    Raises:
        TypeError, ValueError: one line naming the bad argument, before anything is written.
    """
    path = _checked_writer_args(path, trajectories, first_id, DEFAULT_EXIT_DEPTH)
    frames, agents = np.nonzero(trajectories.active)  # row-major: sorted by frame, then agent
    xy = trajectories.positions[frames, agents]
    digits = _SIGNIFICANT_DIGITS.get(xy.dtype, 17)
    geometry = trajectories.geometry
    header = "\n".join(
        [
            "pedrl trajectories, one trial (PedPy text format)",
            f"{FRAMERATE_KEY}: {trajectories.framerate!r}",
            geometry.describe(),
            f"{ID_COL} {FRAME_COL} {X_COL}/m {Y_COL}/m",
        ]
    )
    rows = np.empty(len(frames), dtype=[("id", np.int64), ("frame", np.int64), ("x", xy.dtype), ("y", xy.dtype)])
    rows["id"] = agents + first_id
    rows["frame"] = frames
    rows["x"] = xy[:, X]
    rows["y"] = xy[:, Y]
    np.savetxt(path, rows, fmt=["%d", "%d", f"%.{digits}g", f"%.{digits}g"], header=header, comments="# ")
    return path


def write_pedpy_trajectories(
    directory: str | Path, trajectories_list: Sequence[Trajectories], *, stem: str = "trial"
) -> list[Path]:
    """Write each trial to its own PedPy file ``{directory}/{stem}_{i:04d}.txt`` (one file per trial).

    Returns:
        The paths written, in the order of ``trajectories_list``.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    return [
        write_pedpy_trajectory(directory / f"{stem}_{i:04d}.txt", trajectories)
        for i, trajectories in enumerate(trajectories_list)
    ]


def read_pedpy_trajectory(
    path: str | Path,
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64], float]:
    """Read a PedPy text trajectory file (as written by :func:`write_pedpy_trajectory`).

    The frame rate is parsed as PedPy does: the first number on a comment line containing ``framerate``.
    Coordinates are returned in metres (a ``x/cm`` header divides them by 100).

    Returns:
        ``(ids (M,), frames (M,), xy (M, 2) in m, framerate in 1/s)``.
    """
    path = Path(path)
    framerate: float | None = None
    centimetres = False
    with path.open(encoding="utf-8-sig") as lines:
        for line in lines:
            if not line.startswith("#"):
                break
            if FRAMERATE_KEY in line and framerate is None:
                framerate = _first_number(line)
            centimetres |= "x/cm" in line.lower()
    if framerate is None:
        raise ValueError(f"no '# {FRAMERATE_KEY}: F' comment line in {path}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # a trial with no active agent-frame has no rows
        table = np.loadtxt(path, comments="#", dtype=np.float64, ndmin=2)
    if table.size == 0:
        table = np.empty((0, 4))
    if table.shape[1] < 4:
        raise ValueError(f"expected at least 4 columns 'id frame x y' in {path}, got {table.shape[1]}")
    ids = table[:, 0].astype(np.int64)
    frames = table[:, 1].astype(np.int64)
    xy = table[:, 2:4] / (100.0 if centimetres else 1.0)
    return ids, frames, xy, framerate


def write_geometry_wkt(path: str | Path, geometry: Geometry, *, exit_depth: float = DEFAULT_EXIT_DEPTH) -> Path:
    """Write the walkable area as WKT text (``pedpy.WalkableArea(path.read_text())`` loads it).

    See :meth:`AreaGeometry.to_wkt` for the polygon (the area plus an apron of ``exit_depth`` m beyond each exit;
    :meth:`RoomGeometry.walkable_polygon` for the paper's room).
    """
    path = Path(path)
    path.write_text(geometry.to_wkt(exit_depth=exit_depth) + "\n", encoding="utf-8")
    return path


JUPEDSIM_SQLITE_VERSION: Final = 2
"""The schema of JuPedSim's SQLite trajectory files that :func:`write_jupedsim_sqlite` writes: the one JuPedSim 1.x
writes (``jupedsim.sqlite_serialization``) and PedPy 1.5 reads with its walkable area."""


def write_jupedsim_sqlite(
    path: str | Path, trajectories: Trajectories, *, first_id: int = 0, exit_depth: float = DEFAULT_EXIT_DEPTH
) -> Path:
    """Write one trial as a JuPedSim SQLite trajectory file (schema version 2), with the room's walkable area.

    ``pedpy.load_trajectory_from_jupedsim_sqlite`` and ``pedpy.load_walkable_area_from_jupedsim_sqlite`` read it back,
    and JuPedSim's viewer opens it. Tables: ``trajectory_data (frame, id, pos_x, pos_y, ori_x, ori_y)`` (active
    agent-frames; the orientation is the unit velocity, ``(0, 0)`` for a body at rest), ``metadata`` (``version`` 2,
    ``fps``, the area's bounds ``xmin`` .. ``ymax``), ``geometry (hash, wkt)`` (the area plus an apron of ``exit_depth``
    m beyond each exit, as :func:`write_geometry_wkt`) and ``frame_data (frame, geometry_hash)``. The file is written
    beside its destination and moved into place, so a reader never sees half of it.

    Args:
        path: output file (its parent must exist); replaced if it exists.
        trajectories: the trial; agent ``n`` gets id ``first_id + n``.
        first_id: id of agent 0.
        exit_depth: the apron beyond each exit (m).

    Returns:
        The path written.

    Raises:
        TypeError, ValueError: one line naming the bad argument, before anything is written.
        OSError: the file cannot be written (no partial file is left behind).
    """
    path = _checked_writer_args(path, trajectories, first_id, exit_depth)
    frames, agents = np.nonzero(trajectories.active)
    xy = trajectories.positions[frames, agents].astype(np.float64)
    velocity = trajectories.velocities[frames, agents].astype(np.float64)
    norm = np.hypot(velocity[:, X], velocity[:, Y])
    orientation = np.divide(velocity, norm[:, None], out=np.zeros_like(velocity), where=norm[:, None] > 0)
    wkt = trajectories.geometry.to_wkt(exit_depth=exit_depth)
    geometry_hash = int.from_bytes(hashlib.sha1(wkt.encode()).digest()[:7], "big")  # a stable 56-bit key
    xmin, ymin, xmax, ymax = shapely.from_wkt(wkt).bounds
    rows = zip(
        frames.tolist(), (agents + first_id).tolist(), xy[:, X].tolist(), xy[:, Y].tolist(),
        orientation[:, X].tolist(), orientation[:, Y].tolist(), strict=True,
    )  # fmt: skip
    partial = path.with_name(f".{path.name}.partial")
    partial.unlink(missing_ok=True)
    connection = sqlite3.connect(partial)
    written = False
    try:
        with connection:
            connection.execute(
                "CREATE TABLE trajectory_data (frame INTEGER NOT NULL, id INTEGER NOT NULL, pos_x REAL NOT NULL,"
                " pos_y REAL NOT NULL, ori_x REAL NOT NULL, ori_y REAL NOT NULL)"
            )
            connection.execute("CREATE TABLE metadata(key TEXT NOT NULL UNIQUE PRIMARY KEY, value TEXT NOT NULL)")
            connection.executemany(
                "INSERT INTO metadata VALUES(?, ?)",
                [("version", str(JUPEDSIM_SQLITE_VERSION)), ("fps", repr(float(trajectories.framerate))),
                 ("xmin", repr(xmin)), ("xmax", repr(xmax)), ("ymin", repr(ymin)), ("ymax", repr(ymax))],
            )  # fmt: skip
            connection.execute("CREATE TABLE geometry(hash INTEGER NOT NULL, wkt TEXT NOT NULL)")
            connection.execute("CREATE UNIQUE INDEX geometry_hash on geometry(hash)")
            connection.execute("INSERT INTO geometry VALUES(?, ?)", (geometry_hash, wkt))
            connection.execute("CREATE TABLE frame_data(frame INTEGER NOT NULL, geometry_hash INTEGER NOT NULL)")
            connection.executemany(
                "INSERT INTO frame_data VALUES(?, ?)",
                [(frame, geometry_hash) for frame in range(trajectories.active.shape[0])],
            )
            connection.executemany("INSERT INTO trajectory_data VALUES(?, ?, ?, ?, ?, ?)", rows)
            connection.execute("CREATE INDEX frame_id_idx ON trajectory_data(frame, id)")
        written = True
    finally:
        connection.close()
        if not written:
            partial.unlink(missing_ok=True)
    partial.replace(path)
    return path


def _checked_writer_args(path: str | Path, trajectories: Trajectories, first_id: int, exit_depth: float) -> Path:
    """``path`` as a ``Path`` once a trajectory writer's arguments are checked (one-line errors)."""
    if not isinstance(trajectories, Trajectories):
        raise TypeError(f"trajectories is a {type(trajectories).__name__}: must be pedrl.analysis.Trajectories")
    if isinstance(first_id, bool) or not isinstance(first_id, int | np.integer) or not 0 <= first_id < 2**62:
        raise ValueError(f"first_id={first_id!r} is invalid: must be an integer in [0, 2**62)")
    if isinstance(exit_depth, bool) or not isinstance(exit_depth, int | float) or not 0 <= exit_depth <= 1e3:
        raise ValueError(f"exit_depth={exit_depth!r} is invalid: must be a number of metres in [0, 1000]")
    if not np.isfinite(trajectories.framerate):
        raise ValueError(f"trajectories.framerate={trajectories.framerate!r} is invalid: must be finite and > 0")
    path = Path(path)
    if not path.parent.is_dir():
        raise ValueError(f"path={str(path)!r} is invalid: its folder {str(path.parent)!r} does not exist")
    if path.is_dir():
        raise ValueError(f"path={str(path)!r} is invalid: it is a folder, not a file")
    return path


def _first_number(line: str) -> float | None:
    for token in line.split():
        try:
            return float(token)
        except ValueError:
            continue
    return None

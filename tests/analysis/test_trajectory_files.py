import re
import sqlite3
from pathlib import Path

import numpy as np
import pytest

from pedrl.analysis import (
    FRAMES_PAST_EXIT,
    RoomGeometry,
    Trajectories,
    read_pedpy_trajectory,
    trajectories_for_export,
    write_geometry_wkt,
    write_jupedsim_sqlite,
    write_pedpy_trajectories,
    write_pedpy_trajectory,
)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_round_trip_is_exact(tmp_path, make_trial, dtype):
    trial = make_trial(num_agents=9, num_frames=20, dtype=dtype)
    path = write_pedpy_trajectory(tmp_path / "trial.txt", trial, first_id=100)
    ids, frames, xy, framerate = read_pedpy_trajectory(path)

    expected_frames, expected_agents = np.nonzero(trial.active)
    np.testing.assert_array_equal(ids, expected_agents + 100)
    np.testing.assert_array_equal(frames, expected_frames)
    np.testing.assert_array_equal(xy.astype(dtype), trial.positions[trial.active])
    assert framerate == trial.framerate
    assert len(ids) == trial.active.sum() < trial.active.size  # only active agent-frames


def test_header_format(tmp_path, make_trial):
    trial = make_trial()
    trial = Trajectories(
        positions=trial.positions,
        velocities=trial.velocities,
        active=trial.active,
        framerate=2.5,
        geometry=trial.geometry,
    )
    lines = write_pedpy_trajectory(tmp_path / "trial.txt", trial).read_text().splitlines()
    header = [line for line in lines if line.startswith("#")]
    assert lines[: len(header)] == header  # comments first
    assert "# framerate: 2.5" in header
    assert "# id frame x/m y/m" in header
    # PedPy takes the frame rate from the first number on a line containing "framerate": no other number.
    framerate_lines = [line for line in header if "framerate" in line]
    assert framerate_lines == ["# framerate: 2.5"]
    first_row = lines[len(header)].split()
    assert len(first_row) == 4 and first_row[0] == "0" and first_row[1] == "0"


def test_trial_without_active_agents(tmp_path):
    positions = np.zeros((3, 2, 2))
    trial = Trajectories(
        positions=positions,
        velocities=positions,
        active=np.zeros((3, 2), bool),
        framerate=1.0,
        geometry=RoomGeometry(),
    )
    ids, frames, xy, framerate = read_pedpy_trajectory(write_pedpy_trajectory(tmp_path / "empty.txt", trial))
    assert ids.shape == frames.shape == (0,) and xy.shape == (0, 2) and framerate == 1.0


def test_one_file_per_trial(tmp_path, make_trial):
    trials = [make_trial(seed=seed) for seed in range(3)]
    paths = write_pedpy_trajectories(tmp_path / "pedpy", trials)
    assert [p.name for p in paths] == ["trial_0000.txt", "trial_0001.txt", "trial_0002.txt"]
    for path, trial in zip(paths, trials, strict=True):
        _, _, xy, _ = read_pedpy_trajectory(path)
        np.testing.assert_array_equal(xy.astype(np.float32), trial.positions[trial.active])


def test_missing_framerate_is_an_error(tmp_path):
    path = tmp_path / "bad.txt"
    path.write_text("# id frame x/m y/m\n0 0 1.0 2.0\n")
    with pytest.raises(ValueError, match="framerate"):
        read_pedpy_trajectory(path)


def test_geometry_wkt_file(tmp_path):
    geometry = RoomGeometry(width=20.0, length=30.0, door_width=2.0)
    path = write_geometry_wkt(tmp_path / "room.wkt", geometry, exit_depth=1.5)
    assert path.read_text().strip() == geometry.to_wkt(exit_depth=1.5)


# PedPy, the reference tool (optional extra `pedrl[analysis]`).


def exit_trial() -> Trajectories:
    """Agents walking straight up through the door; each is kept active in the frame it passes the door."""
    geometry = RoomGeometry(width=20.0, length=30.0, door_width=2.0)
    num_frames, num_agents = 20, 6
    start = np.stack([np.linspace(9.3, 10.7, num_agents), np.linspace(12.0, 27.0, num_agents)], axis=-1)
    velocity = np.array([0.0, 2.5])
    t = np.arange(num_frames)[:, None, None]
    positions = start[None] + t * velocity
    passed = positions[..., 1] >= geometry.length
    first_passed = np.cumsum(passed, axis=0) == 1
    active = ~passed | (first_passed & passed)
    return Trajectories(
        positions=positions,
        velocities=np.broadcast_to(velocity, positions.shape).copy(),
        active=active,
        framerate=1.0,
        geometry=geometry,
    )


def test_pedpy_loads_the_file_unchanged(tmp_path: Path, make_trial):
    pedpy = pytest.importorskip("pedpy")
    trial = make_trial(num_agents=10, num_frames=20)
    path = write_pedpy_trajectory(tmp_path / "trial.txt", trial)
    traj_data = pedpy.load_trajectory_from_txt(trajectory_file=path)
    assert traj_data.frame_rate == trial.framerate
    data = traj_data.data
    frames, agents = np.nonzero(trial.active)
    np.testing.assert_array_equal(data["id"].to_numpy(), agents)
    np.testing.assert_array_equal(data["frame"].to_numpy(), frames)
    np.testing.assert_array_equal(data["x"].to_numpy().astype(np.float32), trial.positions[trial.active][:, 0])
    np.testing.assert_array_equal(data["y"].to_numpy().astype(np.float32), trial.positions[trial.active][:, 1])


def test_pedpy_accepts_the_walkable_area_with_the_exit_frames(tmp_path: Path):
    pedpy = pytest.importorskip("pedpy")
    trial = exit_trial()
    assert (trial.positions[trial.active][:, 1] >= trial.geometry.length).sum() == trial.num_agents
    walkable_area = pedpy.WalkableArea(write_geometry_wkt(tmp_path / "room.wkt", trial.geometry).read_text())
    expected_area = 20.0 * 30.0 + (2.0 + 2.0 + 2 * 2.5) / 2 * 2.5
    assert walkable_area.area == pytest.approx(expected_area)
    traj_data = pedpy.load_trajectory_from_txt(trajectory_file=write_pedpy_trajectory(tmp_path / "t.txt", trial))
    assert pedpy.is_trajectory_valid(traj_data=traj_data, walkable_area=walkable_area)
    # Without the apron the exit frames fall outside the room.
    bare = pedpy.WalkableArea(trial.geometry.to_wkt(exit_depth=0.0))
    assert not pedpy.is_trajectory_valid(traj_data=traj_data, walkable_area=bare)


def test_pedpy_classic_density_equals_our_count(tmp_path: Path, make_trial):
    pedpy = pytest.importorskip("pedpy")
    trial = make_trial(num_agents=40, num_frames=25)
    traj_data = pedpy.load_trajectory_from_txt(trajectory_file=write_pedpy_trajectory(tmp_path / "t.txt", trial))
    x_min, y_min, x_max, y_max = 6.0, 18.0, 14.0, 28.0
    area = pedpy.MeasurementArea([(x_min, y_min), (x_max, y_min), (x_max, y_max), (x_min, y_max)])
    classic = pedpy.compute_classic_density(traj_data=traj_data, measurement_area=area)

    x, y = trial.positions[..., 0], trial.positions[..., 1]
    inside = trial.active & (x > x_min) & (x < x_max) & (y > y_min) & (y < y_max)
    ours = inside.sum(axis=1) / ((x_max - x_min) * (y_max - y_min))
    frames = classic["frame"].to_numpy()
    np.testing.assert_array_equal(frames, np.arange(frames.min(), frames.max() + 1))
    assert ours[frames].max() > 0
    np.testing.assert_allclose(classic["density"].to_numpy(), ours[frames], rtol=1e-12)


# JuPedSim's SQLite trajectory files: PedPy reads the trajectories and the walkable area back.


def test_pedpy_reads_the_jupedsim_sqlite_file_with_its_walkable_area(tmp_path: Path):
    pedpy = pytest.importorskip("pedpy")
    trial = exit_trial()
    path = write_jupedsim_sqlite(tmp_path / "trial.sqlite", trial, first_id=7)
    traj_data = pedpy.load_trajectory_from_jupedsim_sqlite(trajectory_file=path)
    assert traj_data.frame_rate == trial.framerate
    frames, agents = np.nonzero(trial.active)
    data = traj_data.data.sort_values(["frame", "id"])
    np.testing.assert_array_equal(data["frame"].to_numpy(), frames)
    np.testing.assert_array_equal(data["id"].to_numpy(), agents + 7)
    np.testing.assert_array_equal(data["x"].to_numpy(), trial.positions[trial.active][:, 0])
    np.testing.assert_array_equal(data["y"].to_numpy(), trial.positions[trial.active][:, 1])
    walkable_area = pedpy.load_walkable_area_from_jupedsim_sqlite(trajectory_file=path)
    assert walkable_area.polygon.equals(pedpy.WalkableArea(trial.geometry.to_wkt()).polygon)
    assert pedpy.is_trajectory_valid(traj_data=traj_data, walkable_area=walkable_area)  # the exit frames included


def test_the_jupedsim_sqlite_file_has_jupedsims_schema_and_replaces_an_old_one(tmp_path: Path):
    import sqlite3

    trial = exit_trial()
    path = tmp_path / "trial.sqlite"
    path.write_text("an older file")
    write_jupedsim_sqlite(path, trial)
    with sqlite3.connect(path) as connection:
        tables = {row[0] for row in connection.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        metadata = dict(connection.execute("SELECT key, value FROM metadata"))
        orientation = connection.execute("SELECT ori_x, ori_y FROM trajectory_data LIMIT 1").fetchone()
        frames = connection.execute("SELECT COUNT(*) FROM frame_data").fetchone()[0]
    assert tables == {"trajectory_data", "metadata", "geometry", "frame_data"}
    assert metadata["version"] == "2" and float(metadata["fps"]) == trial.framerate
    assert orientation == (0.0, 1.0)  # the unit velocity
    assert frames == trial.active.shape[0]
    assert list(tmp_path.iterdir()) == [path]  # no partial file left


def test_jupedsims_own_reader_opens_the_file_as_its_viewer_does(tmp_path: Path):
    """``jupedsim.Recording`` is what JuPedSim's viewer (``jupedsim-visualizer``) reads files with."""
    jupedsim = pytest.importorskip("jupedsim")
    trial = exit_trial()
    recording = jupedsim.Recording(str(write_jupedsim_sqlite(tmp_path / "trial.sqlite", trial)))
    assert recording.num_frames == trial.active.shape[0] and recording.fps == trial.framerate
    assert recording.geometry().area == pytest.approx(20.0 * 30.0 + (2.0 + 2.0 + 2 * 2.5) / 2 * 2.5)  # with the apron
    first = recording.frame(0)
    assert sorted(agent.id for agent in first.agents) == list(np.nonzero(trial.active[0])[0])


@pytest.mark.parametrize(
    ("target", "kwargs", "message"),
    [
        ("trial.sqlite", {"first_id": -1}, "first_id=-1 is invalid"),
        ("trial.sqlite", {"first_id": 1.5}, "first_id=1.5 is invalid"),
        ("trial.sqlite", {"exit_depth": float("nan")}, "exit_depth=nan is invalid"),
        ("missing/trial.sqlite", {}, "does not exist"),
        (".", {}, "it is a folder"),
    ],
)
def test_the_sqlite_writer_refuses_bad_arguments_in_one_line_before_writing(tmp_path: Path, target, kwargs, message):
    with pytest.raises(ValueError, match=message) as error:
        write_jupedsim_sqlite(tmp_path / target, exit_trial(), **kwargs)
    assert "\n" not in str(error.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # nothing written, no partial file
    with pytest.raises(TypeError, match="must be pedrl.analysis.Trajectories"):
        write_jupedsim_sqlite(tmp_path / "trial.sqlite", {"positions": []})


def test_a_failed_sqlite_write_leaves_no_partial_file_and_keeps_the_old_one(tmp_path: Path, monkeypatch):
    path = write_jupedsim_sqlite(tmp_path / "trial.sqlite", exit_trial())
    before = path.read_bytes()

    real_connect = sqlite3.connect

    class FullDisk:
        """A connection whose inserts fail as on a full disk."""

        def __init__(self, target):
            self.connection = real_connect(target)

        def __getattr__(self, name):
            return getattr(self.connection, name)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return self.connection.__exit__(*exc)

        def executemany(self, *args):
            raise sqlite3.OperationalError("database or disk is full")

    monkeypatch.setattr(sqlite3, "connect", FullDisk)
    with pytest.raises(sqlite3.OperationalError, match="disk is full"):
        write_jupedsim_sqlite(path, exit_trial())
    assert path.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["trial.sqlite"]


# What pedrl-eval and pedrl-validate write: every walker that left is counted over the exit line by PedPy.


def pedpy_passing_count(pedpy, path: Path, geometry: RoomGeometry) -> int:
    """PedPy's count of walkers over the door line of ``geometry``, from a JuPedSim SQLite file."""
    line = pedpy.MeasurementLine([(geometry.door_left, geometry.length), (geometry.door_right, geometry.length)])
    traj_data = pedpy.load_trajectory_from_jupedsim_sqlite(trajectory_file=path)
    n_t, crossing_frames = pedpy.compute_n_t(traj_data=traj_data, measurement_line=line)
    return len(crossing_frames)


def through_the_door(trial: Trajectories) -> list[int]:
    """The walkers whose last recorded step crosses the door line between the door posts."""
    geometry = trial.geometry
    walkers = []
    for agent in range(trial.num_agents):
        frame = np.flatnonzero(trial.active[:, agent])[-1]
        (x0, y0), (x1, y1) = trial.positions[frame - 1, agent], trial.positions[frame, agent]
        if y0 < geometry.length <= y1:
            x = x0 + (x1 - x0) * (geometry.length - y0) / (y1 - y0)
            walkers += [agent] if geometry.door_left <= x <= geometry.door_right else []
    return walkers


@pytest.mark.parametrize("framerate", [None, 4.0])
def test_pedpy_counts_every_walker_that_left_through_the_door(tmp_path: Path, make_trial, framerate):
    pedpy = pytest.importorskip("pedpy")
    trial = make_trial(num_agents=40, num_frames=80)  # 1 frame per decision; rows end at the first frame past the door
    walkers = through_the_door(trial)  # the synthetic walkers ignore walls: leave out one that cuts a corner
    trial = Trajectories(
        trial.positions[:, walkers], trial.velocities[:, walkers], trial.active[:, walkers], 1.0, trial.geometry
    )
    left = trial.num_agents
    assert left >= 35 and ((trial.positions[..., 1] >= trial.geometry.length)[trial.active]).sum() == left

    exported = trajectories_for_export(trial, framerate=framerate)
    path = write_jupedsim_sqlite(tmp_path / "exported.sqlite", exported)
    assert pedpy_passing_count(pedpy, path, trial.geometry) == left
    walkable_area = pedpy.load_walkable_area_from_jupedsim_sqlite(trajectory_file=path)
    traj_data = pedpy.load_trajectory_from_jupedsim_sqlite(trajectory_file=path)
    assert pedpy.is_trajectory_valid(traj_data=traj_data, walkable_area=walkable_area)  # held inside the apron
    assert traj_data.frame_rate == (framerate or 1.0)
    text = pedpy.load_trajectory_from_txt(trajectory_file=write_pedpy_trajectory(tmp_path / "t.txt", exported))
    assert len(text.data) == len(traj_data.data)

    # Control: the trial as recorded, rows ending at the first frame past the line, is counted short by PedPy.
    recorded = write_jupedsim_sqlite(tmp_path / "recorded.sqlite", trial)
    assert pedpy_passing_count(pedpy, recorded, trial.geometry) < left


def test_the_export_keeps_recorded_frames_interpolates_between_them_and_holds_walkers_past_the_exit(make_trial):
    trial = make_trial(num_agents=12, num_frames=40, dtype=np.float64)
    exported = trajectories_for_export(trial, framerate=4.0)
    assert exported.framerate == 4.0
    recorded_frames = exported.active[: 4 * trial.num_frames : 4]
    np.testing.assert_array_equal(
        exported.positions[::4][: trial.num_frames][trial.active], trial.positions[trial.active]
    )
    # a frame between two decisions lies on the straight line between them, with the velocity of the second
    both = trial.active[5] & trial.active[6]
    assert both.any()
    np.testing.assert_allclose(
        exported.positions[21][both], 0.75 * trial.positions[5][both] + 0.25 * trial.positions[6][both]
    )
    np.testing.assert_array_equal(exported.velocities[21][both], trial.velocities[6][both])
    # each walker's last recorded frame (past the door) is followed by FRAMES_PAST_EXIT frames held there, at rest
    last = trial.num_frames - 1 - np.argmax(trial.active[::-1], axis=0)
    for agent, frame in enumerate(last):
        rows = np.flatnonzero(exported.active[:, agent])
        assert rows[-1] == 4 * frame + FRAMES_PAST_EXIT
        held = exported.positions[4 * frame : rows[-1] + 1, agent]
        np.testing.assert_array_equal(held, np.broadcast_to(trial.positions[frame, agent], held.shape))
        assert not exported.velocities[4 * frame + 1 : rows[-1] + 1, agent].any()
    assert recorded_frames.sum() == trial.active.sum()
    # no frames past the exit asked for, at the recorded rate: the trial unchanged
    same = trajectories_for_export(trial, frames_past_exit=0)
    np.testing.assert_array_equal(same.active, trial.active)
    np.testing.assert_array_equal(same.positions[same.active], trial.positions[trial.active])


def test_a_walker_still_in_the_room_at_its_last_frame_is_not_held_on(make_trial):
    trial = make_trial(num_agents=12, num_frames=40)
    inside = trial.active & (trial.positions[..., 1] < trial.geometry.length)  # as if the trial had ended there
    trial = Trajectories(trial.positions, trial.velocities, inside, trial.framerate, trial.geometry)
    exported = trajectories_for_export(trial)
    np.testing.assert_array_equal(exported.active, trial.active)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (
            {"framerate": 0.5},
            "framerate=0.5 is invalid: must be a number of frames per second in [1, 1e+06), at least the trial's 1",
        ),
        ({"framerate": 1e6}, "framerate=1000000.0 is invalid: must be a number of frames per second in [1, 1e+06)"),
        ({"framerate": "4"}, "framerate='4' is invalid"),
        ({"frames_past_exit": -1}, "frames_past_exit=-1 is invalid"),
        ({"frames_past_exit": 1.5}, "frames_past_exit=1.5 is invalid"),
    ],
)
def test_the_export_refuses_bad_arguments_in_one_line(make_trial, kwargs, message):
    with pytest.raises(ValueError, match=re.escape(message)) as error:
        trajectories_for_export(make_trial(), **kwargs)
    assert "\n" not in str(error.value)

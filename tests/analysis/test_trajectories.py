import subprocess
import sys

import numpy as np
import pytest
import shapely

from pedrl.analysis import AreaGeometry, Recording, RoomGeometry, Trajectories


def shoelace_area(outline: np.ndarray) -> float:
    x, y = outline[:, 0], outline[:, 1]
    return 0.5 * float(np.sum(x[:-1] * y[1:] - x[1:] * y[:-1]))


def test_walls_follow_the_contract_order():
    geometry = RoomGeometry(width=60.0, length=100.0, door_width=2.0)
    expected = [
        [[0, 0], [60, 0]],
        [[60, 0], [60, 100]],
        [[60, 100], [31, 100]],
        [[29, 100], [0, 100]],
        [[0, 100], [0, 0]],
    ]
    np.testing.assert_array_equal(geometry.walls, expected)
    np.testing.assert_array_equal(geometry.door_center, [30.0, 100.0])
    np.testing.assert_array_equal(geometry.door, [[29.0, 100.0], [31.0, 100.0]])


def test_walkable_polygon_is_room_plus_flared_apron():
    geometry = RoomGeometry(width=20.0, length=30.0, door_width=2.0)
    bare = geometry.walkable_polygon(exit_depth=0.0)
    assert shoelace_area(bare) == pytest.approx(20.0 * 30.0)  # counter-clockwise: positive
    depth = 2.5
    outline = geometry.walkable_polygon(exit_depth=depth)
    apron = (2.0 + (2.0 + 2 * depth)) / 2 * depth
    assert shoelace_area(outline) == pytest.approx(20.0 * 30.0 + apron)
    np.testing.assert_array_equal(outline[0], outline[-1])
    # The boundary crosses y = length only at the door posts.
    on_top = outline[np.isclose(outline[:, 1], 30.0)]
    assert {9.0, 11.0} <= set(on_top[:, 0].tolist())


def test_to_wkt_lists_the_polygon():
    geometry = RoomGeometry(width=20.0, length=30.0, door_width=2.0)
    wkt = geometry.to_wkt(exit_depth=1.0)
    assert wkt.startswith("POLYGON ((") and wkt.endswith("))")
    pairs = [tuple(map(float, pair.split())) for pair in wkt[len("POLYGON ((") : -2].split(",")]
    np.testing.assert_array_equal(pairs, geometry.walkable_polygon(exit_depth=1.0))


def test_contains_excludes_agents_past_the_door():
    geometry = RoomGeometry(width=20.0, length=30.0, door_width=2.0)
    inside = geometry.contains([[0.0, 0.0], [20.0, 29.999], [10.0, 30.0], [-0.1, 5.0], [10.0, 31.0]])
    np.testing.assert_array_equal(inside, [True, True, False, False, False])


def test_room_is_the_area_view_of_its_rectangle():
    """The paper's room is an :class:`AreaGeometry`: its walls, door, normal and bounds are the general attributes."""
    geometry = RoomGeometry(width=20.0, length=30.0, door_width=2.0)
    assert isinstance(geometry, AreaGeometry) and geometry.name == "paper_room"
    assert geometry.bounds == (0.0, 0.0, 20.0, 30.0) and (geometry.x_min, geometry.y_min) == (0.0, 0.0)
    np.testing.assert_array_equal(geometry.exits, [geometry.door])
    np.testing.assert_array_equal(geometry.exit_normals, [[0.0, 1.0]])
    assert geometry.wkt == geometry.to_wkt(exit_depth=0.0)
    assert repr(geometry) == "RoomGeometry(width=20.0, length=30.0, door_width=2.0)"


def test_area_view_of_a_polygon_with_a_hole():
    geometry = AreaGeometry(
        wkt="POLYGON ((0 0, 12 0, 12 10, 0 10, 0 0), (5 4, 7 4, 7 6, 5 6, 5 4))",
        walls=np.zeros((9, 2, 2)),
        exits=[[[12.0, 6.0], [12.0, 4.0]]],
        exit_normals=[[1.0, 0.0]],
        name="custom",
    )
    assert geometry.bounds == (0.0, 0.0, 12.0, 10.0) and (geometry.width, geometry.length) == (12.0, 10.0)
    np.testing.assert_array_equal(geometry.door_center, [12.0, 5.0])
    np.testing.assert_array_equal(geometry.door_normal, [1.0, 0.0])
    np.testing.assert_array_equal(geometry.contains([[1.0, 1.0], [6.0, 5.0], [12.5, 5.0]]), [True, False, False])
    assert geometry.describe() == "area: custom, bounds [0, 0] x [12, 10], 1 exits"
    apron = shapely.from_wkt(geometry.to_wkt(exit_depth=1.5))
    assert apron.area == pytest.approx(12.0 * 10.0 - 4.0 + 2.0 * 1.5)
    assert shapely.from_wkt(geometry.to_wkt(exit_depth=0.0)).equals(shapely.from_wkt(geometry.wkt))


@pytest.mark.parametrize(
    ("width", "length", "door_width"),
    [(0.0, 10.0, 1.0), (10.0, -1.0, 1.0), (10.0, 10.0, 0.0), (10.0, 10.0, 10.0)],
)
def test_invalid_room_is_rejected(width, length, door_width):
    with pytest.raises(ValueError):
        RoomGeometry(width=width, length=length, door_width=door_width)


def valid_arrays(T=4, N=3):
    return dict(
        positions=np.ones((T, N, 2), np.float32),
        velocities=np.zeros((T, N, 2), np.float32),
        active=np.ones((T, N), bool),
        framerate=2.0,
        geometry=RoomGeometry(),
    )


def test_trajectories_sizes():
    trajectories = Trajectories(**valid_arrays(T=5, N=7))
    assert (trajectories.num_frames, trajectories.num_agents) == (5, 7)
    np.testing.assert_allclose(trajectories.times, np.arange(5) / 2.0)
    assert trajectories.speeds.shape == (5, 7)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"positions": np.ones((4, 3), np.float32)}, "positions must have shape"),
        ({"positions": np.ones((4, 3, 3), np.float32)}, "positions must have shape"),
        ({"positions": np.ones((4, 3, 2), np.int64)}, "floating point"),
        ({"velocities": np.zeros((4, 2, 2), np.float32)}, "velocities must have the shape"),
        ({"active": np.ones((4, 2), bool)}, "active must have shape"),
        ({"active": np.ones((4, 3), np.int64)}, "active must be bool"),
        ({"framerate": 0.0}, "framerate must be positive"),
    ],
)
def test_trajectories_validation_errors_are_one_line(change, message):
    with pytest.raises(ValueError, match=message) as error:
        Trajectories(**(valid_arrays() | change))
    assert "\n" not in str(error.value)


def test_non_finite_positions_only_matter_for_active_agents():
    arrays = valid_arrays()
    arrays["positions"][2, 1] = np.nan
    with pytest.raises(ValueError, match="finite"):
        Trajectories(**arrays)
    arrays["active"][2, 1] = False
    Trajectories(**arrays)


def two_runs() -> Recording:
    """A recording of 2 runs of 3 frames of 2 agents, run ``r`` at x = r + 1."""
    positions = np.ones((2, 3, 2, 2), np.float32) * np.array([1.0, 2.0], np.float32)[:, None, None, None]
    in_room = np.ones((2, 3, 2), bool)
    return Recording(positions=positions, in_room=in_room, exit_time=np.full((2, 2), np.nan), frame_rate=2.0)


def test_of_run_reads_the_run_it_names():
    runs = [Trajectories.of_run(two_runs(), index, RoomGeometry()) for index in (0, 1)]
    assert [float(run.positions[0, 0, 0]) for run in runs] == [1.0, 2.0]


@pytest.mark.parametrize("index", [2, 5, -1, -2, 1.0, True, "0"])
def test_of_run_refuses_an_index_that_names_no_run_in_one_line(index):
    with pytest.raises(ValueError) as error:
        Trajectories.of_run(two_runs(), index, RoomGeometry())
    assert str(error.value) == f"index={index!r} is invalid: must be an integer in [0, 1] (the recording holds 2 runs)"


def test_geometry_type_is_checked():
    with pytest.raises(TypeError):
        Trajectories(**(valid_arrays() | {"geometry": (60, 100, 2)}))


def test_analysis_imports_neither_sim_nor_torch_nor_pyplot():
    code = (
        "import sys, pedrl.analysis; "
        "bad = [m for m in ('torch', 'pedrl.sim', 'matplotlib.pyplot') if m in sys.modules]; "
        "print(bad); sys.exit(1 if bad else 0)"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stdout + result.stderr

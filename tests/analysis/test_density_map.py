import numpy as np
import pytest

from pedrl.analysis import (
    DensityMap,
    RoomGeometry,
    Trajectories,
    compute_density_map,
    compute_tile_edges,
    load_density_map,
)


def test_counts_sum_to_active_agent_frames_inside_the_room(make_trial):
    trials = [make_trial(seed=seed, num_agents=15, num_frames=30) for seed in range(4)]
    geometry = trials[0].geometry
    density_map = compute_density_map(trials, tile_size=2.0, geometry=geometry)
    active_inside = sum(int(geometry.contains(t.positions[t.active]).sum()) for t in trials)
    active_total = sum(int(t.active.sum()) for t in trials)
    assert active_inside < active_total  # the exit frames lie past the door and are not counted
    assert density_map.total == active_inside
    assert density_map.counts.shape == (10, 15)
    assert density_map.num_frames == 4 * 30


def single_agent(xy, *, active=True, geometry=None):
    geometry = geometry or RoomGeometry(width=60.0, length=100.0, door_width=2.0)
    positions = np.array([[xy]], dtype=np.float64)
    return Trajectories(
        positions=positions,
        velocities=np.zeros_like(positions),
        active=np.array([[active]]),
        framerate=1.0,
        geometry=geometry,
    )


@pytest.mark.parametrize(
    ("xy", "tile"),
    [((12.3, 47.9), (2, 9)), ((0.0, 0.0), (0, 0)), ((60.0, 99.9), (11, 19)), ((35.0, 5.0), (7, 1))],
)
def test_hand_placed_agent_lands_in_its_tile(xy, tile):
    trial = single_agent(xy)
    density_map = compute_density_map(trial, tile_size=5.0, geometry=trial.geometry)
    expected = np.zeros((12, 20), np.int64)
    expected[tile] = 1
    np.testing.assert_array_equal(density_map.counts, expected)


@pytest.mark.parametrize("xy", [(30.0, 100.0), (30.0, 101.5), (-1.0, 50.0)])
def test_agents_outside_the_room_are_not_counted(xy):
    trial = single_agent(xy)
    assert compute_density_map(trial, tile_size=5.0, geometry=trial.geometry).total == 0


def test_inactive_agents_are_not_counted():
    trial = single_agent((10.0, 10.0), active=False)
    assert compute_density_map(trial, tile_size=5.0, geometry=trial.geometry).total == 0


def test_ragged_last_tile():
    np.testing.assert_allclose(compute_tile_edges(60.0, 7.0), [0, 7, 14, 21, 28, 35, 42, 49, 56, 60])
    np.testing.assert_allclose(compute_tile_edges(60.0, 5.0), np.arange(0, 61, 5))
    np.testing.assert_allclose(compute_tile_edges(1.0, 0.1), np.linspace(0, 1, 11))


def test_save_and_load_round_trip(tmp_path, make_trial):
    trial = make_trial()
    density_map = compute_density_map(trial, tile_size=3.0, geometry=trial.geometry)
    path = density_map.save(tmp_path / "density_map.npz")
    loaded = load_density_map(path)
    assert isinstance(loaded, DensityMap)
    np.testing.assert_array_equal(loaded.counts, density_map.counts)
    np.testing.assert_array_equal(loaded.x_edges, density_map.x_edges)
    np.testing.assert_array_equal(loaded.y_edges, density_map.y_edges)
    assert (loaded.tile_size, loaded.num_frames) == (3.0, density_map.num_frames)
    assert np.load(path)["counts"].sum() == density_map.total


def test_tile_size_must_be_positive():
    with pytest.raises(ValueError):
        compute_density_map([], tile_size=0.0, geometry=RoomGeometry())

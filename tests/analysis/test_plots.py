import numpy as np
import pytest
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from PIL import Image

from pedrl.analysis import (
    SpeedDensityModel,
    animate_trial,
    compute_density_map,
    compute_fundamental_diagram,
    plot_density_map,
    plot_fundamental_diagram,
    plot_learning_curves,
    plot_room,
)


def assert_labelled_in_units(axes: Axes) -> None:
    for label in (axes.get_xlabel(), axes.get_ylabel()):
        assert label and "(" in label and ")" in label, label


def test_plot_room_draws_walls_and_door(tmp_path, make_trial):
    geometry = make_trial().geometry
    axes = plot_room(geometry)
    assert isinstance(axes, Axes)
    assert_labelled_in_units(axes)
    segments = axes.collections[0].get_segments()
    np.testing.assert_array_equal(np.array(segments), geometry.walls)
    (door,) = [line for line in axes.get_lines() if line.get_label() == "door"]
    np.testing.assert_array_equal(door.get_xydata(), geometry.door)
    axes.figure.savefig(tmp_path / "room.png")
    assert (tmp_path / "room.png").stat().st_size > 0


@pytest.mark.parametrize("fit", [True, False, SpeedDensityModel.QUADRATIC])
def test_plot_fundamental_diagram(tmp_path, make_trial, fit):
    trials = [make_trial(seed=seed, num_agents=30, num_frames=30) for seed in range(3)]
    fd = compute_fundamental_diagram(trials, min_density=0.01)
    speed_axes, flow_axes = plot_fundamental_diagram(fd, label="IN-VQQL", fit=fit)
    assert speed_axes.figure is flow_axes.figure
    for axes in (speed_axes, flow_axes):
        assert_labelled_in_units(axes)
        assert len(axes.collections) == 1
        assert len(axes.get_lines()) == (0 if fit is False else 1)
    np.testing.assert_array_equal(speed_axes.collections[0].get_offsets(), np.c_[fd.density, fd.speed])
    np.testing.assert_array_equal(flow_axes.collections[0].get_offsets(), np.c_[fd.density, fd.flow])
    # A second data set on the same axes, for comparison.
    again = plot_fundamental_diagram(fd, axes=(speed_axes, flow_axes), label="IT-VQQL")
    assert again == (speed_axes, flow_axes)
    assert len(speed_axes.collections) == 2
    speed_axes.figure.savefig(tmp_path / "fd.png")
    assert (tmp_path / "fd.png").stat().st_size > 0


def test_plot_density_map(tmp_path, make_trial):
    trial = make_trial()
    density_map = compute_density_map(trial, tile_size=2.0, geometry=trial.geometry)
    figure = Figure()
    axes = figure.add_subplot()
    assert plot_density_map(density_map, geometry=trial.geometry, axes=axes) is axes
    assert_labelled_in_units(axes)
    mesh = axes.collections[0]
    np.testing.assert_array_equal(np.asarray(mesh.get_array()).reshape(15, 10), density_map.counts.T)
    assert len(figure.axes) == 2  # the colour bar
    assert "tile" in figure.axes[1].get_ylabel()
    figure.savefig(tmp_path / "density_map.png")
    assert (tmp_path / "density_map.png").stat().st_size > 0


def test_plot_learning_curves(tmp_path):
    trials = np.arange(0, 1000, 10)
    curves = {
        "IT-VQQL": (trials, np.linspace(0.1, 0.9, 100), np.full(100, 0.05)),
        "VQQL": (trials, np.linspace(0.0, 0.4, 100), np.full(100, 0.1)),
    }
    axes = plot_learning_curves(curves, boundaries=[250, 600], styles={"VQQL": {"linestyle": "--"}})
    assert axes.get_xlabel() == "trials"  # a count: no unit
    assert axes.get_ylabel().startswith("performance (fraction")
    lines = axes.get_lines()
    assert [line.get_label() for line in lines[:2]] == ["IT-VQQL", "VQQL"]
    assert lines[1].get_linestyle() == "--"
    boundaries = [line for line in lines[2:] if line.get_linestyle() == "--"]
    assert sorted(line.get_xdata()[0] for line in boundaries) == [250, 600]
    band = axes.collections[0].get_paths()[0].vertices
    assert band[:, 1].min() == pytest.approx(0.1 - 0.05) and band[:, 1].max() == pytest.approx(0.9 + 0.05)
    axes.figure.savefig(tmp_path / "curves.png")


def test_plot_learning_curves_rejects_mismatched_arrays():
    with pytest.raises(ValueError, match="shapes differ"):
        plot_learning_curves({"bad": (np.arange(3), np.zeros(3), np.zeros(2))})


@pytest.mark.parametrize(("max_frames", "expected"), [(None, 12), (5, 5), (50, 12)])
def test_animate_trial_writes_one_gif_frame_per_trial_frame(tmp_path, make_trial, max_frames, expected):
    trial = make_trial(num_agents=8, num_frames=12)
    path = animate_trial(trial, tmp_path / "trial.gif", fps=5.0, max_frames=max_frames, dpi=40)
    assert path.stat().st_size > 0
    with Image.open(path) as gif:
        assert gif.format == "GIF"
        assert gif.n_frames == expected


def test_animate_trial_hides_inactive_agents(tmp_path, make_trial):
    trial = make_trial(num_agents=8, num_frames=12)
    inactive = trial.__class__(
        positions=trial.positions,
        velocities=trial.velocities,
        active=np.zeros_like(trial.active),
        framerate=trial.framerate,
        geometry=trial.geometry,
    )
    empty = animate_trial(inactive, tmp_path / "empty.gif", max_frames=3, dpi=40)
    full = animate_trial(trial, tmp_path / "full.gif", max_frames=3, dpi=40)
    with Image.open(empty) as a, Image.open(full) as b:
        a.seek(1)
        b.seek(1)
        empty_frame = np.asarray(a.convert("RGB"), dtype=np.int64)
        full_frame = np.asarray(b.convert("RGB"), dtype=np.int64)
    assert empty_frame.shape == full_frame.shape
    assert np.abs(empty_frame - full_frame).sum() > 0

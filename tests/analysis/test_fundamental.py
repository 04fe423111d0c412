import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from pedrl.analysis import (
    DENSITY_COL,
    FLOW_COL,
    FRAME_COL,
    SPEED_COL,
    TRIAL_COL,
    RoomGeometry,
    SpeedDensityModel,
    Trajectories,
    compute_flow,
    compute_fundamental_diagram,
    compute_gaussian_density,
    compute_local_speed,
    compute_local_velocity,
    fit_speed_density,
)
from pedrl.analysis.fundamental import FundamentalDiagram


@pytest.mark.parametrize("radius", [0.5, 1.0, 2.0])
def test_single_agent_on_the_point(radius):
    point = np.array([3.0, 4.0])
    density = compute_gaussian_density(point[None, None, :], np.ones((1, 1), bool), point=point, radius=radius)
    np.testing.assert_allclose(density, [1.0 / (np.pi * radius**2)], rtol=1e-15)


def test_single_agent_at_a_distance():
    distance = 1.7
    positions = np.array([[[distance * 0.6, distance * 0.8]]])
    density = compute_gaussian_density(positions, np.ones((1, 1), bool), point=[0.0, 0.0], radius=1.3)
    np.testing.assert_allclose(density, [np.exp(-(distance**2) / 1.3**2) / (np.pi * 1.3**2)], rtol=1e-14)


def gaussian_lattice_sum_1d(*, spacing: float, offset: float, radius: float, terms: int = 50) -> float:
    """sum_i exp(-(i a + offset)^2 / R^2) over all integers i, by Poisson summation (a theta function)."""
    k = np.arange(1, terms)
    dual = np.exp(-((np.pi * k * radius / spacing) ** 2)) * np.cos(2 * np.pi * k * offset / spacing)
    return np.sqrt(np.pi) * radius / spacing * (1.0 + 2.0 * dual.sum())


def square_lattice(*, spacing: float, origin: np.ndarray, half_extent: float) -> np.ndarray:
    """``(M, 2)`` lattice points ``origin + spacing * (i, j)`` covering ``[-half_extent, half_extent]^2``."""
    n = int(np.ceil(half_extent / spacing)) + 1
    i = np.arange(-n, n + 1)
    grid = np.stack(np.meshgrid(i, i, indexing="ij"), axis=-1).reshape(-1, 2)
    return origin + spacing * grid


@pytest.mark.parametrize(
    ("spacing", "radius", "origin"),
    [(0.25, 1.0, (0.0, 0.0)), (0.7, 1.0, (0.3, -0.1)), (1.5, 1.0, (0.5, 0.75)), (2.0, 0.8, (0.0, 1.0))],
)
def test_lattice_density_speed_and_flow(spacing, radius, origin):
    velocity = np.array([0.6, -1.1])
    lattice = square_lattice(spacing=spacing, origin=np.array(origin), half_extent=10 * radius)
    positions = lattice[None]
    velocities = np.broadcast_to(velocity, positions.shape)
    active = np.ones(positions.shape[:2], bool)
    point = np.zeros(2)

    density = compute_gaussian_density(positions, active, point=point, radius=radius)
    expected = (
        gaussian_lattice_sum_1d(spacing=spacing, offset=origin[0], radius=radius)
        * gaussian_lattice_sum_1d(spacing=spacing, offset=origin[1], radius=radius)
        / (np.pi * radius**2)
    )
    np.testing.assert_allclose(density, [expected], rtol=1e-12)
    if spacing < radius / 3:
        np.testing.assert_allclose(density, [1.0 / spacing**2], rtol=1e-12)

    speed = compute_local_speed(positions, velocities, active, point=point, radius=radius)
    np.testing.assert_allclose(speed, [np.linalg.norm(velocity)], rtol=1e-14)
    np.testing.assert_allclose(compute_flow(density=density, speed=speed), density * np.linalg.norm(velocity))


def test_inactive_agents_are_ignored():
    rng = np.random.default_rng(1)
    positions = rng.uniform(-2, 2, (6, 10, 2))
    velocities = rng.normal(size=(6, 10, 2))
    active = rng.random((6, 10)) < 0.6
    # Inactive agents: moved onto the point with absurd (and NaN) velocities; nothing may change.
    moved = np.where(active[..., None], positions, 0.0)
    junk = np.where(active[..., None], velocities, np.nan)
    for p, v in ((positions, velocities), (moved, junk)):
        density = compute_gaussian_density(p, active, point=[0.0, 0.0])
        speed = compute_local_speed(p, v, active, point=[0.0, 0.0])
        kept_density = [compute_gaussian_density(p[t, active[t]], active[t, active[t]], point=[0, 0]) for t in range(6)]
        np.testing.assert_allclose(density, kept_density, rtol=1e-14)
        assert np.isfinite(speed[active.any(axis=1)]).all()
        if p is positions:
            reference = speed
        else:
            np.testing.assert_allclose(speed, reference, rtol=1e-12)


def test_local_speed_is_the_magnitude_of_the_mean_velocity():
    # Two agents on either side of the point walking apart: the vectors cancel.
    positions = np.array([[[-0.5, 0.0], [0.5, 0.0]]])
    velocities = np.array([[[-1.0, 0.0], [1.0, 0.0]]])
    speed = compute_local_speed(positions, velocities, np.ones((1, 2), bool), point=[0.0, 0.0])
    np.testing.assert_allclose(speed, [0.0], atol=1e-15)
    # A near agent weighs more than a far one.
    positions = np.array([[[0.0, 0.0], [1.0, 0.0]]])
    velocities = np.array([[[1.0, 0.0], [0.0, 0.0]]])
    local = compute_local_velocity(positions, velocities, np.ones((1, 2), bool), point=[0.0, 0.0])
    np.testing.assert_allclose(local, [[1.0 / (1.0 + np.exp(-1.0)), 0.0]], rtol=1e-14)


def test_local_speed_is_nan_without_weight():
    positions = np.zeros((2, 3, 2))
    velocities = np.ones((2, 3, 2))
    active = np.array([[False, False, False], [True, False, False]])
    speed = compute_local_speed(positions, velocities, active, point=[0.0, 0.0])
    assert np.isnan(speed[0])
    np.testing.assert_allclose(speed[1], np.sqrt(2.0))
    # So far away that every weight underflows to 0.
    far = compute_local_speed(np.full((1, 1, 2), 1e3), np.ones((1, 1, 2)), np.ones((1, 1), bool), point=[0, 0])
    assert np.isnan(far[0])


finite = st.floats(-5.0, 5.0, allow_nan=False)


@settings(max_examples=50, deadline=None)
@given(
    positions=arrays(np.float64, (3, 6, 2), elements=finite),
    velocities=arrays(np.float64, (3, 6, 2), elements=st.floats(-2.5, 2.5)),
    active=arrays(np.bool_, (3, 6)),
    permutation=st.permutations(range(6)),
)
def test_density_is_additive_and_speed_bounded_and_order_free(positions, velocities, active, permutation):
    point = np.array([0.5, -0.5])
    density = compute_gaussian_density(positions, active, point=point)
    per_agent = [compute_gaussian_density(positions[:, [n]], active[:, [n]], point=point) for n in range(6)]
    np.testing.assert_allclose(density, np.sum(per_agent, axis=0), rtol=1e-12, atol=1e-300)
    permuted = compute_gaussian_density(positions[:, permutation], active[:, permutation], point=point)
    np.testing.assert_allclose(permuted, density, rtol=1e-12)

    speed = compute_local_speed(positions, velocities, active, point=point)
    fastest = np.where(active, np.linalg.norm(velocities, axis=-1), 0.0).max(axis=1)
    has_weight = density > 0
    assert np.all(speed[has_weight] <= fastest[has_weight] + 1e-9)
    assert np.isnan(speed[~has_weight]).all()


def test_fundamental_diagram_samples_and_rows(make_trial):
    trials = [make_trial(seed=seed, num_agents=30, num_frames=30) for seed in range(3)]
    fd = compute_fundamental_diagram(trials, radius=1.0, min_density=0.02)
    point = trials[0].geometry.door_center - [0.0, 1.0]
    np.testing.assert_array_equal(fd.point, point)
    assert fd.num_samples > 0
    assert (fd.density >= 0.02).all() and (fd.frame >= 1).all()
    np.testing.assert_allclose(fd.flow, fd.density * fd.speed)
    for trial, frame, density, speed in zip(fd.trial, fd.frame, fd.density, fd.speed, strict=True):
        trajectories = trials[trial]
        positions, active = trajectories.positions[frame], trajectories.active[frame]
        expected = compute_gaussian_density(positions, active, point=point)
        np.testing.assert_allclose(density, expected, rtol=1e-12)
        expected_speed = compute_local_speed(positions, trajectories.velocities[frame], active, point=point)
        np.testing.assert_allclose(speed, expected_speed, rtol=1e-12)
    # Every dropped frame is below the threshold.
    for index, trajectories in enumerate(trials):
        kept = set(fd.frame[fd.trial == index].tolist())
        for frame in set(range(1, trajectories.num_frames)) - kept:
            positions, active = trajectories.positions[frame], trajectories.active[frame]
            assert compute_gaussian_density(positions, active, point=point) < 0.02

    rows = fd.to_rows()
    assert len(rows) == fd.num_samples
    assert set(rows[0]) == {TRIAL_COL, FRAME_COL, DENSITY_COL, SPEED_COL, FLOW_COL}
    assert rows[0][DENSITY_COL] == fd.density[0]
    assert isinstance(rows[0][FRAME_COL], int)


def test_fundamental_diagram_skips_the_initial_frame_by_default():
    geometry = RoomGeometry(width=10.0, length=10.0, door_width=2.0)
    positions = np.broadcast_to([5.0, 9.0], (3, 1, 2)).copy()
    trajectories = Trajectories(
        positions=positions,
        velocities=np.zeros_like(positions),
        active=np.ones((3, 1), bool),
        framerate=1.0,
        geometry=geometry,
    )
    np.testing.assert_array_equal(compute_fundamental_diagram(trajectories).frame, [1, 2])
    np.testing.assert_array_equal(compute_fundamental_diagram(trajectories, first_frame=0).frame, [0, 1, 2])
    np.testing.assert_allclose(compute_fundamental_diagram(trajectories).density, 1.0 / np.pi)


def diagram(density, speed):
    density, speed = np.asarray(density, float), np.asarray(speed, float)
    n = len(density)
    return FundamentalDiagram(
        density=density,
        speed=speed,
        flow=density * speed,
        trial=np.zeros(n, np.int64),
        frame=np.arange(n),
        point=np.zeros(2),
        radius=1.0,
    )


@pytest.mark.parametrize(
    ("model", "coefficients"),
    [(SpeedDensityModel.LINEAR, (1.9, -0.8)), (SpeedDensityModel.QUADRATIC, (2.0, -1.5, 0.4))],
)
def test_fit_recovers_exact_polynomials(model, coefficients):
    density = np.linspace(0.05, 1.2, 40)
    speed = np.polynomial.polynomial.polyval(density, coefficients)
    fit = fit_speed_density(diagram(density, speed), model=model)
    np.testing.assert_allclose(fit.coefficients, coefficients, atol=1e-10)
    np.testing.assert_allclose(fit(density), speed, atol=1e-10)
    np.testing.assert_allclose(fit.flow(density), density * speed, atol=1e-10)
    assert fit.num_samples == 40


def test_linear_fit_is_least_squares():
    density = np.array([0.1, 0.2, 0.3, 0.4])
    speed = np.array([2.0, 1.0, 2.0, 1.0])
    fit = fit_speed_density(diagram(density, speed))
    slope, intercept = np.polyfit(density, speed, 1)
    np.testing.assert_allclose(fit.coefficients, (intercept, slope))


def test_fit_needs_enough_distinct_densities():
    with pytest.raises(ValueError, match="distinct densities"):
        fit_speed_density(diagram([0.5, 0.5, 0.5], [1.0, 1.2, 0.9]))

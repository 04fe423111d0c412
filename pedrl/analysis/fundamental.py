r"""Local density, speed and flow (paper section 6, equations 2-5) and the fundamental diagram.

The local density at a point :math:`\vec r` and frame :math:`t` is a Gaussian-weighted count of the active
agents (Helbing et al., the paper's reference [8]):

.. math::

    f_j = \frac{1}{\pi R^2} \exp\left(-\frac{\lVert \vec r_j(t) - \vec r \rVert^2}{R^2}\right), \qquad
    \rho(\vec r, t) = \sum_j f_j \quad [1/m^2],

    \vec S(\vec r, t) = \frac{\sum_j \vec v_j f_j}{\sum_j f_j} \quad [m/s], \qquad
    \vec Q(\vec r, t) = \rho(\vec r, t)\, \vec S(\vec r, t) \quad [1/(m\,s)].

The fundamental diagram plots the local speed :math:`|\vec S|` and the flow :math:`|\vec Q| = \rho |\vec S|`
against :math:`\rho`, sampled once per frame at a fixed point near the exit (the paper uses R = 1 m).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pedrl.analysis.trajectories import Trajectories

DENSITY_COL: Final = "density"
SPEED_COL: Final = "speed"
FLOW_COL: Final = "flow"
TRIAL_COL: Final = "trial"
FRAME_COL: Final = "frame"

DEFAULT_RADIUS: Final = 1.0
"""Radius R (m) of the Gaussian weight; the paper's value."""

DEFAULT_MIN_DENSITY: Final = 0.05
"""Frames with a local density below this (1/m^2) are left out of the fundamental diagram.

One agent at distance d from the point contributes ``exp(-d^2/R^2) / (pi R^2)``; 0.05 1/m^2 keeps the frames
where at least one agent is within about 1.3 R. Below that the local speed is the velocity of agents that are
far from the measurement point.
"""


def compute_gaussian_weights(
    positions: ArrayLike, active: ArrayLike, *, point: ArrayLike, radius: float = DEFAULT_RADIUS
) -> NDArray[np.float64]:
    r"""Gaussian weight of each agent, :math:`f_j = \exp(-|r_j - r|^2 / R^2) / (\pi R^2)` (1/m^2).

    Args:
        positions: ``(T, N, 2)`` agent centres (m).
        active: ``(T, N)`` bool; inactive agents get weight 0.
        point: ``(2,)`` measurement point :math:`\vec r` (m).
        radius: R (m), > 0.

    Returns:
        ``(T, N)`` weights (1/m^2), float64.
    """
    if not radius > 0:
        raise ValueError(f"radius must be positive, got {radius}")
    positions = np.asarray(positions, dtype=np.float64)
    active = np.asarray(active, dtype=bool)
    point = np.asarray(point, dtype=np.float64)
    if point.shape != (2,):
        raise ValueError(f"point must have shape (2,), got {point.shape}")
    if positions.shape[:-1] != active.shape:
        raise ValueError(f"positions {positions.shape} and active {active.shape} disagree")
    squared = np.sum((positions - point) ** 2, axis=-1)
    weights = np.exp(-squared / radius**2) / (np.pi * radius**2)
    return np.where(active, weights, 0.0)


def compute_gaussian_density(
    positions: ArrayLike, active: ArrayLike, *, point: ArrayLike, radius: float = DEFAULT_RADIUS
) -> NDArray[np.float64]:
    r"""Local density :math:`\rho(\vec r, t) = \sum_j f_j` (eq. 2-3), 1/m^2.

    A single agent standing on the point gives :math:`1 / (\pi R^2)`; a uniform crowd of density
    :math:`\rho_0` much wider than R gives :math:`\rho_0`.

    Args:
        positions: ``(T, N, 2)`` agent centres (m).
        active: ``(T, N)`` bool; inactive agents are ignored.
        point: ``(2,)`` measurement point (m).
        radius: R (m).

    Returns:
        ``(T,)`` density (1/m^2).
    """
    return compute_gaussian_weights(positions, active, point=point, radius=radius).sum(axis=-1)


def compute_local_velocity(
    positions: ArrayLike,
    velocities: ArrayLike,
    active: ArrayLike,
    *,
    point: ArrayLike,
    radius: float = DEFAULT_RADIUS,
) -> NDArray[np.float64]:
    r"""Local velocity :math:`\vec S = \sum_j \vec v_j f_j / \sum_j f_j` (eq. 4), m/s.

    Where the weight sum is 0 (no active agent, or all so far away that every weight underflows) the local
    velocity is undefined and NaN is returned; :func:`compute_fundamental_diagram` drops such frames together
    with all frames below ``min_density``.

    Args:
        positions: ``(T, N, 2)`` agent centres (m).
        velocities: ``(T, N, 2)`` agent velocities (m/s).
        active: ``(T, N)`` bool; inactive agents are ignored.
        point: ``(2,)`` measurement point (m).
        radius: R (m).

    Returns:
        ``(T, 2)`` local velocity (m/s); NaN where the weight sum is 0.
    """
    velocities = np.asarray(velocities, dtype=np.float64)
    active = np.asarray(active, dtype=bool)
    weights = compute_gaussian_weights(positions, active, point=point, radius=radius)
    if velocities.shape[:-1] != weights.shape or velocities.shape[-1] != 2:
        raise ValueError(f"velocities must have shape {weights.shape + (2,)}, got {velocities.shape}")
    # Inactive agents may carry NaN velocities; 0 * NaN would poison the sum.
    velocities = np.where(active[..., None], velocities, 0.0)
    total = weights.sum(axis=-1)
    weighted = np.einsum("...n,...nc->...c", weights, velocities)
    with np.errstate(invalid="ignore", divide="ignore"):
        local = weighted / total[..., None]
    return np.where(total[..., None] > 0, local, np.nan)


def compute_local_speed(
    positions: ArrayLike,
    velocities: ArrayLike,
    active: ArrayLike,
    *,
    point: ArrayLike,
    radius: float = DEFAULT_RADIUS,
) -> NDArray[np.float64]:
    r"""Local speed :math:`|\vec S(\vec r, t)|`, the magnitude of the weighted mean velocity (eq. 4), m/s.

    Agents walking in different directions cancel: two agents on the point walking apart give 0.
    NaN where the weight sum is 0 (see :func:`compute_local_velocity`).

    Returns:
        ``(T,)`` local speed (m/s).
    """
    local = compute_local_velocity(positions, velocities, active, point=point, radius=radius)
    return np.linalg.norm(local, axis=-1)


def compute_flow(*, density: ArrayLike, speed: ArrayLike) -> NDArray[np.float64]:
    r"""Flow :math:`|\vec Q| = \rho\, |\vec S|` (eq. 5), 1/(m s): persons per second and metre of width.

    Args:
        density: local density (1/m^2).
        speed: local speed (m/s), same shape.
    """
    return np.asarray(density, dtype=np.float64) * np.asarray(speed, dtype=np.float64)


@dataclass(frozen=True, eq=False)
class FundamentalDiagram:
    """Samples of the fundamental diagram: one row per kept frame of every trial.

    Attributes:
        density: ``(M,)`` local density (1/m^2).
        speed: ``(M,)`` local speed (m/s).
        flow: ``(M,)`` flow ``density * speed`` (1/(m s)).
        trial: ``(M,)`` index of the trial in the list given to :func:`compute_fundamental_diagram`.
        frame: ``(M,)`` frame of the sample within its trial.
        point: ``(2,)`` measurement point (m).
        radius: R of the Gaussian weight (m).
    """

    density: NDArray[np.float64]
    speed: NDArray[np.float64]
    flow: NDArray[np.float64]
    trial: NDArray[np.int64]
    frame: NDArray[np.int64]
    point: NDArray[np.float64]
    radius: float

    def __post_init__(self) -> None:
        lengths = {len(np.asarray(c)) for c in (self.density, self.speed, self.flow, self.trial, self.frame)}
        if len(lengths) != 1:
            raise ValueError(f"density, speed, flow, trial and frame must have one length, got {sorted(lengths)}")

    @property
    def num_samples(self) -> int:
        """M, the number of samples."""
        return len(self.density)

    def columns(self) -> dict[str, NDArray]:
        """The samples as columns, keyed by the ``*_COL`` constants (trial, frame, density, speed, flow)."""
        return {
            TRIAL_COL: self.trial,
            FRAME_COL: self.frame,
            DENSITY_COL: self.density,
            SPEED_COL: self.speed,
            FLOW_COL: self.flow,
        }

    def to_rows(self) -> list[dict[str, float | int]]:
        """One dict per sample with the keys of :meth:`columns` (e.g. for ``csv.DictWriter`` or pandas)."""
        return [
            {
                TRIAL_COL: int(t),
                FRAME_COL: int(f),
                DENSITY_COL: float(d),
                SPEED_COL: float(s),
                FLOW_COL: float(q),
            }
            for t, f, d, s, q in zip(self.trial, self.frame, self.density, self.speed, self.flow, strict=True)
        ]


def default_measurement_point(trajectories: Trajectories, *, radius: float = DEFAULT_RADIUS) -> NDArray[np.float64]:
    """The paper's point "near the exit": ``radius`` metres inside the room from the door centre (m)."""
    geometry = trajectories.geometry
    return geometry.door_center - radius * geometry.door_normal


def compute_fundamental_diagram(
    trajectories_list: Sequence[Trajectories] | Trajectories,
    *,
    point: ArrayLike | None = None,
    radius: float = DEFAULT_RADIUS,
    min_density: float = DEFAULT_MIN_DENSITY,
    first_frame: int = 1,
) -> FundamentalDiagram:
    """Sample local density, speed and flow at one point in every frame of every trial.

    Args:
        trajectories_list: the trials (or a single trial).
        point: ``(2,)`` measurement point (m); default :func:`default_measurement_point` of each trial.
        radius: R of the Gaussian weight (m).
        min_density: frames whose density is below this (1/m^2) are dropped (see ``DEFAULT_MIN_DENSITY``).
        first_frame: frames before this are dropped; the default 1 skips the initial state, where every agent
            stands still by construction.

    Returns:
        The kept samples, in trial then frame order.
    """
    if isinstance(trajectories_list, Trajectories):
        trajectories_list = [trajectories_list]
    parts: list[tuple[NDArray, ...]] = []
    points = []
    for index, trajectories in enumerate(trajectories_list):
        here = default_measurement_point(trajectories, radius=radius) if point is None else np.asarray(point, float)
        points.append(here)
        frames = slice(first_frame, None)
        positions = trajectories.positions[frames]
        active = trajectories.active[frames]
        density = compute_gaussian_density(positions, active, point=here, radius=radius)
        speed = compute_local_speed(positions, trajectories.velocities[frames], active, point=here, radius=radius)
        keep = (density >= min_density) & np.isfinite(speed) & (density > 0)
        frame = np.arange(first_frame, first_frame + len(density))[keep]
        parts.append((density[keep], speed[keep], np.full(len(frame), index, dtype=np.int64), frame))
    if not parts:
        raise ValueError("trajectories_list is empty")
    if any(not np.allclose(p, points[0]) for p in points):
        raise ValueError("the default measurement point differs between trials (different rooms); pass point=")
    density, speed, trial, frame = (np.concatenate(column) for column in zip(*parts, strict=True))
    return FundamentalDiagram(
        density=density,
        speed=speed,
        flow=compute_flow(density=density, speed=speed),
        trial=trial,
        frame=frame.astype(np.int64),
        point=points[0],
        radius=float(radius),
    )


class SpeedDensityModel(Enum):
    """Least-squares model of the speed-density relation; the value is the polynomial degree.

    The paper fits curves "for clarity" only; a polynomial fit is robust with the few, low densities
    (< 1.2 1/m^2) a 60 x 100 m room produces, unlike Weidmann's exponential form.
    """

    LINEAR = 1
    """``S(rho) = c0 + c1 rho``"""
    QUADRATIC = 2
    """``S(rho) = c0 + c1 rho + c2 rho^2``"""


@dataclass(frozen=True)
class SpeedDensityFit:
    """A fitted speed-density curve ``S(rho)`` and the flow curve ``Q(rho) = rho S(rho)`` it implies.

    Attributes:
        model: the model fitted.
        coefficients: polynomial coefficients in ascending powers of rho: ``S = sum_k c_k rho^k``
            (``c_k`` in m/s * m^(2k)).
        num_samples: number of samples the fit used.
    """

    model: SpeedDensityModel
    coefficients: tuple[float, ...]
    num_samples: int

    def speed(self, density: ArrayLike) -> NDArray[np.float64]:
        """``S(rho)`` (m/s) at ``density`` (1/m^2)."""
        return np.polynomial.polynomial.polyval(np.asarray(density, dtype=np.float64), self.coefficients)

    def flow(self, density: ArrayLike) -> NDArray[np.float64]:
        """``Q(rho) = rho S(rho)`` (1/(m s)) at ``density`` (1/m^2)."""
        density = np.asarray(density, dtype=np.float64)
        return density * self.speed(density)

    def __call__(self, density: ArrayLike) -> NDArray[np.float64]:
        """Same as :meth:`speed`."""
        return self.speed(density)


def fit_speed_density(
    fundamental_diagram: FundamentalDiagram, *, model: SpeedDensityModel = SpeedDensityModel.LINEAR
) -> SpeedDensityFit:
    """Least-squares fit of the local speed against the local density.

    Minimises ``sum_i (S(rho_i) - s_i)^2`` over the polynomial coefficients of ``model``.
    The flow curve follows as ``rho S(rho)`` (:meth:`SpeedDensityFit.flow`), not as a separate fit.

    Raises:
        ValueError: fewer distinct densities than coefficients.
    """
    degree = model.value
    density = np.asarray(fundamental_diagram.density, dtype=np.float64)
    speed = np.asarray(fundamental_diagram.speed, dtype=np.float64)
    if len(np.unique(density)) <= degree:
        raise ValueError(f"{model.name} fit needs more than {degree} distinct densities, got {len(np.unique(density))}")
    coefficients = np.polynomial.polynomial.polyfit(density, speed, degree)
    return SpeedDensityFit(model=model, coefficients=tuple(float(c) for c in coefficients), num_samples=len(density))

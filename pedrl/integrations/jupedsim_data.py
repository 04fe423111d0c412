"""What pedrl hands JuPedSim and gets back, with neither jupedsim nor shapely imported: the model and the parameters
pedrl sets (:class:`JuPedSimModel`), the start of a run taken from one of our rooms (:class:`Scene`,
:func:`room_scene`) and the trajectories of a run (:class:`JuPedSimRun`). :mod:`pedrl.integrations.jupedsim` runs
the simulation and re-exports these names."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any, Final

import numpy as np
from numpy.typing import NDArray

from pedrl.common.checks import check_choice, check_number, check_real
from pedrl.sim import RoomEnv

MODELS: Final = (
    "collision_free_speed",
    "collision_free_speed_v2",
    "collision_free_speed_v3",
    "anticipation_velocity",
    "generalized_centrifugal_force",
    "social_force",
    "warp_driver",
)
"""Operational models :func:`simulate` runs: JuPedSim's ``CollisionFreeSpeedModel`` (Tordeux, Chraibi & Seyfried 2016),
its variants ``CollisionFreeSpeedModelV2`` (repulsion parameters per agent) and ``CollisionFreeSpeedModelV3``
(anisotropic, direction-dependent ranges), ``AnticipationVelocityModel`` (Xu, Chraibi & Seyfried 2021, built to form
lanes), ``GeneralizedCentrifugalForceModel`` (Chraibi, Seyfried & Schadschneider 2010), ``SocialForceModel``
(Helbing, Farkas & Vicsek 2000) and ``WarpDriverModel`` (Wolinski et al. 2016)."""


# ---------------------------------------------------------------------- the model
JUPEDSIM_RANGES: Final = {"desired_speed": (0.0, 10.0), "time_gap": (0.1, 10.0), "radius": (0.0, 2.0)}
"""The ranges JuPedSim's collision-free speed model accepts (``CheckModelConstraint``: v0 in [0, 10] m/s, the time gap
in [0.1, 10] s, the radius in (0, 2] m), checked with the config instead of failing mid-run on an agent's position."""
MIN_DT: Final = 1e-3
"""Smallest JuPedSim time step ``dt`` (s), a tenth of its default 0.01 s: at most 1,000 JuPedSim steps per simulated
second, 1,000 per decision of a room deciding once a second (``dt=1e-9`` asked for 10^9 steps per decision)."""


@dataclass(frozen=True)
class JuPedSimModel:
    """The JuPedSim model and the parameters pedrl sets; every other parameter keeps JuPedSim's default.

    The defaults are JuPedSim 1.4's (``CollisionFreeSpeedModelAgentParameters``, ``Simulation``); every other
    parameter of the models and their agents stays at JuPedSim's default (collision-free speed: neighbour repulsion
    strength 8, range 0.1 m, wall repulsion strength 5, range 0.02 m; anticipation velocity: anticipation time 1 s,
    reaction time 0.3 s, wall buffer 0.1 m, push-out strength 0.3, its random seed fixed at 0 so that a run repeats;
    generalized centrifugal force: mass 1, tau 0.5 s, a_v 1 s, neighbour and wall repulsion strengths 0.3 and 0.2
    within 2 m, its ellipse's semi-axes a_min = b_min = ``radius`` and b_max = 2 ``radius`` (its defaults at 0.2 m),
    its exit aprons deeper than the others' (``apron_depth``); social force: body force 120000 kg/s^2, friction
    240000 kg/(m s), mass 80 kg, reaction time 0.5 s, A = 2000 N, B = 0.08 m; warp driver: time horizon 2 s, step
    0.5 s).

    Attributes:
        model: the operational model, one of :data:`MODELS`.
        desired_speed: v0, the free walking speed (m/s); JuPedSim's collision-free speed default 1.2 (its social
            force default is 0.8; every model gets this value). RiMEA test 1 uses 1.33.
        time_gap: T, the time gap (s) of the collision-free speed models and the anticipation velocity model (default
            1.0; the anticipation velocity model's own is 1.06); the others ignore it.
        radius: body radius (m); JuPedSim's collision-free speed default 0.2. Pass the body size of the run compared.
        dt: JuPedSim's time step (s); its default 0.01, at least :data:`MIN_DT`.

    Raises:
        ValueError: one line naming the bad value.
    """

    model: str = "collision_free_speed"
    desired_speed: float = 1.2
    time_gap: float = 1.0
    radius: float = 0.2
    dt: float = 0.01

    def __post_init__(self) -> None:
        check_choice("model", self.model, MODELS)
        for name, unit in (("desired_speed", "m/s"), ("time_gap", "s"), ("radius", "m"), ("dt", "s")):
            check_real(name, getattr(self, name), unit=unit, positive=True)
        if self.dt < MIN_DT:
            raise ValueError(
                f"dt={self.dt!r} is invalid: must be >= {MIN_DT:g} s (JuPedSim's default 0.01 s; {self.dt!r} s would"
                f" take {1.0 / self.dt:,.0f} JuPedSim steps per simulated second, at most {1.0 / MIN_DT:,.0f})"
            )
        for name, (low, high) in JUPEDSIM_RANGES.items():  # JuPedSim's own model constraints, before any run
            check_number(name, getattr(self, name), low=low, high=high, low_open=low == 0.0)


def model_from_settings(settings: Mapping[str, Any] | None, *, prefix: str = "jupedsim") -> JuPedSimModel:
    """The :class:`JuPedSimModel` of a config section (its keys are the model's fields; missing ones keep their
    defaults).

    Raises:
        ValueError: one line naming ``<prefix>.<key>``, for an unknown key or a bad value.
    """
    allowed = [item.name for item in fields(JuPedSimModel)]
    values = dict(settings or {})
    for key in values:
        if key not in allowed:
            raise ValueError(f"{prefix}.{key} is not a setting of the JuPedSim model: allowed: {', '.join(allowed)}")
    try:
        return JuPedSimModel(**values)
    except ValueError as err:
        raise ValueError(f"{prefix}.{err}") from None


# ---------------------------------------------------------------------- the run
@dataclass(frozen=True)
class JuPedSimRun:
    """Trajectories of one JuPedSim run, sampled every ``1 / frame_rate`` s of simulated time.

    Attributes:
        positions: ``(T + 1, N, 2)`` float64 agent centres (m); frame 0 is the start. From the frame at which an agent
            left on, its row holds the point where it left: its centre past its exit's segment, in the apron (at
            most one JuPedSim step further than the first step past it).
        active: ``(T + 1, N)`` bool, the agent is still in the area at frame t.
        left_at: ``(N,)`` int64, the first frame at which the agent is out (its centre past its exit), -1 if never.
        exit_time: ``(N,)`` float64, the simulated time (s) at which the agent was at the point where it left: the
            first JuPedSim step after which its centre was past its exit's segment, or the next; NaN if never.
        frame_rate: frames per second of simulated time (1/s).
    """

    positions: NDArray[np.float64]
    active: NDArray[np.bool_]
    left_at: NDArray[np.int64]
    exit_time: NDArray[np.float64]
    frame_rate: float

    @property
    def num_frames(self) -> int:
        """T + 1, the frames recorded (frame 0 included)."""
        return self.positions.shape[0]

    @property
    def num_agents(self) -> int:
        """N."""
        return self.positions.shape[1]

    @property
    def left(self) -> NDArray[np.bool_]:
        """``(N,)`` bool, the agent left the area during the run."""
        return self.left_at >= 0

    def velocities(self) -> NDArray[np.float64]:
        """``(T + 1, N, 2)`` mean velocity (m/s) over the interval that ends at frame t; 0 at frame 0.

        It is the displacement over the time the agent moved in the interval: ``1 / frame_rate``, or for the frame
        at which it left, the time from the previous frame to its ``exit_time``. Zero once it left.
        """
        displacement = np.diff(self.positions, axis=0, prepend=self.positions[:1])  # (T + 1, N, 2)
        frames = np.arange(self.num_frames, dtype=np.float64)[:, None]  # (T + 1, 1)
        period = 1.0 / self.frame_rate
        exit_time = np.where(self.left, self.exit_time, math.inf)[None, :]  # (1, N)
        moved = np.clip(np.minimum(frames * period, exit_time) - (frames - 1.0) * period, 0.0, period)
        with np.errstate(divide="ignore", invalid="ignore"):
            velocities = np.where(moved[..., None] > 0.0, displacement / moved[..., None], 0.0)
        velocities[0] = 0.0
        return velocities


def pad_frames(values: np.ndarray, length: int, fill: Any = None) -> np.ndarray:
    """``values (T, ...)`` extended to ``length`` frames with ``fill`` (``None``: its last frame), so that runs that
    ended at different times stack."""
    missing = length - values.shape[0]
    if missing <= 0:
        return values
    tail = np.repeat(values[-1:], missing, axis=0) if fill is None else np.full((missing, *values.shape[1:]), fill)
    return np.concatenate([values, tail])


# ---------------------------------------------------------------------- the start, from our room
@dataclass(frozen=True)
class Scene:
    """The start of a run: where each agent stands, the exit it walks to and the waypoints it passes first.

    Attributes:
        positions: ``(N, 2)`` float64 centres (m).
        exit_index: ``(N,)`` int64, the exit of the scenario each agent walks to.
        waypoints: per agent, the points ``(x, y)`` (m) of its route still ahead, in order (may be empty).
    """

    positions: NDArray[np.float64]
    exit_index: NDArray[np.int64]
    waypoints: tuple[tuple[tuple[float, float], ...], ...]


def room_scene(room: RoomEnv, *, replica: int = 0) -> Scene:
    """The scene of replica ``replica`` of ``room`` as it stands (after ``room.reset(...)``): its agents' positions,
    exits and the waypoints of their routes not yet reached (the room skips those reached at the start)."""
    if not 0 <= replica < room.num_replicas:
        raise ValueError(f"replica={replica!r} is invalid: must be in [0, {room.num_replicas})")
    waypoints = room.spawns.waypoints[replica].cpu().tolist()  # (N, K, 2), each agent's own route
    lengths = room.spawns.route_length[replica].cpu().tolist()
    routes = [
        tuple((float(x), float(y)) for x, y in route[:length]) for route, length in zip(waypoints, lengths, strict=True)
    ]
    stage = room.stage[replica].cpu().tolist()
    return Scene(
        positions=room.positions[replica].cpu().double().numpy(),
        exit_index=room.exit_index[replica].cpu().numpy().astype(np.int64),
        waypoints=tuple(route[step:] for route, step in zip(routes, stage, strict=True)),
    )


EXIT_APRON_DEPTH: Final = 1.0
"""Depth (m) of the apron outside each exit: JuPedSim's exit stage, a polygon the agent's centre enters, and the
agents' target (its centre). 0.5 m is too shallow for the social force model: the repulsion of the apron's far end,
``A exp((r - d) / B)``, balances the driving force ``m v0 / tau`` about 0.6 m from it for a body of 0.4 m, and held
such bodies just before the exit line. The generalized centrifugal force model gets a deeper one
(:func:`apron_depth`)."""
GCFM_WALL_REACH: Final = 2.0
"""JuPedSim's ``max_geometry_interaction_distance`` (m) of the generalized centrifugal force model, its default: a
wall repels an agent moving towards it while the gap between the wall and the agent's ellipse is below it."""


def apron_depth(model: JuPedSimModel) -> float:
    """Depth (m) of the exit aprons for ``model``: :data:`EXIT_APRON_DEPTH`, but for the generalized centrifugal force
    model so deep that the apron's far end does not reach an agent on the exit line,
    ``GCFM_WALL_REACH + a_min + a_v v0`` (the wall's reach beyond the ellipse's semi-axis along the walk at full speed,
    ``a_min = radius``, ``a_v = 1 s``): 3.6 m for bodies of 0.4 m at 1.2 m/s.

    That model's wall force is JuPedSim's largest, 3 N against a driving force of ``m v0 / tau`` = 2.4 N, wherever
    the wall is closer than ``0.4 m + 2 a`` to the agent's centre (``a = a_min + a_v v``). Behind a 1 m apron a body
    of 0.4 m therefore stalled 1.2 m from the far end, short of the exit line, and crept over it at 0.01 m/s; the
    crowd behind it blocked the door (in the paper's room 86 % of 100 agents failed)."""
    if model.model != "generalized_centrifugal_force":
        return EXIT_APRON_DEPTH
    return max(EXIT_APRON_DEPTH, GCFM_WALL_REACH + model.radius + 1.0 * model.desired_speed)

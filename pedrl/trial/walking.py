"""How a controller walks where nobody is near: one walker alone in a free corridor and in its own room.

A pedestrian model walks at its free speed straight to its goal where nothing is in its way (RiMEA 1, RiMEA 4's
lowest densities). :func:`probe_walking` places one walker alone, in ``R`` single-walker rooms at once, and lets the
controller act (a learned policy at ``epsilon=0``), in the torch step:

- ``corridor``: RiMEA 1's free corridor (``corridor_length x corridor_width``, 40 m x 2 m, its exit the far end),
  the walker starting at its closed end at each of ``lateral`` places across the width and each of ``headings``
  start headings (degrees from the corridor's axis);
- ``room``: ``places`` random placements in the controller's own room (its spawn areas, random headings), walking to
  its exit (a waypoint first where the room has a route).

Every decision of every walker counts. Measured from the action the walker takes (the speed and heading it commands,
as :func:`pedrl.sim.actions.apply_actions` sets them, before the motion model moves it):

- ``straight``: the share of decisions at the top speed and within one turn step of the bearing of its goal point
  (the smallest non-zero ``turn_ratios`` times pi: 9 degrees in the goal frame of the presets);
- ``heading_offset``: the mean absolute angle between the commanded heading and the bearing of the goal (degrees);
- ``speed_ratio``: the mean commanded speed over the top speed v0;
- ``decisions``: the mean decisions to walk the corridor (40 m), and ``arrived``, the share of corridor walkers that
  left through its exit within ``max_decisions``.

The greedy walker (:class:`pedrl.sim.controllers.GreedyDoorController`) walks the same scenes beside it. The verdict
(:meth:`FreeWalking.passed`) asks for at least :data:`MIN_STRAIGHT` of the decisions straight at top speed and every
corridor walker out within :data:`MAX_DECISION_RATIO` times the greedy walker's decisions (31 for its 29 at 1.34 m/s).
Its control: a walker that always heads 45 degrees off the goal bearing fails it (``tests/trial/test_walking.py``).

:class:`WalkingLog` is the trainers' use: the probe of the learned policy every ``logger.walking_probes``-th of a
run (``walking/*`` in TensorBoard, ``walking_*`` columns of ``learning_curve.csv``); ``python -m
pedrl.evaluation.free_walking`` is the command.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, Final

import torch

from pedrl.common.checks import check_integer, check_number
from pedrl.scenarios.builders import straight_corridor
from pedrl.sim import RoomEnv, RoomParams
from pedrl.sim.controllers import GreedyDoorController
from pedrl.sim.geometry import X, Y, wrap_angle
from pedrl.trial.loop import crowd_loop

MIN_STRAIGHT: Final = 0.9
"""Least share of a lone walker's decisions at top speed within one turn step of the goal bearing to pass."""
MAX_DECISION_RATIO: Final = 31.0 / 29.0
"""Most decisions to walk the corridor, over the greedy walker's, to pass: 31 for 29 at 1.34 m/s."""
MAX_PROBES: Final = 10_000
"""Most probes a training run may ask for (``logger.walking_probes``)."""
TOLERANCE: Final = 1e-4
"""Slack of the top-speed and the turn-step comparisons (float32 rounding)."""


@dataclass(frozen=True)
class WalkingSettings:
    """The scenes of the probe (module docstring), checked when built: a bad value ends in a one-line ``ValueError``
    before any compute.

    Attributes:
        lateral: start places across the corridor's width (evenly spaced, clear of the walls by a body radius).
        headings: start headings in the corridor, degrees from its axis (0: facing the exit).
        places: random placements in the walker's own room (0: the corridor only).
        corridor_length: the corridor's length (m).
        corridor_width: its width (m).
        max_decisions: decisions each walker gets before it is counted as not arrived.
        seed: the room placements and the controller's random draws.
    """

    lateral: int = 3
    headings: tuple[float, ...] = (0.0, 45.0, -45.0, 90.0, -90.0, 180.0)
    places: int = 8
    corridor_length: float = 40.0
    corridor_width: float = 2.0
    max_decisions: int = 120
    seed: int = 0

    def __post_init__(self) -> None:
        check_integer("lateral", self.lateral, minimum=1, maximum=100)
        if len(self.headings) == 0:
            raise ValueError("headings=[] is invalid: must name at least one start heading in [-180, 180] degrees")
        for heading in self.headings:
            check_number("heading", heading, low=-180.0, high=180.0)
        object.__setattr__(self, "headings", tuple(float(h) for h in self.headings))
        check_integer("places", self.places, minimum=0, maximum=10_000)
        check_number("corridor_length", self.corridor_length, low=4.0, high=1000.0)
        check_number("corridor_width", self.corridor_width, low=1.0, high=100.0)
        check_integer("max_decisions", self.max_decisions, minimum=1, maximum=100_000)
        check_integer("seed", self.seed, minimum=0, maximum=2**31 - 1)


@dataclass(frozen=True)
class Walk:
    """What one controller did in one kind of scene.

    Attributes:
        straight: share of decisions at top speed within one turn step of the goal bearing.
        heading_offset: mean absolute offset of the commanded heading from the goal bearing (degrees).
        speed_ratio: mean commanded speed over the top speed.
        decisions: mean decisions to leave of the walkers that left (NaN if none did).
        arrived: share of the walkers that left through their exit within the decisions given.
        count: decisions measured.
    """

    straight: float
    heading_offset: float
    speed_ratio: float
    decisions: float
    arrived: float
    count: int


@dataclass(frozen=True)
class FreeWalking:
    """The probe's figures for a controller (``corridor``, ``room``: :class:`Walk`) and the greedy walker's in the
    same corridor scenes (``greedy_corridor``, the reference of the decisions)."""

    corridor: Walk
    room: Walk | None
    greedy_corridor: Walk

    @property
    def straight(self) -> float:
        """Share of every decision (corridor and room) at top speed within one turn step of the goal bearing."""
        return _pooled(self.corridor, self.room, "straight")

    @property
    def heading_offset(self) -> float:
        """Mean absolute heading offset over every decision (degrees)."""
        return _pooled(self.corridor, self.room, "heading_offset")

    @property
    def speed_ratio(self) -> float:
        """Mean commanded speed over v0, over every decision."""
        return _pooled(self.corridor, self.room, "speed_ratio")

    @property
    def decision_ratio(self) -> float:
        """Decisions to walk the corridor over the greedy walker's (inf when a walker never arrived)."""
        if self.corridor.arrived < 1.0:
            return math.inf
        return self.corridor.decisions / self.greedy_corridor.decisions

    def passed(self) -> bool:
        """At least :data:`MIN_STRAIGHT` straight at top speed, and the corridor walked by every walker in at most
        :data:`MAX_DECISION_RATIO` times the greedy walker's decisions."""
        return self.straight >= MIN_STRAIGHT and self.decision_ratio <= MAX_DECISION_RATIO + TOLERANCE

    def scalars(self) -> dict[str, float]:
        """The figures by the names training logs them (``walking/<name>``, ``walking_<name>``)."""
        return {
            "straight": self.straight,
            "heading_offset_deg": self.heading_offset,
            "speed_ratio": self.speed_ratio,
            "corridor_decisions": self.corridor.decisions,
            "corridor_arrived": self.corridor.arrived,
            "greedy_corridor_decisions": self.greedy_corridor.decisions,
        }


SCALARS: Final = (
    "straight",
    "heading_offset_deg",
    "speed_ratio",
    "corridor_decisions",
    "corridor_arrived",
    "greedy_corridor_decisions",
)
"""The names of :meth:`FreeWalking.scalars`, in order."""


def _pooled(corridor: Walk, room: Walk | None, name: str) -> float:
    parts = [w for w in (corridor, room) if w is not None and w.count > 0]
    total = sum(w.count for w in parts)
    return sum(getattr(w, name) * w.count for w in parts) / total if total else math.nan


def corridor_room(params: RoomParams, settings: WalkingSettings, copies: int, device: torch.device) -> RoomEnv:
    """The free corridor of ``settings`` with one walker in each of its ``scenes x copies`` replicas."""
    scenario = straight_corridor(settings.corridor_length, settings.corridor_width)
    scenes = settings.lateral * len(settings.headings)
    return RoomEnv(
        scenario.geometry(goal_depth=params.goal_depth, device=device),
        replace(params, max_decisions=settings.max_decisions),
        num_replicas=scenes * copies,
        num_agents=1,
        device=device,
    )


def corridor_start(room: RoomEnv, settings: WalkingSettings, copies: int) -> dict[str, torch.Tensor]:
    """Hand placement of :func:`corridor_room`: scene-major, each scene ``copies`` times in a row (so that a policy
    of ``copies = P x E`` rooms per scene acts with every learning process)."""
    radius, width = room.params.agent_radius, settings.corridor_width
    margin = radius + 0.05
    lateral = (
        torch.linspace(margin, width - margin, settings.lateral) if settings.lateral > 1 else torch.tensor([width / 2])
    )
    headings = torch.tensor(settings.headings) * (math.pi / 180.0)
    ys = lateral.repeat_interleave(len(settings.headings))
    angles = headings.repeat(settings.lateral)
    positions = torch.stack((torch.full_like(ys, radius + 0.05), ys), dim=-1)
    positions = positions.repeat_interleave(copies, 0)[:, None].to(room.device)
    return {"positions": positions, "headings": angles.repeat_interleave(copies)[:, None].to(room.device)}


class _Measured:
    """``controller`` acting, every decision's commanded speed and heading measured against the goal bearing (module
    docstring) before the room moves the walkers: a controller of :func:`pedrl.trial.loop.crowd_loop`."""

    def __init__(self, controller: Any, params: RoomParams) -> None:
        self.controller, self.max_speed = controller, params.max_speed
        turns = torch.tensor(params.turn_ratios, dtype=torch.float32).abs() * math.pi
        self.turn_step = float(turns[turns > 0].min()) if bool((turns > 0).any()) else 0.0
        self.straight = self.offsets = self.speeds = 0.0
        self.count = 0

    def act(self, env: Any, obs: torch.Tensor, info: Any) -> torch.Tensor:
        actions = self.controller.act(env, obs, info)
        acting = env.active
        to_goal = env.targets() - env.positions
        speeds, headings = env.decide(actions)
        offset = wrap_angle(headings - torch.atan2(to_goal[..., Y], to_goal[..., X])).abs()[acting]
        speed = speeds[acting] / self.max_speed
        top, aligned = speed >= 1.0 - TOLERANCE, offset <= self.turn_step + TOLERANCE
        self.straight += float((top & aligned).sum())
        self.offsets += float(offset.sum())
        self.speeds += float(speed.sum())
        self.count += int(acting.sum())
        return actions


def walk(room: RoomEnv, controller: Any, *, seed: int, options: dict[str, torch.Tensor] | None = None) -> Walk:
    """One trial of single walkers in every replica of ``room`` with ``controller`` (``act(env, obs, info)``) in the
    torch step (:func:`pedrl.trial.loop.crowd_loop`), every decision measured (module docstring)."""
    measured = _Measured(controller, room.params)
    record = crowd_loop(room, measured, record=True, start=room.reset(seed=seed, options=options)).record
    left = torch.from_numpy(record.exit_time[:, 0] * room.params.decisions_per_second)
    arrived = left.isfinite()
    count = measured.count
    return Walk(
        straight=measured.straight / count if count else math.nan,
        heading_offset=math.degrees(measured.offsets / count) if count else math.nan,
        speed_ratio=measured.speeds / count if count else math.nan,
        decisions=float(left[arrived].mean()) if bool(arrived.any()) else math.nan,
        arrived=float(arrived.double().mean()),
        count=count,
    )


def probe_walking(
    make_controller: Callable[[], Any],
    params: RoomParams,
    *,
    home: Callable[..., RoomEnv] | None = None,
    settings: WalkingSettings | None = None,
    copies: int = 1,
    device: str | torch.device = "cpu",
    greedy_corridor: Walk | None = None,
) -> FreeWalking:
    """The free-walking figures of the controllers ``make_controller()`` builds (one per kind of scene, each seeded
    by the caller or at ``epsilon=0``) and of the greedy walker beside them in the corridor.

    Args:
        make_controller: builds the controller under test, ``act(env, obs, info) -> (R, 1)``.
        params: the room settings the controller acts in (bodies, speeds, sensing, actions, motion).
        home: the controller's own room, ``home(num_replicas=, num_agents=, device=)`` (None: the corridor only).
        settings: the scenes (None: :class:`WalkingSettings`' defaults).
        copies: replicas per scene (``P x E`` for a policy of ``P`` processes of ``E`` rooms: each acts).
        device: where the rooms run.
        greedy_corridor: the greedy walker's corridor walk under the same ``params``, ``settings`` and ``copies``,
            when the caller already has it (None: walked here).
    """
    settings = settings if settings is not None else WalkingSettings()
    check_integer("copies", copies, minimum=1, maximum=100_000)
    device = torch.device(device)

    def corridor(controller: Any) -> Walk:
        room = corridor_room(params, settings, copies, device)
        return walk(room, controller, seed=settings.seed, options=corridor_start(room, settings, copies))

    def own(controller: Any) -> Walk | None:
        if home is None or settings.places == 0:
            return None
        room = home(num_replicas=settings.places * copies, num_agents=1, device=device)
        return walk(room, controller, seed=settings.seed)

    return FreeWalking(
        corridor=corridor(make_controller()),
        room=own(make_controller()),
        greedy_corridor=greedy_corridor if greedy_corridor is not None else corridor(GreedyDoorController()),
    )


def probe_learned(
    policy: Any,
    params: RoomParams,
    *,
    home: Callable[..., RoomEnv] | None,
    settings: WalkingSettings | None = None,
    greedy_corridor: Walk | None = None,
) -> FreeWalking:
    """:func:`probe_walking` of a learned ``policy`` (tables or network: ``policy.controller(epsilon, generator)``) at
    ``epsilon=0``, its random draws seeded by ``settings.seed``, every learning process acting."""
    settings = settings if settings is not None else WalkingSettings()

    def make() -> Any:
        return policy.controller(0.0, torch.Generator(device=policy.device).manual_seed(settings.seed))

    copies = policy.num_processes * policy.layout.rooms_per_process
    return probe_walking(
        make, params, home=home, settings=settings, copies=copies, device=policy.device, greedy_corridor=greedy_corridor
    )


class WalkingLog:
    """The probe during training: :func:`probe_learned` of the learned policy after every ``every``-th trial and after
    the last, its own rooms and draws (the run's generators are not touched, so a run gives the same tables, network
    and curve with the probe on or off).

    Args:
        probes: probes over the run (0: none), evenly spaced: every ``ceil(trials / probes)`` trials.
        trials: the run's trials, over every phase.
        params: the run's room settings.
        home: the run's own room, ``home(num_replicas=, num_agents=, device=)``.
    """

    def __init__(self, probes: int, trials: int, params: RoomParams, home: Callable[..., RoomEnv]) -> None:
        check_integer("logger.walking_probes", probes, minimum=0, maximum=MAX_PROBES)
        self.every = math.ceil(trials / probes) if probes else 0
        self.trials, self.params, self.home = trials, params, home
        self.greedy_corridor: Walk | None = None  # the greedy walker's corridor walk: the same at every probe

    def due(self, global_trial: int) -> bool:
        """Whether the probe runs after the trial ``global_trial`` (counted from 0 over the run)."""
        done = global_trial + 1
        return self.every > 0 and (done % self.every == 0 or done == self.trials)

    def measure(self, global_trial: int, policy: Any) -> dict[str, float] | None:
        """:meth:`FreeWalking.scalars` of ``policy`` when :meth:`due`, else None."""
        if not self.due(global_trial):
            return None
        probe = probe_learned(policy, self.params, home=self.home, greedy_corridor=self.greedy_corridor)
        self.greedy_corridor = probe.greedy_corridor
        return probe.scalars()

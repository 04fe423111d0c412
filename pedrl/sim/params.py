"""The constants of a batch of rooms, :class:`RoomParams`: every setting of :class:`pedrl.sim.RoomEnv` but the batch
shape, the device and the walkable area, validated, with what the fast path (the fused numba trial) supports of each
and how the fast path's kernels receive it.

Each field declares, with :func:`setting`, its fast-path support (every value, :data:`ANY`, or only some,
:func:`only`; a class listed stands for its instances: the motion models) and how it reaches the kernels:
:func:`kernel` (an entry of :data:`KernelRoom` computed from the value, named as the field or as told), :func:`model`
(several entries computed from a motion model, with the model's fields they read), :func:`derived` (an entry computed
from the built room, for values that several settings make), :func:`through` (the setting takes part in another
field's entry) or :func:`host` (the kernels never read it, with the reason). :meth:`RoomParams.fast_path_reason` is an
allow-list computed from the support, and :data:`KernelRoom` and :meth:`RoomParams.kernel_room` are built from the
packing declarations, so that a setting the fast path supports cannot be left out of what the kernels receive: a
field without both declarations, or a field of a motion model the fast path runs that its packing does not read, is a
``TypeError`` when this module is imported.
"""

from __future__ import annotations

from collections import namedtuple
from collections.abc import Callable, Mapping
from dataclasses import MISSING, dataclass, field, fields
from typing import Any, Final

import numpy as np
import torch

from pedrl.sim.actions import DEFAULT_SPEED_RATIOS, DEFAULT_TURN_RATIOS
from pedrl.sim.motion import CONTACT_MODELS, Continuous, Headway, MotionModel, Slide, Stop, Yield
from pedrl.sim.motion.common import STEERING_NAMES, neighbour_search, steering_constant
from pedrl.sim.rewards import PASSING_SIDES, REWARD_DEFAULTS, RewardTable
from pedrl.sim.room_checks import check_substeps, check_time_steps, checked_settings

__all__ = [
    "ANY",
    "FastSupport",
    "KernelRoom",
    "RoomParams",
    "derived",
    "host",
    "kernel",
    "model",
    "only",
    "setting",
    "through",
    "undeclared",
    "unread",
]

FAST: Final = "fast"
"""The metadata key of a field's :class:`FastSupport`."""
PACKING: Final = "packing"
"""The metadata key of a field's :class:`Packing`."""


@dataclass(frozen=True)
class FastSupport:
    """The values of a setting that the fast path runs: all (``values`` None) or those listed (a class listed stands
    for its instances, whatever their parameters, but not for a subclass's: a motion model's class)."""

    values: tuple[Any, ...] | None = None

    def reason(self, name: str, value: Any) -> str | None:
        """Why the fast path cannot run with ``name=value`` (one phrase), or None when it can."""
        if self.values is None or value in self.values:
            return None
        if type(value) in self.classes():
            return None
        shown = [_shown(v) for v in self.values]
        allowed = shown[0] if len(shown) == 1 else f"{', '.join(shown[:-1])} or {shown[-1]}"
        return f"with {name}={_shown(value)} (it runs {name}={allowed})"

    def classes(self) -> tuple[type, ...]:
        """The classes listed (their instances run)."""
        return tuple(value for value in self.values or () if isinstance(value, type))


ANY: Final = FastSupport()
"""Every value runs on the fast path."""


def only(*values: Any) -> FastSupport:
    """Only ``values`` run on the fast path."""
    return FastSupport(tuple(values))


@dataclass(frozen=True)
class Packing:
    """How a setting reaches the kernels: as entries of :data:`KernelRoom`, each ``(name, value(setting, room))`` (a
    name None: the field's); through another field's entry (``through``); or not at all (``host``, with the reason).
    ``reads``: for a motion model, the fields of the model that its entries (or the room's derived ones) read."""

    entries: tuple[tuple[str | None, Callable[[Any, Any], Any]], ...] = ()
    through: str | None = None
    host: str | None = None
    reads: tuple[str, ...] = ()


def kernel(convert: Callable[[Any], Any], entry: str | None = None) -> Packing:
    """The kernels read ``convert(value)`` as the entry ``entry`` (None: the field's name)."""
    return Packing(((entry, lambda value, room: convert(value)),))


def model(*, reads: tuple[str, ...], **entries: Callable[[Any], Any]) -> Packing:
    """A motion model reaches the kernels as several entries, each ``convert(model)``, which read the model's fields
    ``reads`` between them: every field of every model class the fast path runs must be among them
    (:func:`unread`)."""
    packed = tuple((entry, lambda value, room, convert=convert: convert(value)) for entry, convert in entries.items())
    return Packing(packed, reads=reads)


def derived(entry: str, value: Callable[[Any], Any]) -> Packing:
    """The kernels read ``value(room)`` (the built ``RoomEnv``) as the entry ``entry``: a constant that this setting
    and others make (e.g. the sub-steps of a decision)."""
    return Packing(((entry, lambda _, room: value(room)),))


def through(entry: str) -> Packing:
    """The setting reaches the kernels in another field's entry ``entry``."""
    return Packing(through=entry)


def host(reason: str) -> Packing:
    """The kernels never read the setting (``reason``: where it acts instead)."""
    return Packing(host=reason)


def setting(support: FastSupport, packing: Packing, default: Any = MISSING) -> Any:
    """A :class:`RoomParams` field with its fast-path ``support`` and its ``packing`` for the kernels declared, and its
    ``default`` (the config's: ``conf/env/room.yaml``, ``conf/motion/stop.yaml``)."""
    if not isinstance(support, FastSupport) or not isinstance(packing, Packing):
        raise TypeError("setting(support, packing): a FastSupport (ANY, only(...)) and a Packing (kernel(...), ...)")
    return field(default=default, metadata={FAST: support, PACKING: packing})


def _shown(value: Any) -> str:
    """A value as the config writes it: ``true``, a motion model (or its class) by its name."""
    if isinstance(value, bool):
        return str(value).lower()
    return value.name if isinstance(value, MotionModel | type) else str(value)


_AREA: Final = "the walkable area, which the kernels read as walls and exits (Geometry.kernel_walls, kernel_exits)"


def _float32(values: torch.Tensor) -> np.ndarray:
    return values.to(torch.float32).numpy()


@dataclass(frozen=True)
class RoomParams:
    """The settings of a room, checked when they are made (a one-line ``ValueError`` naming the bad value): what
    ``RoomEnv(area, params, ...)`` takes besides the walkable area and the batch. ``RoomParams(max_speed=1.34,
    motion=Yield(order="door_first"))`` is the keyword way to write them; ``dataclasses.replace`` changes some.

    Attributes:
        agent_radius: Body radius (m, ``> 0``); a body must fit through every exit of the area.
        max_speed: Maximum speed (m/s, ``> 0``).
        decisions_per_second: Decisions per simulated second (1/s, ``> 0``).
        max_decisions: Decisions per trial before the remaining agents are truncated (``>= 1``).
        num_neighbours: Number k of sensed neighbours (``>= 0``).
        num_walls: Number w of sensed walls (``>= 0``, at most the area's walls).
        speed_ratios: Speed change of each of the 9 speed indices, as a fraction of ``max_speed`` (index 4, the
            no-op, 0); in the ``goal`` frame the speed itself, each in ``[0, 1]``.
        turn_ratios: Heading change of each of the 9 turn indices, as a fraction of pi (rad) (index 4, the no-op, 0);
            in the ``goal`` frame the heading relative to the bearing of the goal point.
        reward_goal: Reward for reaching the door.
        reward_crash_wall: Reward for a decision in which the agent hit a wall.
        reward_crash_agent: Reward for a decision in which the agent hit another (and no wall).
        reward_default: Reward otherwise: -1 is a time cost per decision (the paper's Table 2 has 0).
        substep_length: Longest move per sub-step (m), in ``(0, agent_radius]``; ``None`` means ``agent_radius``
            (:attr:`substep`). Every motion model sub-steps a decision by it.
        goal_depth: How far behind each exit its goal point lies (m, ``>= 0``): the reference line of the state
            (paper Table 1) runs to it. 0 is the exit's centre.
        reward_progress: Reward per metre by which a decision brings the agent closer to the goal point (``>= 0``;
            0 is the paper's Table 2, 1 the default): walking to the door at 2 m/s earns ``2 * reward_progress`` per
            decision, standing still 0.
        reward_deviation: Reward per unit of a decision's commanded deviation from the greedy walker's velocity,
            ``(1 - speed / max_speed) + deviation_turn |heading - bearing of the goal point| / pi`` (``<= 0``; 0, the
            default, and the paper: none; :class:`pedrl.sim.rewards.RewardTable`).
        deviation_turn: Weight of the heading part of that deviation, in ``[0, MAX_DEVIATION_TURN]``: 1 (the default)
            prices a quarter turn off the goal bearing as half a stop; 0 prices the speed only, so that stepping
            aside costs nothing and slowing down does.
        deviation_radius: Price that deviation only where no other walker of the room stands within this distance
            (m, in ``[0, MAX_DEVIATION_RADIUS]``) of the deciding walker: a walker in company deviates for free, a
            free walker pays (:func:`pedrl.sim.rewards.unpriced_in_company`); 0 (the default): priced everywhere.
        deviation_gate: Who within that radius frees a walker from the price
            (:data:`pedrl.sim.rewards.DEVIATION_GATES`): ``"company"`` (the default), any other walker; ``"oncoming"``,
            only one ahead of it on the line to its goal that commands a velocity against that line, so that walkers
            going the same way pay as a free walker does.
        reward_passing: Reward per decision in which an oncoming walker within ``passing_radius`` ahead of the agent
            is on the wrong side of its line to its goal (``<= 0``; 0, the default, and the paper: none;
            :func:`pedrl.sim.rewards.wrong_side_passing`).
        passing_radius: How far ahead (m, in ``[0, MAX_DEVIATION_RADIUS]``; 4, the default) an oncoming walker
            counts for ``reward_passing``.
        passing_band: How far off the agent's line to its goal (m, in ``[0, MAX_DEVIATION_RADIUS]``; 0.8, the
            default) an oncoming walker must be, on the side ``passing_side`` asks, for ``reward_passing`` not to be
            paid.
        passing_side: That side (:data:`pedrl.sim.rewards.PASSING_SIDES`): ``"either"`` (the default), ``"right"``
            (the agent keeps right: the oncoming walker on its left) or ``"left"``.
        compile_sensing: Run the sensing through ``torch.compile`` (inductor; needs a C++ compiler on CPU). Off by
            default: about a third of the sensing saved for 10 to 30 s of compilation per process, and features that
            differ from the eager ones in the last bits (docs/configuration.md).
        action_frame: What an action changes (``pedrl.sim.actions.ACTION_FRAMES``): ``"heading"`` (the paper: speed
            and heading change from their current values) or ``"goal"`` (the action sets the speed and the heading
            relative to the bearing of the agent's goal point, its door or waypoint).
        motion: How bodies move through a decision: a motion model of :mod:`pedrl.sim.motion` with its parameters
            (``Stop``, the paper's reading, by default; ``Simultaneous``, ``Slide``, ``Headway``, ``Yield``,
            ``Continuous``: docs/configuration.md, "Motion models"). Under every model but ``Stop`` and
            ``Simultaneous`` the speed after the step is the distance actually walked per second. A contact
            (``info["crashed_agent"]``, ``crashed_wall``, the crash rewards) is a decision in which another body (a
            wall) cut the agent's move: stopped it, or deflected it; slowing down for a body ahead is no contact, and
            a wall contact takes precedence.
        queue_weight: How much an agent without an assigned exit weighs the queue at each exit when it chooses one
            at placement (in ``[0, MAX_QUEUE_WEIGHT]``; 0: the exit of the shortest route; :mod:`pedrl.sim.routing`).
    """

    agent_radius: float = setting(ANY, kernel(float), 0.4)
    max_speed: float = setting(ANY, kernel(np.float32), 2.5)
    decisions_per_second: float = setting(
        ANY, derived("decision_length", lambda room: float(room.params.decision_length)), 1.0
    )
    max_decisions: int = setting(ANY, kernel(int), 200)
    num_neighbours: int = setting(ANY, kernel(int), 7)
    num_walls: int = setting(ANY, kernel(int), 2)
    speed_ratios: tuple[float, ...] = setting(
        ANY, derived("speed_changes", lambda room: _float32(room.speed_changes)), DEFAULT_SPEED_RATIOS
    )
    turn_ratios: tuple[float, ...] = setting(
        ANY, derived("turn_changes", lambda room: _float32(room.turn_changes)), DEFAULT_TURN_RATIOS
    )
    reward_goal: float = setting(ANY, kernel(np.float32), REWARD_DEFAULTS["reward_goal"])
    reward_crash_wall: float = setting(ANY, kernel(np.float32), REWARD_DEFAULTS["reward_crash_wall"])
    reward_crash_agent: float = setting(ANY, kernel(np.float32), REWARD_DEFAULTS["reward_crash_agent"])
    reward_default: float = setting(ANY, kernel(np.float32), REWARD_DEFAULTS["reward_default"])
    substep_length: float | None = setting(ANY, derived("num_substeps", lambda room: int(room.num_substeps)), None)
    goal_depth: float = setting(ANY, host(_AREA), 0.0)
    reward_progress: float = setting(ANY, kernel(np.float32), REWARD_DEFAULTS["reward_progress"])
    reward_deviation: float = setting(ANY, kernel(np.float32), REWARD_DEFAULTS["reward_deviation"])
    deviation_turn: float = setting(ANY, kernel(np.float32), 1.0)
    deviation_radius: float = setting(ANY, kernel(np.float32), 0.0)
    deviation_gate: str = setting(ANY, kernel(lambda gate: gate == "oncoming", "deviation_oncoming"), "company")
    reward_passing: float = setting(ANY, kernel(np.float32), REWARD_DEFAULTS["reward_passing"])
    passing_radius: float = setting(ANY, kernel(np.float32), 4.0)
    passing_band: float = setting(ANY, kernel(np.float32), 0.8)
    passing_side: str = setting(ANY, kernel(PASSING_SIDES.index), "either")
    compile_sensing: bool = setting(only(False), host("the fast path senses in its own kernel"), False)
    action_frame: str = setting(ANY, kernel(lambda frame: frame == "goal", "goal_frame"), "heading")
    # every model but Simultaneous (Stop only with axis-aligned walls: RoomEnv.fast_path_reason); its time_step
    # reaches the kernels in num_substeps, the room's sub-steps of a decision
    motion: MotionModel = setting(
        only(Stop, Slide, Headway, Yield, Continuous),
        model(
            reads=("order", "contact", "time_gap", "time_step", "steering"),
            contact=lambda motion: CONTACT_MODELS.index(motion.contact),
            door_first=lambda motion: motion.order == "door_first",
            time_gap=lambda motion: float(1.0 if motion.time_gap is None else motion.time_gap),  # headway rules only
            continuous=lambda motion: motion.steering is not None,
            **{
                f"steering_{name}": lambda motion, name=name: steering_constant(motion.steering, name)
                for name in STEERING_NAMES
            },
            # the neighbour search (grids from GRID_MIN_AGENTS agents, exact reaches)
            grid_min_agents=lambda motion: neighbour_search().min_agents,
            grid_reach_scale=lambda motion: neighbour_search().reach_scale,
        ),
        Stop(),
    )
    queue_weight: float = setting(ANY, host("used at placement, in torch"), 0.0)

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any] | None = None, /, **more: Any) -> RoomParams:
        """The settings given by name (a mapping and keywords alike), the rest the defaults; a name that is no
        setting is a one-line ``ValueError`` listing the settings (where ``RoomParams(...)`` raises a ``TypeError``)."""
        given = {**(settings or {}), **more}
        names = [item.name for item in fields(cls)]
        for name in given:
            if name not in names:
                raise ValueError(f"{name} is not a setting of the room: its settings are {', '.join(names)}")
        return cls(**given)

    def __post_init__(self) -> None:
        for name, value in checked_settings(self).items():  # the checked, normalised values (floats, tuples)
            object.__setattr__(self, name, value)

    @property
    def decision_length(self) -> float:
        """Duration of a decision (s): ``1 / decisions_per_second``."""
        return 1.0 / self.decisions_per_second

    @property
    def substep(self) -> float:
        """The longest move per sub-step (m): ``substep_length``, or the body radius where it is None."""
        return self.agent_radius if self.substep_length is None else self.substep_length

    @property
    def num_substeps(self) -> int:
        """Sub-steps per decision: the step model's, and on the walking layer at least one per ``time_step``."""
        steps = check_substeps(self.max_speed, self.decisions_per_second, self.substep)
        return check_time_steps(steps, self.motion, self.decision_length)

    @property
    def rewards(self) -> RewardTable:
        """The rewards (``reward_goal``, ``reward_crash_wall``, ``reward_crash_agent``, ``reward_default``,
        ``reward_progress``, ``reward_deviation``) as their table."""
        return RewardTable.of(self)

    def kernel_room(self, room: Any) -> KernelRoom:
        """The constants the kernels read (:data:`KernelRoom`), each from its field's packing declaration; ``room``
        is the built ``RoomEnv`` of these settings (for the :func:`derived` entries)."""
        return KernelRoom(
            **{
                entry or item.name: value(getattr(self, item.name), room)
                for item in fields(self)
                for entry, value in item.metadata[PACKING].entries
            }
        )

    def fast_path_reason(self) -> str | None:
        """Why the fast path cannot run these settings (one phrase, the first setting it does not support), or None."""
        for item in fields(self):
            reason = item.metadata[FAST].reason(item.name, getattr(self, item.name))
            if reason is not None:
                return reason
        return None


def undeclared(cls: type) -> list[str]:
    """The fields of the dataclass ``cls`` that declare no fast-path support or no packing."""
    return [
        item.name
        for item in fields(cls)
        if not isinstance(item.metadata.get(FAST), FastSupport) or not isinstance(item.metadata.get(PACKING), Packing)
    ]


def _kernel_entries(cls: type) -> list[str]:
    """The entries of the kernels' room constants declared by ``cls``'s fields, in field order; ``TypeError`` for a
    :func:`through` that names no entry, two fields packed into one entry, or a field of a model the fast path runs
    that its packing does not read (:func:`unread`)."""
    packings = [(item.name, item.metadata[PACKING]) for item in fields(cls)]
    entries = [entry or name for name, packing in packings for entry, _ in packing.entries]
    if len(set(entries)) != len(entries):
        raise TypeError(f"two settings of {cls.__name__} are packed into one kernel entry: {entries}")
    for name, packing in packings:
        if packing.through is not None and packing.through not in entries:
            raise TypeError(f"{cls.__name__}.{name} reaches the kernels through {packing.through!r}, no entry")
    missing = unread(cls)
    if missing:
        raise TypeError(f"the fast path runs model fields that {cls.__name__}'s packing does not read: {missing}")
    return entries


def unread(cls: type) -> list[str]:
    """``setting.Model.field`` for each field of a model class that a setting of the dataclass ``cls`` lists as run
    by the fast path, and that the setting's packing does not read (:func:`model`'s ``reads``)."""
    missing = []
    for item in fields(cls):
        packing, support = item.metadata.get(PACKING), item.metadata.get(FAST)
        if isinstance(packing, Packing) and isinstance(support, FastSupport) and packing.host is None:
            for klass in support.classes():
                missing += [
                    f"{item.name}.{klass.__name__}.{f.name}" for f in fields(klass) if f.name not in packing.reads
                ]
    return missing


KernelRoom = namedtuple("KernelRoom", _kernel_entries(RoomParams), module=__name__)
"""The room constants the numba kernels read, by name: one entry per :func:`kernel` or :func:`derived` declaration of
:class:`RoomParams` (built from the declarations, in field order)."""

"""The checks of ``RoomEnv``'s arguments, ``reset`` options and actions: each a one-line ``ValueError`` that names the
bad value (the generic checks of a number, a choice or a device are in :mod:`pedrl.common.checks`)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, Final

import torch

from pedrl.common.checks import check_choice, check_number, check_real
from pedrl.sim.actions import NOOP_INDEX, NUM_SPEED_CHANGES, count_substeps
from pedrl.sim.geometry import Geometry
from pedrl.sim.motion import COLLISION_RULES, CONTACT_MODELS
from pedrl.sim.rewards import MAX_REWARD, RewardTable

COLLISION_ORDERS: Final = ("random", "door_first")
"""Orders of action of the sequential collision rule (see ``RoomEnv``)."""
OPTION_KEYS: Final = ("positions", "headings", "speeds", "replicas")
"""The keys of ``RoomEnv.reset``'s ``options``."""
MAX_SUBSTEPS: Final = 1000
"""Most sub-steps per decision (``max_speed / decisions_per_second / substep_length``, 7 by default): the sequential
collision rule loops over them, so ``max_speed=1e5`` (250 000 sub-steps) hung and ``1e9`` tried to allocate 20 GB."""


def check_extent(
    *, width: Any, length: Any, door_width: Any, agent_radius: Any, geometry: Any
) -> tuple[float, float, float, float]:
    """``(width, length, door_width, agent_radius)`` checked: positive, a body fits through the door (every exit of
    ``geometry``) and in the room; with a ``geometry``, ``width`` and ``length`` are the extent of its bounds."""
    checked_width = check_real("width", width, unit="m", positive=True)
    checked_length = check_real("length", length, unit="m", positive=True)
    checked_door = check_real("door_width", door_width, unit="m", positive=True)
    radius = check_real("agent_radius", agent_radius, unit="m", positive=True)
    if geometry is None:
        if checked_door > checked_width:
            raise ValueError(
                f"door_width={door_width!r} is invalid: the door must fit in its wall, at most width={width!r} m"
            )
        if 2.0 * radius > checked_door:
            raise ValueError(
                f"agent_radius={agent_radius!r} is invalid: a body must fit through the door, at most"
                f" door_width / 2 = {checked_door / 2.0!r} m"
            )
    elif not isinstance(geometry, Geometry):
        raise ValueError(f"geometry of type {type(geometry).__name__} is invalid: must be a pedrl.sim.Geometry")
    else:
        checked_width = geometry.bounds[2] - geometry.bounds[0]
        checked_length = geometry.bounds[3] - geometry.bounds[1]
        narrowest = float(torch.linalg.vector_norm(geometry.exits[:, 1] - geometry.exits[:, 0], dim=-1).min())
        if 2.0 * radius > narrowest:
            raise ValueError(
                f"agent_radius={agent_radius!r} is invalid: a body must fit through every exit, at most"
                f" {narrowest / 2.0:g} m (half the narrowest exit)"
            )
    if 2.0 * radius >= min(checked_width, checked_length):
        raise ValueError(
            f"agent_radius={agent_radius!r} is invalid: a body must fit in the room, less than"
            f" min(width, length) / 2 = {min(checked_width, checked_length) / 2.0!r} m"
        )
    return checked_width, checked_length, checked_door, radius


def check_ratios(
    name: str, value: Any, *, unit: str, bounds: tuple[float, float] | None = None, noop: bool | None = None
) -> tuple[float, ...]:
    """Nine finite ratios, else a one-line ``ValueError``: with ``bounds``, each within them; with ``noop`` (the
    default when there are no bounds), the no-op (index 4) equal to 0."""
    if isinstance(value, str | bytes) or not isinstance(value, Sequence | torch.Tensor):
        try:
            value = list(value)  # e.g. an OmegaConf ListConfig
        except TypeError:
            raise ValueError(f"{name}={value!r} is invalid: must be a sequence of 9 finite numbers") from None
    items = [float(item) if isinstance(item, torch.Tensor) else item for item in value]
    if len(items) != NUM_SPEED_CHANGES:
        raise ValueError(f"{name} has {len(items)} values: must be a sequence of 9 finite numbers ({unit})")
    ratios = tuple(check_real(f"{name}[{index}]", item, unit=unit) for index, item in enumerate(items))
    if bounds is not None:
        low, high = bounds
        for index, ratio in enumerate(ratios):
            if not low <= ratio <= high:
                raise ValueError(
                    f"{name}[{index}]={ratio!r} is invalid: with action_frame=goal each is a speed in [{low}, {high}]"
                    f" ({unit})"
                )
    if (bounds is None if noop is None else noop) and ratios[NOOP_INDEX] != 0.0:
        raise ValueError(f"{name}[{NOOP_INDEX}]={ratios[NOOP_INDEX]!r} is invalid: the no-op (index 4) must be 0.0")
    return ratios


MAX_SPEED_CHANGE: Final = 1.0
"""Largest ``|speed_ratios[i]|`` of the heading frame (a change of ``max_speed``): speeds are kept in ``[0,
max_speed]``, so a larger change does what this one does."""
MAX_TURN: Final = 1.0
"""Largest ``|turn_ratios[j]|`` (fractions of pi): a turn, or an offset from the goal's bearing, within +-pi."""


def check_action_set(
    speed_ratios: Any, turn_ratios: Any, *, goal_frame: bool
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """``(speed_ratios, turn_ratios)`` checked (:func:`check_ratios`) and bounded: the heading frame's speed changes
    within +-:data:`MAX_SPEED_CHANGE`, the goal frame's speeds in [0, 1], every turn within +-:data:`MAX_TURN` (+-pi);
    and not degenerate: some speed above 0 (else no walker ever moves) and two turns apart (else no walker can
    choose its heading). Each refusal is one line naming the value and what is allowed."""
    speeds = check_ratios(
        "speed_ratios", speed_ratios, unit="fraction of max_speed", bounds=(0.0, 1.0) if goal_frame else None
    )
    turns = check_ratios("turn_ratios", turn_ratios, unit="fraction of pi", noop=not goal_frame)
    for name, ratios, most, what in (
        ("speed_ratios", speeds, MAX_SPEED_CHANGE, "a speed change in [-1, 1] (fraction of max_speed)"),
        ("turn_ratios", turns, MAX_TURN, "a turn in [-1, 1] (fraction of pi: within +-pi)"),
    ):
        for index, ratio in enumerate(ratios):
            if abs(ratio) > most:
                raise ValueError(f"{name}[{index}]={ratio!r} is invalid: each is {what}")
    if max(speeds) <= 0.0:
        raise ValueError(
            f"speed_ratios={list(speeds)} is invalid: at least one must be above 0 (fraction of max_speed), else no"
            " walker ever moves"
        )
    if len(set(turns)) == 1:
        raise ValueError(
            f"turn_ratios={list(turns)} is invalid: all alike, so no walker can choose its heading; at least two must"
            " differ (fraction of pi)"
        )
    return speeds, turns


def check_rewards(goal: Any, crash_wall: Any, crash_agent: Any, default: Any) -> RewardTable:
    """The rewards of Table 2 (``reward_goal``, ``reward_crash_wall``, ``reward_crash_agent``, ``reward_default``),
    each within ``[-MAX_REWARD, MAX_REWARD]``."""
    return RewardTable(
        goal=check_number("reward_goal", goal, low=-MAX_REWARD, high=MAX_REWARD),
        crash_wall=check_number("reward_crash_wall", crash_wall, low=-MAX_REWARD, high=MAX_REWARD),
        crash_agent=check_number("reward_crash_agent", crash_agent, low=-MAX_REWARD, high=MAX_REWARD),
        default=check_number("reward_default", default, low=-MAX_REWARD, high=MAX_REWARD),
    )


def check_substep_length(substep_length: Any, agent_radius: Any) -> float:
    """``substep_length`` in ``(0, agent_radius]`` (``agent_radius``, already checked, if ``None``)."""
    if substep_length is None:
        return float(agent_radius)
    checked = check_real("substep_length", substep_length, unit="m", positive=True)
    if checked > float(agent_radius):
        raise ValueError(
            f"substep_length={substep_length!r} is invalid: must be in"
            f" (0, agent_radius={agent_radius!r}] m so that nothing tunnels"
        )
    return checked


def check_rules(collision_rule: Any, collision_order: Any, contact: Any) -> tuple[str, str, str]:
    """``(collision_rule, collision_order, contact)`` checked, and compatible: every contact model but ``stop``
    resolves movers in turn, so it needs the sequential rule."""
    rule = check_choice("collision_rule", collision_rule, COLLISION_RULES)
    order = check_choice("collision_order", collision_order, COLLISION_ORDERS)
    model = check_choice("contact", contact, CONTACT_MODELS)
    if model != "stop" and rule != "sequential":
        raise ValueError(
            f"collision_rule={collision_rule!r} is invalid with contact={contact!r}: the slide, headway and yield"
            " rules resolve movers in turn (collision_rule: sequential; it applies to contact=stop only)"
        )
    return rule, order, model


MOTIONS: Final = ("step", "continuous")
"""How bodies walk between decisions (``RoomEnv(motion=...)``): ``step``, the paper's model (the decision's velocity,
sub-stepped by ``substep_length``, under the contact rule); ``continuous``, the decision sets a desired direction and
speed and the collision-free speed model with its direction rule walks every body at a time step of ``time_step``."""
MAX_TIME_STEP: Final = 0.05
"""Longest time step (s) of ``motion=continuous``."""
CONTINUOUS_CONTACTS: Final = ("headway", "yield")


def check_motion(motion: Any, contact: str, time_step: Any, neighbour_repulsion: Any, wall_repulsion: Any):
    """``(motion, time_step, neighbour_repulsion, wall_repulsion)`` checked: ``continuous`` walks by the
    collision-free speed rule, so it needs contact ``headway`` or ``yield``; each repulsion is ``(strength >= 0,
    range > 0 m)``."""
    model = check_choice("motion", motion, MOTIONS)
    if model == "continuous" and contact not in CONTINUOUS_CONTACTS:
        raise ValueError(
            f"contact={contact!r} is invalid with motion='continuous': it walks by the collision-free speed rule"
            " (contact: headway or yield)"
        )
    step = check_number("time_step", time_step, low=0.0, high=MAX_TIME_STEP, low_open=True)
    repulsions = []
    for name, value in (("neighbour_repulsion", neighbour_repulsion), ("wall_repulsion", wall_repulsion)):
        try:
            pair = tuple(value)
        except TypeError:
            pair = ()
        if isinstance(value, str | bytes) or len(pair) != 2:
            raise ValueError(f"{name}={value!r} is invalid: must be [strength, range] (strength >= 0, range > 0 m)")
        strength = check_number(f"{name}[0]", pair[0], low=0.0, high=MAX_REWARD)
        reach = check_number(f"{name}[1]", pair[1], low=0.0, high=10.0, low_open=True)
        repulsions.append((strength, reach))
    return model, step, repulsions[0], repulsions[1]


def check_time_steps(num_substeps: int, room: Any) -> int:
    """The sub-steps of a decision of ``room`` (a ``RoomEnv`` being built): the step model's ``num_substeps``; under
    ``motion=continuous`` at least ``ceil(decision_length / time_step)``, at most :data:`MAX_SUBSTEPS`, else a
    one-line ``ValueError``."""
    if room.motion_model != "continuous":
        return num_substeps
    decision_length, time_step = room.decision_length, room.time_step
    steps = math.ceil(decision_length / time_step * (1.0 - 1e-9))  # the slack keeps e.g. 1 / 0.05 at 20
    if steps > MAX_SUBSTEPS:
        raise ValueError(
            f"time_step={time_step!r} s is invalid with decisions_per_second={1.0 / decision_length:.6g}: a decision"
            f" would take {steps} time steps; at most {MAX_SUBSTEPS} (raise time_step or decisions_per_second)"
        )
    return max(num_substeps, steps)


PAIRWISE_BYTES: Final = 40
"""Bytes per ``(replica, agent, agent)`` entry of the pairwise matrices a decision allocates (sensing distances and
sort, the swept-disc pre-filter): a measured upper bound, for the memory estimate of :func:`step_memory`."""
PAIR_BYTES: Final = 120
"""Bytes per ordered candidate pair of the sequential rule (indices, proposals, gaps)."""
PAIR_BYTES_PER_SUBSTEP: Final = 40
"""Bytes per ordered candidate pair and sub-step of the simultaneous rule (proposals, gaps, conflicts)."""
STATE_BYTES: Final = 128
"""Bytes per agent of the state, observations, rewards and flags of one decision."""


def step_memory(num_replicas: int, num_agents: int, num_substeps: int, collision_rule: str) -> int:
    """Estimated peak bytes of one ``RoomEnv.step``: the worst case, every pair of agents close enough to collide.

    Pairwise ``(R, N, N)`` matrices, plus the candidate pairs of the collision rule: ``R N (N - 1)`` ordered pairs,
    each held once (sequential) or at every sub-step (simultaneous).
    """
    ordered_pairs = num_replicas * num_agents * (num_agents - 1)
    per_pair = PAIR_BYTES_PER_SUBSTEP * num_substeps if collision_rule == "simultaneous" else PAIR_BYTES
    return num_replicas * num_agents * (STATE_BYTES + PAIRWISE_BYTES * num_agents) + ordered_pairs * per_pair


def check_goal_depth(goal_depth: Any) -> float:
    """``goal_depth`` as a finite float ``>= 0`` (m)."""
    checked = check_real("goal_depth", goal_depth, unit="m")
    if checked < 0:
        raise ValueError(f"goal_depth={goal_depth!r} is invalid: must be a finite number >= 0 (m)")
    return checked


def check_substeps(max_speed: float, decisions_per_second: float, substep_length: float) -> int:
    """Sub-steps per decision, at most :data:`MAX_SUBSTEPS`, else a one-line ``ValueError`` with the numbers."""
    decision_length = 1.0 / decisions_per_second
    move = max_speed * decision_length  # m per decision at top speed
    if move / substep_length > MAX_SUBSTEPS:
        raise ValueError(
            f"max_speed={max_speed!r} m/s, decisions_per_second={decisions_per_second!r} and "
            f"substep_length={substep_length!r} m are invalid together: a decision would take "
            f"{move / substep_length:.3g} sub-steps; max_speed / decisions_per_second / substep_length "
            f"must be at most {MAX_SUBSTEPS}"
        )
    return count_substeps(max_speed=max_speed, decision_length=decision_length, substep_length=substep_length)


def read_options(options: Mapping[str, Any] | None) -> dict[str, Any]:
    """``reset``'s ``options`` as a dict, with no key outside :data:`OPTION_KEYS`."""
    options = dict(options or {})
    unknown = sorted(set(options) - set(OPTION_KEYS))
    if unknown:
        allowed = ", ".join(OPTION_KEYS)
        raise ValueError(f"options key {unknown[0]!r} is invalid: must be one of {allowed}")
    return options


def read_option(
    options: Mapping[str, Any],
    key: str,
    shape: tuple[int, ...],
    *,
    device: torch.device,
    dtype: torch.dtype = torch.float32,
) -> torch.Tensor | None:
    """``options[key]`` as a tensor of ``shape`` (finite if floating point), or ``None`` if it is absent or None."""
    if options.get(key) is None:
        return None
    value = torch.as_tensor(options[key], dtype=dtype, device=device)
    if tuple(value.shape) != shape:
        raise ValueError(f"options[{key!r}] has shape {tuple(value.shape)}: must be {shape}")
    if dtype.is_floating_point and not bool(torch.isfinite(value).all()):
        raise ValueError(f"options[{key!r}] is invalid: every value must be finite")
    return value


def check_actions(actions: Any, shape: tuple[int, int], *, device: torch.device) -> torch.Tensor:
    """``actions`` as an int64 tensor of ``shape`` on ``device``: an integer tensor, of that shape."""
    if not isinstance(actions, torch.Tensor):
        raise ValueError(f"actions of type {type(actions).__name__} is invalid: must be a torch.Tensor")
    if tuple(actions.shape) != shape:
        raise ValueError(f"actions.shape={tuple(actions.shape)} is invalid: must be {shape}")
    if actions.is_floating_point() or actions.is_complex() or actions.dtype == torch.bool:
        raise ValueError(f"actions.dtype={actions.dtype} is invalid: must be an integer dtype (int64)")
    return actions.to(device=device, dtype=torch.int64)

"""The checks of a room's settings (``RoomParams``), ``RoomEnv``'s arguments, ``reset`` options and actions: each a
one-line ``ValueError`` that names the bad value (the generic checks of a number, a choice or a device are in
:mod:`pedrl.common.checks`)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, Final

import torch

from pedrl.common.checks import check_bool, check_choice, check_integer, check_number, check_real, shown
from pedrl.sim.actions import ACTION_FRAMES, COMMAND_WIDTH, NOOP_INDEX, NUM_SPEED_CHANGES, count_substeps
from pedrl.sim.geometry import Geometry, extent
from pedrl.sim.motion import MOTION_MODELS, MotionModel
from pedrl.sim.rewards import (
    DEVIATION_GATES,
    MAX_DEVIATION_RADIUS,
    MAX_DEVIATION_TURN,
    PASSING_SIDES,
    RewardTable,
)
from pedrl.sim.routing import MAX_QUEUE_WEIGHT

OPTION_KEYS: Final = ("positions", "headings", "speeds", "replicas")
"""The keys of ``RoomEnv.reset``'s ``options``."""
MAX_DECISIONS: Final = 10**7
"""Most decisions of a trial (``max_decisions``): four months of walk at one decision per second, a thousand times
the longest trial of any preset; a crowd still in its room then is stuck (a greedy walker held at a wall keeps a
trial going to its end), and a trial of this length at 100 agents takes 17 minutes at the fastest measured rate."""
MAX_SUBSTEPS: Final = 1000
"""Most sub-steps per decision (``max_speed / decisions_per_second / substep_length``, 7 by default): the sequential
collision rule loops over them, so ``max_speed=1e5`` (250 000 sub-steps) hung and ``1e9`` tried to allocate 20 GB."""


def check_area(area: Any, agent_radius: Any) -> float:
    """``agent_radius`` checked against the walkable ``area`` (a compiled :class:`~pedrl.sim.geometry.Geometry`):
    positive, a body fits through every exit and in the area's extent."""
    if not isinstance(area, Geometry):
        raise ValueError(
            f"area of type {type(area).__name__} is invalid: must be a pedrl.sim.Geometry (a scenario's,"
            " pedrl.scenarios: Scenario.geometry() or Scenario.room(...))"
        )
    radius = check_real("agent_radius", agent_radius, unit="m", positive=True)
    narrowest = float(torch.linalg.vector_norm(area.exits[:, 1] - area.exits[:, 0], dim=-1).min())
    if 2.0 * radius > narrowest:
        raise ValueError(
            f"agent_radius={agent_radius!r} is invalid: a body must fit through every exit, at most"
            f" {narrowest / 2.0:g} m (half the narrowest exit)"
        )
    width, length = extent(area)
    if 2.0 * radius >= min(width, length):
        raise ValueError(
            f"agent_radius={agent_radius!r} is invalid: a body must fit in the room, less than"
            f" min(width, length) / 2 = {min(width, length) / 2.0!r} m"
        )
    return radius


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


def check_motion(motion: Any) -> MotionModel:
    """``motion`` if it is a motion model (:mod:`pedrl.sim.motion`; it checked its own parameters when it was made),
    else a one-line ``ValueError`` listing them."""
    if not isinstance(motion, MotionModel):
        names = ", ".join(model.__name__ for model in MOTION_MODELS.values())
        raise ValueError(
            f"motion={shown(motion)} is invalid: must be a motion model of pedrl.sim.motion ({names}), e.g."
            " Yield(time_gap=1.0, order='door_first')"
        )
    return motion


def check_time_steps(num_substeps: int, motion: MotionModel, decision_length: float) -> int:
    """The sub-steps of a decision under ``motion``: the step model's ``num_substeps``; on the continuous walking
    layer (a model with a ``time_step``) at least ``ceil(decision_length / time_step)``, at most
    :data:`MAX_SUBSTEPS`, else a one-line ``ValueError``."""
    time_step = motion.time_step
    if time_step is None:
        return num_substeps
    steps = math.ceil(decision_length / time_step * (1.0 - 1e-9))  # the slack keeps e.g. 1 / 0.05 at 20
    if steps > MAX_SUBSTEPS:
        raise ValueError(
            f"env.motion.time_step={time_step!r} s is invalid with decisions_per_second={1.0 / decision_length:.6g}:"
            f" a decision would take {steps} time steps; at most {MAX_SUBSTEPS} (raise time_step or"
            " decisions_per_second)"
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


GRID_BYTES: Final = 96
"""Bytes per agent of the fused trial's grids of cells and scratch (cells, items, candidates)."""


def step_memory(
    num_replicas: int, num_agents: int, num_substeps: int, collision_rule: str, *, kernels: bool = False
) -> int:
    """Estimated peak bytes of one decision. ``kernels``: of the fused trial's kernels, which find neighbours through
    grids of cells (linear in the agents). Else of ``RoomEnv.step`` (the torch reference), the worst case, every
    pair of agents close enough to collide: pairwise ``(R, N, N)`` matrices, plus the candidate pairs of the collision
    rule, ``R N (N - 1)`` ordered pairs, each held once (sequential) or at every sub-step (simultaneous).
    """
    if kernels:
        return num_replicas * num_agents * (STATE_BYTES + GRID_BYTES)
    ordered_pairs = num_replicas * num_agents * (num_agents - 1)
    per_pair = PAIR_BYTES_PER_SUBSTEP * num_substeps if collision_rule == "simultaneous" else PAIR_BYTES
    return num_replicas * num_agents * (STATE_BYTES + PAIRWISE_BYTES * num_agents) + ordered_pairs * per_pair


def checked_settings(params: Any) -> dict[str, Any]:
    """Every setting of ``params`` (a :class:`~pedrl.sim.params.RoomParams` being made) checked, each a one-line
    ``ValueError`` naming the bad value, and normalised (floats, tuples): the values to keep. The checks that need the
    walkable area (a body fits its exits, ``num_walls`` at most its walls) are the room's (:func:`check_area`)."""
    radius = check_real("agent_radius", params.agent_radius, unit="m", positive=True)
    checked = {
        "agent_radius": radius,
        "max_speed": check_real("max_speed", params.max_speed, unit="m/s", positive=True),
        "decisions_per_second": check_real(
            "decisions_per_second", params.decisions_per_second, unit="1/s", positive=True
        ),
        "max_decisions": check_integer("max_decisions", params.max_decisions, minimum=1, maximum=MAX_DECISIONS),
        "num_neighbours": check_integer("num_neighbours", params.num_neighbours, minimum=0),
        "num_walls": check_integer("num_walls", params.num_walls, minimum=0),
        "action_frame": check_choice("action_frame", params.action_frame, ACTION_FRAMES),
    }
    goal_frame = checked["action_frame"] == "goal"
    checked["speed_ratios"], checked["turn_ratios"] = check_action_set(
        params.speed_ratios, params.turn_ratios, goal_frame=goal_frame
    )
    checked |= RewardTable.of(params).settings()  # each reward checked by the table
    checked["deviation_turn"] = check_number("deviation_turn", params.deviation_turn, low=0.0, high=MAX_DEVIATION_TURN)
    checked["deviation_radius"] = check_number(
        "deviation_radius", params.deviation_radius, low=0.0, high=MAX_DEVIATION_RADIUS
    )
    checked["deviation_gate"] = check_choice("deviation_gate", params.deviation_gate, DEVIATION_GATES)
    for name in ("passing_radius", "passing_band"):
        checked[name] = check_number(name, getattr(params, name), low=0.0, high=MAX_DEVIATION_RADIUS)
    checked["passing_side"] = check_choice("passing_side", params.passing_side, PASSING_SIDES)
    substep = check_substep_length(params.substep_length, radius)
    checked["substep_length"] = None if params.substep_length is None else substep
    checked["motion"] = check_motion(params.motion)
    checked["goal_depth"] = check_goal_depth(params.goal_depth)
    checked["compile_sensing"] = check_bool("compile_sensing", params.compile_sensing)
    checked["queue_weight"] = check_number("queue_weight", params.queue_weight, low=0.0, high=MAX_QUEUE_WEIGHT)
    decision_length = 1.0 / checked["decisions_per_second"]
    check_time_steps(
        check_substeps(checked["max_speed"], checked["decisions_per_second"], substep),
        checked["motion"],
        decision_length,
    )
    return checked


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


def check_actions(actions: Any, shape: tuple[int, int], *, device: torch.device, frame: str) -> torch.Tensor:
    """``actions`` on ``device``: action indices, an integer tensor of ``shape`` (as int64), or in the ``goal`` action
    ``frame`` continuous commands, a finite floating tensor of ``shape + (2,)`` (as float32,
    :data:`pedrl.sim.actions.COMMAND_WIDTH`)."""
    if not isinstance(actions, torch.Tensor):
        raise ValueError(f"actions of type {type(actions).__name__} is invalid: must be a torch.Tensor")
    if actions.is_floating_point():
        if frame != "goal":
            raise ValueError(
                f"actions.dtype={actions.dtype} is invalid in the {frame!r} action frame: continuous commands need "
                "env.action_frame=goal (else integer action indices)"
            )
        if tuple(actions.shape) != (*shape, COMMAND_WIDTH):
            wanted = (*shape, COMMAND_WIDTH)
            raise ValueError(f"actions.shape={tuple(actions.shape)} is invalid: continuous commands must be {wanted}")
        if not bool(torch.isfinite(actions).all()):
            raise ValueError("actions hold NaN or infinite commands: every command must be finite")
        return actions.to(device=device, dtype=torch.float32).contiguous()
    if tuple(actions.shape) != shape:
        raise ValueError(f"actions.shape={tuple(actions.shape)} is invalid: must be {shape}")
    if actions.is_complex() or actions.dtype == torch.bool:
        raise ValueError(
            f"actions.dtype={actions.dtype} is invalid: must be an integer dtype (int64), or float commands"
        )
    return actions.to(device=device, dtype=torch.int64)

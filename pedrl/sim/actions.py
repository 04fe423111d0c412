"""The action codec: an action ``a`` in ``[0, 81)`` is ``speed_index * 9 + turn_index``, and what it does to a
body's speed and heading in each action frame (``ACTION_FRAMES``); velocities and the sub-step count of a decision.
Each torch function with a kernel has its numba twin beside it, one agent at a time: :func:`apply_actions` and
:func:`apply_action_kernel` (the fused step's ``act_room``), :func:`velocities_from` and :func:`velocity_kernel`.

In the paper's ``heading`` frame index 4 of each axis is the no-op, so ``NOOP_ACTION = 40`` keeps speed and heading;
in the ``goal`` frame an action sets the speed and the heading relative to the bearing of the goal point.

A continuous controller (PPO's continuous head) commands the ``goal`` frame's speed and heading directly: a
*command* ``(speed ratio, heading offset)`` per agent (:data:`COMMAND_WIDTH`), executed as it is by
:func:`apply_commands` and its twin :func:`apply_command_kernel`; :func:`commands_of` writes a ``goal``-frame action as
the command it is.
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np
import torch

from pedrl._numba import cached_njit
from pedrl.sim.geometry import wrap_angle
from pedrl.sim.sensing_kernel import wrap

NUM_SPEED_CHANGES: Final = 9
NUM_TURNS: Final = 9
NUM_ACTIONS: Final = NUM_SPEED_CHANGES * NUM_TURNS
NOOP_INDEX: Final = 4
NOOP_ACTION: Final = NOOP_INDEX * NUM_TURNS + NOOP_INDEX
DEFAULT_SPEED_RATIOS: Final = (-1.0, -0.5, -0.25, -0.1, 0.0, 0.1, 0.25, 0.5, 1.0)
"""Speed change per decision, as a fraction of ``max_speed``."""
DEFAULT_TURN_RATIOS: Final = (-0.75, -0.25, -0.08, -0.025, 0.0, 0.025, 0.08, 0.25, 0.75)
"""Heading change per decision, as a fraction of pi (the paper gives none): turns of 4.5, 14.4, 45 and 135 degrees
either way. The smallest turn is fine enough to line up with a 1 m opening: within four decisions any heading
error falls to at most 2.25 degrees, so a full-speed step of 2.5 m lands within 0.1 m of the aimed line (the
clearance of a 0.4 m body in a 1 m opening); ``COARSE_TURN_RATIOS`` left up to 9 degrees (0.39 m)."""
COARSE_TURN_RATIOS: Final = (-0.75, -0.5, -0.25, -0.1, 0.0, 0.1, 0.25, 0.5, 0.75)
"""The former default turn ratios (smallest turn 18 degrees), kept for old runs and the golden trajectories."""
ACTION_FRAMES: Final = ("heading", "goal")
"""What an action changes. ``heading`` (the paper): the speed and the heading change by the ratios from their
current values. ``goal``: the speed index sets the speed to ``speed_ratios[i] * max_speed`` and the turn index sets
the heading to the bearing of the agent's goal point (its door or waypoint) plus ``turn_ratios[j] * pi``: the
greedy walker is one action, and an action means the same whatever the heading before it."""
GOAL_SPEED_RATIOS: Final = (0.0, 0.2, 0.4, 0.6, 0.7, 0.8, 0.9, 0.95, 1.0)
"""Speeds of the ``goal`` frame's 9 speed indices, as fractions of ``max_speed``: the main job's
(``conf/experiment/main.yaml``), most of them near the top."""
GOAL_TURN_RATIOS: Final = (-0.5, -0.25, -0.1, -0.05, 0.0, 0.05, 0.1, 0.25, 0.5)
"""Headings of the ``goal`` frame's 9 turn indices, relative to the bearing of the goal, as fractions of pi: 0,
+-9, +-18, +-45 and +-90 degrees (the main job's)."""


COMMAND_WIDTH: Final = 2
"""Numbers of a continuous command: the speed as a fraction of ``max_speed`` (clipped to ``[0, 1]``) and the heading
relative to the bearing of the goal point (rad, wrapped to ``(-pi, pi]``); the ``goal`` action frame only."""


def decode_actions(actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Split actions into speed and turn indices.

    Args:
        actions: Actions ``(R, N)`` int64 in ``[0, 81)``.

    Returns:
        ``speed_index`` and ``turn_index``, each ``(R, N)`` int64 in ``[0, 9)``.
    """
    return torch.div(actions, NUM_TURNS, rounding_mode="floor"), torch.remainder(actions, NUM_TURNS)


def encode_actions(*, speed_index: torch.Tensor, turn_index: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`decode_actions`: ``speed_index * 9 + turn_index`` (int64, same shape)."""
    return speed_index * NUM_TURNS + turn_index


def apply_actions(
    *,
    speeds: torch.Tensor,
    headings: torch.Tensor,
    actions: torch.Tensor,
    speed_changes: torch.Tensor,
    turn_changes: torch.Tensor,
    max_speed: float,
    active: torch.Tensor,
    bearings: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Apply one decision's actions to speeds and headings.

    The ``heading`` frame (``bearings`` None): ``s <- clip(s + speed_changes[speed_index], 0, max_speed)`` and
    ``theta <- wrap(theta + turn_changes[turn_index])``. The ``goal`` frame (``bearings`` given):
    ``s <- clip(speed_changes[speed_index], 0, max_speed)`` and ``theta <- wrap(bearing + turn_changes[turn_index])``
    (``ACTION_FRAMES``). Inactive agents keep their values.

    Args:
        speeds: Speeds ``(R, N)`` (m/s).
        headings: Headings ``(R, N)`` (rad).
        actions: Actions ``(R, N)`` int64 in ``[0, 81)``.
        speed_changes: Speed change of each speed index ``(9,)`` (m/s), i.e. ``speed_ratios * max_speed``.
        turn_changes: Heading change of each turn index ``(9,)`` (rad), i.e. ``turn_ratios * pi``.
        max_speed: Maximum speed (m/s).
        active: Agents that act ``(R, N)`` bool.
        bearings: The ``goal`` frame: the world angle ``(R, N)`` (rad) from each agent to its goal point.

    Returns:
        New ``speeds`` ``(R, N)`` (m/s) and ``headings`` ``(R, N)`` (rad).
    """
    speed_index, turn_index = decode_actions(actions.reshape(-1))
    # index_select: plain indexing opens a parallel region for a few thousand indices already
    speed_change = speed_changes.index_select(0, speed_index).view_as(speeds)
    turn_change = turn_changes.index_select(0, turn_index).view_as(headings)
    if bearings is not None:
        return _toward_goal(speeds, headings, speed_change, turn_change, bearings, max_speed, active)
    new_speeds = (speeds + speed_change).clamp_(0.0, max_speed)
    new_headings = wrap_angle(headings + turn_change)
    return torch.where(active, new_speeds, speeds), torch.where(active, new_headings, headings)


@cached_njit(nogil=True, inline="always")
def apply_action_kernel(room, active, speed, heading, action, position, target):
    """:func:`apply_actions` of one agent, float32: ``room`` is :class:`pedrl.sim.params.KernelRoom` (its
    ``speed_changes``, ``turn_changes``, ``max_speed`` and ``goal_frame``), ``position`` and ``target`` the agent's
    centre and goal point ``(x, y)`` (m; the ``goal`` frame's bearing). Returns the new ``(speed, heading)``; an
    inactive agent keeps its own."""
    if not active:
        return speed, heading
    speed_change, turn_change = room.speed_changes[action // NUM_TURNS], room.turn_changes[action % NUM_TURNS]
    if room.goal_frame:
        return _toward_goal_kernel(room, speed_change, turn_change, position, target)
    return min(max(speed + speed_change, np.float32(0.0)), room.max_speed), wrap(heading + turn_change)


def apply_commands(
    *,
    speeds: torch.Tensor,
    headings: torch.Tensor,
    commands: torch.Tensor,
    max_speed: float,
    active: torch.Tensor,
    bearings: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Apply one decision's continuous commands (:data:`COMMAND_WIDTH`): ``s <- clip(ratio * max_speed, 0,
    max_speed)`` and ``theta <- wrap(bearing + offset)``; inactive agents keep their values.

    Args:
        speeds, headings: ``(R, N)`` (m/s, rad).
        commands: ``(R, N, 2)`` float32: the speed ratio and the heading offset (rad) of each agent.
        max_speed: Maximum speed (m/s).
        active: Agents that act ``(R, N)`` bool.
        bearings: The world angle ``(R, N)`` (rad) from each agent to its goal point.

    Returns:
        New ``speeds`` and ``headings`` ``(R, N)``.
    """
    return _toward_goal(speeds, headings, commands[..., 0] * max_speed, commands[..., 1], bearings, max_speed, active)


def _toward_goal(
    speeds: torch.Tensor,
    headings: torch.Tensor,
    new_speeds: torch.Tensor,
    offsets: torch.Tensor,
    bearings: torch.Tensor,
    max_speed: float,
    active: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The ``goal`` frame's decision, of an action and of a command alike: the speed ``new_speeds`` (m/s) clipped to
    ``[0, max_speed]`` and the heading ``bearings + offsets`` wrapped, for the ``active`` agents."""
    new_headings = wrap_angle(bearings + offsets)
    return torch.where(active, new_speeds.clamp(0.0, max_speed), speeds), torch.where(active, new_headings, headings)


@cached_njit(nogil=True, inline="always")
def apply_command_kernel(room, active, speed, heading, ratio, offset, position, target):
    """:func:`apply_commands` of one agent, float32 (``ratio`` and ``offset`` its command; the arguments otherwise as
    :func:`apply_action_kernel`'s). Returns the new ``(speed, heading)``; an inactive agent keeps its own."""
    if not active:
        return speed, heading
    return _toward_goal_kernel(room, ratio * room.max_speed, offset, position, target)


@cached_njit(nogil=True, inline="always")
def _toward_goal_kernel(room, speed, offset, position, target):
    """:func:`_toward_goal` of one agent: the speed (m/s) clipped to the room's top speed, the heading ``offset``
    from the bearing of ``target`` seen from ``position``."""
    bearing = np.arctan2(target[1] - position[1], target[0] - position[0])
    return min(max(speed, np.float32(0.0)), room.max_speed), wrap(bearing + offset)


def commands_of(actions: torch.Tensor, *, speed_changes: torch.Tensor, turn_changes: torch.Tensor,
                max_speed: float) -> torch.Tensor:  # fmt: skip
    """The ``goal``-frame ``actions (...)`` int64 as the commands ``(..., 2)`` float32 that do the same: each speed
    index's speed over ``max_speed`` and each turn index's heading offset (``speed_changes`` and ``turn_changes``
    ``(9,)``, a room's)."""
    speed_index, turn_index = decode_actions(actions.reshape(-1))
    ratio = speed_changes.index_select(0, speed_index) / max_speed
    return torch.stack((ratio, turn_changes.index_select(0, turn_index)), dim=-1).view(*actions.shape, COMMAND_WIDTH)


def velocities_from(*, speeds: torch.Tensor, headings: torch.Tensor) -> torch.Tensor:
    """Velocity vectors ``s * (cos theta, sin theta)``.

    Args:
        speeds: Speeds ``(R, N)`` (m/s).
        headings: Headings ``(R, N)`` (rad).

    Returns:
        Velocities ``(R, N, 2)`` (m/s).
    """
    # one op (no parallel region for small tensors, unlike cos and sin); equal to s * (cos, sin) to 1 ulp
    return torch.view_as_real(torch.polar(speeds, headings))


@cached_njit(nogil=True, inline="always")
def velocity_kernel(speed, heading):
    """:func:`velocities_from` of one agent: ``(s cos theta, s sin theta)`` (m/s)."""
    return speed * np.cos(heading), speed * np.sin(heading)


def count_substeps(*, max_speed: float, decision_length: float, substep_length: float) -> int:
    """Number of sub-steps so that no body moves more than ``substep_length`` per sub-step.

    Args:
        max_speed: Maximum speed (m/s).
        decision_length: Duration of one decision (s).
        substep_length: Longest move per sub-step (m).

    Returns:
        ``ceil(max_speed * decision_length / substep_length)``, at least 1.
    """
    # The tiny relative slack keeps e.g. 2.5 / 0.5 at 5 despite float rounding.
    return max(1, math.ceil(max_speed * decision_length / substep_length * (1.0 - 1e-9)))

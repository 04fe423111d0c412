"""Immediate rewards per decision (paper Table 2, and the progress toward the goal point): the one home of a reward.

:class:`RewardTable` is the record (each value checked when it is made), :func:`compute_rewards` the torch function
(``RoomEnv.step``'s, the specification) and :func:`reward_kernel` its numba twin (``act_room``'s, one agent at a
time), side by side. A reward is a field of the table, the setting ``reward_<field>`` of
:class:`~pedrl.sim.params.RoomParams` (the kernels read it from ``KernelRoom`` by that name), a term in each of the two
functions and its default in ``conf/env/room.yaml``; ``tests/sim/test_rewards.py`` holds the list of files that name a
reward to that.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any, Final

import numpy as np
import torch

from pedrl._numba import cached_njit
from pedrl.common.checks import check_number
from pedrl.sim.geometry import wrap_angle
from pedrl.sim.pairs import close_pairs
from pedrl.sim.sensing_kernel import wrap

__all__ = [
    "DEVIATION_GATES",
    "MAX_REWARD",
    "PASSING_SIDES",
    "REWARD_DEFAULTS",
    "SETTING_PREFIX",
    "RewardTable",
    "commanded_deviation",
    "compute_rewards",
    "crowded_kernel",
    "deviation_kernel",
    "in_company",
    "passing_kernel",
    "reward_kernel",
    "unpriced_in_company",
    "wrong_side_passing",
]

MAX_REWARD: Final = 1e6
"""Largest ``|reward|`` (and ``reward_progress``, per m) accepted. Q values and returns are float32 sums of rewards
over up to ``max_decisions`` decisions (bounded by ``max|r| / (1 - gamma)`` and ``max|r| * max_decisions``); this
keeps them about 20 orders of magnitude below float32's 3.4e38 (``reward_goal=1e38`` learned inf and NaN tables)."""
MAX_DEVIATION_TURN: Final = 10.0
"""Largest ``deviation_turn`` (the weight of the heading part of the deviation price) accepted."""
MAX_DEVIATION_RADIUS: Final = 1000.0
"""Largest ``deviation_radius`` (m) accepted."""
DEVIATION_GATES: Final = ("company", "oncoming")
"""Values of ``deviation_gate``: who, within ``deviation_radius``, frees a walker from the deviation price (any other
walker, or only one ahead of it on the line to its goal that commands a velocity against that line)."""
PASSING_SIDES: Final = ("either", "right", "left")
"""Values of ``passing_side``: where an oncoming walker within ``passing_radius`` ahead must be, ``passing_band`` m or
more off the deciding walker's line to its goal, for ``reward_passing`` not to be paid: on either side, on its left
(the walker keeps right), on its right (it keeps left)."""
_EITHER, _RIGHT, _LEFT = (PASSING_SIDES.index(side) for side in ("either", "right", "left"))
"""The kernels' ``passing_side``, its index in :data:`PASSING_SIDES`."""
SETTING_PREFIX: Final = "reward_"
"""A reward ``x`` of the table is the room's setting ``reward_x``."""


def _reward(default: float, *, low: float | None = None, high: float | None = None) -> Any:
    """A reward of the table: its ``default`` and the range of values it accepts (None: ``-MAX_REWARD``,
    ``MAX_REWARD``, read when a table is made)."""
    return field(default=default, metadata={"low": low, "high": high})


@dataclass(frozen=True)
class RewardTable:
    """Reward values of one decision, each checked when the table is made (a one-line ``ValueError`` naming the
    setting ``reward_<name>``): a number in ``[-MAX_REWARD, MAX_REWARD]``, ``progress`` in ``[0, MAX_REWARD]``,
    ``deviation`` in ``[-MAX_REWARD, 0]``. Its defaults are the room's, the one set (:data:`REWARD_DEFAULTS`, which
    :class:`~pedrl.sim.params.RoomParams` and ``conf/env/room.yaml`` hold): Table 2's goal and crashes, a time cost of 1
    and 1 per metre of progress where Table 2 has 0 and 0 (``rewards=paper`` sets those).

    Attributes:
        goal: Reaching the door.
        crash_wall: A wall contact during the decision: a wall cut the agent's move (stopped it under the ``stop``
            contact model, deflected or stopped it under ``slide`` and ``headway``; see ``RoomEnv``'s ``contact``).
        crash_agent: A body contact (and no wall contact) during the decision: another body cut the agent's move.
        default: Anything else (a time cost per decision).
        progress: Per metre by which the decision brought the agent closer to its goal point (added to the above;
            0 in the paper).
        deviation: Per unit of the decision's commanded deviation from the greedy walker's velocity (added to the
            above; at most 0; 0, the default, and in the paper: none): ``(1 - speed / max_speed) + deviation_turn
            |heading - bearing| / pi`` of the commanded speed and heading against the bearing of the goal point
            (:func:`commanded_deviation`, in ``[0, 1 + deviation_turn]``). Where the motion model caps what any
            command walks (a queue), decisions that walk alike differ by it, and the straight one at top speed is the
            best.
        passing: Per decision in which an oncoming walker (one within ``passing_radius`` m ahead of the agent on its
            line to its goal, commanding a velocity against that line) is on that line's wrong side of
            ``passing_band``: nearer than that to the line (``passing_side="either"``), or not that far to its left
            (``"right"``: keep right, the norm Chen et al. 2017 taught by such a price) or to its right (``"left"``)
            (added to the above; at most 0; 0, the default, and in the paper: none; :func:`wrong_side_passing`).
    """

    goal: float = _reward(100.0)
    crash_wall: float = _reward(-15.0)
    crash_agent: float = _reward(-4.0)
    default: float = _reward(-1.0)
    progress: float = _reward(1.0, low=0.0)
    deviation: float = _reward(0.0, high=0.0)
    passing: float = _reward(0.0, high=0.0)

    def __post_init__(self) -> None:
        for item in fields(self):
            name = SETTING_PREFIX + item.name
            low, high = item.metadata["low"], item.metadata["high"]
            low, high = -MAX_REWARD if low is None else low, MAX_REWARD if high is None else high
            value = check_number(name, getattr(self, item.name), low=low, high=high)
            object.__setattr__(self, item.name, value)

    @classmethod
    def of(cls, settings: Any) -> RewardTable:
        """The table of the settings ``settings.reward_<name>`` (a :class:`~pedrl.sim.params.RoomParams`), checked."""
        return cls(**{item.name: getattr(settings, SETTING_PREFIX + item.name) for item in fields(cls)})

    def settings(self) -> dict[str, float]:
        """The table as the room's settings, ``{"reward_<name>": value}``."""
        return {SETTING_PREFIX + item.name: getattr(self, item.name) for item in fields(self)}


REWARD_DEFAULTS: Final = RewardTable().settings()
"""The one default set of rewards, ``{"reward_<name>": value}``: the room's settings take theirs from it."""


def compute_rewards(
    *,
    table: RewardTable,
    reached: torch.Tensor,
    crashed_wall: torch.Tensor,
    crashed_agent: torch.Tensor,
    acting: torch.Tensor,
    progress: torch.Tensor | None = None,
    deviation: torch.Tensor | None = None,
    passing: torch.Tensor | None = None,
) -> torch.Tensor:
    """Reward of each agent for one decision.

    ``goal`` if it reached the door, else ``crash_wall`` if it hit a wall, else ``crash_agent`` if it hit an
    agent, else ``default``; plus ``table.progress * progress``, ``table.deviation * deviation`` and ``table.passing``
    where ``passing``; 0 for agents that did not act (inactive at the start of the decision).

    Args:
        table: The reward values.
        reached: Agents that reached the door (their own exit) ``(R, N)`` bool.
        crashed_wall: Agents whose move a wall cut ``(R, N)`` bool.
        crashed_agent: Agents whose move another body cut, and no wall ``(R, N)`` bool.
        acting: Agents active during the decision ``(R, N)`` bool.
        progress: How much closer to its goal point the decision brought each agent ``(R, N)`` (m); None: no
            progress term.
        deviation: :func:`commanded_deviation` of each agent's decision ``(R, N)``; None: no deviation term.
        passing: :func:`wrong_side_passing` of each agent's decision ``(R, N)`` bool; None: no passing term.

    Returns:
        Rewards ``(R, N)`` float32.
    """
    reward = torch.where(crashed_agent, table.crash_agent, table.default)
    reward = torch.where(crashed_wall, table.crash_wall, reward)
    reward = torch.where(reached, table.goal, reward)
    reward = torch.where(acting, reward, 0.0).to(torch.float32)
    if table.progress and progress is not None:
        reward = reward + torch.where(acting, table.progress * progress, 0.0)
    if table.deviation and deviation is not None:
        reward = reward + torch.where(acting, table.deviation * deviation, 0.0)
    if table.passing and passing is not None:
        reward = reward + torch.where(acting & passing, table.passing, 0.0)
    return reward


def commanded_deviation(
    speeds: torch.Tensor,
    headings: torch.Tensor,
    positions: torch.Tensor,
    targets: torch.Tensor,
    max_speed: float,
    turn: float = 1.0,
) -> torch.Tensor:
    """How far commanded ``speeds`` and ``headings`` ``(R, N)`` lie from the greedy walker's, top speed straight at
    the goal point, from ``positions`` to ``targets`` ``(R, N, 2)``: ``(1 - speed / max_speed) + turn |heading -
    bearing| / pi``, in ``[0, 1 + turn]`` (float32; ``turn`` the room's ``deviation_turn``)."""
    to_goal = targets - positions
    bearings = torch.atan2(to_goal[..., 1], to_goal[..., 0])
    return (1.0 - speeds / max_speed) + wrap_angle(headings - bearings).abs() / np.float32(np.pi) * turn


def unpriced_in_company(
    deviation: torch.Tensor,
    positions: torch.Tensor,
    present: torch.Tensor,
    radius: float,
    *,
    oncoming: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> torch.Tensor:
    """``deviation`` ``(R, N)`` where no other ``present`` agent of the room stands within ``radius`` m of the agent
    (its centre, ``positions`` ``(R, N, 2)`` before the decision), 0 where one does: the room's
    ``deviation_radius``, a price on deviating from the greedy walker's velocity only where a walker is free to walk
    it. ``radius`` 0: ``deviation`` unchanged. With ``oncoming`` = ``(velocities, targets)`` ``(R, N, 2)`` (the
    decision's commanded velocities and goal points; ``deviation_gate="oncoming"``) only an oncoming walker frees
    agent ``i``: one within the radius, ahead of it (``(p_j - p_i) . (t_i - p_i) > 0``) and commanding a velocity
    against its line to its goal (``v_j . (t_i - p_i) < 0``); walkers going its way do not."""
    if radius <= 0:
        return deviation
    crowded = in_company(positions, present, radius, oncoming=oncoming)
    return torch.where(crowded, torch.zeros_like(deviation), deviation)


def in_company(
    positions: torch.Tensor,
    present: torch.Tensor,
    radius: float,
    *,
    oncoming: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> torch.Tensor:
    """Whether another ``present`` agent stands within ``radius`` m of each agent ``(R, N)`` bool (with ``oncoming``,
    an oncoming one): the gate of :func:`unpriced_in_company`, and the heading prior's; False everywhere for
    ``radius`` 0."""
    crowded = torch.zeros_like(present)
    if radius <= 0:
        return crowded
    room, i, j = _pairs_within(positions, radius)
    frees_i, frees_j = present[room, j], present[room, i]  # j near i frees i, i near j frees j
    if oncoming is not None:
        velocities, targets = oncoming
        frees_i = frees_i & _oncoming(positions, velocities, targets, room, i, j)
        frees_j = frees_j & _oncoming(positions, velocities, targets, room, j, i)
    crowded[room[frees_i], i[frees_i]] = True
    crowded[room[frees_j], j[frees_j]] = True
    return crowded


def _pairs_within(positions: torch.Tensor, radius: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The pairs ``(room, i, j)`` of centres at most ``radius`` apart: found in linear memory (pedrl.sim.pairs) below a
    limit a hair over the radius, then decided by the kernels' test, a squared gap at most ``radius ** 2`` in
    float32."""
    room, i, j = close_pairs(positions, radius * (1.0 + 1e-6))
    near = (positions[room, i] - positions[room, j]).square().sum(dim=-1) <= radius * radius
    return room[near], i[near], j[near]


def _oncoming(
    positions: torch.Tensor, velocities: torch.Tensor, targets: torch.Tensor, room: torch.Tensor, i: torch.Tensor,
    j: torch.Tensor,
) -> torch.Tensor:  # fmt: skip
    """Whether agent ``j`` is oncoming for agent ``i`` (pairs ``(room, i, j)``): ahead of ``i`` on its line to its
    goal and commanding a velocity against it; the kernel's sums, component by component."""
    line = targets[room, i] - positions[room, i]
    gap = positions[room, j] - positions[room, i]
    velocity = velocities[room, j]
    ahead = gap[:, 0] * line[:, 0] + gap[:, 1] * line[:, 1] > 0
    return ahead & (velocity[:, 0] * line[:, 0] + velocity[:, 1] * line[:, 1] < 0)


def wrong_side_passing(
    positions: torch.Tensor,
    velocities: torch.Tensor,
    targets: torch.Tensor,
    present: torch.Tensor,
    radius: float,
    band: float,
    side: str,
) -> torch.Tensor:
    """Whether an oncoming walker is on the wrong side of each agent ``(R, N)`` bool (``reward_passing``'s
    decisions): another ``present`` agent ``j`` within ``radius`` m of agent ``i`` (centres ``positions`` ``(R, N,
    2)`` before the decision), ahead of it on its line to its goal point (``targets``) and commanding a velocity
    (``velocities``, the decision's) against that line, whose signed distance from that line (``> 0``: to its left)
    is under ``band`` in size (``side="either"``), under ``band`` (``"right"``: ``i`` keeps ``j`` on its left) or
    over ``-band`` (``"left"``). ``radius`` 0: False everywhere."""
    wrong = torch.zeros_like(present)
    if radius <= 0:
        return wrong
    room, i, j = _pairs_within(positions, radius)
    for a, b in ((i, j), (j, i)):  # j for i, then i for j
        line = targets[room, a] - positions[room, a]
        gap = positions[room, b] - positions[room, a]
        facing = present[room, a] & present[room, b] & _oncoming(positions, velocities, targets, room, a, b)
        length = torch.sqrt(line[:, 0] * line[:, 0] + line[:, 1] * line[:, 1])
        lateral = (line[:, 0] * gap[:, 1] - line[:, 1] * gap[:, 0]) / length
        if side == "either":
            facing = facing & (lateral.abs() < band)
        else:
            facing = facing & ((lateral < band) if side == "right" else (lateral > -band))
        wrong[room[facing], a[facing]] = True
    return wrong


@cached_njit(nogil=True, inline="always")
def deviation_kernel(room, speed, heading, position, target):
    """:func:`commanded_deviation` of one agent, float32 (``position`` and ``target`` ``(x, y)``, m); 0 where the room
    prices no deviation (``reward_deviation`` 0: nothing computed)."""
    if room.reward_deviation == 0:
        return np.float32(0.0)
    bearing = np.arctan2(target[1] - position[1], target[0] - position[0])
    return (np.float32(1.0) - speed / room.max_speed) + abs(wrap(heading - bearing)) / np.float32(
        np.pi
    ) * room.deviation_turn


@cached_njit(nogil=True, inline="always")
def _oncoming_kernel(gap_x, gap_y, line_x, line_y, velocity):
    """:func:`_oncoming` of one pair: the other agent, ``gap`` from the deciding one, is ahead of it on its ``line``
    to its goal and its ``velocity`` ``(2,)`` points against that line."""
    return gap_x * line_x + gap_y * line_y > 0 and velocity[0] * line_x + velocity[1] * line_y < 0


@cached_njit(nogil=True, inline="always")
def crowded_kernel(room, r, i, positions, present, velocities, targets):
    """Whether another ``present`` agent of room ``r`` frees agent ``i`` from the deviation price
    (:func:`unpriced_in_company` of one agent): it stands within the room's ``deviation_radius`` of ``i``, and under
    the ``oncoming`` gate is ahead of ``i`` on its line to its goal (``targets``) commanding a velocity
    (``velocities``) against that line; False where the radius is 0."""
    radius = room.deviation_radius
    if radius <= 0:
        return False
    x, y, reach = positions[r, i, 0], positions[r, i, 1], radius * radius
    line_x, line_y = targets[r, i, 0] - x, targets[r, i, 1] - y
    for j in range(positions.shape[1]):
        if j == i or not present[r, j]:
            continue
        gap_x, gap_y = positions[r, j, 0] - x, positions[r, j, 1] - y
        if gap_x**2 + gap_y**2 > reach:
            continue
        if not room.deviation_oncoming or _oncoming_kernel(gap_x, gap_y, line_x, line_y, velocities[r, j]):
            return True
    return False


@cached_njit(nogil=True, inline="always")
def passing_kernel(room, r, i, positions, present, velocities, targets):
    """:func:`wrong_side_passing` of agent ``i`` of room ``r`` (the room's ``passing_radius``, ``passing_band`` and
    ``passing_side``, the index of :data:`PASSING_SIDES`); False where the room prices no passing."""
    radius = room.passing_radius
    if room.reward_passing == 0 or radius <= 0 or not present[r, i]:
        return False
    x, y, reach, band = positions[r, i, 0], positions[r, i, 1], radius * radius, room.passing_band
    line_x, line_y = targets[r, i, 0] - x, targets[r, i, 1] - y
    length = np.sqrt(line_x * line_x + line_y * line_y)
    for j in range(positions.shape[1]):
        if j == i or not present[r, j]:
            continue
        gap_x, gap_y = positions[r, j, 0] - x, positions[r, j, 1] - y
        if gap_x**2 + gap_y**2 > reach:
            continue
        if not _oncoming_kernel(gap_x, gap_y, line_x, line_y, velocities[r, j]):
            continue  # behind, or going i's way
        lateral = (line_x * gap_y - line_y * gap_x) / length
        side = room.passing_side
        if (side == _EITHER and abs(lateral) < band) or (side == _RIGHT and lateral < band):
            return True
        if side == _LEFT and lateral > -band:
            return True
    return False


@cached_njit(nogil=True, inline="always")
def reward_kernel(room, acting, reached, crashed_wall, crashed_agent, start, end, target, deviation, passing):
    """:func:`compute_rewards` of one agent, float32: ``room`` is :class:`pedrl.sim.params.KernelRoom` (its
    ``reward_<name>`` entries), the flags bools, ``start`` and ``end`` the agent's centre before and after the decision
    and ``target`` its goal point, each ``(x, y)`` (m), ``deviation`` its decision's :func:`deviation_kernel` and
    ``passing`` its :func:`passing_kernel`."""
    if not acting:
        return np.float32(0.0)
    value = room.reward_default
    if crashed_agent:
        value = room.reward_crash_agent
    if crashed_wall:
        value = room.reward_crash_wall
    if reached:
        value = room.reward_goal
    before = np.hypot(start[0] - target[0], start[1] - target[1])
    after = np.hypot(end[0] - target[0], end[1] - target[1])
    value = value + room.reward_progress * (before - after)
    if room.reward_deviation != 0:
        value = value + room.reward_deviation * deviation
    if passing:
        value = value + room.reward_passing
    return value

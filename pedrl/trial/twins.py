"""The twin harness: the torch trial loop and the stage kernels of the fused trial, driven in lockstep through whole
trials, stage by stage, against one table of tolerances (as Gymnasium's ``check_environments_match`` drives two
environments with the same actions).

Every decision of a trial starts both paths from the torch path's :class:`~pedrl.sim.state.RoomState`, so that an
error of one stage never feeds the next and every comparison is of one stage alone:

- **act**: :func:`pedrl.sim.step_kernel.act_room` against :meth:`pedrl.sim.RoomEnv.step`, with the same actions and
  the same order of action (the draws ``RoomEnv`` makes for it);
- **sense**: :func:`pedrl.sim.sensing_kernel.sense_room` against the step's observation;
- **encode**: :func:`pedrl.vq.encode_kernel.encode_room` (a factored table's
  :func:`pedrl.vq.factored_kernel.encode_factored_room`) against :meth:`pedrl.rl.TabularPolicy.rows`, from the
  same features and the same void fillings;
- **learn**: :func:`pedrl.rl.kernels.td_batch` (``td_set_batch`` for row sets) against
  :func:`pedrl.rl.td_update_torch`, on the same transitions.

The actions are epsilon-greedy on the torch path's tables. :data:`TOLERANCES` is the one declared table; the tests
(``tests/trial/test_twins.py``) run it over every scenario x contact rule x quantizer kind.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np
import torch

from pedrl.rl.policy import TabularPolicy
from pedrl.rl.qlearning import td_update_torch
from pedrl.rl.qtable import factored_values
from pedrl.sim import RoomEnv
from pedrl.sim.sensing import void_draws
from pedrl.sim.state import RoomState
from pedrl.trial import fused

__all__ = ["TOLERANCES", "Tolerances", "TwinReport", "check_twins"]


@dataclass(frozen=True)
class Tolerances:
    """How far the kernel path may be from the torch path, stage by stage.

    Attributes:
        feature: Features: distances and speeds within this relative error (absolute below 1), angles within this
            many radians, modulo 2 pi.
        position: Positions after a decision (m), for agents whose flags agree.
        speed: Speeds after a decision (m/s), for agents whose flags agree.
        reward: Rewards of a decision, for agents whose flags agree.
        flag_share: Share of acting agents whose contact, exit or goal flags may differ (a move that grazes a body
            or a wall within float32 rounding can go either way).
        id_share: Share of encoded agents whose state id may differ (near-ties of two prototypes).
        table: Q values after a TD update of the same transitions (absolute).
        velocity: The neighbours' velocities beside the state (m/s, absolute; ``info["neighbour_velocity"]``).
    """

    feature: float = 1e-5
    position: float = 1e-4
    speed: float = 1e-4
    reward: float = 1e-3
    flag_share: float = 0.01
    id_share: float = 0.01
    table: float = 1e-6
    velocity: float = 1e-5


TOLERANCES: Final = Tolerances()
"""The declared tolerances of the fast path (docs/performance.md, "The fused trial")."""


@dataclass
class TwinReport:
    """The worst differences of a lockstep run (see :class:`Tolerances` for each)."""

    decisions: int = 0
    agent_decisions: int = 0
    encoded: int = 0
    feature_excess: float = -math.inf
    """Worst ``difference - bound`` of a feature: at most 0 when every feature is within its bound."""
    position: float = 0.0
    speed: float = 0.0
    reward: float = 0.0
    flag_mismatches: int = 0
    id_mismatches: int = 0
    table: float = 0.0
    velocity: float = 0.0
    other: list[str] | None = None
    """Differences that no tolerance allows (the active flags, waypoint stages, numbers of sensed neighbours)."""

    def failures(self, tolerances: Tolerances = TOLERANCES) -> list[str]:
        """What exceeds ``tolerances``, one phrase each (empty when the paths match)."""
        out = list(self.other or [])
        if self.feature_excess > 0:
            out.append(f"a feature is {self.feature_excess:.3g} over its bound")
        for name in ("position", "speed", "reward", "table", "velocity"):
            if getattr(self, name) > getattr(tolerances, name):
                out.append(f"{name} differs by {getattr(self, name):.3g} (tolerance {getattr(tolerances, name)})")
        if self.flag_mismatches > tolerances.flag_share * max(self.agent_decisions, 1):
            out.append(f"{self.flag_mismatches} of {self.agent_decisions} agent decisions' flags differ")
        if self.id_mismatches > tolerances.id_share * max(self.encoded, 1):
            out.append(f"{self.id_mismatches} of {self.encoded} state ids differ")
        return out


def check_twins(
    env: RoomEnv,
    policy: TabularPolicy,
    *,
    seed: int,
    epsilon: float = 0.3,
    alpha: float = 0.3,
    gamma: float = 0.9,
    tolerances: Tolerances = TOLERANCES,
) -> TwinReport:
    """One trial of every room of ``env`` from ``reset(seed=seed)``, both paths in lockstep (module docstring).

    ``policy``'s tables are updated by the torch path (a copy by the kernel path, compared after each update). The
    report's :meth:`~TwinReport.failures` lists what exceeds ``tolerances``."""
    from pedrl.rl.kernels import td_batch, td_scratch, td_set_batch
    from pedrl.sim.sensing_kernel import room_search, sense_room
    from pedrl.sim.step_kernel import NO_COMMANDS, Events, Work, act_room, act_scratch

    report = TwinReport(other=[])
    rooms, agents, params = env.num_replicas, env.num_agents, env.params
    generator = torch.Generator().manual_seed(seed)
    obs, info = env.reset(seed=seed)
    inputs = fused.room_inputs(env)
    work, scratch = Work.allocate(rooms, agents, env.num_substeps), act_scratch(agents)
    events = Events.allocate(rooms, agents)
    factored = policy.encoder.num_slots is not None
    packed = policy.kernel_arrays()
    encoder = packed.factored if factored else packed.encoder
    process = policy.layout.of(rooms, agents, env.device)[0].view(rooms, agents)[:, 0].tolist()
    angles = _angle_columns(env)
    table = policy.q_values.view(-1, policy.num_actions)
    rows, void = _encode(report, policy, obs, info, env.active.clone(), generator, process, encoder, None)
    while bool(env.active.any()):
        # ---- act: from the torch state, the same actions and order of action
        acting = env.active.clone()
        actions = _epsilon_greedy(table, rows, epsilon, generator).view(rooms, agents)
        work.draws[:] = torch.rand(acting.shape, generator=_copy(env.generator)).numpy()  # the step's own draws
        state = env.state.clone().arrays()
        for r in range(rooms):
            act_room(r, state, actions.numpy(), NO_COMMANDS, inputs.room, inputs.walls, inputs.exits, inputs.routes,
                     work, events, scratch)  # fmt: skip
        obs, reward, terminated, _, info = env.step(actions)
        _compare_step(report, env, state, events, acting, reward, terminated, info)
        # ---- sense: from the torch state after the step
        features = np.zeros((rooms, agents, env.num_features), np.float32)
        num_sensed = np.zeros((rooms, agents), np.int64)
        velocity = np.zeros((rooms, agents, params.num_neighbours, 2), np.float32)
        size = max(agents, env.geometry.num_walls)
        mine = env.state.arrays()
        in_room = (acting & ~terminated).numpy()  # terminated: passed any exit
        for r in range(rooms):
            sense_room(r, mine, in_room, inputs.walls, params.num_neighbours, params.num_walls,
                       room_search(inputs.room), features, num_sensed, np.empty((2, size), np.float32),
                       np.empty((2, size), np.int64), velocity)  # fmt: skip
        if not np.array_equal(num_sensed, info["num_sensed"].numpy()):
            report.other.append(f"decision {report.decisions}: the numbers of sensed neighbours differ")
        gap = float(np.abs(velocity - info["neighbour_velocity"].numpy()).max(initial=0.0))
        report.velocity = max(report.velocity, gap)
        present = torch.from_numpy(in_room)
        _compare_features(report, env, torch.from_numpy(features), obs, present, angles, tolerances.feature)
        # ---- encode: from the torch features, with the same void fillings
        next_rows, void = _encode(report, policy, obs, info, present, generator, process, encoder, void)
        # ---- learn: the same transitions
        valid, left = acting.view(-1), terminated.view(-1)
        copy = table.clone()
        td_update_torch(policy.q_values, rows, actions.view(-1), reward.view(-1), next_rows, left, valid,
                        alpha=alpha, gamma=gamma)  # fmt: skip
        arrays = (copy, rows, actions.view(-1), reward.view(-1).float(), next_rows, left, valid)
        numbers = (np.float32(alpha), np.float32(gamma), np.zeros(valid.shape[0], np.float32))
        if factored:
            entries = rows.numel()
            keys, tally, _ = td_scratch(entries)
            td_set_batch(*(a.contiguous().numpy() for a in arrays), *numbers, np.empty((1, table.shape[1]), np.float32),
                         keys, tally, np.empty(entries, np.int64))  # fmt: skip
        else:
            td_batch(*(a.contiguous().numpy() for a in arrays), *numbers, *td_scratch(valid.shape[0]))
        report.table = max(report.table, float((copy - table).abs().max()))
        rows = next_rows
        report.decisions += 1
    return report


def _copy(generator: torch.Generator) -> torch.Generator:
    return torch.Generator().set_state(generator.get_state())


def _angle_columns(env: RoomEnv) -> torch.Tensor:
    """The feature columns that are angles (the door's, each neighbour's and each wall's bearing)."""
    k, w = env.params.num_neighbours, env.params.num_walls
    columns = [1] + [5 + 3 * i for i in range(k)] + [3 + 3 * k + 2 * i + 1 for i in range(w)]
    mask = torch.zeros(env.num_features, dtype=torch.bool)
    mask[columns] = True
    return mask


def _epsilon_greedy(table: torch.Tensor, rows: torch.Tensor, epsilon: float, generator: torch.Generator):
    explore = torch.rand(rows.shape[:1], generator=generator) < epsilon
    uniform = torch.randint(table.shape[1], rows.shape[:1], generator=generator)
    values = factored_values(table, rows) if rows.ndim == 2 else table.index_select(0, rows)
    return torch.where(explore, uniform, values.argmax(1))


def _compare_step(report, env, state, events, acting, reward, terminated, info) -> None:
    """The kernel's state and events after a decision against the torch step's."""
    agree = acting.clone()
    for theirs, mine in ((info["crashed_wall"], events.crashed_wall), (info["crashed_agent"], events.crashed_agent),
                         (terminated, events.left), (info["reached"], events.goal)):  # fmt: skip
        agree &= theirs == torch.from_numpy(mine)
    report.flag_mismatches += int((acting & ~agree).sum())
    report.agent_decisions += int(acting.sum())
    after = RoomState.from_arrays(state)
    close = agree.unsqueeze(-1)
    report.position = max(report.position, float(((after.positions - env.positions) * close).abs().max()))
    report.speed = max(report.speed, float(((after.speeds - env.speeds) * agree).abs().max()))
    report.reward = max(report.reward, float(((torch.from_numpy(events.reward) - reward) * agree).abs().max()))
    if not torch.equal(after.active | ~agree, env.active | ~agree) or not torch.equal(after.stage, env.stage):
        report.other.append(f"decision {report.decisions}: the active flags or waypoint stages differ")


def _canonical(features: torch.Tensor, k: int, w: int) -> torch.Tensor:
    """``features`` with the neighbour and wall slots of equal distances (within 1e-4 m) ordered by bearing: two walls
    or bodies at one distance are sensed in either order (a tie of float32 distances), as slots of one set."""
    out = features.clone()
    for start, count, width in ((3, k, 3), (3 + 3 * k, w, 2)):
        block = out[..., start : start + count * width].unflatten(-1, (count, width))
        distance, bearing = block[..., width - 2], block[..., width - 1]
        order = (torch.round(distance.double() / 1e-4) * 10.0 + bearing.double()).argsort(-1)  # float64: exact
        block = block.gather(-2, order.unsqueeze(-1).expand_as(block))
        out[..., start : start + count * width] = block.flatten(-2)
    return out


def _compare_features(report, env: RoomEnv, features, expected, present, angles, tolerance: float) -> None:
    """The worst excess of a feature over its bound (relative ``tolerance``, or ``tolerance`` rad for angles)."""
    features = _canonical(features, env.params.num_neighbours, env.params.num_walls)
    expected = _canonical(expected, env.params.num_neighbours, env.params.num_walls)
    difference = (features - expected).abs()
    difference[..., angles] = torch.minimum(difference[..., angles], 2 * math.pi - difference[..., angles])
    bound = torch.where(angles, torch.full_like(expected, tolerance), tolerance * expected.abs().clamp_min(1.0))
    excess = torch.where(present.unsqueeze(-1), difference - bound, -torch.inf)
    report.feature_excess = max(report.feature_excess, float(excess.max()))


def _encode(report, policy, obs, info, present, generator, process, encoder, void):
    """The torch path's rows of ``obs`` and the kernel's from the same features and void fillings, compared for the
    ``present`` agents; returns the torch rows and the void fillings (kept for a trial under ``void_draws=trial``)."""
    from pedrl.vq.encode_kernel import encode_buffers, encode_room
    from pedrl.vq.factored_kernel import encode_factored_room

    rooms, agents = present.shape
    settings = policy.encoder.settings
    random_void = settings.void_features == "random"
    if random_void and (void is None or settings.void_draws == "decision" or info["decision"] == 0):
        void = void_draws((rooms * agents,), num_neighbours=settings.num_neighbours, generator=_copy(generator))
    rows = policy.rows(obs, info, generator)
    fills = void.view(rooms, agents, -1).numpy() if random_void else np.zeros((rooms, agents, 1), np.float32)
    base = policy.layout.of(rooms, agents, obs.device)[1].view(rooms, agents).numpy()
    features, num_sensed = obs.contiguous().numpy(), info["num_sensed"].contiguous().numpy()
    if rows.ndim == 2:  # row sets of a factored table: the same set, slot by slot
        mine = np.zeros((rooms, agents, rows.shape[1]), np.int64)
        x = np.empty(obs.shape[-1], np.float32)
        for r in range(rooms):
            encode_factored_room(r, present.numpy(), base, mine, features, num_sensed, settings.kernel(), encoder, x)
        same = (torch.from_numpy(mine).view(rows.shape) == rows).all(1).view(rooms, agents)[present]
        report.id_mismatches += int((~same).sum())
        report.encoded += int(same.numel())
        return rows, void
    mine = np.zeros((rooms, agents), np.int64)
    buffers = encode_buffers(agents, obs.shape[-1])
    for r in range(rooms):
        encode_room(r, process[r], present.numpy(), base, mine, features, num_sensed, fills, settings.kernel(),
                    encoder.arrays, encoder.tree, encoder.pruned, buffers)  # fmt: skip
    same = (torch.from_numpy(mine).view(-1) == rows).view(rooms, agents)[present]
    report.id_mismatches += int((~same).sum())
    report.encoded += int(same.numel())
    return rows, void

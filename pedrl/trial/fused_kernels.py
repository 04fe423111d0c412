"""The fused trial: the torch trial loop (:func:`pedrl.trial.loop.crowd_loop`) as one compiled loop per learning
process, composed of the stage kernels that sit beside their torch twins:

- act: :func:`pedrl.sim.step_kernel.act_room` (:meth:`pedrl.sim.RoomEnv.step` without the observation);
- sense: :func:`pedrl.sim.sensing_kernel.sense_room` (:func:`pedrl.sim.sensing.observe`);
- encode: :func:`pedrl.vq.encode_kernel.encode_room` (:meth:`pedrl.vq.StateEncoder.prepare` and the nearest prototype),
  or for a factored table :func:`pedrl.vq.factored_kernel.encode_factored_room` (a row set per agent);
- learn: :func:`pedrl.rl.kernels.td_batch` (:func:`pedrl.rl.td_update_torch`), the same kernel as the torch loop's
  (:func:`pedrl.rl.kernels.td_set_batch` for row sets);
- choose: :func:`pedrl.rl.kernels.epsilon_greedy_row` (:func:`pedrl.rl.epsilon_greedy`; ``epsilon_greedy_set``).

The learning processes run in parallel (``prange``); a process runs its ``E`` rooms in turn, decision by decision,
and owns its tables, so no two threads write the same row. Every room draws from its own counter-based stream
(:mod:`pedrl.sim.streams`), so a seed gives the same trial at any thread count. The random numbers are not torch's,
so the two paths agree within the tolerances that ``tests/trial/test_twins.py`` states and checks.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import prange

from pedrl._numba import cached_njit
from pedrl.rl.kernels import epsilon_greedy_row, epsilon_greedy_set, td_batch, td_set_batch
from pedrl.sim.greedy_kernel import greedy_action
from pedrl.sim.sensing_kernel import room_search, sense_room
from pedrl.sim.step_kernel import act_room, act_scratch
from pedrl.sim.streams import next_uniform
from pedrl.vq.encode_kernel import draw_void, encode_buffers, encode_room
from pedrl.vq.factored_kernel import encode_factored_room

__all__ = ["Learning", "Observed", "Trace", "fused_trial"]


class Learning(NamedTuple):
    """How the trial acts and learns."""

    epsilon: np.float32
    learn: bool
    """Update the tables (else only act)."""
    alpha: np.float32
    gamma: np.float32
    void_each_decision: bool
    """Random void fillings drawn again at every decision (else once per trial)."""
    greedy: bool
    """The greedy walker acts (:func:`pedrl.sim.greedy_kernel.greedy_action`), and nothing is encoded."""
    until: np.int64
    """The call returns once the trial has taken this many decisions (a trial run in parts, for a progress bar; the
    next call goes on where it stopped, with the same numbers)."""


class Observed(NamedTuple):
    """The latest observation of every room and what the agents chose (:meth:`allocate`)."""

    features: np.ndarray
    """``(R, N, F)`` float32."""
    num_sensed: np.ndarray
    rows: np.ndarray
    """``(R, N)`` int64: each agent's table row."""
    next_rows: np.ndarray
    actions: np.ndarray
    sets: np.ndarray
    """``(R, N, M)`` int64: each agent's row set of a factored table (``M = 0`` for a plain one)."""
    next_sets: np.ndarray

    @classmethod
    def allocate(cls, rooms: int, agents: int, features: int, slots: int = 0) -> Observed:
        shape = (rooms, agents)
        return cls(
            np.zeros((*shape, features), np.float32),
            *(np.zeros(shape, np.int64) for _ in range(4)),
            *(np.full((*shape, slots), -1, np.int64) for _ in range(2)),
        )


class Trace(NamedTuple):
    """A recorded trial (``T = 1``: not recorded): frame 0 the reset, frame t after decision ``t * every`` (and a
    room's last frame after its last decision) (:meth:`allocate`)."""

    positions: np.ndarray
    """``(R, T, N, 2)`` float32 (m)."""
    velocities: np.ndarray
    """``(R, T, N, 2)`` float32 (m/s)."""
    present: np.ndarray
    """``(R, T, N)`` bool: in frame 0 the agents in the room, in frame t those that took its decision."""
    every: np.int64
    """Decisions between frames (1: every decision)."""

    @classmethod
    def allocate(cls, rooms: int, frames: int, agents: int, every: int = 1) -> Trace:
        return cls(
            np.zeros((rooms, frames, agents, 2), np.float32),
            np.zeros((rooms, frames, agents, 2), np.float32),
            np.zeros((rooms, frames, agents), np.bool_),
            np.int64(every),
        )


@cached_njit(nogil=True)
def _record(r, frame, state, present, trace):
    """Frame ``frame`` of room ``r`` into ``trace``: positions, velocities, and who is in it (``present``)."""
    trace.positions[r, frame] = state.positions[r]
    trace.velocities[r, frame] = state.velocities[r]
    trace.present[r, frame] = present[r]


@cached_njit(nogil=True)
def _run_process(
    p, rooms, state, room, walls, exits, routes, encoder, tree, pruned, settings, factored, learning, table,
    base_rows, process_of, streams, work, events, observed, void, totals, td_sums, trace, start,
):  # fmt: skip
    """Every decision of process ``p``'s rooms ``p E .. p E + E - 1`` until they are empty (or ``learning.until``),
    from decision ``start`` (0: the reset, observed first); returns the decisions taken. ``factored``
    (:class:`pedrl.vq.factored_kernel.FactoredArrays`) of any slots: the table is factored, and the agents act on
    and learn into row sets."""
    positions, speeds, active = state.positions, state.speeds, state.active
    k, w, search = room.num_neighbours, room.num_walls, room_search(room)
    random_void, epsilon, greedy = settings.random_void, learning.epsilon, learning.greedy
    speed_changes, turn_changes, goal_frame = room.speed_changes, room.turn_changes, room.goal_frame
    record = trace.present.shape[1] > 1  # frame 0 the reset, frame t after decision t * every
    features, num_sensed, rows, next_rows = observed.features, observed.num_sensed, observed.rows, observed.next_rows
    actions, reward, acting = observed.actions, events.reward, events.acting
    num_agents = positions.shape[1]
    first = p * rooms
    batch = slice(first * num_agents, (first + rooms) * num_agents)  # the process's rooms, flat
    size = max(num_agents, walls.starts.shape[0])
    distances, indices = np.empty((2, size), np.float32), np.empty((2, size), np.int64)
    no_velocity = np.zeros((0, 0, 0, 2), np.float32)  # the tables read no neighbour velocity
    no_commands = np.zeros((0, 0, 2), np.float32)  # they act by action index
    buffers = encode_buffers(num_agents, features.shape[2])
    scratch = act_scratch(num_agents)
    errors = np.empty(rooms * num_agents, np.float32)
    sets, next_sets = observed.sets, observed.next_sets
    num_slots = sets.shape[2]  # factored.num_slots, as allocated
    is_factored = num_slots > 0
    entries = rooms * num_agents * max(num_slots, 1)
    slots = 1
    while slots < 2 * entries:
        slots *= 2
    keys, tally, slot_of = np.empty(slots, np.int64), np.empty(slots, np.int64), np.empty(entries, np.int64)
    values, x = np.empty((1, table.shape[1]), np.float32), np.empty(features.shape[2], np.float32)

    # ---- the first observation and choice
    for r in range(first, first + rooms if start == 0 else first):
        if record:
            _record(r, 0, state, active, trace)
        if random_void:
            draw_void(r, void, streams)
        sense_room(r, state, active, walls, k, w, search, features, num_sensed, distances, indices, no_velocity)
        if is_factored:
            encode_factored_room(r, active, base_rows, sets, features, num_sensed, settings, factored, x)
        elif not greedy:
            encode_room(r, process_of[r], active, base_rows, rows, features, num_sensed, void, settings, encoder,
                        tree, pruned, buffers)  # fmt: skip
        for i in range(num_agents):
            if active[r, i]:
                actions[r, i] = _choose(r, i, greedy, is_factored, features, speed_changes, turn_changes, goal_frame,
                                        epsilon, streams, table, rows, sets, values)  # fmt: skip
    steps = start
    while steps < learning.until and active[first : first + rooms].any():
        # ---- act, sense, encode (each room)
        for r in range(first, first + rooms):
            for i in range(num_agents):
                work.draws[r, i] = next_uniform(streams, r)  # the order of the movers
            act_room(r, state, actions, no_commands, room, walls, exits, routes, work, events, scratch)
            if record and ((steps + 1) % trace.every == 0 or not active[r].any()):
                _record(r, (steps + trace.every) // trace.every, state, acting, trace)
            if random_void and learning.void_each_decision:
                draw_void(r, void, streams)
            sense_room(r, state, events.in_room, walls, k, w, search, features, num_sensed, distances, indices,
                       no_velocity)  # fmt: skip
            if is_factored:
                encode_factored_room(r, events.in_room, base_rows, next_sets, features, num_sensed, settings, factored,
                                     x)  # fmt: skip
            elif not greedy:
                encode_room(r, process_of[r], events.in_room, base_rows, next_rows, features, num_sensed, void,
                            settings, encoder, tree, pruned, buffers)  # fmt: skip
        # ---- learn (the process's rooms at once, into its tables)
        if learning.learn and is_factored:
            flat_sets = sets.reshape((sets.shape[0] * num_agents, num_slots))
            flat_next = next_sets.reshape((sets.shape[0] * num_agents, num_slots))
            total, count = td_set_batch(
                table, flat_sets[batch], actions.reshape(-1)[batch], reward.reshape(-1)[batch], flat_next[batch],
                events.left.reshape(-1)[batch], acting.reshape(-1)[batch], learning.alpha, learning.gamma, errors,
                values, keys, tally, slot_of,
            )  # fmt: skip
            td_sums[p, 0] += total
            td_sums[p, 1] += count
        elif learning.learn:
            total, count = td_batch(
                table, rows.reshape(-1)[batch], actions.reshape(-1)[batch], reward.reshape(-1)[batch],
                next_rows.reshape(-1)[batch], events.left.reshape(-1)[batch], acting.reshape(-1)[batch],
                learning.alpha, learning.gamma, errors, keys, tally, slot_of,
            )  # fmt: skip
            td_sums[p, 0] += total
            td_sums[p, 1] += count
        # ---- tally and choose
        for r in range(first, first + rooms):
            for i in range(num_agents):
                if acting[r, i]:
                    totals.returns[r, i] += reward[r, i]
                    totals.crashes_agent[r, i] += events.crashed_agent[r, i]
                    totals.crashes_wall[r, i] += events.crashed_wall[r, i]
                    totals.reached[r, i] += events.goal[r, i]
                    totals.speed_sum[r, i] += speeds[r, i]
                    totals.decisions[r, i] += 1.0
                rows[r, i] = next_rows[r, i]
                for m in range(num_slots):
                    sets[r, i, m] = next_sets[r, i, m]
                if active[r, i]:
                    actions[r, i] = _choose(r, i, greedy, is_factored, features, speed_changes, turn_changes,
                                            goal_frame, epsilon, streams, table, rows, sets, values)  # fmt: skip
        steps += 1
    return steps


@cached_njit(nogil=True, inline="always")
def _choose(r, i, greedy, is_factored, features, speed_changes, turn_changes, goal_frame, epsilon, streams, table, rows,
            sets, values):  # fmt: skip
    """Agent ``i``'s action: the greedy walker's, or epsilon-greedy on its table row or (factored) its row set."""
    if greedy:
        return greedy_action(features[r, i, 1], speed_changes, turn_changes, goal_frame, epsilon, streams, r)
    if is_factored:
        return epsilon_greedy_set(table, sets[r, i], values, epsilon, streams, r)
    return epsilon_greedy_row(table, rows[r, i], epsilon, streams, r)


@cached_njit(nogil=True, parallel=True)
def fused_trial(
    rooms, state, room, walls, exits, routes, encoder, tree, pruned, settings, factored, learning, table, base_rows,
    process_of, streams, work, events, observed, void, totals, td_sums, steps, trace,
):  # fmt: skip
    """A whole trial of every room from its reset state: the processes ``p`` of ``E = rooms`` rooms each in
    parallel, each by :func:`_run_process`; ``steps[p]`` holds the decisions taken before (0: from the reset) and
    gets them after.

    ``state`` (:class:`pedrl.sim.state.KernelState`) is updated in place; ``learning`` is :class:`Learning`;
    ``totals`` (:class:`pedrl.trial.stats.Totals` of ``(R, N)`` float64 arrays) gets each agent's return, body
    contacts, wall contacts, goal, speed sum and decisions; ``td_sums`` ``(P, 2)`` float64 the sum of ``|TD error|``
    and the updates; ``trace`` (:class:`Trace`) gets a frame every ``trace.every`` decisions when it has more than
    one. ``room``, ``walls``, ``exits``,
    ``routes``, ``work`` and ``events`` are :func:`pedrl.sim.step_kernel.act_room`'s; ``encoder``, ``tree``,
    ``pruned`` and ``settings`` :func:`pedrl.vq.encode_kernel.encode_room`'s, ``factored``
    :func:`pedrl.vq.factored_kernel.encode_factored_room`'s (a stub of no slots for a plain table).
    """
    for p in prange(steps.shape[0]):
        steps[p] = _run_process(
            p, rooms, state, room, walls, exits, routes, encoder, tree, pruned, settings, factored, learning, table,
            base_rows, process_of, streams, work, events, observed, void, totals, td_sums, trace, steps[p],
        )  # fmt: skip

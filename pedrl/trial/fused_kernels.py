"""The fused trial: the torch trial loop (:func:`pedrl.trial.rollout.run_trial`) as one compiled loop per learning
process, composed of the stage kernels that sit beside their torch twins:

- act: :func:`pedrl.sim.step_kernel.act_room` (:meth:`pedrl.sim.RoomEnv.step` without the observation);
- sense: :func:`pedrl.sim.sensing_kernel.sense_room` (:func:`pedrl.sim.sensing.observe`);
- encode: :func:`pedrl.vq.encode_kernel.encode_room` (:meth:`pedrl.vq.StateEncoder.prepare` and the nearest prototype);
- learn: :func:`pedrl.rl.kernels.td_batch` (:func:`pedrl.rl.td_update_torch`), the same kernel as the torch loop's;
- choose: :func:`pedrl.rl.kernels.epsilon_greedy_row` (:func:`pedrl.rl.epsilon_greedy`).

The learning processes run in parallel (``prange``); a process runs its ``E`` rooms in turn, decision by decision,
and owns its tables, so no two threads write the same row. Every room draws from its own counter-based stream
(:mod:`pedrl.sim.streams`), so a seed gives the same trial at any thread count. The random numbers are not torch's,
so the two paths agree within the tolerances that ``tests/trial/test_twins.py`` states and checks.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from pedrl._numba import cached_njit
from pedrl.rl.kernels import epsilon_greedy_row, td_batch
from pedrl.sim.greedy_kernel import greedy_action
from pedrl.sim.sensing_kernel import sense_room
from pedrl.sim.step_kernel import act_room, act_scratch
from pedrl.sim.streams import next_uniform
from pedrl.vq.encode_kernel import draw_void, encode_buffers, encode_room

__all__ = ["fused_trial"]


@cached_njit(nogil=True)
def _record(r, frame, state, present, trace):
    """Frame ``frame`` of room ``r`` into ``trace``: positions, velocities, and who is in it (``present``)."""
    positions, velocities = state[0], state[1]
    trace[0][r, frame] = positions[r]
    trace[1][r, frame] = velocities[r]
    trace[2][r, frame] = present[r]


@cached_njit(nogil=True)
def _run_process(
    p, rooms, state, room, walls, exits, encoder, tree, settings, learning, table, base_rows, process_of,
    streams, work, events, observed, void, totals, td_sums, trace,
):  # fmt: skip
    """Every decision of process ``p``'s rooms ``p E .. p E + E - 1`` until they are empty; returns the decisions
    taken."""
    positions, _, _, speeds, active, _, _, _, _ = state
    k, random_void = settings[0], settings[4]
    epsilon, learn, alpha, gamma, void_each_decision, greedy = learning
    speed_changes, turn_changes, goal_frame = room[0], room[1], room[9]
    trace_positions, trace_velocities, trace_active = trace
    record = trace_active.shape[1] > 1  # frame 0 the reset, frame t after decision t
    features, num_sensed, rows, next_rows, actions = observed
    reward, left, goal, crashed_wall, crashed_agent, acting, in_room = events
    num_agents, num_features = positions.shape[1], features.shape[2]
    w = (num_features - 3 - 3 * k) // 2  # the wall slots of the state's 3 + 3k + 2w features
    first = p * rooms
    batch = slice(first * num_agents, (first + rooms) * num_agents)  # the process's rooms, flat
    size = max(num_agents, walls[0].shape[0])
    distances, indices = np.empty((2, size), np.float32), np.empty((2, size), np.int64)
    buffers = encode_buffers(num_agents, num_features)
    scratch = act_scratch(num_agents)
    errors = np.empty(rooms * num_agents, np.float32)
    slots = 1
    while slots < 2 * rooms * num_agents:
        slots *= 2
    keys, tally, slot_of = np.empty(slots, np.int64), np.empty(slots, np.int64), np.empty(rooms * num_agents, np.int64)

    # ---- the first observation and choice
    for r in range(first, first + rooms):
        if record:
            _record(r, 0, state, active, trace)
        if random_void:
            draw_void(r, void, streams)
        sense_room(r, state, active, walls, k, w, features, num_sensed, distances, indices)
        if not greedy:
            encode_room(r, process_of[r], active, base_rows, rows, features, num_sensed, void, settings, encoder,
                        tree, buffers)  # fmt: skip
        for i in range(num_agents):
            if active[r, i]:
                actions[r, i] = (
                    greedy_action(features[r, i, 1], speed_changes, turn_changes, goal_frame, epsilon, streams, r)
                    if greedy else epsilon_greedy_row(table, rows[r, i], epsilon, streams, r)
                )  # fmt: skip
    steps = 0
    while active[first : first + rooms].any():
        # ---- act, sense, encode (each room)
        for r in range(first, first + rooms):
            for i in range(num_agents):
                work[-1][r, i] = next_uniform(streams, r)  # the order of the movers
            act_room(r, state, actions, room, walls, exits, work, events, scratch)
            if record:
                _record(r, steps + 1, state, acting, trace)
            if random_void and void_each_decision:
                draw_void(r, void, streams)
            sense_room(r, state, in_room, walls, k, w, features, num_sensed, distances, indices)
            if not greedy:
                encode_room(r, process_of[r], in_room, base_rows, next_rows, features, num_sensed, void, settings,
                            encoder, tree, buffers)  # fmt: skip
        # ---- learn (the process's rooms at once, into its tables)
        if learn:
            total, count = td_batch(
                table, rows.reshape(-1)[batch], actions.reshape(-1)[batch], reward.reshape(-1)[batch],
                next_rows.reshape(-1)[batch], left.reshape(-1)[batch], acting.reshape(-1)[batch], alpha, gamma,
                errors, keys, tally, slot_of,
            )  # fmt: skip
            td_sums[p, 0] += total
            td_sums[p, 1] += count
        # ---- tally and choose
        for r in range(first, first + rooms):
            for i in range(num_agents):
                if acting[r, i]:
                    totals[0, r, i] += reward[r, i]
                    totals[1, r, i] += crashed_agent[r, i]
                    totals[2, r, i] += crashed_wall[r, i]
                    totals[3, r, i] += goal[r, i]
                    totals[4, r, i] += speeds[r, i]
                    totals[5, r, i] += 1.0
                rows[r, i] = next_rows[r, i]
                if active[r, i]:
                    actions[r, i] = (
                        greedy_action(features[r, i, 1], speed_changes, turn_changes, goal_frame, epsilon, streams, r)
                        if greedy else epsilon_greedy_row(table, rows[r, i], epsilon, streams, r)
                    )  # fmt: skip
        steps += 1
    return steps


@cached_njit(nogil=True, parallel=True)
def fused_trial(
    rooms, state, room, walls, exits, encoder, tree, settings, learning, table, base_rows, process_of,
    streams, work, events, observed, void, totals, td_sums, steps, trace,
):  # fmt: skip
    """A whole trial of every room from its reset state: the processes ``p`` of ``E = rooms`` rooms each in
    parallel, each by :func:`_run_process`; ``steps[p]`` gets its decisions.

    ``state`` is the rooms' ``(positions (R, N, 2), velocities (R, N, 2), headings (R, N), speeds (R, N), active
    (R, N), exit_index (R, N), targets (R, N, 2), decisions (R,), stage (R, N))``, updated in place; ``learning``
    is ``(epsilon, learn, alpha, gamma, void_each_decision, greedy)`` (``greedy``: the greedy walker of
    :func:`pedrl.sim.greedy_kernel.greedy_action` acts, and nothing is encoded); ``totals`` ``(6, R, N)`` float64 gets
    each agent's return, body contacts, wall contacts, goal, speed sum and decisions; ``td_sums`` ``(P, 2)`` float64
    the sum of ``|TD error|`` and the updates; ``trace`` ``(positions (R, T, N, 2), velocities (R, T, N, 2), present
    (R, T, N))`` gets frame 0 (the reset) and frame t after decision t when ``T > 1`` (``T = max_decisions + 1``).
    The other tuples are those of :func:`act_room`, :func:`sense_room` and :func:`pedrl.vq.encode_kernel.encode_agent`.
    """
    for p in prange(steps.shape[0]):
        steps[p] = _run_process(
            p, rooms, state, room, walls, exits, encoder, tree, settings, learning, table, base_rows, process_of,
            streams, work, events, observed, void, totals, td_sums, trace,
        )  # fmt: skip

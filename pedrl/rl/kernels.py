"""Numba kernels of the Q tables; their specifications are `pedrl.rl.qlearning.td_update_torch` and
`pedrl.rl.qtable.greedy_torch`.

One TD update (:func:`td_batch`) and one greedy choice (:func:`greedy_row`, with :func:`epsilon_greedy_row` drawing
from a room's stream) serve both the torch trial loop's dispatchers and the fused trial. Each reproduces its torch
function of `pedrl.rl` to the bit, with the same random numbers drawn by torch
beforehand, so a seed gives the same run either way (the tests check it): :func:`td_update_kernel` is the twin of
:func:`pedrl.rl.qlearning.td_update_torch`, :func:`greedy_kernel` that of :func:`pedrl.rl.qtable.greedy_torch`.
On a CPU a decision's greedy choice or TD update is a dozen small torch operations; here it is one pass over the
batch. The row sets of a factored table have their twins too: :func:`greedy_set`, :func:`epsilon_greedy_set` and
:func:`td_set_batch` (the sum of a set's rows, :func:`pedrl.rl.factored_values`).
"""

from __future__ import annotations

import numpy as np
import torch

from pedrl._numba import cached_njit
from pedrl.sim.streams import GOLDEN, next_uniform

__all__ = [
    "epsilon_greedy_row",
    "epsilon_greedy_set",
    "greedy_kernel",
    "greedy_row",
    "greedy_set",
    "td_batch",
    "td_scratch",
    "td_set_batch",
    "td_update_kernel",
]


@cached_njit(nogil=True)
def _prefetch(table, rows, actions, used, next_rows, next_used, sink):
    """Check the used rows and actions against the table (numba does not), and load every cache line of those
    rows, one independent load after another, so that the memory system fetches many at once (the work on a
    row would otherwise wait for each of its lines in turn). Returns the first bad position, or -1."""
    num_rows, num_actions = table.shape
    total = np.float32(0.0)
    for b in range(rows.shape[0]):
        if used[b]:
            if rows[b] < 0 or rows[b] >= num_rows or actions[b] < 0 or actions[b] >= num_actions:
                return b
            for a in range(0, num_actions, 16):
                total += table[rows[b], a]
    for b in range(next_rows.shape[0]):
        if next_used[b]:
            if next_rows[b] < 0 or next_rows[b] >= num_rows:
                return b
            for a in range(0, num_actions, 16):
                total += table[next_rows[b], a]
    sink[0] = total  # keeps the loads
    return -1


def _checked_prefetch(table, rows, actions, used, next_rows, next_used) -> None:
    """:func:`_prefetch`, raising ``IndexError`` (as torch's gathers do) for a row or action out of range."""
    bad = _prefetch(table, rows, actions, used, next_rows, next_used, np.empty(1, np.float32))
    if bad >= 0:
        raise IndexError(
            f"entry {bad}: row or action out of range for Q tables of {table.shape[0]} rows x {table.shape[1]} actions"
        )


@cached_njit(nogil=True, inline="always")
def _row_max(table, row):
    """``table[row].amax()`` as torch computes it (NaN if any value is NaN): four running maxima without branches
    (a max is exact, so their order changes nothing), and a NaN flag."""
    m0 = m1 = m2 = m3 = np.float32(-np.inf)
    nan = False
    num_actions = table.shape[1]
    a = 0
    while a + 4 <= num_actions:
        v0, v1, v2, v3 = table[row, a], table[row, a + 1], table[row, a + 2], table[row, a + 3]
        m0 = max(m0, v0)
        m1 = max(m1, v1)
        m2 = max(m2, v2)
        m3 = max(m3, v3)
        nan |= (v0 != v0) | (v1 != v1) | (v2 != v2) | (v3 != v3)
        a += 4
    while a < num_actions:
        v0 = table[row, a]
        m0 = max(m0, v0)
        nan |= v0 != v0
        a += 1
    return np.float32(np.nan) if nan else max(max(m0, m1), max(m2, m3))


@cached_njit(nogil=True, inline="always")
def greedy_row(table, row, uniform):
    """The greedy action of ``row``: the ``floor(uniform c)``-th of its ``c`` tied maxima (action 0 for a NaN row,
    as torch's argmax of an all-False mask)."""
    num_actions = table.shape[1]
    best = _row_max(table, row)
    count = 0
    for a in range(num_actions):
        count += table[row, a] == best
    pick = min(np.int64(uniform * np.float32(count)), count - 1)
    for a in range(num_actions):
        if table[row, a] == best:
            if pick == 0:
                return a
            pick -= 1
    return 0


@cached_njit(nogil=True, inline="always")
def epsilon_greedy_row(table, row, epsilon, streams, r):
    """:func:`pedrl.rl.epsilon_greedy` of one row, drawing from room ``r``'s stream: a uniform action with probability
    ``epsilon``, else :func:`greedy_row`."""
    num_actions = table.shape[1]
    if next_uniform(streams, r) < epsilon:
        return min(np.int64(next_uniform(streams, r) * np.float32(num_actions)), num_actions - 1)
    return greedy_row(table, row, next_uniform(streams, r))


@cached_njit(nogil=True, inline="always")
def set_values(table, rows, values):
    """``values (1, U)``: the sum of the rows ``rows (M,)`` of ``table`` (-1 reads nothing), slot by slot."""
    for a in range(table.shape[1]):
        values[0, a] = np.float32(0.0)
    for m in range(rows.shape[0]):
        if rows[m] >= 0:
            for a in range(table.shape[1]):
                values[0, a] += table[rows[m], a]


@cached_njit(nogil=True, inline="always")
def greedy_set(table, rows, uniform, values):
    """:func:`greedy_row` of the summed rows of the set ``rows (M,)`` (``values (1, U)`` is scratch)."""
    set_values(table, rows, values)
    return greedy_row(values, 0, uniform)


@cached_njit(nogil=True, inline="always")
def epsilon_greedy_set(table, rows, values, epsilon, streams, r):
    """:func:`epsilon_greedy_row` of the row set ``rows (M,)`` (the same draws)."""
    num_actions = table.shape[1]
    if next_uniform(streams, r) < epsilon:
        return min(np.int64(next_uniform(streams, r) * np.float32(num_actions)), num_actions - 1)
    return greedy_set(table, rows, next_uniform(streams, r), values)


@cached_njit(nogil=True)
def _greedy(table, rows, uniform, actions):
    for b in range(rows.shape[0]):
        actions[b] = greedy_row(table, rows[b], uniform[b])


@cached_njit(nogil=True)
def _greedy_sets(table, rows, uniform, actions):
    values = np.empty((1, table.shape[1]), np.float32)
    for b in range(rows.shape[0]):
        actions[b] = greedy_set(table, rows[b], uniform[b], values)


def greedy_kernel(q_values: torch.Tensor, rows: torch.Tensor, uniform: torch.Tensor) -> torch.Tensor:
    """Greedy actions of ``rows (B,)`` of the flat tables, the ``floor(uniform * c)``-th of ``c`` tied maxima."""
    actions = torch.empty(rows.shape[0], dtype=torch.int64)
    table = q_values.view(-1, q_values.shape[-1]).numpy()
    if rows.ndim == 2:  # row sets of a factored table
        _check_sets(table, rows.numpy(), None)
        _greedy_sets(table, rows.numpy(), uniform.numpy(), actions.numpy())
        return actions
    num = rows.shape[0]
    _checked_prefetch(
        table, rows.numpy(), np.zeros(num, np.int64), np.ones(num, np.bool_), rows.numpy()[:0], np.zeros(0, np.bool_)
    )
    _greedy(table, rows.numpy(), uniform.numpy(), actions.numpy())
    return actions


def td_scratch(num: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The scratch of :func:`td_batch` for batches of at most ``num`` entries: the hash table's keys and tallies (a
    power of two of at least ``2 num`` slots) and each entry's slot."""
    slots = 1
    while slots < 2 * num:
        slots *= 2
    return np.empty(slots, np.int64), np.empty(slots, np.int64), np.empty(max(num, 1), np.int64)


@cached_njit(nogil=True, inline="always")
def _clear_counts(keys, tally):
    """Empty the hash table of :func:`td_scratch`; returns its probe mask and the shift of its hash."""
    keys[:] = -1
    tally[:] = 0
    return keys.shape[0] - 1, np.uint64(64 - np.int64(np.log2(keys.shape[0])))


@cached_njit(nogil=True, inline="always")
def _count(keys, tally, entry, mask, bits):
    """Count one more hit of the table entry ``entry`` (open addressing, linear probing); returns its slot."""
    slot = np.int64((np.uint64(entry) * GOLDEN) >> bits)
    while keys[slot] != -1 and keys[slot] != entry:
        slot = (slot + 1) & mask
    keys[slot] = entry
    tally[slot] += 1
    return slot


@cached_njit(nogil=True)
def td_batch(table, rows, actions, rewards, next_rows, terminal, valid, alpha, gamma, td_error, keys, tally, slot_of):
    """Equation 1 for a batch of transitions (:func:`pedrl.rl.qlearning.td_update_torch`): every error from the tables
    before the update, the increments of one ``(row, action)`` averaged and added in batch order. Returns the sum of
    ``|TD error|`` and the number of updates.

    ``table`` ``(rows, actions)`` float32; ``rows``, ``actions``, ``next_rows`` ``(B,)`` int64; ``rewards`` ``(B,)``
    float32; ``terminal`` and ``valid`` ``(B,)`` bool; ``td_error`` ``(B,)`` float32 gets the errors (0 where not
    ``valid``). ``keys``, ``tally`` and ``slot_of`` are :func:`td_scratch`: the entries hitting one ``(row, action)``
    are counted in an open-addressing hash table (a sort cost more than the rest of the update).
    """
    num, num_actions = rows.shape[0], table.shape[1]
    flat = table.reshape(-1)
    mask, bits = _clear_counts(keys, tally)
    total, count = 0.0, 0
    for b in range(num):
        slot_of[b] = -1
        if not valid[b]:
            td_error[b] = 0.0
            continue
        next_value = np.float32(0.0) if terminal[b] else _row_max(table, next_rows[b])
        entry = rows[b] * num_actions + actions[b]
        td_error[b] = (rewards[b] + gamma * next_value) - flat[entry]
        slot_of[b] = _count(keys, tally, entry, mask, bits)
        total += abs(td_error[b])
        count += 1
    for b in range(num):
        if slot_of[b] >= 0:  # torch's `alpha / counts`: a reciprocal
            entry = rows[b] * num_actions + actions[b]
            flat[entry] += td_error[b] * ((np.float32(1.0) / np.float32(tally[slot_of[b]])) * alpha)
    return total, count


def _check_sets(table, rows, actions) -> None:
    """``IndexError`` (as torch's gathers) for a row of a set beyond the table (-1 is an empty slot) or an action out
    of range."""
    if rows.size and (rows.max() >= table.shape[0] or rows.min() < -1):
        raise IndexError(f"a row set holds a row out of range for Q tables of {table.shape[0]} rows")
    if actions is not None and actions.size and (actions.min() < 0 or actions.max() >= table.shape[1]):
        raise IndexError(f"an action is out of range for Q tables of {table.shape[1]} actions")


@cached_njit(nogil=True)
def td_set_batch(table, rows, actions, rewards, next_rows, terminal, valid, alpha, gamma, td_error, values, keys,
                 tally, slot_of):  # fmt: skip
    """:func:`td_batch` for row sets ``rows``, ``next_rows`` ``(B, M)`` of a factored table
    (:func:`pedrl.rl.qlearning.td_update_torch`'s rule for them): the TD error of the summed values, shared by the
    ``n`` rows of the set (``delta / n`` each), the increments of one ``(row, action)`` averaged and added in
    entry order. ``values (1, U)`` is scratch; ``keys`` and ``tally`` are :func:`td_scratch` of ``B M`` entries,
    ``slot_of (B M,)``. Returns the sum of ``|TD error|`` and the number of updates."""
    num, slots_per = rows.shape
    num_actions = table.shape[1]
    flat = table.reshape(-1)
    mask, bits = _clear_counts(keys, tally)
    total, count = 0.0, 0
    for b in range(num):
        for m in range(slots_per):
            slot_of[b * slots_per + m] = -1
        if not valid[b]:
            td_error[b] = 0.0
            continue
        next_value = np.float32(0.0)
        if not terminal[b]:
            set_values(table, next_rows[b], values)
            next_value = _row_max(values, 0)
        value = np.float32(0.0)
        for m in range(slots_per):
            if rows[b, m] >= 0:
                value += table[rows[b, m], actions[b]]
        td_error[b] = (rewards[b] + gamma * next_value) - value
        for m in range(slots_per):
            if rows[b, m] >= 0:
                slot_of[b * slots_per + m] = _count(keys, tally, rows[b, m] * num_actions + actions[b], mask, bits)
        total += abs(td_error[b])
        count += 1
    for b in range(num):
        n = 0
        for m in range(slots_per):
            n += rows[b, m] >= 0
        share = td_error[b] / np.float32(max(n, 1))
        for m in range(slots_per):
            slot = slot_of[b * slots_per + m]
            if slot >= 0:
                flat[rows[b, m] * num_actions + actions[b]] += share * (
                    (np.float32(1.0) / np.float32(tally[slot])) * alpha
                )
    return total, count


def td_update_kernel(
    q_values: torch.Tensor,
    rows: torch.Tensor,
    actions: torch.Tensor,
    rewards: torch.Tensor,
    next_rows: torch.Tensor,
    terminal: torch.Tensor,
    valid: torch.Tensor,
    *,
    alpha: float,
    gamma: float,
) -> torch.Tensor:
    """:func:`pedrl.rl.qlearning.td_update_torch` on the CPU, compiled (same arguments, same result to the bit)."""
    num = rows.shape[0]
    td_error = torch.empty(num, dtype=torch.float32)
    table = q_values.view(-1, q_values.shape[-1]).numpy()
    rows, actions, next_rows = rows.numpy(), actions.numpy(), next_rows.numpy()
    terminal, valid = terminal.numpy(), valid.numpy()
    if rows.ndim == 2:  # row sets of a factored table
        _check_sets(table, rows[valid], actions[valid])
        _check_sets(table, next_rows[valid & ~terminal], None)
        keys, tally, _ = td_scratch(num * rows.shape[1])
        td_set_batch(
            table, rows, actions, rewards.to(torch.float32).numpy(), next_rows, terminal, valid, np.float32(alpha),
            np.float32(gamma), td_error.numpy(), np.empty((1, table.shape[1]), np.float32), keys, tally,
            np.empty(max(num * rows.shape[1], 1), np.int64),
        )  # fmt: skip
        return td_error
    _checked_prefetch(table, rows, actions, valid, next_rows, valid & ~terminal)
    td_batch(
        table,
        rows,
        actions,
        rewards.to(torch.float32).numpy(),
        next_rows,
        terminal,
        valid,
        np.float32(alpha),
        np.float32(gamma),
        td_error.numpy(),
        *td_scratch(num),
    )
    return td_error

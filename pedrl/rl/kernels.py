"""Numba kernels of the Q tables; their specifications are `pedrl.rl.qlearning.td_update_torch` and
`pedrl.rl.qtable.greedy_torch`.

Each reproduces its torch function of `pedrl.rl` to the bit, with the same random numbers drawn by torch
beforehand, so a seed gives the same run either way (the tests check it): :func:`td_update_kernel` is the twin of
:func:`pedrl.rl.qlearning.td_update_torch`, :func:`greedy_kernel` that of :func:`pedrl.rl.qtable.greedy_torch`.
On a CPU a decision's greedy choice or TD update is a dozen small torch operations; here it is one pass over the
batch.
"""

from __future__ import annotations

import numpy as np
import torch

from pedrl._numba import cached_njit

__all__ = ["greedy_kernel", "td_update_kernel"]


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


@cached_njit(nogil=True)
def _greedy(table, rows, uniform, actions):
    num_actions = table.shape[1]
    for b in range(rows.shape[0]):
        row = rows[b]
        best = _row_max(table, row)
        count = 0
        for a in range(num_actions):
            count += table[row, a] == best
        pick = np.int64(uniform[b] * np.float32(count))
        pick = min(pick, count - 1)
        chosen = 0  # no maximum (a NaN row): action 0, as torch's argmax of an all-False mask
        for a in range(num_actions):
            if table[row, a] == best:
                if pick == 0:
                    chosen = a
                    break
                pick -= 1
        actions[b] = chosen


def greedy_kernel(q_values: torch.Tensor, rows: torch.Tensor, uniform: torch.Tensor) -> torch.Tensor:
    """Greedy actions of ``rows (B,)`` of the flat tables, the ``floor(uniform * c)``-th of ``c`` tied maxima."""
    actions = torch.empty(rows.shape[0], dtype=torch.int64)
    table = q_values.view(-1, q_values.shape[-1]).numpy()
    num = rows.shape[0]
    _checked_prefetch(
        table, rows.numpy(), np.zeros(num, np.int64), np.ones(num, np.bool_), rows.numpy()[:0], np.zeros(0, np.bool_)
    )
    _greedy(table, rows.numpy(), uniform.numpy(), actions.numpy())
    return actions


@cached_njit(nogil=True)
def _td(table, rows, actions, rewards, next_rows, terminal, valid, alpha, gamma, td_error):
    num, num_actions = rows.shape[0], table.shape[1]
    flat = table.reshape(-1)
    entries = np.empty(num, dtype=np.int64)  # flat (row, action) index, -1 where skipped
    counts = np.empty(num, dtype=np.int64)  # entries hitting the same (row, action)
    for b in range(num):
        if not valid[b]:
            td_error[b] = 0.0
            entries[b] = -1
            continue
        next_value = np.float32(0.0) if terminal[b] else _row_max(table, next_rows[b])
        entries[b] = rows[b] * num_actions + actions[b]
        td_error[b] = (rewards[b] + gamma * next_value) - flat[entries[b]]  # every error before any update
    # increments averaged over the entries that hit the same (row, action), added in batch order; the entries are
    # counted in an open-addressing hash table (a sort cost more than the rest of the update)
    bits = 1
    while (1 << bits) < 2 * num:
        bits += 1
    keys = np.full(1 << bits, -1, dtype=np.int64)
    tally = np.zeros(1 << bits, dtype=np.int64)
    mask = (1 << bits) - 1
    slots = np.zeros(num, dtype=np.int64)
    for b in range(num):
        if entries[b] < 0:
            continue
        slot = np.int64((np.uint64(entries[b]) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(64 - bits))
        while keys[slot] != -1 and keys[slot] != entries[b]:
            slot = (slot + 1) & mask
        keys[slot] = entries[b]
        tally[slot] += 1
        slots[b] = slot
    for b in range(num):
        counts[b] = tally[slots[b]] if entries[b] >= 0 else 1  # a skipped entry adds 0 below, whatever its count
    for b in range(num):
        scale = (np.float32(1.0) / np.float32(counts[b])) * alpha  # torch's `alpha / counts`: a reciprocal
        if entries[b] < 0:  # a skipped entry adds 0 to entry 0, as torch's index_add_ does
            flat[0] = flat[0] + np.float32(0.0) * scale
        else:
            flat[entries[b]] = flat[entries[b]] + td_error[b] * scale


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
    _checked_prefetch(table, rows, actions, valid, next_rows, valid & ~terminal)
    _td(
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
    )
    return td_error

"""The Q-learning update (paper equation 1), batched over flat table rows.

Twins: :func:`td_update_torch` is the specification (torch, any device), :func:`pedrl.rl.kernels.td_update_kernel`
its numba kernel for the CPU (the same numbers to the bit), and :func:`td_update` chooses between them.

A factored table (row sets ``(B, M)``, :mod:`pedrl.vq.factored`) learns by the same equation on the sum of a state's
rows: the TD error ``delta = r + gamma max_a' Q(s', a') - Q(s, a)`` of the summed values is shared among the ``n``
rows the state reads, each moving by ``alpha delta / n`` (then averaged with the other entries that hit the same
``(row, action)`` in the call, as in the plain table). An agent alone thus moves its own ``Q(s, a)`` by exactly
``alpha delta``, as one plain row would: the rows of a state never overshoot together.
"""

from __future__ import annotations

import torch

from pedrl._numba import use_kernels
from pedrl.rl.qtable import factored_values

__all__ = ["td_update", "td_update_torch"]


def td_update(
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
    compiled: bool | None = None,
) -> torch.Tensor:
    """One synchronous Q-learning step, in place on `q_values` (paper equation 1):

    `Q(s, a) <- Q(s, a) + alpha [r + gamma max_a' Q(s', a') - Q(s, a)]`.

    - Terminal transitions (the agent reached the door) do not bootstrap: the target is `r`. A trial cut by the
      time limit (truncation) is not terminal, so it bootstraps from `s'` as usual.
    - Invalid entries (inactive agents) are skipped: no update, TD error 0; their rows and actions may hold
      anything.
    - All TD errors are computed from the tables before the step. When several entries hit the same
      `(row, action)` in one call, their increments are averaged: `Q += alpha * mean(td)`. With `E` rooms of one
      process sharing a table this is one mean TD step per decision, not `E` steps.
    - Nothing is read back on the host (no data-dependent shapes), so a GPU never waits for it.

    Args:
        q_values: `(R, A, K, U)` float32 Q tables, updated in place.
        rows: `(B,)` int64 flat rows of `s` (`pedrl.rl.table_rows`), or `(B, M)` row sets of a factored table
            (-1: a slot that reads nothing; module docstring).
        actions: `(B,)` int64 actions `a` in `[0, U)`.
        rewards: `(B,)` float32 rewards `r` received after the action.
        next_rows: `(B,)` int64 flat rows of `s'`, or `(B, M)` row sets (ignored where `terminal` or not `valid`).
        terminal: `(B,)` bool, True where the transition ends the agent's trial at the door.
        valid: `(B,)` bool, False for entries to skip.
        alpha: learning rate `alpha` in `(0, 1]`.
        gamma: discount `gamma` in `[0, 1]`.
        compiled: use the numba kernel (`pedrl.rl.kernels`: one pass, the same numbers to the bit, increments of
            one entry added in batch order as `index_add_` adds them; None: on the CPU when numba is there).

    Returns:
        `(B,)` float32 TD errors `r + gamma max_a' Q(s', a') - Q(s, a)` (0 where not `valid`).
    """
    if use_kernels(q_values.device, compiled):
        from pedrl.rl.kernels import td_update_kernel  # imports numba: only where it is used

        return td_update_kernel(q_values, rows, actions, rewards, next_rows, terminal, valid, alpha=alpha, gamma=gamma)
    return td_update_torch(q_values, rows, actions, rewards, next_rows, terminal, valid, alpha=alpha, gamma=gamma)


def td_update_torch(
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
    """:func:`td_update` in torch, on any device: the specification of
    :func:`pedrl.rl.kernels.td_update_kernel` (same arguments but ``compiled``, same result)."""
    if rows.ndim == 2:
        return _td_factored_torch(
            q_values, rows, actions, rewards, next_rows, terminal, valid, alpha=alpha, gamma=gamma
        )
    num_actions = q_values.shape[-1]
    flat = q_values.view(-1, num_actions)
    zero = torch.zeros((), dtype=rows.dtype, device=rows.device)
    rows = torch.where(valid, rows, zero)
    actions = torch.where(valid, actions, zero)
    bootstrap = valid & ~terminal
    next_value = flat.index_select(0, torch.where(bootstrap, next_rows, zero)).amax(1)  # gathers: index_select
    target = rewards + gamma * torch.where(bootstrap, next_value, torch.zeros_like(next_value))
    entries = rows * num_actions + actions
    td_error = torch.where(valid, target - q_values.view(-1).index_select(0, entries), torch.zeros_like(target))
    _add_averaged(q_values, entries, td_error, valid, alpha)
    return td_error


def _add_averaged(
    q_values: torch.Tensor, entries: torch.Tensor, steps: torch.Tensor, valid: torch.Tensor, alpha: float
) -> None:
    """``q_values.view(-1)[entries] += steps * alpha / c``, ``c`` the number of valid entries hitting the same value
    (their increments averaged), added in entry order; entries not ``valid`` must be 0 with a step of 0."""
    # duplicates: the size of each entry's group, found by sorting (no host read: skipped entries form a group
    # of their own under the key -1, and add 0 to entry 0)
    keys, order = torch.where(valid, entries, -1).sort()
    starts = torch.ones_like(keys, dtype=torch.bool)
    starts[1:] = keys[1:] != keys[:-1]
    group = torch.empty_like(order).scatter_(0, order, starts.cumsum(0) - 1)
    counts = torch.zeros_like(steps).index_add_(0, group, torch.ones_like(steps))
    q_values.view(-1).index_add_(0, entries, steps * (alpha / counts.index_select(0, group)))


def _td_factored_torch(q_values, rows, actions, rewards, next_rows, terminal, valid, *, alpha, gamma) -> torch.Tensor:
    """:func:`td_update_torch` of row sets ``(B, M)`` (module docstring): the specification of
    :func:`pedrl.rl.kernels.td_set_batch`."""
    num_actions = q_values.shape[-1]
    zero = torch.zeros((), dtype=rows.dtype, device=rows.device)
    actions = torch.where(valid, actions, zero)
    bootstrap = valid & ~terminal
    value = factored_values(q_values, rows).gather(1, actions[:, None]).squeeze(1)
    next_value = factored_values(q_values, next_rows).amax(1)
    target = rewards + gamma * torch.where(bootstrap, next_value, torch.zeros_like(next_value))
    td_error = torch.where(valid, target - value, torch.zeros_like(target))
    active = valid[:, None] & (rows >= 0)
    share = td_error / active.sum(1).clamp_min(1).to(td_error.dtype)
    entries = torch.where(active, rows * num_actions + actions[:, None], zero).reshape(-1)
    steps = torch.where(active, share[:, None], torch.zeros((), dtype=share.dtype, device=share.device)).reshape(-1)
    _add_averaged(q_values, entries, steps, active.reshape(-1), alpha)
    return td_error

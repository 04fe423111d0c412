"""Q tables and action selection.

All learning processes and agents share one tensor `q_values (R, A, K, U)`: `R` learning processes, `A` learning
agents (one table each), `K` prototypes (states), `U = 81` actions; float32, zero-initialised. Functions work on
*flat rows* of `q_values.view(R * A * K, U)`: row `(r * A + a) * K + s` holds the action values of state `s` in
table `a` of process `r` (`table_rows`). Any batch layout (replicas, rooms, agents) flattens to a `(B,)` vector of
rows, and nothing loops over agents.

A factored table (:class:`pedrl.vq.FactoredQuantizer`) gives each state a set of `M` rows, `(B, M)` with -1 for a
slot that reads nothing, and a state's action values are the sum of its rows (:func:`factored_values`); every function
here takes `(B,)` rows or `(B, M)` row sets.
"""

from __future__ import annotations

import ctypes
import sys

import torch

from pedrl._numba import use_kernels

__all__ = [
    "NUM_ACTIONS",
    "epsilon_greedy",
    "factored_values",
    "greedy",
    "in_huge_pages",
    "table_rows",
    "zeros_q_values",
]

#: Actions per decision: 9 speed changes x 9 turns (see docs/design.md).
NUM_ACTIONS = 81


HUGE_PAGE = 2 << 20
"""Bytes of a transparent huge page on x86-64 Linux."""
_MADV_HUGEPAGE = 14


def _advise_huge_pages(tensor: torch.Tensor) -> bool:
    """Ask Linux to back ``tensor``'s memory (the whole 2 MiB pages inside it) with transparent huge pages.

    Q tables are read and written at random rows: with 4 KiB pages nearly every access misses the TLB, and in a
    virtual machine a miss walks two page tables. Measured on this project's 2-core VM, the greedy choice of 400
    random rows of a 531 MiB table took 3.5 ms with 4 KiB pages and 0.18 ms with huge pages. Advice only: False
    where it is not taken (other systems, THP off); nothing else changes.
    """
    start = (tensor.data_ptr() + HUGE_PAGE - 1) & ~(HUGE_PAGE - 1)
    stop = (tensor.data_ptr() + tensor.numel() * tensor.element_size()) & ~(HUGE_PAGE - 1)
    if not sys.platform.startswith("linux") or stop <= start:
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.madvise(ctypes.c_void_p(start), ctypes.c_size_t(stop - start), _MADV_HUGEPAGE) == 0
    except (OSError, AttributeError):  # pragma: no cover - no libc madvise
        return False


def empty_tables(shape: tuple[int, ...], device: torch.device | str) -> torch.Tensor:
    """Uninitialised float32 Q tables; on the CPU advised into huge pages before any page is touched."""
    tables = torch.empty(shape, dtype=torch.float32, device=device)
    if tables.device.type == "cpu":
        _advise_huge_pages(tables)
    return tables


def in_huge_pages(q_values: torch.Tensor) -> torch.Tensor:
    """``q_values`` itself off the CPU, else a copy in memory advised into huge pages (for loaded tables)."""
    if q_values.device.type != "cpu" or q_values.numel() * q_values.element_size() < 2 * HUGE_PAGE:
        return q_values
    return empty_tables(tuple(q_values.shape), q_values.device).copy_(q_values)


def zeros_q_values(
    num_processes: int,
    num_tables: int,
    num_states: int,
    num_actions: int = NUM_ACTIONS,
    *,
    device: torch.device | str,
) -> torch.Tensor:
    """Zero-initialised Q tables (on the CPU in huge pages, see `_advise_huge_pages`).

    Args:
        num_processes: `R`, independent learning processes.
        num_tables: `A`, tables (learning agents) per process.
        num_states: `K`, prototypes of the quantiser.
        num_actions: `U`.
        device: where the tables live.

    Returns:
        `(R, A, K, U)` float32 zeros.
    """
    return empty_tables((num_processes, num_tables, num_states, num_actions), device).zero_()


def table_rows(
    process: torch.Tensor,
    table: torch.Tensor,
    state: torch.Tensor,
    *,
    num_tables: int,
    num_states: int,
) -> torch.Tensor:
    """Flat row indices `(process * num_tables + table) * num_states + state`.

    Args:
        process: `(B,)` int64 learning process `r in [0, R)`.
        table: `(B,)` int64 table `a in [0, A)` (agent `n` of a room uses table `n mod A`).
        state: `(B,)` int64 prototype id `s in [0, K)`.
        num_tables: `A`.
        num_states: `K`.

    Returns:
        `(B,)` int64 rows of `q_values.view(-1, U)`.
    """
    return (process * num_tables + table) * num_states + state


def factored_values(q_values: torch.Tensor, rows: torch.Tensor) -> torch.Tensor:
    """Action values ``(B, U)`` of row sets ``rows (B, M)``: the sum of each set's rows, slot by slot in order
    (slots of -1 add nothing), the order :func:`pedrl.rl.kernels.greedy_set` sums them in."""
    flat = q_values.view(-1, q_values.shape[-1])
    active = rows >= 0
    safe = rows.clamp_min(0)
    total = torch.zeros(rows.shape[0], flat.shape[1], dtype=flat.dtype, device=flat.device)
    nothing = torch.zeros((), dtype=flat.dtype, device=flat.device)
    for slot in range(rows.shape[1]):
        total = total + torch.where(active[:, slot, None], flat.index_select(0, safe[:, slot]), nothing)
    return total


def greedy(
    q_values: torch.Tensor,
    rows: torch.Tensor,
    generator: torch.Generator | None = None,
    *,
    compiled: bool | None = None,
) -> torch.Tensor:
    """Greedy actions `argmax_a Q(row, a)`, ties broken uniformly at random.

    Random tie-breaking matters while tables are still zero: a fixed choice (the lowest action) would send every
    agent in an unvisited state the same way.

    Args:
        q_values: `(R, A, K, U)` Q tables.
        rows: `(B,)` int64 flat rows (`table_rows`), or `(B, M)` row sets of a factored table.
        generator: random source for ties (on `q_values.device`; None: torch's default).
        compiled: use the numba kernel (`pedrl.rl.kernels`, the same actions for the same random numbers; None:
            on the CPU when numba is there).

    Returns:
        `(B,)` int64 actions in `[0, U)`.
    """
    if use_kernels(q_values.device, compiled):
        from pedrl.rl.kernels import greedy_kernel  # imports numba: only where it is used

        uniform = torch.rand(rows.shape[0], generator=generator, device=q_values.device)
        return greedy_kernel(q_values, rows, uniform)
    return greedy_torch(q_values, rows, generator)


def greedy_torch(q_values: torch.Tensor, rows: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
    """:func:`greedy` in torch, on any device: the specification of :func:`pedrl.rl.kernels.greedy_kernel`. The
    argmax of each row `rows (B,)` of `q_values`, ties broken uniformly at random.

    The `j`-th of a row's `c` tied maxima is picked with `j` uniform in `[0, c)`: a running count of the maxima
    exceeds `j` first at that action. One random number per row, not one per action. Counts are int16 (`U` is
    small), the fastest of the variants measured on CPU.
    """
    if rows.ndim == 2:
        values = factored_values(q_values, rows)
    else:  # index_select: a plain row gather from a large table is several times slower on CPU
        values = q_values.view(-1, q_values.shape[-1]).index_select(0, rows)
    num_rows, num_actions = values.shape
    best = values.amax(1, keepdim=True)
    running = (values == best).to(torch.int16).cumsum(1, dtype=torch.int16)
    count = running[:, -1].long()
    uniform = torch.rand(num_rows, generator=generator, device=values.device)
    pick = (uniform * count).long().clamp_(max=count - 1).to(torch.int16)
    # A materialised right-hand side: broadcast int16 comparisons are slow in torch on CPU.
    return (running > pick[:, None].expand(-1, num_actions).contiguous()).byte().argmax(1)


def epsilon_greedy(
    q_values: torch.Tensor,
    rows: torch.Tensor,
    epsilon: float | torch.Tensor,
    generator: torch.Generator | None = None,
    *,
    compiled: bool | None = None,
) -> torch.Tensor:
    """Epsilon-greedy actions: uniformly random with probability `epsilon`, else greedy (random tie-breaking).

    The random action is drawn from all `U` actions, so it is the greedy one with probability `1 / U`.

    Args:
        q_values: `(R, A, K, U)` Q tables.
        rows: `(B,)` int64 flat rows (`table_rows`), or `(B, M)` row sets.
        epsilon: exploration probability in `[0, 1]`, a float or a tensor broadcastable to `(B,)`.
        generator: random source (on `q_values.device`; None: torch's default).
        compiled: see `greedy`.

    Returns:
        `(B,)` int64 actions in `[0, U)`.
    """
    num_actions = q_values.shape[-1]
    device = q_values.device
    actions = greedy(q_values, rows, generator, compiled=compiled)
    explore = torch.rand(rows.shape[0], generator=generator, device=device) < epsilon
    random_actions = torch.randint(num_actions, (rows.shape[0],), generator=generator, device=device)
    return torch.where(explore, random_actions, actions)

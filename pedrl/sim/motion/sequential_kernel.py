"""Numba kernel of the sequential rule; its specification is
:func:`pedrl.sim.motion.sequential.move_agents_sequential_torch`, to the bit (whose own specification is the literal
agent-by-agent loop :func:`pedrl.sim.reference.move_agents_sequential_literal`: this kernel is that loop, compiled).
``_touches_walls`` and ``_passes_exits`` are :meth:`Geometry.touches_walls <pedrl.sim.geometry.Geometry.touches_walls>`
(axis-aligned walls) and :meth:`Geometry.passes_exits <pedrl.sim.geometry.Geometry.passes_exits>` of one point."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch

from pedrl._numba import cached_njit
from pedrl.sim.geometry import Geometry
from pedrl.sim.grid_kernel import RELATIVE_SLACK, SLACK, bin_points, bin_segments, cell_range, make_cells
from pedrl.sim.motion.common import KernelMoves, Search, neighbour_search
from pedrl.sim.sensing_kernel import room_search

__all__ = ["SequentialConstants", "sequential_constants", "sequential_room", "sequential_substeps"]

SEARCH = neighbour_search()
"""The default neighbour search (:func:`pedrl.sim.motion.common.neighbour_search`)."""


class SequentialConstants(NamedTuple):
    """The constants of one decision under the sequential rule (``stop``), read by name by :func:`sequential_room`:
    built from the room's kernel constants by :func:`sequential_constants` (the fused step) and from the decision's
    arguments by :func:`sequential_substeps` (the torch room's dispatcher)."""

    radius_sq: np.float32
    """``r^2`` (m^2): a wall closer than ``r`` is touched."""
    contact_sq: np.float32
    """``(2 r)^2`` (m^2): a body closer than ``2 r`` is hit."""
    search: Search
    """The neighbour search: grids from ``search.min_agents`` agents."""


@cached_njit(nogil=True)
def sequential_constants(room):
    """The :class:`SequentialConstants` of a decision of a room whose kernel constants are ``room``
    (:class:`pedrl.sim.params.KernelRoom`)."""
    radius = room.agent_radius
    return SequentialConstants(
        np.float32(radius * radius), np.float32(4.0 * radius * radius),
        room_search(room),
    )  # fmt: skip


@cached_njit(nogil=True, inline="always")
def _touches_walls(x, y, low, high, radius_sq):
    """`Geometry.touches_walls` of an axis-aligned geometry: clamp to each wall's box, nearest squared gap."""
    nearest = np.float32(np.inf)
    for s in range(low.shape[0]):
        gap_x = min(max(x, low[s, 0]), high[s, 0]) - x
        gap_y = min(max(y, low[s, 1]), high[s, 1]) - y
        nearest = min(nearest, gap_x * gap_x + gap_y * gap_y)
    return nearest < radius_sq


@cached_njit(nogil=True, inline="always")
def _touches_listed(x, y, low, high, boxes, c, radius_sq):
    """:func:`_touches_walls` over the walls listed in cell ``c`` of ``boxes``."""
    nearest = np.float32(np.inf)
    for k in range(boxes.start[c], boxes.start[c + 1]):
        s = boxes.items[k]
        gap_x = min(max(x, low[s, 0]), high[s, 0]) - x
        gap_y = min(max(y, low[s, 1]), high[s, 1]) - y
        nearest = min(nearest, gap_x * gap_x + gap_y * gap_y)
    return nearest < radius_sq


@cached_njit(nogil=True, inline="always")
def _passes_exits(x, y, depth, start, normal, tangent, span):
    """`Geometry.passes_exits` of one point."""
    for e in range(start.shape[0]):
        offset_x = x - start[e, 0]
        offset_y = y - start[e, 1]
        beyond = offset_x * normal[e, 0] + offset_y * normal[e, 1]
        along = offset_x * tangent[e, 0] + offset_y * tangent[e, 1]
        if beyond >= 0 and beyond < depth and along >= 0 and along <= span[e]:
            return True
    return False


@cached_njit(nogil=True)
def _step_grids(r, positions, step, present, low, high, contact_sq, num_substeps, grid, scale):
    """The grids of one decision of room ``r`` under the sequential rule: the bodies' cells over the box they cannot
    leave in the decision, the axis-aligned walls (``low``-``high`` segments) listed per cell within a body's radius
    plus a step, and the reach of a contact (a body and a mover each within a step of their binned places), times
    ``scale`` (1 but in the tests' control). Without ``grid``, a grid of one cell."""
    longest = np.float32(0.0)
    low_x = low_y = np.float32(np.inf)
    high_x = high_y = np.float32(-np.inf)
    count = 0
    for i in range(positions.shape[1]):
        if present[r, i] and grid:
            count += 1
            longest = max(longest, np.sqrt(step[r, i, 0] ** 2 + step[r, i, 1] ** 2))
            low_x, high_x = min(low_x, positions[r, i, 0]), max(high_x, positions[r, i, 0])
            low_y, high_y = min(low_y, positions[r, i, 1]), max(high_y, positions[r, i, 1])
    if count == 0:
        low_x = low_y = high_x = high_y = np.float32(0.0)
    slack = longest * np.float32(num_substeps) + SLACK
    one = np.float32(1.0) + RELATIVE_SLACK
    contact = np.sqrt(contact_sq)
    reach = (contact + np.float32(2.0) * longest) * one * scale + SLACK
    cells = make_cells(low_x - slack, low_y - slack, high_x + slack, high_y + slack, reach, positions.shape[1], count)
    walls = low.shape[0] if grid else 0
    inverse = np.empty(walls, np.float32)
    for s in range(walls):
        length_sq = (high[s, 0] - low[s, 0]) ** 2 + (high[s, 1] - low[s, 1]) ** 2
        inverse[s] = np.float32(1.0) / length_sq if length_sq > 0 else np.float32(0.0)
    boxes = bin_segments(
        cells,
        low[:walls],
        high[:walls] - low[:walls],
        inverse,
        (contact * np.float32(0.5) + longest) * one * scale + SLACK,
    )
    return cells, boxes, reach


@cached_njit(nogil=True)
def _sequential(positions, step, going, present, depth, walls, low, high, exits, order, motion, out):
    num_replicas, num_agents = going.shape
    moved = np.zeros(num_agents, dtype=np.float32)  # sub-steps moved, per agent of the replica
    acted_moved = np.zeros(num_agents, dtype=np.bool_)  # moved in this sub-step (it acted already)
    passed = np.zeros(num_agents, dtype=np.bool_)
    current = np.empty((num_agents, 2), dtype=np.float32)
    for r in range(num_replicas):
        sequential_room(
            r, positions, step, going, present, depth, walls, low, high, exits, order, motion, out, moved, acted_moved,
            passed, current,
        )  # fmt: skip


@cached_njit(nogil=True)
def sequential_room(
    r, positions, step, going, present, depth, walls, low, high, exits, order, motion, out, moved, acted_moved,
    passed, current,
):  # fmt: skip
    """The sub-steps of replica ``r`` (of :func:`sequential_substeps`) into ``out``
    (:class:`pedrl.sim.motion.common.KernelMoves`, its ``cut_body`` untouched): ``exits`` is
    :class:`pedrl.sim.geometry.Exits`, ``motion`` :class:`SequentialConstants` (with a grid, rebuilt each sub-step from
    the bodies' places, each within one step of them while it lasts, the same numbers as every pair); ``moved``,
    ``acted_moved``, ``passed`` ``(N,)`` and ``current`` ``(N, 2)`` are scratch."""
    start, normal, tangent, span = exits.start, exits.normal, exits.tangent, exits.span
    radius_sq, contact_sq, search = motion.radius_sq, motion.contact_sq, motion.search
    blocked, crashed_wall, reached = out.blocked, out.cut_wall, out.reached
    num_agents = going.shape[1]
    num_substeps = walls.shape[0]
    own_walls = low.shape[0] > 0  # axis-aligned walls: tested here, else ``walls`` holds the tests
    for i in range(num_agents):
        moved[i] = 0.0
        current[i, 0] = positions[r, i, 0]
        current[i, 1] = positions[r, i, 1]
    grid = num_agents >= search.min_agents
    cells, boxes, reach = _step_grids(
        r, positions, step, present, low, high, contact_sq, num_substeps, grid, search.reach_scale
    )
    nx = cells.shape[0]
    for k in range(num_substeps):
        anyone = False
        for i in range(num_agents):
            anyone |= going[r, i]
        if not anyone:
            break
        if grid:
            bin_points(cells, current, present[r])
        scale = np.float32(k + 1)
        for i in range(num_agents):
            acted_moved[i] = False
            passed[i] = False
        for rank in range(num_agents):
            i = order[r, rank]
            if not going[r, i]:
                continue
            proposal_x = positions[r, i, 0] + scale * step[r, i, 0]
            proposal_y = positions[r, i, 1] + scale * step[r, i, 1]
            if own_walls and grid:  # the walls listed in the cell of the mover's place
                x0, _, y0, _ = cell_range(cells, current[i, 0], current[i, 1], np.float32(0.0))
                c = y0 * nx + x0
                touches = _touches_listed(proposal_x, proposal_y, low, high, boxes, c, radius_sq)
            else:
                touches = _touches_walls(proposal_x, proposal_y, low, high, radius_sq) if own_walls else walls[k, r, i]
            if touches:
                blocked[r, i] = True
                crashed_wall[r, i] = True
                going[r, i] = False
                continue
            hit = False
            x0, x1, y0, y1 = cell_range(cells, current[i, 0], current[i, 1], reach) if grid else (0, 0, 0, 0)
            for row in range(y0, y1 + 1):  # the bodies binned within reach, or (no grid) all
                first, last = (cells.start[row * nx + x0], cells.start[row * nx + x1 + 1]) if grid else (0, num_agents)
                for index in range(first, last):
                    j = cells.items[index] if grid else index
                    if j == i or not present[r, j]:
                        continue
                    if acted_moved[j]:  # acted before i and moved: it stands on its proposal
                        other_x = positions[r, j, 0] + scale * step[r, j, 0]
                        other_y = positions[r, j, 1] + scale * step[r, j, 1]
                    else:  # still to act, or stopped: where it stands
                        other_x = current[j, 0]
                        other_y = current[j, 1]
                    gap_x = proposal_x - other_x
                    gap_y = proposal_y - other_y
                    if gap_x * gap_x + gap_y * gap_y < contact_sq:
                        hit = True
                        break
                if hit:
                    break
            if hit:
                blocked[r, i] = True
                going[r, i] = False
                continue
            acted_moved[i] = True
            if _passes_exits(proposal_x, proposal_y, depth[r, i], start, normal, tangent, span):
                reached[r, i] = True
                passed[i] = True
                going[r, i] = False
        for i in range(num_agents):
            if acted_moved[i]:
                moved[i] += np.float32(1.0)
            if passed[i]:
                present[r, i] = False
            current[i, 0] = positions[r, i, 0] + moved[i] * step[r, i, 0]
            current[i, 1] = positions[r, i, 1] + moved[i] * step[r, i, 1]
    for i in range(num_agents):
        out.moved_to[r, i, 0] = current[i, 0]
        out.moved_to[r, i, 1] = current[i, 1]


def sequential_substeps(
    *,
    positions: torch.Tensor,
    step: torch.Tensor,
    going: torch.Tensor,
    active: torch.Tensor,
    geometry: Geometry,
    agent_radius: float,
    num_substeps: int,
    walls: torch.Tensor | None,
    depth: torch.Tensor,
    priority: torch.Tensor,
    search: Search = SEARCH,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The sub-steps of :func:`pedrl.sim.motion.sequential.move_agents_sequential_torch`, agent by agent, compiled.

    The float32 operations are torch's, in the same order: proposals ``p + k d``, the wall test of
    :meth:`Geometry.touches_walls` (done here for axis-aligned walls; ``walls (S, R, N)`` bool holds it for the
    others), :meth:`Geometry.passes_exits` with ``depth (R, N)``, and the contact test ``|gap|^2 < (2 r)^2``.

    Args:
        positions: ``(R, N, 2)`` float32 at the start of the decision.
        step: ``(R, N, 2)`` float32 move per sub-step.
        going: ``(R, N)`` bool, active agents with a non-zero step.
        active: ``(R, N)`` bool, agents in the room (bodies that collide).
        geometry: the room.
        agent_radius: body radius (m).
        num_substeps: ``S``.
        walls: ``(S, R, N)`` bool wall tests of the proposals, needed only when some wall is not axis-aligned.
        depth: ``(R, N)`` float32 depth of the exit test.
        priority: ``(R, N)`` order of action, lowest first.
        search: :data:`SEARCH` (the tests change it).

    Returns:
        ``(positions, blocked, crashed_wall, reached)``.
    """
    shape = going.shape
    out = torch.empty_like(positions)
    blocked = torch.zeros(shape, dtype=torch.bool)
    crashed_wall = torch.zeros(shape, dtype=torch.bool)
    reached = torch.zeros(shape, dtype=torch.bool)
    if walls is None:
        walls = torch.zeros((num_substeps, *shape), dtype=torch.bool)  # the kernel tests the walls (if any)
        low, high = geometry.box_low, geometry.box_high
    else:
        low = high = torch.zeros((0, 2))
    radius_sq = agent_radius * agent_radius  # both products as torch's callers write them
    contact_sq = 4.0 * agent_radius * agent_radius
    _sequential(
        positions.contiguous().numpy(),
        step.contiguous().numpy(),
        going.numpy().copy(),
        active.numpy().copy(),
        depth.contiguous().numpy(),
        walls.contiguous().numpy(),
        low.contiguous().numpy(),
        high.contiguous().numpy(),
        geometry.kernel_exits(),
        priority.argsort(dim=1).numpy(),
        SequentialConstants(radius_sq=np.float32(radius_sq), contact_sq=np.float32(contact_sq), search=search),
        KernelMoves(out.numpy(), blocked.numpy(), crashed_wall.numpy(), np.zeros(shape, np.bool_), reached.numpy()),
    )
    return out, blocked, crashed_wall, reached

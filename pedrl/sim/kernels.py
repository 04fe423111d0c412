"""CPU kernels of the simulation, compiled with numba.

On the CPU a decision of a few hundred agents is a few hundred small torch operations of microseconds each; the
same work written as loops and compiled costs a few microseconds in all. Each kernel here reproduces a torch
function of `pedrl.sim` to the bit (same float32 operations in the same order), which the tests check; the torch
code stays the reference and the path on other devices.
"""

from __future__ import annotations

import functools

import numpy as np
import torch

from pedrl._numba import numba as load_numba

__all__ = ["sequential_substeps"]


@functools.cache
def _sequential():
    numba = load_numba()

    @numba.njit(cache=True, nogil=True)
    def run(positions, step, going, present, walls, passes, order, contact_sq, out, blocked, crashed_wall, reached):
        num_substeps, num_replicas, num_agents = walls.shape
        moved = np.zeros(num_agents, dtype=np.float32)  # sub-steps moved, per agent of the replica
        acted_moved = np.zeros(num_agents, dtype=np.bool_)  # moved in this sub-step (it acted already)
        passed = np.zeros(num_agents, dtype=np.bool_)
        current = np.empty((num_agents, 2), dtype=np.float32)
        for r in range(num_replicas):
            for i in range(num_agents):
                moved[i] = 0.0
                current[i, 0] = positions[r, i, 0]
                current[i, 1] = positions[r, i, 1]
            for k in range(num_substeps):
                anyone = False
                for i in range(num_agents):
                    anyone |= going[r, i]
                if not anyone:
                    break
                scale = np.float32(k + 1)
                for i in range(num_agents):
                    acted_moved[i] = False
                    passed[i] = False
                for rank in range(num_agents):
                    i = order[r, rank]
                    if not going[r, i]:
                        continue
                    if walls[k, r, i]:
                        blocked[r, i] = True
                        crashed_wall[r, i] = True
                        going[r, i] = False
                        continue
                    proposal_x = positions[r, i, 0] + scale * step[r, i, 0]
                    proposal_y = positions[r, i, 1] + scale * step[r, i, 1]
                    hit = False
                    for j in range(num_agents):
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
                        blocked[r, i] = True
                        going[r, i] = False
                        continue
                    acted_moved[i] = True
                    if passes[k, r, i]:
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
                out[r, i, 0] = current[i, 0]
                out[r, i, 1] = current[i, 1]

    return run


def sequential_substeps(
    *,
    positions: torch.Tensor,
    step: torch.Tensor,
    going: torch.Tensor,
    active: torch.Tensor,
    walls: torch.Tensor,
    passes_door: torch.Tensor,
    priority: torch.Tensor,
    contact_sq: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The sub-steps of :func:`pedrl.sim.dynamics.move_agents_sequential`, agent by agent, compiled.

    Args:
        positions: ``(R, N, 2)`` float32 at the start of the decision.
        step: ``(R, N, 2)`` float32 move per sub-step.
        going: ``(R, N)`` bool, active agents with a non-zero step.
        active: ``(R, N)`` bool, agents in the room (bodies that collide).
        walls: ``(S, R, N)`` bool, whether the proposal of each sub-step touches a wall.
        passes_door: ``(S, R, N)`` bool, whether it is past an exit.
        priority: ``(R, N)`` order of action, lowest first.
        contact_sq: squared contact distance (the comparison runs in float32, as torch's does).

    Returns:
        ``(positions, blocked, crashed_wall, reached)``.
    """
    shape = going.shape
    out = torch.empty_like(positions)
    blocked = torch.zeros(shape, dtype=torch.bool)
    crashed_wall = torch.zeros(shape, dtype=torch.bool)
    reached = torch.zeros(shape, dtype=torch.bool)
    _sequential()(
        positions.contiguous().numpy(),
        step.contiguous().numpy(),
        going.numpy().copy(),
        active.numpy().copy(),
        walls.contiguous().numpy(),
        passes_door.contiguous().numpy(),
        priority.argsort(dim=1).numpy(),
        np.float32(contact_sq),
        out.numpy(),
        blocked.numpy(),
        crashed_wall.numpy(),
        reached.numpy(),
    )
    return out, blocked, crashed_wall, reached

"""The collision rules written literally: the specifications of `pedrl.sim.motion` (slow loops, for the tests).

Each function here is the plainest reading of one rule of docs/design.md: a loop over sub-steps, and within each
over rounds (the simultaneous rule) or over agents in their order of action (the sequential rule). They use the
room's own wall and exit tests (:meth:`Geometry.touches_walls <pedrl.sim.geometry.Geometry.touches_walls>`,
:meth:`Geometry.passes_exits <pedrl.sim.geometry.Geometry.passes_exits>` with the depth the simulation uses), so
they hold for any geometry, not only the paper's room. The fast code must return their numbers to the bit, which
``tests/sim/test_dynamics.py`` checks:

- :func:`move_agents_literal` is the specification of :func:`pedrl.sim.motion.move_agents` (``simultaneous``);
- :func:`move_agents_sequential_literal` that of :func:`pedrl.sim.motion.move_agents_sequential` (``sequential``,
  the paper's reading), of its torch code and of its numba kernel.

They loop in Python over sub-steps, rounds or agents, a few torch operations at a time: never use them to simulate.
"""

from __future__ import annotations

import torch

from pedrl.sim.motion.common import PAIR_MARGIN, Motion, Movement

__all__ = ["move_agents_literal", "move_agents_sequential_literal"]


def move_agents_literal(
    *,
    positions: torch.Tensor,
    velocities: torch.Tensor,
    active: torch.Tensor,
    motion: Motion,
) -> Movement:
    """The collision rule of docs/design.md written literally: a loop over sub-steps, rounds inside each.

    Same arguments and result as :func:`pedrl.sim.motion.move_agents`, except that ``crashed_agent`` may also be
    set where ``crashed_wall`` is (the fast code clears it there).
    """
    geometry, agent_radius, decision_length, num_substeps = motion.values()
    num_replicas, num_agents, _ = positions.shape
    step = velocities * (decision_length / num_substeps)
    moving = active & (step != 0).any(-1)
    step = step * moving.unsqueeze(-1)
    depth = step.norm(dim=-1) + PAIR_MARGIN  # of the exit test: a centre moves less than this per sub-step
    in_room = active.clone()
    going = moving.clone()
    moved = torch.zeros(num_replicas, num_agents, dtype=torch.int64)
    crashed_wall = torch.zeros_like(active)
    crashed_agent = torch.zeros_like(active)
    reached = torch.zeros_like(active)
    contact_sq = 4.0 * agent_radius**2
    not_self = ~torch.eye(num_agents, dtype=torch.bool)
    for substep in range(1, num_substeps + 1):
        current = positions + moved.to(torch.float32).unsqueeze(-1) * step
        proposal = positions + float(substep) * step
        wall_hit = going & geometry.touches_walls(proposal, radius=agent_radius)
        blocked = wall_hit.clone()
        for _ in range(num_agents + 1):
            go = going & ~blocked
            target = torch.where(go.unsqueeze(-1), proposal, current)
            gaps = proposal.unsqueeze(2) - target.unsqueeze(1)  # [r, i, j] = proposal_i - target_j
            close = ((gaps * gaps).sum(-1) < contact_sq) & not_self & in_room.unsqueeze(1)
            new = go & close.any(-1)
            if not new.any():
                break
            blocked |= new
            crashed_agent |= new
        crashed_wall |= wall_hit
        moved = moved + go.long()
        arrived = go & geometry.passes_exits(proposal, depth=depth)
        reached |= arrived
        in_room &= ~arrived
        going = go & ~arrived
    return Movement(
        positions=positions + moved.to(torch.float32).unsqueeze(-1) * step,
        blocked=crashed_wall | crashed_agent,
        crashed_wall=crashed_wall,
        crashed_agent=crashed_agent,
        reached=reached,
    )


def move_agents_sequential_literal(
    *,
    positions: torch.Tensor,
    velocities: torch.Tensor,
    active: torch.Tensor,
    motion: Motion,
    priority: torch.Tensor,
) -> Movement:
    """The paper's rule written literally: sub-step after sub-step, agent after agent in priority order.

    Same arguments (but ``sync_free`` and ``compiled``) and result as
    :func:`pedrl.sim.motion.move_agents_sequential`.
    """
    geometry, agent_radius, decision_length, num_substeps = motion.values()
    num_replicas, num_agents, _ = positions.shape
    step = velocities * (decision_length / num_substeps)
    going = active & (step != 0).any(-1)
    depth = step.norm(dim=-1) + PAIR_MARGIN  # of the exit test: a centre moves less than this per sub-step
    present = active.clone()
    moved = torch.zeros(num_replicas, num_agents)
    crashed_wall = torch.zeros_like(active)
    blocked = torch.zeros_like(active)
    reached = torch.zeros_like(active)
    for substep in range(1, num_substeps + 1):
        for r in range(num_replicas):
            for i in priority[r].argsort().tolist():
                if not going[r, i]:
                    continue
                proposal = positions[r, i] + float(substep) * step[r, i]
                wall = bool(geometry.touches_walls(proposal, radius=agent_radius))
                current = positions[r] + moved[r].unsqueeze(-1) * step[r]  # where everyone stands now
                gaps = proposal - current
                others = present[r].clone()
                others[i] = False
                body = bool((((gaps * gaps).sum(-1) < 4.0 * agent_radius**2) & others).any())
                if wall or body:
                    blocked[r, i] = True
                    crashed_wall[r, i] |= wall
                    going[r, i] = False
                    continue
                moved[r, i] += 1
                if geometry.passes_exits(proposal, depth=depth[r, i]):  # out: it collides until the sub-step ends
                    reached[r, i] = True
                    going[r, i] = False
        present &= ~reached
    return Movement(
        positions=positions + moved.unsqueeze(-1) * step,
        blocked=blocked,
        crashed_wall=crashed_wall,
        crashed_agent=blocked & ~crashed_wall,
        reached=reached,
    )

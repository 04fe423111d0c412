"""The kernels' grids of cells (:mod:`pedrl.sim.grid_kernel`) return the all-pairs loop's numbers to the bit: whole
walks of crowds through the built-in rooms under every contact rule (the stop rule's kernel and the sliding one's)
and the walking layer, grid against every pair; and a grid that drops the neighbours beyond half its reach (the
control) differs."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pedrl._numba import numba_available
from pedrl.scenarios import bottleneck, corridor, custom, four_exits, paper_room
from pedrl.sim.motion.common import Movement, Search, Steering, neighbour_search

pytestmark = pytest.mark.skipif(not numba_available(), reason="the grids are the numba kernels'")

PAIRS = neighbour_search(min_agents=2**30)
GRID = neighbour_search(min_agents=0)
SHRUNK = neighbour_search(min_agents=0, reach_scale=0.5)
RULES = ("stop", "slide", "headway", "yield", "continuous")


def _ring_room():
    """A round hall drawn with 391 wall segments and one exit: many walls, each near few bodies."""
    angles = np.linspace(0.0, 2.0 * np.pi, 401)[:-1]
    ring = [(round(10 + 9 * np.cos(a), 4), round(10 + 9 * np.sin(a), 4)) for a in angles]
    ring = [ring[0], *ring[10:]]  # a straight 1.4 m edge for the exit
    text = ", ".join(f"{x} {y}" for x, y in [*ring, ring[0]])
    return custom(geometry=f"POLYGON (({text}))", exits=[[*ring[0], *ring[1]]])


ROOMS = {
    "paper_room": (lambda: paper_room(width=12.0, length=15.0, door_width=1.5), 150),
    "bottleneck": (bottleneck, 60),
    "corridor": (corridor, 80),
    "four_exits": (four_exits, 200),
    "ring": (_ring_room, 150),
}


def walk(room: str, rule: str, search: Search, decisions: int = 12, seed: int = 0) -> list[torch.Tensor]:
    """The positions and flags after each decision of a crowd walked towards its goals (speeds drawn per decision)
    by ``sliding_substeps`` with the neighbour ``search``."""
    from pedrl.sim.motion.sliding_kernel import sliding_substeps

    build, agents = ROOMS[room]
    env = build().room(num_replicas=2, num_agents=agents, agent_radius=0.2, max_speed=1.34)
    env.reset(seed=seed)
    starts, directions, inverse = env.geometry.wall_segments()
    generator = torch.Generator().manual_seed(seed)
    positions, active = env.positions.clone(), env.active.clone()
    targets = env.targets().clone()
    out = []
    for _ in range(decisions):
        offset = targets - positions
        norm = torch.linalg.vector_norm(offset, dim=-1, keepdim=True).clamp_min(1e-6)
        speeds = 1.34 * (0.5 + 0.5 * torch.rand(active.shape, generator=generator)).unsqueeze(-1)
        velocities = offset / norm * speeds
        order = torch.rand(active.shape, generator=generator)
        if rule == "stop":
            movement = _stop(positions, velocities, active, env, order, search)
        else:
            movement = sliding_substeps(
                positions=positions, velocities=velocities, active=active, geometry=env.geometry,
                wall_starts=starts, wall_directions=directions, wall_inverse=inverse,
                agent_radius=env.params.agent_radius, substep_length=0.05 if rule == "continuous" else 0.25,
                num_substeps=20 if rule == "continuous" else 4,
                order=order.argsort(dim=1), time_gap=None if rule == "slide" else 0.4,
                yield_to_earlier=rule in ("yield", "continuous"),
                steering=Steering() if rule == "continuous" else None, search=search,
            )  # fmt: skip
        positions = movement.positions
        active = active & ~movement.reached
        out += [movement.positions, movement.blocked, movement.crashed_wall, movement.crashed_agent, movement.reached]
    return out


def _stop(positions, velocities, active, env, priority, search) -> Movement:
    """One decision of the stop rule's kernel (``sequential_substeps``, as ``move_agents_sequential`` calls it)."""
    from pedrl.sim.motion.sequential_kernel import sequential_substeps

    step = velocities * (1.0 / 4)
    walls = None
    if not env.geometry.axis_aligned:
        substeps = torch.arange(1, 5).to(positions.dtype).view(-1, 1, 1, 1)
        walls = env.geometry.touches_walls(positions + substeps * step, radius=env.params.agent_radius)
    moved_to, blocked, crashed_wall, reached = sequential_substeps(
        positions=positions, step=step, going=active & (step != 0).any(-1), active=active, geometry=env.geometry,
        agent_radius=env.params.agent_radius, num_substeps=4, walls=walls, depth=step.norm(dim=-1) + 1e-3,
        priority=priority, search=search,
    )  # fmt: skip
    return Movement(moved_to, blocked, crashed_wall, blocked & ~crashed_wall, reached)


@pytest.mark.parametrize("rule", RULES)
@pytest.mark.parametrize("room", sorted(ROOMS))
def test_grid_walks_as_every_pair_to_the_bit(room, rule):
    grid, pairs = walk(room, rule, GRID), walk(room, rule, PAIRS)
    for index, (a, b) in enumerate(zip(grid, pairs, strict=True)):
        assert torch.equal(a, b), f"output {index % 5} of decision {index // 5}"


@pytest.mark.parametrize("rule", ["stop", "headway", "continuous"])
def test_a_grid_that_drops_neighbours_differs(rule):
    """The control: a grid that searches half the reach misses bodies the rules react to."""
    shrunk, pairs = walk("bottleneck", rule, SHRUNK), walk("bottleneck", rule, PAIRS)
    assert not all(torch.equal(a, b) for a, b in zip(shrunk, pairs, strict=True))

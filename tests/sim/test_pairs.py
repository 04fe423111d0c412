"""``pedrl.sim.pairs``: the close pairs found through cells are exactly the true entries of the ``(R, N, N)`` table
of squared gaps, and placing a large crowd allocates nothing of the square of its size."""

from __future__ import annotations

import math

import pytest
import torch
from torch.utils._python_dispatch import TorchDispatchMode

from pedrl.scenarios import paper_room
from pedrl.sim import pairs


def table(points: torch.Tensor, limit: float) -> set[tuple[int, int, int]]:
    """The specification: the ``(R, N, N)`` table's pairs ``j < i`` below ``limit``."""
    offsets = points.unsqueeze(2) - points.unsqueeze(1)
    close = ((offsets * offsets).sum(-1) < limit * limit).tril_(-1)
    return {tuple(int(v) for v in row) for row in close.nonzero().tolist()}


def found(points: torch.Tensor, limit: float) -> set[tuple[int, int, int]]:
    replica, agent, other = pairs.close_pairs(points, limit)
    result = set(zip(replica.tolist(), agent.tolist(), other.tolist(), strict=True))
    assert len(result) == replica.numel()  # each pair once
    return result


def crowd(seed: int, replicas: int, agents: int, side: float, lattice: bool = False) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    if lattice:  # exact ties at the limit, and points on cell borders
        grid = torch.stack(torch.meshgrid(torch.arange(40.0), torch.arange(40.0), indexing="ij"), -1).reshape(-1, 2)
        return (grid[:agents] * 0.4).expand(replicas, -1, -1).contiguous()
    points = side * torch.rand((replicas, agents, 2), generator=generator)
    points[0, :5] = points[0, 5:10]  # coincident points
    points[-1, 3] = math.nan  # a NaN point has no pair
    return points


@pytest.mark.parametrize(
    ("seed", "replicas", "agents", "side", "limit", "lattice"),
    [(0, 3, 900, 12.0, 0.4, False), (1, 1, 2000, 60.0, 0.8, False), (2, 2, 700, 3.0, 0.4, False),
     (3, 2, 1600, 0.0, 0.4, True), (4, 1, 600, 200.0, 0.4, False)],
)  # fmt: skip
def test_cells_find_exactly_the_tables_pairs(seed, replicas, agents, side, limit, lattice):
    points = crowd(seed, replicas, agents, side, lattice)
    assert agents >= pairs.DENSE_AGENTS  # the cells' path
    expected = table(points, limit)
    assert expected  # the scenes have close pairs
    assert found(points, limit) == expected


def test_a_search_of_fewer_cells_misses_pairs(monkeypatch):
    """The control: cells half the limit wide (the 3 x 3 block then reaches only half of it) miss pairs."""
    points = crowd(0, 2, 900, 12.0)
    expected = table(points, 0.8)
    monkeypatch.setattr(pairs, "CELL_SCALE", 0.5)
    assert found(points, 0.8) != expected


class _Largest(TorchDispatchMode):
    """Records the largest tensor any torch operation returns."""

    def __init__(self) -> None:
        super().__init__()
        self.largest = 0

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        for value in out if isinstance(out, (tuple, list)) else (out,):
            if isinstance(value, torch.Tensor):
                self.largest = max(self.largest, value.numel())
        return out


def test_placing_a_large_crowd_holds_nothing_quadratic():
    """5,000 agents placed and checked (``RoomEnv.place``, the fused trial's reset): no tensor of more than 60 N
    elements (the table would hold N^2 = 25e6); ``reset``'s torch observation (the reference) holds the table."""
    num_agents = 5000
    env = paper_room(width=120.0, length=120.0, door_width=2.0).room(num_agents=num_agents, agent_radius=0.2)
    with _Largest() as mode:
        env.place(seed=0)
        env.place(seed=1, options={"positions": env.positions.clone()})  # check_positions
    assert mode.largest <= 60 * num_agents
    with _Largest() as control:
        env.reset(seed=0)
    assert control.largest >= num_agents**2
    replica, _, _ = pairs.close_pairs(env.positions, 0.4 - 1e-6)
    assert replica.numel() == 0  # and nobody overlaps


def test_a_crowd_of_100000_is_built_for_the_fused_trial_and_refused_by_the_torch_step():
    """The memory check of a room counts the fused trial's linear grids where it runs the room; the torch step, which
    senses every pair (40 GiB a thousand million pairs), refuses in one line before it allocates them."""
    env = paper_room(width=500.0, length=500.0, door_width=4.0).room(num_agents=100_000, agent_radius=0.2)
    assert env.step_memory() < 1 << 30 < env.step_memory(kernels=False)
    env.place(seed=0)  # the fused trial's reset
    assert int(env.active.sum()) == 100_000
    with pytest.raises(ValueError, match=r"^this run needs about .* pairs .*fused trial") as error:
        env.reset(seed=0)
    assert "\n" not in str(error.value)

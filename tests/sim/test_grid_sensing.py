"""The sensing kernel's grids (:func:`pedrl.sim.sensing_kernel.sense_room`) return the scan over every agent and
every wall to the bit: the same neighbours and walls in the same slots, the same features, on crowds in the built-in
rooms, on lattices where distances tie exactly, from no neighbour slot to more slots than agents present, with agents
absent; and a search that stops one ring early (the control) differs."""

from __future__ import annotations

import numpy as np
import pytest

from pedrl._numba import numba_available
from pedrl.scenarios import bottleneck, corridor, custom, four_exits, paper_room
from pedrl.sim.motion.common import Search, neighbour_search
from pedrl.sim.state import KernelState
from tests.sim.test_grid import _ring_room

pytestmark = pytest.mark.skipif(not numba_available(), reason="the grids are the numba kernels'")

PAIRS = neighbour_search(min_agents=2**30)
GRID = neighbour_search(min_agents=0)
EARLY = neighbour_search(min_agents=0, reach_scale=0.0)
"""The control: the ring search trusts one ring more than it visited, so it stops a ring early."""


def _comb_room(teeth: int = 40):
    """An 80 m hall whose ceiling has ``teeth`` square notches: 163 axis-aligned walls on whole metres, so that
    agents on a half-metre lattice are exactly as far from several walls (ties broken by index)."""
    width = 2 * teeth
    top = []
    for tooth in range(teeth):
        x = width - 2 * tooth
        top += [(x, 8), (x, 9), (x - 1, 9), (x - 1, 8)]
    ring = [(0, 0), (width // 2 - 1, 0), (width // 2 + 1, 0), (width, 0), *top, (0, 8)]
    text = ", ".join(f"{x} {y}" for x, y in [*ring, ring[0]])
    return custom(geometry=f"POLYGON (({text}))", exits=[[width // 2 - 1, 0, width // 2 + 1, 0]])


ROOMS = {
    "bottleneck": (bottleneck, 60),
    "corridor": (corridor, 80),
    "four_exits": (four_exits, 200),
    "ring": (_ring_room, 150),
    "comb": (_comb_room, 100),
}
MANY_WALLS = ("ring", "comb")
"""The rooms with enough walls for a grid of walls (``sensing_kernel._WALL_GRID_MIN``)."""


def sense(state: KernelState, present: np.ndarray, walls, k: int, w: int, search: Search):
    """``sense_room`` of every room: the features, the numbers sensed and the neighbours' velocities."""
    from pedrl.sim.sensing_kernel import sense_room

    rooms, agents = present.shape
    features = np.full((rooms, agents, 3 + 3 * k + 2 * w), np.float32(7.0))  # every entry is written
    num_sensed = np.full((rooms, agents), 7, np.int64)
    velocity = np.full((rooms, agents, k, 2), np.float32(7.0))
    size = max(agents, walls.starts.shape[0])
    for r in range(rooms):
        sense_room(r, state, present, walls, k, w, search, features, num_sensed, np.empty((2, size), np.float32),
                   np.empty((2, size), np.int64), velocity)  # fmt: skip
    return features, num_sensed, velocity


def assert_same(grid, pairs) -> None:
    assert np.array_equal(grid[1], pairs[1]), "the numbers sensed differ"
    assert np.array_equal(grid[2], pairs[2]), "the neighbours' velocities differ"
    rows = np.flatnonzero((grid[0] != pairs[0]).any(-1).reshape(-1))
    first = divmod(int(rows[0]), grid[0].shape[1]) if rows.size else None
    assert rows.size == 0, f"{rows.size} agents' features differ (the first: room, agent {first})"


def crowd(room: str, seed: int):
    """The room's crowd after a reset, walking at random, with a fifth of it absent: state, present, walls."""
    build, agents = ROOMS[room]
    env = build().room(num_replicas=2, num_agents=agents, agent_radius=0.2, max_speed=1.34)
    env.reset(seed=seed)
    state = env.state.arrays()
    rng = np.random.default_rng(seed)
    state.headings[:] = rng.uniform(-np.pi, np.pi, state.headings.shape)
    state.speeds[:] = rng.uniform(0.0, 1.34, state.speeds.shape)
    state.velocities[:] = np.stack((np.cos(state.headings), np.sin(state.headings)), -1) * state.speeds[..., None]
    present = state.active & (rng.random(state.active.shape) < 0.8)
    return state, present, env.geometry.kernel_walls()


def made_state(points: np.ndarray, goal, rng) -> KernelState:
    """One room of agents at ``points`` ``(N, 2)``, heading at random for ``goal``."""
    agents = points.shape[0]
    headings = rng.uniform(-np.pi, np.pi, (1, agents)).astype(np.float32)
    speeds = rng.uniform(0.0, 1.34, (1, agents)).astype(np.float32)
    velocities = np.stack((np.cos(headings), np.sin(headings)), -1) * speeds[..., None]
    return KernelState(
        positions=np.ascontiguousarray(points[None], np.float32), velocities=velocities.astype(np.float32),
        headings=headings, speeds=speeds, active=np.ones((1, agents), np.bool_),
        exit_index=np.zeros((1, agents), np.int64), targets=np.broadcast_to(np.float32(goal), (1, agents, 2)).copy(),
        decisions=np.zeros(1, np.int64), stage=np.zeros((1, agents), np.int64),
    )  # fmt: skip


def lattice(room: str, seed: int):
    """A 24 x 14 lattice of 0.5 m over the room's crowd box (whole and half metres: squared distances exact, and
    many equal), in shuffled index order, a sixth absent."""
    state, _, walls = crowd(room, seed)
    rng = np.random.default_rng(seed)
    low = np.floor(state.positions[0][state.active[0]].min(0))
    grid_x, grid_y = np.meshgrid(np.arange(24) * 0.5, np.arange(14) * 0.5)
    points = low + np.stack((grid_x.ravel(), grid_y.ravel()), -1)
    points = points[rng.permutation(24 * 14)]
    present = rng.random((1, points.shape[0])) < 5 / 6
    return made_state(points, low + 3.25, rng), present, walls


SLOTS = [(0, 0), (1, 1), (7, 2), (12, 5), (400, 400)]
"""``(k, w)``: none, one, the paper's, more, and more than there are agents and walls."""


@pytest.mark.parametrize(("k", "w"), SLOTS)
@pytest.mark.parametrize("room", sorted(ROOMS))
def test_the_grid_senses_the_crowd_as_every_pair(room, k, w):
    state, present, walls = crowd(room, seed=k)
    assert_same(sense(state, present, walls, k, w, GRID), sense(state, present, walls, k, w, PAIRS))


@pytest.mark.parametrize(("k", "w"), SLOTS)
@pytest.mark.parametrize("room", sorted(ROOMS))
def test_the_grid_breaks_exact_ties_as_every_pair(room, k, w):
    state, present, walls = lattice(room, seed=w)
    pairs = sense(state, present, walls, k, w, PAIRS)
    assert_same(sense(state, present, walls, k, w, GRID), pairs)
    if k == 7:  # the case is one of ties: many agents hold two neighbours at the same distance
        distances = pairs[0][..., 4 : 3 + 3 * k : 3]
        assert ((distances[..., 1:] == distances[..., :-1]) & (distances[..., 1:] > 0)).any(-1).sum() > 100


@pytest.mark.parametrize("present_count", [0, 1, 2, 3, 8])
def test_the_grid_senses_a_few_present_as_every_pair(present_count):
    state, present, walls = crowd("ring", seed=present_count)
    present[:] = False
    present[:, np.random.default_rng(0).permutation(150)[:present_count]] = True
    for k, w in SLOTS:
        assert_same(sense(state, present, walls, k, w, GRID), sense(state, present, walls, k, w, PAIRS))


def test_the_grid_senses_ten_thousand_as_every_pair():
    """A crowd of 10,000 in the paper's room: half at random, half on a 0.25 m lattice (ties)."""
    walls = paper_room().room(num_replicas=1, num_agents=2).geometry.kernel_walls()
    rng = np.random.default_rng(3)
    scattered = rng.random((5000, 2)) * (60.0, 100.0)
    grid_x, grid_y = np.meshgrid(np.arange(100) * 0.25, np.arange(50) * 0.25)
    points = np.concatenate((scattered, 20.0 + np.stack((grid_x.ravel(), grid_y.ravel()), -1)))[rng.permutation(10000)]
    state = made_state(points, (31.0, 100.0), rng)
    present = rng.random((1, 10000)) < 0.95
    assert_same(sense(state, present, walls, 7, 2, GRID), sense(state, present, walls, 7, 2, PAIRS))


@pytest.mark.parametrize("room", sorted(ROOMS))
def test_a_search_that_stops_a_ring_early_differs(room):
    """The control: trusting one ring more than visited loses neighbours (and, with a grid of walls, walls)."""
    state, present, walls = crowd(room, seed=0)
    early, pairs = sense(state, present, walls, 7, 2, EARLY), sense(state, present, walls, 7, 2, PAIRS)
    assert not np.array_equal(early[0][..., 3:24], pairs[0][..., 3:24])
    if room in MANY_WALLS:
        assert not np.array_equal(early[0][..., 24:], pairs[0][..., 24:])

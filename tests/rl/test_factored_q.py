"""Q learning on row sets of a factored table: the torch specification, its numba twins, and what the rule does."""

import pytest
import torch

from pedrl._numba import numba_available
from pedrl.rl import epsilon_greedy, factored_values, greedy, td_update

kernels = pytest.mark.skipif(not numba_available(), reason="numba is off (PEDRL_NO_NUMBA)")


def batch(seed: int, size: int = 400, slots: int = 10, rows: int = 120):
    """Tables ``(2, 1, 60, 81)`` and random transitions over row sets, a third of their slots empty (-1)."""
    generator = torch.Generator().manual_seed(seed)
    q_values = torch.randn(2, 1, rows // 2, 81, generator=generator)
    q_values[0, 0, :4] = 0.0  # tied rows
    sets = []
    for _ in range(2):
        ids = torch.randint(0, rows, (size, slots), generator=generator)
        ids[torch.rand(size, slots, generator=generator) < 0.33] = -1
        ids[:, 0] = torch.randint(0, rows, (size,), generator=generator)  # the own slot is always read
        sets.append(ids)
    actions = torch.randint(0, 81, (size,), generator=generator)
    rewards = torch.randn(size, generator=generator)
    terminal = torch.rand(size, generator=generator) < 0.2
    valid = torch.rand(size, generator=generator) < 0.9
    return q_values, sets[0], actions, rewards, sets[1], terminal, valid


def test_the_values_of_a_set_are_the_sum_of_its_rows():
    q_values = torch.arange(3 * 81, dtype=torch.float32).view(1, 1, 3, 81)
    rows = torch.tensor([[0, 2, -1], [1, -1, -1]])
    values = factored_values(q_values, rows)
    assert torch.equal(values[0], q_values[0, 0, 0] + q_values[0, 0, 2])
    assert torch.equal(values[1], q_values[0, 0, 1])


@kernels
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_kernels_equal_the_torch_specification_to_the_bit(seed):
    q_values, rows, actions, rewards, next_rows, terminal, valid = batch(seed)
    mine, theirs = q_values.clone(), q_values.clone()
    args = (actions, rewards, next_rows, terminal, valid)
    td_kernel = td_update(mine, rows, *args, alpha=0.3, gamma=0.9, compiled=True)
    td_torch = td_update(theirs, rows, *args, alpha=0.3, gamma=0.9, compiled=False)
    assert torch.equal(td_kernel, td_torch) and torch.equal(mine, theirs)
    assert not torch.equal(mine, q_values)  # it learned
    draws = [torch.Generator().manual_seed(seed) for _ in range(2)]
    assert torch.equal(greedy(mine, rows, draws[0], compiled=True), greedy(mine, rows, draws[1], compiled=False))


def test_one_slot_sets_learn_as_plain_rows():
    q_values, rows, actions, rewards, next_rows, terminal, valid = batch(3)
    plain, sets = q_values.clone(), q_values.clone()
    args = (actions, rewards)
    td_plain = td_update(plain, rows[:, 0], *args, next_rows[:, 0], terminal, valid, alpha=0.3, gamma=0.9)
    td_sets = td_update(sets, rows[:, :1], *args, next_rows[:, :1], terminal, valid, alpha=0.3, gamma=0.9)
    assert torch.equal(td_plain, td_sets) and torch.equal(plain, sets)


@pytest.mark.parametrize("compiled", [False, pytest.param(True, marks=kernels)])
def test_an_agent_alone_moves_its_summed_value_by_alpha_times_its_error(compiled):
    """The error is shared among the n rows of the set (delta / n each): the sum moves by exactly alpha delta, as one
    plain row would, and every row of the set by alpha delta / n."""
    q_values = torch.zeros(1, 1, 8, 81)
    q_values[0, 0, 5, 7] = 2.0
    rows, next_rows = torch.tensor([[0, 3, 5, -1]]), torch.tensor([[1, -1, -1, -1]])
    before = float(factored_values(q_values, rows)[0, 7])
    args = (torch.tensor([7]), torch.tensor([1.0]), next_rows, torch.tensor([True]), torch.tensor([True]))
    td = td_update(q_values, rows, *args, alpha=0.5, gamma=0.9, compiled=compiled)
    assert float(td[0]) == pytest.approx(1.0 - 2.0)
    assert float(factored_values(q_values, rows)[0, 7]) == pytest.approx(before + 0.5 * -1.0)
    assert float(q_values[0, 0, 0, 7]) == pytest.approx(-0.5 / 3) and float(q_values[0, 0, 3, 7]) == pytest.approx(
        -0.5 / 3
    )
    assert float(q_values[0, 0, 1].abs().sum()) == 0.0  # s' only bootstraps


def test_a_shared_neighbour_row_learns_from_every_slot():
    """A factored table generalises: a neighbour row learned at one slot drives the choice at another."""
    q_values = torch.zeros(1, 1, 4, 81)
    generator = torch.Generator().manual_seed(0)
    good = 11
    for _ in range(200):  # own state 0, a neighbour of id 2 sensed at slot 1: action 11 pays, the others cost
        actions = epsilon_greedy(q_values, torch.tensor([[0, 2, -1]]), 1.0, generator)
        reward = torch.where(actions == good, 1.0, -1.0)
        td_update(q_values, torch.tensor([[0, 2, -1]]), actions, reward, torch.tensor([[0, -1, -1]]),
                  torch.tensor([True]), torch.tensor([True]), alpha=0.3, gamma=0.9)  # fmt: skip
    # the same neighbour, now at slot 2, with another own state (row 1) never visited
    choice = greedy(q_values, torch.tensor([[1, -1, 2]]), torch.Generator().manual_seed(1))
    assert int(choice) == good

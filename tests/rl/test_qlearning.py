"""Q tables, epsilon-greedy selection and the TD update (paper equation 1)."""

import math

import pytest
import torch

from pedrl.rl import NUM_ACTIONS, epsilon_greedy, greedy, table_rows, td_update, zeros_q_values


def test_zeros_and_table_rows():
    q_values = zeros_q_values(2, 3, 5, device="cpu")
    assert q_values.shape == (2, 3, 5, NUM_ACTIONS) and q_values.dtype == torch.float32
    assert not bool(q_values.any())
    process = torch.tensor([0, 1, 1, 0])
    table = torch.tensor([0, 2, 0, 1])
    state = torch.tensor([4, 3, 0, 2])
    rows = table_rows(process, table, state, num_tables=3, num_states=5)
    q_values[1, 2, 3, 7] = 1.5
    flat = q_values.view(-1, NUM_ACTIONS)
    assert float(flat[rows[1], 7]) == 1.5
    for i in range(4):
        q_values.zero_()
        q_values[process[i], table[i], state[i], 0] = 1.0
        assert float(flat[rows[i], 0]) == 1.0


def test_td_update_matches_equation_1_by_hand():
    q_values = zeros_q_values(1, 2, 3, num_actions=4, device="cpu")
    q_values[0, 0, 1] = torch.tensor([0.5, -1.0, 2.0, 0.25])  # s
    q_values[0, 1, 2] = torch.tensor([3.0, 1.0, -2.0, 0.0])  # s'
    rows = table_rows(torch.tensor([0]), torch.tensor([0]), torch.tensor([1]), num_tables=2, num_states=3)
    next_rows = table_rows(torch.tensor([0]), torch.tensor([1]), torch.tensor([2]), num_tables=2, num_states=3)
    alpha, gamma, reward = 0.35, 0.91, -4.0
    td = td_update(
        q_values,
        rows,
        torch.tensor([1]),
        torch.tensor([reward]),
        next_rows,
        torch.tensor([False]),
        torch.tensor([True]),
        alpha=alpha,
        gamma=gamma,
    )
    expected_td = reward + gamma * 3.0 - (-1.0)
    assert float(td[0]) == pytest.approx(expected_td, abs=1e-6)
    assert float(q_values[0, 0, 1, 1]) == pytest.approx(-1.0 + alpha * expected_td, abs=1e-6)
    # Nothing else moved.
    untouched = q_values.clone()
    untouched[0, 0, 1, 1] = -1.0
    assert torch.equal(untouched[0, 0, 1], torch.tensor([0.5, -1.0, 2.0, 0.25]))
    assert torch.equal(q_values[0, 1, 2], torch.tensor([3.0, 1.0, -2.0, 0.0]))


def test_terminal_does_not_bootstrap_but_truncation_does():
    q_values = zeros_q_values(1, 1, 2, num_actions=3, device="cpu")
    q_values[0, 0, 1] = 10.0
    rows, next_rows = torch.tensor([0, 0]), torch.tensor([1, 1])
    actions = torch.tensor([0, 1])
    td = td_update(
        q_values,
        rows,
        actions,
        torch.tensor([100.0, 0.0]),
        next_rows,
        torch.tensor([True, False]),  # entry 0 reached the door; entry 1 was cut by the time limit
        torch.tensor([True, True]),
        alpha=0.5,
        gamma=0.9,
    )
    torch.testing.assert_close(td, torch.tensor([100.0, 9.0]))
    torch.testing.assert_close(q_values[0, 0, 0], torch.tensor([50.0, 4.5, 0.0]))


def test_invalid_entries_are_skipped():
    q_values = zeros_q_values(1, 1, 4, num_actions=3, device="cpu")
    before = q_values.clone()
    td = td_update(
        q_values,
        torch.tensor([2, 10**9]),  # an invalid entry may carry any row
        torch.tensor([1, -5]),
        torch.tensor([1.0, 50.0]),
        torch.tensor([3, -1]),
        torch.tensor([False, False]),
        torch.tensor([True, False]),
        alpha=0.1,
        gamma=0.9,
    )
    assert float(td[1]) == 0.0
    changed = (q_values != before).nonzero().tolist()
    assert changed == [[0, 0, 2, 1]]
    assert float(q_values[0, 0, 2, 1]) == pytest.approx(0.1)


def test_duplicate_entries_are_averaged():
    q_values = zeros_q_values(1, 1, 3, num_actions=2, device="cpu")
    q_values[0, 0, 2] = torch.tensor([4.0, 1.0])
    rows = torch.tensor([0, 0, 0, 1])
    actions = torch.tensor([1, 1, 1, 0])
    rewards = torch.tensor([1.0, 2.0, 6.0, 3.0])
    next_rows = torch.tensor([2, 2, 1, 2])
    terminal = torch.tensor([False, True, False, False])
    alpha, gamma = 0.5, 0.5
    td = td_update(
        q_values, rows, actions, rewards, next_rows, terminal, torch.ones(4, dtype=torch.bool), alpha=alpha, gamma=gamma
    )
    expected = torch.tensor([1.0 + 0.5 * 4.0, 2.0, 6.0 + 0.0, 3.0 + 0.5 * 4.0])
    torch.testing.assert_close(td, expected)
    assert float(q_values[0, 0, 0, 1]) == pytest.approx(alpha * float(expected[:3].mean()), abs=1e-6)
    assert float(q_values[0, 0, 1, 0]) == pytest.approx(alpha * 5.0, abs=1e-6)


def test_greedy_and_epsilon_zero_pick_the_maximum():
    generator = torch.Generator().manual_seed(0)
    q_values = torch.randn(2, 3, 50, NUM_ACTIONS, generator=generator)
    rows = torch.randint(0, 2 * 3 * 50, (500,), generator=generator)
    expected = q_values.view(-1, NUM_ACTIONS)[rows].argmax(1)
    assert torch.equal(greedy(q_values, rows, generator), expected)
    assert torch.equal(epsilon_greedy(q_values, rows, 0.0, generator), expected)
    assert torch.equal(epsilon_greedy(q_values, rows, torch.zeros(500), generator), expected)


def test_epsilon_one_is_uniform():
    generator = torch.Generator().manual_seed(1)
    q_values = torch.randn(1, 1, 4, NUM_ACTIONS, generator=generator)
    samples = 81 * 400
    rows = torch.randint(0, 4, (samples,), generator=generator)
    actions = epsilon_greedy(q_values, rows, 1.0, generator)
    counts = torch.bincount(actions, minlength=NUM_ACTIONS).double()
    expected = samples / NUM_ACTIONS
    chi_square = float(((counts - expected) ** 2 / expected).sum())
    # 80 degrees of freedom: mean 80, standard deviation ~12.6; 160 is far in the tail.
    assert chi_square < 160.0
    assert counts.min() > 0


def test_epsilon_mixes_in_the_expected_proportion():
    generator = torch.Generator().manual_seed(2)
    q_values = torch.zeros(1, 1, 1, NUM_ACTIONS)
    q_values[..., 40] = 1.0
    samples = 20_000
    actions = epsilon_greedy(q_values, torch.zeros(samples, dtype=torch.int64), 0.3, generator)
    greedy_share = float((actions == 40).double().mean())
    expected = 0.7 + 0.3 / NUM_ACTIONS
    assert greedy_share == pytest.approx(expected, abs=4 * math.sqrt(expected * (1 - expected) / samples))


def test_ties_are_broken_uniformly():
    generator = torch.Generator().manual_seed(3)
    q_values = torch.zeros(1, 2, 1, NUM_ACTIONS)
    tied = [3, 17, 40, 80]
    q_values[0, 1, 0, tied] = 2.0
    samples = 8000
    # Table 0 is all zeros (81-way tie), table 1 has 4 tied maxima.
    rows = torch.arange(samples) % 2
    actions = greedy(q_values, rows, generator)
    zero_table = actions[rows == 0]
    assert torch.unique(zero_table).numel() > 70
    four_way = actions[rows == 1]
    assert set(four_way.tolist()) == set(tied)
    counts = torch.bincount(four_way, minlength=NUM_ACTIONS)[tied].double()
    expected = four_way.numel() / 4
    assert float(((counts - expected) ** 2 / expected).sum()) < 16.3  # chi-square, 3 dof, p ~ 0.001


@pytest.mark.parametrize("seed", range(5))
def test_compiled_kernels_equal_the_torch_code_to_the_bit(seed):
    """The numba kernels (the CPU default) give the same actions and tables as the torch code, with duplicates,
    skipped and terminal entries, tied and NaN-free maxima, for the same generator."""
    generator = torch.Generator().manual_seed(seed)
    q_values = torch.randint(-3, 3, (2, 3, 5, NUM_ACTIONS), generator=generator).float() * 0.5  # many ties
    q_values[0, 0, 0] = 0.0  # an all-tied row
    num = 200
    rows = torch.randint(0, 2 * 3 * 5, (num,), generator=generator)
    rows[:40] = rows[0]  # duplicate rows, and below duplicate (row, action) entries
    actions = torch.randint(0, NUM_ACTIONS, (num,), generator=generator)
    actions[:20] = actions[0]
    rewards = torch.randn(num, generator=generator)
    next_rows = torch.randint(0, 2 * 3 * 5, (num,), generator=generator)
    terminal = torch.rand(num, generator=generator) < 0.2
    valid = torch.rand(num, generator=generator) < 0.8
    results = {}
    for compiled in (False, True):
        tables = q_values.clone()
        chosen = epsilon_greedy(tables, rows, 0.3, torch.Generator().manual_seed(seed), compiled=compiled)
        td = td_update(
            tables, rows, actions, rewards, next_rows, terminal, valid, alpha=0.35, gamma=0.91, compiled=compiled
        )
        results[compiled] = (chosen, td, tables)
    for torch_value, compiled_value in zip(results[False], results[True], strict=True):
        assert torch.equal(torch_value, compiled_value)


def test_compiled_kernels_refuse_rows_out_of_range_and_ignore_skipped_entries():
    q_values = zeros_q_values(1, 1, 4, device="cpu")
    with pytest.raises(IndexError, match="entry 1: row or action out of range"):
        greedy(q_values, torch.tensor([0, 4]), compiled=True)
    rows, actions = torch.tensor([0, 99]), torch.tensor([3, 999])  # entry 1 is skipped: anything goes
    td = td_update(
        q_values, rows, actions, torch.ones(2), torch.tensor([1, -5]), torch.tensor([False, False]),
        torch.tensor([True, False]), alpha=0.5, gamma=0.9, compiled=True,
    )  # fmt: skip
    assert td.tolist() == [1.0, 0.0] and q_values[0, 0, 0, 3] == 0.5
    with pytest.raises(IndexError, match="out of range"):
        td_update(
            q_values, rows, actions, torch.ones(2), torch.tensor([1, -5]), torch.tensor([False, False]),
            torch.tensor([True, True]), alpha=0.5, gamma=0.9, compiled=True,
        )  # fmt: skip

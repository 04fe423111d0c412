"""The replay memory's batches (:class:`pedrl.rl.replay.ReplayBuffer`): uniform over what a ring holds, or, balanced,
every room it holds drawn alike (a room of a lone walker as often as a crowd's), and the rooms kept for a resume."""

import pytest
import torch

from pedrl.rl.replay import Batch, NStepWindow, ReplayBuffer


def filled(per_room: dict[int, int], *, processes: int = 2, capacity: int = 1000) -> ReplayBuffer:
    """A memory of ``processes`` rings, each holding ``per_room[r]`` transitions of room ``r``, their reward ``r``."""
    buffer = ReplayBuffer(processes, capacity, 3)
    for room, count in per_room.items():
        rows = count * processes
        batch = Batch(torch.zeros(rows, 3), torch.zeros(rows, dtype=torch.int64), torch.full((rows,), float(room)),
                      torch.zeros(rows, 3), torch.zeros(rows, dtype=torch.bool))  # fmt: skip
        buffer.add(torch.arange(processes).repeat_interleave(count), batch, room)
    return buffer


@pytest.mark.parametrize(("balanced", "expected"), [(False, [0.95, 0.05]), (True, [0.5, 0.5])])
def test_a_balanced_batch_draws_each_room_alike_and_a_plain_one_as_the_ring_holds_them(balanced, expected):
    buffer = filled({0: 950, 1: 50})
    batch = buffer.sample(20_000, torch.Generator().manual_seed(0), balanced=balanced)
    assert batch.rewards.shape == (2, 20_000)
    for ring in batch.rewards:
        shares = torch.bincount(ring.long(), minlength=2).double() / ring.numel()
        torch.testing.assert_close(shares, torch.tensor(expected, dtype=torch.float64), atol=0.01, rtol=0)


def test_a_balanced_batch_is_seeded_and_draws_only_what_the_ring_holds():
    buffer = filled({0: 30, 2: 10})
    first = buffer.sample(500, torch.Generator().manual_seed(4), balanced=True)
    again = buffer.sample(500, torch.Generator().manual_seed(4), balanced=True)
    assert torch.equal(first.rewards, again.rewards)
    assert set(first.rewards.unique().tolist()) == {0.0, 2.0}


def test_the_rooms_travel_with_the_rings_and_an_older_file_reads_as_room_0():
    buffer = filled({0: 5, 1: 7})
    tensors = buffer.tensors()
    assert torch.equal(tensors["replay/rooms"][0, :12], torch.tensor([0] * 5 + [1] * 7))
    copy = ReplayBuffer(2, 1000, 3)
    copy.load_tensors(tensors)
    assert torch.equal(copy.rooms, buffer.rooms)
    older = {name: tensor for name, tensor in tensors.items() if name != "replay/rooms"}
    copy.load_tensors(older)
    assert not bool(copy.rooms.any())


def _decision(t: int, rows: int = 3) -> Batch:
    """Decision ``t`` of ``rows`` walkers: inputs ``t`` (row ``r``: ``t + 10 r``, 3 wide), action ``t``, reward
    ``2^t``, next inputs ``t + 1``."""
    base = (torch.arange(rows, dtype=torch.float32)[:, None] * 10).expand(rows, 3)
    return Batch(base + t, torch.full((rows,), t), torch.full((rows,), 2.0**t), base + t + 1,
                 torch.zeros(rows, dtype=torch.bool))  # fmt: skip


def test_an_n_step_window_returns_each_transition_once_with_its_discounted_rewards_and_horizon():
    """Row 0 walks 5 decisions and leaves at the 5th; the clock cuts row 1 after 2; row 2 never acts. With n = 3 and
    gamma 0.5, row 0's transition from decision s sums the rewards 2^s .. 2^(s+h-1) discounted, h = min(3, 5 - s), up
    to the input after decision s + h - 1; a cut row bootstraps (not terminal), a row that left does not."""
    gamma, window, found = 0.5, NStepWindow(3, 0.5), []
    for t in range(5):
        taken = _decision(t)
        taken = taken._replace(terminated=torch.tensor([t == 4, False, False]))
        valid = torch.tensor([True, t < 2, False])
        ended = taken.terminated | torch.tensor([False, t == 1, False])
        rows, batch = window.fold(taken, valid, ended)
        for i, row in enumerate(rows.tolist()):
            found.append((row, int(batch.actions[i]), int(batch.horizons[i]), float(batch.rewards[i]),
                          float(batch.next_inputs[i, 0]), bool(batch.terminated[i])))  # fmt: skip
    expected = []
    for row, steps in ((0, 5), (1, 2)):
        for start in range(steps):
            h = min(3, steps - start)
            ret = sum(gamma**i * 2.0 ** (start + i) for i in range(h))
            expected.append((row, start, h, ret, 10.0 * row + start + h, row == 0 and start + h == 5))
    assert sorted(found) == sorted(expected)


def test_a_one_step_window_returns_the_decision_itself():
    window = NStepWindow(1, 0.9)
    taken = _decision(2)
    rows, batch = window.fold(taken, torch.tensor([True, False, True]), torch.zeros(3, dtype=torch.bool))
    assert rows.tolist() == [0, 2]
    for name in ("inputs", "actions", "rewards", "next_inputs", "terminated"):
        assert torch.equal(getattr(batch, name), getattr(taken, name)[rows])
    assert batch.horizons.tolist() == [1, 1]


def test_horizons_travel_with_the_rings_and_sample_with_their_transitions():
    buffer = ReplayBuffer(1, 100, 3, horizons=True)
    batch = _decision(0)._replace(horizons=torch.tensor([1, 2, 3], dtype=torch.uint8))
    batch = batch._replace(rewards=torch.tensor([1.0, 2.0, 3.0]))
    buffer.add(torch.zeros(3, dtype=torch.int64), batch)
    drawn = buffer.sample(200, torch.Generator().manual_seed(0))
    assert torch.equal(drawn.horizons.float(), drawn.rewards)  # each horizon beside its own transition
    copy = ReplayBuffer(1, 100, 3, horizons=True)
    copy.load_tensors(buffer.tensors())
    assert torch.equal(copy.horizons, buffer.horizons)
    missing = {name: tensor for name, tensor in buffer.tensors().items() if name != "replay/horizons"}
    with pytest.raises(ValueError, match="^tensor replay/horizons is missing$"):
        copy.load_tensors(missing)
    assert "replay/horizons" not in ReplayBuffer(1, 100, 3).tensors()  # one-step memories are stored as before

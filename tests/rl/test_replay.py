"""The replay memory's batches (:class:`pedrl.rl.replay.ReplayBuffer`): uniform over what a ring holds, or, balanced,
every room it holds drawn alike (a room of a lone walker as often as a crowd's), and the rooms kept for a resume."""

import pytest
import torch

from pedrl.rl.replay import Batch, ReplayBuffer


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

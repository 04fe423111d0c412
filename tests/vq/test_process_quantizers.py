"""ProcessQuantizers: one quantizer per learning process, encoding each row with its own process's quantizer."""

import pytest
import torch

from pedrl.sim.sensing import feature_indices
from pedrl.vq import ProcessQuantizers, Quantizer, UnionQuantizer


def _fitted(seed: int, dim: int = 5, k: int = 16) -> Quantizer:
    generator = torch.Generator().manual_seed(seed)
    states = torch.randn(400, dim, generator=generator) * (seed + 1) + seed
    quantizer, _ = Quantizer.fit(states, k, generator=generator, max_iterations=10)
    return quantizer


def test_each_row_is_encoded_by_its_own_process_in_both_layouts():
    parts = [_fitted(seed) for seed in range(3)]
    quantizers = ProcessQuantizers(parts)
    states = torch.randn(3 * 8, 5) * 2 + 1
    # the trainers' layout: 8 consecutive rows per process, one batched search
    contiguous = quantizers.encode(states)
    expected = torch.cat([part.encode(block) for part, block in zip(parts, states.view(3, 8, 5), strict=True)])
    assert torch.equal(contiguous, expected)
    # evaluation's layout: replica i driven by process i mod P
    process = torch.arange(24).remainder(3)
    ids = quantizers.encode(states, process=process)
    for index, part in enumerate(parts):
        assert torch.equal(ids[process == index], part.encode(states[process == index]))
    # the processes really differ: the same states get other prototypes from another process
    assert not torch.equal(parts[0].encode(states), parts[1].encode(states))


def test_union_parts_and_state_dict_round_trip():
    parts = []
    for seed in range(2):
        index = feature_indices(1, 2, 0)  # own features and one neighbour of a 2-neighbour, 0-wall layout
        generator = torch.Generator().manual_seed(seed)
        states = torch.randn(300, 9, generator=generator)
        plain, _ = Quantizer.fit(states[:, index], 8, generator=generator, max_iterations=5)
        parts.append(UnionQuantizer().unite(1, index, plain))
    quantizers = ProcessQuantizers(parts)
    states = torch.randn(10, 9)
    num_sensed = torch.ones(10, dtype=torch.int64)
    ids = quantizers.encode(states, num_sensed)
    assert torch.equal(ids[:5], parts[0].encode(states[:5], num_sensed[:5]))
    assert torch.equal(ids[5:], parts[1].encode(states[5:], num_sensed[5:]))
    state = quantizers.state_dict()
    assert ProcessQuantizers.holds(state) and not ProcessQuantizers.holds(parts[0].state_dict())
    again = ProcessQuantizers.from_state_dict(state, UnionQuantizer.from_state_dict)
    assert torch.equal(again.encode(states, num_sensed), ids)
    with pytest.raises(ValueError, match="num_sensed is required"):
        quantizers.encode(states)


def test_parts_must_agree_on_the_number_of_prototypes():
    with pytest.raises(ValueError, match="same number of prototypes"):
        ProcessQuantizers([_fitted(0, k=8), _fitted(1, k=16)])
    with pytest.raises(ValueError, match="cannot be split"):
        ProcessQuantizers([_fitted(0), _fitted(1)]).encode(torch.zeros(3, 5))

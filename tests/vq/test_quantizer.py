"""Quantizer and UnionQuantizer: standardisation, encoding against brute force, union routing, persistence."""

import pytest
import torch

from pedrl.vq import Quantizer, UnionQuantizer


def states(num, dim, *, seed, scale=None, shift=None):
    generator = torch.Generator().manual_seed(seed)
    scale = scale if scale is not None else torch.linspace(0.5, 20.0, dim)
    shift = shift if shift is not None else torch.linspace(-10.0, 30.0, dim)
    return shift + scale * torch.randn(num, dim, generator=generator)


def brute_force_ids(quantizer: Quantizer, raw: torch.Tensor) -> torch.Tensor:
    standardised = (raw.double() - quantizer.mean.double()) / quantizer.std.double()
    return torch.cdist(standardised, quantizer.prototypes.double()).argmin(-1)


def assert_encodes_nearest(quantizer: Quantizer, raw: torch.Tensor, ids: torch.Tensor) -> None:
    standardised = (raw.double() - quantizer.mean.double()) / quantizer.std.double()
    distance = torch.cdist(standardised, quantizer.prototypes.double()).square()
    best = distance.min(-1).values
    chosen = distance.gather(-1, ids[..., None]).squeeze(-1)
    assert bool((chosen <= best + 1e-5 * (1 + best)).all())


def fitted(dim=6, num_prototypes=40, *, seed=0, num=2000):
    data = states(num, dim, seed=seed)
    quantizer, result = Quantizer.fit(
        data, num_prototypes, generator=torch.Generator().manual_seed(seed), max_iterations=10
    )
    return quantizer, result, data


def test_fit_standardisation_statistics():
    quantizer, result, data = fitted()
    torch.testing.assert_close(quantizer.mean, data.double().mean(0).float())
    torch.testing.assert_close(quantizer.std, data.double().std(0, correction=0).float())
    standardised = quantizer.standardise(data)
    torch.testing.assert_close(standardised.mean(0), torch.zeros(6), atol=1e-5, rtol=0)
    torch.testing.assert_close(standardised.std(0, correction=0), torch.ones(6), atol=1e-5, rtol=0)
    assert quantizer.num_prototypes == 40 and quantizer.dim == 6
    assert quantizer.prototypes.shape == (40, 6)
    # The prototypes live in standardised space: near the data there, far from the raw data.
    assert float(quantizer.prototypes.abs().max()) < 6.0
    assert torch.equal(result.prototypes, quantizer.prototypes)


def test_constant_feature_gets_unit_std():
    data = states(500, 3, seed=1)
    data[:, 1] = 7.0
    quantizer, _ = Quantizer.fit(data, 10, max_iterations=3)
    assert float(quantizer.std[1]) == 1.0
    assert float(quantizer.mean[1]) == pytest.approx(7.0)
    assert bool(torch.isfinite(quantizer.prototypes).all())


@pytest.mark.parametrize("precision", ["float32", "bfloat16", "auto"])
def test_encode_matches_brute_force(precision):
    data = states(2000, 28, seed=2)
    base, _ = Quantizer.fit(data, 520, max_iterations=2, generator=torch.Generator().manual_seed(0))
    quantizer = Quantizer(mean=base.mean, std=base.std, prototypes=base.prototypes, precision=precision)
    queries = states(800, 28, seed=3)
    ids = quantizer.encode(queries)
    assert ids.dtype == torch.int64 and ids.shape == (800,)
    assert bool(((ids >= 0) & (ids < 520)).all())
    assert_encodes_nearest(quantizer, queries, ids)
    assert float((ids == brute_force_ids(quantizer, queries)).float().mean()) > 0.999


def test_encode_arbitrary_leading_shapes():
    quantizer, _, _ = fitted()
    queries = states(2 * 3 * 5, 6, seed=4)
    flat = quantizer.encode(queries)
    shaped = quantizer.encode(queries.view(2, 3, 5, 6))
    assert shaped.shape == (2, 3, 5)
    assert torch.equal(shaped.reshape(-1), flat)
    assert quantizer.encode(queries[0]).shape == ()
    assert quantizer.encode(queries[:0]).shape == (0,)
    assert torch.equal(quantizer.encode(queries, chunk_size=7), flat)
    with pytest.raises(ValueError):
        quantizer.encode(torch.zeros(4, 5))


def test_decode_returns_raw_prototypes():
    quantizer, _, data = fitted()
    ids = quantizer.encode(data[:50])
    decoded = quantizer.decode(ids)
    assert decoded.shape == (50, 6)
    # decode undoes the standardisation of the prototypes.
    torch.testing.assert_close(quantizer.standardise(decoded), quantizer.prototypes[ids], rtol=1e-5, atol=1e-5)


def test_state_dict_round_trip():
    quantizer, _, data = fitted()
    state = quantizer.state_dict()
    assert set(state) == {"mean", "std", "prototypes"}
    assert all(isinstance(value, torch.Tensor) and value.is_contiguous() for value in state.values())
    restored = Quantizer.from_state_dict({key: value.clone() for key, value in state.items()})
    assert torch.equal(restored.encode(data), quantizer.encode(data))
    moved = quantizer.to("cpu")
    assert torch.equal(moved.encode(data), quantizer.encode(data))


def test_quantizer_rejects_inconsistent_tensors():
    with pytest.raises(ValueError):
        Quantizer(mean=torch.zeros(3), std=torch.ones(3), prototypes=torch.zeros(4, 2))
    with pytest.raises(ValueError):
        Quantizer(mean=torch.zeros(2), std=torch.tensor([1.0, 0.0]), prototypes=torch.zeros(4, 2))


# ---------------------------------------------------------------------------- UnionQuantizer

NUM_FEATURES = 3 + 3 * 3 + 2 * 2  # k = 3 neighbours, w = 2 walls: 16 features


def projection(num_sensed: int) -> torch.Tensor:
    """Features of a state with `num_sensed` neighbours (own 3, the first neighbours, the walls)."""
    own = list(range(3 + 3 * num_sensed))
    walls = list(range(3 + 3 * 3, NUM_FEATURES))
    return torch.tensor(own + walls, dtype=torch.int64)


def part_quantizer(num_sensed: int, num_prototypes: int, *, seed: int) -> Quantizer:
    data = states(400, NUM_FEATURES, seed=seed)[:, projection(num_sensed)]
    quantizer, _ = Quantizer.fit(data, num_prototypes, generator=torch.Generator().manual_seed(seed), max_iterations=5)
    return quantizer


@pytest.fixture
def union():
    union = UnionQuantizer()
    for num_sensed, size in ((1, 12), (3, 20), (0, 5)):
        union = union.unite(num_sensed, projection(num_sensed), part_quantizer(num_sensed, size, seed=num_sensed))
    return union


def test_union_offsets_and_sizes(union):
    assert union.num_sensed == [0, 1, 3]
    assert union.part_sizes == {0: 5, 1: 12, 3: 20}
    assert union.offsets == {0: 0, 1: 5, 3: 17}
    assert union.num_prototypes == 37


def test_union_routes_each_state_to_its_part(union):
    generator = torch.Generator().manual_seed(9)
    full = states(2 * 60, NUM_FEATURES, seed=10).view(2, 60, NUM_FEATURES)
    num_sensed = torch.randint(0, 6, (2, 60), generator=generator)
    ids = union.encode(full, num_sensed)
    assert ids.shape == (2, 60) and ids.dtype == torch.int64
    # No part for 2: the largest smaller n (1). Above every part (4, 5): the largest (3).
    expected_part = {0: 0, 1: 1, 2: 1, 3: 3, 4: 3, 5: 3}
    for n, part in expected_part.items():
        mask = num_sensed == n
        if not bool(mask.any()):
            continue
        index, quantizer = union.part(part)
        offset, size = union.offsets[part], union.part_sizes[part]
        assert bool(((ids[mask] >= offset) & (ids[mask] < offset + size)).all())
        assert torch.equal(ids[mask] - offset, quantizer.encode(full[mask][:, index]))


def test_union_with_no_smaller_part_uses_the_smallest():
    union = UnionQuantizer().unite(2, projection(2), part_quantizer(2, 6, seed=2))
    union = union.unite(3, projection(3), part_quantizer(3, 4, seed=3))
    full = states(10, NUM_FEATURES, seed=11)
    ids = union.encode(full, torch.zeros(10, dtype=torch.int64))
    index, quantizer = union.part(2)
    assert torch.equal(ids, quantizer.encode(full[:, index]))


def test_unite_same_part_keeps_old_prototypes_in_raw_units(union):
    old_index, old = union.part(1)
    new = part_quantizer(1, 7, seed=21)
    united = union.unite(1, projection(1), new)
    index, merged = united.part(1)
    assert torch.equal(index, old_index)
    assert merged.num_prototypes == 12 + 7
    torch.testing.assert_close(merged.mean, new.mean)
    torch.testing.assert_close(merged.std, new.std)
    # Old prototypes first, unchanged in raw units; then the new ones.
    torch.testing.assert_close(merged.decode(torch.arange(12)), old.decode(torch.arange(12)), rtol=1e-5, atol=1e-4)
    torch.testing.assert_close(merged.prototypes[12:], new.prototypes)
    assert united.part_sizes == {0: 5, 1: 19, 3: 20}
    assert united.offsets == {0: 0, 1: 5, 3: 24}
    # The original union is unchanged.
    assert union.part_sizes == {0: 5, 1: 12, 3: 20}
    with pytest.raises(ValueError):
        union.unite(1, projection(2)[: new.dim], new)


def test_union_state_dict_round_trip(union):
    state = union.state_dict()
    assert all(isinstance(value, torch.Tensor) for value in state.values())
    restored = UnionQuantizer.from_state_dict({key: value.clone() for key, value in state.items()})
    full = states(200, NUM_FEATURES, seed=12)
    num_sensed = torch.randint(0, 4, (200,), generator=torch.Generator().manual_seed(13))
    assert restored.part_sizes == union.part_sizes
    assert torch.equal(restored.encode(full, num_sensed), union.encode(full, num_sensed))
    assert torch.equal(union.to("cpu").encode(full, num_sensed), union.encode(full, num_sensed))


def test_union_errors():
    with pytest.raises(RuntimeError):
        UnionQuantizer().encode(torch.zeros(2, NUM_FEATURES), torch.zeros(2, dtype=torch.int64))
    union = UnionQuantizer().unite(0, projection(0), part_quantizer(0, 3, seed=0))
    with pytest.raises(ValueError):
        union.encode(torch.zeros(2, NUM_FEATURES), torch.zeros(3, dtype=torch.int64))
    with pytest.raises(ValueError):
        union.unite(1, projection(0), part_quantizer(1, 3, seed=1))

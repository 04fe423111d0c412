"""The factored quantizer (`pedrl.vq.factored`): slots, shared factors, files, its kernel twin, its checks."""

import pytest
import torch

from pedrl._numba import numba_available
from pedrl.rl.policy import TabularPolicy, from_tensors
from pedrl.sim.sensing import num_features
from pedrl.vq import FactoredQuantizer, Quantizer, factor_specs
from pedrl.vq.encoder import EncoderSettings, StateEncoder, quantizer_from_state_dict
from pedrl.vq.settings import VQSettings

K, W = 7, 2
SPECS = factor_specs(
    {
        "own": {"num_prototypes": 12},
        "neighbour": {"num_prototypes": 9, "weights": {"distance": 3}},
        "wall": {"num_prototypes": 5},
    }
)


def states(count: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """Random prepared states ``(count, 28)`` and their sensed neighbours, 0..7."""
    generator = torch.Generator().manual_seed(seed)
    values = torch.rand(count, num_features(K, W), generator=generator) * 4
    sensed = torch.randint(0, K + 1, (count,), generator=generator)
    return values, sensed


def fitted() -> FactoredQuantizer:
    values, sensed = states(600)
    quantizer, distortion = FactoredQuantizer.fit(
        values, sensed, SPECS, num_neighbours=K, num_walls=W, max_states=10_000,
        generator=torch.Generator().manual_seed(0), max_iterations=10,
    )  # fmt: skip
    assert distortion > 0
    return quantizer


def test_ids_are_one_own_a_neighbour_per_sensed_slot_and_a_wall_per_wall():
    quantizer = fitted()
    assert quantizer.num_prototypes == 12 + 9 + 5 and quantizer.num_slots == 1 + K + W
    values, sensed = states(50, seed=1)
    ids = quantizer.encode(values, sensed)
    assert ids.shape == (50, 1 + K + W)
    assert bool((ids[:, 0] >= 0).all() and (ids[:, 0] < 12).all())
    neighbours = ids[:, 1 : 1 + K]
    slot = torch.arange(K)[None, :]
    assert torch.equal(neighbours >= 0, slot < sensed[:, None])  # -1 beyond the sensed ones, and only there
    assert bool(((neighbours[neighbours >= 0] >= 12) & (neighbours[neighbours >= 0] < 21)).all())
    assert bool(((ids[:, 1 + K :] >= 21) & (ids[:, 1 + K :] < 26)).all())
    # each slot is its factor's own quantizer on that slot's features
    own, nb, walls = quantizer.split(values)
    assert torch.equal(ids[:, 0], quantizer.own.encode(own))
    assert torch.equal(ids[:, 1 + K :] - 21, quantizer.wall.encode(walls))


def test_one_neighbour_quantizer_serves_every_slot():
    """What a neighbour at slot 3 is, slot 1 knows: the same features give the same id in any slot."""
    quantizer = fitted()
    values, _ = states(1, seed=2)
    neighbour = values[0, 3 + 3 * 3 : 3 + 3 * 4].clone()
    values[0, 3 + 3 * 1 : 3 + 3 * 2] = neighbour
    ids = quantizer.encode(values, torch.tensor([K]))
    assert ids[0, 1 + 1] == ids[0, 1 + 3]


def test_the_factor_weights_are_applied():
    quantizer = fitted()
    plain = quantizer.neighbour.std * torch.tensor([1.0, 3.0, 1.0])
    values, sensed = states(600)
    _, neighbours, _ = quantizer.split(values)
    rows = neighbours[torch.arange(K)[None, :] < sensed[:, None]]
    assert torch.allclose(plain, rows.double().std(0, correction=0).float(), rtol=1e-4)


def test_a_factored_quantizer_round_trips_through_a_policy_file(tmp_path):
    quantizer = fitted()
    settings = EncoderSettings(num_neighbours=K, num_walls=W, max_distance=10.0, max_speed=1.0)
    policy = TabularPolicy(StateEncoder(settings, quantizer), torch.randn(2, 1, quantizer.num_prototypes, 81))
    path = policy.save(tmp_path / "policy.safetensors")
    loaded = TabularPolicy.load(path)
    assert isinstance(loaded.encoder.quantizer, FactoredQuantizer)
    assert torch.equal(loaded.q_values, policy.q_values)
    values, sensed = states(40, seed=3)
    assert torch.equal(loaded.encoder.quantizer.encode(values, sensed), quantizer.encode(values, sensed))


def test_a_factor_left_out_reads_nothing_and_round_trips():
    values, sensed = states(300)
    specs = factor_specs({"own": {"num_prototypes": 6}, "wall": {"num_prototypes": 4}})
    quantizer, _ = FactoredQuantizer.fit(
        values, sensed, specs, num_neighbours=K, num_walls=W, max_states=1000, generator=torch.Generator()
    )
    assert quantizer.neighbour is None and quantizer.num_slots == 1 + W and quantizer.num_prototypes == 10
    again = quantizer_from_state_dict(quantizer.state_dict())
    assert torch.equal(again.encode(values, sensed), quantizer.encode(values, sensed))


def test_a_plain_quantizer_still_loads_as_one():
    plain = Quantizer(mean=torch.zeros(28), std=torch.ones(28), prototypes=torch.randn(4, 28))
    assert isinstance(quantizer_from_state_dict(plain.state_dict()), Quantizer)


def test_value_transfer_maps_each_factor_to_itself():
    quantizer = fitted()
    nearest = quantizer.nearest_in(quantizer)
    assert torch.equal(nearest, torch.arange(quantizer.num_prototypes))
    no_walls = FactoredQuantizer(own=quantizer.own, neighbour=quantizer.neighbour, wall=None, num_neighbours=K,
                                 num_walls=W)  # fmt: skip
    assert bool((quantizer.nearest_in(no_walls)[21:] == -1).all())


def test_a_checkpoint_for_other_slots_is_refused():
    quantizer = fitted()
    settings = EncoderSettings(num_neighbours=5, num_walls=W, max_distance=10.0, max_speed=1.0)
    tensors = {"q_values": torch.zeros(1, 1, quantizer.num_prototypes, 81)}
    tensors |= {f"quantizer/{k}": v for k, v in quantizer.state_dict().items()}
    with pytest.raises(ValueError, match="reads 7 neighbour and 2 wall slots: the observations have 5 and 2"):
        from_tensors(settings, tensors)


@pytest.mark.parametrize(
    ("factors", "message"),
    [
        ({"door": {"num_prototypes": 4}}, "vq.factors.door is not a factor: allowed: own, neighbour, wall"),
        ({"own": {"num_prototypes": 0}}, r"vq.factors.own.num_prototypes=0 is invalid"),
        ({"own": {"num_prototypes": 4, "weights": {"speed": float("inf")}}}, "weights.speed=inf is invalid"),
        ({"own": {"num_prototypes": 4, "weights": {"heading": 1.0}}}, "weights.heading names no feature"),
        ({"own": {"num_prototypes": 4, "size": 3}}, "vq.factors.own.size is unknown"),
        ({"neighbour": {"num_prototypes": 4}}, "vq.factors.own is missing"),
        ({"own": 5}, r"vq.factors.own=5 is invalid"),
        ([1, 2], r"vq.factors=\[1, 2\] is invalid"),
    ],
)
def test_bad_factors_are_refused_in_one_line(factors, message):
    with pytest.raises(ValueError, match=message) as info:
        VQSettings.from_config({"per_process": False, "factors": factors})
    assert "\n" not in str(info.value)


def test_factors_need_one_shared_quantizer():
    with pytest.raises(ValueError, match="vq.per_process=true is invalid with vq.factors"):
        VQSettings.from_config({"per_process": True, "factors": {"own": {"num_prototypes": 4}}})


@pytest.mark.skipif(not numba_available(), reason="numba is off (PEDRL_NO_NUMBA)")
def test_the_kernel_encodes_as_the_encoder():
    """:func:`pedrl.vq.factored_kernel.encode_factored_room` against :meth:`StateEncoder.encode` (log distances):
    the same sets but for near-ties of two prototypes (within float32 rounding), which may go either way."""
    from pedrl.vq.factored_kernel import encode_factored

    quantizer = fitted()
    settings = EncoderSettings(num_neighbours=K, num_walls=W, max_distance=10.0, max_speed=1.0,
                               distance_transform="log")  # fmt: skip
    encoder = StateEncoder(settings, quantizer)
    raw, sensed = states(2000, seed=4)
    expected = encoder.encode(raw.view(20, 100, -1), {"num_sensed": sensed.view(20, 100), "decision": 1}, None)
    found = encode_factored(encoder, raw.view(20, 100, -1), sensed.view(20, 100))
    assert found.shape == expected.shape
    assert float((found != expected).any(1).float().mean()) <= 0.002

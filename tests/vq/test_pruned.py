"""The literal encoding's batched search (pedrl.vq.pruned) gives the scan's answer: the float64 nearest prototype
wherever no two distances tie within float32 rounding, the float32 scan's (lowest id) where they do."""

import numpy as np
import pytest
import torch

from pedrl._numba import numba_available
from pedrl.algos.registry import env_factory
from pedrl.vq import Quantizer, pruned
from pedrl.vq.pruned import PrunedIndex
from pedrl.vq.tree import TreeIndex
from tests.vq.test_tree import brute_force, clustered

pytestmark = pytest.mark.skipif(not numba_available(), reason="numba is off (PEDRL_NO_NUMBA)")


def spread(num: int, generator: torch.Generator, dim: int = 28) -> torch.Tensor:
    """States like the literal ones: every column standardised, none dominant."""
    return torch.randn(num, dim, generator=generator)


def scan(prototypes: torch.Tensor, points: torch.Tensor, sets: torch.Tensor | None = None):
    """The float32 scan (the specification's answer, ties included)."""
    index = TreeIndex(prototypes)
    index.scans = True
    return index.search(points, sets)


def clear(points: torch.Tensor, prototypes: torch.Tensor) -> torch.Tensor:
    """Points whose nearest and second-nearest float64 distances differ by more than float32 rounding."""
    distances = ((points.double()[:, None, :] - prototypes.double()[None]) ** 2).sum(-1)
    if distances.shape[1] == 1:
        return torch.ones(points.shape[0], dtype=torch.bool)
    two = distances.topk(2, largest=False).values
    return two[:, 1] - two[:, 0] > 1e-5 * (1.0 + two[:, 1])


def check(prototypes: torch.Tensor, points: torch.Tensor, sets=None, hints=None) -> torch.Tensor:
    """The search's ids: the scan's ids and float32 distances everywhere, float64 brute force's where clear."""
    ids, sq_dist = PrunedIndex(prototypes).search(points, sets, hints)
    expected, expected_dist = scan(prototypes, points, sets)
    assert torch.equal(ids, expected)
    assert torch.equal(sq_dist, expected_dist)
    if prototypes.ndim == 2:
        rows = clear(points, prototypes)
        assert torch.equal(ids[rows], brute_force(points[rows], prototypes)[0])
    return ids


@pytest.mark.parametrize(("num_prototypes", "dim"), [(1, 28), (5, 28), (17, 28), (100, 13), (600, 28), (700, 5)])
@pytest.mark.parametrize("data", ["spread", "clustered"])
def test_the_search_equals_float64_brute_force_and_the_scan(num_prototypes, dim, data):
    generator = torch.Generator().manual_seed(num_prototypes + dim)
    make = spread if data == "spread" else clustered
    prototypes, points = make(num_prototypes, generator, dim=dim), make(400, generator, dim=dim)
    check(prototypes, points)


def test_past_the_pair_budget_the_index_goes_without_its_nearest_lists_and_finds_the_same(monkeypatch):
    """An index whose nearest-prototype lists would take more than GRAPH_MAX_PAIRS pair distances (``T K^2``: 200 000
    prototypes, 14 minutes a set) is built without them, and its answers are the scan's still; built in blocks small
    enough, the lists are those of one block (the control)."""
    generator = torch.Generator().manual_seed(5)
    prototypes, points = spread(600, generator), spread(400, generator)
    hints = torch.randint(600, (400,), generator=generator)
    whole = PrunedIndex(prototypes).kernel_arrays().graph
    monkeypatch.setattr(pruned, "GRAPH_BLOCK_BYTES", 12 * 600 * 7)  # blocks of 7 rows
    assert np.array_equal(PrunedIndex(prototypes).kernel_arrays().graph, whole)
    monkeypatch.setattr(pruned, "GRAPH_MAX_PAIRS", 600 * 600 - 1)
    assert PrunedIndex(prototypes).kernel_arrays().graph.shape == (1, 600, 0)
    assert torch.equal(check(prototypes, points, hints=hints), check(prototypes, points))


def literal_states(agents: int = 20, decisions: int = 40) -> torch.Tensor:
    """Raw states of a random walk in the paper's room, decision after decision: ``(decisions, rooms * agents, 28)``."""
    env = env_factory({"_target_": "pedrl.sim.RoomEnv"}, {"name": "paper_room"})(num_replicas=4, num_agents=agents)
    obs, _ = env.reset(seed=3)
    generator = torch.Generator().manual_seed(3)
    frames = []
    for _ in range(decisions):
        frames.append(obs.reshape(-1, obs.shape[-1]).clone())
        obs, *_ = env.step(torch.randint(env.num_actions, (4, agents), generator=generator))
    return torch.stack(frames)


def test_on_literal_states_from_any_first_guess():
    """States of the paper's room, standardised as the literal presets do (raw distances, weights 1), K = 512: the
    search from each agent's previous prototype (the fused trial's guess), from none and from garbage."""
    states = literal_states()
    quantizer, _ = Quantizer.fit(states[:20].reshape(-1, 28), 512, max_iterations=5)
    points = quantizer.standardise(states[20:]).reshape(-1, 28)
    previous, _ = scan(quantizer.prototypes, quantizer.standardise(states[19:-1]).reshape(-1, 28))
    garbage = torch.randint(-600, 1200, (points.shape[0],), generator=torch.Generator().manual_seed(0))
    answers = [check(quantizer.prototypes, points, hints=hints) for hints in (previous, None, garbage)]
    assert all(torch.equal(answer, answers[0]) for answer in answers)
    assert int(clear(points, quantizer.prototypes).sum()) > 0.95 * points.shape[0]  # brute force checked the most


def test_exact_ties_go_to_the_lowest_id_and_prototypes_themselves_are_found():
    generator = torch.Generator().manual_seed(4)
    base = spread(300, generator)
    prototypes = torch.cat([base, base[:50]])  # ids 300..349 duplicate 0..49
    ids = check(prototypes, prototypes)
    assert torch.equal(ids, torch.cat([torch.arange(300), torch.arange(50)]))


def test_equal_distances_go_to_the_lowest_id_wherever_it_sits():
    """Points at the origin, exactly between two prototypes (+delta and -delta: float32 differences of equal size)
    with the others farther; and the origin among the 56 unit vectors +-e_i, all at distance 1."""
    generator = torch.Generator().manual_seed(5)
    prototypes = 5.0 + spread(400, generator)
    delta = spread(1, generator)[0] * 0.5
    prototypes[150], prototypes[60] = -delta, delta
    ids = check(prototypes, torch.zeros(3, 28))
    assert ids.tolist() == [60, 60, 60]
    axes = torch.cat([torch.eye(28), -torch.eye(28)])[torch.randperm(56, generator=generator)]
    assert check(axes, torch.zeros(2, 28)).tolist() == [0, 0]


def test_near_ties_within_float32_rounding_are_the_scan_s():
    """Pairs of prototypes one float32 ulp apart in one column: their float64 distances differ, their float32 ones
    may tie; either way the id is the scan's."""
    generator = torch.Generator().manual_seed(6)
    base = spread(200, generator)
    twins = base.clone()
    twins[:, 0] = torch.nextafter(base[:, 0], torch.full_like(base[:, 0], 10.0))
    prototypes = torch.cat([twins, base])  # each twin has the lower id
    points = base + 1e-3 * spread(200, generator)
    ids = check(prototypes, points)
    assert bool(((ids == torch.arange(200)) | (ids == torch.arange(200) + 200)).all())


def test_several_sets_nan_and_huge_points():
    generator = torch.Generator().manual_seed(7)
    sets = torch.stack([spread(300, generator), spread(300, generator) + 2.0, clustered(300, generator)])
    points = spread(500, generator)
    points[3] = float("nan")
    points[4, 7] = float("inf")
    points[5] = 1e7  # past the bounds' range: searched by the scan
    which = torch.randint(0, 3, (500,), generator=generator)
    ids = check(sets, points, which)
    assert ids[3] == 0 and ids[4] == 0
    for index in range(3):
        rows = (which == index) & clear(points, sets[index])
        assert torch.equal(ids[rows], brute_force(points[rows], sets[index])[0])


def test_bad_input_is_refused_with_a_message():
    index = PrunedIndex(torch.randn(20, 4))
    with pytest.raises(ValueError, match=r"expected points \(B, 4\)"):
        index.search(torch.randn(3, 5))
    with pytest.raises(ValueError, match=r"sets must be \(3,\) ints in \[0, 1\)"):
        index.search(torch.randn(3, 4), torch.tensor([0, 1, 0]))
    with pytest.raises(ValueError, match="prototypes must be"):
        PrunedIndex(torch.randn(0, 4))


def test_the_encoder_of_a_literal_config_searches_in_batches():
    """A quantizer of literal states (raw distances, weights 1) is scanned, so ``encode_room`` searches its rooms in
    batches (its work counters move), with the ids of the per-agent scan (``encode_agent``)."""
    from pedrl.sim.sensing import MIN_VOID_DISTANCE
    from pedrl.vq.encode_kernel import encode_agent, encode_buffers, encode_room, pack_encoder
    from pedrl.vq.encoder import EncoderSettings, StateEncoder

    states = literal_states(decisions=30)
    quantizer, _ = Quantizer.fit(states[:20].reshape(-1, 28), 600, max_iterations=3)
    encoder = StateEncoder(EncoderSettings(7, 2, 116.6, 2.5), quantizer)
    packed = pack_encoder(encoder, 4)
    assert packed.arrays.scan and packed.pruned.rows.shape[:2] == (1, 600)  # scanned; the batch's rows
    features = states[25].view(4, 20, 28).contiguous().numpy()
    num_sensed = np.full((4, 20), 7, np.int64)
    present = np.ones((4, 20), bool)
    present[1, 3] = present[2, ::2] = False
    base = np.arange(80, dtype=np.int64).reshape(4, 20) * 1000
    settings = encoder.settings.kernel()
    assert settings == (7, np.float32(116.6), np.float32(2.5), np.float32(MIN_VOID_DISTANCE), False, False)
    void = np.zeros((4, 20, 1), np.float32)
    buffers = encode_buffers(20, 28)
    rows = np.full((4, 20), -5, np.int64)  # no usable guess
    for r in range(4):
        encode_room(r, r, present, base, rows, features, num_sensed, void, settings, packed.arrays, packed.tree,
                    packed.pruned, buffers)  # fmt: skip
    leaf_pairs = packed.pruned.first_n.shape[1] // 32
    assert buffers.batch.counts[0] == present.sum() * leaf_pairs  # each present agent met each leaf pair
    for r in range(4):
        for i in range(20):
            expected = base[r, i] + (
                encode_agent(
                    r,
                    i,
                    r,
                    features,
                    num_sensed,
                    void,
                    settings,
                    packed.arrays,
                    packed.tree,
                    buffers.x,
                    buffers.point,
                    buffers.nodes,
                    buffers.sums,
                )  # fmt: skip
                if present[r, i]
                else 0
            )
            assert rows[r, i] == expected

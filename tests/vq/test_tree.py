"""The k-d tree search (pedrl.vq.tree) is exact: the argmin of float64 distances, ties to the lowest id."""

import pytest
import torch

from pedrl.vq import ProcessQuantizers, Quantizer
from pedrl.vq.tree import LEAF_SIZE, TreeIndex


def brute_force(points: torch.Tensor, prototypes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Float64 nearest prototype (``argmin`` returns the first minimum) and its squared distance."""
    distances = ((points.double()[:, None, :] - prototypes.double()[None]) ** 2).sum(-1)
    best, ids = distances.min(1)
    return ids, best


def clustered(num: int, generator: torch.Generator, *, dim: int = 28, scale: float = 4.0) -> torch.Tensor:
    """Points like the room's states: three wide features, the rest narrow."""
    widths = torch.full((dim,), 0.1)
    widths[:3] = scale
    return torch.randn(num, dim, generator=generator) * widths


@pytest.mark.parametrize("num_prototypes", [1, 5, LEAF_SIZE, LEAF_SIZE + 1, 100, 1000])
@pytest.mark.parametrize("data", ["clustered", "isotropic"])
def test_tree_search_equals_float64_brute_force(num_prototypes, data):
    generator = torch.Generator().manual_seed(num_prototypes)
    make = clustered if data == "clustered" else (lambda n, g: torch.randn(n, 28, generator=g))
    prototypes, points = make(num_prototypes, generator), make(500, generator)
    ids, sq_dist = TreeIndex(prototypes).search(points)
    expected_ids, expected_dist = brute_force(points, prototypes)
    assert torch.equal(ids, expected_ids)
    torch.testing.assert_close(sq_dist, expected_dist.float(), rtol=1e-6, atol=1e-6)


def test_ties_go_to_the_lowest_id_and_prototypes_themselves_are_found():
    generator = torch.Generator().manual_seed(0)
    base = clustered(300, generator)
    prototypes = torch.cat([base, base[:50]])  # ids 300..349 duplicate 0..49
    ids, sq_dist = TreeIndex(prototypes).search(prototypes)
    expected = torch.cat([torch.arange(300), torch.arange(50)])
    assert torch.equal(ids, expected)
    assert torch.equal(sq_dist, torch.zeros(350))


def test_several_sets_each_point_searches_its_own():
    generator = torch.Generator().manual_seed(1)
    sets = torch.stack([clustered(200, generator), clustered(200, generator) + 3.0, clustered(200, generator)])
    points = clustered(600, generator)
    which = torch.randint(0, 3, (600,), generator=generator)
    ids, _ = TreeIndex(sets).search(points, which)
    for index in range(3):
        rows = which == index
        assert torch.equal(ids[rows], brute_force(points[rows], sets[index])[0])


def test_bad_input_is_refused_with_a_message():
    tree = TreeIndex(torch.randn(20, 4))
    with pytest.raises(ValueError, match=r"expected points \(B, 4\)"):
        tree.search(torch.randn(3, 5))
    stacked = TreeIndex(torch.randn(2, 20, 4))
    with pytest.raises(ValueError, match=r"sets must be \(3,\) ints in \[0, 2\)"):
        stacked.search(torch.randn(3, 4), torch.tensor([0, 1, 2]))
    with pytest.raises(ValueError, match="prototypes must be"):
        TreeIndex(torch.randn(0, 4))


def test_quantizers_encode_with_the_tree_as_with_the_matrix_search():
    """``precision="auto"`` on the CPU uses the tree; ``"float32"`` the matrix product: the same ids (no ties in
    random data), for one quantizer and for one per process (its trees stacked)."""
    generator = torch.Generator().manual_seed(2)
    states = clustered(4000, generator)
    parts = []
    for seed in range(3):
        fitted, _ = Quantizer.fit(
            states[seed * 1000 : (seed + 2) * 1000], 300, generator=torch.Generator().manual_seed(seed)
        )
        assert fitted.precision == "auto"
        parts.append(fitted)
    queries = clustered(900, generator)
    for part in parts:
        matrix = Quantizer(mean=part.mean, std=part.std, prototypes=part.prototypes, precision="float32")
        assert torch.equal(part.encode(queries), matrix.encode(queries))
        assert part._tree is not None  # the tree did the work
    per_process = ProcessQuantizers(parts)
    process = torch.arange(3).repeat_interleave(300)
    expected = torch.cat([part.encode(queries[process == p]) for p, part in enumerate(parts)])
    assert torch.equal(per_process.encode(queries), expected)  # the trainers' layout: 300 rows per process
    shuffled = torch.randperm(900, generator=generator)
    assert torch.equal(per_process.encode(queries[shuffled], process=process[shuffled]), expected[shuffled])


@pytest.mark.parametrize("data", ["clustered", "isotropic"])
def test_the_leaf_scan_gives_the_tree_search_s_answers(data):
    """``scans`` searches by a scan of every leaf: the same ids and float32 distances, ties included; the tree
    chooses it for states spread over all 28 columns (its splits then use them all), not for nearly 3-D ones."""
    generator = torch.Generator().manual_seed(7)
    make = clustered if data == "clustered" else (lambda n, g: torch.randn(n, 28, generator=g))
    prototypes = make(1000, generator)
    prototypes = torch.cat([prototypes, prototypes[:40]])  # ties: ids 1000.. duplicate 0..39
    points = torch.cat([make(400, generator), prototypes[:40]])
    index = TreeIndex(prototypes)
    assert index.scans == (data == "isotropic")
    answers = []
    for scans in (False, True):
        index.scans = scans
        answers.append(index.search(points))
    assert torch.equal(answers[0][0], answers[1][0]) and torch.equal(answers[0][1], answers[1][1])
    assert torch.equal(answers[1][0], brute_force(points, prototypes)[0])

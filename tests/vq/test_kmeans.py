"""k-means and nearest-prototype search against brute-force references."""

import pytest
import torch

from pedrl.vq.kmeans import PrototypeIndex, cpu_has_native_bfloat16, kmeans, kmeans_plus_plus, nearest_prototype

PRECISIONS = ["float32", "bfloat16"]


def brute_force(points: torch.Tensor, prototypes: torch.Tensor) -> torch.Tensor:
    """`(B, K)` squared distances in float64 (the reference)."""
    return torch.cdist(points.double(), prototypes.double()).square()


def assert_nearest(points, prototypes, ids, sq_dist, *, rtol=1e-5):
    """`ids` are nearest prototypes up to float32 ties, and `sq_dist` are their squared distances."""
    reference = brute_force(points, prototypes)
    best = reference.min(1).values
    chosen = reference.gather(1, ids[:, None]).squeeze(1)
    slack = rtol * (1.0 + best)
    assert bool((chosen <= best + slack).all()), "a point was not assigned to a nearest prototype"
    torch.testing.assert_close(sq_dist.double(), chosen, rtol=1e-4, atol=1e-4)


def mixture(num_points, dim, num_components, *, spread=0.3, seed=0):
    generator = torch.Generator().manual_seed(seed)
    centres = 4.0 * torch.randn(num_components, dim, generator=generator)
    component = torch.randint(num_components, (num_points,), generator=generator)
    return centres[component] + spread * torch.randn(num_points, dim, generator=generator), centres, component


@pytest.mark.parametrize("precision", PRECISIONS)
@pytest.mark.parametrize(("num_points", "dim", "num_prototypes"), [(700, 28, 600), (300, 5, 1000), (50, 3, 7)])
def test_nearest_prototype_matches_brute_force(precision, num_points, dim, num_prototypes):
    generator = torch.Generator().manual_seed(num_points)
    points = torch.randn(num_points, dim, generator=generator)
    prototypes = torch.randn(num_prototypes, dim, generator=generator)
    ids, sq_dist = nearest_prototype(points, prototypes, precision=precision, chunk_size=128)
    assert ids.dtype == torch.int64 and sq_dist.dtype == torch.float32
    assert ids.shape == sq_dist.shape == (num_points,)
    assert_nearest(points, prototypes, ids, sq_dist)


@pytest.mark.parametrize("precision", PRECISIONS)
def test_nearest_prototype_hard_cases(precision):
    generator = torch.Generator().manual_seed(1)
    # Far from the origin with a small spread (the matrix form needs centring), duplicated prototypes
    # (ties go to the lowest index) and points sitting exactly on prototypes.
    prototypes = 50.0 + 0.05 * torch.randn(800, 12, generator=generator)
    prototypes = torch.cat([prototypes, prototypes[:100]])
    points = torch.cat(
        [prototypes[torch.randint(800, (200,), generator=generator)], 50.0 + 0.05 * torch.randn(300, 12)]
    )
    ids, sq_dist = nearest_prototype(points, prototypes, precision=precision)
    assert_nearest(points, prototypes, ids, sq_dist)
    assert bool((ids < 800).all()), "ties must go to the lowest index"
    assert bool((sq_dist[:200] < 1e-6).all())


def test_precisions_agree_and_auto_is_exact():
    points, _, _ = mixture(3000, 28, 50, seed=3)
    prototypes = points[:1024] + 0.01
    ids32, dist32 = nearest_prototype(points, prototypes, precision="float32")
    ids16, dist16 = nearest_prototype(points, prototypes, precision="bfloat16")
    idsauto, _ = nearest_prototype(points, prototypes)
    reference = brute_force(points, prototypes)
    for ids in (ids32, ids16, idsauto):
        assert_nearest(points, prototypes, ids, reference.gather(1, ids[:, None]).squeeze(1).float())
    assert float((ids32 == ids16).float().mean()) > 0.999
    # float32 returns ||x||^2 + (||c||^2 - 2 x.c), bfloat16 the direct sum((x - c)^2): equal up to rounding.
    torch.testing.assert_close(dist32, dist16, rtol=1e-4, atol=1e-3)


def test_auto_precision_choice():
    prototypes = torch.randn(1024, 4)
    index = PrototypeIndex(prototypes)
    assert index.precision == ("bfloat16" if cpu_has_native_bfloat16() else "float32")
    assert PrototypeIndex(torch.randn(16, 4)).precision == "float32"


@pytest.mark.parametrize("precision", PRECISIONS)
def test_chunked_equals_unchunked(precision):
    points, _, _ = mixture(600, 28, 40, seed=4)
    prototypes = torch.randn(700, 28, generator=torch.Generator().manual_seed(5))
    whole = nearest_prototype(points, prototypes, precision=precision, chunk_size=10_000)
    ids, sq_dist = nearest_prototype(points[:40], prototypes, precision=precision, chunk_size=1)
    assert torch.equal(ids, whole[0][:40])
    torch.testing.assert_close(sq_dist, whole[1][:40])
    for chunk_size in (97, 256):
        ids, sq_dist = nearest_prototype(points, prototypes, precision=precision, chunk_size=chunk_size)
        assert torch.equal(ids, whole[0])
        torch.testing.assert_close(sq_dist, whole[1])


def test_empty_batch():
    ids, sq_dist = nearest_prototype(torch.zeros(0, 3), torch.randn(5, 3))
    assert ids.shape == sq_dist.shape == (0,)


@pytest.mark.parametrize("precision", PRECISIONS)
def test_kmeans_labels_are_nearest_and_distortion_non_increasing(precision):
    data, _, _ = mixture(2500, 28, 30, spread=1.0, seed=6)
    result = kmeans(data, 520, max_iterations=5, tolerance=0.0, precision=precision, chunk_size=700)
    assert result.prototypes.shape == (520, 28)
    assert result.labels.shape == (2500,) and result.labels.dtype == torch.int64
    assert len(result.distortion) == result.iterations + 1
    assert result.iterations == 5 and not result.converged
    reference = brute_force(data, result.prototypes)
    chosen = reference.gather(1, result.labels[:, None]).squeeze(1)
    best = reference.min(1).values
    assert bool((chosen <= best + 1e-5 * (1 + best)).all())
    assert result.distortion[-1] == pytest.approx(float(best.mean()), rel=1e-4)
    for before, after in zip(result.distortion, result.distortion[1:], strict=False):
        assert after <= before * (1 + 1e-6)


def test_kmeans_recovers_planted_clusters():
    data, centres, component = mixture(3000, 6, 8, spread=0.05, seed=7)
    result = kmeans(data, 8, generator=torch.Generator().manual_seed(0), max_iterations=50, tolerance=1e-6)
    assert result.converged
    # Every planted centre has a prototype next to it, and the partition is the planted one.
    distance = torch.cdist(centres, result.prototypes)
    assert float(distance.min(1).values.max()) < 0.05
    matched = distance.argmin(1)
    assert torch.equal(matched[component], result.labels)
    assert result.distortion[-1] == pytest.approx(6 * 0.05**2, rel=0.1)


def test_kmeans_empty_cluster_is_reseeded():
    data, _, _ = mixture(2000, 4, 5, spread=0.5, seed=8)
    # Prototypes 3 and 4 start far away from every point: they get no point in the first assignment.
    init = torch.cat([data[:3], torch.full((2, 4), 1e3)])
    result = kmeans(data, 5, init=init, max_iterations=1, tolerance=0.0)
    assert result.prototypes.shape == (5, 4)
    assert bool(torch.isfinite(result.prototypes).all())
    assert bool((result.prototypes.abs() < 1e2).all()), "empty clusters must be moved onto data points"
    assert result.distortion[1] <= result.distortion[0]
    longer = kmeans(data, 5, init=init, max_iterations=20, tolerance=0.0)
    assert torch.bincount(longer.labels, minlength=5).min() > 0
    for before, after in zip(longer.distortion, longer.distortion[1:], strict=False):
        assert after <= before * (1 + 1e-6)


def test_kmeans_is_deterministic_for_a_seed():
    data, _, _ = mixture(2000, 10, 20, spread=1.0, seed=9)
    first = kmeans(data, 64, generator=torch.Generator().manual_seed(42), max_iterations=5)
    second = kmeans(data, 64, generator=torch.Generator().manual_seed(42), max_iterations=5)
    other = kmeans(data, 64, generator=torch.Generator().manual_seed(43), max_iterations=5)
    assert torch.equal(first.prototypes, second.prototypes)
    assert torch.equal(first.labels, second.labels)
    assert first.distortion == second.distortion
    assert not torch.equal(first.prototypes, other.prototypes)


def test_kmeans_random_init_and_tolerance_stop():
    data, _, _ = mixture(1500, 5, 10, spread=0.5, seed=10)
    result = kmeans(data, 10, init="random", max_iterations=200, tolerance=1e-3)
    assert result.converged and result.iterations < 200
    previous, last = result.distortion[-2], result.distortion[-1]
    assert (previous - last) / previous < 1e-3


def test_kmeans_fewer_distinct_points_than_prototypes_warns_and_shrinks():
    distinct = torch.tensor([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [5.0, 5.0], [2.0, 3.0]])
    data = distinct.repeat(40, 1)
    for init in ("kmeans++", "random"):
        with pytest.warns(UserWarning, match="only 5 distinct points"):
            result = kmeans(data, 8, init=init)
        assert result.prototypes.shape == (5, 2)
        assert result.distortion[-1] == pytest.approx(0.0, abs=1e-10)
        assert torch.equal(torch.unique(result.prototypes, dim=0), torch.unique(distinct, dim=0))


def test_kmeans_plus_plus_seeds_are_distinct_data_points():
    data, _, _ = mixture(500, 3, 5, seed=11)
    seeds = kmeans_plus_plus(data, 50, generator=torch.Generator().manual_seed(0))
    assert seeds.shape == (50, 3)
    assert torch.unique(seeds, dim=0).shape[0] == 50
    assert bool((seeds[:, None, :] == data[None, :, :]).all(2).any(1).all())


def test_kmeans_rejects_bad_arguments():
    with pytest.raises(ValueError):
        kmeans(torch.zeros(0, 3), 2)
    with pytest.raises(ValueError):
        kmeans(torch.randn(10, 3), 0)
    with pytest.raises(ValueError):
        kmeans(torch.randn(10, 3), 2, init=torch.zeros(3, 3))
    with pytest.raises(ValueError):
        nearest_prototype(torch.randn(4, 3), torch.randn(2, 3), precision="float16")

"""The same answers on CUDA (skipped without a GPU)."""

import pytest
import torch

from pedrl.rl import epsilon_greedy, td_update, zeros_q_values
from pedrl.vq import Quantizer, UnionQuantizer
from pedrl.vq.kmeans import kmeans, nearest_prototype

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")


def test_nearest_prototype_and_kmeans_on_cuda():
    generator = torch.Generator().manual_seed(0)
    points = torch.randn(3000, 28, generator=generator)
    prototypes = torch.randn(600, 28, generator=generator)
    ids_cpu, _ = nearest_prototype(points, prototypes, precision="float32")
    ids_cuda, sq_dist = nearest_prototype(points.cuda(), prototypes.cuda(), precision="bfloat16")
    assert ids_cuda.device.type == "cuda" and sq_dist.device.type == "cuda"
    assert float((ids_cuda.cpu() == ids_cpu).float().mean()) > 0.999
    result = kmeans(points.cuda(), 64, generator=torch.Generator(device="cuda").manual_seed(0), max_iterations=5)
    assert result.prototypes.device.type == "cuda"
    for before, after in zip(result.distortion, result.distortion[1:], strict=False):
        assert after <= before * (1 + 1e-6)


def test_quantizers_and_q_learning_on_cuda():
    data = torch.randn(1000, 6, generator=torch.Generator().manual_seed(1)).cuda()
    quantizer, _ = Quantizer.fit(data, 32, generator=torch.Generator(device="cuda").manual_seed(0), max_iterations=3)
    assert torch.equal(quantizer.encode(data).cpu(), quantizer.to("cpu").encode(data.cpu()))
    union = UnionQuantizer().unite(0, torch.arange(6, device="cuda"), quantizer)
    ids = union.encode(data, torch.zeros(1000, dtype=torch.int64, device="cuda"))
    assert ids.device.type == "cuda"
    q_values = zeros_q_values(2, 2, 32, device="cuda")
    generator = torch.Generator(device="cuda").manual_seed(0)
    rows = ids[:100]
    actions = epsilon_greedy(q_values, rows, 0.2, generator)
    td = td_update(
        q_values,
        rows,
        actions,
        torch.ones(100, device="cuda"),
        ids[100:200],
        torch.zeros(100, dtype=torch.bool, device="cuda"),
        torch.ones(100, dtype=torch.bool, device="cuda"),
        alpha=0.5,
        gamma=0.9,
    )
    assert td.device.type == "cuda" and float(q_values.sum()) > 0

"""k-means and encode benchmark: pedrl against scikit-learn and faiss-cpu on the same data and initial centroids.

Metrics (all wall-clock, best of `repeats`; keys prefixed `kmeans_` in the returned dict):
    - `seconds_per_iteration`: marginal cost of one Lloyd iteration (assignment of every point plus centroid
      update), measured as `(T(n2) - T(n1)) / (n2 - n1)` for runs of `n1` and `n2` iterations, so set-up, the
      initial assignment and final passes cancel out.
    - `ratio_pedrl_over_faiss`, `ratio_pedrl_over_sklearn`: pedrl time / other time (below 1: pedrl is faster).
    - `encode_states_per_second`: `Quantizer.encode` throughput for a batch of `encode_batch` states (every agent
      of every room is encoded at every decision of training).

scikit-learn and faiss are optional (`pip install pedrl[bench]`); when missing, their entries are None and
`kmeans_skipped` says why. Run: `python -m pedrl.bench.kmeans [--quick]`.
"""

from __future__ import annotations

import functools
import json
import math
import time
import warnings
from collections.abc import Callable

import torch

from pedrl.vq.kmeans import PrototypeIndex, kmeans
from pedrl.vq.quantizer import Quantizer

__all__ = ["mixture_data", "run"]


def mixture_data(
    num_points: int, dim: int, *, num_components: int, generator: torch.Generator, device: torch.device | str
) -> torch.Tensor:
    """Standardised mixture-of-Gaussians data, `(num_points, dim)` float32.

    Component centres are N(0, 3^2 I), points are centre + N(0, I), then every feature is standardised, as the
    quantiser does with real states.
    """
    centres = 3.0 * torch.randn(num_components, dim, generator=generator, device=device)
    component = torch.randint(num_components, (num_points,), generator=generator, device=device)
    points = centres[component] + torch.randn(num_points, dim, generator=generator, device=device)
    return (points - points.mean(0)) / points.std(0)


def _best_time(function: Callable[[], object], repeats: int) -> float:
    best = math.inf
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        best = min(best, time.perf_counter() - start)
    return best


def run(*, quick: bool = False, device: str = "cpu", repeats: int = 3) -> dict:
    """Runs the benchmark and returns a JSON-serialisable dict.

    The libraries are timed in turn within each of `repeats` rounds and the best time of each is kept, so a
    machine shared with other jobs slows them alike.

    Args:
        quick: small problem (N = 20k, K = 512) for smoke tests; the full one is N = 200k, d = 28, K = 4096.
        device: torch device for pedrl (scikit-learn and faiss always run on CPU).
        repeats: rounds; timings are the best of this many.

    Returns:
        `{"kmeans_config": ..., "kmeans_seconds_per_iteration": {"pedrl", "sklearn", "faiss"},
        "kmeans_ratio_pedrl_over_faiss", "kmeans_ratio_pedrl_over_sklearn", "kmeans_skipped": {name: reason},
        "encode_states_per_second"}`.
    """
    num_points, dim, num_prototypes = (20_000, 28, 512) if quick else (200_000, 28, 4096)
    low, high = (2, 4) if quick else (3, 8)
    encode_batch = 8000
    generator = torch.Generator(device=device).manual_seed(0)
    data = mixture_data(num_points, dim, num_components=256, generator=generator, device=device)
    start_index = torch.randperm(num_points, generator=generator, device=device)[:num_prototypes]
    initial = data[start_index].clone()
    skipped: dict[str, str] = {}
    runners = _runners(data, initial, num_prototypes=num_prototypes, device=device, skipped=skipped)
    seconds = _seconds_per_iteration(runners, low=low, high=high, repeats=repeats)
    encode_seconds = _encode_seconds(data[:encode_batch], initial, device=device, repeats=repeats)

    def ratio(other: str) -> float | None:
        value = seconds.get(other)
        return seconds["pedrl"] / value if value else None

    return {
        "kmeans_config": {
            "num_points": num_points,
            "dim": dim,
            "num_prototypes": num_prototypes,
            "iterations": [low, high],
            "device": device,
            "torch_threads": torch.get_num_threads(),
            "precision": PrototypeIndex(initial).precision,
            "encode_batch": encode_batch,
        },
        "kmeans_seconds_per_iteration": seconds,
        "kmeans_ratio_pedrl_over_faiss": ratio("faiss"),
        "kmeans_ratio_pedrl_over_sklearn": ratio("sklearn"),
        "kmeans_skipped": skipped,
        "encode_states_per_second": encode_batch / encode_seconds,
    }


def _sync(device: str) -> None:
    if torch.device(device).type == "cuda":
        torch.cuda.synchronize()


def _runners(
    data: torch.Tensor, initial: torch.Tensor, *, num_prototypes: int, device: str, skipped: dict[str, str]
) -> dict[str, Callable[[int], None]]:
    """One k-means run of `n` iterations per library installed, from the same data and initial centroids; the
    libraries missing go to `skipped` with the reason."""
    num_points, dim = data.shape
    data_cpu = data.cpu().numpy()
    initial_cpu = initial.cpu().numpy()

    def run_pedrl(n: int) -> None:
        kmeans(data, num_prototypes, max_iterations=n, tolerance=0.0, init=initial)
        _sync(device)

    runners: dict[str, Callable[[int], None]] = {"pedrl": run_pedrl}
    try:
        from sklearn.cluster import KMeans
    except ImportError as error:
        skipped["sklearn"] = f"scikit-learn not installed ({error})"
    else:

        def run_sklearn(n: int) -> None:
            model = KMeans(
                n_clusters=num_prototypes, init=initial_cpu, n_init=1, max_iter=n, tol=0.0, algorithm="lloyd"
            )
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # e.g. "fewer distinct clusters" on the quick problem
                model.fit(data_cpu)

        runners["sklearn"] = run_sklearn
    try:
        import faiss
    except ImportError as error:
        skipped["faiss"] = f"faiss-cpu not installed ({error})"
    else:

        def run_faiss(n: int) -> None:
            model = faiss.Kmeans(
                dim,
                num_prototypes,
                niter=n,
                verbose=False,
                seed=0,
                max_points_per_centroid=num_points,  # no subsampling: the same data as the others
                min_points_per_centroid=1,
            )
            model.train(data_cpu, init_centroids=initial_cpu)

        runners["faiss"] = run_faiss
    return runners


def _seconds_per_iteration(
    runners: dict[str, Callable[[int], None]], *, low: int, high: int, repeats: int
) -> dict[str, float | None]:
    """The marginal time of one iteration of each runner, `(T(high) - T(low)) / (high - low)` of the best times;
    None for the libraries without a runner."""
    best = {(name, n): math.inf for name in runners for n in (low, high)}
    for name in runners:
        runners[name](low)  # warm-up (JIT kernels, allocations)
    for _ in range(repeats):
        for name, runner in runners.items():
            for n in (low, high):
                best[name, n] = min(best[name, n], _best_time(functools.partial(runner, n), 1))
    seconds: dict[str, float | None] = {name: None for name in ("pedrl", "sklearn", "faiss")}
    for name in runners:
        seconds[name] = max(best[name, high] - best[name, low], 0.0) / (high - low)
    return seconds


def _encode_seconds(states: torch.Tensor, prototypes: torch.Tensor, *, device: str, repeats: int) -> float:
    """The best time of `Quantizer.encode` of `states` with the identity standardisation and `prototypes`."""
    dim = states.shape[1]
    quantizer = Quantizer(
        mean=torch.zeros(dim, device=device),
        std=torch.ones(dim, device=device),
        prototypes=prototypes,
    )

    def encode() -> None:
        quantizer.encode(states)
        _sync(device)

    encode()
    return _best_time(encode, max(repeats, 5))


def main() -> None:
    """Command line: prints the result of `run` as JSON."""
    from pedrl.common.commands import OneLineParser, integer_arg

    parser = OneLineParser(prog="python -m pedrl.bench.kmeans", description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small problem")
    parser.add_argument("--device", default="cpu", choices=("cpu", "cuda"))
    parser.add_argument("--repeats", type=integer_arg(1, 1000), default=3)
    arguments = parser.parse_args()
    print(json.dumps(run(quick=arguments.quick, device=arguments.device, repeats=arguments.repeats), indent=2))


if __name__ == "__main__":
    main()

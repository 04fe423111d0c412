"""Literal encoding benchmark: the nearest prototype of the literal presets' states, by the scan against the batched
search of :mod:`pedrl.vq.pruned`, at one thread (both kernels are serial).

The states are those of a random walk in the paper's room (rooms of 20 agents), standardised as the literal presets
do (raw distances, every weight 1) by a quantizer of ``K`` prototypes fitted on their first half; the second half is
searched decision by decision, as the fused trial does: the scan state by state (:func:`pedrl.vq.tree.scan_point`,
the path of the literal presets before the batched search), the batched search room by room, each agent from its
previous decision's prototype. Beside them, the matrix product that a BLAS library offers for the same search
(``|q|^2 - 2 x . q`` by ``torch.addmm``, then ``argmin``), per room (20 states, as each process of a literal run
has its own quantizer) and per decision (every room at once): its time, and how often float32 rounding of that
expanded form gives another id than the scan (an exact search built on it must recheck those near-ties).

Metrics (keys of the returned dict, best of ``repeats``):
    - ``literal_config``: rooms, agents, decisions, ``K``, states searched;
    - ``literal_us_per_state``: ``{"scan", "pruned", "matmul_room", "matmul_decision"}`` microseconds per state,
      and ``literal_speedup`` (scan / pruned);
    - ``literal_work``: per state, the leaf pairs met (all), the leaves of the second and third passes (what the
      bounds left) and the exact distances taken;
    - ``literal_same_ids``: whether the scan and the batched search gave the same ids (they must);
    - ``literal_matmul_other_ids``: the fraction of states whose matrix-product id differs from the scan's.

Run: ``python -m pedrl.bench.literal [--quick]`` or ``python -m pedrl.bench --only literal``.
"""

from __future__ import annotations

import json
import math
import time

import numpy as np
import torch

from pedrl._numba import cached_njit
from pedrl.vq.pruned import PrunedIndex, batch_scratch
from pedrl.vq.pruned_kernel import prepare_batch, search_batch
from pedrl.vq.quantizer import Quantizer
from pedrl.vq.tree import TreeIndex, scan_point

__all__ = ["literal_states", "run"]

AGENTS = 20


def literal_states(rooms: int, decisions: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """Raw states ``(decisions, rooms, AGENTS, 28)`` of a random walk in the paper's room and who is in it."""
    from pedrl.algos.registry import env_factory

    env = env_factory({"_target_": "pedrl.sim.RoomEnv"}, {"name": "paper_room"})(num_replicas=rooms, num_agents=AGENTS)
    obs, _ = env.reset(seed=seed)
    generator = torch.Generator().manual_seed(seed)
    frames, present = [], []
    for _ in range(decisions):
        frames.append(obs.clone())
        present.append(env.active.clone())
        obs, *_ = env.step(torch.randint(env.num_actions, (rooms, AGENTS), generator=generator))
    return torch.stack(frames), torch.stack(present)


@cached_njit(nogil=True)
def _scan_all(points, present, prototypes, ids_of, out):
    sums = np.empty(16, np.float32)
    for d in range(points.shape[0]):
        for r in range(points.shape[1]):
            for i in range(points.shape[2]):
                if present[d, r, i]:
                    out[d, r, i], _ = scan_point(points[d, r, i], 0, prototypes, ids_of, sums)


@cached_njit(nogil=True)
def _search_all(points, present, index, scratch, counts, out):
    """Room by room and decision by decision, each agent from its previous prototype (``out`` holds -1 first)."""
    batch = np.empty((points.shape[2], points.shape[3]), np.float32)
    hints, agents = np.empty(points.shape[2], np.int64), np.empty(points.shape[2], np.int64)
    for d in range(points.shape[0]):
        for r in range(points.shape[1]):
            n = 0
            for i in range(points.shape[2]):
                if present[d, r, i]:
                    batch[n] = points[d, r, i]
                    hints[n] = out[d - 1, r, i] if d > 0 else -1
                    agents[n] = i
                    n += 1
            prepare_batch(batch, n, hints, 0, index, scratch)
            search_batch(batch, n, 0, index, scratch, counts)
            for a in range(n):
                out[d, r, agents[a]] = scratch.best_id[a]  # no state here is NaN or huge (left to the scan)


def run(*, quick: bool = False, repeats: int = 3) -> dict:
    """The benchmark (module docstring): K = 4096 on 20 rooms x 200 decisions (quick: K = 512, 4 rooms x 60)."""
    rooms, decisions, prototypes = (4, 60, 512) if quick else (20, 200, 4096)
    raw, present = literal_states(rooms, decisions)
    half = decisions // 2
    fitted = raw[:half][present[:half]]
    quantizer, _ = Quantizer.fit(fitted, prototypes, max_iterations=5, generator=torch.Generator().manual_seed(0))
    tree, pruned = TreeIndex(quantizer.prototypes), PrunedIndex(quantizer.prototypes)
    order = torch.from_numpy(tree.columns[0])
    points = np.ascontiguousarray(quantizer.standardise(raw[half:])[..., order].numpy())
    mask = np.ascontiguousarray(present[half:].numpy())
    old, new = np.full(mask.shape, -1, np.int64), np.full(mask.shape, -1, np.int64)
    counts = np.zeros(4, np.int64)
    scratch = batch_scratch(AGENTS, points.shape[-1])
    best = {"scan": math.inf, "pruned": math.inf}
    for _ in range(repeats + 1):  # the first round compiles
        tic = time.perf_counter()
        _scan_all(points, mask, tree.kernel_arrays().prototypes, tree.kernel_arrays().ids_of, old)
        best["scan"] = min(best["scan"], time.perf_counter() - tic)
        counts[:] = 0
        new[:] = -1
        tic = time.perf_counter()
        _search_all(points, mask, pruned.kernel_arrays(), scratch, counts, new)
        best["pruned"] = min(best["pruned"], time.perf_counter() - tic)
    product, other = _matmul(quantizer, raw[half:], repeats)
    states = int(mask.sum())
    per_state = {name: seconds / states * 1e6 for name, seconds in best.items()}
    per_state |= product
    work = counts / states
    return {
        "literal_config": {
            "rooms": rooms,
            "agents": AGENTS,
            "decisions": decisions - half,
            "states": states,
            "prototypes": prototypes,
        },  # fmt: skip
        "literal_us_per_state": per_state,
        "literal_speedup": per_state["scan"] / per_state["pruned"],
        "literal_work": {
            "leaf_pairs": work[0],
            "second_pass_leaves": work[1],
            "third_pass_leaves": work[2],
            "exact_distances": work[3],
        },  # fmt: skip
        "literal_same_ids": bool(np.array_equal(old[mask], new[mask])),
        "literal_matmul_other_ids": float(np.mean(other.numpy()[mask] != old[mask])),
    }


def _matmul(quantizer: Quantizer, raw: torch.Tensor, repeats: int) -> tuple[dict[str, float], torch.Tensor]:
    """Microseconds per state of ``argmin(|q|^2 - 2 x . q)`` by room and by decision (every state of the batch
    counted, present or not), and its ids ``(decisions, rooms, agents)``."""
    points = quantizer.standardise(raw).to(torch.float32).contiguous()
    prototypes = quantizer.prototypes.to(torch.float32)
    norms, columns = (prototypes * prototypes).sum(1), prototypes.t().contiguous()
    decisions, rooms = points.shape[:2]
    ids = torch.empty(points.shape[:3], dtype=torch.int64)
    timing, threads = {}, torch.get_num_threads()
    torch.set_num_threads(1)  # as the numba kernels
    for name, batches in (
        ("matmul_room", points.reshape(decisions * rooms, AGENTS, -1)),
        ("matmul_decision", points.reshape(decisions, rooms * AGENTS, -1)),
    ):
        out, found = torch.empty(batches.shape[1], norms.shape[0]), ids.view(len(batches), -1)
        best = math.inf
        for _ in range(repeats + 1):
            tic = time.perf_counter()
            for index, batch in enumerate(batches):
                torch.addmm(norms, batch, columns, beta=1, alpha=-2, out=out)
                found[index] = out.argmin(1)
            best = min(best, time.perf_counter() - tic)
        timing[name] = best / ids.numel() * 1e6
    torch.set_num_threads(threads)
    return timing, ids


def main() -> None:
    """Command line: prints the result of `run` as JSON."""
    from pedrl.common.commands import OneLineParser, integer_arg

    parser = OneLineParser(prog="python -m pedrl.bench.literal", description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small problem")
    parser.add_argument("--repeats", type=integer_arg(1, 1000), default=3)
    arguments = parser.parse_args()
    print(json.dumps(run(quick=arguments.quick, repeats=arguments.repeats), indent=2))


if __name__ == "__main__":
    main()

"""Generalized Lloyd algorithm (k-means) and exact nearest-prototype search, in torch on CPU or CUDA.

The paper (section 3) finds the prototypes of its vector quantiser with the Generalized Lloyd Algorithm; this
module is that algorithm, sized for data sets of up to about a million 28-feature states and `K = 4096`
prototypes on a small CPU.

Distances are squared Euclidean. The nearest-prototype search (`PrototypeIndex`) uses the matrix form
`||x - c||^2 = ||x||^2 + (||c||^2 - 2 x . c)`, one matrix product per block of `chunk_size` rows, so the `(B, K)`
distance matrix is never materialised: memory is `O(chunk_size * K)`, not `O(B * K)`. On CPUs with bfloat16
instructions the product runs in bfloat16 as a certified filter followed by an exact float32 re-ranking; the
result is exact either way. Ties (equal computed distances) go to the lowest prototype index.
"""

from __future__ import annotations

import functools
import math
import warnings
from dataclasses import dataclass
from typing import Literal

import torch

__all__ = [
    "KMeansResult",
    "Precision",
    "PrototypeIndex",
    "cpu_has_native_bfloat16",
    "default_chunk_size",
    "kmeans",
    "kmeans_plus_plus",
    "nearest_prototype",
]

#: Rows per block on CPU: a `(512, 4096)` float32 score block (8 MiB) measured fastest on a 2-core EPYC.
CPU_CHUNK_SIZE = 512
#: Rows per block of the bfloat16 CPU search (its per-block overhead is larger).
BF16_CHUNK_SIZE = 1024
#: Rows per block on CUDA, where larger blocks keep the device busy.
CUDA_CHUNK_SIZE = 16384
#: Group width of the two-level minimum of the float32 CPU search (see `_block_argmin`).
MIN_GROUP_SIZE = 128
#: The bfloat16 search views a `(n, K)` block as `(n, BF16_CLASS_SIZE, K / BF16_CLASS_SIZE)` (see `PrototypeIndex`).
BF16_CLASS_SIZE = 16
#: The bfloat16 search falls back to float32 for a block with more candidates than this per row (on average).
BF16_MAX_CANDIDATES_PER_ROW = 256
#: `precision="auto"` uses bfloat16 only from this many prototypes on (below it float32 is as fast) ...
BF16_MIN_PROTOTYPES = 512
#: ... and for searches of at least this many points (below it the fixed cost of the filter dominates).
BF16_MIN_POINTS = 512
#: Rows converted to float64 at a time when summing clusters (bounds the temporary memory).
SUM_CHUNK_SIZE = 65536
#: Default number of points k-means++ seeds from, per prototype (`init_sample_size = this * K`).
INIT_SAMPLES_PER_PROTOTYPE = 8

Precision = Literal["auto", "float32", "bfloat16"]

# Unit roundoffs used by the error bound of the bfloat16 search.
_U_IN = 2.0**-8  # float32 -> bfloat16 round-to-nearest, as torch converts the inputs
_U_OUT = 2.0**-7  # bfloat16 output of the product: allows for truncation as well as rounding
_U_OUT1 = _U_OUT / (1.0 - _U_OUT)
_U_ACC = 2.0**-24  # float32 accumulation; a sum of n terms errs by at most about n * _U_ACC of their magnitudes

_WORKSPACES: dict[tuple[str, torch.dtype], torch.Tensor] = {}


def _workspace(rows: int, cols: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """A reusable `(rows, cols)` scratch block.

    Allocating a fresh multi-MiB block per call costs page faults comparable to the search itself, so one buffer
    per (device, dtype) is kept and grown on demand. Not thread-safe; the returned block is overwritten by the
    next search on the same device.
    """
    key = (str(device), dtype)
    buffer = _WORKSPACES.get(key)
    if buffer is None or buffer.numel() < rows * cols:
        buffer = torch.empty(rows * cols, dtype=dtype, device=device)
        _WORKSPACES[key] = buffer
    return buffer[: rows * cols].view(rows, cols)


@functools.cache
def cpu_has_native_bfloat16() -> bool:
    """True if this CPU has bfloat16 dot-product instructions (AVX512-BF16 or AMX-BF16; Linux only)."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as cpuinfo:
            flags = cpuinfo.read()
    except OSError:
        return False
    return " avx512_bf16" in flags or " amx_bf16" in flags


def default_chunk_size(device: torch.device | str) -> int:
    """Rows per block for `nearest_prototype` on `device`.

    Args:
        device: where the search runs.

    Returns:
        `CPU_CHUNK_SIZE` on CPU, `CUDA_CHUNK_SIZE` elsewhere.
    """
    return CPU_CHUNK_SIZE if torch.device(device).type == "cpu" else CUDA_CHUNK_SIZE


@dataclass(frozen=True)
class KMeansResult:
    """Outcome of `kmeans`.

    Attributes:
        prototypes: `(K, d)` float32, the final prototypes (centroids).
        labels: `(M,)` int64, index of the nearest prototype of every point, for the final prototypes.
        distortion: mean squared distance from a point to its prototype, one value per assignment step:
            `distortion[0]` is for the initial prototypes, `distortion[t]` after `t` centroid updates.
            Non-increasing (up to float32 rounding).
        iterations: number of centroid updates performed (`len(distortion) - 1`).
        converged: True if the relative decrease of the distortion fell below `tolerance` before the cap.
    """

    prototypes: torch.Tensor
    labels: torch.Tensor
    distortion: list[float]
    iterations: int
    converged: bool


def _block_argmin(scores: torch.Tensor, rows: torch.Tensor, group: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Row-wise `(min, argmin)` of a `(n, K)` block, `K` a multiple of `group`.

    On CPU `Tensor.min(dim)` over 4096 columns is about as slow as the matrix product that fills the block. The
    value-only `amin` is vectorised and much faster, so this takes a two-level minimum: `amin` within groups of
    `group` columns, `argmin` over the `K / group` group minima, then `argmin` inside the winning group only.
    Both `argmin`s return the first minimum, so ties go to the lowest column index, as a flat `argmin` would.

    Args:
        scores: `(n, K)` block of scores.
        rows: `(>= n,)` int64 `arange`, reused across blocks.
        group: group width; `K % group == 0`.

    Returns:
        `(values (n,), indices (n,))`.
    """
    n, width = scores.shape
    grouped = scores.view(n, width // group, group)
    group_min = grouped.amin(2)
    best_group = group_min.argmin(1)
    inner = grouped[rows[:n], best_group].argmin(1)
    values = group_min.gather(1, best_group[:, None]).squeeze(1)
    return values, best_group * group + inner


class PrototypeIndex:
    """Exact nearest-prototype search over fixed `(K, d)` prototypes, with per-prototype data cached.

    Points and prototypes are first centred on the prototypes' mean (distances do not change), which keeps the
    matrix form accurate for data far from the origin. Two exact methods, chosen by `precision`:

    - `"float32"`: scores `||c||^2 - 2 x . c` by one `torch.addmm` per block of rows into a reused
      `(chunk_size, K)` buffer, then a two-level minimum on CPU (`_block_argmin`) or `min` on CUDA.
    - `"bfloat16"` (CPU only; other devices use float32): the product in bfloat16, several times faster where
      the CPU has bfloat16 instructions, used only to *filter*: a rigorous error bound (see `_search_bfloat16`)
      gives, for every point, a threshold that every prototype that could be the nearest one passes. Those
      candidates (about 10 of 4096 on standardised 28-feature data) are re-ranked with float32 distances
      `sum((x - c)^2)`, so the answer is exact, not approximate. The `(n, K)` block is seen as
      `(n, 16, K / 16)`: a vertical `amin` gives class minima, and only classes under the threshold are
      expanded. A block with pathologically many candidates falls back to float32.

    `"auto"` picks bfloat16 on a CPU with native bfloat16 instructions when `K >= BF16_MIN_PROTOTYPES` and the
    search has at least `BF16_MIN_POINTS` points, else float32. Both return the lowest index among prototypes
    at exactly equal computed distance; the two methods can break ties within float32 rounding differently.

    The search keeps no reference to the points; it reuses a module-level scratch buffer per device (not
    thread-safe).
    """

    def __init__(
        self,
        prototypes: torch.Tensor,
        *,
        precision: Precision = "auto",
        chunk_size: int | None = None,
    ) -> None:
        """Prepares the search.

        Args:
            prototypes: `(K, d)` float32.
            precision: `"auto"`, `"float32"` or `"bfloat16"` (see the class docstring).
            chunk_size: rows per block (None: `BF16_CHUNK_SIZE` for bfloat16, else
                `default_chunk_size(device)`).
        """
        if prototypes.ndim != 2 or prototypes.shape[0] == 0:
            raise ValueError(f"prototypes must be (K, d) with K > 0, got {tuple(prototypes.shape)}")
        if precision not in ("auto", "float32", "bfloat16"):
            raise ValueError(f"precision must be 'auto', 'float32' or 'bfloat16', got {precision!r}")
        self.prototypes = prototypes.to(torch.float32)
        self.device = prototypes.device
        num, dim = self.prototypes.shape
        on_cpu = self.device.type == "cpu"
        self._auto = precision == "auto"
        if self._auto:
            native = on_cpu and num >= BF16_MIN_PROTOTYPES and cpu_has_native_bfloat16()
            precision = "bfloat16" if native else "float32"
        elif not on_cpu:
            # GPU bfloat16 products may reduce partial sums in reduced precision, outside the error bound.
            precision = "float32"
        #: `"float32"` or `"bfloat16"`: the method used (with `"auto"`, bfloat16 only for large searches).
        self.precision: Precision = precision
        self._chunk_float32 = chunk_size or default_chunk_size(self.device)
        self._chunk_bfloat16 = chunk_size or BF16_CHUNK_SIZE
        self._centre = self.prototypes.mean(0)
        centred = self.prototypes - self._centre
        self._centred = centred
        sq_norms = centred.square().sum(1)

        # float32 search: prototypes padded to whole groups with unreachable (infinite-norm) dummies.
        self._group = MIN_GROUP_SIZE if on_cpu and num > MIN_GROUP_SIZE else 0
        pad = (-num) % self._group if self._group else 0
        self._transposed = torch.cat([centred, torch.zeros(pad, dim, device=self.device)]).t()
        self._padded_sq_norms = torch.cat([sq_norms, torch.full((pad,), math.inf, device=self.device)])

        if precision == "bfloat16":
            # The product approximates ||x~ - c~||^2 + o for the bfloat16-rounded x~ and c~. Prototype side:
            # [-2 c~, 1, 1, ||c~||^2 (hi), ||c~||^2 (lo)]; point side: [x~, ||x~||^2 + o (hi), (lo), 1, 1].
            pad = (-num) % BF16_CLASS_SIZE
            rounded = centred.to(torch.bfloat16).to(torch.float32)
            rounded_sq_norms = rounded.square().sum(1)
            high = rounded_sq_norms.to(torch.bfloat16).to(torch.float32)
            augmented = torch.cat(
                [
                    -2.0 * rounded,
                    torch.ones(num, 2, device=self.device),
                    high[:, None],
                    (rounded_sq_norms - high)[:, None],
                ],
                dim=1,
            )
            dummies = torch.zeros(pad, dim + 4, device=self.device)
            dummies[:, dim + 2] = math.inf  # never a candidate
            self._bf16_transposed = torch.cat([augmented, dummies]).to(torch.bfloat16).t()
            width = self._bf16_transposed.shape[1] // BF16_CLASS_SIZE
            self._member_offsets = torch.arange(BF16_CLASS_SIZE, device=self.device) * width  # (16,)
            self._max_norm = float(sq_norms.max().sqrt()) * 1.001
            self._max_rounded_sq_norm = float(rounded_sq_norms.max()) * 1.001

    @property
    def num_prototypes(self) -> int:
        """`K`."""
        return self.prototypes.shape[0]

    def search(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Nearest prototype of every point.

        Args:
            points: `(B, d)` float32 on the prototypes' device.

        Returns:
            `(ids (B,) int64, sq_dist (B,) float32)`: index of the nearest prototype (lowest on ties) and the
            squared distance to it (>= 0).
        """
        if points.ndim != 2 or points.shape[1] != self.prototypes.shape[1]:
            raise ValueError(f"expected points (B, {self.prototypes.shape[1]}), got {tuple(points.shape)}")
        num_points = points.shape[0]
        ids = torch.empty(num_points, dtype=torch.int64, device=self.device)
        sq_dist = torch.empty(num_points, dtype=torch.float32, device=self.device)
        if num_points == 0:
            return ids, sq_dist
        centred = points.to(torch.float32) - self._centre
        if self.precision == "bfloat16" and (not self._auto or num_points >= BF16_MIN_POINTS):
            self._search_bfloat16(centred, ids, sq_dist)
        else:
            chunk = self._chunk_float32
            for start in range(0, num_points, chunk):
                stop = min(start + chunk, num_points)
                self._search_float32(centred[start:stop], ids[start:stop], sq_dist[start:stop])
        return ids, sq_dist

    def _search_float32(self, block: torch.Tensor, ids: torch.Tensor, sq_dist: torch.Tensor) -> None:
        """Exact float32 search of one `(n, d)` block, written into `ids (n,)` and `sq_dist (n,)`."""
        n = block.shape[0]
        scores = _workspace(n, self._transposed.shape[1], torch.float32, self.device)
        torch.addmm(self._padded_sq_norms, block, self._transposed, beta=1.0, alpha=-2.0, out=scores)
        if self._group:
            rows = torch.arange(n, device=self.device)
            values, indices = _block_argmin(scores, rows, self._group)
        else:
            values, indices = scores.min(1)
        ids.copy_(indices)
        torch.add(values, block.square().sum(1), out=sq_dist).clamp_(min=0.0)

    def _search_bfloat16(self, points: torch.Tensor, ids: torch.Tensor, sq_dist: torch.Tensor) -> None:
        """Exact search by bfloat16 filtering and float32 re-ranking (see the class docstring).

        Error analysis, for a point `x` and prototypes `c_k`, with `x~`, `c~` their bfloat16 roundings:

        - Distances move by less than the rounding: `| ||x - c|| - ||x~ - c~|| | <= delta = u |x| + u max|c|`
          (triangle inequality, `u = 2^-8`).
        - The product is exact for bfloat16 factors and accumulates in float32, so the score is
          `S_k = ||x~ - c~_k||^2 + o` up to `eps` (accumulation, float32 norms, hi/lo splits), and its bfloat16
          output `A_k` is within relative `u_out` of `S_k`. The offset `o > eps` keeps every score positive, so
          bfloat16 scores order like their int16 bit patterns.
        - With `m` the smallest score, the true minimum distance is at most `sqrt(H) + delta`,
          `H = A_m (1 + u_out') - o + eps`, and prototype `k` can only match it if
          `A_k <= T = ((sqrt(H) + 2 delta)^2 + o + eps) / (1 - u_out')`: those are the candidates.
        """
        num_points, dim = points.shape
        gamma = 2.0 * (dim + 8) * _U_ACC  # the product sums dim + 4 terms; twice that for room
        rounded = points.to(torch.bfloat16)
        rounded_sq_norms = rounded.to(torch.float32).square().sum(1)
        max_norm, max_sq_norm = self._max_norm, self._max_rounded_sq_norm
        delta = _U_IN * 1.001 * (points.square().sum(1).sqrt() + max_norm)
        magnitudes = 2.0 * rounded_sq_norms.sqrt() * math.sqrt(max_sq_norm) + rounded_sq_norms + max_sq_norm
        epsilon = gamma * magnitudes + (_U_IN**2 + gamma) * (rounded_sq_norms + max_sq_norm)
        offset = 4.0 * epsilon + 1e-3
        epsilon = epsilon + 2.02 * (_U_IN**2 + gamma) * offset
        point_column = rounded_sq_norms + offset
        point_high = point_column.to(torch.bfloat16)
        augmented = torch.empty(num_points, dim + 4, dtype=torch.bfloat16, device=self.device)
        augmented[:, :dim] = rounded
        augmented[:, dim] = point_high
        augmented[:, dim + 1] = point_column - point_high.to(torch.float32)
        augmented[:, dim + 2 :] = 1.0
        padded = self._bf16_transposed.shape[1]
        width = padded // BF16_CLASS_SIZE
        for start in range(0, num_points, self._chunk_bfloat16):
            stop = min(start + self._chunk_bfloat16, num_points)
            n = stop - start
            scores = _workspace(n, padded, torch.bfloat16, self.device)
            torch.mm(augmented[start:stop], self._bf16_transposed, out=scores)
            # Column classes: class j holds columns j, j + width, j + 2 width, ... (a vertical amin is cheapest).
            keys = scores.view(torch.int16).view(n, BF16_CLASS_SIZE, width)
            class_min = keys.amin(1)
            row_min = class_min.amin(1).view(torch.bfloat16).to(torch.float32)
            eps, off = epsilon[start:stop], offset[start:stop]
            best_bound = (row_min * (1.0 + _U_OUT1) - off + eps).clamp(min=0.0).sqrt() + 2.0 * delta[start:stop]
            threshold = (best_bound.square() + off + eps) / (1.0 - _U_OUT1)
            if not bool(torch.isfinite(threshold).all()):
                self._search_float32(points[start:stop], ids[start:stop], sq_dist[start:stop])
                continue
            # Round up when converting, so that the comparison stays conservative.
            threshold_keys = (threshold * (1.0 + 2.0**-7)).to(torch.bfloat16).view(torch.int16)
            # int16 comparisons against a broadcast column are slow in torch; a materialised one is not.
            column = threshold_keys[:, None].expand(n, width).contiguous()
            rows, classes = (class_min <= column).nonzero(as_tuple=True)
            # members[p, m] = keys[rows[p], m, classes[p]], gathered from the flat block (faster than fancy indexing)
            member_index = (rows * padded + classes).unsqueeze(1) + self._member_offsets
            members = keys.view(-1).take(member_index)
            column = threshold_keys[rows][:, None].expand(-1, BF16_CLASS_SIZE).contiguous()
            pairs, member = (members <= column).nonzero(as_tuple=True)
            if pairs.numel() > BF16_MAX_CANDIDATES_PER_ROW * n:
                self._search_float32(points[start:stop], ids[start:stop], sq_dist[start:stop])
                continue
            candidate_rows = rows[pairs]
            candidates = member * width + classes[pairs]
            exact = (
                (points.index_select(0, start + candidate_rows) - self._centred.index_select(0, candidates))
                .square()
                .sum(1)
            )
            # Row-wise argmin as one scatter: non-negative float32 values order like their bit patterns, so
            # (distance bits << 32 | index) sorts by distance, then index.
            packed = (exact.view(torch.int32).to(torch.int64) << 32) | candidates
            best = torch.full((n,), torch.iinfo(torch.int64).max, dtype=torch.int64, device=self.device)
            best.scatter_reduce_(0, candidate_rows, packed, reduce="amin")
            ids[start:stop] = best & 0xFFFFFFFF
            sq_dist[start:stop] = (best >> 32).to(torch.int32).view(torch.float32)


def nearest_prototype(
    points: torch.Tensor,
    prototypes: torch.Tensor,
    *,
    chunk_size: int | None = None,
    precision: Precision = "auto",
) -> tuple[torch.Tensor, torch.Tensor]:
    """Index of and squared distance to the nearest prototype of every point (exact search).

    Memory is `O(chunk_size * K)` whatever `B` is. See `PrototypeIndex` for the method; build one directly to
    search the same prototypes many times.

    Args:
        points: `(B, d)` float32.
        prototypes: `(K, d)` float32, same device.
        chunk_size: rows per block (None: the default of `PrototypeIndex`).
        precision: `"auto"`, `"float32"` or `"bfloat16"` (both exact; see `PrototypeIndex`).

    Returns:
        `(ids (B,) int64, sq_dist (B,) float32)`: nearest prototype (lowest index on ties) and the squared
        distance to it (>= 0).
    """
    if points.ndim != 2 or prototypes.ndim != 2 or points.shape[1] != prototypes.shape[1]:
        raise ValueError(f"expected points (B, d) and prototypes (K, d), got {points.shape}, {prototypes.shape}")
    return PrototypeIndex(prototypes, precision=precision, chunk_size=chunk_size).search(points)


def kmeans_plus_plus(points: torch.Tensor, num_prototypes: int, *, generator: torch.Generator) -> torch.Tensor:
    """k-means++ seeding (Arthur and Vassilvitskii, 2007): each new seed is a point drawn with probability
    proportional to its squared distance to the nearest seed chosen so far.

    Cost is `O(num_prototypes * M * d)` with a Python step per seed, so callers pass a subsample.

    Args:
        points: `(M, d)` float32.
        num_prototypes: number of seeds `K`.
        generator: random source (on the device of `points`).

    Returns:
        `(K', d)` seeds, pairwise distinct rows of `points`. `K' < K` only when `points` has fewer than `K`
        distinct rows (seeding stops once every point coincides with a seed).
    """
    num_points = points.shape[0]
    device = points.device
    chosen = torch.empty(num_prototypes, dtype=torch.int64, device=device)
    chosen[0] = torch.randint(num_points, (1,), generator=generator, device=device)[0]
    uniforms = torch.rand(num_prototypes, generator=generator, device=device, dtype=torch.float64)
    point_sq_norms = points.square().sum(1)
    closest = torch.full((num_points,), math.inf, dtype=points.dtype, device=device)
    for k in range(num_prototypes):
        if k > 0:
            cumulative = closest.to(torch.float64).cumsum(0)
            total = cumulative[-1]
            if total.item() <= 0.0:
                return points[chosen[:k]].clone()
            # Inverse-CDF draw; points at distance 0 (already seeds, or their duplicates) cannot be drawn.
            index = torch.searchsorted(cumulative, (uniforms[k] * total)[None], right=True)
            chosen[k] = index.clamp_(max=num_points - 1)[0]
        seed = points[chosen[k]]
        distance = torch.addmv(point_sq_norms + seed.dot(seed), points, seed, alpha=-2.0).clamp_(min=0.0)
        torch.minimum(closest, distance, out=closest)
        closest[chosen[k]] = 0.0
    return points[chosen].clone()


def _initial_prototypes(
    data: torch.Tensor,
    num_prototypes: int,
    init: Literal["kmeans++", "random"] | torch.Tensor,
    generator: torch.Generator,
    init_sample_size: int | None,
) -> torch.Tensor:
    """Initial `(K', d)` prototypes, `K' < K` only if `data` has fewer than `K` distinct rows (see `kmeans`)."""
    num_points = data.shape[0]
    device = data.device
    if isinstance(init, torch.Tensor):
        if init.shape != (num_prototypes, data.shape[1]):
            raise ValueError(f"init tensor must be ({num_prototypes}, {data.shape[1]}), got {tuple(init.shape)}")
        return init.to(device=device, dtype=data.dtype).clone()
    if init == "random":
        chosen = data[torch.randperm(num_points, generator=generator, device=device)[:num_prototypes]]
        if chosen.shape[0] == num_prototypes and torch.unique(chosen, dim=0).shape[0] == num_prototypes:
            return chosen.clone()
        # Repeated rows: fine (empty clusters get re-seeded) unless the data has fewer than K distinct rows.
        distinct = torch.unique(data, dim=0)
        return distinct if distinct.shape[0] < num_prototypes else chosen.clone()
    if init != "kmeans++":
        raise ValueError(f"init must be 'kmeans++', 'random' or a tensor, got {init!r}")
    sample_size = init_sample_size or INIT_SAMPLES_PER_PROTOTYPE * num_prototypes
    sample_size = min(max(sample_size, num_prototypes), num_points)
    sample = data[torch.randperm(num_points, generator=generator, device=device)[:sample_size]]
    seeds = kmeans_plus_plus(sample, num_prototypes, generator=generator)
    if seeds.shape[0] < num_prototypes and sample_size < num_points:
        seeds = kmeans_plus_plus(data, num_prototypes, generator=generator)  # the subsample was too repetitive
    return seeds


def kmeans(
    data: torch.Tensor,
    num_prototypes: int,
    *,
    max_iterations: int = 100,
    tolerance: float = 1e-4,
    generator: torch.Generator | None = None,
    init: Literal["kmeans++", "random"] | torch.Tensor = "kmeans++",
    chunk_size: int | None = None,
    init_sample_size: int | None = None,
    precision: Precision = "auto",
) -> KMeansResult:
    """Generalized Lloyd algorithm (batch k-means) on `(M, d)` data.

    Each iteration assigns every point to its nearest prototype (`nearest_prototype`, exact) and moves every
    prototype to the mean of its points (`index_add_`, no loop over clusters). It stops when the relative decrease
    of the distortion `(D[t-1] - D[t]) / D[t-1]` is below `tolerance`, or after `max_iterations` updates.

    Initialisation:
        - `"kmeans++"` (default): k-means++ seeding on a random subsample of `init_sample_size` points (default
          `8 K`, at most `M`), so seeding costs about as much as a few Lloyd iterations even for `K = 4096`.
        - `"random"`: `K` data points drawn uniformly without replacement.
        - a `(K, d)` tensor: used as given (copied).

    Empty clusters: a prototype that receives no point is moved onto a data point, the points farthest from their
    current prototype first (one distinct point per empty cluster). The other prototypes move to their means as
    usual. Neither step can increase the distortion, so `K` prototypes are kept and the distortion is
    non-increasing.

    Fewer distinct points than `K`: k-means cannot place `K` distinct prototypes, so `K` is reduced to the number
    of distinct points with a `UserWarning` and the prototypes are those points (distortion 0). Only checked for
    the built-in initialisations; a tensor `init` is trusted.

    Args:
        data: `(M, d)` float32 points (on CPU or CUDA; everything runs on that device).
        num_prototypes: number of prototypes `K >= 1`.
        max_iterations: cap on the number of centroid updates.
        tolerance: relative distortion decrease below which the run has converged (0 runs to the cap).
        generator: random source for the initialisation, on `data.device`; None uses a fresh one seeded with 0.
        init: `"kmeans++"`, `"random"` or a `(K, d)` tensor.
        chunk_size: rows per block of the nearest-prototype search (None: per-device default).
        init_sample_size: points used by k-means++ seeding (None: `8 K`).
        precision: method of the (exact) nearest-prototype search, see `PrototypeIndex`.

    Returns:
        A `KMeansResult`.
    """
    if data.ndim != 2 or data.shape[0] == 0:
        raise ValueError(f"data must be (M, d) with M > 0, got {tuple(data.shape)}")
    if num_prototypes < 1:
        raise ValueError(f"num_prototypes must be >= 1, got {num_prototypes}")
    device = data.device
    data = data.to(torch.float32)
    if generator is None:
        generator = torch.Generator(device=device).manual_seed(0)
    prototypes = _initial_prototypes(data, num_prototypes, init, generator, init_sample_size)
    if prototypes.shape[0] < num_prototypes:
        warnings.warn(
            f"k-means: the data has only {prototypes.shape[0]} distinct points for {num_prototypes} prototypes; "
            f"using K = {prototypes.shape[0]}",
            UserWarning,
            stacklevel=2,
        )
        num_prototypes = prototypes.shape[0]

    labels, sq_dist = nearest_prototype(data, prototypes, chunk_size=chunk_size, precision=precision)
    distortion = [float(sq_dist.double().mean())]
    converged = False
    iterations = 0
    dim = data.shape[1]
    while iterations < max_iterations:
        # Update: every prototype moves to the mean of its points (float64 sums for accuracy).
        sums = torch.zeros(num_prototypes, dim, dtype=torch.float64, device=device)
        for start in range(0, data.shape[0], SUM_CHUNK_SIZE):
            rows = slice(start, start + SUM_CHUNK_SIZE)
            sums.index_add_(0, labels[rows], data[rows].to(torch.float64))
        counts = torch.bincount(labels, minlength=num_prototypes)
        filled = counts > 0
        prototypes = torch.where(filled[:, None], sums / counts.clamp(min=1)[:, None], prototypes.double())
        prototypes = prototypes.to(torch.float32)
        empty = (~filled).nonzero().squeeze(1)
        if empty.numel() > 0:
            # Re-seed each empty cluster on one of the points farthest from their prototype.
            farthest = torch.topk(sq_dist, min(empty.numel(), sq_dist.numel())).indices
            prototypes[empty[: farthest.numel()]] = data[farthest]
        iterations += 1

        labels, sq_dist = nearest_prototype(data, prototypes, chunk_size=chunk_size, precision=precision)
        distortion.append(float(sq_dist.double().mean()))
        previous, current = distortion[-2], distortion[-1]
        if previous <= 0.0 or (previous - current) / previous < tolerance:
            converged = True
            break
    return KMeansResult(prototypes, labels, distortion, iterations, converged)

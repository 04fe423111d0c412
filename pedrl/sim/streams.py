"""Counter-based random streams for the numba kernels: one splitmix64 stream per room, so that a seed gives the
same draws at any thread count (the kernels' twins draw from torch generators instead)."""

from __future__ import annotations

import numpy as np

from pedrl._numba import cached_njit

__all__ = ["next_uniform", "seed_streams"]

GOLDEN = np.uint64(0x9E3779B97F4A7C15)
"""splitmix64's increment (the golden ratio), also the multiplier of the kernels' open-addressing hashes."""


@cached_njit(nogil=True, inline="always")
def _mix(z):
    """splitmix64's finaliser: a 64-bit hash."""
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@cached_njit(nogil=True)
def seed_streams(seed, streams):
    """One splitmix64 stream per room, from ``seed`` (uint64)."""
    for r in range(streams.shape[0]):
        streams[r] = _mix(seed + GOLDEN * np.uint64(r + 1))


@cached_njit(nogil=True, inline="always")
def next_uniform(streams, r):
    """The next float32 in ``[0, 1)`` of room ``r``'s stream (24 random bits)."""
    streams[r] += GOLDEN
    return np.float32(np.float64(_mix(streams[r]) >> np.uint64(40)) * (1.0 / 16777216.0))

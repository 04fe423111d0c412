"""numba, for the CPU kernels of the simulation (`pedrl.sim.kernels`), the Q tables (`pedrl.rl.kernels`) and the
quantizer (`pedrl.vq.tree`).

numba compiles a kernel at its first call (about 13 s for all of them on a 2-core CPU) and keeps it in its on-disk
cache (``__pycache__`` next to the module, or ``NUMBA_CACHE_DIR``), so later processes load them in under a second.
The torch code stays the reference and the path on other devices: the kernels return its numbers to the bit (the
tree search the exact argmin, which can order float32 ties differently from the matrix search).
"""

from __future__ import annotations

import functools
import os
from types import ModuleType
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import torch

__all__ = ["numba", "numba_available", "use_kernels"]

DISABLE_VARIABLE = "PEDRL_NO_NUMBA"
"""Set it (to anything but empty or ``0``) to run the torch code on the CPU too."""


@functools.cache
def numba_available() -> bool:
    """Whether the numba kernels are used: numba imports and ``PEDRL_NO_NUMBA`` is not set."""
    if os.environ.get(DISABLE_VARIABLE, "") not in ("", "0"):
        return False
    try:
        import numba as _  # noqa: F401
    except ImportError:  # pragma: no cover - numba is a dependency
        return False
    return True


def use_kernels(device: torch.device, compiled: bool | None = None) -> bool:
    """Whether to run a numba kernel: ``compiled`` when given, else on the CPU when numba is available."""
    if compiled is not None:
        return compiled
    return device.type == "cpu" and numba_available()


def numba() -> ModuleType:
    """The numba module, with LLVM's SLP vectorizer on (numba leaves it off): it packs independent scalar chains,
    such as the eight distances of a k-d tree leaf, into vector instructions."""
    import numba as module

    module.config.SLP_VECTORIZE = 1
    return module

"""numba, for the CPU kernels of the simulation (`pedrl.sim.kernels`) and the quantizer (`pedrl.vq.tree`).

numba compiles a kernel at its first call (a few seconds) and keeps it in its on-disk cache (``__pycache__``
next to the module, or ``NUMBA_CACHE_DIR``), so later processes load it in milliseconds. The torch code stays the
reference and the path on other devices: the kernels return the same numbers (the simulation's to the bit).
"""

from __future__ import annotations

import functools
import os
from types import ModuleType

__all__ = ["numba", "numba_available"]

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


def numba() -> ModuleType:
    """The numba module, with LLVM's SLP vectorizer on (numba leaves it off): it packs independent scalar chains,
    such as the eight distances of a k-d tree leaf, into vector instructions."""
    import numba as module

    module.config.SLP_VECTORIZE = 1
    return module

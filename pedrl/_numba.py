"""numba, for the CPU kernels of the simulation (`pedrl.sim.motion.*_kernel`), the Q tables (`pedrl.rl.kernels`) and the
quantizer (`pedrl.vq.tree`).

numba compiles a kernel at its first call (minutes for the fused trial's kernels on a 2-core CPU) and keeps it in its
on-disk cache (``NUMBA_CACHE_DIR`` where it is set and writable, else ``__pycache__`` next to the module, else the
user's cache folder, ``~/.cache/numba``), so later processes load them in under a second. Kernels are declared with
:func:`cached_njit`: the first compile of a process whose cache is cold says so in one line on stderr
(:data:`COMPILING`), and each kernel whose compile took a second or more says so in one line when it is done
(:data:`COMPILED`: the first run's progress); a kernel whose cache files cannot be read (truncated, garbage) is
recompiled into a fresh cache, with one warning line per process, instead of failing every run, and where no folder
can hold a cache the kernels are compiled in every process, with one warning line.
The torch code stays the reference and the path on other devices: the kernels return its numbers to the bit (the
tree search the exact argmin, which can order float32 ties differently from the matrix search). Each kernel module
names its specification in its first line. In `pedrl.sim.motion` and `pedrl.rl.qlearning` a function with a
kernel is a dispatcher under the plain name (it asks :func:`use_kernels`), beside its torch twin ``*_torch``: e.g.
``pedrl.rl.td_update`` runs ``pedrl.rl.kernels.td_update_kernel`` or ``pedrl.rl.td_update_torch``.
"""

from __future__ import annotations

import functools
import os
import sys
import time
from collections.abc import Callable
from types import ModuleType
from typing import TYPE_CHECKING, Any

from pedrl.notices import warn

if TYPE_CHECKING:
    import torch

__all__ = ["cached_njit", "numba", "numba_available", "use_kernels"]

_HEALED: list[str] = []
"""The kernels whose cache this process found unreadable and rebuilt (the first one is reported)."""
_COMPILED: list[str] = []
"""The kernels this process compiled because their cache held no copy (the first one is announced)."""
_UNCACHED: list[str] = []
"""The kernels declared without a cache because no folder could hold one (the first one is reported)."""
COMPILING = (
    "pedrl: compiling the numba kernels (first run only: seconds to minutes per kernel, a line as each one taking"
    " longer than a second is done; cached afterwards in {folder})"
)
"""The line printed on stderr before the first compile of a process whose cache holds no copy of a kernel."""
COMPILED = "pedrl: compiled {kernel}{callees} in {seconds:.0f} s"
"""The line printed on stderr when a kernel compiled by this process (with the kernels it calls) is done, where it
took :data:`PROGRESS_SECONDS` or more: the first run's progress through its kernels."""
PROGRESS_SECONDS = 1.0
"""Compiles shorter than this say nothing when they are done (a tiny kernel's line would only be noise)."""
_IN_PROGRESS: list[tuple[str, float, int]] = []
"""The kernels being compiled, outermost first: name, start (perf_counter) and the count of compiles before it."""
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


def cached_njit(**options: Any) -> Callable[[Callable[..., Any]], Any]:
    """``numba.njit(cache=True, **options)`` of :func:`numba` (SLP vectorizer on), with an on-disk cache that heals
    itself.

    numba reads a kernel's cache (an index ``<module>.<kernel>-<line>.pyXY.nbi`` and data files ``...nbc``) at the
    kernel's first call with new argument types, and fails there, on every run, when a file is corrupt (an
    ``UnpicklingError`` after a full disk or an interrupted copy). Here that failure empties the kernel's index
    (numba's own ``flush``), so the kernel is compiled again and its cache rewritten, and says so in one line. Where
    the cache cannot be rewritten, the kernel is compiled without it for this process.
    """

    def decorate(function: Callable[..., Any]) -> Any:
        try:
            dispatcher = numba().njit(cache=True, **options)(function)
        except RuntimeError as err:  # numba found no writable folder for the cache ("no locator available")
            if not _UNCACHED:
                warn(
                    f"numba has no writable folder for its cache ({str(err).splitlines()[0]}): the kernels are"
                    " compiled in every run; set NUMBA_CACHE_DIR to a writable folder to keep them"
                )
            _UNCACHED.append(function.__qualname__)
            return numba().njit(cache=False, **options)(function)
        dispatcher._cache = _healing_cache_class()(dispatcher.py_func)  # numba has no public hook for its cache
        return dispatcher

    return decorate


@functools.cache
def _healing_cache_class() -> type:
    """numba's ``FunctionCache`` with a ``load_overload`` that recovers from unreadable cache files."""
    from numba.core.caching import FunctionCache

    class HealingCache(FunctionCache):
        def __init__(self, py_func: Callable[..., Any]) -> None:
            super().__init__(py_func)
            # numba dates a cache by its kernel's own file: a kernel inlined from another module (a reward, a
            # gate) left a caller's cache that still ran the old code; the stamp also dates every kernel module
            self._cache_file._source_stamp = (self._cache_file._source_stamp, kernel_sources_stamp())

        def load_overload(self, sig: Any, target_context: Any) -> Any:
            try:
                loaded = super().load_overload(sig, target_context)
            except Exception as err:  # whatever a corrupt file raises: pickle, EOF, type errors
                kernel = f"{self._py_func.__module__}.{self._py_func.__qualname__}"
                reason = f"{type(err).__name__}: {err}".splitlines()[0]
                try:
                    self.flush()  # an empty index: the old data files are no longer read, and get overwritten
                    outcome = "recompiled into a fresh cache"
                except OSError:
                    self.disable()
                    outcome = "recompiled without a cache (the cache folder cannot be written)"
                if not _HEALED:  # one line per process: a corrupt cache folder holds many kernels
                    warn(
                        f"numba's cache of {kernel} in {self.cache_path!r} could not be read ({reason}); {outcome}"
                        " (and so is any other kernel whose cache cannot be read)"
                    )
                _HEALED.append(kernel)
                return None
            if loaded is None and self._enabled:  # a cold cache: numba compiles next
                if not _COMPILED and not _HEALED:
                    print(COMPILING.format(folder=cache_folder(self)), file=sys.stderr, flush=True)
                kernel = f"{self._py_func.__module__}.{self._py_func.__qualname__}"
                _COMPILED.append(kernel)
                _IN_PROGRESS.append((kernel, time.perf_counter(), len(_COMPILED)))
            return loaded

        def save_overload(self, sig: Any, data: Any) -> None:
            super().save_overload(sig, data)
            compiled_done(f"{self._py_func.__module__}.{self._py_func.__qualname__}")

    return HealingCache


@functools.cache
def kernel_sources_stamp() -> tuple[tuple[str, int, int], ...]:
    """The modification time and size of every pedrl module that defines numba kernels (``@cached_njit``), by path
    within the package: part of every kernel's cache stamp, so that editing any kernel module compiles every kernel
    again (numba itself dates a cache by the kernel's own file only, not by the kernels of other modules it calls)."""
    root = os.path.dirname(os.path.abspath(__file__))
    stamps = []
    for folder, _, names in sorted(os.walk(root)):
        for name in sorted(names):
            path = os.path.join(folder, name)
            if name.endswith(".py") and path != os.path.abspath(__file__):
                with open(path, encoding="utf-8") as source:
                    if "@cached_njit" not in source.read():
                        continue
                stat = os.stat(path)
                stamps.append((os.path.relpath(path, root), stat.st_mtime_ns, stat.st_size))
    return tuple(stamps)


def compiled_done(kernel: str) -> None:
    """``kernel``'s compile is done (numba saves it to the cache): where it was the outermost compile in progress
    and took :data:`PROGRESS_SECONDS` or more, say so in one line on stderr (:data:`COMPILED`), with the count of the
    kernels it called that were compiled with it."""
    for index in range(len(_IN_PROGRESS) - 1, -1, -1):
        if _IN_PROGRESS[index][0] == kernel:
            _, start, before = _IN_PROGRESS.pop(index)
            if index == 0:
                seconds, callees = time.perf_counter() - start, len(_COMPILED) - before
                if seconds >= PROGRESS_SECONDS:
                    with_callees = f" (and {callees} kernel{'s' if callees != 1 else ''} it calls)" if callees else ""
                    line = COMPILED.format(kernel=kernel, callees=with_callees, seconds=seconds)
                    print(line, file=sys.stderr, flush=True)
                _IN_PROGRESS.clear()  # a callee whose compile failed leaves nothing behind
            return


def cache_folder(cache: Any) -> str:
    """The folder that holds the kernels' caches, for messages: ``NUMBA_CACHE_DIR`` or the user's cache folder (each
    holds one sub-folder per source folder), or, for the caches beside the modules, their ``__pycache__`` folders."""
    from numba.core.caching import InTreeCacheLocator

    path = cache.cache_path
    if isinstance(cache._impl.locator, InTreeCacheLocator):
        package = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        return f"the __pycache__ folders under {package}" if path.startswith(package) else path
    return os.path.dirname(path)

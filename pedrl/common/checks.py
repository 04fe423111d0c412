"""One-line checks of user values, before any compute: each names the bad value and what is allowed."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from numbers import Integral, Real
from pathlib import Path
from typing import Any

import torch

DEVICE_TYPES = ("cpu", "cuda")
"""Device types pedrl runs on (``cuda[:index]`` for a GPU)."""
MAX_SEED = 2**32 - 1
"""Largest ``seed``: derived seeds (``seed * 10007 + phase``, ``seed * 1013 + agents``) stay within int64."""
MAX_TRIALS = 10**9
"""Most trials of any count a user gives (a training phase's, its gathering's, an evaluation's per agent count): years
of compute at the fastest measured rates; more is a typo (or a ``trials_growth`` that overflows)."""
FASTEST_AGENT_DECISIONS = 1e6
"""Agent-decisions per second above any measured run (the fused trial's best is 880k on 2 threads,
docs/performance.md): a run's worst case at this rate is the shortest it could take on any machine."""
SLOW_AGENT_DECISIONS = 1e5
"""Agent-decisions per second of the slower paths (the torch loop, a network acting; docs/performance.md): the other
end of a printed estimate."""
YEAR_S = 365.25 * 86_400
"""A run whose worst case would take longer than this at the fastest rate is refused: no machine could finish it."""
LARGE_RUN_S = 600.0
"""A run whose worst case would take longer than this at the fastest rate prints its estimate before any compute."""


def check_integer(name: str, value: Any, *, minimum: int, maximum: int | None = None) -> int:
    """``value`` as an int in ``[minimum, maximum]``, else a one-line ``ValueError``.

    A whole float (``1e9`` or ``5.0`` on the command line, which YAML reads as floats) is refused with a hint to
    write the digits, so that the message does not look like a contradiction.
    """
    allowed = f"an integer >= {minimum}" if maximum is None else f"an integer in [{minimum}, {maximum}]"
    in_range = isinstance(value, float) and minimum <= value <= (math.inf if maximum is None else maximum)
    if in_range and value.is_integer():
        raise ValueError(
            f"{name}={value!r} is invalid: must be {allowed}, written with digits only "
            f"({value!r} is read as a float: write {int(value)})"
        )
    if isinstance(value, bool) or not isinstance(value, Integral):
        raise ValueError(f"{name}={value!r} is invalid: must be {allowed}")
    if value < minimum or (maximum is not None and value > maximum):
        raise ValueError(f"{name}={value!r} is invalid: must be {allowed}")
    return int(value)


def check_real(name: str, value: Any, *, unit: str, positive: bool = False) -> float:
    """``value`` as a finite float (``> 0`` if ``positive``), else a one-line ``ValueError``."""
    allowed = f"a finite number > 0 ({unit})" if positive else f"a finite number ({unit})"
    if isinstance(value, bool) or not isinstance(value, Real) or not math.isfinite(float(value)):
        raise ValueError(f"{name}={value!r} is invalid: must be {allowed}")
    if positive and value <= 0:
        raise ValueError(f"{name}={value!r} is invalid: must be {allowed}")
    return float(value)


def check_number(
    name: str, value: Any, *, low: float = -math.inf, high: float = math.inf, low_open: bool = False
) -> float:
    """``value`` as a finite float in ``[low, high]`` (``(low, high]`` if ``low_open``), else a one-line
    ``ValueError``."""
    ok = isinstance(value, Real) and not isinstance(value, bool) and math.isfinite(float(value))
    ok = ok and (low < value if low_open else low <= value) and value <= high
    if not ok:
        interval = f"{'(' if low_open else '['}{low:g}, {high:g}]" if math.isfinite(high) else None
        allowed = f"a number in {interval}" if interval else f"a finite number {'>' if low_open else '>='} {low:g}"
        raise ValueError(f"{name}={value!r} is invalid: must be {allowed}")
    return float(value)


def check_trials_per_iteration(trials: Any, iterations: Any, *, maximum: int = MAX_TRIALS) -> int:
    """``trials`` as an int in ``[iterations, maximum]`` (``iterations`` checked first), else a one-line
    ``ValueError`` that names both keys when ``trials`` is below ``iterations``: each iteration learns a trial at
    least."""
    check_integer("iterations", iterations, minimum=1, maximum=maximum)
    if isinstance(trials, Integral) and not isinstance(trials, bool) and trials < iterations:
        raise ValueError(
            f"trials={trials!r} is invalid with iterations={iterations!r}: must be an integer in [{iterations}, "
            f"{maximum}] (each iteration learns a trial at least), or lower iterations"
        )
    return check_integer("trials", trials, minimum=iterations, maximum=maximum)


def check_epsilons(start: Any, end: Any) -> tuple[float, float]:
    """``epsilon_start`` and ``epsilon_end`` as floats in ``[0, 1]`` with ``end <= start`` (exploration decays from one
    to the other), else a one-line ``ValueError`` naming the bad value."""
    start = check_number("epsilon_start", start, low=0.0, high=1.0)
    end = check_number("epsilon_end", end, low=0.0, high=1.0)
    if end > start:
        raise ValueError(
            f"epsilon_end={end!r} is invalid with epsilon_start={start!r}: must be a number in [0, {start:g}] "
            "(exploration decays from epsilon_start to epsilon_end; equal values keep it constant)"
        )
    return start, end


def check_choice(name: str, value: Any, allowed: tuple[str, ...]) -> str:
    """``value`` if it is one of ``allowed``, else a one-line ``ValueError`` listing them."""
    if not isinstance(value, str) or value not in allowed:
        raise ValueError(f"{name}={value!r} is invalid: must be one of {', '.join(allowed)}")
    return value


def check_bool(name: str, value: Any) -> bool:
    """``value`` if it is a bool (``true``/``false`` on the command line), else a one-line ``ValueError``."""
    if not isinstance(value, bool):
        raise ValueError(f"{name}={value!r} is invalid: must be true or false")
    return value


def shown(value: Any, *, limit: int = 80) -> str:
    """``repr(value)`` cut to ``limit`` characters, with the full length, so that a message stays one short line
    whatever a config or a file holds (a 1 MB path, a whole WKT polygon); a string keeps its first and last
    ``limit / 2`` characters (a long path keeps its file name)."""
    try:
        text = repr(value)
    except RecursionError:
        return f"<a {type(value).__name__} nested too deep to show>"
    if len(text) <= limit:
        return text
    if isinstance(value, list | tuple | dict):
        return f"{text[:limit]}... ({len(value)} items)"
    if isinstance(value, str | bytes):  # a path's file name is at its end: keep both ends
        return f"{text[: limit // 2]}...{text[-(limit // 2) :]} ({len(value)} characters)"
    return f"{text[:limit]}... ({len(text)} characters)"


def check_device(value: Any) -> torch.device:
    """``value`` as a usable CPU or CUDA torch device, else a one-line ``ValueError`` that says why: not a device
    name, a device type other than cpu and cuda, or a device this machine cannot use (torch's reason)."""
    allowed = f"device={value!r} is invalid: must be cpu or cuda[:index], available here"
    try:
        device = torch.device(value)
    except (RuntimeError, TypeError, ValueError):
        raise ValueError(f"{allowed} (not a device name)") from None
    if device.type not in DEVICE_TYPES:
        raise ValueError(f"{allowed} (device type {device.type!r} is not supported)")
    try:
        torch.empty(1, device=device)
    except (RuntimeError, AssertionError) as error:
        raise ValueError(f"{allowed} ({first_line(error).split('. ')[0][:100]})") from None
    return device


# ---------------------------------------------------------------------- memory
GIB = 2**30


def available_memory(device: torch.device) -> int:
    """Bytes that can still be allocated on ``device``: free GPU memory, or the host's ``MemAvailable``."""
    if device.type == "cuda":
        free, _ = torch.cuda.mem_get_info(device)
        return int(free)
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:  # not Linux: the physical memory
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, OSError, ValueError):
        return 2**63 - 1


def check_memory(needs: Mapping[str, float], *, device: torch.device, advice: str) -> None:
    """Refuse, with one line giving the numbers, a run whose estimated peak memory exceeds what ``device`` has free.

    Args:
        needs: estimated bytes of the largest allocations, by what they hold (e.g. ``"Q tables"``).
        device: where they are allocated.
        advice: which values to lower, appended to the message.
    """
    total = sum(needs.values())
    available = available_memory(device)
    if total <= available:
        return
    parts = ", ".join(f"{what} {_gib(size)}" for what, size in sorted(needs.items(), key=lambda kv: -kv[1]) if size)
    raise ValueError(
        f"this run needs about {_gib(total)} of memory ({parts}), more than the {_gib(available)} available on "
        f"{device.type}: {advice}"
    )


def _gib(size: float) -> str:
    return f"{size / GIB:.3g} GiB"


def first_line(err: BaseException) -> str:
    """The first line of an error's message (its type's name when empty): what a one-line error quotes."""
    return (str(err).strip().splitlines() or [type(err).__name__])[0]


def duration(seconds: float) -> str:
    """``seconds`` in the unit a person reads: ``45 s``, ``12 min``, ``3.4 h``, ``5.2 days``, ``3.1e+03 years``."""
    for unit, size in (("years", YEAR_S), ("days", 86_400.0), ("h", 3_600.0), ("min", 60.0)):
        if seconds >= size:
            return f"{seconds / size:.3g} {unit}"
    return f"{seconds:.2g} s"

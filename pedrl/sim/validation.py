"""One-line validation of user values: each check names the bad value and what is allowed, before any compute."""

from __future__ import annotations

import math
from numbers import Integral, Real
from typing import Any

import torch


def check_integer(name: str, value: Any, *, minimum: int, maximum: int | None = None) -> int:
    """``value`` as an int in ``[minimum, maximum]``, else a one-line ``ValueError``."""
    allowed = f"an integer >= {minimum}" if maximum is None else f"an integer in [{minimum}, {maximum}]"
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


def check_choice(name: str, value: Any, allowed: tuple[str, ...]) -> str:
    """``value`` if it is one of ``allowed``, else a one-line ``ValueError`` listing them."""
    if not isinstance(value, str) or value not in allowed:
        raise ValueError(f"{name}={value!r} is invalid: must be one of {', '.join(allowed)}")
    return value


def check_device(value: Any) -> torch.device:
    """``value`` as a usable torch device, else a one-line ``ValueError``."""
    try:
        device = torch.device(value)
        torch.empty(1, device=device)
    except (RuntimeError, AssertionError, TypeError, ValueError) as error:
        reason = (str(error).strip().splitlines() or [type(error).__name__])[0].split(". ")[0][:100]
        raise ValueError(
            f"device={value!r} is invalid: must be a torch device available here, e.g. 'cpu' ({reason})"
        ) from None
    return device

"""Progress that reads well where it lands: a bar redrawn in place on a terminal, lines in a log.

A tqdm bar writes every redraw, each behind a carriage return; on a terminal they overwrite each other, in a log file
(``pedrl-eval ... 2> eval.log``, a batch job's output) they pile up by the thousand. :func:`progress_bar` gives the
bar on a terminal and, elsewhere, a :class:`LineProgress`: one plain line each time the count passes another
``every_pct`` percent of the total, and no more often than one line per ``min_seconds`` (a fast loop writes only its
last line, a slow one a line every few percent).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import Any, Protocol, TextIO

EVERY_PCT = 10
"""Off a terminal, a line each time the count passes another this many percent of the total."""
MIN_SECONDS = 5.0
"""Off a terminal, at most one line per this many seconds (the last line, at the total, is always written)."""


class Bar(Protocol):
    """What the callers use of a tqdm bar."""

    n: int

    def update(self, n: int = 1) -> Any: ...

    def set_postfix(self, refresh: bool = True, **values: Any) -> Any: ...

    def close(self) -> Any: ...


def interactive(stream: TextIO | None = None) -> bool:
    """Whether ``stream`` (stderr by default) is a terminal, where a bar redraws in place."""
    stream = sys.stderr if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    return bool(isatty and isatty())


class LineProgress:
    """A bar's stand-in for logs: ``<label>: 40 % (80/200 decisions, 12 s, at most 18 s left; agents_left=31)``
    lines; the time left is the pace so far over the rest of the count (at most: a crowd that empties ends early).

    Args:
        total: the count at which the work is done (> 0).
        label: what is counted, first on every line.
        unit: the unit of the count, plural (``decisions``).
        every_pct: a line each time the count passes another this many percent of ``total`` (None:
            :data:`EVERY_PCT`).
        min_seconds: at most one line per this many seconds, but for the one at ``total`` (None: :data:`MIN_SECONDS`).
        stream: where lines go (stderr by default).
        clock: seconds, for tests (``time.perf_counter`` by default).
    """

    def __init__(
        self,
        total: int,
        label: str,
        *,
        unit: str = "steps",
        every_pct: float | None = None,
        min_seconds: float | None = None,
        stream: TextIO | None = None,
        clock: Callable[[], float] = time.perf_counter,
    ) -> None:
        self.total = max(int(total), 1)
        self.label = label
        self.unit = unit
        self.every_pct = EVERY_PCT if every_pct is None else every_pct
        self.min_seconds = MIN_SECONDS if min_seconds is None else min_seconds
        self.stream = stream
        self.clock = clock
        self.n = 0
        self.postfix: dict[str, Any] = {}
        self.start = clock()
        self.last_line = self.start
        self.step_written = 0  # the last multiple of every_pct written
        self.closed = False

    def update(self, n: int = 1) -> None:
        """Count ``n`` more; write a line when another ``every_pct`` percent is passed (and ``min_seconds`` since the
        last line), or the total is reached."""
        self.n = min(self.n + int(n), self.total)
        step = int(100.0 * self.n / self.total // self.every_pct)
        now = self.clock()
        done = self.n >= self.total
        if step > self.step_written and (done or now - self.last_line >= self.min_seconds):
            self.step_written = step
            self.last_line = now
            self._write(now)

    def set_postfix(self, refresh: bool = True, **values: Any) -> None:
        """Values shown at the end of the next line (``agents_left=31``)."""
        del refresh  # lines are written on update only
        self.postfix = dict(values)

    def close(self) -> None:
        """Nothing more to write: a count that stopped short of the total (every agent out early) says nothing."""
        self.closed = True

    def _write(self, now: float) -> None:
        percent = 100.0 * self.n / self.total
        extra = "; " + ", ".join(f"{key}={value}" for key, value in self.postfix.items()) if self.postfix else ""
        spent = now - self.start
        left = f", at most {spent / self.n * (self.total - self.n):.0f} s left" if 0 < self.n < self.total else ""
        line = f"{self.label}: {percent:3.0f} % ({self.n}/{self.total} {self.unit}, {spent:.0f} s{left}{extra})"
        print(line, file=self.stream if self.stream is not None else sys.stderr, flush=True)


def progress_bar(total: int, label: str, *, unit: str, stream: TextIO | None = None) -> Bar:
    """A tqdm bar of ``total`` ``unit`` named ``label`` on a terminal (cleared when closed), else a
    :class:`LineProgress` (``stream``: stderr by default, and the stream whose terminal is asked)."""
    if interactive(stream):
        from tqdm import tqdm

        return tqdm(total=total, desc=label, unit=unit, dynamic_ncols=True, leave=False, file=stream)
    return LineProgress(total, label, unit=f"{unit}s", stream=stream)

"""What every command line shares, with no Hydra: user mistakes end in one line on stderr and exit code 2, never a
traceback.

The ``python -m`` tools (``pedrl.evaluation.resolution``, ``pedrl.evaluation.neighbours``,
``pedrl.validation.calibrate``, ``pedrl.bench``, ``pedrl.embed``) parse their arguments with :class:`OneLineParser`
and the types :func:`integer_arg` and :func:`number_arg`; the Hydra entry points build on these in :mod:`pedrl.cli`.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

CONFIG_DIR = str(Path(__file__).resolve().parents[2] / "conf")
"""The top-level ``conf/`` folder: the Hydra configs of every console command, and of the tests."""


def fail(program: str, message: str) -> NoReturn:
    """Print ``<program>: error: <first line of message>`` on stderr and exit with code 2."""
    print(f"{program}: error: {message.splitlines()[0] if message else 'invalid input'}", file=sys.stderr)
    sys.exit(2)


class OneLineParser(argparse.ArgumentParser):
    """The ``argparse`` parser of the ``python -m`` tools: a mistake on the command line (a missing argument, a value
    of the wrong type or out of bounds: :func:`integer_arg`, :func:`number_arg`) ends in one line and exit code 2,
    ``<prog>: error: argument --agents: '1e9' is invalid: must be an integer in [1, 1000]``, where argparse prints
    its usage first."""

    def error(self, message: str) -> NoReturn:
        fail(self.prog, f"{message} ({self.prog} --help lists the arguments)")


def integer_arg(low: int, high: int | None = None) -> Callable[[str], int]:
    """An argparse ``type``: an integer in ``[low, high]`` (``high`` None: no upper bound)."""
    allowed = f"an integer in [{low}, {high}]" if high is not None else f"an integer >= {low}"

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < low or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"{text!r} is invalid: must be {allowed}")
        return value

    return parse


def number_arg(low: float, high: float | None = None, *, low_open: bool = False) -> Callable[[str], float]:
    """An argparse ``type``: a finite number in ``[low, high]`` (``(low, high]`` if ``low_open``)."""
    bracket = "(" if low_open else "["
    allowed = (
        f"a number in {bracket}{low:g}, {high:g}]"
        if high is not None
        else f"a number {'>' if low_open else '>='} {low:g}"
    )

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        inside = math.isfinite(value) and (value > low if low_open else value >= low)
        if not inside or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"{text!r} is invalid: must be {allowed}")
        return value

    return parse


def describe_os_error(err: OSError, *, folder: Path | None = None) -> str:
    """One line naming the path a file-system error is about and the reason: ``cannot use '/x': Permission denied``.

    A write error that names no file (``ENOSPC`` at ``close``; pedrl's own writers name theirs, see
    :func:`pedrl.io.files.named`) names the folder being written in: ``folder``, else the working directory, where
    relative outputs go: ``cannot write in '/runs/a': No space left on device``.
    """
    if err.filename is not None:
        return f"cannot use {str(err.filename)!r}: {err.strerror or err}"
    where = folder if folder is not None else Path.cwd()
    return f"cannot write in {str(where)!r}: {err.strerror or err}"

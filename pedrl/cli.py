"""What the entry points share: user mistakes end in one line on stderr and exit code 2, never a traceback."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from pedrl.io import CheckpointError

T = TypeVar("T")


def run_reporting_errors(program: str, action: Callable[[], T]) -> T:
    """Run ``action``; a bad value, path or checkpoint, or a file that cannot be written (``OSError``), prints
    ``<program>: error: <one line>`` and exits with 2."""
    from hydra.errors import InstantiationException

    try:
        return action()
    except (ValueError, CheckpointError) as err:
        message = str(err)
    except InstantiationException as err:
        message = str(err.__cause__ or err)
    except OSError as err:  # a full disk, a folder without write permission: name the path
        message = f"{str(err.filename)!r}: {err.strerror}" if err.filename and err.strerror else str(err)
    print(f"{program}: error: {message.splitlines()[0] if message else 'invalid input'}", file=sys.stderr)
    sys.exit(2)


def hydra_output_dir() -> Path:
    """The run directory Hydra made for this run (every output goes under it)."""
    from hydra.core.hydra_config import HydraConfig

    return Path(HydraConfig.get().runtime.output_dir)

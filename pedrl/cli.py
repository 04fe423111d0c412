"""What the entry points share: user mistakes end in one line on stderr and exit code 2, never a traceback."""

from __future__ import annotations

import functools
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn, TypeVar

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from pedrl.io import CheckpointError

T = TypeVar("T")
PROGRAMS = {"train": "pedrl-train", "evaluate": "pedrl-eval", "plot": "pedrl-plot", "validate": "pedrl-validate"}
"""Console command of each Hydra job name (the module's name)."""


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
    except OSError as err:  # a read-only folder, a file where a folder should be, ...
        message = describe_os_error(err)
    fail(program, message)


def check_group_choices(
    program: str, args: list[str], config_dir: str | Path, groups: tuple[str, ...] | None = None
) -> None:
    """Refuse ``group=option`` overrides naming no file of ``conf/<group>/``, or a group the program does not
    compose (``groups``; ``None``: every group), with one line where Hydra would print a multi-line composition
    error: ``pedrl-train: error: scenario='mall' is invalid: must be one of ...``."""
    for arg in args:
        key, sep, value = arg.partition("=")
        key = key.lstrip("+~")
        if arg.startswith("-") or not sep or "." in key or not value or "(" in value:
            continue
        group = Path(config_dir) / key
        if not group.is_dir():
            continue
        if groups is not None and key not in groups and not key.startswith("hydra"):
            own = ", ".join(("hydra", *groups))
            fail(program, f"{key}={value!r} is invalid: {program} has no {key} group (its groups: {own})")
        options = sorted(path.stem for path in group.glob("*.yaml"))
        for option in value.split(","):  # a --multirun list
            if option not in options and option != "null":
                fail(program, f"{key}={option!r} is invalid: must be one of {', '.join(options)}")


def checked_groups(
    program: str, config_dir: str | Path, groups: tuple[str, ...] | None = None
) -> Callable[[Callable[..., T]], Callable[..., T]]:
    """Decorate a ``@hydra.main`` entry point: check its command line's group options first
    (:func:`check_group_choices`), when it is called as a console script (without arguments)."""

    def decorate(main: Callable[..., T]) -> Callable[..., T]:
        @functools.wraps(main)
        def run(*args: Any, **kwargs: Any) -> T:
            if not args and not kwargs:
                check_group_choices(program, sys.argv[1:], config_dir, groups)
            return main(*args, **kwargs)

        return run

    return decorate


def fail(program: str, message: str) -> NoReturn:
    """Print ``<program>: error: <first line of message>`` on stderr and exit with code 2."""
    print(f"{program}: error: {message.splitlines()[0] if message else 'invalid input'}", file=sys.stderr)
    sys.exit(2)


def describe_os_error(err: OSError) -> str:
    """One line naming the path a file-system error is about and the reason: ``cannot use '/x': Permission denied``."""
    path = err.filename if err.filename is not None else "?"
    return f"cannot use {str(path)!r}: {err.strerror or err}"


class OutputDirCheck(Callback):
    """Hydra callback: before Hydra creates the run (or sweep) directory, make sure it can be a writable folder.

    Hydra itself would fail there with a traceback; this ends in one line naming the path and exit code 2.
    """

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        self._check(config, config.hydra.run.dir)

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        self._check(config, config.hydra.sweep.dir)

    @staticmethod
    def _check(config: DictConfig, directory: Any) -> None:
        program = PROGRAMS.get(str(config.hydra.job.name), f"pedrl-{config.hydra.job.name}")
        problem = output_dir_problem(Path(str(directory)))
        if problem:
            fail(program, problem)


def output_dir_problem(directory: Path) -> str | None:
    """Why ``directory`` cannot hold a run's outputs (one line naming it), or None when it can.

    It is created if missing (with its parents), then a file is written into it and removed again: permission bits
    alone do not tell (root ignores them, a read-only mount does not show in them).
    """
    allowed = "must be a folder this user can write in (hydra.run.dir=...)"
    if directory.exists() and not directory.is_dir():
        return f"output folder {str(directory)!r} is invalid: it is a file; {allowed}"
    try:
        directory.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=directory):
            pass
    except OSError as err:
        reason = err.strerror or type(err).__name__
        return f"output folder {str(directory)!r} is invalid: {reason}; {allowed}"
    return None


def hydra_output_dir() -> Path:
    """The run directory Hydra made for this run (every output goes under it)."""
    from hydra.core.hydra_config import HydraConfig

    return Path(HydraConfig.get().runtime.output_dir)

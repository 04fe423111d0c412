"""What the Hydra entry points share: user mistakes end in one line on stderr and exit code 2, never a traceback.

Only the entry points (``pedrl.train``, ``evaluate``, ``validate``, ``plot``, ``export``, ``sweep``) import this module;
what a ``python -m`` tool needs too (``CONFIG_DIR``, ``fail``, the ``argparse`` helpers) is in
:mod:`pedrl.common.commands`, below every layer.
"""

from __future__ import annotations

import contextlib
import difflib
import functools
import os
import re
import sys
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, ClassVar, Final, TypeVar

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from pedrl.common import commands
from pedrl.common.checks import first_line
from pedrl.common.commands import CONFIG_DIR as CONFIG_DIR  # re-exported: the conf/ folder of every entry point
from pedrl.common.commands import fail
from pedrl.io import CheckpointError

T = TypeVar("T")
PROGRAMS = {"train": "pedrl-train", "evaluate": "pedrl-eval", "plot": "pedrl-plot", "validate": "pedrl-validate"}
"""Console command of each Hydra job name (the module's name)."""
CONFIG_NAMES = {
    "pedrl-train": "train",
    "pedrl-eval": "eval",
    "pedrl-plot": "plot",
    "pedrl-validate": "validate",
    "pedrl-export": "export",
}
"""Primary config (``conf/<name>.yaml``) of each console command."""


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
    except OSError as err:  # a read-only folder, a file where a folder should be, a full disk (named by its folder)
        message = describe_os_error(err)
    fail(program, message)


INTERNAL_GROUPS: Final = {"debug_algo": "algo", "debug_experiment": "experiment"}
"""Groups that ``debug=<name>`` chooses with the group beside it (``debug_experiment/<debug>_<experiment>.yaml``): a
patch for a debug run, never a choice of its own. Given alone, ``debug_experiment=default_main_dqn`` patched the
full default run (no debug budgets) and trained for ten minutes without a word; it is refused in one line."""


def internal_group_problem(key: str, value: str, config_dir: str | Path) -> str | None:
    """Why ``key=value`` may not be given on the command line (``key`` one of :data:`INTERNAL_GROUPS`), with the
    command that means it (``experiment=main_dqn debug=default``), or None for another key."""
    beside = INTERNAL_GROUPS.get(key)
    if beside is None:
        return None
    debugs = sorted((path.stem for path in (Path(config_dir) / "debug").glob("*.yaml")), key=len, reverse=True)
    debug = next((name for name in debugs if value.startswith(f"{name}_")), None)
    meant = f": run {beside}={value.removeprefix(f'{debug}_')} debug={debug}" if debug else ""
    return (
        f"{key}={value!r} is invalid: {key} is chosen by debug=<name> with {beside}=<name>, not given on the command"
        f" line (alone it patches the full run, not a debug one){meant}"
    )


def check_group_choices(
    program: str, args: list[str], config_dir: str | Path, groups: tuple[str, ...] | None = None
) -> None:
    """Refuse ``group=option`` overrides naming no file of ``conf/<group>/``, or a group the program does not
    compose (``groups``; ``None``: every group), with one line where Hydra would print a multi-line composition
    error: ``pedrl-train: error: scenario='mall' is invalid: must be one of ...``; and the groups that ``debug=``
    chooses itself (:data:`INTERNAL_GROUPS`)."""
    for arg in args:
        key, sep, value = arg.partition("=")
        key = key.lstrip("+~")
        if arg.startswith("-") or not sep or "." in key or not value or "(" in value:
            continue
        if (problem := internal_group_problem(key, value, config_dir)) is not None:
            fail(program, problem)
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


def check_added_keys(program: str, args: list[str], config_dir: str | Path, config_name: str) -> None:
    """Refuse a ``+key=value`` (or ``++key=value``) override whose key the composed config does not have: no code
    reads a key that is not in the config, so the value would be ignored without a word. One line naming it and the
    nearest key: ``pedrl-validate: error: +lanes_ratio=[5,1] is invalid: lanes_ratio is not a setting of
    pedrl-validate, and nothing reads an added key (its settings: ...)``. Group choices (``+experiment=main``) and
    Hydra's own keys are left to Hydra."""
    added = []
    for arg in args:
        key, sep, _ = arg.partition("=")
        if not arg.startswith("+") or not sep:
            continue
        key = key.lstrip("+")
        if key.startswith("hydra") or (Path(config_dir) / key).is_dir():
            continue
        added.append((arg, key))
    if not added:
        return
    config = _composed_config(config_dir, config_name, args)
    if config is None:
        return  # Hydra's own error follows
    for arg, key in added:
        parent, _, leaf = key.rpartition(".")
        node = OmegaConf.select(config, parent, default=None) if parent else config
        if OmegaConf.is_dict(node) and leaf in list(node.keys()):  # a key it has (its value may be ??? or null)
            continue
        near = nearest_key(key, config)
        if near is not None:
            hint = f"did you mean {near}=...?"
        else:
            names = [str(name) for name in node if str(name) != "hydra"] if OmegaConf.is_dict(node) else []
            hint = f"the keys of {parent or 'the config'}: {', '.join(sorted(names)[:20])}" if names else ""
        fail(
            program,
            f"{arg} is invalid: {key} is not a setting of {program}, and nothing reads an added key"
            + (f" ({hint})" if hint else ""),
        )


def checked_groups(
    program: str, config_dir: str | Path, groups: tuple[str, ...] | None = None, config_name: str | None = None
) -> Callable[[Callable[..., T]], Callable[..., T]]:
    """Decorate a ``@hydra.main`` entry point called as a console script (without arguments): check its command
    line's group options first (:func:`check_group_choices`), then run it with Hydra's own failures in one line
    (:func:`run_hydra_reporting_errors`). ``config_name``: its primary config (default from :data:`CONFIG_NAMES`)."""
    name = config_name or CONFIG_NAMES.get(program, program.removeprefix("pedrl-"))

    def decorate(main: Callable[..., T]) -> Callable[..., T]:
        @functools.wraps(main)
        def run(*args: Any, **kwargs: Any) -> T:
            if args or kwargs:
                return main(*args, **kwargs)
            check_group_choices(program, sys.argv[1:], config_dir, groups)
            check_added_keys(program, sys.argv[1:], config_dir, name)
            return run_hydra_reporting_errors(program, main, config_dir=config_dir, config_name=name)

        return run

    return decorate


def run_hydra_reporting_errors(program: str, main: Callable[[], T], *, config_dir: str | Path, config_name: str) -> T:
    """Run a ``@hydra.main`` entry point; what Hydra itself fails on ends in one line and exit code 2.

    - An unknown key (``env.widht=5``), a bad override or a group Hydra cannot compose:
      ``pedrl-train: error: env.widht is not a key of the config: did you mean env.width? (...)``
      (:func:`describe_hydra_error`), where Hydra prints six lines and exits with 1.
    - A run folder or ``.hydra/`` file Hydra cannot write (a full disk, a read-only mount): the path and the reason
      (:func:`describe_os_error`), where Hydra prints a traceback.
    - A Hydra key that cannot be resolved (``hydra.run.dir=${oops}``): the key and OmegaConf's reason.

    Any other exception is re-raised with its whole traceback: it is a bug, not a user's mistake.
    """
    from hydra.errors import ConfigCompositionException, OverrideParseException
    from omegaconf.errors import OmegaConfBaseException

    OutputDirCheck.folder = None  # not an earlier run's (tests run many in one process)
    try:
        with _hydra_raising():
            return main()
    except (ConfigCompositionException, OverrideParseException) as err:
        message = describe_hydra_error(err, config_dir=config_dir, config_name=config_name, argv=sys.argv[1:])
    except OmegaConfBaseException as err:  # a Hydra key that cannot be resolved: hydra.run.dir=${oops}
        reason = first_line(err)
        key = getattr(err, "full_key", None)
        message = f"{key} is invalid: {reason}" if key else reason
    except BrokenPipeError:  # stdout piped into a program that stopped reading (`pedrl-train --help | head`)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # Python's advice: no second error at exit
        sys.exit(1)
    except OSError as err:
        message = describe_os_error(err)
    except ValueError as err:  # logging.config: "Unable to configure handler 'file'" from the log file's OSError
        if not isinstance(err.__cause__, OSError):
            message = _describe_override_failure(err)
        else:
            message = describe_os_error(err.__cause__)
    except Exception as err:
        message = _describe_override_failure(err)
    fail(program, message)


@contextlib.contextmanager
def _hydra_raising() -> Iterator[None]:
    """Let exceptions out of ``@hydra.main`` instead of Hydra printing them and exiting with 1 (its documented
    ``HYDRA_FULL_ERROR=1``); the caller's setting comes back afterwards."""
    saved = os.environ.get("HYDRA_FULL_ERROR")
    os.environ["HYDRA_FULL_ERROR"] = "1"
    try:
        yield
    finally:
        if saved is None:
            os.environ.pop("HYDRA_FULL_ERROR", None)
        else:
            os.environ["HYDRA_FULL_ERROR"] = saved


def describe_hydra_error(err: Exception, *, config_dir: str | Path, config_name: str, argv: list[str]) -> str:
    """One line for a Hydra composition or override error.

    An unknown key names the key, the nearest key of the composed config and the ``+`` that adds a new one:
    ``env.widht is not a key of the config: did you mean env.width? (a new key needs +env.widht=...)``. Other
    errors (``+seed=1`` where ``seed`` exists, an override Hydra cannot parse) keep Hydra's words, on one line.
    """
    from omegaconf.errors import OmegaConfBaseException

    message = str(err)
    if isinstance(getattr(err, "override", None), str):  # OverrideParseException
        reason = (message.strip().splitlines() or ["cannot be parsed"])[0]
        return f"{err.override!r} is not a valid override ({reason}): write key=value, +key=value or ~key"
    override = re.match(r"Could not override '([^']+)'", message)
    full_key = getattr(err.__cause__, "full_key", None)
    if override is None or not full_key:
        text = " ".join(line.strip() for line in message.splitlines() if line.strip() and "hydra.cc/docs" not in line)
        if isinstance(err.__cause__, OmegaConfBaseException):
            text = f"{text.rstrip('.')}: {(str(err.__cause__).strip().splitlines() or [''])[0]}"
        return text or type(err).__name__
    key = str(full_key)
    from pedrl.configs.motion import command_line_advice  # a flat key of the motion model: its new spelling

    config = _composed_config(config_dir, config_name, argv)
    motion = OmegaConf.select(config, "env.motion", default=None) if config is not None else None
    motion = OmegaConf.to_container(motion) if OmegaConf.is_dict(motion) else None
    moved = command_line_advice(key, _typed_overrides(argv), motion)
    if moved is not None:
        return moved
    new_key = ""  # no `+key=` advice: an added key is refused too (check_added_keys), as nothing reads it
    if config is None:
        return f"{key} is not a key of the config" + (f" ({new_key})" if new_key else "")
    parent, _, _ = key.rpartition(".")
    parent_node = OmegaConf.select(config, parent, default=None) if parent else config
    if parent and not OmegaConf.is_dict(parent_node):
        return f"{key} is not a key of the config: {parent} is a value, not a group of keys"
    near = nearest_key(key, config)
    if near is not None:
        return f"{key} is not a key of the config: did you mean {near}?" + (f" ({new_key})" if new_key else "")
    keys = sorted(str(name) for name in parent_node if str(name) != "hydra")
    shown = ", ".join(keys[:20]) + (", ..." if len(keys) > 20 else "")
    where = f"the keys of {parent} are" if parent else "the top-level keys are"
    return f"{key} is not a key of the config: {where} {shown}" + (f"; {new_key}" if new_key else "")


def _typed_overrides(argv: list[str]) -> dict[str, Any]:
    """The command line's overrides, key to value as Hydra's grammar reads them (``4e-1`` a float); one Hydra cannot
    parse keeps its text."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    parser, typed = OverridesParser.create(), {}
    for item in argv:
        written, sep, text = item.lstrip("+~").partition("=")
        if not sep or written.startswith("-"):
            continue
        try:
            typed[written] = parser.parse_overrides([item])[0].value()
        except Exception:  # an override Hydra cannot parse is quoted as typed
            typed[written] = text
    return typed


def nearest_key(key: str, config: DictConfig) -> str | None:
    """The key of ``config`` a mistyped dotted ``key`` most likely means: a close name beside it
    (``env.widht`` -> ``env.width``), else a close dotted key anywhere (``num_prototypes`` -> ``vq.num_prototypes``),
    else a key anywhere whose last part is close (``widht`` -> ``env.width``); ``None`` if none is close."""
    parent, _, leaf = key.rpartition(".")
    node = OmegaConf.select(config, parent, default=None) if parent else config
    if OmegaConf.is_dict(node):
        beside = difflib.get_close_matches(leaf, [str(name) for name in node], n=1)
        if beside:
            return f"{parent}.{beside[0]}" if parent else beside[0]
    everywhere = [name for name in _dotted_keys(config) if key.startswith("hydra.") or not name.startswith("hydra")]
    anywhere = difflib.get_close_matches(key, everywhere, n=1, cutoff=0.8)
    if anywhere:
        return anywhere[0]
    leaves = {}  # the last part of every dotted key -> the first key ending in it
    for name in everywhere:
        leaves.setdefault(name.rpartition(".")[2], name)
    same_leaf = difflib.get_close_matches(leaf, list(leaves), n=1, cutoff=0.8)
    return leaves[same_leaf[0]] if same_leaf else None


def _dotted_keys(config: DictConfig) -> list[str]:
    """Every key of ``config`` as a dotted path, groups included (``env``, ``env.width``, ...)."""

    def walk(node: Any, prefix: str) -> Iterator[str]:
        if isinstance(node, dict):
            for name, child in node.items():
                yield f"{prefix}{name}"
                yield from walk(child, f"{prefix}{name}.")

    return list(walk(OmegaConf.to_container(config, resolve=False), ""))


def _composed_config(config_dir: str | Path, config_name: str, argv: list[str]) -> DictConfig | None:
    """The config the command line composes, with its group choices (the first option of a sweep list) and
    Hydra's own node, but none of its value overrides (one of them is what failed); ``None`` if it cannot be."""
    from hydra import compose, initialize_config_dir
    from hydra._internal.utils import get_args_parser
    from hydra.core.global_hydra import GlobalHydra

    try:
        args, _ = get_args_parser().parse_known_args(argv)
    except SystemExit:
        return None
    choices = []
    for item in args.overrides or []:
        key, sep, value = item.partition("=")
        if sep and value and "(" not in value and (Path(config_dir) / key.lstrip("+~")).is_dir():
            choices.append(f"{key}={value.split(',')[0]}")
    GlobalHydra.instance().clear()  # the failed run left it set up
    for overrides in (choices, []):
        try:
            with initialize_config_dir(version_base="1.3", config_dir=str(Path(config_dir).resolve())):
                return compose(args.config_name or config_name, overrides, return_hydra_config=True)
        except Exception:  # no suggestion is better than a second error
            continue
    return None


def _describe_override_failure(err: Exception) -> str:
    """One line for an error Hydra did not wrap, raised while it applied a command-line override
    (``env.speed_ratios.x=1``: OmegaConf's ``ValueError``); re-raises anything else, which is a bug."""
    traceback = err.__traceback__
    while traceback is not None:
        frame = traceback.tb_frame
        if frame.f_code.co_name == "_apply_overrides_to_config" and frame.f_globals.get("__name__", "").startswith(
            "hydra."
        ):
            line = getattr(frame.f_locals.get("override"), "input_line", None)
            reason = first_line(err)
            return f"{line!r} cannot be applied to the config ({reason})" if line else reason
        traceback = traceback.tb_next
    raise err


def describe_os_error(err: OSError) -> str:
    """One line naming the path a file-system error is about and the reason: ``cannot use '/x': Permission denied``.

    A write error that names no file (``ENOSPC`` at ``close``) names the run (or sweep) folder as
    :class:`OutputDirCheck` saw it, else the working directory (:func:`pedrl.common.commands.describe_os_error`):
    ``cannot write in '/runs/a': No space left on device``.
    """
    return commands.describe_os_error(err, folder=OutputDirCheck.folder)


class OutputDirCheck(Callback):
    """Hydra callback: before Hydra creates the run (or sweep) directory, make sure it can be a writable folder.

    Hydra itself would fail there with a traceback; this ends in one line naming the path and exit code 2.
    """

    folder: ClassVar[Path | None] = None
    """The folder last checked: a later write error that names no file (a full disk) is blamed on it."""

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        self._check(config, "hydra.run.dir")

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        self._check(config, "hydra.sweep.dir")

    @staticmethod
    def _check(config: DictConfig, key: str) -> None:
        from omegaconf.errors import OmegaConfBaseException

        program = PROGRAMS.get(str(config.hydra.job.name), f"pedrl-{config.hydra.job.name}")
        try:  # Hydra turns a callback's exception into a warning of five lines, and goes on
            directory = OmegaConf.select(config, key, throw_on_missing=True)
        except OmegaConfBaseException as err:  # hydra.run.dir=${oops}
            fail(program, f"{key} is invalid: {first_line(err)}")
        OutputDirCheck.folder = Path(str(directory))
        problem = output_dir_problem(OutputDirCheck.folder)
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

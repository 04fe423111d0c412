"""What a config may hold, typed or stored in a file, and the room it describes: no trainer is imported here.

A config (typed by a user, or stored in a checkpoint that someone shared) never names code: ``env._target_`` and
``algo._target_`` select one of the known classes, and every other ``_target_``, and every other Hydra
instantiation key (``_partial_``, ``_args_``, ``_recursive_``, ...), anywhere in the config, is refused. Rooms are
then built by calling :class:`pedrl.sim.RoomEnv` with the config's plain values, which its constructor validates
like any typed value; nothing is ever instantiated from a config node. The trainers a config may name are listed
here by name (:data:`ALGO_TARGETS`); :mod:`pedrl.algos.registry` maps them to their classes.

A config stored in a checkpoint is also bounded before anything walks it (:func:`check_stored_config`).
"""

from __future__ import annotations

import copy
import inspect
import os
import re
import shlex
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Final, NamedTuple

from pedrl.io import Checkpoint, CheckpointError, load_checkpoint, save_checkpoint
from pedrl.scenarios import MAX_WKT_BYTES, build_scenario, check_scenario_sizes, geometry_file, inline_geometry
from pedrl.sim import RoomEnv
from pedrl.sim.checks import shown

ENV_CLASSES: Final[dict[str, type[RoomEnv]]] = {"pedrl.sim.RoomEnv": RoomEnv, "pedrl.sim.env.RoomEnv": RoomEnv}
"""Allowed values of ``env._target_``."""
ALGO_TARGETS: Final[dict[str, str]] = {
    "pedrl.algos.VQQL": "vqql",
    "pedrl.algos.vqql.VQQL": "vqql",
    "pedrl.algos.ITVQQL": "it_vqql",
    "pedrl.algos.it_vqql.ITVQQL": "it_vqql",
    "pedrl.algos.INVQQL": "in_vqql",
    "pedrl.algos.in_vqql.INVQQL": "in_vqql",
}
"""Allowed values of ``algo._target_``, with the name of the algorithm each selects."""
KNOWN_TARGETS: Final = {"env._target_": ENV_CLASSES, "algo._target_": ALGO_TARGETS}
HISTORICAL_VALUES: Final = {
    "env.compile_sensing": False,
    "env.contact": "stop",
    "env.time_gap": 1.0,
    "algo.value_transfer": False,
    "algo.tables": "agent",
    "algo.void_draws": "decision",
    "vq.distance_transform": "none",
    "mix": [],
    "fused": False,
}
"""Keys added after checkpoints were first written, with the value the runs of older checkpoints had (one table per
agent, raw distances and void fillings drawn at every encode came before their keys; every trial ran the torch loop
before the fused one)."""
VOID_FEATURES_DEFAULTS: Final = {"vqql": "zero", "it_vqql": "random", "in_vqql": "zero"}
"""``algo.void_features`` of each algorithm when its config does not say (IT-VQQL fills void slots, section 5.1)."""
ENV_RUN_ARGUMENTS: Final = ("num_replicas", "num_agents", "device", "geometry")
"""Room arguments supplied at run time (not config values): the geometry comes from the ``scenario`` config."""
MAX_CONFIG_DEPTH: Final = 16
"""Deepest nesting of a stored config (a run's config is 4 deep: ``scenario.exits[0][1]``)."""
MAX_CONFIG_STRING: Final = 4096
"""Longest string (or key) of a stored config, bar ``scenario.geometry``, the room's WKT text (10 MB)."""
MAX_MIX: Final = 16
"""Most rooms of a ``mix`` (training across scenarios)."""
MAX_MIX_AGENTS: Final = 10_000
"""Most agents of a room of a ``mix``."""
MAX_CONFIG_VALUES: Final = 100_000
"""Most values (mappings, lists and leaves) of a stored config."""


class TrainingRoom(NamedTuple):
    """A room a run trains in besides its scenario's (``mix``): its label, its factory (:func:`env_factory`), its
    agents, its ``mix`` entry as a checkpoint stores it (a WKT file replaced by its text) and its longest distance
    (m, the room's diagonal)."""

    label: str
    factory: Callable[..., RoomEnv]
    num_agents: int
    config: dict[str, Any]
    max_distance: float


def check_names_no_code(config: Mapping[str, Any], *, stored: bool = False) -> None:
    """Refuse a config that names code or holds anything but plain values.

    Args:
        config: the resolved config, plain containers (``OmegaConf.to_container(cfg, resolve=True)``, or the
            ``config`` of a checkpoint's metadata).
        stored: the config comes from a file; it was resolved before it was saved, so an interpolation
            (``${...}``) in it was put there by hand and is refused too.

    Raises:
        ValueError: one line naming the key and what is allowed.
    """
    _walk(config, "", stored)


def _walk(node: Any, path: str, stored: bool) -> None:
    if isinstance(node, Mapping):
        for key, value in node.items():
            name = f"{path}{key}"
            if not isinstance(key, str):
                raise ValueError(f"config key {name!r} is invalid: keys must be strings")
            if key.startswith("_") and key.endswith("_") and len(key) > 1:
                _check_special_key(name, value)
                continue
            _walk(value, f"{name}.", stored)
    elif isinstance(node, list | tuple):
        for index, value in enumerate(node):
            _walk(value, f"{path.rstrip('.')}[{index}].", stored)
    elif isinstance(node, str):
        if stored and "${" in node:
            raise ValueError(f"{path.rstrip('.')}={node!r} is invalid: a stored config holds no interpolation")
    elif not (node is None or isinstance(node, bool | int | float)):
        raise ValueError(f"{path.rstrip('.')} holds a {type(node).__name__}: only plain values are allowed")


def _check_special_key(name: str, value: Any) -> None:
    known = KNOWN_TARGETS.get(name)
    if known is None:
        raise ValueError(
            f"{name} is not allowed: configs name no code (only env._target_ and algo._target_, "
            "which select a pedrl room and trainer)"
        )
    if not isinstance(value, str) or value not in known:
        raise ValueError(f"{name}={value!r} is invalid: must be one of {', '.join(known)}")


def env_factory(
    env: Mapping[str, Any], scenario: Mapping[str, Any] | None = None, *, files: bool = True
) -> Callable[..., RoomEnv]:
    """The room of the ``env`` config in the ``scenario``: ``factory(num_replicas=, num_agents=, device=)`` builds it.

    The scenario (``None``: the paper's room of the ``env`` keys) is built once, with shapely; each room is
    :meth:`pedrl.scenarios.Scenario.room`: validated, then its agents checked against the spawn areas.
    ``files=False`` (a config stored in a checkpoint) opens no file: its ``scenario.geometry`` must be WKT text.

    Raises:
        ValueError: one line, for a key the room does not take or a bad scenario (values are validated when the room
            is built).
    """
    settings = config_settings("env", env, ENV_CLASSES, supplied=ENV_RUN_ARGUMENTS)
    built = build_scenario(scenario, room=settings, files=files)

    def factory(*, num_replicas: int, num_agents: int, device: str | Any = "cpu") -> RoomEnv:
        return built.room(num_replicas=num_replicas, num_agents=num_agents, device=device, **settings)

    factory.scenario = built  # type: ignore[attr-defined]
    return factory


def config_settings(
    section: str, node: Any, classes: Mapping[str, type], *, supplied: tuple[str, ...]
) -> dict[str, Any]:
    if not isinstance(node, Mapping):
        raise ValueError(f"{section}={node!r} is invalid: must be a mapping with a _target_")
    target = node.get("_target_")
    if not isinstance(target, str) or target not in classes:
        raise ValueError(f"{section}._target_={target!r} is invalid: must be one of {', '.join(classes)}")
    allowed = [name for name in _parameters(classes[target]) if name not in supplied]
    settings = {key: value for key, value in node.items() if key != "_target_"}
    for key in settings:
        if key not in allowed:
            raise ValueError(f"{section}.{key} is not a setting of {target}: allowed: {', '.join(allowed)}")
    return settings


def _parameters(cls: type) -> list[str]:
    """Keyword parameters of ``cls``, following ``**kwargs`` up to the base classes' constructors."""
    names: list[str] = []
    for klass in cls.__mro__:
        if "__init__" not in vars(klass) or klass is object:
            continue
        parameters = inspect.signature(klass.__init__).parameters.values()
        names += [p.name for p in parameters if p.name != "self" and p.kind is p.KEYWORD_ONLY and p.name not in names]
        if not any(p.kind is p.VAR_KEYWORD for p in parameters):
            break
    return names


def check_stored_config(checkpoint: Checkpoint, *, kind: str = "checkpoint") -> dict[str, Any]:
    """The training config stored in ``checkpoint`` (a ``kind`` of file: ``checkpoint`` or ``policy``, for the
    messages), refused if it is not a mapping of plain values or names code.

    It is bounded before anything walks it (:data:`MAX_CONFIG_DEPTH`, :data:`MAX_CONFIG_STRING`,
    :data:`MAX_CONFIG_VALUES`, and the scenario's exits and spawn areas), and it must hold its room: a
    ``scenario.geometry`` that names a WKT file (checkpoints written before rooms were stored) is refused with the
    command that re-exports the checkpoint, since pedrl opens no file a checkpoint names.

    Raises:
        CheckpointError: one line naming the file and the bad key.
    """
    return checked_config(checkpoint.metadata.get("config"), f"{kind} {str(checkpoint.path)!r}", checkpoint.path)


def checked_config(config: Any, where: str, path: Path | None = None) -> dict[str, Any]:
    """:func:`check_stored_config` of a ``config`` read from the file ``path`` (``where`` names it in messages)."""
    if not isinstance(config, dict) or not all(isinstance(config.get(key), dict) for key in ("env", "algo")):
        raise CheckpointError(f"{where} holds no training config (a mapping with env and algo) to rebuild its run")
    mix = config.get("mix") if isinstance(config.get("mix"), list) else []
    try:
        check_scenario_sizes(config.get("scenario"))  # counts only: first, for the clearest line
        if len(mix) > MAX_MIX:
            raise ValueError(f"mix holds {len(mix)} rooms: at most {MAX_MIX}")
        for entry in mix:
            check_scenario_sizes(entry)
        _check_config_size(config)
        wkt_file = geometry_file(config.get("scenario"))
        if wkt_file is None:
            check_names_no_code(config, stored=True)
    except ValueError as err:
        raise CheckpointError(f"{where} holds a config that is refused: {err}") from None
    if wkt_file is not None:
        raise CheckpointError(
            f"{where} names its room's WKT file (scenario.geometry={shown(wkt_file)}) instead of holding the room,"
            " and pedrl opens no file a checkpoint names: re-export it with `python -m pedrl.embed"
            f" {shlex.quote(str(path))} ROOM.wkt` (ROOM.wkt: the file it was trained on)"
        )
    return config


def mix_rooms(env: Mapping[str, Any], mix: Any, *, home: str = "room", files: bool = True) -> list[TrainingRoom]:
    """The rooms of a ``mix`` config: a list of scenario configs (``name`` and the builder's keys, as in
    ``conf/scenario/``), each with the ``agents`` it holds; each room is the ``env`` config's, in its scenario.

    Labels (the TensorBoard tags and the ``room`` column of ``learning_curve.csv``) are ``<name>_<agents>``, with
    ``_<index>`` added where two would be the same; the run's own room is labelled ``home``, its scenario's name.

    Raises:
        ValueError: one line naming ``mix[i]`` and the bad value.
    """
    if mix is None:
        return []
    if not isinstance(mix, list | tuple):
        raise ValueError(
            f"mix={shown(mix)} is invalid: must be a list of scenarios, e.g. [{{name: corridor, agents: 40}}]"
        )
    if len(mix) > MAX_MIX:
        raise ValueError(f"mix holds {len(mix)} rooms: at most {MAX_MIX}")
    rooms, labels = [], {home}
    for index, entry in enumerate(mix):
        where = f"mix[{index}]"
        if not isinstance(entry, Mapping) or not isinstance(entry.get("name"), str):
            raise ValueError(
                f"{where}={shown(entry)} is invalid: must be a scenario config with a name and agents, e.g. "
                "{name: corridor, agents: 40}"
            )
        agents = entry.get("agents")
        if isinstance(agents, bool) or not isinstance(agents, int) or not 1 <= agents <= MAX_MIX_AGENTS:
            raise ValueError(f"{where}.agents={shown(agents)} is invalid: must be an integer in [1, {MAX_MIX_AGENTS}]")
        try:
            scenario = inline_geometry({key: value for key, value in entry.items() if key != "agents"}, files=files)
            factory = env_factory(env, scenario, files=files)
            max_distance = factory(num_replicas=1, num_agents=agents).max_distance  # the agents must fit
        except ValueError as err:
            raise ValueError(f"{where}: {err}") from None
        label = f"{scenario['name']}_{agents}"
        label = label if label not in labels else f"{label}_{index}"
        labels.add(label)
        rooms.append(TrainingRoom(label, factory, agents, {**scenario, "agents": agents}, max_distance))
    return rooms


def _check_config_size(config: dict[str, Any]) -> None:
    """Refuse a stored config nested too deep, too large or holding too long a string, walking it without
    recursion (a 600-deep list must give one line, not a RecursionError)."""
    stack: list[tuple[Any, str, int]] = [(config, "", 0)]
    count = 0
    while stack:
        node, path, depth = stack.pop()
        count += 1
        if count > MAX_CONFIG_VALUES:
            raise ValueError(f"it holds more than {MAX_CONFIG_VALUES} values")
        if depth > MAX_CONFIG_DEPTH:
            raise ValueError(f"{_cut(path)} is nested deeper than {MAX_CONFIG_DEPTH} levels")
        if isinstance(node, dict):
            for key, value in node.items():
                if isinstance(key, str) and len(key) > MAX_CONFIG_STRING:
                    raise ValueError(f"config key {shown(key)} is invalid: at most {MAX_CONFIG_STRING} characters")
                stack.append((value, f"{path}.{key}" if path else str(key), depth + 1))
        elif isinstance(node, list):
            stack.extend((value, f"{path}[{index}]", depth + 1) for index, value in enumerate(node))
        elif isinstance(node, str):
            most = MAX_WKT_BYTES if _is_geometry_path(path) else MAX_CONFIG_STRING
            if len(node) > most:
                raise ValueError(f"{_cut(path)}={shown(node)} is invalid: at most {most} characters")


def _is_geometry_path(path: str) -> bool:
    """``scenario.geometry`` or ``mix[i].geometry``: where a stored config holds a room's WKT text."""
    return path == "scenario.geometry" or re.fullmatch(r"mix\[\d+\]\.geometry", path) is not None


def _cut(path: str) -> str:
    return path if len(path) <= 120 else path[:120] + "..."


def embed_geometry(path: str | os.PathLike, wkt: str | os.PathLike, *, output: str | os.PathLike | None = None) -> Path:
    """Re-export a checkpoint that names its room's WKT file (``scenario.geometry``, written before rooms were
    stored) with that room's WKT text in its stored config; ``python -m pedrl.embed`` runs it.

    ``wkt`` is read once, under the bounds of :func:`pedrl.scenarios.read_wkt`, and the stored exits and spawn areas
    must fit its polygon. Tensors and every other value are kept; the file is written atomically, to ``output``
    (default: in place).

    Raises:
        CheckpointError: one line, for a checkpoint that names no WKT file, a bad WKT file, or a room its stored
            exits do not fit.
    """
    source = load_checkpoint(path)
    where = f"checkpoint {str(source.path)!r}"
    config = copy.deepcopy(source.metadata.get("config"))
    scenario = config.get("scenario") if isinstance(config, dict) else None
    if geometry_file(scenario) is None:
        raise CheckpointError(f"{where} names no WKT file (scenario.geometry): there is nothing to re-export")
    try:
        scenario = inline_geometry({**scenario, "geometry": str(wkt)})
        build_scenario(scenario, files=False)  # the stored exits and spawn areas must fit the polygon
    except ValueError as err:
        raise CheckpointError(f"cannot re-export {where}: {err}") from None
    config["scenario"] = scenario
    header = ("format", "format_version", "pedrl_version")  # written anew by save_checkpoint
    metadata = {key: value for key, value in source.metadata.items() if key not in header} | {"config": config}
    destination = Path(output) if output is not None else source.path
    check_stored_config(Checkpoint(tensors=source.tensors, metadata=metadata, path=destination))
    return save_checkpoint(destination, tensors=source.tensors, metadata=metadata)


# ---------------------------------------------------------------------- metadata


def stored_value(config: Mapping[str, Any], key: str) -> Any:
    """The value of the dotted ``key`` (``"algo.tables"``) in a stored ``config``, else its
    :data:`HISTORICAL_VALUES` entry (``KeyError`` if neither)."""
    section, _, name = key.partition(".")
    node = config.get(section)
    if isinstance(node, Mapping) and name in node:
        return node[name]
    return HISTORICAL_VALUES[key]

"""A config stored in a checkpoint or a policy file: bounded and checked before anything walks it
(:func:`check_stored_config`), and read with the values of its time for keys added since (:data:`HISTORICAL_VALUES`,
:func:`stored_value`, :func:`stored_env`).
"""

from __future__ import annotations

import copy
import re
import shlex
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Final

from pedrl.common.checks import shown
from pedrl.configs.motion import FLAT_KEYS, check_no_flat_keys, flat_motion, is_flat
from pedrl.configs.names import ENV_CLASSES, check_names_no_code
from pedrl.configs.rooms import MAX_MIX, ROOM_SETTINGS
from pedrl.io import Checkpoint, CheckpointError
from pedrl.scenarios import MAX_WKT_BYTES, check_scenario_sizes, geometry_file

HISTORICAL_VALUES: Final = {
    "env.compile_sensing": False,
    "env.contact": "stop",  # the flat keys of the motion model (pedrl.configs.motion), before env.motion named one
    "env.time_gap": 1.0,
    "env.motion": "step",
    "env.reward_deviation": 0.0,
    "env.deviation_turn": 1.0,
    "env.deviation_radius": 0.0,
    "env.deviation_gate": "company",
    "env.reward_passing": 0.0,
    "env.passing_radius": 4.0,
    "env.passing_band": 0.8,
    "env.passing_side": "either",
    "algo.value_transfer": False,
    "algo.head": "joint",
    "algo.replay_balance": "none",
    "algo.neighbour_velocity": False,
    "algo.n_step": 1,
    "algo.heading_prior": 0.0,
    "algo.prior_radius": 0.0,
    "algo.company_heading": "none",
    "algo.tables": "agent",
    "algo.void_draws": "decision",
    "vq.distance_transform": "none",
    "mix": [],
    "fused": False,
}
"""Keys added after checkpoints were first written, with the value the runs of older checkpoints had (one table per
agent, raw distances and void fillings drawn at every encode came before their keys; every trial ran the torch loop
before the fused one; the neural learner's first networks had the joint head, a uniform memory and the 28 features
alone and one-step returns; no run paid for deviation or passing before its key)."""
MAX_CONFIG_DEPTH: Final = 16
"""Deepest nesting of a stored config (a run's config is 4 deep: ``scenario.exits[0][1]``)."""
MAX_CONFIG_STRING: Final = 4096
"""Longest string (or key) of a stored config, bar ``scenario.geometry``, the room's WKT text (10 MB)."""
MAX_CONFIG_VALUES: Final = 100_000
"""Most values (mappings, lists and leaves) of a stored config."""


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


def check_config_bounds(config: Any, where: str) -> dict[str, Any]:
    """A stored ``config`` bounded before anything walks it (its rooms' sizes, depth, values, strings): one-line
    ``CheckpointError`` naming ``where`` (the file) otherwise. Every reader of a stored config starts here."""
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
    except ValueError as err:
        raise CheckpointError(f"{where} holds a config that is refused: {err}") from None
    return config


def checked_config(config: Any, where: str, path: Path | None = None) -> dict[str, Any]:
    """:func:`check_stored_config` of a ``config`` read from the file ``path`` (``where`` names it in messages)."""
    check_config_bounds(config, where)
    try:
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


def stored_value(config: Mapping[str, Any], key: str) -> Any:
    """The value of the dotted ``key`` (``"algo.tables"``) in a stored ``config``, else its
    :data:`HISTORICAL_VALUES` entry (``KeyError`` if neither)."""
    section, _, name = key.partition(".")
    node = config.get(section)
    if isinstance(node, Mapping) and name in node:
        return node[name]
    return HISTORICAL_VALUES[key]


def stored_env(config: Mapping[str, Any]) -> dict[str, Any]:
    """The ``env`` settings of a stored ``config`` as the run had them, in today's form: a key it lacks that the room
    takes and that was added since (:data:`HISTORICAL_VALUES`: ``compile_sensing``, ...) gets the value of its time,
    not the room's current default; the flat keys that described the motion model before ``env.motion`` named one
    (``contact``, ``collision_rule``, ``time_gap``, ``motion: step``, ...) become the model they gave, as a
    ``motion`` node (:func:`pedrl.configs.motion.flat_motion`; a flat key it lacks: the value of its time). Every room
    or encoder rebuilt from a stored config starts from these settings.

    Raises:
        ValueError: one line, for flat keys that make no model (a crafted file).
    """
    env = dict(config["env"])
    if is_flat(env):
        if isinstance(env.get("motion"), Mapping):  # both forms at once: written by hand
            check_no_flat_keys(env)
        flat = {key: env.pop(key) for key in FLAT_KEYS if key in env}
        for key in FLAT_KEYS:
            if key not in flat and f"env.{key}" in HISTORICAL_VALUES:
                flat[key] = HISTORICAL_VALUES[f"env.{key}"]
        env["motion"] = flat_motion(flat).to_config()
    target = env.get("_target_")
    taken = ROOM_SETTINGS if isinstance(target, str) and target in ENV_CLASSES else ()  # else refused with the room
    for key, value in HISTORICAL_VALUES.items():
        section, _, name = key.partition(".")
        if section == "env" and name not in env and name in taken:
            env[name] = copy.deepcopy(value)
    return env


def current_form(config: Mapping[str, Any]) -> dict[str, Any]:
    """A stored ``config`` with its ``env`` in today's form (:func:`stored_env`), the rest as it was written: what a
    resumed run compares with its own config."""
    return {**config, "env": stored_env(config)}

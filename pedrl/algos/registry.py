"""The only classes a config may name, and the checks that keep configs from naming anything else.

A config (typed by a user, or stored in a checkpoint that someone shared) never names code: ``env._target_`` and
``algo._target_`` select one of the known classes below, and every other ``_target_``, and every other Hydra
instantiation key (``_partial_``, ``_args_``, ``_recursive_``, ...), anywhere in the config, is refused. Rooms and
trainers are then built by calling these classes with the config's plain values, which their constructors
validate like any typed value; nothing is ever instantiated from a config node.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Mapping
from typing import Any, Final

from pedrl.algos.base import Trainer, VQSettings
from pedrl.algos.in_vqql import INVQQL
from pedrl.algos.it_vqql import ITVQQL
from pedrl.algos.vqql import VQQL
from pedrl.scenarios import build_scenario
from pedrl.sim import RoomEnv

ENV_CLASSES: Final[dict[str, type[RoomEnv]]] = {"pedrl.sim.RoomEnv": RoomEnv, "pedrl.sim.env.RoomEnv": RoomEnv}
"""Allowed values of ``env._target_``."""
TRAINER_CLASSES: Final[dict[str, type[Trainer]]] = {
    "pedrl.algos.VQQL": VQQL,
    "pedrl.algos.vqql.VQQL": VQQL,
    "pedrl.algos.ITVQQL": ITVQQL,
    "pedrl.algos.it_vqql.ITVQQL": ITVQQL,
    "pedrl.algos.INVQQL": INVQQL,
    "pedrl.algos.in_vqql.INVQQL": INVQQL,
}
"""Allowed values of ``algo._target_``."""
KNOWN_TARGETS: Final = {"env._target_": ENV_CLASSES, "algo._target_": TRAINER_CLASSES}
ENV_RUN_ARGUMENTS: Final = ("num_replicas", "num_agents", "device", "geometry")
"""Room arguments supplied at run time (not config values): the geometry comes from the ``scenario`` config."""
TRAINER_RUN_ARGUMENTS: Final = (
    "env",
    "vq",
    "processes",
    "rooms_per_process",
    "checkpoint_every",
    "device",
    "seed",
    "run_dir",
    "tensorboard",
    "progress",
    "run_config",
)
"""Trainer arguments that come from other parts of the config than ``algo``."""


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
    settings = _settings("env", env, ENV_CLASSES, supplied=ENV_RUN_ARGUMENTS)
    built = build_scenario(scenario, room=settings, files=files)

    def factory(*, num_replicas: int, num_agents: int, device: str | Any = "cpu") -> RoomEnv:
        return built.room(num_replicas=num_replicas, num_agents=num_agents, device=device, **settings)

    factory.scenario = built  # type: ignore[attr-defined]
    return factory


def trainer_class(algo: Mapping[str, Any]) -> tuple[type[Trainer], dict[str, Any]]:
    """The trainer class named by ``algo._target_`` and its settings from the ``algo`` config.

    Raises:
        ValueError: one line, for a key the trainer does not take.
    """
    settings = _settings("algo", algo, TRAINER_CLASSES, supplied=TRAINER_RUN_ARGUMENTS)
    return TRAINER_CLASSES[algo["_target_"]], settings


def vq_settings(vq: Mapping[str, Any]) -> dict[str, Any]:
    """The ``vq`` config as :class:`pedrl.algos.VQSettings` keyword arguments (one line for an unknown key)."""
    if not isinstance(vq, Mapping):
        raise ValueError(f"vq={vq!r} is invalid: must be a mapping of quantizer settings")
    VQSettings.from_config(vq)
    return dict(vq)


def _settings(section: str, node: Any, classes: Mapping[str, type], *, supplied: tuple[str, ...]) -> dict[str, Any]:
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

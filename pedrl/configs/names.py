"""What a config may name: the room and trainer classes ``env._target_`` and ``algo._target_`` select, and the check
that a config names no other code (:func:`check_names_no_code`).

The trainers a config may name are listed here by name (:data:`ALGO_TARGETS`); :mod:`pedrl.algos.registry` maps
them to their classes, so that nothing here imports a trainer.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Final

from pedrl.sim import RoomEnv

ENV_CLASSES: Final[dict[str, type[RoomEnv]]] = {"pedrl.sim.RoomEnv": RoomEnv, "pedrl.sim.env.RoomEnv": RoomEnv}
"""Allowed values of ``env._target_``."""
ALGO_TARGETS: Final[dict[str, str]] = {
    "pedrl.algos.VQQL": "vqql",
    "pedrl.algos.vqql.VQQL": "vqql",
    "pedrl.algos.ITVQQL": "it_vqql",
    "pedrl.algos.it_vqql.ITVQQL": "it_vqql",
    "pedrl.algos.INVQQL": "in_vqql",
    "pedrl.algos.in_vqql.INVQQL": "in_vqql",
    "pedrl.algos.DQN": "dqn",
    "pedrl.algos.dqn.DQN": "dqn",
    "pedrl.algos.PPO": "ppo",
    "pedrl.algos.ppo.PPO": "ppo",
}
"""Allowed values of ``algo._target_``, with the name of the algorithm each selects."""
KNOWN_TARGETS: Final = {"env._target_": ENV_CLASSES, "algo._target_": ALGO_TARGETS}
VOID_FEATURES_DEFAULTS: Final = {"vqql": "zero", "it_vqql": "random", "in_vqql": "zero", "dqn": "zero", "ppo": "zero"}
"""``algo.void_features`` of each algorithm when its config does not say (IT-VQQL fills void slots, section 5.1)."""


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

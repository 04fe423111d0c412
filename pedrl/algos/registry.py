"""The trainer classes a config may name, by the names :data:`pedrl.configs.ALGO_TARGETS` allows.

The checks that keep configs from naming code, and the room a config describes, are in :mod:`pedrl.configs`, which
imports no trainer (evaluation reads checkpoints through it); this module adds the classes.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, Final

from omegaconf import DictConfig, OmegaConf

from pedrl.algos.dqn import DQN
from pedrl.algos.in_vqql import INVQQL
from pedrl.algos.it_vqql import ITVQQL
from pedrl.algos.ppo import PPO
from pedrl.algos.run import RUN_KEYS, LearningRun, RunSpec
from pedrl.algos.vqql import VQQL
from pedrl.common.checks import MAX_SEED, check_integer
from pedrl.configs import (
    ALGO_TARGETS,
    ENV_CLASSES,
    ENV_RUN_ARGUMENTS,
    check_names_no_code,
    config_settings,
    env_factory,
    mix_rooms,
)
from pedrl.scenarios import inline_geometry
from pedrl.vq.settings import VQSettings

__all__ = [
    "ENV_CLASSES",
    "ENV_RUN_ARGUMENTS",
    "RUN_KEYS",
    "TRAINER_CLASSES",
    "build_trainer",
    "check_names_no_code",
    "env_factory",
    "trainer_class",
    "vq_settings",
]

TRAINER_CLASSES: Final[dict[str, type[LearningRun]]] = {
    "pedrl.algos.VQQL": VQQL,
    "pedrl.algos.vqql.VQQL": VQQL,
    "pedrl.algos.ITVQQL": ITVQQL,
    "pedrl.algos.it_vqql.ITVQQL": ITVQQL,
    "pedrl.algos.INVQQL": INVQQL,
    "pedrl.algos.in_vqql.INVQQL": INVQQL,
    "pedrl.algos.DQN": DQN,
    "pedrl.algos.dqn.DQN": DQN,
    "pedrl.algos.PPO": PPO,
    "pedrl.algos.ppo.PPO": PPO,
}
"""The class of each allowed value of ``algo._target_`` (the keys of :data:`pedrl.configs.ALGO_TARGETS`)."""
assert set(TRAINER_CLASSES) == set(ALGO_TARGETS) and all(
    ALGO_TARGETS[target] == cls.name for target, cls in TRAINER_CLASSES.items()
)


def trainer_class(algo: Mapping[str, Any]) -> tuple[type[LearningRun], dict[str, Any]]:
    """The trainer class named by ``algo._target_`` and its settings from the ``algo`` config.

    Raises:
        ValueError: one line, for a key the trainer does not take.
    """
    settings = config_settings("algo", algo, TRAINER_CLASSES, supplied=RUN_KEYS)
    return TRAINER_CLASSES[algo["_target_"]], settings


def vq_settings(vq: Mapping[str, Any]) -> dict[str, Any]:
    """The ``vq`` config as :class:`pedrl.algos.VQSettings` keyword arguments (one line for an unknown key)."""
    if not isinstance(vq, Mapping):
        raise ValueError(f"vq={vq!r} is invalid: must be a mapping of quantizer settings")
    VQSettings.from_config(vq)
    return dict(vq)


def build_trainer(cfg: DictConfig, run_dir: str | Path, *, files: bool = True) -> LearningRun:
    """Build the trainer of ``cfg.algo`` on the run the rest of ``cfg`` describes (a :class:`RunSpec`: the room of
    ``cfg.env``, the mix, processes, device, seed, ...); validates every value first.

    Only the known room and trainer classes are built (:mod:`pedrl.algos.registry`): a config names no code, so
    a ``_target_`` other than theirs, anywhere, is refused, and nothing is instantiated from a config node.
    A custom room's WKT file (``scenario.geometry``) is read once, here, and the run config, which every checkpoint
    stores, holds its WKT text instead of the path. ``files=False`` (a config read from a checkpoint) opens no file.
    """
    _check_top_level(cfg)
    config = OmegaConf.to_container(cfg, resolve=True)
    check_names_no_code(config)
    if isinstance(config.get("scenario"), dict):
        config["scenario"] = inline_geometry(config["scenario"], files=files)
    trainer, settings = trainer_class(config["algo"])
    scenario = config.get("scenario") or {}
    home = str(scenario.get("name", "paper_room"))
    mix = mix_rooms(config["env"], config.get("mix"), home=home, files=files)
    config["mix"] = [room.config for room in mix]  # a WKT file's text, not its name; null is []
    run = RunSpec(
        env=env_factory(config["env"], config.get("scenario"), files=files),
        mix=mix,
        home=home,
        vq=vq_settings(config["vq"]),
        processes=config["processes"],
        rooms_per_process=config["rooms_per_process"],
        checkpoint_every=config["checkpoint_every"],
        device=config["device"],
        seed=config["seed"],
        run_dir=str(run_dir),
        tensorboard=config["logger"]["tensorboard"],
        walking_probes=config["logger"].get("walking_probes", 0),
        progress=config["progress"],
        run_config=config,
        fused=config.get("fused"),
    )
    return trainer(run, **settings)


def _check_top_level(cfg: DictConfig) -> None:
    if cfg.get("threads") is not None:
        check_integer("threads", cfg.get("threads"), minimum=1)
    for key, minimum in (("processes", 1), ("rooms_per_process", 1), ("checkpoint_every", 0)):
        check_integer(key, cfg.get(key), minimum=minimum)
    check_integer("seed", cfg.get("seed"), minimum=0, maximum=MAX_SEED)

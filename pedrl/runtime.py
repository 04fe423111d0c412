"""What the entry points share to run a job: the trainer a config describes, and torch's CPU thread count.

``pedrl-train`` builds its trainer with :func:`build_trainer`; ``pedrl-eval`` rebuilds the trainer of a checkpoint
with it (the trainer knows how observations are quantized). Both set torch's threads with :func:`set_threads`.
Entry points import this module, never each other.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch
from omegaconf import DictConfig, OmegaConf

from pedrl.algos import Trainer
from pedrl.algos.registry import check_names_no_code, env_factory, trainer_class, vq_settings
from pedrl.scenarios import inline_geometry
from pedrl.sim.checks import MAX_SEED, check_integer


def build_trainer(cfg: DictConfig, run_dir: str | Path, *, files: bool = True) -> Trainer:
    """Build the trainer of ``cfg.algo`` with the room of ``cfg.env``; validates every value first.

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
    return trainer(
        **settings,
        env=env_factory(config["env"], config.get("scenario"), files=files),
        vq=vq_settings(config["vq"]),
        processes=config["processes"],
        rooms_per_process=config["rooms_per_process"],
        checkpoint_every=config["checkpoint_every"],
        device=config["device"],
        seed=config["seed"],
        run_dir=str(run_dir),
        tensorboard=config["logger"]["tensorboard"],
        progress=config["progress"],
        run_config=config,
    )


def _check_top_level(cfg: DictConfig) -> None:
    if cfg.get("threads") is not None:
        check_integer("threads", cfg.get("threads"), minimum=1)
    for key, minimum in (("processes", 1), ("rooms_per_process", 1), ("checkpoint_every", 0)):
        check_integer(key, cfg.get(key), minimum=minimum)
    check_integer("seed", cfg.get("seed"), minimum=0, maximum=MAX_SEED)


def set_threads(threads: int | None) -> None:
    """Set torch's CPU thread count (None: leave torch's default); validated by :func:`build_trainer`."""
    if threads is not None and torch.get_num_threads() != threads:
        torch.set_num_threads(threads)


def launcher_threads() -> int | None:
    """This job's share of the cores when it runs under ``hydra/launcher=parallel``: ``cores // n_jobs`` (at least 1),
    so that the jobs running side by side do not each spin one OpenMP thread per core against each other; None
    otherwise (a single run, or another launcher: torch's default)."""
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return None
    launcher = HydraConfig.get().get("launcher") or {}
    if "joblib" not in str(launcher.get("_target_", "")).lower():
        return None
    return share_of_cores(launcher.get("n_jobs"), available_cores())


def available_cores() -> int:
    """CPU cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def share_of_cores(n_jobs: Any, cores: int) -> int:
    """Threads per job when ``n_jobs`` jobs share ``cores`` cores: ``cores // jobs``, at least 1.

    ``n_jobs`` follows joblib: a positive count, ``-1`` one job per core, ``-2`` all cores but one, and so on;
    None counts as one job.
    """
    jobs = 1 if n_jobs is None else int(n_jobs)
    if jobs < 0:
        jobs = max(1, cores + 1 + jobs)
    return max(1, cores // max(1, jobs))

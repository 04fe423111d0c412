"""What the entry points share to run a job: torch's CPU thread count, alone or in a parallel sweep.

``pedrl-train``, ``pedrl-eval`` and ``pedrl-validate`` set torch's threads with :func:`set_threads`. Entry points import
this module, never each other; the trainer a config describes is built by :func:`pedrl.algos.registry.build_trainer`.
"""

from __future__ import annotations

import os
from typing import Any

import torch


def set_threads(threads: int | None) -> None:
    """Set torch's CPU thread count (None: leave torch's default); each entry point checks ``threads`` first."""
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

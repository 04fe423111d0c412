"""What a DQN checkpoint must hold for ``algo=dqn`` to continue from it (``resume=``): the same algorithm, a config
that differs only in keys the results do not depend on, the same trial path, and every tensor (the networks, Adam's
state, the replay memory, the generators) checked as a user's value is (one line naming the file and the key)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from pedrl.algos.run import open_resume
from pedrl.io import CheckpointError
from pedrl.policy_files import RNG_KEYS, check_rng_state
from pedrl.rl.deep_q import DoubleDQN
from pedrl.rl.network import head_outputs
from pedrl.rl.neural import NeuralPolicy, neural_from_tensors
from pedrl.rl.replay import ReplayBuffer


@dataclass
class ResumedDQN:
    """A validated DQN checkpoint: where the run stands and everything it continues with."""

    global_trial: int
    done: bool
    policy: NeuralPolicy
    update: DoubleDQN
    buffer: ReplayBuffer
    rng_trainer: torch.Tensor
    rng_env: torch.Tensor
    wall_time_s: float
    final: dict[str, float] = field(default_factory=dict)
    summaries: list[dict[str, Any]] = field(default_factory=list)


def load_dqn_resume(trainer: Any, path: str | Path) -> ResumedDQN:
    """Read and check the checkpoint ``trainer`` (a :class:`pedrl.algos.DQN`) continues from.

    Raises:
        CheckpointError: one line naming the file and what is wrong.
    """
    checkpoint = open_resume(trainer, path)
    meta, where = checkpoint.metadata, f"checkpoint {str(path)!r}"
    try:
        global_trial, done = trial_progress(trainer, meta)
        tensors = checkpoint.tensors
        policy = neural_from_tensors(trainer.encoder_settings, tensors, num_actions=trainer.env.num_actions)
        outputs = head_outputs(trainer.head, trainer.env.num_actions)
        expected = (trainer.processes, (trainer.width, *trainer.hidden, outputs))
        if (policy.num_processes, policy.network.widths) != expected:
            raise ValueError(
                f"the network is {policy.num_processes} x {list(policy.network.widths)}: the config makes "
                f"{expected[0]} x {list(expected[1])}"
            )
        if policy.network.head != trainer.head:
            raise ValueError(f"the network's head is {policy.network.head}: the config makes {trainer.head}")
        policy = trainer.make_policy(policy.network, policy.mean, policy.std)
        policy.network.requires_grad_(True)
        update = DoubleDQN(policy, trainer.settings, trainer.learning_rate)
        update.load_tensors(tensors)
        update.updates, update.decisions = checked_count(meta, "updates"), checked_count(meta, "decisions")
        buffer = trainer.make_buffer()
        buffer.load_tensors(tensors)
        rng = [check_rng_state(name, tensors[name]) if name in tensors else missing_tensor(name) for name in RNG_KEYS]
    except ValueError as err:
        raise CheckpointError(f"{where}: {err}") from None
    summaries = meta.get("summaries") or [{}]
    trainer.summary = dict(summaries[0]) if isinstance(summaries[0], dict) else {}
    return ResumedDQN(global_trial, done, policy, update, buffer, rng[0], rng[1], float(meta.get("wall_time_s", 0.0)),
                      {k: float(v) for k, v in (meta.get("final") or {}).items()}, [trainer.summary])  # fmt: skip


def trial_progress(trainer: Any, meta: dict[str, Any]) -> tuple[int, bool]:
    """The checkpoint's global trial (checked against its iteration and trial) and whether the run is done: the
    progress of a learner whose iterations are blocks of one run of trials (the DQN's, PPO's)."""
    phases = trainer.phases()
    iteration, trial = meta.get("iteration"), meta.get("trial")
    indices = [phase.index for phase in phases]
    if isinstance(iteration, bool) or iteration not in indices:
        raise ValueError(f"metadata iteration={iteration!r} is invalid: must be one of {indices}")
    phase = phases[iteration - 1]
    if isinstance(trial, bool) or not isinstance(trial, int) or not 1 <= trial <= phase.trials:
        raise ValueError(f"metadata trial={trial!r} is invalid: must be an integer in [1, {phase.trials}]")
    global_trial = sum(p.trials for p in phases[: iteration - 1]) + trial
    if meta.get("global_trial") != global_trial:
        raise ValueError(f"metadata global_trial={meta.get('global_trial')!r} is invalid: must be {global_trial}")
    return global_trial, global_trial == trainer.trials


def checked_count(meta: dict[str, Any], key: str) -> int:
    value = meta.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"metadata {key}={value!r} is invalid: must be an integer >= 0")
    return value


def missing_tensor(name: str) -> torch.Tensor:
    raise ValueError(f"tensor {name} is missing")

"""What a checkpoint must hold for a trainer to continue from it (``resume=``).

Every value of a checkpoint is checked against the trainer built from the config, as if a user had typed it
(the checks that need no trainer are :mod:`pedrl.policy_files`'s, which evaluation runs too):
the metadata (algorithm, phase, trial, stored config), the Q tables ``q_values (P, A, K, U)`` (float32, finite,
P processes, A tables, K prototypes of the quantizer, U = 81 actions), the quantizer's tensors (their count, K,
feature dimension, dtype and finiteness) and the generator states. A problem gives one line naming the file,
the key, what it is and what is allowed (:class:`pedrl.io.CheckpointError`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import torch

from pedrl.configs import HISTORICAL_VALUES
from pedrl.io import Checkpoint, CheckpointError
from pedrl.policy_files import RNG_KEYS, check_rng_state, check_run_metadata, check_tensor_names
from pedrl.rl import in_huge_pages
from pedrl.rl.policy import QUANTIZER_PREFIX, rebuild_quantizer
from pedrl.vq import ProcessQuantizers

if TYPE_CHECKING:
    from pedrl.algos.phase import Phase, TrainerView


@dataclass(frozen=True)
class RestoredState:
    """A validated checkpoint, ready to continue or evaluate.

    Attributes:
        position: index of the checkpoint's phase in ``trainer.phases()``.
        phase: that phase.
        trial: trials of that phase done, in ``[0, phase.trials]``.
        phase_complete: ``trial == phase.trials``.
        quantizer: the rebuilt quantizer.
        q_values: ``(P, A, K, U)`` float32 tables, on the trainer's device.
        rng_trainer: uint8 state of the trainer's generator.
        rng_env: uint8 state of the room's generator.
        summaries: per-phase summaries so far.
        distortion: the phase's quantizer distortion.
        wall_time_s: wall time of the run up to the checkpoint (s), over every segment.
        final: final figures, stored once the last phase is complete (empty otherwise, and in older files).
        global_trial: trials of the run done, over every phase.
        done: the last phase is complete (nothing is left to run).
    """

    position: int
    phase: Phase
    trial: int
    phase_complete: bool
    quantizer: Any
    q_values: torch.Tensor
    rng_trainer: torch.Tensor
    rng_env: torch.Tensor
    summaries: list[dict[str, Any]]
    distortion: float
    wall_time_s: float = 0.0
    final: dict[str, float] = field(default_factory=dict)
    global_trial: int = 0
    done: bool = False


def restore_state(trainer: TrainerView, checkpoint: Checkpoint) -> RestoredState:
    """Validate ``checkpoint`` (its header already checked, :func:`pedrl.algos.run.open_resume`) against ``trainer`` and
    rebuild its quantizer and tables; the generator states of a mid-phase checkpoint must fit the trainer's device.

    Args:
        trainer: the trainer built from the run's config.
        checkpoint: the loaded file.

    Raises:
        CheckpointError: one line naming the file, the bad key, what it is and what is allowed.
    """
    where = f"checkpoint {str(checkpoint.path)!r}"
    meta = checkpoint.metadata
    try:
        position, phase, trial = _check_progress(trainer, meta)
        check_run_metadata(meta, checkpoint.metadata["config"], max_summaries=position + 1)
        check_tensor_names(checkpoint)
        quantizer = _rebuild_quantizer(trainer, checkpoint, position)
        q_values = _check_tables(trainer, checkpoint.tensors.get("q_values"), phase, quantizer.num_prototypes)
        rng = [_check_rng(trainer, name, checkpoint.tensors[name], restore=trial < phase.trials) for name in RNG_KEYS]
    except CheckpointError:
        raise
    except ValueError as err:
        raise CheckpointError(f"{where}: {err}") from None
    return RestoredState(
        position=position,
        phase=phase,
        trial=trial,
        phase_complete=trial == phase.trials,
        quantizer=quantizer,
        q_values=in_huge_pages(q_values.to(trainer.device)),
        rng_trainer=rng[0],
        rng_env=rng[1],
        summaries=list(meta.get("summaries", [])),
        distortion=float(meta.get("distortion", math.nan)),
        wall_time_s=float(meta.get("wall_time_s", 0.0)),
        final={key: float(value) for key, value in meta.get("final", {}).items()},
        global_trial=sum(p.trials for p in trainer.phases()[:position]) + trial,
        done=trial == phase.trials and position == len(trainer.phases()) - 1,
    )


def _check_progress(trainer: TrainerView, meta: dict[str, Any]) -> tuple[int, Phase, int]:
    if meta.get("algo") != trainer.name:
        raise ValueError(f"metadata algo={meta.get('algo')!r} is not the config's algorithm: must be {trainer.name!r}")
    phases = trainer.phases()
    indices = [p.index for p in phases]
    iteration = meta.get("iteration")
    if isinstance(iteration, bool) or not isinstance(iteration, int) or iteration not in indices:
        raise ValueError(f"metadata iteration={iteration!r} is invalid: must be one of the phases {indices}")
    position = indices.index(iteration)
    phase = phases[position]
    trial = meta.get("trial")
    if isinstance(trial, bool) or not isinstance(trial, int) or not 0 <= trial <= phase.trials:
        raise ValueError(f"metadata trial={trial!r} is invalid: must be an integer in [0, {phase.trials}]")
    complete = meta.get("phase_complete")
    if complete is not (trial == phase.trials):
        raise ValueError(
            f"metadata phase_complete={complete!r} is invalid: must be {trial == phase.trials} at trial {trial} "
            f"of {phase.trials}"
        )
    if trial == 0:  # a phase's first checkpoint comes after a trial (or at its end): its start is the previous phase's
        raise ValueError(f"metadata trial=0 is invalid: must be in [1, {phase.trials}] (no checkpoint before a trial)")
    if meta.get("agents") != phase.num_agents:
        raise ValueError(f"metadata agents={meta.get('agents')!r} is invalid: phase {iteration} has {phase.num_agents}")
    return position, phase, trial


# ---------------------------------------------------------------------- tensors
def _rebuild_quantizer(trainer: TrainerView, checkpoint: Checkpoint, position: int) -> Any:
    quantizer = rebuild_quantizer(checkpoint.tensors_with_prefix(QUANTIZER_PREFIX))
    per_process = isinstance(quantizer, ProcessQuantizers)
    count = quantizer.num_processes if per_process else 1
    if per_process != trainer.vq.per_process or (per_process and count != trainer.processes):
        expected = f"{trainer.processes} (one per process)" if trainer.vq.per_process else "1 (shared)"
        raise ValueError(
            f"the checkpoint holds {count} quantizer(s): vq.per_process={trainer.vq.per_process} needs {expected}"
        )
    for index, part in enumerate(quantizer.parts if per_process else [quantizer]):
        problem = trainer.check_quantizer(part, position)
        if problem:
            raise ValueError(f"quantizer {index}: {problem}")
    return quantizer


def _check_tables(trainer: TrainerView, q_values: torch.Tensor, phase: Phase, num_prototypes: int) -> torch.Tensor:
    env = trainer.env_for(phase.num_agents)
    expected = (trainer.processes, trainer.num_tables(phase), num_prototypes, env.num_actions)
    allowed = f"float32 {expected} (processes, tables, prototypes, actions)"
    if q_values.dtype != torch.float32 or tuple(q_values.shape) != expected:
        raise ValueError(f"tensor q_values is {q_values.dtype} {tuple(q_values.shape)}: must be {allowed}")
    if not bool(torch.isfinite(q_values).all()):
        raise ValueError("tensor q_values holds NaN or infinite values: must be finite")
    return q_values


def _check_rng(trainer: TrainerView, name: str, state: torch.Tensor, *, restore: bool) -> torch.Tensor:
    """A generator state; one that will be restored is tried on a generator of the trainer's device."""
    state = check_rng_state(name, state)
    if restore:
        try:
            torch.Generator(device=trainer.device).set_state(state)
        except (RuntimeError, ValueError, TypeError):
            expected = torch.Generator(device=trainer.device).get_state().shape[0]
            raise ValueError(
                f"tensor {name} is not a {trainer.device.type} generator state: must be uint8 ({expected},)"
            ) from None
    return state


RESUME_INDEPENDENT = ("resume", "device", "progress", "logger", "hydra", "threads")
"""Top-level keys that may change on resume: the results do not depend on them."""


def config_mismatch(saved: Mapping[str, Any], current: Mapping[str, Any], prefix: str = "") -> str:
    """The first differing key between two nested configs, ignoring keys that may change on resume; a key that an
    older checkpoint lacks counts as its value in ``HISTORICAL_VALUES``."""
    for key in sorted(set(saved) | set(current)):
        if not prefix and key in RESUME_INDEPENDENT:
            continue
        a = saved.get(key, HISTORICAL_VALUES.get(f"{prefix}{key}", "<absent>"))
        b = current.get(key, "<absent>")
        if isinstance(a, Mapping) and isinstance(b, Mapping):
            found = config_mismatch(a, b, f"{prefix}{key}.")
            if found:
                return found
        elif a != b:
            return f"{prefix}{key} was {short_json(a)} there and is {short_json(b)} here"
    return ""


def short_json(value: Any, limit: int = 80) -> str:
    """``value`` as JSON, cut to ``limit`` characters: a room's WKT text may run to megabytes."""
    text = json.dumps(value)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"

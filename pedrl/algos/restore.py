"""What a checkpoint must hold for a trainer to continue from it (``resume=``) or for ``pedrl-eval`` to use it.

Every value of a checkpoint is checked against the trainer built from the config, as if a user had typed it:
the metadata (algorithm, phase, trial, stored config), the Q tables ``q_values (P, A, K, U)`` (float32, finite,
P processes, A tables, K prototypes of the quantizer, U = 81 actions), the quantizer's tensors (their count, K,
feature dimension, dtype and finiteness) and the generator states. A problem gives one line naming the file,
the key, what it is and what is allowed (:class:`pedrl.io.CheckpointError`).
"""

from __future__ import annotations

import copy
import math
import os
import shlex
from dataclasses import dataclass, field
from numbers import Real
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

import torch

from pedrl.io import Checkpoint, CheckpointError, load_checkpoint, save_checkpoint
from pedrl.rl import in_huge_pages
from pedrl.scenarios import MAX_WKT_BYTES, build_scenario, check_scenario_sizes, geometry_file, inline_geometry
from pedrl.sim.checks import shown
from pedrl.vq import ProcessQuantizers

if TYPE_CHECKING:
    from pedrl.algos.base import Phase, Trainer

QUANTIZER_PREFIX: Final = "quantizer"
RNG_KEYS: Final = ("rng/trainer", "rng/env")
QUANTIZER_DTYPES: Final = {
    "mean": torch.float32,
    "std": torch.float32,
    "prototypes": torch.float32,
    "feature_index": torch.int64,
    "num_sensed": torch.int64,
}
"""dtype of every quantizer tensor, by the last part of its name (``process000/part3.prototypes``)."""
MAX_CONFIG_DEPTH: Final = 16
"""Deepest nesting of a stored config (a run's config is 4 deep: ``scenario.exits[0][1]``)."""
MAX_CONFIG_STRING: Final = 4096
"""Longest string (or key) of a stored config, bar ``scenario.geometry``, the room's WKT text (10 MB)."""
MAX_CONFIG_VALUES: Final = 100_000
"""Most values (mappings, lists and leaves) of a stored config."""


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


def restore_state(trainer: Trainer, checkpoint: Checkpoint, *, continue_training: bool = True) -> RestoredState:
    """Validate ``checkpoint`` against ``trainer`` and rebuild its quantizer and tables.

    Args:
        trainer: the trainer built from the run's config.
        checkpoint: the loaded file.
        continue_training: the generator states will be restored (a mid-phase resume), so they must also fit a
            generator of the trainer's device; ``pedrl-eval`` does not use them.

    Raises:
        CheckpointError: one line naming the file, the bad key, what it is and what is allowed.
    """
    where = f"checkpoint {str(checkpoint.path)!r}"
    meta = checkpoint.metadata
    check_stored_config(checkpoint)
    try:
        position, phase, trial = _check_progress(trainer, meta)
        _check_extras(meta, position)
        _check_tensor_names(checkpoint)
        quantizer = _rebuild_quantizer(trainer, checkpoint, position)
        q_values = _check_tables(trainer, checkpoint.tensors.get("q_values"), phase, quantizer.num_prototypes)
        restore_rng = continue_training and trial < phase.trials
        rng = [_check_rng(trainer, name, checkpoint.tensors[name], restore=restore_rng) for name in RNG_KEYS]
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
    )


def check_stored_config(checkpoint: Checkpoint) -> dict[str, Any]:
    """The training config stored in ``checkpoint``, refused if it is not a mapping of plain values or names code.

    It is bounded before anything walks it (:data:`MAX_CONFIG_DEPTH`, :data:`MAX_CONFIG_STRING`,
    :data:`MAX_CONFIG_VALUES`, and the scenario's exits and spawn areas), and it must hold its room: a
    ``scenario.geometry`` that names a WKT file (checkpoints written before rooms were stored) is refused with the
    command that re-exports the checkpoint, since pedrl opens no file a checkpoint names.

    Raises:
        CheckpointError: one line naming the file and the bad key.
    """
    from pedrl.algos.registry import check_names_no_code  # the registry imports the trainers, which import us

    config = checkpoint.metadata.get("config")
    where = f"checkpoint {str(checkpoint.path)!r}"
    if not isinstance(config, dict) or not all(isinstance(config.get(key), dict) for key in ("env", "algo")):
        raise CheckpointError(f"{where} holds no training config (a mapping with env and algo) to rebuild its run")
    try:
        check_scenario_sizes(config.get("scenario"))  # counts only: first, for the clearest line
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
            f" {shlex.quote(str(checkpoint.path))} ROOM.wkt` (ROOM.wkt: the file it was trained on)"
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
            most = MAX_WKT_BYTES if path == "scenario.geometry" else MAX_CONFIG_STRING
            if len(node) > most:
                raise ValueError(f"{_cut(path)}={shown(node)} is invalid: at most {most} characters")


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
def _check_progress(trainer: Trainer, meta: dict[str, Any]) -> tuple[int, Phase, int]:
    if meta.get("algo") != trainer.name:
        raise ValueError(f"metadata algo={meta.get('algo')!r} is not the config's algorithm: must be {trainer.name!r}")
    phases = trainer.phases()
    indices = [p.index for p in phases]
    iteration = meta.get("iteration")
    if not _is_int(iteration) or iteration not in indices:
        raise ValueError(f"metadata iteration={iteration!r} is invalid: must be one of the phases {indices}")
    position = indices.index(iteration)
    phase = phases[position]
    trial = meta.get("trial")
    if not _is_int(trial) or not 0 <= trial <= phase.trials:
        raise ValueError(f"metadata trial={trial!r} is invalid: must be an integer in [0, {phase.trials}]")
    complete = meta.get("phase_complete")
    if complete is not (trial == phase.trials):
        raise ValueError(
            f"metadata phase_complete={complete!r} is invalid: must be {trial == phase.trials} at trial {trial} "
            f"of {phase.trials}"
        )
    if meta.get("agents") != phase.num_agents:
        raise ValueError(f"metadata agents={meta.get('agents')!r} is invalid: phase {iteration} has {phase.num_agents}")
    return position, phase, trial


def _check_extras(meta: dict[str, Any], position: int) -> None:
    summaries = meta.get("summaries", [])
    listed = isinstance(summaries, list) and all(isinstance(summary, dict) for summary in summaries)
    if not listed or len(summaries) > position + 1:
        raise ValueError(f"metadata summaries are invalid: must be a list of at most {position + 1} mappings")
    distortion = meta.get("distortion", math.nan)
    if not _is_real(distortion) or (math.isfinite(distortion) and distortion < 0) or math.isinf(distortion):
        raise ValueError(f"metadata distortion={distortion!r} is invalid: must be a number >= 0")
    wall_time = meta.get("wall_time_s", 0.0)
    if not _is_real(wall_time) or not (math.isfinite(wall_time) and wall_time >= 0):
        raise ValueError(f"metadata wall_time_s={wall_time!r} is invalid: must be a finite number >= 0")
    final = meta.get("final", {})
    if not isinstance(final, dict) or not all(_is_real(v) for v in final.values()):
        raise ValueError("metadata final is invalid: must map figure names to numbers")


# ---------------------------------------------------------------------- tensors
def _check_tensor_names(checkpoint: Checkpoint) -> None:
    for name in ("q_values", *RNG_KEYS):
        if name not in checkpoint.tensors:
            raise ValueError(f"tensor {name} is missing")
    for name in checkpoint.tensors:
        if name not in ("q_values", *RNG_KEYS) and not name.startswith(QUANTIZER_PREFIX + "/"):
            raise ValueError(f"tensor {name} is unknown: allowed: q_values, rng/trainer, rng/env, quantizer/...")
    if not checkpoint.tensors_with_prefix(QUANTIZER_PREFIX):
        raise ValueError("the quantizer tensors (quantizer/...) are missing")


def _rebuild_quantizer(trainer: Trainer, checkpoint: Checkpoint, position: int) -> Any:
    tensors = checkpoint.tensors_with_prefix(QUANTIZER_PREFIX)
    for name, tensor in tensors.items():
        leaf = name.rsplit("/", 1)[-1].rsplit(".", 1)[-1]
        dtype = QUANTIZER_DTYPES.get(leaf)
        if dtype is None:
            raise ValueError(f"tensor quantizer/{name} is unknown: allowed names end in {', '.join(QUANTIZER_DTYPES)}")
        if tensor.dtype != dtype:
            raise ValueError(f"tensor quantizer/{name} is {tensor.dtype}: must be {dtype}")
        if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
            raise ValueError(f"tensor quantizer/{name} holds NaN or infinite values: must be finite")
    try:
        quantizer = trainer.quantizer_from_state_dict(tensors)
    except (KeyError, ValueError, RuntimeError, TypeError, IndexError) as err:
        reason = (str(err).strip().splitlines() or [type(err).__name__])[0]
        raise ValueError(f"the quantizer tensors do not form a quantizer ({reason})") from None
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


def _check_tables(trainer: Trainer, q_values: torch.Tensor, phase: Phase, num_prototypes: int) -> torch.Tensor:
    env = trainer._env(phase.num_agents)
    expected = (trainer.processes, trainer.num_tables(phase), num_prototypes, env.num_actions)
    allowed = f"float32 {expected} (processes, tables, prototypes, actions)"
    if q_values.dtype != torch.float32 or tuple(q_values.shape) != expected:
        raise ValueError(f"tensor q_values is {q_values.dtype} {tuple(q_values.shape)}: must be {allowed}")
    if not bool(torch.isfinite(q_values).all()):
        raise ValueError("tensor q_values holds NaN or infinite values: must be finite")
    return q_values


def _check_rng(trainer: Trainer, name: str, state: torch.Tensor, *, restore: bool) -> torch.Tensor:
    """A generator state; one that will be restored is tried on a generator of the trainer's device."""
    state = state.cpu()
    if state.dtype != torch.uint8 or state.ndim != 1:
        raise ValueError(f"tensor {name} is {state.dtype} {tuple(state.shape)}: must be a uint8 generator state")
    if restore:
        try:
            torch.Generator(device=trainer.device).set_state(state)
        except (RuntimeError, ValueError, TypeError):
            expected = torch.Generator(device=trainer.device).get_state().shape[0]
            raise ValueError(
                f"tensor {name} is not a {trainer.device.type} generator state: must be uint8 ({expected},)"
            ) from None
    return state


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_real(value: Any) -> bool:
    return isinstance(value, Real) and not isinstance(value, bool)

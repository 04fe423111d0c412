"""Learned policies from files: a training checkpoint or an exported policy, read without a trainer or Hydra.

Usage::

    import pedrl

    policy = pedrl.load_policy("outputs/main/run/checkpoints/last.safetensors")   # or an exported policy.safetensors
    room = pedrl.room_factory(policy)(num_replicas=1, num_agents=40)            # the room it learned in
    obs, info = room.reset(seed=0)
    generator = torch.Generator().manual_seed(0)                                  # exploration, ties, void fillings
    while room.active.any():
        actions = policy.act(obs, info, epsilon=0.0, generator=generator)
        obs, reward, terminated, truncated, info = room.step(actions)

:func:`export_policy` (``pedrl-export``) writes a policy file: the encoder and the tables with their metadata (the
algorithm, and the training config, which holds the room it learned in), without the generator states and phase
bookkeeping a checkpoint keeps to resume training.

Both kinds of file are refused and checked the same way: nothing in them is executed (safetensors), the stored
config may name no code and is bounded (:func:`pedrl.configs.check_stored_config`), and every tensor is checked
against the encoder and the room (:meth:`pedrl.rl.TabularPolicy.check`). Progress metadata that only a resumed
training run reads (the phase, the trial) is checked against the run's phases by ``pedrl-train resume=...``.
"""

from __future__ import annotations

import math
import os
import weakref
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Final

import torch

from pedrl.common.checks import check_choice, check_device, check_integer, first_line, shown
from pedrl.configs import (
    ALGO_TARGETS,
    VOID_FEATURES_DEFAULTS,
    check_stored_config,
    checked_config,
    env_factory,
    mix_rooms,
    stored_env,
    stored_value,
)
from pedrl.io import Checkpoint, CheckpointError, load_checkpoint
from pedrl.rl.neural import NEURAL_LEARNER, NeuralPolicy
from pedrl.rl.policy import (
    POLICY_KIND,
    POLICY_READERS,
    TABLE_LEARNER,
    LearnedPolicy,
    TabularPolicy,
    check_learner,
    check_policy_file,
    from_tensors,
)
from pedrl.sim import RoomEnv
from pedrl.vq.encoder import EncoderSettings, StateEncoder
from pedrl.vq.factored import FactoredQuantizer, factor_specs
from pedrl.vq.quantizer import ProcessQuantizers

RNG_KEYS: Final = ("rng/trainer", "rng/env")
"""Generator states a training checkpoint holds (to resume mid-phase)."""
_ROOMS: weakref.WeakKeyDictionary[LearnedPolicy, Callable[..., RoomEnv]] = weakref.WeakKeyDictionary()
"""The room factory each loaded policy was checked against: :func:`room_factory` reuses it (building a stored room
reads its WKT text with shapely, up to 10 MB)."""


FILE_KINDS: Final = ("checkpoint", "policy")
"""The kinds of file :func:`load_policy` reads: a training checkpoint, or a policy of ``pedrl-export``."""


def load_policy(
    path: str | Path,
    *,
    device: str | torch.device = "cpu",
    kind: str | None = None,
    hint: str | None = None,
) -> LearnedPolicy:
    """Read the learned policy of a training checkpoint or of an exported policy file.

    Args:
        path: a ``.safetensors`` file written by ``pedrl-train`` or ``pedrl-export``.
        device: where the tables and the quantizer go.
        kind: ``"checkpoint"`` or ``"policy"`` to accept only that kind of file (None: either).
        hint: what the one-line refusal of the other kind advises (e.g. ``"pass it as policy="``).

    Returns:
        The policy (a :class:`~pedrl.rl.TabularPolicy`, or a :class:`~pedrl.rl.NeuralPolicy` of ``algo=dqn``), with
        ``metadata["config"]`` (the training config) and ``metadata["algo"]``;
        :func:`room_factory` builds the room it learned in.

    Raises:
        CheckpointError: one line naming the file, for a missing, foreign, corrupt or crafted one.
        ValueError: one line, for a bad ``device`` or ``kind`` (before the file is read).
    """
    if not isinstance(path, str | os.PathLike):
        raise TypeError(f"path={shown(path)} is invalid: must be a str or os.PathLike naming a .safetensors file")
    device = check_device(device)
    if kind is not None and kind not in FILE_KINDS:
        raise ValueError(f"kind={kind!r} is invalid: must be None, {' or '.join(map(repr, FILE_KINDS))}")
    checkpoint = load_checkpoint(path, device=device)
    stored_kind = checkpoint.metadata.get("kind")
    if stored_kind is not None and stored_kind != POLICY_KIND:
        raise CheckpointError(
            f"file {str(path)!r} has metadata kind={shown(stored_kind)}, which is unknown: a training checkpoint has no"
            f" kind, a policy of pedrl-export kind={POLICY_KIND!r}"
        )
    exported = stored_kind == POLICY_KIND
    found = "policy" if exported else "checkpoint"
    if kind is not None and kind != found:
        names = {"policy": "an exported policy", "checkpoint": "a training checkpoint"}
        advice = f" ({hint})" if hint else ""
        raise CheckpointError(f"{str(path)!r} is {names[found]}, not {names[kind]}{advice}")
    where = f"{found} {str(path)!r}"
    config = check_stored_config(checkpoint, kind=found)
    try:
        _check_config_parts(config)
        factory = env_factory(stored_env(config), config.get("scenario"), files=False)
    except (ValueError, KeyError, TypeError) as err:
        raise CheckpointError(f"{where} holds a config this pedrl refuses ({first_line(err)})") from None
    try:
        algo = ALGO_TARGETS[config["algo"]["_target_"]]
        metadata = {"algo": algo, "config": config, "source": str(path)}
        room = factory(num_replicas=1, num_agents=1, device=device)
        learner = stored_learner(checkpoint.metadata, algo)
        if learner != TABLE_LEARNER:
            # a network: its file is checked by what it must hold, the rest (optimizer, memory) ignored
            if not exported:
                check_run_metadata(checkpoint.metadata, config)
            settings = _network_settings(
                EncoderSettings.from_metadata(_stored_encoder(checkpoint.metadata)), config, room
            )
            read = POLICY_READERS[learner]
            policy = read(settings, checkpoint.tensors, num_actions=room.num_actions, metadata=metadata)
        else:
            if exported:
                stored = check_policy_file(checkpoint.metadata, checkpoint.tensors)
            else:
                stored = _check_training_file(checkpoint, config)
            settings = _encoder_settings(stored, config, room)
            tensors = {k: v for k, v in checkpoint.tensors.items() if k not in RNG_KEYS}
            policy = from_tensors(settings, tensors, num_actions=room.num_actions, metadata=metadata)
        check_sizes_against_config(policy, config)
    except ValueError as err:
        raise CheckpointError(f"{where}: {first_line(err)}") from None
    _ROOMS[policy] = factory
    return policy


def stored_learner(meta: Mapping[str, Any], algo: str) -> str:
    """The learner of a file (the key of its reader, :data:`pedrl.rl.policy.POLICY_READERS`): its metadata's
    ``learner``, or in a file written before the key that of its algorithm (``dqn``: a network; any other: tables).
    One line for an unknown one."""
    return check_learner(meta.get("learner", NEURAL_LEARNER if algo == "dqn" else TABLE_LEARNER))


def export_policy(
    checkpoint: str | Path, out: str | Path, *, device: str | torch.device = "cpu", processes: int | None = None
) -> Path:
    """Write the policy of a training checkpoint to ``out``: its encoder and tables, with their metadata;
    ``processes`` keeps the tables (and per-process quantizers) of the first ``processes`` learning processes only
    (None: all), for a smaller file.

    Raises:
        CheckpointError: one line, for a checkpoint that cannot be read or a file that cannot be written.
        ValueError: one line, for ``processes`` outside ``1 .. P``.
    """
    policy = load_policy(checkpoint, device=device, kind="checkpoint", hint="it is exported already")
    if processes is not None and isinstance(policy, NeuralPolicy):
        check_integer("processes", processes, minimum=1, maximum=policy.num_processes)
        tensors = {name: tensor[:processes].clone() for name, tensor in policy.network.tensors("network").items()}
        tensors.update(zip(("inputs/mean", "inputs/std"), (policy.mean, policy.std), strict=True))
        policy = POLICY_READERS[policy.learner](policy.encoder.settings, tensors, metadata=policy.metadata)
    elif processes is not None:
        check_integer("processes", processes, minimum=1, maximum=policy.num_processes)
        quantizer = policy.encoder.quantizer
        if isinstance(quantizer, ProcessQuantizers):
            quantizer = ProcessQuantizers(quantizer.parts[:processes])
        encoder = StateEncoder(policy.encoder.settings, quantizer)
        policy = TabularPolicy(encoder, policy.q_values[:processes].clone(), metadata=policy.metadata)
    return policy.save(out)


PRETRAINED: Final = {
    "main": "experiment=main, seed 0, the tables of its first learning process (pedrl-export processes=1)",
    "pedestrian_walk": "experiment=pedestrian_walk, seed 0, the tables of its first learning process",
    "pedestrian_free": "experiment=pedestrian_free_dqn, seed 0, its network (one learning process); beside it "
    "pedestrian_free.onnx and its contract pedestrian_free.onnx.json (pedrl-export out=....onnx)",
    "main_ppo": "experiment=main_ppo (PPO's continuous head), seed 0, its actor: the paper room's best crowd; "
    "beside it main_ppo.onnx and its contract main_ppo.onnx.json",
    "pedestrian_walk_ppo": "experiment=pedestrian_walk_ppo (PPO's continuous head with a heading alone and a company "
    "term), seed 0, its actor: alone straight at v0 (the probe passes), 5 of 6 validation tests; beside it "
    "pedestrian_walk_ppo.onnx and its contract",
}
"""The policy files shipped with pedrl (``pedrl/policies/<name>.safetensors``), to try evaluation, validation and the
PettingZoo adapter without training first."""


def pretrained(name: str) -> Path:
    """The path of the shipped policy file ``name`` (:data:`PRETRAINED`); one-line ``ValueError`` for another name.

    ``pedrl.load_policy(pedrl.pretrained("main"))`` is the main job's learned crowd; ``pedrl-eval policy=<path>`` and
    ``pedrl-validate checkpoint=<path>`` read the same file."""
    check_choice("name", name, tuple(PRETRAINED))
    return Path(__file__).resolve().parent / "policies" / f"{name}.safetensors"


def room_factory(
    policy: LearnedPolicy,
    scenario: Mapping[str, Any] | None = None,
    *,
    max_decisions: int | None = None,
    queue_weight: float | None = None,
) -> Callable[..., RoomEnv]:
    """``factory(num_replicas=, num_agents=, device=)`` building rooms of the policy's training config (bodies,
    speeds, sensing, rewards), in its own scenario or in ``scenario`` (a ``scenario`` config; a WKT file it names
    is read), with trials of ``max_decisions`` decisions and exits chosen with ``queue_weight`` (None: as trained).
    ``factory.scenario`` is the :class:`~pedrl.scenarios.Scenario`.

    Raises:
        TypeError: one line, for a ``policy`` that :func:`load_policy` did not return (a tables' or a network's).
        ValueError: one line, for a bad ``scenario`` or ``max_decisions``, or a policy without a training config.
    """
    if not isinstance(policy, TabularPolicy | NeuralPolicy):
        raise TypeError(
            f"policy={shown(policy)} is invalid: must be a TabularPolicy or NeuralPolicy, as pedrl.load_policy returns"
        )
    overrides = overridden(max_decisions=max_decisions, queue_weight=queue_weight)
    env = room_settings(policy) | overrides
    config = policy.metadata["config"]
    if scenario is not None:
        return env_factory(env, scenario)
    if not overrides and policy in _ROOMS:
        return _ROOMS[policy]
    return env_factory(env, config.get("scenario"), files=False)


def overridden(**settings: Any) -> dict[str, Any]:
    """The room settings given (not None) of those an evaluation may change: ``max_decisions``, ``queue_weight``."""
    return {key: value for key, value in settings.items() if value is not None}


def room_settings(policy: LearnedPolicy) -> dict[str, Any]:
    """The ``env`` settings (bodies, speeds, sensing, rewards) of the room ``policy`` learned in: its training
    config's, checked as a stored config is (:func:`pedrl.configs.checked_config`), a key added since the policy
    was trained taking the value of its time (:func:`pedrl.configs.stored_env`).

    Raises:
        ValueError: one line, for a policy that holds no training config (one built in memory).
    """
    config = policy.metadata.get("config")
    if policy not in _ROOMS:  # a policy file read by TabularPolicy.load, or built in memory: check what it holds
        config = checked_config(config, f"policy of {policy.metadata.get('source', 'unknown origin')}")
    return stored_env(config)


# ---------------------------------------------------------------------- checks
def check_tensor_names(checkpoint: Checkpoint) -> None:
    """One-line ``ValueError`` unless a training checkpoint holds ``q_values``, both generator states and
    ``quantizer/...`` tensors, and nothing else."""
    for name in ("q_values", *RNG_KEYS):
        if name not in checkpoint.tensors:
            raise ValueError(f"tensor {name} is missing")
    for name in checkpoint.tensors:
        if name not in ("q_values", *RNG_KEYS) and not name.startswith("quantizer/"):
            raise ValueError(f"tensor {name} is unknown: allowed: q_values, rng/trainer, rng/env, quantizer/...")


def check_rng_state(name: str, state: torch.Tensor) -> torch.Tensor:
    """A generator state on the CPU; one line unless it is a 1-D uint8 tensor."""
    state = state.cpu()
    if state.dtype != torch.uint8 or state.ndim != 1:
        raise ValueError(f"tensor {name} is {state.dtype} {tuple(state.shape)}: must be a uint8 generator state")
    return state


def check_run_metadata(meta: Mapping[str, Any], config: Mapping[str, Any], max_summaries: int | None = None) -> None:
    """One-line ``ValueError`` for a training checkpoint's metadata that is not what ``pedrl-train`` writes: the
    algorithm of its config, a phase number >= 1, a trial >= 0, and the phase summaries, distortion, wall time and
    final figures of the right types (at most ``max_summaries`` summaries, when given)."""
    algo = ALGO_TARGETS.get(config["algo"].get("_target_"))
    if meta.get("algo") != algo:
        raise ValueError(f"metadata algo={meta.get('algo')!r} is not the config's algorithm: must be {algo!r}")
    for key, low in (("iteration", 1), ("trial", 0), ("agents", 1)):
        value = meta.get(key)
        if not _is_int(value) or value < low:
            raise ValueError(f"metadata {key}={value!r} is invalid: must be an integer >= {low}")
    if not isinstance(meta.get("phase_complete"), bool):
        raise ValueError(f"metadata phase_complete={meta.get('phase_complete')!r} is invalid: must be true or false")
    summaries = meta.get("summaries", [])
    listed = isinstance(summaries, list) and all(isinstance(summary, dict) for summary in summaries)
    if not listed or (max_summaries is not None and len(summaries) > max_summaries):
        most = f"at most {max_summaries} " if max_summaries is not None else ""
        raise ValueError(f"metadata summaries are invalid: must be a list of {most}mappings")
    distortion = meta.get("distortion", math.nan)
    if not _is_real(distortion) or (math.isfinite(distortion) and distortion < 0) or math.isinf(distortion):
        raise ValueError(f"metadata distortion={distortion!r} is invalid: must be a number >= 0")
    wall_time = meta.get("wall_time_s", 0.0)
    if not _is_real(wall_time) or not (math.isfinite(wall_time) and wall_time >= 0):
        raise ValueError(f"metadata wall_time_s={wall_time!r} is invalid: must be a finite number >= 0")
    final = meta.get("final", {})
    if not isinstance(final, dict) or not all(_is_real(v) for v in final.values()):
        raise ValueError("metadata final is invalid: must map figure names to numbers")


def check_sizes_against_config(policy: LearnedPolicy, config: Mapping[str, Any]) -> None:
    """One line for a file whose stored training config contradicts its tensors (an altered file): a network's hidden
    layers must be the config's ``algo.hidden``; a table's prototypes at most the config's ``vq.num_prototypes``
    (IN-VQQL: per stage), a factored table's factors those of ``vq.factors``, each with at most its K (k-means keeps
    fewer where the states hold fewer distinct ones)."""
    algo, vq = config["algo"], config.get("vq") or {}
    if isinstance(policy, NeuralPolicy):
        hidden, widths = algo.get("hidden"), list(policy.network.widths[1:-1])
        if hidden is not None and list(hidden) != widths:
            raise ValueError(
                f"its config's algo.hidden={shown(list(hidden))} disagrees with its network's layers {widths}"
            )
        return
    quantizer = policy.encoder.quantizer
    if isinstance(quantizer, FactoredQuantizer):
        specs = {spec.name: spec.num_prototypes for spec in factor_specs(vq.get("factors")) or ()}
        held = {name: part.num_prototypes for name, part in quantizer.parts.items()}
        if set(held) != set(specs) or any(held[name] > specs[name] for name in held):
            raise ValueError(f"its config's vq.factors (K {specs}) disagree with its factored table's (K {held})")
        return
    if vq.get("factors") is not None:
        raise ValueError("its config's vq.factors disagree with its table over one quantizer of the whole state")
    stages = algo.get("stages") if ALGO_TARGETS[algo["_target_"]] == "in_vqql" else None
    per_phase = vq.get("num_prototypes")
    if not isinstance(per_phase, int) or isinstance(per_phase, bool):
        return  # the config's own check refuses a bad value; an old one without it has nothing to compare
    limit = per_phase * (len(stages) if isinstance(stages, list | tuple) else 1)
    if quantizer.num_prototypes > limit:
        raise ValueError(
            f"its config's vq.num_prototypes={per_phase} disagrees with its quantizer's {quantizer.num_prototypes} "
            f"prototypes: must hold at most {limit}"
        )


def _check_config_parts(config: Mapping[str, Any]) -> None:
    """One line for a stored config whose ``algo`` names no known trainer or whose ``vq`` is not a mapping."""
    target = config["algo"].get("_target_")
    if target not in ALGO_TARGETS:
        raise ValueError(f"algo._target_={shown(target)} is invalid: must be one of {', '.join(ALGO_TARGETS)}")
    if not isinstance(config.get("vq", {}), Mapping):
        raise ValueError(f"vq={shown(config.get('vq'))} is invalid: must be a mapping of quantizer settings")


def _check_training_file(checkpoint: Checkpoint, config: Mapping[str, Any]) -> EncoderSettings | None:
    """The checks of a training checkpoint that need no trainer; returns its stored encoder settings (None in files
    written before they were stored)."""
    check_run_metadata(checkpoint.metadata, config)
    check_tensor_names(checkpoint)
    for name in RNG_KEYS:
        check_rng_state(name, checkpoint.tensors[name])
    tables = stored_value(config, "algo.tables")
    q_values = checkpoint.tensors["q_values"]
    expected = 1 if tables == "process" else checkpoint.metadata["agents"]
    if q_values.ndim == 4 and q_values.shape[1] != expected:
        raise ValueError(
            f"tensor q_values is {q_values.dtype} {tuple(q_values.shape)}: algo.tables={tables} with "
            f"{checkpoint.metadata['agents']} agents needs {expected} tables per process"
        )
    stored = checkpoint.metadata.get("encoder")
    return None if stored is None else EncoderSettings.from_metadata(stored)


def _encoder_settings(stored: EncoderSettings | None, config: Mapping[str, Any], room: RoomEnv) -> EncoderSettings:
    """The encoder settings a file stores, which must agree with its config and room; or (checkpoints written before
    they were stored) those its config and room give, keys it lacks taking the values of their time
    (:data:`pedrl.configs.HISTORICAL_VALUES`)."""
    algo = config["algo"]
    derived = EncoderSettings.for_room(
        room,
        void_features=algo.get("void_features", VOID_FEATURES_DEFAULTS[ALGO_TARGETS[algo["_target_"]]]),
        void_draws=stored_value(config, "algo.void_draws"),
        distance_transform=stored_value(config, "vq.distance_transform"),
    ).spanning(mix_rooms(stored_env(config), config.get("mix"), files=False))  # trained across scenarios: every room
    if stored is not None and stored != derived:
        raise ValueError(f"metadata encoder={stored.to_metadata()!r} disagrees with its config: must be {derived}")
    return derived


def _network_settings(stored: EncoderSettings, config: Mapping[str, Any], room: RoomEnv) -> EncoderSettings:
    """The input settings a network's file stores, which must be those its config and room give (the trainer's:
    :class:`pedrl.algos.dqn.DQN`)."""
    derived = EncoderSettings.for_room(room, distance_transform=stored_value(config, "vq.distance_transform"))
    derived = derived.spanning(mix_rooms(stored_env(config), config.get("mix"), files=False))
    if stored != derived:
        raise ValueError(f"metadata encoder={stored.to_metadata()!r} disagrees with its config: must be {derived}")
    return derived


def _stored_encoder(meta: Mapping[str, Any]) -> Mapping[str, Any]:
    """The encoder settings a network's file stores (every such file stores them)."""
    stored = meta.get("encoder")
    if not isinstance(stored, Mapping):
        raise ValueError(f"metadata encoder={shown(stored)} is invalid: a network's file stores its encoder settings")
    return stored


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_real(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)

"""The eval config (``conf/eval.yaml``): its validation, and :func:`evaluate`, which runs the engine on it.

Every check runs before any compute: :func:`validate_config` on the values alone, :func:`check_against_room` once
the checkpoint's room is known. :func:`evaluate` then hands plain values (:class:`EvalSettings`) to
:func:`pedrl.evaluation.engine.evaluate_policy`.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any, Final

import torch
from omegaconf import DictConfig, ListConfig, OmegaConf

from pedrl.analysis.trajectories import Geometry
from pedrl.analysis.trajectory_files import FRAMES_PAST_EXIT, MAX_FRAMERATE
from pedrl.common.checks import (
    FASTEST_AGENT_DECISIONS,
    LARGE_RUN_S,
    MAX_SEED,
    MAX_TRIALS,
    SLOW_AGENT_DECISIONS,
    YEAR_S,
    check_bool,
    check_choice,
    check_device,
    check_integer,
    check_memory,
    check_number,
    duration,
    first_line,
)
from pedrl.evaluation.engine import (
    EvalSettings,
    Recorder,
    build_rooms,
    check_fused_controller,
    evaluate_policy,
    load_controller,
    measurement_point,
    output_paths,
    room_geometry,
    write_scaling,
)
from pedrl.integrations.jupedsim import INSTALL_HINT, JuPedSimModel, installed, model_from_settings
from pedrl.io.files import check_outputs
from pedrl.rl.policy import PolicyController
from pedrl.runtime import set_threads
from pedrl.sim import RoomEnv
from pedrl.sim.room_checks import MAX_DECISIONS
from pedrl.sim.routing import check_queue_weight
from pedrl.trial.crowd import choose_path
from pedrl.trial.fused import record_every
from pedrl.vq.pruned import graph_memory

CONTROLLERS: Final = ("learned", "greedy", "jupedsim")
DENSITY_MAP_BYTES_PER_TILE: Final = 40
"""Bytes per density-map tile in the memory estimate: the int64 counts, numpy's float64 histogram and the sum."""
RECORD_BYTES_PER_AGENT_FRAME: Final = 80
"""Bytes per recorded agent-frame of a batch in the memory estimate: positions and velocities (float32 x 2) on the
device, stacked on the host and again as trajectories, and the activity flags."""
EXPORT_BYTES_PER_AGENT_FRAME: Final = 100
"""Bytes per agent-frame of an exported trial in the memory estimate: its resampling's float64 blend and the resampled
positions, velocities and flags."""
EXPORT_FILE_BYTES_PER_AGENT_FRAME: Final = 96
"""Bytes per agent-frame of the two trajectory files of an exported trial, measured: about 30 in PedPy's text file, 62
in JuPedSim's SQLite file."""
LARGE_EXPORT_BYTES: Final = 2**30
"""Trajectory files of an ``export.fps`` expected to hold more than this are announced with their size."""


# ---------------------------------------------------------------------- the evaluation
def evaluate(cfg: DictConfig, *, run_dir: str | Path) -> list[dict[str, Any]]:
    """Evaluate ``cfg.checkpoint`` (or the exported ``cfg.policy``) at every agent count of ``cfg.agents`` with
    ``cfg.controller``, then with each controller of ``cfg.references`` on the same scenes and rules; returns the
    ``scaling.csv`` rows of all of them, the controller's first.

    Every output goes under ``run_dir`` (``pedrl-eval`` gives Hydra's output dir), a reference's under
    ``run_dir/<reference>/``, and ``run_dir/scaling.csv`` holds every controller's rows; see the
    :mod:`pedrl.evaluation` docstring.

    Raises:
        ValueError: one line, for an invalid config value (before any compute).
        CheckpointError: one line, for a checkpoint that cannot be used.
    """
    # ---- validation and setup: every check before any compute, for every controller
    validate_config(cfg)
    set_threads(cfg.get("threads"))
    run_dir = Path(run_dir)
    device = torch.device(cfg.device)
    prepared = [(name, *_prepare(cfg, name, device)) for name in controllers(cfg)]
    runs = [(name, policy, envs, geometry) for name, policy, envs, geometry, _ in prepared]
    settings = settings_from_config(cfg)
    work = sum(worst_case(cfg, policy.processes, envs) for _, policy, envs, _ in runs)
    for index, (name, policy, envs, _) in enumerate(runs):  # every output writable, before the first trial
        folder = run_dir if index == 0 else run_dir / name
        check_outputs(*output_paths(folder, settings, list(envs), processes=policy.processes))
    if work / FASTEST_AGENT_DECISIONS > LARGE_RUN_S:  # a long run says so, and shows every batch's progress
        print(estimate_line(work, max(memory for *_, memory in prepared)), flush=True)
        settings = replace(settings, progress=True)
    export_bytes = sum(export_file_bytes(cfg, policy.processes, envs) for _, policy, envs, _ in runs)
    if export_bytes > LARGE_EXPORT_BYTES:
        print(
            f"pedrl-eval: export.fps={cfg.export.fps!r} writes up to {export_bytes / 2**30:.3g} GiB of trajectory "
            f"files (export.trials={cfg.export.trials!r} trials of each agent count, .txt and .sqlite, if no walker "
            "leaves early)",
            flush=True,
        )

    # ---- the evaluations, from plain values
    rows: list[dict[str, Any]] = []
    for index, (name, policy, envs, geometry) in enumerate(runs):
        rows += evaluate_policy(
            policy,
            envs,
            geometry,
            replace(settings, controller=name),
            run_dir=run_dir if index == 0 else run_dir / name,
            config_text=OmegaConf.to_yaml(cfg),
        )
    if len(runs) > 1:  # every controller's rows side by side in the run's own table
        write_scaling(run_dir, rows)
    return rows


def controllers(cfg: DictConfig) -> list[str]:
    """The controllers a validated eval config runs: ``controller``, then each of ``references`` that differs."""
    names = [str(cfg.controller)]
    for name in cfg.get("references") or []:
        if name not in names:
            names.append(str(name))
    return names


def _prepare(cfg: DictConfig, controller: str, device: torch.device) -> tuple[Any, dict[int, RoomEnv], Geometry, float]:
    """The policy file made ready for ``controller``, its rooms and their area, checked against the config, and the
    estimated bytes of its largest allocations (:func:`check_against_room`)."""
    kind, path = source(cfg)
    policy = load_controller(
        path,
        kind=kind,
        controller=controller,
        epsilon=float(cfg.epsilon),
        device=device,
        max_decisions=cfg.max_decisions,
        queue_weight=cfg.get("queue_weight"),
        scenario=_scenario(cfg),
        jupedsim=jupedsim_model(cfg),
    )
    trials_per_batch = min(int(cfg.trials_per_batch), int(cfg.trials))
    envs = build_rooms(policy, list(cfg.agents), trials_per_batch=trials_per_batch, device=device)
    geometry = room_geometry(envs, policy.env_factory.scenario)
    check_run_length(cfg, worst_case(cfg, policy.processes, envs))
    memory = check_against_room(cfg, geometry, envs, policy.controller)
    if isinstance(policy.controller, Recorder):
        for env in envs.values():
            policy.controller.check(env)
    check_fused_controller(policy.controller, envs.values(), cfg.get("fused"))
    return policy, envs, geometry, memory


def source(cfg: DictConfig) -> tuple[str, str]:
    """``("checkpoint", path)`` or ``("policy", path)``: the file a validated eval config evaluates."""
    policy = _given(cfg, "policy")
    return ("policy", policy) if policy is not None else ("checkpoint", str(cfg.checkpoint))


def _given(cfg: DictConfig, key: str) -> str | None:
    """The value of ``key`` when one was given (not null, empty or Hydra's missing ``???``)."""
    value = cfg.get(key) if key in cfg and not OmegaConf.is_missing(cfg, key) else None
    return None if value in (None, "") else str(value)


def _scenario(cfg: DictConfig) -> dict[str, Any] | None:
    """The ``scenario`` asked for (``scenario=<name>`` on the command line), else ``None``: the checkpoint's own."""
    scenario = cfg.get("scenario")
    return None if scenario is None else OmegaConf.to_container(scenario, resolve=True)


def jupedsim_model(cfg: DictConfig) -> JuPedSimModel:
    """The JuPedSim model of the ``jupedsim`` settings (validated); ``controller=jupedsim`` runs it."""
    settings = cfg.get("jupedsim")
    return model_from_settings(None if settings is None else OmegaConf.to_container(settings, resolve=True))


def settings_from_config(cfg: DictConfig) -> EvalSettings:
    """The plain values of a validated eval config (:func:`validate_config`)."""
    return EvalSettings(
        trials=int(cfg.trials),
        seed=int(cfg.seed),
        controller=str(cfg.controller),
        radius=float(cfg.measurement.radius),
        distance=float(cfg.measurement.distance),
        min_density=float(cfg.measurement.min_density),
        plot_points=int(cfg.measurement.plot_points),
        tile_size=float(cfg.density_map.tile_size),
        export_trials=int(cfg.export.trials),
        animation=bool(cfg.animation.enabled),
        animation_fps=float(cfg.animation.fps),
        animation_max_frames=None if cfg.animation.max_frames is None else int(cfg.animation.max_frames),
        tensorboard=bool(cfg.tensorboard),
        fused=cfg.get("fused"),
        export_fps=None if cfg.export.get("fps") is None else float(cfg.export.fps),
    )


# ---------------------------------------------------------------------- validation
def validate_config(cfg: DictConfig) -> None:
    """Raise a one-line ``ValueError`` naming the first invalid (or missing) value of the eval config."""
    from omegaconf.errors import OmegaConfBaseException

    try:
        _validate_values(cfg)
    except OmegaConfBaseException as err:  # e.g. a key deleted with ~key
        raise ValueError(f"the eval config is incomplete: {first_line(err)}") from None


def _validate_values(cfg: DictConfig) -> None:
    checkpoint, policy = _given(cfg, "checkpoint"), _given(cfg, "policy")
    if checkpoint is None and policy is None:
        raise ValueError(
            "checkpoint is missing: pass checkpoint=<path of a .safetensors checkpoint> "
            "(or policy=<file of pedrl-export>)"
        )
    if checkpoint is not None and policy is not None:
        raise ValueError(f"policy={policy!r} is invalid with checkpoint={checkpoint!r}: give one of them")
    agents = cfg.get("agents")
    if not isinstance(agents, ListConfig | list | tuple) or not agents:
        raise ValueError(f"agents={agents!r} is invalid: must be a non-empty list of integers >= 1, e.g. [20,40]")
    agents = list(agents)
    if any(isinstance(a, bool) or not isinstance(a, int) or a < 1 for a in agents):
        raise ValueError(f"agents={agents!r} is invalid: must be a non-empty list of integers >= 1, e.g. [20,40]")
    if len(set(agents)) != len(agents):
        raise ValueError(f"agents={agents!r} is invalid: every agent count must appear once")
    check_integer("trials", cfg.get("trials"), minimum=1, maximum=MAX_TRIALS)
    check_integer("trials_per_batch", cfg.get("trials_per_batch"), minimum=1)
    check_choice("controller", cfg.get("controller"), CONTROLLERS)
    references = cfg.get("references")
    if references is None:
        references = []
    if not isinstance(references, ListConfig | list | tuple):
        raise ValueError(
            f"references={references!r} is invalid: must be a list of {', '.join(CONTROLLERS[1:])} (or [] for none)"
        )
    for name in references:
        check_choice("references", name, CONTROLLERS[1:])
    jupedsim_model(cfg)
    if "jupedsim" in (cfg.controller, *references) and not installed():
        which = "controller" if cfg.controller == "jupedsim" else "references"
        raise ValueError(f"{which}=jupedsim is invalid here: {INSTALL_HINT}")
    check_number("epsilon", cfg.get("epsilon"), low=0.0, high=1.0)
    if cfg.get("max_decisions") is not None:
        check_integer("max_decisions", cfg.max_decisions, minimum=1, maximum=MAX_DECISIONS)
    check_queue_weight(cfg.get("queue_weight"))
    check_integer("seed", cfg.get("seed"), minimum=0, maximum=MAX_SEED)
    threads = cfg.get("threads")
    if threads is not None:
        check_integer("threads", threads, minimum=1)
    check_device(cfg.get("device"))
    check_number("measurement.radius", cfg.measurement.radius, low=0.0, low_open=True)
    check_number("measurement.distance", cfg.measurement.distance, low=0.0)
    check_number("measurement.min_density", cfg.measurement.min_density, low=0.0)
    check_integer("measurement.plot_points", cfg.measurement.plot_points, minimum=1)
    check_number("density_map.tile_size", cfg.density_map.tile_size, low=0.0, low_open=True)
    check_integer("export.trials", cfg.export.trials, minimum=0)
    if cfg.export.get("fps") is not None:
        check_number("export.fps", cfg.export.fps, low=0.0, low_open=True)
    check_bool("animation.enabled", cfg.animation.enabled)
    check_number("animation.fps", cfg.animation.fps, low=0.0, low_open=True)
    if cfg.animation.max_frames is not None:
        check_integer("animation.max_frames", cfg.animation.max_frames, minimum=1)
    check_bool("tensorboard", cfg.get("tensorboard"))
    choose_path([], None, cfg.get("fused"))  # the value; the rooms are checked once built


def check_against_room(cfg: DictConfig, geometry: Geometry, envs: dict[int, RoomEnv], controller: Any = None) -> float:
    """The checks that need the checkpoint's room, before any compute: the measurement point lies inside it, the
    export's frame rate lies in the trajectory writer's range, from the decisions' rate up, and the recordings,
    density maps, room states, the encoder's search structures and an exported trial fit in memory. Returns the
    estimated bytes of those allocations.

    ``controller`` (None: the rooms alone) decides each batch's path (:func:`pedrl.trial.crowd.choose_path`): the fused
    trial keeps a frame every :func:`pedrl.trial.fused.record_every` decisions and builds the nearest-prototype lists
    of a learned policy's quantizer (:func:`pedrl.vq.pruned.graph_memory`); the torch loop keeps every frame."""
    distance = float(cfg.measurement.distance)
    if distance >= geometry.length or not bool(geometry.contains(measurement_point(geometry, distance))):
        raise ValueError(
            f"measurement.distance={cfg.measurement.distance!r} is invalid: the measurement point must be inside the "
            f"room, a distance in [0, {geometry.length:g}) m (the room's length) in front of the door"
        )
    fps, decisions = (cfg.get("export") or {}).get("fps"), next(iter(envs.values())).params.decisions_per_second
    if fps is not None and not decisions <= fps < MAX_FRAMERATE:
        raise ValueError(
            f"export.fps={fps!r} is invalid: must be a number of frames per second in [{decisions:g}, "
            f"{MAX_FRAMERATE:g}), at least the room's {decisions:g} decisions per second (or null: the recording's "
            "frame rate)"
        )
    tile_size = float(cfg.density_map.tile_size)
    tiles = math.ceil(geometry.width / tile_size) * math.ceil(geometry.length / tile_size)
    # a batch the fused trial records keeps a frame every few decisions and builds the quantizer's search lists
    # (a network's fused path records through the trial loop, every decision: not thinned, no search lists)
    network = getattr(controller, "stepped", False)
    thinned = {agents: _recording_path(env, controller, cfg.get("fused")) == "fused" and not network
               for agents, env in envs.items()}  # fmt: skip
    frames = max(_kept_frames(env, thinned=thinned[agents]) for agents, env in envs.items())  # of one batch
    needs = {
        f"density map (density_map.tile_size={cfg.density_map.tile_size!r}: {tiles:.3g} tiles)": (
            DENSITY_MAP_BYTES_PER_TILE * tiles
        ),
        "recorded trials": RECORD_BYTES_PER_AGENT_FRAME * frames,
        "room": max(env.step_memory() for env in envs.values()),
    }
    if fps is not None and int(cfg.export.trials):
        frames = max(export_frames(float(fps), env) * env.num_agents for env in envs.values())
        needs[f"an exported trial (export.fps={fps!r}: {frames:.3g} agent-frames)"] = (
            EXPORT_BYTES_PER_AGENT_FRAME * frames
        )
    if any(thinned.values()) and isinstance(controller, PolicyController) and not network:
        from pedrl.vq.encode_kernel import packed_sets  # numba's module, loaded where the fused trial runs

        sets, size = packed_sets(controller.policy.encoder.quantizer)
        needs[f"nearest-prototype lists ({sets} x {size} prototypes)"] = graph_memory(sets, size)
    check_memory(
        needs,
        device=next(iter(envs.values())).device,
        advice="raise density_map.tile_size, or lower trials_per_batch, the agents, max_decisions or export.fps",
    )
    return float(sum(needs.values()))


# ---------------------------------------------------------------------- how long, how large
def worst_case(cfg: DictConfig, processes: int, envs: dict[int, RoomEnv]) -> float:
    """Agent-decisions of one controller's evaluation if no walker leaves before its trial's end: ``trials x
    processes x agents x max_decisions``, summed over the agent counts (a stuck walker keeps a trial going)."""
    return float(sum(int(cfg.trials) * processes * agents * env.params.max_decisions for agents, env in envs.items()))


def check_run_length(cfg: DictConfig, work: float) -> None:
    """Refuse, in one line naming the keys, an evaluation whose worst case (``work`` agent-decisions of a controller,
    :func:`worst_case`) would take more than a year at a rate above any measured run."""
    seconds = work / FASTEST_AGENT_DECISIONS
    if seconds <= YEAR_S:
        return
    length = cfg.get("max_decisions")
    length = "null (the trained room's)" if length is None else length
    raise ValueError(
        f"trials={cfg.trials!r} is invalid with agents={list(cfg.agents)} and max_decisions={length}: the evaluation "
        f"runs up to {work:.3g} agent-decisions (x processes, if no walker leaves), "
        f"{duration(seconds)} at {FASTEST_AGENT_DECISIONS:g} per second (faster than any measured run): must be at "
        f"most {YEAR_S * FASTEST_AGENT_DECISIONS:.3g} agent-decisions (a year): lower trials, the agents or "
        "max_decisions"
    )


def estimate_line(work: float, memory: float) -> str:
    """The line a long evaluation prints before any compute: its worst case, how long that takes at the measured
    rates, and its memory."""
    fast, slow = work / FASTEST_AGENT_DECISIONS, work / SLOW_AGENT_DECISIONS
    return (
        f"pedrl-eval: a long run: up to {work:.3g} agent-decisions (trials x processes x agents x max_decisions, if "
        f"no walker leaves early), {duration(fast)} to {duration(slow)} at {SLOW_AGENT_DECISIONS:g}-"
        f"{FASTEST_AGENT_DECISIONS:g} agent-decisions per second, about {memory / 2**30:.3g} GiB of memory; every "
        "batch shows its progress"
    )


def export_frames(fps: float, env: RoomEnv) -> int:
    """Frames of one exported trial at ``fps`` in ``env`` at most: the decisions' frames resampled, and the frames a
    walker that left is kept past its exit (:func:`pedrl.analysis.trajectory_files.trajectories_for_export`)."""
    return math.ceil(env.params.max_decisions * fps / env.params.decisions_per_second) + 1 + FRAMES_PAST_EXIT


def export_file_bytes(cfg: DictConfig, processes: int, envs: dict[int, RoomEnv]) -> float:
    """Bytes of one controller's trajectory files at ``export.fps`` if no walker leaves early (0 without a rate)."""
    fps, trials = cfg.export.get("fps"), min(int(cfg.export.trials), int(cfg.trials) * processes)
    if fps is None:
        return 0.0
    frames = sum(export_frames(float(fps), env) * env.num_agents for env in envs.values())
    return float(EXPORT_FILE_BYTES_PER_AGENT_FRAME * frames * trials)


def _recording_path(env: RoomEnv, controller: Any, setting: Any) -> str:
    """The path a recorded batch in ``env`` takes, as :func:`pedrl.trial.crowd.choose_path` chooses it (a
    ``fused=true`` the room cannot run is refused by the room's own check, and counted here as the torch loop)."""
    try:
        return choose_path([env], controller, setting, record=True).name
    except ValueError:
        return "torch"


def _kept_frames(env: RoomEnv, *, thinned: bool) -> int:
    """Agent-frames a batch in ``env`` keeps: every decision's (the torch loop), or every
    :func:`pedrl.trial.fused.record_every` decisions' and the start (the fused trial), in every room."""
    every = record_every(env.num_replicas, env.num_agents, env.params.max_decisions) if thinned else 1
    return env.num_replicas * (-(-env.params.max_decisions // every) + 1) * env.num_agents

"""The evaluation engine of ``pedrl-eval``: reload a learned policy and simulate it with more agents (paper section 6,
Tables 4 and 5).

- :mod:`pedrl.evaluation.engine`: a checkpoint or exported policy made ready to simulate (:func:`load_controller`,
  through :func:`pedrl.load_policy`: no trainer is built), the trials recorded
  batch by batch (:func:`record_batch`), the figures of Tables 4/5 (:class:`ScalingStats`) and the whole run over
  plain arguments (:func:`evaluate_policy`).
- :mod:`pedrl.evaluation.batch`: what simulates whole trials itself (:class:`Recorder`); a batch of evaluated
  trials, however recorded, is a :class:`pedrl.analysis.Recording`.
- :mod:`pedrl.evaluation.report`: the figures and files of a run and the console table (:func:`print_table`).
- :mod:`pedrl.evaluation.config`: the eval config: its validation and :func:`evaluate`, which turns a validated
  config into the engine's plain arguments. ``pedrl/evaluate.py`` is the ``@hydra.main`` wrapper around it.
- :mod:`pedrl.evaluation.jupedsim_reference`: ``controller=jupedsim``, JuPedSim on the same scenes
  (:class:`JuPedSimReference`, a :class:`Recorder`).

The file's stored training config rebuilds its room, and its state encoder (void filling, distance transform,
quantizer) and tables ``q_values (P, A, K, U)`` drive the agents as a :class:`pedrl.rl.TabularPolicy`
(``controller=learned``), or the non-learned :class:`~pedrl.sim.controllers.GreedyDoorController` does
(``controller=greedy``), or JuPedSim's collision-free speed model simulates the same initial scenes in the same area
with the same body radius and trial length (``controller=jupedsim``, settings ``jupedsim.*``;
:mod:`pedrl.evaluation.jupedsim_reference`). For every agent count of ``agents`` it simulates ``trials`` trials with the
tables of every one of the P learning processes (``trials * P`` simulated trials, numbered ``run = trial * P +
process``); agent ``n`` acts with table ``n mod A``. Initial positions depend only on ``seed`` and the agent count,
so both controllers face the same scenarios.

Outputs, under the run directory:

- ``scaling.csv`` (and ``scaling.json``): one row per controller and agent count, the columns of
  ``SCALING_COLUMNS``:

  ``controller``: ``learned``, ``greedy`` or ``jupedsim``, the config's ``controller`` first, then each of its
  ``references`` (``[greedy]`` by default: the non-learned walker on the same scenes, bodies, contact rule and
  ``epsilon``); ``agents``; ``fails_pct`` and ``fails_std``: mean and standard deviation over the simulated trials of
  the percentage of agents that did not reach the door (Tables 4/5); ``mean_speed`` and ``speed_std`` (m/s): mean and
  standard deviation of the speed of every agent after every decision it took; ``evacuation_time_s``: mean time
  until the last agent passed the door, over the ``evacuated_trials`` trials in which every agent did;
  ``evacuated_pct``: the share of trials (%) in which every agent passed the door; ``stuck_pct``: the share of
  agents (%) still in the room at the end of their trial whose path over its last ``STUCK_WINDOW = 20`` decisions
  was shorter than ``STUCK_PATH = 0.4`` m (one body radius): frozen, not merely slow;
  ``door_flow`` (persons/s): mean over trials with at least two distinct passing times of
  ``(n - 1) / (t_last - t_first)``, n agents passing the door between the first and the last passing time;
  ``crashes_per_agent``: contacts per agent and trial, decisions in which another body cut the agent's move
  (``info["crashed_agent"]``; see ``RoomEnv``'s ``contact``); ``wall_crashes_per_agent``: the same for walls,
  counted apart (both NaN, n/a, for ``controller=jupedsim``: JuPedSim's models have no cut move);
  ``trials``: simulated trials (``trials * P``).
- ``fundamental_diagram.csv`` (``agents, trial, frame, density, speed, flow``) and ``fundamental_diagram.png``:
  Gaussian local density (1/m^2), local speed (m/s) and flow (1/(m s)) of equations 2-5, radius
  ``measurement.radius``, sampled every frame at the point ``measurement.distance`` in front of the door centre,
  one colour and fitted curve per agent count.
- ``density_map_<agents>.npy`` (int64 ``(nx, ny)`` agent-frames per tile, x-major, of all trials) and ``.png``.
- ``trajectories/geometry.wkt`` and ``trajectories/agents_<agents>/trial_XXX.txt`` (PedPy text format) for the
  first ``export.trials`` simulated trials (``XXX`` is the run number).
- ``animation_<agents>.gif``: the first simulated trial, agents coloured by speed.
- ``tb/``: TensorBoard scalars ``eval/<column>`` (step = agent count), the figures as images, the config as text.

A reference's own outputs (all of the above but the joint ``scaling.csv``) go under ``<run dir>/<reference>/``.

Frames: frame 0 is the initial state and frame ``t`` the state after decision ``t``; an agent is in frame ``t``
when it took decision ``t`` (so it appears in the frame where it passes the door, beyond the door line, and in
the last frame of a trial cut by ``max_decisions``).
"""

from pedrl.evaluation.config import (
    CONTROLLERS,
    check_against_room,
    controllers,
    evaluate,
    settings_from_config,
    validate_config,
)
from pedrl.evaluation.engine import (
    CONTROLLER_SEED_STRIDE,
    ENV_SEED_STRIDE,
    SCALING_COLUMNS,
    STUCK_PATH,
    STUCK_WINDOW,
    EvalSettings,
    LoadedPolicy,
    Recorder,
    ScalingStats,
    build_rooms,
    evaluate_policy,
    load_controller,
    record_batch,
    room_geometry,
    simulate_agent_count,
    stuck_agents,
    write_scaling,
)
from pedrl.evaluation.jupedsim_reference import JuPedSimReference
from pedrl.evaluation.report import (
    FUNDAMENTAL_COLUMNS,
    print_table,
    write_density_map,
    write_fundamental_diagram,
    write_scaling_json,
)

__all__ = [
    "CONTROLLERS",
    "CONTROLLER_SEED_STRIDE",
    "ENV_SEED_STRIDE",
    "FUNDAMENTAL_COLUMNS",
    "SCALING_COLUMNS",
    "STUCK_PATH",
    "STUCK_WINDOW",
    "EvalSettings",
    "JuPedSimReference",
    "LoadedPolicy",
    "Recorder",
    "ScalingStats",
    "build_rooms",
    "check_against_room",
    "controllers",
    "evaluate",
    "evaluate_policy",
    "load_controller",
    "print_table",
    "record_batch",
    "room_geometry",
    "settings_from_config",
    "simulate_agent_count",
    "stuck_agents",
    "validate_config",
    "write_density_map",
    "write_fundamental_diagram",
    "write_scaling",
    "write_scaling_json",
]

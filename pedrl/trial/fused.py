"""The fused trial: a whole trial of every room as one compiled pass per learning process, on every core.

:func:`run_trial_fused` is the torch loop (:func:`pedrl.trial.loop.crowd_loop`) of a learning trial on the CPU without
a torch operation per decision: one call of :func:`pedrl.trial.fused_kernels.fused_trial` runs every decision of the
trial (the loop over the stage kernels: act, sense, encode, learn, choose), the learning processes in parallel over
numba's threads. :func:`record_trial_fused` runs a trial of a learned policy or of the greedy walker without learning
and records every frame, for ``pedrl-eval`` and ``pedrl-validate``. The torch loop stays the reference (and the path on
a GPU, or with ``fused=false``); this one matches it within the tolerances of :mod:`pedrl.trial.twins` and equals
itself for a seed at any thread count. Both are run by :func:`pedrl.trial.crowd.run_crowd` only, after
:func:`pedrl.trial.crowd.choose_path` found that they can run the room and the controller (an allow-list).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Final, NamedTuple

import numpy as np
import torch

from pedrl._numba import numba
from pedrl.rl.policy import PolicyController, TabularPolicy, one_state_encoder
from pedrl.sim import RoomEnv
from pedrl.sim.geometry import Exits, Walls
from pedrl.sim.params import KernelRoom
from pedrl.sim.spawning import Routes
from pedrl.sim.state import KernelState, RoomState
from pedrl.trial.loop import Learner
from pedrl.trial.stats import TOTALS, Totals, TrialStats
from pedrl.vq.encoder import EncoderSettings

__all__ = ["FusedTrace", "RoomInputs", "record_trial_fused", "room_inputs", "run_trial_fused", "set_kernel_threads"]


def set_kernel_threads(threads: int) -> None:
    """Run numba's parallel kernels on ``threads`` threads (at most the cores numba started with), in its
    ``workqueue`` layer, whose idle threads sleep instead of spinning against torch's."""
    module = numba()
    if module.config.THREADING_LAYER == "default":
        module.config.THREADING_LAYER = "workqueue"
    module.set_num_threads(max(1, min(threads, module.config.NUMBA_NUM_THREADS)))


def run_trial_fused(env: RoomEnv, learner: Learner) -> TrialStats:
    """``learner``'s trial (a learning or acting trial of its policy) as one compiled pass (module docstring): the
    statistics of :func:`pedrl.trial.loop.crowd_loop`'s. Its ``generator`` gives the trial's seed (one draw); the
    room's resets draw from ``env.generator``."""
    policy = learner.policy
    totals, td_sums, steps, _, _ = _launch(
        env, policy, learner.epsilon, learner.generator, learner.learn, learner.alpha, learner.gamma, record=False
    )
    return _stats(env, torch.from_numpy(totals).float(), td_sums, steps, policy.num_processes, learner.learn)


@dataclass(frozen=True)
class FusedTrace:
    """What the fused kernels trace of a trial of every room (numpy, frame 0 the reset, frame t after decision
    ``t * every``), read once into the trial's :class:`~pedrl.common.recording.Recording` and statistics
    (:func:`pedrl.trial.crowd.run_crowd`).

    Attributes:
        positions: ``(R, T, N, 2)`` agent centres (m).
        velocities: ``(R, T, N, 2)`` velocities (m/s).
        active: ``(R, T, N)`` bool: in frame 0 the agents in the room, in frame t those that took decision t.
        totals: ``(len(TOTALS), R, N)`` float64 per-agent totals (:data:`pedrl.trial.stats.TOTALS`): the goal row
            says who reached its own exit, the decisions row when (the decision at which it left).
        every: Decisions between frames (1 but for crowds too large to record every decision, :func:`record_every`).
    """

    positions: np.ndarray
    velocities: np.ndarray
    active: np.ndarray
    totals: np.ndarray
    every: int = 1

    def in_room(self) -> np.ndarray:
        """``(R, T, N)`` bool: who is in the room after frame t (who takes decision t + 1; nobody after the last)."""
        return np.concatenate((self.active[:, 1:], np.zeros_like(self.active[:, :1])), axis=1)


def record_trial_fused(
    env: RoomEnv, controller: Any, *, reset: bool = True, progress: Progress | None = None
) -> FusedTrace:
    """One trial of every room of ``env``, acted by ``controller`` (a learned policy, epsilon-greedy without
    learning, or the greedy walker, with the controller's own ``epsilon`` and ``generator``), recorded frame by
    frame: from a reset (its generator draws the scene), or with ``reset=False`` from the rooms' current state (a
    reset the caller made, e.g. with placed agents). A trial whose every frame would take more than
    :data:`RECORD_BYTES` is recorded every ``every`` decisions (:func:`record_every`); ``progress`` is called as the
    trial goes on (:data:`Progress`)."""
    greedy = not isinstance(controller, PolicyController)
    policy = _walker_policy(env) if greedy else controller.policy
    every = record_every(env.num_replicas, env.num_agents, env.params.max_decisions)
    totals, _, steps, trace, room_steps = _launch(
        env, policy, controller.epsilon, controller.generator, False, 0.0, 0.0, record=True, greedy=greedy,
        reset=reset, every=every, progress=progress,
    )  # fmt: skip
    frames = -(-int(steps.max()) // every) + 1
    positions, velocities, active = trace.positions[:, :frames], trace.velocities[:, :frames], trace.present[:, :frames]
    for r, last in enumerate(room_steps.tolist()):  # a room that emptied early keeps its last frame, as in torch
        last = -(-last // every)
        positions[r, last + 1 :] = positions[r, last]
        velocities[r, last + 1 :] = velocities[r, last]
    return FusedTrace(positions, velocities, active, totals, every)


RECORD_BYTES: Final = 2 << 30
"""A recorded trial's frames take at most this many bytes (2 GiB): a larger crowd or a longer trial is recorded
every few decisions (:func:`record_every`)."""
PROGRESS_EVERY: Final = 2_000_000
"""A trial with a progress bar returns to it after about this many agent-decisions (a part of the trial)."""
Progress = Callable[[int, int], None]
"""Called with the decisions taken and the agents still in the rooms, after each part of a trial."""


def record_every(rooms: int, agents: int, max_decisions: int) -> int:
    """Decisions between recorded frames: 1, or as few more as keep ``max_decisions + 1`` frames of ``rooms x
    agents`` positions, velocities and flags (17 bytes an agent) within :data:`RECORD_BYTES`."""
    per_frame = 17 * rooms * agents
    return max(1, -(-(max_decisions + 1) * per_frame // RECORD_BYTES))


def _walker_policy(env: RoomEnv) -> TabularPolicy:
    """Tables of one state for the greedy walker's trial, which reads none: the encoder and table arrays of the
    kernel's signature, so that the walker runs the compiled code the learned crowd runs."""
    return _walker_policy_for(EncoderSettings.for_room(env), env.num_actions)


@functools.lru_cache(maxsize=8)
def _walker_policy_for(settings: EncoderSettings, num_actions: int) -> TabularPolicy:
    """:func:`_walker_policy`, built (and its quantizer packed) once per room settings, not once per batch."""
    return TabularPolicy(one_state_encoder(settings), torch.zeros(1, 1, 1, num_actions))


class RoomInputs(NamedTuple):
    """What :func:`pedrl.sim.step_kernel.act_room` reads of a room besides its state (:func:`room_inputs`)."""

    room: KernelRoom
    walls: Walls
    exits: Exits
    routes: Routes


def room_inputs(env: RoomEnv) -> RoomInputs:
    """The room's constants, walls, exits and routes as the kernels read them, each built beside its type."""
    return RoomInputs(
        env.params.kernel_room(env),
        env.geometry.kernel_walls(),
        env.geometry.kernel_exits(),
        env.spawns.kernel_routes(),
    )


def _launch(env, policy, epsilon, generator, learn, alpha, gamma, *, record, greedy=False, reset=True, every=1,
            progress=None):  # fmt: skip
    """Reset ``env`` (unless ``reset`` is False), run :func:`pedrl.trial.fused_kernels.fused_trial` (in parts of
    about :data:`PROGRESS_EVERY` agent-decisions, each followed by ``progress``, when it is given) and write the
    rooms' state back: the per-agent totals, the TD sums, each thread's decisions, the trace (one frame unless
    ``record``, else a frame every ``every`` decisions) and each room's decisions."""
    from pedrl.sim.step_kernel import Events, Work
    from pedrl.sim.streams import seed_streams
    from pedrl.trial.fused_kernels import Learning, Observed, Trace, fused_trial

    set_kernel_threads(torch.get_num_threads())
    if reset:
        env.place()
    rooms, agents = env.num_replicas, env.num_agents
    layout = policy.layout
    process, base_rows = layout.of(rooms, agents, env.device)
    # rooms that learn into shared tables run in one thread; rooms that only read them, each in its own
    group = (layout.rooms_per_process if layout.blocks(rooms) else rooms) if learn else 1
    state = env.state.arrays()
    streams = np.empty(rooms, np.uint64)
    seed_streams(np.uint64(int(torch.randint(0, 2**62, (1,), generator=generator))), streams)
    totals = np.zeros((len(TOTALS), rooms, agents))  # the rows of the Totals the kernels add to, by name
    td_sums = np.zeros((rooms // group, 2))
    steps = np.zeros(rooms // group, np.int64)
    settings = policy.encoder.settings
    random_void = settings.void_features == "random"
    frames = -(-env.params.max_decisions // every) + 1 if record else 1
    trace = Trace.allocate(rooms, frames, agents if record else 1, every)
    part = max(1, PROGRESS_EVERY // (rooms * agents)) if progress is not None else 2**62
    learning = Learning(np.float32(epsilon), learn, np.float32(alpha), np.float32(gamma),
                        settings.void_draws == "decision", greedy, np.int64(part))  # fmt: skip
    packed = policy.kernel_arrays()
    factored = packed.factored
    inputs = room_inputs(env)
    scratch = (
        Work.allocate(rooms, agents, env.num_substeps),
        Events.allocate(rooms, agents),
        Observed.allocate(rooms, agents, env.num_features, int(factored.num_slots)),
        np.zeros((rooms, agents, 3 * settings.num_neighbours + 1 if random_void else 1), np.float32),
    )
    arrays = (packed.encoder.arrays, packed.encoder.tree, packed.encoder.pruned, packed.settings, factored)
    table, rows = packed.table, base_rows.view(rooms, agents).numpy()
    room_of = process.view(rooms, agents)[:, 0].contiguous().numpy()
    while True:  # one call, or parts of one trial (the same numbers)
        fused_trial(group, state, inputs.room, inputs.walls, inputs.exits, inputs.routes, *arrays, learning, table,
                    rows, room_of, streams, *scratch, Totals(*totals), td_sums, steps, trace)  # fmt: skip
        if progress is None or not state.active.any():
            break
        progress(int(steps.max()), int(state.active.sum()))
        learning = learning._replace(until=learning.until + part)
    if progress is not None:
        progress(int(steps.max()), 0)
    room_steps = state.decisions.copy()  # each room's own decisions, before every clock is set to the trial's
    _write_back(env, state, int(steps.max()))
    return totals, td_sums, steps, trace, room_steps


def _write_back(env: RoomEnv, state: KernelState, steps: int) -> None:
    """The rooms' state after the trial, into ``env``: every room's clock at the trial's decisions (as the torch loop,
    which steps every room until all are empty), the trial clock advanced by them."""
    after = RoomState.from_arrays(state)
    after.decisions.fill_(steps)
    env.load_state(after, decisions_taken=steps)


def _stats(env: RoomEnv, totals: torch.Tensor, td_sums: np.ndarray, steps: np.ndarray, processes: int,
           learn: bool) -> TrialStats:  # fmt: skip
    if not learn:
        td_error = torch.zeros(processes)
    elif td_sums.shape[0] == processes:  # the trainers' layout: a row of sums per learning process
        td_error = torch.from_numpy(td_sums[:, 0] / np.maximum(td_sums[:, 1], 1.0))
    else:  # rooms that share tables across processes in one group: one pooled figure, no spread to show
        td_error = torch.full((processes,), float(td_sums[:, 0].sum()) / max(float(td_sums[:, 1].sum()), 1.0))
    return TrialStats.from_totals(
        totals,
        processes=processes,
        num_agents=env.num_agents,
        decision_length=env.params.decision_length,
        td_error=td_error,
        decisions=int(steps.max()),
    )

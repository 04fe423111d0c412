"""One trial of a crowd, through the path chosen here: the fused trial or the torch loop.

:func:`run_crowd` is what training (:func:`pedrl.trial.loop.crowd_loop`), ``pedrl-eval``
(:func:`pedrl.evaluation.engine.record_batch`) and ``pedrl-validate`` (:class:`pedrl.validation.crowds.PedrlCrowd`)
run a trial with; :func:`choose_path` is the one place that chooses its path, and the one that refuses
``fused=true`` in one line where the fused trial cannot run. ``fused`` is the setting of every entry point:

- None (the default): the fused trial (:mod:`pedrl.trial.fused`, one compiled pass on the CPU) wherever it can run,
  else the torch loop;
- True: the fused trial, or a one-line ``ValueError`` naming what it cannot run;
- False: the torch loop (:func:`pedrl.trial.loop.crowd_loop`), the reference.

Where the fused trial runs is an allow-list: the room's own (:meth:`pedrl.sim.RoomEnv.fast_path_reason`, from the
declarations of :class:`pedrl.sim.params.RoomParams`), numba, and the controller: a learned policy (the tables and
quantizer of every kind: shared, per process and IN-VQQL's union, on the CPU) or the greedy walker. A network's
controller (``stepped``: :class:`pedrl.rl.neural.NeuralController`, the DQN's learner) takes the same allow-list: on
the fused path the compiled kernels step each decision (:class:`pedrl.trial.stepped.CompiledRoom`) and the network
acts in torch between them. The two paths
agree within the tolerances of :mod:`pedrl.trial.twins`, not to the bit: their random streams differ.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any, Literal, NamedTuple

import numpy as np
import torch

from pedrl._numba import numba_available
from pedrl.common.recording import Recording
from pedrl.rl.policy import LearnedPolicy, PolicyController
from pedrl.sim import RoomEnv
from pedrl.sim.controllers import GreedyDoorController
from pedrl.trial.fused import FusedTrace, Progress, record_trial_fused, run_trial_fused
from pedrl.trial.loop import CrowdRun, Learner, crowd_loop, exit_times
from pedrl.trial.stats import TOTALS, Totals, TrialStats
from pedrl.trial.stepped import CompiledRoom


class TrialPath(NamedTuple):
    """The path of a trial: ``name``, ``"fused"`` (the fused trial) or ``"torch"`` (the torch loop), and ``why_not``:
    None on the fused path, else why the torch loop runs (``"fused=false"``, or ``"the fused trial cannot run ..."``).
    """

    name: str
    why_not: str | None


def choose_path(
    rooms: Iterable[RoomEnv], controller: Any, fused: Any, *, record: bool = False, placed: bool = False
) -> TrialPath:
    """The path of a trial of ``controller`` in each of ``rooms`` under the setting ``fused`` (module docstring).

    ``controller`` is a :class:`~pedrl.trial.loop.Learner`, a :class:`~pedrl.rl.policy.PolicyController`, the
    greedy walker, any other controller (the torch loop only), or None to check the rooms alone (before the
    controller exists); no rooms checks the value of ``fused`` alone. ``record``: the trial is recorded; ``placed``:
    it starts from the agents as the caller placed them.

    Raises:
        ValueError: one line, for a ``fused`` that is not a boolean or null, or ``fused=true`` where the fused trial
            cannot run.
    """
    if fused is not None and not isinstance(fused, bool):
        raise ValueError(f"fused={fused!r} is invalid: must be true, false or null")
    if fused is False:
        return TrialPath("torch", "fused=false")
    for room in rooms:
        reason = _reason(room, controller, record=record, placed=placed)
        if reason is not None:
            if fused:
                raise ValueError(f"fused=true is invalid: the fused trial cannot run {reason} (false or null)")
            return TrialPath("torch", f"the fused trial cannot run {reason}")
    return TrialPath("fused", None)


def run_crowd(
    env: RoomEnv,
    controller: Any,
    *,
    fused: bool | None,
    record: bool = False,
    start: tuple[torch.Tensor, Mapping[str, Any]] | Literal["placed"] | None = None,
    progress: Progress | None = None,
) -> CrowdRun:
    """One trial in every room of ``env``, acted by ``controller`` (see :func:`choose_path`), on the path
    :func:`choose_path` chooses for ``fused``: its statistics and, with ``record``, its recording.

    It starts from a reset (``env``'s generator draws the scenes) or from ``start``, the ``(obs, info)`` of a reset
    the caller made (placed agents), or ``"placed"``: the caller placed them with :meth:`RoomEnv.place` (no
    observation: a crowd of any size, through the fused trial only). A :class:`~pedrl.trial.loop.Learner` draws the
    fused trial's seed from its generator; a controller its own ``epsilon`` and ``generator``. ``progress`` (a
    recorded trial's) is called with the decisions taken and the agents left, now and then
    (:data:`pedrl.trial.fused.Progress`).

    Raises:
        ValueError: one line, for ``fused`` (:func:`choose_path`), or ``start="placed"`` in a room with no agent in
            it (never placed, or emptied by a trial): its trial would be empty.
    """
    if isinstance(start, str) and start == "placed" and not bool(env.active.any()):
        raise ValueError(
            "start='placed' is invalid here: no agent is in the room; call RoomEnv.place first (or start=None to reset)"
        )
    if choose_path([env], controller, fused, record=record, placed=start is not None).name == "torch":
        if start == "placed":
            raise ValueError("start='placed' is invalid here: the torch loop starts from a reset's observation")
        return crowd_loop(env, controller, record=record, start=start, progress=progress)
    if isinstance(controller, Learner):
        return CrowdRun(run_trial_fused(env, controller), None)
    if getattr(controller, "stepped", False):  # a network: the kernels step each decision, it acts in torch between
        return crowd_loop(CompiledRoom(env), controller, record=record, progress=progress)
    trace = record_trial_fused(env, controller, reset=start is None, progress=progress)
    return CrowdRun(_fused_stats(env, trace), _fused_record(env, trace) if record else None)


# ---------------------------------------------------------------------- what the fused trial can run
def _reason(env: RoomEnv, controller: Any, *, record: bool, placed: bool) -> str | None:
    """Why the fused trial cannot run ``controller`` in ``env`` (one phrase), or None when it can."""
    if controller is None:
        return _room_reason(env)
    if isinstance(controller, Learner):
        if record or placed:
            return "a learning trial recorded or from placed agents"
        return _policy_reason(env, controller.policy)
    if getattr(controller, "stepped", False):  # acts in torch between compiled decisions (a network)
        if placed:
            return "a network's trial from placed agents"
        policy = getattr(controller, "policy", None)
        return _room_reason(env) if policy is None else _policy_reason(env, policy)
    if isinstance(controller, PolicyController):
        return _policy_reason(env, controller.policy)
    if type(controller) is GreedyDoorController:
        return _room_reason(env)
    return f"with a {type(controller).__name__} (it runs learned policies and the greedy walker)"


def _policy_reason(env: RoomEnv, policy: LearnedPolicy) -> str | None:
    """Why the fused trial cannot run ``policy`` in ``env`` (one phrase), or None when it can: the policy's own
    reasons (:meth:`~pedrl.rl.policy.TabularPolicy.kernel_reason`), then the room's."""
    return policy.kernel_reason(env) or _room_reason(env)


def _room_reason(env: RoomEnv) -> str | None:
    """Why the fused trial cannot run in ``env`` (one phrase), or None when it can: the room's own
    :meth:`~pedrl.sim.RoomEnv.fast_path_reason` (an allow-list of its settings), and numba."""
    if not numba_available():
        return "without numba (PEDRL_NO_NUMBA is set, or numba is missing)"
    return env.fast_path_reason()


# ---------------------------------------------------------------------- the fused trial's recording
def _fused_record(env: RoomEnv, trace: FusedTrace) -> Recording:
    """The fused trial's trace as the torch loop records a trial (speeds from the recorded velocities), a frame every
    ``trace.every`` decisions."""
    totals = Totals(*trace.totals)
    taken = trace.active[:, 1:]
    speed_sq = np.where(taken, (trace.velocities[:, 1:].astype(np.float64) ** 2).sum(-1), 0.0)
    return Recording(
        positions=trace.positions,
        velocities=trace.velocities,
        in_room=trace.in_room(),
        exit_time=exit_times(
            np.where(totals.reached > 0, totals.decisions, -1).astype(np.int64), env.params.decisions_per_second
        ),
        frame_rate=env.params.decisions_per_second / trace.every,
        radius=env.params.agent_radius,
        max_speed=env.params.max_speed,
        crashes=totals.crashes_agent.astype(np.int64),
        wall_crashes=totals.crashes_wall.astype(np.int64),
        speed_sum=np.sqrt(speed_sq).sum((1, 2)),
        speed_sq_sum=speed_sq.sum((1, 2)),
        speed_count=taken.sum((1, 2)).astype(np.int64),
    )


def _fused_stats(env: RoomEnv, trace: FusedTrace) -> TrialStats:
    """The statistics of a recorded fused trial, all rooms together (one process, as the torch loop's)."""
    return TrialStats.from_totals(
        torch.from_numpy(trace.totals).float().view(len(TOTALS), -1),
        processes=1,
        num_agents=env.num_agents,
        decision_length=env.params.decision_length,
        td_error=torch.zeros(1),
        decisions=trace.positions.shape[1] - 1,
    )

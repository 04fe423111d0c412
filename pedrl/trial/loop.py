"""The torch crowd loop, the reference trial: a room stepped to its end by a controller, for training, evaluation and
validation alike.

:func:`crowd_loop` resets the rooms (or starts from a reset the caller made), lets the controller act decision after
decision until every room is empty, and returns the trial's statistics (:class:`~pedrl.trial.stats.TrialStats`) and,
when asked, its recording (a :class:`~pedrl.common.recording.Recording`). The controller is a :class:`Learner` (a
learned policy acting epsilon-greedily and, in training, learning by equation 1) or any controller with ``act(env, obs,
info) -> (R, N)`` (a :class:`~pedrl.rl.policy.PolicyController`, the greedy walker). Which path runs a trial, this loop
or the fused trial, is chosen in one place: :func:`pedrl.trial.crowd.run_crowd`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Final, NamedTuple

import numpy as np
import torch

from pedrl.common.recording import Recording
from pedrl.rl import epsilon_greedy, td_update
from pedrl.rl.policy import TabularPolicy
from pedrl.sim import RoomEnv
from pedrl.trial.stats import TOTALS, Totals, TrialStats

DEVICE_CHECK_EVERY: Final = 8
"""Decisions between two reads of "is any room still occupied" by an unrecorded trial on a GPU (each read waits)."""


class Driver:
    """What :func:`crowd_loop` drives a trial with: a :class:`Learner`, the trainers' gathering, or any other
    controller wrapped as :class:`Acting`. The defaults act on nothing and learn nothing.

    Attributes:
        processes: P, the learning processes whose statistics the trial reports (rooms process-major).
        sync_free: off the CPU, the trial may run a few decisions in rooms already empty (they change nothing), so
            that no decision waits for the host.
    """

    processes = 1
    sync_free = False

    def begin(self, env: RoomEnv, obs: torch.Tensor, info: Mapping[str, Any]) -> None:
        """The first observations of a trial, after the reset."""

    def act(self, env: RoomEnv, obs: torch.Tensor, info: Mapping[str, Any]) -> torch.Tensor:
        """Actions ``(R, N)`` int64 for the latest observations."""
        raise NotImplementedError

    def observe(
        self,
        obs: torch.Tensor,
        info: Mapping[str, Any],
        reward: torch.Tensor,
        terminated: torch.Tensor,
        valid: torch.Tensor,
    ) -> None:
        """The observations after a decision: ``reward``, ``terminated`` and ``valid`` (who acted) flat ``(R * N,)``."""

    def td_error(self) -> torch.Tensor:
        """``(P,)`` the trial's mean absolute TD error (0 without learning)."""
        return torch.zeros(self.processes)


class Learner(Driver):
    """A learned policy in the trial loop: it acts epsilon-greedily on ``policy``'s tables and, if ``learn``, applies
    equation 1 to ``policy.q_values`` in place with learning rate ``alpha`` and discount ``gamma``.

    ``generator`` draws the exploration, the ties and the random void fillings (the trainer's). On the CPU only the
    agents still in a room are encoded.
    """

    sync_free = True

    def __init__(
        self,
        policy: TabularPolicy,
        *,
        epsilon: float,
        generator: torch.Generator,
        learn: bool,
        alpha: float = 0.0,
        gamma: float = 0.0,
    ) -> None:
        self.policy, self.epsilon, self.generator = policy, epsilon, generator
        self.learn, self.alpha, self.gamma = learn, alpha, gamma
        self.processes = policy.num_processes

    def begin(self, env: RoomEnv, obs: torch.Tensor, info: Mapping[str, Any]) -> None:
        """Encode the first observations of a trial."""
        self._on_cpu = env.device.type == "cpu"
        mask = env.active.reshape(-1) if self._on_cpu else None
        self._rows = self.policy.rows(obs, info, self.generator, rows_mask=mask)
        # per learning process: the sum of |TD error| and the number of updates (the spread over processes is real)
        self._process = self.policy.layout.of(env.num_replicas, env.num_agents, env.device)[0]
        self._td_total = torch.zeros(2, self.processes, device=env.device)

    def act(self, env: RoomEnv, obs: torch.Tensor, info: Mapping[str, Any]) -> torch.Tensor:
        """Actions ``(R, N)``, epsilon-greedy on the rows of the latest observations."""
        self._actions = epsilon_greedy(self.policy.q_values, self._rows, self.epsilon, self.generator)
        return self._actions.view(env.num_replicas, env.num_agents)

    def observe(self, obs, info, reward, terminated, valid) -> None:
        """Encode the observations after a decision and learn from it (:meth:`Driver.observe`)."""
        in_room = valid & ~terminated  # their next state is needed: in the room, or cut by the clock
        next_rows = self.policy.rows(obs, info, self.generator, rows_mask=in_room if self._on_cpu else None)
        if self.learn:
            q_values, rows, actions = self.policy.q_values, self._rows, self._actions
            td = td_update(
                q_values, rows, actions, reward, next_rows, terminated, valid, alpha=self.alpha, gamma=self.gamma
            )
            self._td_total[0].index_add_(0, self._process, td.abs().to(self._td_total.dtype))
            self._td_total[1].index_add_(0, self._process, valid.to(self._td_total.dtype))
        self._rows = next_rows

    def td_error(self) -> torch.Tensor:
        if not self.learn:
            return super().td_error()
        return self._td_total[0] / self._td_total[1].clamp_min(1)


class Acting(Driver):
    """A controller with ``act(env, obs, info) -> (R, N)`` in the trial loop: it acts and learns nothing; its
    statistics are those of all rooms together (one process)."""

    def __init__(self, controller: Any) -> None:
        self.controller = controller

    def act(self, env: RoomEnv, obs: torch.Tensor, info: Mapping[str, Any]) -> torch.Tensor:
        return self.controller.act(env, obs, info)


class CrowdRun(NamedTuple):
    """What a trial gives: its statistics, per learning process (one for a controller that does not learn), and its
    recording (None unless asked for)."""

    stats: TrialStats
    record: Recording | None


class Frames:
    """The recorder of the trial loop, decision by decision: a :class:`~pedrl.common.recording.Recording` of every
    room at the end."""

    def __init__(self, env: RoomEnv) -> None:
        shape, device = env.active.shape, env.positions.device
        self.env = env
        self.positions, self.velocities = [_host(env.positions)], [_host(env.velocities)]
        self.in_room = [_host(env.active)]
        self.left_at = torch.full(shape, -1, dtype=torch.int64, device=device)
        self.crashes = torch.zeros(shape, dtype=torch.int64, device=device)
        self.wall_crashes = torch.zeros(shape, dtype=torch.int64, device=device)
        self.speed_sum = torch.zeros(shape, dtype=torch.float64, device=device)
        self.speed_sq_sum = torch.zeros(shape, dtype=torch.float64, device=device)
        self.speed_count = torch.zeros(shape, dtype=torch.int64, device=device)
        self.decision = 0

    def add(self, env: RoomEnv, info: Mapping[str, Any], acting: torch.Tensor) -> None:
        """The frame after a decision that the agents ``acting`` ``(R, N)`` took."""
        self.decision += 1
        self.left_at = torch.where(info["reached"], self.decision, self.left_at)  # through its own exit
        self.crashes += info["crashed_agent"].to(torch.int64)
        self.wall_crashes += info["crashed_wall"].to(torch.int64)
        speed = torch.where(acting, info["speed"].double(), 0.0)
        self.speed_sum += speed
        self.speed_sq_sum += speed * speed
        self.speed_count += acting.to(torch.int64)
        self.positions.append(_host(env.positions))
        self.velocities.append(_host(env.velocities))
        self.in_room.append(_host(env.active))

    def record(self) -> Recording:
        """The trial of every room, frame 0 the start and frame t after decision t."""
        env = self.env
        return Recording(
            positions=torch.stack(self.positions, 1).numpy(),
            velocities=torch.stack(self.velocities, 1).numpy(),
            in_room=torch.stack(self.in_room, 1).numpy(),
            exit_time=exit_times(self.left_at.cpu().numpy(), env.params.decisions_per_second),
            frame_rate=env.params.decisions_per_second,
            radius=env.params.agent_radius,
            max_speed=env.params.max_speed,
            crashes=self.crashes.cpu().numpy(),
            wall_crashes=self.wall_crashes.cpu().numpy(),
            speed_sum=self.speed_sum.sum(1).cpu().numpy(),
            speed_sq_sum=self.speed_sq_sum.sum(1).cpu().numpy(),
            speed_count=self.speed_count.sum(1).cpu().numpy(),
        )


def exit_times(left_at: np.ndarray, rate: float) -> np.ndarray:
    """``(R, N)`` float64 times (s) of the decisions or frames ``left_at`` (``rate`` of them a second) at which agents
    left through their own exit (-1: never, NaN)."""
    return np.where(left_at >= 0, left_at / rate, np.nan)


def _host(tensor: torch.Tensor) -> torch.Tensor:
    """A copy on the host (the room replaces its tensors at every decision; a copy keeps the frame whatever it does)."""
    return tensor.to("cpu", copy=True)


def crowd_loop(
    env: RoomEnv,
    controller: Any,
    *,
    record: bool = False,
    start: tuple[torch.Tensor, Mapping[str, Any]] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> CrowdRun:
    """One trial in every room of ``env``, acted by ``controller`` (a :class:`Driver` such as a :class:`Learner`, or
    any controller with ``act(env, obs, info) -> (R, N)``), from a reset (``env``'s generator draws the scene) or
    from ``start``, the ``(obs, info)`` of a reset the caller made (placed agents). ``record``: keep every frame.
    ``progress``: called after each decision with the decisions taken and the agents left.

    The trial ends when every room is empty. The loop reads that flag after every decision, but off the CPU for an
    unrecorded trial of a ``sync_free`` driver only every :data:`DEVICE_CHECK_EVERY` decisions, so that no decision
    waits for the host (the extra decisions of empty rooms change nothing).
    """
    driver = controller if isinstance(controller, Driver) else Acting(controller)
    rooms, num_agents = env.num_replicas, env.num_agents
    obs, info = env.reset() if start is None else start
    driver.begin(env, obs, info)
    frames = Frames(env) if record else None
    totals = torch.zeros(len(TOTALS), rooms * num_agents, device=env.device)  # per agent, in TOTALS' order
    decisions = torch.zeros((), dtype=torch.int64, device=env.device)
    check_every = DEVICE_CHECK_EVERY if driver.sync_free and not record and env.device.type != "cpu" else 1
    step = 0
    while step % check_every or bool(env.active.any()):
        valid = env.active.reshape(-1)
        actions = driver.act(env, obs, info)
        obs, reward, terminated, _, info = env.step(actions)
        reward, terminated = reward.reshape(-1), terminated.reshape(-1)
        driver.observe(obs, info, reward, terminated, valid)
        validf = valid.float()
        totals += torch.stack(
            Totals(
                returns=reward,
                crashes_agent=info["crashed_agent"].reshape(-1),
                crashes_wall=info["crashed_wall"].reshape(-1),
                reached=info["reached"].reshape(-1),
                speed_sum=info["speed"].reshape(-1) * validf,
                decisions=validf,
            )
        )
        decisions += valid.any()
        if frames is not None:
            frames.add(env, info, valid.view(rooms, num_agents))
        step += 1
        if progress is not None:
            progress(step, int(env.active.sum()))
    stats = TrialStats.from_totals(
        totals,
        processes=driver.processes,
        num_agents=num_agents,
        decision_length=env.params.decision_length,
        td_error=driver.td_error(),
        decisions=int(decisions),
    )
    return CrowdRun(stats, None if frames is None else frames.record())

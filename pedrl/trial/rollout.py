"""The two rollouts of a phase: gathering the quantizer's states, and one learning (or acting) trial in every room.

Both run the ``R = P E`` rooms of a trainer in lock-step (``P`` learning processes, ``E`` rooms each), agents of
room ``r`` belonging to process ``r // E`` (:class:`pedrl.rl.TableLayout`), through the one trial loop
(:func:`pedrl.trial.loop.crowd_loop`; a learning trial through :func:`pedrl.trial.crowd.run_crowd`, which may choose
the fused trial instead).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NamedTuple

import torch

from pedrl.rl import epsilon_greedy
from pedrl.rl.policy import TableLayout, TabularPolicy, offset_ids
from pedrl.sim import RoomEnv
from pedrl.trial.loop import Driver, crowd_loop
from pedrl.trial.stats import TrialStats
from pedrl.vq.encoder import StateEncoder


class Gathered(NamedTuple):
    """States recorded for a quantizer.

    Attributes:
        states: ``(M, F)`` observations as the quantizer sees them (void slots filled, distances transformed).
        num_sensed: ``(M,)`` neighbours sensed in each.
        process: ``(M,)`` int64 learning process whose rooms visited each.
        success_rate: share of agents that reached the door while gathering.
    """

    states: torch.Tensor
    num_sensed: torch.Tensor
    process: torch.Tensor
    success_rate: float


def gather(
    env: RoomEnv,
    encoder: StateEncoder,
    policy: TabularPolicy | None,
    *,
    trials: int,
    epsilon: float,
    processes: int,
    generator: torch.Generator,
) -> Gathered:
    """Record the states visited in ``trials`` trials, following ``policy`` epsilon-greedily (None: a random walk).

    ``encoder`` prepares the observations (its quantizer is not used: ``policy`` encodes with its own). The trials
    run in the torch loop (:func:`pedrl.trial.loop.crowd_loop`), whatever ``fused`` says: a few per phase.
    """
    gatherer = Gatherer(env, encoder, policy, epsilon=epsilon, processes=processes, generator=generator)
    successes = []
    for _ in range(trials):
        crowd_loop(env, gatherer)
        successes.append(gatherer.reached.float().mean())
    states, counts, owners = (torch.cat(parts) for parts in (gatherer.states, gatherer.counts, gatherer.owners))
    return Gathered(states, counts, owners, float(torch.stack(successes).mean()))


class Gatherer(Driver):
    """The controller of :func:`gather` in the trial loop: before each decision it keeps the states of the agents in
    the rooms as the quantizer sees them, then acts on them (randomly, or epsilon-greedily on ``policy``)."""

    # sync_free stays False: every decision's states are kept, no decision of an empty room

    def __init__(
        self,
        env: RoomEnv,
        encoder: StateEncoder,
        policy: TabularPolicy | None,
        *,
        epsilon: float,
        processes: int,
        generator: torch.Generator,
    ) -> None:
        rooms, num_agents = env.num_replicas, env.num_agents
        self.encoder, self.policy, self.epsilon, self.generator = encoder, policy, epsilon, generator
        self.process_of_row, _ = TableLayout(processes, 1, 1, rooms // processes).of(rooms, num_agents, env.device)
        if policy is not None:
            _, self.base_rows = policy.layout.of(rooms, num_agents, env.device)
        self.states: list[torch.Tensor] = []
        self.counts: list[torch.Tensor] = []
        self.owners: list[torch.Tensor] = []

    def begin(self, env: RoomEnv, obs: torch.Tensor, info: Mapping[str, Any]) -> None:
        self.reached = torch.zeros(env.num_replicas, env.num_agents, dtype=torch.bool, device=env.device)

    def act(self, env: RoomEnv, obs: torch.Tensor, info: Mapping[str, Any]) -> torch.Tensor:
        rooms, num_agents = env.num_replicas, env.num_agents
        active = env.active.reshape(-1)
        num_sensed = info["num_sensed"].reshape(-1)
        flat_obs = self.encoder.prepare(obs.reshape(-1, env.num_features), num_sensed, info["decision"], self.generator)
        self.states.append(flat_obs[active])
        self.counts.append(num_sensed[active])
        self.owners.append(self.process_of_row[active])
        if self.policy is None:
            actions = torch.randint(env.num_actions, (rooms * num_agents,), generator=self.generator, device=env.device)
        else:
            rows = offset_ids(self.base_rows, self.policy.encoder.encode_prepared(flat_obs, num_sensed))
            actions = epsilon_greedy(self.policy.q_values, rows, self.epsilon, self.generator)
        return actions.view(rooms, num_agents)

    def observe(self, obs, info, reward, terminated, valid) -> None:
        self.reached |= info["reached"]


def check_finite(phase_index: int, trial: int, stats: TrialStats, q_values: torch.Tensor, *, last: bool) -> None:
    """Stop with one line when learning turned inf or NaN: the trial's returns and TD errors, and at the phase's
    ``last`` trial the tables themselves (a full pass, too slow for every trial)."""
    finite = bool(torch.isfinite(stats.episodic_return).all() and torch.isfinite(stats.td_error).all())
    if finite and last:
        finite = bool(torch.isfinite(q_values).all())
    if not finite:
        raise ValueError(
            f"phase {phase_index}, trial {trial}: the returns or Q tables turned inf or NaN (float32 overflow): "
            "the rewards (env.reward_*) must be much smaller"
        )

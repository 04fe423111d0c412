"""The two rollouts of a phase: gathering the quantizer's states, and one learning (or acting) trial in every room.

Both run the ``R = P E`` rooms of a trainer in lock-step (``P`` learning processes, ``E`` rooms each), agents of
room ``r`` belonging to process ``r // E`` (:class:`pedrl.rl.TableLayout`).
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from pedrl.rl import epsilon_greedy
from pedrl.rl.policy import TableLayout, TabularPolicy
from pedrl.sim import RoomEnv
from pedrl.trial.crowd import run_crowd
from pedrl.trial.loop import Learner
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

    ``encoder`` prepares the observations (its quantizer is not used: ``policy`` encodes with its own).
    """
    rooms, num_agents = env.num_replicas, env.num_agents
    process_of_row, _ = TableLayout(processes, 1, 1, rooms // processes).of(rooms, num_agents, env.device)
    if policy is not None:
        _, base_rows = policy.layout.of(rooms, num_agents, env.device)
    chunks, counts, owners, successes = [], [], [], []
    for _ in range(trials):
        obs, info = env.reset()
        reached = torch.zeros(rooms, num_agents, dtype=torch.bool, device=env.device)
        while True:
            active = env.active.reshape(-1)
            num_sensed = info["num_sensed"].reshape(-1)
            flat_obs = encoder.prepare(obs.reshape(-1, env.num_features), num_sensed, info["decision"], generator)
            chunks.append(flat_obs[active])
            counts.append(num_sensed[active])
            owners.append(process_of_row[active])
            if policy is None:
                actions = torch.randint(env.num_actions, (rooms * num_agents,), generator=generator, device=env.device)
            else:
                rows = base_rows + policy.encoder.encode_prepared(flat_obs, num_sensed)
                actions = epsilon_greedy(policy.q_values, rows, epsilon, generator)
            obs, _, terminated, truncated, info = env.step(actions.view(rooms, num_agents))
            reached |= info["reached"]
            if not bool(env.active.any()):
                break
        successes.append(reached.float().mean())
    return Gathered(torch.cat(chunks), torch.cat(counts), torch.cat(owners), float(torch.stack(successes).mean()))


def run_trial(
    env: RoomEnv,
    policy: TabularPolicy,
    *,
    epsilon: float,
    generator: torch.Generator,
    learn: bool,
    alpha: float = 0.0,
    gamma: float = 0.0,
    fused: bool | None = None,
) -> TrialStats:
    """Run one trial in every room, acting epsilon-greedily and (if ``learn``) applying equation 1 to
    ``policy.q_values`` in place with learning rate ``alpha`` and discount ``gamma``: a
    :class:`~pedrl.trial.loop.Learner`'s trial.

    ``fused``: run the trial as one compiled pass (:mod:`pedrl.trial.fused`; a one-line ``ValueError`` where it
    cannot run), or the torch loop (:func:`pedrl.trial.loop.crowd_loop`), the reference (False); None: the fused
    pass wherever it can run (on the CPU with numba). :func:`pedrl.trial.crowd.run_crowd` chooses.
    """
    learner = Learner(policy, epsilon=epsilon, generator=generator, learn=learn, alpha=alpha, gamma=gamma)
    return run_crowd(env, learner, fused=fused).stats


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

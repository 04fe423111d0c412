"""The two rollouts of a phase: gathering the quantizer's states, and one learning (or acting) trial in every room.

Both run the ``R = P E`` rooms of a trainer in lock-step (``P`` learning processes, ``E`` rooms each), agents of
room ``r`` belonging to process ``r // E`` (:class:`pedrl.rl.TableLayout`).
"""

from __future__ import annotations

from typing import Final, NamedTuple

import torch

from pedrl.rl import epsilon_greedy, td_update
from pedrl.rl.policy import TableLayout, TabularPolicy
from pedrl.sim import RoomEnv
from pedrl.trial.stats import TOTALS, TrialStats
from pedrl.vq.encoder import StateEncoder

DEVICE_CHECK_EVERY: Final = 8
"""Decisions between two reads of "is any room still occupied" by the trial loop on a GPU (each read waits)."""


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
    ``policy.q_values`` in place with learning rate ``alpha`` and discount ``gamma``.

    ``fused``: run the trial as one compiled pass (:func:`pedrl.trial.fused.run_trial_fused`; a one-line
    ``ValueError`` where it cannot run), or the torch loop below, the reference (False); None: the fused pass
    wherever it can run (on the CPU with numba).

    Only the agents still in a room are encoded. On CPU the loop ends as soon as every room is empty; on other
    devices it reads that flag only every :data:`DEVICE_CHECK_EVERY` decisions, so that no decision waits for the
    host (the extra decisions of empty rooms change nothing).
    """
    if fused is not False:
        from pedrl.trial.fused import fused_reason, run_trial_fused

        reason = fused_reason(env, policy)
        if reason is None:
            return run_trial_fused(
                env, policy, epsilon=epsilon, generator=generator, learn=learn, alpha=alpha, gamma=gamma
            )
        if fused:
            raise ValueError(f"fused=true is invalid: the fused trial cannot run {reason} (false or null)")
    rooms, num_agents = env.num_replicas, env.num_agents
    processes, q_values = policy.num_processes, policy.q_values
    on_cpu = env.device.type == "cpu"
    obs, info = env.reset()
    rows = policy.rows(obs, info, generator, rows_mask=env.active.reshape(-1) if on_cpu else None)
    totals = torch.zeros(len(TOTALS), rooms * num_agents, device=env.device)  # per agent, in TOTALS' order
    td_total = torch.zeros(2, device=env.device)  # sum of |TD error|, number of updates
    decisions = torch.zeros((), dtype=torch.int64, device=env.device)
    step = 0
    while True:
        valid = env.active.reshape(-1)
        actions = epsilon_greedy(q_values, rows, epsilon, generator)
        obs, reward, terminated, truncated, info = env.step(actions.view(rooms, num_agents))
        reward, terminated = reward.reshape(-1), terminated.reshape(-1)
        in_room = valid & ~terminated  # their next state is needed: in the room, or cut by the clock
        next_rows = policy.rows(obs, info, generator, rows_mask=in_room if on_cpu else None)
        if learn:
            td = td_update(q_values, rows, actions, reward, next_rows, terminated, valid, alpha=alpha, gamma=gamma)
            td_total += torch.stack((td.abs().sum(), valid.sum()))
        validf = valid.float()
        events = (info["crashed_agent"], info["crashed_wall"], info["reached"])
        totals += torch.stack(
            (reward, *(event.reshape(-1) for event in events), info["speed"].reshape(-1) * validf, validf)
        )
        decisions += valid.any()
        rows = next_rows
        step += 1
        if (on_cpu or step % DEVICE_CHECK_EVERY == 0) and not bool(env.active.any()):
            break
    td_error = (td_total[0] / td_total[1].clamp_min(1)).expand(processes) if learn else torch.zeros(processes)
    return TrialStats.from_totals(
        totals,
        processes=processes,
        num_agents=num_agents,
        decision_length=env.decision_length,
        td_error=td_error,
        decisions=int(decisions),
    )


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

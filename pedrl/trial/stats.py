"""What a trial reports: :class:`TrialStats`, per learning process, from the torch loop and the fused trial alike."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Final, NamedTuple

import torch


class Totals(NamedTuple):
    """Per-agent totals a trial accumulates, read by name: the rows of the torch loop's accumulator
    (:func:`pedrl.trial.loop.crowd_loop`, ``(len(TOTALS), R * N)``) and the fused trial's ``(R, N)`` float64 arrays."""

    returns: Any
    """The sum of the agent's rewards."""
    crashes_agent: Any
    """Decisions in which another body cut its move."""
    crashes_wall: Any
    """Decisions in which a wall cut its move."""
    reached: Any
    """1 if it left through its own exit (its goal), else 0."""
    speed_sum: Any
    """The sum of its speeds after each decision it took (m/s)."""
    decisions: Any
    """The decisions it took."""


TOTALS: Final = Totals._fields
"""The names of the :class:`Totals`, in the order of their rows."""


@dataclass
class TrialStats:
    """Per-process statistics of one trial, each ``(P,)``.

    Besides the agents' own figures, two figures of the crowd, per room and then averaged over the process's rooms:
    ``evacuation_time`` (s), when the room's last agent left (the trial's length when some never did), and
    ``door_flow`` (persons/s), ``(n - 1) / (t_last - t_first)`` over the ``n`` agents that reached their goal, as
    ``pedrl-eval``'s column (NaN for a process none of whose rooms saw two agents leave at different times).
    """

    success_rate: torch.Tensor
    episodic_return: torch.Tensor
    crashes_agent: torch.Tensor
    crashes_wall: torch.Tensor
    mean_speed: torch.Tensor
    td_error: torch.Tensor
    evacuation_time: torch.Tensor
    door_flow: torch.Tensor
    decisions: int = 0
    agent_decisions: int = 0

    @classmethod
    def from_totals(
        cls,
        totals: torch.Tensor,
        *,
        processes: int,
        num_agents: int,
        decision_length: float,
        td_error: torch.Tensor,
        decisions: int,
    ) -> TrialStats:
        """The statistics of a trial from its per-agent ``totals`` ``(len(TOTALS), R * N)`` (rooms process-major),
        ``td_error`` ``(P,)`` and the ``decisions`` the longest room took.

        An agent's ``decisions`` total is the decisions it took in the room: for one that reached its goal, the
        decision at which it left.
        """
        totals = totals.float().cpu()
        rows = Totals(*totals.view(len(TOTALS), processes, -1))
        reached, moves = rows.reached, rows.decisions
        # per room (P, E, N): the times at which its agents left
        left = reached.view(processes, -1, num_agents) > 0
        times = moves.view(processes, -1, num_agents) * decision_length
        last = times.amax(-1)  # every agent's clock ends when it leaves or when the trial ends
        first = torch.where(left, times, torch.inf).amin(-1)
        last_exit = torch.where(left, times, -torch.inf).amax(-1)
        count = left.sum(-1)
        measured = (count >= 2) & (last_exit > first)
        flow = torch.where(measured, (count - 1) / torch.where(measured, last_exit - first, 1.0), torch.nan)
        return cls(
            success_rate=reached.mean(1),
            episodic_return=rows.returns.mean(1),
            crashes_agent=rows.crashes_agent.mean(1),
            crashes_wall=rows.crashes_wall.mean(1),
            mean_speed=rows.speed_sum.sum(1) / moves.sum(1).clamp_min(1),
            td_error=td_error.float().cpu(),
            evacuation_time=last.mean(1),
            door_flow=flow.nanmean(1),
            decisions=decisions,
            agent_decisions=int(moves.sum()),
        )

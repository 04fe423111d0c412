"""IN-VQQL: incremental in the number of agents, with projection and a union of quantizers (Figure 3, 5.2)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch

from pedrl.algos.base import Trainer
from pedrl.algos.it_vqql import _budgets
from pedrl.algos.phase import Phase, staged_phases
from pedrl.algos.run import RunSpec
from pedrl.rl.qtable import empty_tables
from pedrl.sim.sensing import feature_indices
from pedrl.vq import UnionQuantizer

PAPER_STAGES = (1, 2, 3, 4, 5, 6, 7, 8, 10, 20)


def replicate_tables(q_values: torch.Tensor, num_agents: int) -> torch.Tensor:
    """Tables for ``num_agents`` agents from ``q_values (R, A, K, U)``: agent ``n`` gets a copy of table ``n mod A``.

    Returns:
        ``(R, num_agents, K, U)``.
    """
    source = torch.arange(num_agents, device=q_values.device).remainder(q_values.shape[1])
    shape = (q_values.shape[0], num_agents, *q_values.shape[2:])
    return torch.index_select(q_values, 1, source, out=empty_tables(shape, q_values.device))


class INVQQL(Trainer):
    """Incremental VQQL.

    Stage ``i`` has ``stages[i]`` agents; with ``m`` agents an agent senses ``min(m - 1, k)`` neighbours, so the
    state grows from stage to stage. States of stage ``i`` are gathered while following stage ``i - 1``'s tables,
    replicated to the new agents, epsilon-greedily; a state with more neighbours than the previous quantizer knows
    is projected (Gamma: only the features of its nearest neighbours that quantizer knows are kept). A new
    quantizer is fitted on the stage's full states (those with ``min(m - 1, k)`` neighbours) and united with the
    previous ones: the union encodes a state with the sub-quantizer of its number of sensed neighbours. New tables
    over the union's prototypes are then learned from scratch.

    Memory: the union grows by ``K`` prototypes per stage, and the tables are ``(R, m, K_union, 81)`` float32.
    At paper scale (10 stages of K = 4096, R = 20, 20 agents) that is 40960 prototypes and 5.3 GB of tables,
    within this machine's 24 GiB; ``vq.num_prototypes`` or ``processes`` shrink it linearly.

    Args:
        stages: agents per stage (paper: 1, 2, 3, 4, 5, 6, 7, 8, 10, 20).
        trials: learning trials per stage: one number for all, or one per stage (the paper grows them).
        trials_growth: when ``trials`` is one number, stage ``i`` learns ``trials * trials_growth**(i-1)`` trials.
        gather_trials: trials recorded per stage for the quantizer.
        gather_epsilon: exploration while gathering from stage 2 on (stage 1 is a random walk).
        run, **common: the run and the keyword arguments of :class:`pedrl.algos.base.Trainer`.
    """

    name = "in_vqql"

    def __init__(
        self,
        run: RunSpec,
        *,
        stages: Sequence[int] = PAPER_STAGES,
        trials: int | Sequence[int] = 1000,
        trials_growth: float = 1.0,
        gather_trials: int = 5,
        gather_epsilon: float = 0.07,
        **common: Any,
    ) -> None:
        self.stages = _stages(stages)
        self.trial_budgets = _budgets("trials", trials, len(self.stages), trials_growth)
        self.gather_trials = gather_trials
        self.gather_epsilon = gather_epsilon
        if run.vq.factors is not None:
            raise ValueError(
                "vq.factors is invalid with algo=in_vqql: a factored table reads any number of neighbours by its "
                "shared neighbour factor, which is what IN-VQQL's projection and union are for; use algo=vqql or "
                "algo=it_vqql"
            )
        super().__init__(run, **common)

    def phases(self) -> list[Phase]:
        return staged_phases(
            self.stages, self.trial_budgets, gather_trials=self.gather_trials, gather_epsilon=self.gather_epsilon
        )

    def max_prototypes(self, phase: Phase) -> int:
        """The union of stage ``i`` has at most ``i K`` prototypes (K more per stage)."""
        return self.vq.num_prototypes * phase.index

    def gather_tables(self, phase: Phase, previous: tuple[Any, torch.Tensor] | None):
        if previous is None:
            return None
        quantizer, q_values = previous
        return quantizer, replicate_tables(q_values, phase.num_agents)

    def sensed_neighbours(self, num_agents: int) -> int:
        """Neighbours an agent senses when ``num_agents`` agents are in the room: ``min(m - 1, k)``."""
        return min(num_agents - 1, self.env_for(num_agents).params.num_neighbours)

    def fit_quantizer(
        self,
        phase: Phase,
        states: torch.Tensor,
        num_sensed: torch.Tensor,
        previous: Any | None,
        num_prototypes: int | None = None,
    ) -> tuple[Any, float]:
        """The previous union and a new part fitted on the stage's full states (those with ``min(m - 1, k)``
        neighbours: every agent's first state of a trial is one). Fewer distinct full states than K shrink the new
        part's K (see :meth:`Trainer.fit_quantizers`)."""
        env = self.env_for(phase.num_agents)
        n = self.sensed_neighbours(phase.num_agents)
        index = feature_indices(n, env.params.num_neighbours, env.params.num_walls).to(self.device)
        full = states[num_sensed == n][:, index]
        quantizer, distortion = self.fit_plain_quantizer(full, index, num_prototypes=num_prototypes)
        union = previous if previous is not None else UnionQuantizer()
        return union.unite(n, index, quantizer), distortion

    def kept_prototypes(self, previous: Any | None) -> int:
        """The union keeps every prototype of the previous stages."""
        return 0 if previous is None else previous.num_prototypes

    def check_quantizer(self, part: Any, position: int) -> str | None:
        """A union with one part per number of sensed neighbours of stages ``1 .. position + 1``, each reading the
        features of its projection, with at most ``vq.num_prototypes`` prototypes per stage."""
        if not isinstance(part, UnionQuantizer):
            return f"is a {type(part).__name__}: must be a UnionQuantizer"
        expected = sorted({self.sensed_neighbours(m) for m in self.stages[: position + 1]})
        if part.num_sensed != expected:
            return f"has parts for {part.num_sensed} sensed neighbours: must have {expected}"
        env = self.env_for(self.stages[0])
        for n in expected:
            index, quantizer = part.part(n)
            wanted = feature_indices(n, env.params.num_neighbours, env.params.num_walls)
            if not torch.equal(index.cpu(), wanted) or quantizer.dim != wanted.numel():
                return f"part {n} reads features {index.tolist()}: must read {wanted.tolist()}"
        limit = (position + 1) * self.vq.num_prototypes
        if not 1 <= part.num_prototypes <= limit:
            return f"has {part.num_prototypes} prototypes: must have 1 to {limit} after stage {position + 1}"
        return None


def _stages(stages: Any) -> list[int]:
    """``stages`` as a list of strictly increasing agent counts >= 1, else a one-line ``ValueError``."""
    allowed = "must be a list of increasing integer agent counts >= 1, e.g. [1,2,4]"
    if isinstance(stages, str | bytes) or not isinstance(stages, Sequence) or not stages:
        raise ValueError(f"stages={stages!r} is invalid: {allowed}")
    counts = list(stages)
    if any(isinstance(m, bool) or not isinstance(m, int) or m < 1 for m in counts) or counts != sorted(set(counts)):
        raise ValueError(f"stages={counts!r} is invalid: {allowed}")
    return counts

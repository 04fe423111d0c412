"""VQQL: one quantizer fitted on a random walk, then Q-learning from scratch (paper section 3, the baseline)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from pedrl.algos.base import Trainer
from pedrl.algos.phase import MAX_TRIALS, Phase
from pedrl.algos.run import RunSpec
from pedrl.common.checks import check_trials_per_iteration
from pedrl.rl import LinearSchedule


class VQQL(Trainer):
    """Vector Quantization for Q-Learning with a fixed number of agents.

    The quantizer is fitted once, on states recorded while every agent walks at random; Q tables are then
    learned from scratch for ``trials`` trials. To give long runs a checkpoint per iteration, the learning run is
    split into ``iterations`` equal blocks of trials that share one quantizer and carry their tables over
    (unlike IT-VQQL, where every iteration starts again). The paper uses alpha = 0.25 for this baseline.

    Args:
        num_agents: learning agents in the room (paper: 20).
        trials: total learning trials.
        iterations: blocks the trials are split into, each ending with a checkpoint.
        gather_trials: random-walk trials recorded for the quantizer.
        alpha: learning rate (the paper's VQQL baseline: 0.25).
        run, **common: the run and the keyword arguments of :class:`pedrl.algos.base.Trainer`.
    """

    name = "vqql"

    def __init__(
        self,
        run: RunSpec,
        *,
        num_agents: int = 20,
        trials: int = 3000,
        iterations: int = 1,
        gather_trials: int = 5,
        alpha: float = 0.25,
        **common: Any,
    ) -> None:
        self.num_agents = num_agents
        self.trials = trials
        self.iterations = iterations
        self.gather_trials = gather_trials
        check_trials_per_iteration(trials, iterations, maximum=MAX_TRIALS)
        super().__init__(run, alpha=alpha, **common)

    def phases(self) -> list[Phase]:
        block, extra = divmod(self.trials, self.iterations)
        return [
            Phase(
                index=i + 1,
                num_agents=self.num_agents,
                trials=block + (1 if i < extra else 0),
                gather_trials=self.gather_trials,
                gather_epsilon=1.0,
            )
            for i in range(self.iterations)
        ]

    def continues_previous(self, phase: Phase) -> bool:
        return phase.index > 1

    def epsilon_schedule(self, phase: Phase) -> Callable[[int], float]:
        """One linear decay over the whole run: the blocks are one learning process."""
        offset = sum(p.trials for p in self.phases()[: phase.index - 1])
        schedule = LinearSchedule(
            start=self.epsilon_start,
            end=self.epsilon_end,
            decay_trials=max(1, round(self.epsilon_decay_fraction * self.trials)),
        )
        return lambda trial: schedule(offset + trial)

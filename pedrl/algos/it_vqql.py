"""IT-VQQL: iterative re-quantization over a fixed number of agents (paper Figure 2, section 5.1)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from pedrl.algos.base import MAX_TRIALS, Phase, Trainer
from pedrl.sim.validation import check_integer, check_number


class ITVQQL(Trainer):
    """Iterative VQQL.

    Iteration ``i`` gathers states while following iteration ``i - 1``'s tables epsilon-greedily
    (``gather_epsilon``, paper: 0.07; iteration 1 is a random walk because its tables are zero), fits a new
    quantizer on them and learns new tables from scratch. Empty neighbour slots are filled with random valid
    values before quantization (``void_features="random"``, section 5.1) so the quantizer always sees full states.

    Args:
        num_agents: learning agents (paper: 20): one number for every iteration, or one per iteration (a crowd
            curriculum: the last iterations learn, and quantize, the dense states of a larger crowd; tables are
            shared by agents ``n mod A``, so ``tables="process"`` keeps one table whatever the count).
        iterations: number of iterations (paper: 15).
        trials: learning trials per iteration: one number for all, or one per iteration.
        trials_growth: when ``trials`` is one number, iteration ``i`` learns ``trials * trials_growth**(i-1)``
            trials (budgets grow per iteration, as in Figure 4).
        gather_trials: trials recorded per iteration for the quantizer.
        gather_epsilon: exploration while gathering from iteration 2 on.
        **common: the keyword arguments of :class:`pedrl.algos.base.Trainer` (``void_features`` defaults to
            ``"random"`` here).
    """

    name = "it_vqql"

    def __init__(
        self,
        *,
        num_agents: int | Sequence[int] = 20,
        iterations: int = 15,
        trials: int | Sequence[int] = 1000,
        trials_growth: float = 1.0,
        gather_trials: int = 5,
        gather_epsilon: float = 0.07,
        **common: Any,
    ) -> None:
        self.iterations = iterations
        check_integer("iterations", iterations, minimum=1, maximum=MAX_TRIALS)
        self.agents_per_iteration = _agents("num_agents", num_agents, iterations)
        self.trial_budgets = _budgets("trials", trials, iterations, trials_growth)
        self.gather_trials = gather_trials
        self.gather_epsilon = gather_epsilon
        common.setdefault("void_features", "random")
        super().__init__(**common)

    def phases(self) -> list[Phase]:
        return [
            Phase(
                index=i + 1,
                num_agents=agents,
                trials=budget,
                gather_trials=self.gather_trials,
                gather_epsilon=1.0 if i == 0 else self.gather_epsilon,
            )
            for i, (agents, budget) in enumerate(zip(self.agents_per_iteration, self.trial_budgets, strict=True))
        ]


def _budgets(name: str, trials: int | Sequence[int], count: int, growth: float) -> list[int]:
    """Per-phase trial budgets from one number (grown geometrically) or an explicit list, each at most
    :data:`~pedrl.algos.base.MAX_TRIALS`."""
    check_integer("the number of phases", count, minimum=1)
    if isinstance(trials, int) and not isinstance(trials, bool):
        check_integer(name, trials, minimum=1, maximum=MAX_TRIALS)
        growth = check_number(f"{name}_growth", growth, low=0.0, low_open=True)
        budgets = []
        for index in range(count):
            try:
                budget = trials * growth**index
            except OverflowError:  # growth**index beyond the float range
                budget = math.inf
            if not budget <= MAX_TRIALS:
                raise ValueError(
                    f"{name}_growth={growth!r} is invalid: phase {index + 1} would learn {budget:.3g} trials "
                    f"({name} * {name}_growth^{index}); every phase must learn at most {MAX_TRIALS:.0e}"
                )
            budgets.append(max(1, round(budget)))
        return budgets
    if isinstance(trials, str) or not isinstance(trials, Sequence) or len(trials) != count:
        raise ValueError(f"{name}={trials!r} is invalid: must be an integer >= 1 or a list of {count} of them")
    for index, budget in enumerate(trials):
        check_integer(f"{name}[{index}]", budget, minimum=1, maximum=MAX_TRIALS)
    return list(trials)


def _agents(name: str, num_agents: int | Sequence[int], count: int) -> list[int]:
    """Agents of each of ``count`` phases from one number or a list of ``count`` numbers, each an integer >= 1."""
    if isinstance(num_agents, int) and not isinstance(num_agents, bool):
        check_integer(name, num_agents, minimum=1)
        return [num_agents] * count
    if isinstance(num_agents, str) or not isinstance(num_agents, Sequence) or len(num_agents) != count:
        raise ValueError(f"{name}={num_agents!r} is invalid: must be an integer >= 1 or a list of {count} of them")
    for index, agents in enumerate(num_agents):
        check_integer(f"{name}[{index}]", agents, minimum=1)
    return list(num_agents)

"""IT-VQQL: iterative re-quantization over a fixed number of agents (paper Figure 2, section 5.1)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import torch

from pedrl.algos.base import Trainer
from pedrl.algos.phase import MAX_TRIALS, Phase, staged_phases
from pedrl.algos.run import RunSpec
from pedrl.common.checks import check_bool, check_integer, check_number
from pedrl.vq import FactoredQuantizer, ProcessQuantizers


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
        value_transfer: start each iteration's tables from the previous iteration's instead of zeros (the paper's
            footnote 1): row ``k`` of a new table is the old table's row at the old prototype nearest to new
            prototype ``k`` (the old quantizer's encoding of the new prototype, decoded to features), table ``a``
            taking old table ``a mod A_old``; one quantizer per process maps process by process.
        void_features: empty neighbour slots filled with random valid values before quantization (section 5.1),
            so the quantizer always sees full states; ``"zero"`` leaves them at 0.
        run, **common: the run and the keyword arguments of :class:`pedrl.algos.base.Trainer`.
    """

    name = "it_vqql"

    def __init__(
        self,
        run: RunSpec,
        *,
        num_agents: int | Sequence[int] = 20,
        iterations: int = 15,
        trials: int | Sequence[int] = 1000,
        trials_growth: float = 1.0,
        gather_trials: int = 5,
        gather_epsilon: float = 0.07,
        value_transfer: bool = False,
        void_features: str = "random",
        **common: Any,
    ) -> None:
        self.iterations = iterations
        check_integer("iterations", iterations, minimum=1, maximum=MAX_TRIALS)
        self.agents_per_iteration = _agents("num_agents", num_agents, iterations)
        self.trial_budgets = _budgets("trials", trials, iterations, trials_growth)
        self.gather_trials = gather_trials
        self.gather_epsilon = gather_epsilon
        self.value_transfer = check_bool("value_transfer", value_transfer)
        super().__init__(run, void_features=void_features, **common)

    def phases(self) -> list[Phase]:
        agents = self.agents_per_iteration
        return staged_phases(
            agents, self.trial_budgets, gather_trials=self.gather_trials, gather_epsilon=self.gather_epsilon
        )

    def gather_tables(self, phase: Phase, previous: tuple[Any, torch.Tensor] | None):
        """Re-quantization: iteration ``i`` gathers its states following iteration ``i - 1``'s tables
        (epsilon-greedily, ``gather_epsilon``), so that its prototypes lie where the learned agents walk."""
        return previous

    def initial_q_values(
        self, phase: Phase, quantizer: Any, previous: tuple[Any, torch.Tensor] | None, num_actions: int
    ) -> torch.Tensor:
        """Zeros, or with ``value_transfer`` the previous iteration's rows at the nearest old prototypes."""
        q_values = super().initial_q_values(phase, quantizer, previous, num_actions)
        if not self.value_transfer or previous is None:
            return q_values
        old_quantizer, old_q_values = previous
        old_tables = torch.arange(q_values.shape[1], device=q_values.device) % old_q_values.shape[1]
        for process in range(q_values.shape[0]):
            new, old = _process_part(quantizer, process), _process_part(old_quantizer, process)
            if isinstance(new, FactoredQuantizer):
                nearest = new.nearest_in(old)  # (K,), -1 where the old quantizer lacks the factor
                rows = old_q_values[process][old_tables][:, nearest.clamp_min(0)]
                q_values[process] = torch.where((nearest >= 0)[None, :, None], rows, q_values[process])
                continue
            nearest = old.encode(new.decode(torch.arange(new.num_prototypes, device=new.device)))  # (K,)
            q_values[process] = old_q_values[process][old_tables][:, nearest]
        return q_values


def _process_part(quantizer: Any, process: int) -> Any:
    """The quantizer that encodes process ``process``'s states: its own part, or the shared quantizer."""
    return quantizer.parts[process] if isinstance(quantizer, ProcessQuantizers) else quantizer


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

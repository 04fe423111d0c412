"""A phase of a trainer (an IT-VQQL iteration, an IN-VQQL stage, the VQQL run) and the result of a run."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from pedrl.common.checks import MAX_TRIALS, check_integer, check_number

if TYPE_CHECKING:
    import torch

    from pedrl.sim import RoomEnv
    from pedrl.vq.settings import VQSettings


@dataclass(frozen=True)
class Phase:
    """One iteration (IT-VQQL), stage (IN-VQQL) or the single VQQL run.

    Attributes:
        index: 1-based phase number, as in the paper's figures.
        num_agents: agents in the room, all of them learning.
        trials: learning trials of this phase.
        gather_trials: trials run to gather the quantizer's training states.
        gather_epsilon: exploration rate while gathering (1.0 is a random walk).
    """

    index: int
    num_agents: int
    trials: int
    gather_trials: int
    gather_epsilon: float

    def __post_init__(self) -> None:
        """Check every value before any compute (one line naming it)."""
        check_integer("num_agents", self.num_agents, minimum=1)
        check_integer("trials", self.trials, minimum=1, maximum=MAX_TRIALS)
        check_integer("gather_trials", self.gather_trials, minimum=1, maximum=MAX_TRIALS)
        check_number("gather_epsilon", self.gather_epsilon, low=0.0, high=1.0)


@dataclass
class TrainResult:
    """What :meth:`Trainer.fit` returns: final figures and where the outputs are.

    ``wall_time_s`` is the run's wall time over every segment (a resumed run adds the time up to its checkpoint).
    """

    final: dict[str, float]
    run_dir: Path
    checkpoint: Path
    wall_time_s: float
    phases: list[dict[str, Any]] = field(default_factory=list)
    finished_before: bool = False
    """The run was resumed from the checkpoint of its last phase: nothing was left to do or written."""

    @classmethod
    def finished(cls, run_dir: Path, checkpoint: Path, wall_time_s: float, final, summaries) -> TrainResult:
        """The result of a run resumed from the checkpoint of its last phase: nothing to do, nothing rewritten."""
        return cls(dict(final), run_dir, checkpoint, wall_time_s, list(summaries), finished_before=True)


def staged_phases(
    agents: Sequence[int], budgets: Sequence[int], *, gather_trials: int, gather_epsilon: float
) -> list[Phase]:
    """One phase per number of learning agents (IT-VQQL's iterations, IN-VQQL's stages), with its trial budget; the
    first gathers by a random walk (epsilon 1), the later ones with ``gather_epsilon`` on the previous tables."""
    return [
        Phase(
            index=i + 1,
            num_agents=count,
            trials=budget,
            gather_trials=gather_trials,
            gather_epsilon=1.0 if i == 0 else gather_epsilon,
        )
        for i, (count, budget) in enumerate(zip(agents, budgets, strict=True))
    ]


class TrainerView(Protocol):
    """What the budget checks (:mod:`pedrl.algos.budget`) and a resume (:mod:`pedrl.algos.restore`) read of a trainer;
    :class:`pedrl.algos.base.Trainer` is one. Typed here, below the trainer, so that neither module imports it."""

    name: str
    config: Any
    device: torch.device
    processes: int
    rooms_per_process: int
    vq: VQSettings

    def phases(self) -> list[Phase]: ...

    def env_for(self, num_agents: int) -> RoomEnv: ...

    def rooms(self, env: RoomEnv) -> list[tuple[str, RoomEnv]]: ...

    def num_tables(self, phase: Phase) -> int: ...

    def max_prototypes(self, phase: Phase) -> int: ...

    def check_quantizer(self, part: Any, position: int) -> str | None: ...

    def trial_path(self) -> tuple[str, str | None]: ...

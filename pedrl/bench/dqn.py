"""The neural learner's speed beside the fused tabular trial (``python -m pedrl.bench --only dqn``).

Every row runs the main job's room (:data:`pedrl.bench.factored.ROOM`: the paper's room, the yield rule with the
door-first order, the goal frame's actions) with 80 agents a room (quick: 20) and reports agent-decisions per second,
the best of ``trials`` trials after a warm-up:

- ``tabular``: the fused learning trial of experiment=main's plain table (P = 8 processes of E = 8 rooms), as
  ``--only factored`` measures it;
- ``dqn learning``: a learning trial of experiment=main_dqn (one process of 8 rooms, two hidden layers of 256, two
  gradient steps of 512 transitions per decision), the kernels stepping each decision and the network acting and
  learning in torch between them;
- ``dqn acting``: the same network acting alone (epsilon 0, no memory, no update), as pedrl-eval runs it.

Keys of the returned dict: ``dqn`` (one row per learner with ``learner``, ``rooms``, ``agents``, ``seconds`` and
``agent_decisions_per_s``) and ``dqn_ratio`` (the DQN's learning rate over the fused tabular trial's).
"""

from __future__ import annotations

import time
from typing import Any

from pedrl.bench.factored import PLAIN, ROOM
from pedrl.bench.factored import measure as measure_tables

NETWORK: dict[str, Any] = {"hidden": [256, 256], "batch_size": 512, "gradient_steps": 2, "learning_starts": 0}
"""experiment=main_dqn's network and update (learning from the first decision: every trial timed learns)."""


def measure(*, quick: bool, trials: int) -> list[dict]:
    """Agent-decisions per second of the DQN learning and acting (module docstring)."""
    import torch

    from pedrl.algos import DQN, RunSpec
    from pedrl.algos.dqn_learning import DeepQLearner
    from pedrl.configs import env_factory
    from pedrl.trial.crowd import run_crowd

    agents, rooms = (20, 2) if quick else (80, 8)
    run = RunSpec(env=env_factory(ROOM, {"name": "paper_room"}), vq=PLAIN, processes=1, rooms_per_process=rooms,
                  progress=False,
                  tensorboard=False)  # fmt: skip
    trainer = DQN(run, num_agents=agents, gather_trials=1, buffer_size=100_000, **NETWORK)
    trainer.start()
    rows = []
    for learner, learn in (("dqn learning", True), ("dqn acting", False)):
        best_rate, best_seconds = 0.0, 0.0
        for trial in range(trials + 1):  # the first: the warm-up (compilation, the memory filled)
            driver = DeepQLearner(trainer.policy, epsilon=0.1 if learn else 0.0, generator=trainer.generator,
                                  update=trainer.update if learn else None, buffer=trainer.buffer)  # fmt: skip
            tic = time.perf_counter()
            with torch.no_grad() if not learn else torch.enable_grad():
                stats = run_crowd(trainer.env, driver, fused=True).stats
            seconds = time.perf_counter() - tic
            if trial and stats.agent_decisions / seconds > best_rate:
                best_rate, best_seconds = stats.agent_decisions / seconds, seconds
        rows.append({"learner": learner, "rooms": rooms, "agents": agents, "seconds": best_seconds,
                     "agent_decisions_per_s": best_rate})  # fmt: skip
        print(f"  {learner}: {best_rate:,.0f} agent-decisions/s", flush=True)
    return rows


def run(*, quick: bool = False, trials: int | None = None) -> dict:
    """The dqn section of ``python -m pedrl.bench`` (module docstring)."""
    trials = trials or (1 if quick else 3)
    (table,) = measure_tables(quick=quick, trials=trials, tables=("plain",))
    rows = [{"learner": "tabular", **{k: v for k, v in table.items() if k != "table"}}]
    rows += measure(quick=quick, trials=trials)
    by_learner = {row["learner"]: row["agent_decisions_per_s"] for row in rows}
    return {"dqn": rows, "dqn_ratio": by_learner["dqn learning"] / by_learner["tabular"]}

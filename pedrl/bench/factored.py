"""The factored table's speed: the fused learning trial of the main job's room with one plain quantizer and with a
factored table, side by side (``python -m pedrl.bench --only factored``).

Both rows run the same room (experiment=main's: the paper's room, the yield rule with the door-first order, the goal
frame's actions), the same crowd (80 learning agents, P = 8 processes of E = 8 rooms; quick: 20 agents, P = E = 2)
and the same trainer (IT-VQQL's first phase), through the same fused trial: the plain row with main's quantizer
(K = 2048 over the 28 features, one id per state), the factored row with experiment=main_factored's factors (own 256,
neighbour 256, wall 32: 1 + 7 + 2 ids per state, the Q values their rows' sum). Keys of the returned dict:

- ``factored``: one row per table with ``table``, ``states`` (K of the tables), ``slots`` (ids per state),
  ``seconds`` (the best of ``trials`` learning trials after a warm-up) and ``agent_decisions_per_s``;
- ``factored_ratio``: the factored row's rate over the plain row's.
"""

from __future__ import annotations

import time
from typing import Any

PLAIN: dict[str, Any] = {
    "num_prototypes": 2048,
    "max_states": 30_000,
    "max_iterations": 10,
    "per_process": False,
}
"""experiment=main's quantizer (fewer Lloyd iterations: the fit is not timed)."""
FACTORS: dict[str, Any] = {
    "own": {"num_prototypes": 256},
    "neighbour": {"num_prototypes": 256, "weights": {"distance": 2.0}},
    "wall": {"num_prototypes": 32},
}
"""experiment=main_factored's factors."""
ROOM: dict[str, Any] = {
    "_target_": "pedrl.sim.RoomEnv",
    "motion": {"name": "yield", "order": "door_first"},
    "action_frame": "goal",
    "speed_ratios": [0.0, 0.2, 0.4, 0.6, 0.7, 0.8, 0.9, 0.95, 1.0],
    "turn_ratios": [-0.5, -0.25, -0.1, -0.05, 0.0, 0.05, 0.1, 0.25, 0.5],
}
"""experiment=main's room settings."""


def measure(*, quick: bool, trials: int, tables: tuple[str, ...] = ("plain", "factored")) -> list[dict]:
    """Agent-decisions per second of the fused learning trial with each of ``tables`` (module docstring)."""
    from pedrl.algos import ITVQQL, RunSpec
    from pedrl.configs import env_factory

    agents, processes, rooms = (20, 2, 2) if quick else (80, 8, 8)
    rows = []
    chosen = [
        (name, vq) for name, vq in (("plain", PLAIN), ("factored", {**PLAIN, "factors": FACTORS})) if name in tables
    ]
    for table, vq in chosen:
        run = RunSpec(
            env=env_factory(ROOM, {"name": "paper_room"}),
            vq=vq,
            processes=processes,
            rooms_per_process=rooms,
            fused=True,
            progress=False,
            tensorboard=False,
        )
        trainer = ITVQQL(run, num_agents=agents, iterations=1, trials=1, gather_trials=1, void_features="zero")
        env = trainer.env_for(agents)
        env.reset(seed=0)
        phase = trainer.phases()[0]
        gathered = trainer.gather(phase, env, None)
        quantizer, _ = trainer.fit_quantizers(phase, gathered, None)
        q_values = trainer.initial_q_values(phase, quantizer, None, env.num_actions)
        trainer.run_trial(env, quantizer, q_values, epsilon=0.4, learn=True)  # warm-up (and compilation)
        best_rate, best_seconds = 0.0, 0.0
        for _ in range(trials):
            tic = time.perf_counter()
            stats = trainer.run_trial(env, quantizer, q_values, epsilon=0.4, learn=True)
            seconds = time.perf_counter() - tic
            if stats.agent_decisions / seconds > best_rate:
                best_rate, best_seconds = stats.agent_decisions / seconds, seconds
        slots = getattr(quantizer, "num_slots", 1)
        rows.append(
            {
                "table": table,
                "states": quantizer.num_prototypes,
                "slots": slots,
                "agents": agents,
                "processes": processes,
                "rooms_per_process": rooms,
                "seconds": best_seconds,
                "agent_decisions_per_s": best_rate,
            }
        )
        rate = f"{best_rate:,.0f} agent-decisions/s"
        print(f"  {table} table (K={quantizer.num_prototypes}, {slots} ids a state): {rate}", flush=True)
    return rows


def run(*, quick: bool = False, trials: int | None = None) -> dict:
    """The factored section of ``python -m pedrl.bench`` (module docstring)."""
    rows = measure(quick=quick, trials=trials or (1 if quick else 3))
    by_table = {row["table"]: row["agent_decisions_per_s"] for row in rows}
    return {"factored": rows, "factored_ratio": by_table["factored"] / by_table["plain"]}

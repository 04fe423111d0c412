"""The ``eval`` section of ``python -m pedrl.bench``: recording a batch of ``pedrl-eval`` (every frame of every room)
through the fused trial's kernels against the torch loop, in the paper's room, for the greedy walker (which needs no
checkpoint; a learned crowd adds the encoding, in the kernels as in torch).

Target (docs/performance.md, "Evaluation through the fused trial"): the kernels at least 3 times the torch loop's
rate at 100 agents.
"""

from __future__ import annotations

import time
from typing import Final

import torch

from pedrl.evaluation.engine import record_batch
from pedrl.scenarios import paper_room
from pedrl.sim.actions import GOAL_SPEED_RATIOS, GOAL_TURN_RATIOS
from pedrl.sim.controllers import GreedyDoorController
from pedrl.sim.motion import Yield

SIZES: Final = ((80, 100), (80, 20))
"""(rooms R, agents N) per batch: pedrl-eval's batch of the main job (8 processes x 10 trials) at 100 and 20 agents."""
MAIN_ROOM: Final = {
    "motion": Yield(order="door_first"),
    "action_frame": "goal",
    "speed_ratios": GOAL_SPEED_RATIOS,
    "turn_ratios": GOAL_TURN_RATIOS,
}
"""The main job's room (conf/experiment/main.yaml) but its rewards, which recording does not read."""
TARGET: Final = 3.0
"""The kernels' rate over the torch loop's at 100 agents that the section checks."""


def run(*, quick: bool = False, device: str = "cpu") -> dict:
    """Agent-decisions recorded per second on each path, and their ratio (``eval`` of ``bench.json``)."""
    if device != "cpu":
        return {"eval": {"skipped": f"the fused trial runs on the CPU, not {device}"}}
    results = {}
    for rooms, agents in ((8, 40),) if quick else SIZES:
        rates = {}
        for path, fused in (("torch", False), ("fused", True)):
            env = paper_room().room(num_replicas=rooms, num_agents=agents, **MAIN_ROOM)
            env.reset(seed=0)
            record_batch(env, GreedyDoorController(), fused=fused)  # compiles, warms the caches
            env.reset(seed=1)
            start = time.perf_counter()
            record = record_batch(env, GreedyDoorController(), fused=fused)
            seconds = time.perf_counter() - start
            rates[path] = float(record.speed_count.sum()) / seconds
        results[f"R{rooms}_N{agents}"] = {
            "torch_agent_decisions_per_s": rates["torch"],
            "fused_agent_decisions_per_s": rates["fused"],
            "ratio": rates["fused"] / rates["torch"],
            "threads": torch.get_num_threads(),
        }
    return {"eval": results}

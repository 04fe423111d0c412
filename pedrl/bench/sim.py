"""Simulation benchmark: random-action stepping of :class:`~pedrl.sim.RoomEnv`.

Metrics (wall-clock, after a warm-up):
    - ``env_steps_per_s``: ``RoomEnv.step`` calls per second, each advancing all R replicas by one decision
      (drawing the random actions included; a trial that reaches ``max_decisions`` is reset, inside the timing).
    - ``agent_steps_per_s``: ``env_steps_per_s * R * N``, agent-decisions simulated per second.

Run through ``python -m pedrl.bench --only sim``; :func:`run` writes nothing.
"""

from __future__ import annotations

import time
from typing import Final

import torch

from pedrl.scenarios import paper_room
from pedrl.sim.actions import NUM_ACTIONS

__all__ = ["SIZES", "run", "time_stepping"]

SIZES: Final = ((20, 20), (1000, 20), (20, 100))
"""(replicas R, agents N) to measure."""


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def time_stepping(
    *, num_replicas: int, num_agents: int, warmup_steps: int, steps: int, device: str = "cpu", seed: int = 0
) -> dict:
    """Time ``steps`` random-action steps of a ``RoomEnv(num_replicas, num_agents)`` after ``warmup_steps``.

    Args:
        num_replicas: Replicas R.
        num_agents: Agents per replica N.
        warmup_steps: Untimed steps first.
        steps: Timed steps.
        device: Torch device.
        seed: Seed of the environment and of the actions.

    Returns:
        ``{"replicas", "agents", "steps", "seconds", "env_steps_per_s", "agent_steps_per_s"}``.
    """
    env = paper_room().room(num_replicas=num_replicas, num_agents=num_agents, device=device)
    env.reset(seed=seed)
    generator = torch.Generator(device=env.device).manual_seed(seed)
    shape = (num_replicas, num_agents)

    def advance(count: int) -> None:
        for _ in range(count):
            if env.decision >= env.params.max_decisions:
                env.reset()
            env.step(torch.randint(0, NUM_ACTIONS, shape, generator=generator, device=env.device))

    advance(warmup_steps)
    _sync(env.device)
    start = time.perf_counter()
    advance(steps)
    _sync(env.device)
    seconds = time.perf_counter() - start
    return {
        "replicas": num_replicas,
        "agents": num_agents,
        "steps": steps,
        "seconds": seconds,
        "env_steps_per_s": steps / seconds,
        "agent_steps_per_s": steps * num_replicas * num_agents / seconds,
    }


def run(*, quick: bool = False, device: str = "cpu") -> dict:
    """Measure random-action stepping for every size in :data:`SIZES`.

    Args:
        quick: Few steps, for a smoke check (the figures are then rough).
        device: Torch device.

    Returns:
        ``{"sim": [{"replicas", "agents", "steps", "seconds", "env_steps_per_s", "agent_steps_per_s"}, ...]}``.
    """
    results = []
    for num_replicas, num_agents in SIZES:
        budget = 20_000 if quick else 1_000_000  # agent-steps timed per size
        steps = max(5, min(500, budget // (num_replicas * num_agents)))
        result = time_stepping(
            num_replicas=num_replicas,
            num_agents=num_agents,
            warmup_steps=max(2, steps // 10),
            steps=steps,
            device=device,
        )
        print(
            f"  sim R={num_replicas} N={num_agents}: {result['env_steps_per_s']:,.0f} env steps/s,"
            f" {result['agent_steps_per_s']:,.0f} agent-steps/s",
            flush=True,
        )
        results.append(result)
    return {"sim": results, "routed_reset": time_routed_reset(repeats=2 if quick else 5, device=device)}


def time_routed_reset(*, repeats: int, device: str = "cpu", resets: int = 20) -> dict:
    """Seconds per ``reset`` of 8 rooms of 40 walkers in the held-out partition room with its routes (each walker's
    exit and route chosen at placement, :mod:`pedrl.sim.routing`) and without them (the best of ``repeats``)."""
    from dataclasses import replace

    from omegaconf import OmegaConf

    from pedrl.common.commands import CONFIG_DIR
    from pedrl.scenarios import build_scenario

    scenario = build_scenario(OmegaConf.to_container(OmegaConf.load(f"{CONFIG_DIR}/scenario/partition_room.yaml")))
    rooms = {
        "with_routes": scenario.room(num_replicas=8, num_agents=40, device=device, agent_radius=0.2),
        "without_routes": replace(scenario, routes=None).room(
            num_replicas=8, num_agents=40, device=device, agent_radius=0.2
        ),
    }
    for env in rooms.values():
        env.reset(seed=0)  # warm-up
    best = dict.fromkeys(rooms, float("inf"))
    for _ in range(repeats):
        for name, env in rooms.items():
            _sync(env.device)
            start = time.perf_counter()
            for seed in range(resets):
                env.reset(seed=seed)
            _sync(env.device)
            best[name] = min(best[name], (time.perf_counter() - start) / resets)
    print(
        f"  reset of 8 x 40 walkers in the partition room: {best['with_routes'] * 1e3:.1f} ms with routes,"
        f" {best['without_routes'] * 1e3:.1f} ms without",
        flush=True,
    )
    return {name: {"seconds_per_reset": value} for name, value in best.items()}

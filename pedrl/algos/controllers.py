"""Controllers that act in a room: learned tables (for evaluation) and a non-learned greedy reference."""

from __future__ import annotations

import math
from typing import Any, Protocol

import torch

from pedrl.rl import epsilon_greedy
from pedrl.sim import RoomEnv


class Controller(Protocol):
    """Chooses actions ``(R, N)`` for a room from its observation ``(R, N, F)`` and info."""

    def act(self, env: RoomEnv, obs: torch.Tensor, info: dict[str, Any]) -> torch.Tensor: ...


class LearnedController:
    """Acts with learned tables ``q_values (P, A, K, U)`` over a quantizer, as the trainer that learned them.

    Replica ``i`` of the room is driven by process ``i mod P``; agent ``n`` uses table ``n mod A``, so a room with
    more agents than were learned replicates the learned tables (agent 20 reuses table 0, and so on).

    Args:
        trainer: the trainer that learned the tables (it knows how observations are quantized).
        quantizer: its :class:`pedrl.vq.Quantizer` or :class:`pedrl.vq.UnionQuantizer`.
        q_values: the tables.
        epsilon: exploration rate (0: greedy, ties broken at random).
    """

    def __init__(self, *, trainer: Any, quantizer: Any, q_values: torch.Tensor, epsilon: float) -> None:
        self.trainer = trainer
        self.quantizer = quantizer
        self.q_values = q_values
        self.epsilon = epsilon
        self._base: dict[tuple[int, int], torch.Tensor] = {}

    def _base_rows(self, replicas: int, agents: int) -> torch.Tensor:
        key = (replicas, agents)
        if key not in self._base:
            processes, tables, states, _ = self.q_values.shape
            device = self.q_values.device
            process = torch.arange(replicas, device=device).remainder(processes).repeat_interleave(agents)
            table = torch.arange(agents, device=device).remainder(tables).repeat(replicas)
            self._base[key] = (process * tables + table) * states
        return self._base[key]

    def act(self, env: RoomEnv, obs: torch.Tensor, info: dict[str, Any]) -> torch.Tensor:
        replicas, agents, _ = obs.shape
        rows = self._base_rows(replicas, agents) + self.trainer.encode_observations(self.quantizer, obs, info)
        return epsilon_greedy(self.q_values, rows, self.epsilon, self.trainer.generator).view(replicas, agents)


class GreedyDoorController:
    """The non-learned reference: turn towards the door as far as one decision allows, at full speed.

    It has no collision avoidance: the room's collision rule stops it on contact, as it stops learned agents.
    """

    def act(self, env: RoomEnv, obs: torch.Tensor, info: dict[str, Any]) -> torch.Tensor:
        velocity_angle = obs[..., 1]  # heading relative to the line to the door, rad
        turns = torch.as_tensor(env.turn_ratios, dtype=obs.dtype, device=obs.device) * math.pi
        # the turn that leaves the smallest angle to the door
        residual = torch.remainder(velocity_angle.unsqueeze(-1) + turns + math.pi, 2 * math.pi) - math.pi
        turn_index = residual.abs().argmin(dim=-1)
        speed_index = torch.as_tensor(env.speed_ratios, device=obs.device).argmax()
        return speed_index * len(env.turn_ratios) + turn_index

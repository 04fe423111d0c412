"""Controllers that act in a room: learned tables (for evaluation) and a non-learned greedy reference.

A controller maps a room's observation ``obs (R, N, F)`` and ``info`` (as :meth:`pedrl.sim.RoomEnv.step` returns
them) to actions ``(R, N)`` int64 in ``[0, 81)``. Actions of inactive agents are ignored by the room.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any, Protocol

import torch

from pedrl.rl import epsilon_greedy, table_rows
from pedrl.sim import RoomEnv
from pedrl.sim.checks import check_number

Encoder = Callable[[torch.Tensor, Mapping[str, Any], torch.Tensor], torch.Tensor]
"""``encode(obs (R, N, F), info, process (R * N,)) -> prototype ids (R * N,)`` int64, e.g. a trainer's
``encode_observations``; ``process`` is the learning process whose quantizer and tables drive each agent."""


class Controller(Protocol):
    """Chooses actions ``(R, N)`` for a room from its observation ``(R, N, F)`` and info."""

    def act(self, env: RoomEnv, obs: torch.Tensor, info: Mapping[str, Any]) -> torch.Tensor: ...


class LearnedController:
    """Acts epsilon-greedily on learned tables ``q_values (P, A, K, U)``.

    Replication rule (docs/design.md): replica ``i`` of the room is driven by learning process ``p = i mod P``,
    and agent ``n`` of every replica uses table ``n mod A`` of that process. A room with more agents than were
    learned therefore reuses the learned tables: with ``A = 20``, agents 20, 40, 60 and 80 all act with table 0,
    agent 21 with table 1, and so on. A room with fewer agents uses the first tables only.

    Args:
        q_values: ``(P, A, K, U)`` tables: P learning processes, A learning agents, K prototypes, U actions.
        encode: ``encode(obs (R, N, F), info, process (R * N,)) -> ids (R * N,)``, the prototype of every agent's
            state, as the trainer that learned the tables quantized it (``functools.partial(trainer.encode_observations,
            quantizer)``).
        epsilon: exploration rate in ``[0, 1]``; 0 is greedy (ties between equal action values broken at random).
        generator: random source for exploration and ties, on the device of ``q_values``; reseed it for
            reproducible runs.
    """

    def __init__(
        self,
        *,
        q_values: torch.Tensor,
        encode: Encoder,
        epsilon: float = 0.0,
        generator: torch.Generator | None = None,
    ) -> None:
        if q_values.ndim != 4:
            raise ValueError(f"q_values must have shape (P, A, K, U), got {tuple(q_values.shape)}")
        check_number("epsilon", epsilon, low=0.0, high=1.0)
        self.q_values = q_values
        self.encode = encode
        self.epsilon = float(epsilon)
        self.generator = generator if generator is not None else torch.Generator(device=q_values.device)
        self._layouts: dict[tuple[int, int], tuple[torch.Tensor, torch.Tensor]] = {}

    @property
    def num_processes(self) -> int:
        """P, the learning processes stored in the tables."""
        return self.q_values.shape[0]

    @property
    def num_tables(self) -> int:
        """A, the learned tables per process."""
        return self.q_values.shape[1]

    def table_of(self, replicas: int, agents: int) -> tuple[torch.Tensor, torch.Tensor]:
        """``(process (R, N), table (R, N))``: the table ``q_values[process, table]`` every agent acts with."""
        device = self.q_values.device
        process = torch.arange(replicas, device=device).remainder(self.num_processes)
        table = torch.arange(agents, device=device).remainder(self.num_tables)
        return process[:, None].expand(replicas, agents), table[None, :].expand(replicas, agents)

    def _layout(self, replicas: int, agents: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Flat ``(R * N,)`` learning process of every agent, and the row ``(p * A + a) * K`` of its table in
        ``q_values.view(-1, U)``; cached per room shape."""
        key = (replicas, agents)
        if key not in self._layouts:
            process, table = self.table_of(replicas, agents)
            rows = table_rows(process, table, 0, num_tables=self.num_tables, num_states=self.q_values.shape[2])
            self._layouts[key] = (process.reshape(-1), rows.reshape(-1))
        return self._layouts[key]

    def act(self, env: RoomEnv | None, obs: torch.Tensor, info: Mapping[str, Any]) -> torch.Tensor:
        """Actions ``(R, N)`` int64 for observations ``obs (R, N, F)``."""
        replicas, agents, _ = obs.shape
        process, base_rows = self._layout(replicas, agents)
        rows = base_rows + self.encode(obs, info, process)
        return epsilon_greedy(self.q_values, rows, self.epsilon, self.generator).view(replicas, agents)


class GreedyDoorController:
    """The non-learned reference: turn towards the door as far as one decision allows, at full speed.

    Every decision it takes the largest speed increase (full speed from standstill in one decision with the
    default ratios) and the turn that leaves the smallest angle between heading and the line to the door centre.
    It has no collision avoidance: the room's collision rule stops it on contact (speed 0 for the rest of the
    decision), as it stops learned agents, and it accelerates again at the next decision. With ``epsilon > 0`` a
    fraction ``epsilon`` of its actions are uniform random ones, as the learned controller's are: a push to the
    door with some noise, which tells what the room lets a crowd do.

    Args:
        epsilon: fraction of random actions in ``[0, 1]``.
        generator: random source of those actions (CPU generator for a CPU room).
    """

    def __init__(self, *, epsilon: float = 0.0, generator: torch.Generator | None = None) -> None:
        check_number("epsilon", epsilon, low=0.0, high=1.0)
        self.epsilon = float(epsilon)
        self.generator = generator if generator is not None else torch.Generator()

    def act(self, env: RoomEnv, obs: torch.Tensor, info: Mapping[str, Any]) -> torch.Tensor:
        """Actions ``(R, N)`` int64 for observations ``obs (R, N, F)`` of ``env``."""
        velocity_angle = obs[..., 1]  # heading relative to the line to the door, rad, in (-pi, pi]
        turns = torch.as_tensor(env.turn_ratios, dtype=obs.dtype, device=obs.device) * math.pi
        residual = torch.remainder(velocity_angle.unsqueeze(-1) + turns + math.pi, 2 * math.pi) - math.pi
        turn_index = residual.abs().argmin(dim=-1)
        speed_index = int(torch.as_tensor(env.speed_ratios).argmax())
        actions = speed_index * len(env.turn_ratios) + turn_index
        if self.epsilon == 0.0:
            return actions
        draw = torch.rand(actions.shape, generator=self.generator, device=self.generator.device)
        random = torch.randint(
            0, env.num_actions, actions.shape, generator=self.generator, device=self.generator.device
        )
        return torch.where(draw.to(actions.device) < self.epsilon, random.to(actions.device), actions)

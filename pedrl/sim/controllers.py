"""What acts in a room during evaluation (:class:`Controller`), and the non-learned greedy reference.

A learned policy acts through :meth:`pedrl.rl.TabularPolicy.controller`.

A controller maps a room's observation ``obs (R, N, F)`` and ``info`` (as :meth:`pedrl.sim.RoomEnv.step` returns
them) to actions ``(R, N)`` int64 in ``[0, 81)``. Actions of inactive agents are ignored by the room.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, Protocol

import torch

from pedrl.common.checks import check_number
from pedrl.sim.env import RoomEnv


class Controller(Protocol):
    """Chooses actions ``(R, N)`` for a room from its observation ``(R, N, F)`` and info."""

    def act(self, env: RoomEnv, obs: torch.Tensor, info: Mapping[str, Any]) -> torch.Tensor: ...


class GreedyDoorController:
    """The non-learned reference: turn towards the door as far as one decision allows, at full speed.

    Every decision it takes the largest speed increase (full speed from standstill in one decision with the
    default ratios) and the turn that leaves the smallest angle between heading and the line to the door centre;
    in the ``goal`` action frame, the top speed straight at the door (or waypoint), whatever its heading was.
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
        turns = torch.as_tensor(env.params.turn_ratios, dtype=obs.dtype, device=obs.device) * math.pi
        if env.params.action_frame == "goal":  # the turn index sets the heading relative to the line to the door
            residual = turns.expand(*obs.shape[:-1], -1)
        else:
            velocity_angle = obs[..., 1]  # heading relative to the line to the door, rad, in (-pi, pi]
            residual = torch.remainder(velocity_angle.unsqueeze(-1) + turns + math.pi, 2 * math.pi) - math.pi
        turn_index = residual.abs().argmin(dim=-1)
        speed_index = int(torch.as_tensor(env.params.speed_ratios).argmax())
        actions = speed_index * len(env.params.turn_ratios) + turn_index
        if self.epsilon == 0.0:
            return actions
        draw = torch.rand(actions.shape, generator=self.generator, device=self.generator.device)
        random = torch.randint(
            0, env.num_actions, actions.shape, generator=self.generator, device=self.generator.device
        )
        return torch.where(draw.to(actions.device) < self.epsilon, random.to(actions.device), actions)

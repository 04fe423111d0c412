"""Crowds the validation suite simulates: a pedrl room driven by a controller (learned tables or greedy), or JuPedSim.

A crowd turns a scenario, a number of agents and a time budget into a :class:`~pedrl.validation.measures.Recording`;
the tests judge recordings only, so every model is held to the same measures. Both crowds place their agents with
the pedrl room of the run (its ``reset(seed=...)``, or the test's hand placement): JuPedSim starts from the very
positions, exits and routes of the pedrl runs it is compared with.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np
import torch

from pedrl.scenarios import Scenario
from pedrl.sim import RoomEnv
from pedrl.validation.measures import Recording


class Crowd(Protocol):
    """Simulates the agents of a scenario; ``radius`` (m) is the body size of every run."""

    radius: float

    def simulate(
        self,
        scenario: Scenario,
        *,
        num_agents: int,
        replicas: int,
        max_time: float,
        seed: int,
        max_speed: float | None = None,
        positions: np.ndarray | None = None,
        headings: np.ndarray | None = None,
    ) -> Recording:
        """Run ``replicas`` runs of ``num_agents`` agents in ``scenario`` for at most ``max_time`` s.

        Args:
            max_speed: The test's free speed (m/s), or ``None`` for the crowd's own.
            positions: ``(R, N, 2)`` start positions (m), or ``None`` for the room's placement in its spawn areas.
            headings: ``(R, N)`` start headings (rad) of hand-placed agents, or ``None`` for the room's (uniform).
        """
        ...


@dataclass
class PedrlCrowd:
    """A pedrl room of the run's ``env`` settings, driven by ``controller`` (``act(env, obs, info) -> (R, N)``).

    A test's ``max_speed`` replaces the room's top speed; the controller's speed changes stay fractions of it.
    """

    controller: Any
    env_settings: Mapping[str, Any] = field(default_factory=dict)
    device: torch.device = field(default_factory=lambda: torch.device("cpu"))

    @property
    def radius(self) -> float:
        return float(self.env_settings.get("agent_radius", 0.4))

    def room(
        self,
        scenario: Scenario,
        *,
        num_agents: int,
        replicas: int,
        max_time: float,
        max_speed: float | None = None,
        placed: bool = False,
    ) -> RoomEnv:
        """The room of a run (``placed``: the agents are placed by hand, so the spawn areas' capacity is not
        checked); raises a one-line ``ValueError`` when the agents cannot fit."""
        settings = {key: value for key, value in self.env_settings.items() if key not in ("_target_", "max_decisions")}
        if max_speed is not None:
            settings["max_speed"] = max_speed
        rate = float(settings.get("decisions_per_second", 1.0))
        room = dict(
            settings,
            num_agents=num_agents,
            num_replicas=replicas,
            max_decisions=max(1, math.ceil(max_time * rate)),
            device=self.device,
        )
        if placed:
            return RoomEnv(**room, geometry=scenario.geometry(goal_depth=float(settings.get("goal_depth", 0.0))))
        return scenario.room(**room)

    def simulate(
        self,
        scenario: Scenario,
        *,
        num_agents: int,
        replicas: int,
        max_time: float,
        seed: int,
        max_speed: float | None = None,
        positions: np.ndarray | None = None,
        headings: np.ndarray | None = None,
    ) -> Recording:
        env = self.room(
            scenario,
            num_agents=num_agents,
            replicas=replicas,
            max_time=max_time,
            max_speed=max_speed,
            placed=positions is not None,
        )
        obs, info = env.reset(seed=seed, options=_options(positions, headings))
        frames, active = [env.positions.clone()], [env.active.clone()]
        left_at = torch.full(env.active.shape, -1, dtype=torch.int64, device=env.device)
        decision = 0
        while bool(env.active.any()):
            obs, _, terminated, _, info = env.step(self.controller.act(env, obs, info))
            decision += 1
            left_at = torch.where(terminated, decision, left_at)
            frames.append(env.positions.clone())
            active.append(env.active.clone())
        return Recording(
            positions=torch.stack(frames).cpu().numpy(),
            active=torch.stack(active).cpu().numpy(),
            left_at=left_at.cpu().numpy(),
            frame_rate=env.decisions_per_second,
            radius=env.agent_radius,
            max_speed=env.max_speed,
        )


@dataclass
class JuPedSimCrowd:
    """JuPedSim's model (:class:`pedrl.integrations.jupedsim.JuPedSimModel`) from the start positions, exits and
    routes of a pedrl room of the same scenario, agents and seed (``placement``, a :class:`PedrlCrowd` whose room
    only places the agents).

    A test's ``max_speed`` becomes JuPedSim's desired speed; otherwise the model's own (JuPedSim's default).
    Replicas run one after another.
    """

    model: Any
    placement: PedrlCrowd
    frame_rate: float = 2.0

    @property
    def radius(self) -> float:
        return self.model.radius

    def simulate(
        self,
        scenario: Scenario,
        *,
        num_agents: int,
        replicas: int,
        max_time: float,
        seed: int,
        max_speed: float | None = None,
        positions: np.ndarray | None = None,
        headings: np.ndarray | None = None,
    ) -> Recording:
        from pedrl.integrations.jupedsim import room_scene, simulate

        model = self.model if max_speed is None else replace(self.model, desired_speed=max_speed)
        env = self.placement.room(
            scenario, num_agents=num_agents, replicas=replicas, max_time=max_time, placed=positions is not None
        )
        env.reset(seed=seed, options=_options(positions, headings))
        runs = []
        for replica in range(replicas):
            scene = room_scene(env, replica=replica)
            runs.append(
                simulate(
                    scenario,
                    positions=scene.positions,
                    exit_index=scene.exit_index,
                    waypoints=scene.waypoints,
                    model=model,
                    max_time=max_time,
                    frame_rate=self.frame_rate,
                )
            )
        length = max(run.positions.shape[0] for run in runs)
        return Recording(
            positions=np.stack([_pad(run.positions, length) for run in runs], axis=1),
            active=np.stack([_pad(run.active, length, fill=False) for run in runs], axis=1),
            left_at=np.stack([run.left_at for run in runs]),
            frame_rate=self.frame_rate,
            radius=model.radius,
            max_speed=model.desired_speed,
        )


def _options(positions: np.ndarray | None, headings: np.ndarray | None) -> dict[str, torch.Tensor] | None:
    """The room's ``reset`` options of a hand placement."""
    if positions is None:
        return None
    options = {"positions": torch.as_tensor(positions, dtype=torch.float32)}
    if headings is not None:
        options["headings"] = torch.as_tensor(headings, dtype=torch.float32)
    return options


def _pad(values: np.ndarray, length: int, fill: Any = None) -> np.ndarray:
    """``values (T, ...)`` extended to ``length`` frames with ``fill`` (default: its last frame)."""
    missing = length - values.shape[0]
    if missing <= 0:
        return values
    tail = np.repeat(values[-1:], missing, axis=0) if fill is None else np.full((missing, *values.shape[1:]), fill)
    return np.concatenate([values, tail])

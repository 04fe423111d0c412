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

from pedrl.analysis import Recording
from pedrl.configs import room_keywords
from pedrl.integrations.jupedsim import pad_frames, simulate_room
from pedrl.scenarios import Scenario
from pedrl.sim import RoomEnv, RoomParams
from pedrl.trial.crowd import run_crowd


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


def exit_times(left_at: np.ndarray, frame_rate: float) -> np.ndarray:
    """``(R, N)`` times (s) of the frames ``left_at`` at which agents left (-1: never, NaN)."""
    return np.where(left_at >= 0, left_at / frame_rate, np.nan)


@dataclass
class PedrlCrowd:
    """A pedrl room of the run's ``env`` settings, driven by ``controller`` (``act(env, obs, info) -> (R, N)``).

    A test's ``max_speed`` replaces the room's top speed; the controller's speed changes stay fractions of it.
    """

    controller: Any
    env_settings: Mapping[str, Any] = field(default_factory=dict)
    device: torch.device = field(default_factory=lambda: torch.device("cpu"))
    fused: bool | None = None
    """Run through the fused trial's kernels, or the torch loop (False); None: the kernels wherever they can run
    (:func:`pedrl.trial.crowd.run_crowd` chooses)."""

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
        settings = room_keywords(self.env_settings)
        settings.pop("max_decisions", None)
        if max_speed is not None:
            settings["max_speed"] = max_speed
        rate = float(settings.get("decisions_per_second", 1.0))
        params = RoomParams.from_settings(settings, max_decisions=max(1, math.ceil(max_time * rate)))
        batch = {"num_agents": num_agents, "num_replicas": replicas, "device": self.device}
        if placed:
            return RoomEnv(scenario.geometry(), params, **batch)
        return scenario.room(params, **batch)

    def start(
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
    ) -> tuple[RoomEnv, tuple[torch.Tensor, dict[str, Any]]]:
        """The room of a run, reset for ``seed`` with the hand placement (if any); and ``reset``'s ``(obs, info)``."""
        env = self.room(
            scenario,
            num_agents=num_agents,
            replicas=replicas,
            max_time=max_time,
            max_speed=max_speed,
            placed=positions is not None,
        )
        options = None
        if positions is not None:
            options = {"positions": torch.as_tensor(positions, dtype=torch.float32)}
            if headings is not None:
                options["headings"] = torch.as_tensor(headings, dtype=torch.float32)
        return env, env.reset(seed=seed, options=options)

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
        env, (obs, info) = self.start(
            scenario,
            num_agents=num_agents,
            replicas=replicas,
            max_time=max_time,
            seed=seed,
            max_speed=max_speed,
            positions=positions,
            headings=headings,
        )
        record = run_crowd(env, self.controller, fused=self.fused, record=True, start=(obs, info)).record
        return Recording(
            positions=record.positions,
            in_room=record.in_room,
            exit_time=exit_times(record.left_at, env.params.decisions_per_second),
            frame_rate=env.params.decisions_per_second,
            radius=env.params.agent_radius,
            max_speed=env.params.max_speed,
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
        model = self.model if max_speed is None else replace(self.model, desired_speed=max_speed)
        env, _ = self.placement.start(
            scenario,
            num_agents=num_agents,
            replicas=replicas,
            max_time=max_time,
            seed=seed,
            positions=positions,
            headings=headings,
        )
        runs = simulate_room(scenario, env, model=model, max_time=max_time, frame_rate=self.frame_rate)
        length = max(run.positions.shape[0] for run in runs)
        return Recording(
            positions=np.stack([pad_frames(run.positions, length) for run in runs]),
            in_room=np.stack([pad_frames(run.active, length, fill=False) for run in runs]),
            exit_time=exit_times(np.stack([run.left_at for run in runs]), self.frame_rate),
            frame_rate=self.frame_rate,
            radius=model.radius,
            max_speed=model.desired_speed,
        )

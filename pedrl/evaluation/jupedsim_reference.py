"""``controller=jupedsim``: JuPedSim's model in place of a controller, on the evaluation's own scenes.

:class:`JuPedSimReference` records a batch as :func:`pedrl.evaluation.engine.record_batch` does for a controller:
it resets the room (whose generator draws the same initial scenes as for the other controllers), then runs
:func:`pedrl.integrations.jupedsim.simulate` from each replica's scene, one replica after another, with the room's
body radius, over the room's trial length (``max_decisions / decisions_per_second`` s), sampled once per decision.
The frames then follow the room's conventions, so that every figure of Tables 4/5 is computed the same way:

- an agent is in frame t if it was in the area at frame t - 1 (it "took decision t"): it appears in the frame at
  which it left, at the point where it crossed its exit (JuPedSim removes it there);
- its exit time is that frame's time, ``left_at / decisions_per_second``, as the room counts whole decisions;
- its speed in frame t is its mean speed over the interval ending there (over the part before it left, in the
  frame at which it left);
- contacts and wall contacts are n/a (NaN): the room's contacts are moves its contact rule cut, an event JuPedSim's
  models do not have (the collision-free speed model slows down before contact instead).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from pedrl.common.recording import Recording
from pedrl.integrations.jupedsim import (
    JuPedSimModel,
    JuPedSimRun,
    apron_depth,
    check_model,
    pad_frames,
    simulate_room,
    walkable_with_aprons,
)
from pedrl.scenarios import Scenario
from pedrl.sim import RoomEnv


@dataclass(frozen=True)
class JuPedSimReference:
    """JuPedSim's ``model`` in ``scenario`` (the rooms' scenario), on the rooms' initial scenes.

    Attributes:
        scenario: the scenario the rooms are built in.
        model: the JuPedSim model; its ``radius`` is replaced by the room's ``agent_radius``.
    """

    scenario: Scenario
    model: JuPedSimModel

    def check(self, env: RoomEnv) -> None:
        """One-line ``ValueError`` if a decision of ``env`` is not a whole number of JuPedSim steps, the scenario
        has no room for JuPedSim's exit aprons, or JuPedSim refuses the model's parameters at the room's body radius."""
        model = replace(self.model, radius=env.params.agent_radius)
        walkable_with_aprons(self.scenario, depth=apron_depth(model))
        check_model(model)
        steps = env.params.decision_length / self.model.dt
        if abs(steps - round(steps)) > 1e-6 * steps or round(steps) < 1:
            raise ValueError(
                f"jupedsim.dt={self.model.dt!r} is invalid: a decision of the room (1 / decisions_per_second ="
                f" {env.params.decision_length:g} s) must be a whole number of JuPedSim steps"
            )

    def record(self, env: RoomEnv) -> Recording:
        """Reset ``env`` (its generator draws the scenes) and simulate every replica's scene with JuPedSim."""
        env.reset()
        model = replace(self.model, radius=env.params.agent_radius)
        max_time = env.params.max_decisions * env.params.decision_length
        return batch_record(
            simulate_room(
                self.scenario, env, model=model, max_time=max_time, frame_rate=env.params.decisions_per_second
            )
        )


def batch_record(runs: list[JuPedSimRun]) -> Recording:
    """JuPedSim runs of one scene count as a :class:`~pedrl.common.recording.Recording` (one replica each), in
    the room's conventions (module docstring); shorter runs are padded with their last frame, agents inactive."""
    length = max(run.num_frames for run in runs)
    frames = np.arange(length)[:, None]  # (T, 1)
    positions, velocities, in_room, active, speeds = [], [], [], [], []
    for run in runs:
        in_frame = (~run.left)[None, :] | (frames <= run.left_at[None, :])  # (T, N): in the area at frame t - 1
        velocity = pad_frames(run.velocities(), length, fill=0.0)
        positions.append(pad_frames(run.positions, length))
        velocities.append(velocity)
        active.append(in_frame)
        in_room.append((~run.left)[None, :] | (frames < run.left_at[None, :]))  # (T, N): in the area at frame t
        speeds.append(np.where(in_frame[1:], np.linalg.norm(velocity[1:], axis=-1), 0.0))  # (T - 1, N) m/s
    speed = np.stack(speeds)  # (R, T - 1, N)
    counted = np.stack(active)[:, 1:]
    return Recording(
        positions=np.stack(positions).astype(np.float32),
        velocities=np.stack(velocities).astype(np.float32),
        in_room=np.stack(in_room),
        exit_time=np.stack([np.where(run.left, run.left_at / run.frame_rate, math.nan) for run in runs]),
        frame_rate=runs[0].frame_rate,
        crashes=np.full((len(runs), runs[0].num_agents), math.nan),
        wall_crashes=np.full((len(runs), runs[0].num_agents), math.nan),
        speed_sum=speed.sum(axis=(1, 2)),
        speed_sq_sum=(speed * speed).sum(axis=(1, 2)),
        speed_count=counted.sum(axis=(1, 2)),
    )

"""Synthetic trials for the analysis tests: agents walking straight to the door of a room."""

from collections.abc import Callable

import numpy as np
import pytest

from pedrl.analysis import RoomGeometry, Trajectories


def walk_to_door(
    *,
    seed: int = 0,
    num_agents: int = 12,
    num_frames: int = 25,
    geometry: RoomGeometry | None = None,
    dtype: type = np.float32,
) -> Trajectories:
    """Agents start uniformly in the room and walk towards the door centre at a constant speed per agent.

    An agent stays active up to and including the first frame whose centre is at ``y >= length`` (the exit
    frame, as a recorder is advised to keep it), and is inactive afterwards.
    """
    geometry = geometry or RoomGeometry(width=20.0, length=30.0, door_width=2.0)
    rng = np.random.default_rng(seed)
    positions = np.zeros((num_frames, num_agents, 2))
    velocities = np.zeros_like(positions)
    positions[0] = rng.uniform([1.0, 1.0], [geometry.width - 1.0, geometry.length - 1.0], (num_agents, 2))
    speeds = rng.uniform(0.5, 2.5, (num_agents, 1))
    active = np.ones((num_frames, num_agents), dtype=bool)
    for t in range(1, num_frames):
        heading = geometry.door_center + [0.0, 0.5] - positions[t - 1]
        heading /= np.linalg.norm(heading, axis=-1, keepdims=True)
        velocities[t] = heading * speeds
        positions[t] = positions[t - 1] + velocities[t]
        active[t] = active[t - 1] & (positions[t - 1, :, 1] < geometry.length)
    return Trajectories(
        positions=positions.astype(dtype),
        velocities=velocities.astype(dtype),
        active=active,
        framerate=1.0,
        geometry=geometry,
    )


@pytest.fixture
def make_trial() -> Callable[..., Trajectories]:
    return walk_to_door

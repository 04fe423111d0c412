"""Batched room simulation: the compiled walkable area, dynamics, sensing, rewards and ``RoomEnv`` (pure torch, no
I/O)."""

from pedrl.sim.actions import (
    ACTION_FRAMES,
    COARSE_TURN_RATIOS,
    COMMAND_WIDTH,
    DEFAULT_SPEED_RATIOS,
    DEFAULT_TURN_RATIOS,
    GOAL_SPEED_RATIOS,
    GOAL_TURN_RATIOS,
    NOOP_ACTION,
    NUM_ACTIONS,
    apply_actions,
    apply_commands,
    commands_of,
    decode_actions,
    encode_actions,
    velocities_from,
)
from pedrl.sim.env import PlacementError, RoomEnv
from pedrl.sim.geometry import Geometry, RouteTable, SpawnArea, X, Y, wrap_angle
from pedrl.sim.motion import Movement, move_agents
from pedrl.sim.params import RoomParams
from pedrl.sim.rewards import RewardTable, compute_rewards
from pedrl.sim.sensing import (
    Observation,
    feature_indices,
    feature_names,
    fill_void_neighbours,
    num_features,
    observe,
)
from pedrl.sim.spawning import Spawns

__all__ = [
    "ACTION_FRAMES",
    "DEFAULT_SPEED_RATIOS",
    "GOAL_SPEED_RATIOS",
    "GOAL_TURN_RATIOS",
    "COARSE_TURN_RATIOS",
    "DEFAULT_TURN_RATIOS",
    "NOOP_ACTION",
    "NUM_ACTIONS",
    "X",
    "Y",
    "Movement",
    "Observation",
    "PlacementError",
    "RewardTable",
    "RoomEnv",
    "RoomParams",
    "Geometry",
    "RouteTable",
    "SpawnArea",
    "Spawns",
    "COMMAND_WIDTH",
    "apply_actions",
    "apply_commands",
    "commands_of",
    "compute_rewards",
    "decode_actions",
    "encode_actions",
    "feature_indices",
    "feature_names",
    "fill_void_neighbours",
    "move_agents",
    "num_features",
    "observe",
    "velocities_from",
    "wrap_angle",
]

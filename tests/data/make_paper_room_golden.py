"""Write ``paper_room_golden.npz``: seeded trajectories of the rectangular room, the reference for the geometry.

Generated once with the rectangle-only simulation (before polygons): the paper's room as a polygon scenario must give
the same features, positions, rewards and flags to the bit (``tests/sim/test_scenario_golden.py``).
Run ``python tests/data/make_paper_room_golden.py`` only to regenerate after a deliberate change of the dynamics.
"""

from pathlib import Path

import numpy as np
import torch

from pedrl.scenarios import paper_room
from pedrl.sim import COARSE_TURN_RATIOS
from pedrl.sim.motion import Simultaneous, Stop

CASES = {
    # name: (room kwargs, decisions)
    "paper_sequential": (dict(num_replicas=2, num_agents=20), 25),
    "small_sequential": (dict(num_replicas=2, num_agents=12, width=6.0, length=8.0, door_width=1.5), 60),
    "small_door_first": (
        dict(num_replicas=2, num_agents=12, width=6.0, length=8.0, door_width=1.5, motion=Stop(order="door_first")),
        60,
    ),
    "small_simultaneous": (
        dict(num_replicas=2, num_agents=12, width=6.0, length=8.0, door_width=1.5, motion=Simultaneous()),
        60,
    ),
}


def simulate(kwargs: dict, decisions: int, seed: int = 7) -> dict[str, np.ndarray]:
    """Features, positions, rewards, reached and crash flags of a seeded run under seeded random actions."""
    sizes = {key: value for key, value in kwargs.items() if key in ("width", "length", "door_width")}
    settings = {key: value for key, value in kwargs.items() if key not in sizes}
    # the action set the golden runs were recorded with
    env = paper_room(**sizes).room(**{"turn_ratios": COARSE_TURN_RATIOS, **settings})
    actions = torch.Generator().manual_seed(seed + 1)
    obs, _ = env.reset(seed=seed)
    record = {"features": [obs], "positions": [env.positions], "reward": [], "reached": [], "crashed": []}
    for _ in range(decisions):
        chosen = torch.randint(0, env.num_actions, (env.num_replicas, env.num_agents), generator=actions)
        obs, reward, terminated, _, info = env.step(chosen)
        record["features"].append(obs)
        record["positions"].append(env.positions)
        record["reward"].append(reward)
        record["reached"].append(terminated)
        record["crashed"].append(info["crashed_agent"] | info["crashed_wall"])
    return {key: torch.stack(values).numpy() for key, values in record.items()}


if __name__ == "__main__":
    arrays = {}
    for name, (kwargs, decisions) in CASES.items():
        for key, value in simulate(kwargs, decisions).items():
            arrays[f"{name}/{key}"] = value
    path = Path(__file__).with_name("paper_room_golden.npz")
    np.savez_compressed(path, **arrays)
    print(path, path.stat().st_size, "bytes")

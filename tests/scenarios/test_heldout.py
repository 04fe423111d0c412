"""The held-out rooms (conf/scenario/l_room.yaml, pillar_room.yaml, and partition_room.yaml, corridor_room.yaml whose
exit is out of sight from every start: tests/scenarios/test_routes.py): geometries that no training run sees, given
as WKT (tests/data/heldout/), that a crowd can leave by every exit."""

from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf

from pedrl.cli import CONFIG_DIR
from pedrl.scenarios import build_scenario
from pedrl.sim.controllers import GreedyDoorController
from pedrl.sim.motion import Yield

CONF = Path(CONFIG_DIR) / "scenario"
DATA = Path(__file__).resolve().parents[1] / "data" / "heldout"
NOMINAL = {"l_room": 60, "pillar_room": 40, "partition_room": 40, "corridor_room": 40}
"""The nominal crowd of each room (its config's header)."""


def scenario_config(name: str) -> dict:
    return OmegaConf.to_container(OmegaConf.load(CONF / f"{name}.yaml"), resolve=True)


@pytest.mark.parametrize("name", sorted(NOMINAL))
def test_the_config_holds_the_wkt_of_the_data_file(name):
    """One polygon: the scenario config's WKT text is the file's, so the tests and the users run the same room."""
    assert scenario_config(name)["geometry"] == (DATA / f"{name}.wkt").read_text().strip()


@pytest.mark.parametrize(("name", "least"), [("l_room", 1.0), ("pillar_room", 0.75)])
def test_a_small_crowd_of_greedy_walkers_leaves_by_every_exit(name, least):
    """The rooms can be left: 10 walkers heading straight for their nearest exit all leave the L-room, by both exits,
    and most leave the pillar room (those aimed at the pillar slide round it). At the nominal crowds the greedy
    walkers leave 88 % (L-room, 60) and 53 % (pillar room, 40) of the time: the pillar is what a learned pedestrian
    must handle (docs/results.md)."""
    scenario = build_scenario(scenario_config(name))
    env = scenario.room(
        num_replicas=4, num_agents=10, device="cpu", max_decisions=150, motion=Yield(order="door_first")
    )
    controller = GreedyDoorController(epsilon=0.1, generator=torch.Generator().manual_seed(0))
    obs, info = env.reset(seed=1)
    exits_used = torch.zeros(env.geometry.num_exits, dtype=torch.bool)
    reached = torch.zeros(env.num_replicas, env.num_agents, dtype=torch.bool)
    while bool(env.active.any()):
        obs, _, _, _, info = env.step(controller.act(env, obs, info))
        reached |= info["reached"]
        exits_used |= torch.zeros_like(exits_used).index_fill(0, env.exit_index[info["reached"]], True)
    assert float(reached.float().mean()) >= least, float(reached.float().mean())
    assert bool(exits_used.all()), "every exit is used (the L-room's two: agents take the nearest)"


def test_the_pillar_stands_in_front_of_the_door():
    """The control that the pillar is there: a walker aimed straight at the door centre from below is blocked by it
    (the hole's walls), which a room without the pillar does not do."""
    config = scenario_config("pillar_room")
    rooms = {"with pillar": config, "without": {**config, "geometry": "POLYGON ((0 0, 16 0, 16 12, 0 12, 0 0))"}}
    walls_hit = {}
    for label, cfg in rooms.items():
        env = build_scenario(cfg).room(num_replicas=1, num_agents=1, device="cpu", max_decisions=30)
        obs, info = env.reset(options={"positions": [[[8.0, 6.0]]], "headings": [[torch.pi / 2]], "speeds": [[1.0]]})
        hits = 0
        for _ in range(10):
            obs, _, _, _, info = env.step(torch.tensor([[40]]))  # keep speed and heading: straight up
            hits += int(info["crashed_wall"].sum())
        walls_hit[label] = hits
    assert walls_hit["with pillar"] > 0 and walls_hit["without"] == 0

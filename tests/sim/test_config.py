"""conf/env/room.yaml builds a room (through the scenario group's area) and mirrors the defaults of the room's
settings and of the paper's room."""

import dataclasses
import inspect
from pathlib import Path

from omegaconf import OmegaConf

from pedrl.configs import AREA_SETTINGS, env_factory
from pedrl.scenarios import paper_room
from pedrl.sim import RoomEnv, RoomParams

CONFIG = Path(__file__).resolve().parents[2] / "conf" / "env" / "room.yaml"


def test_room_config_builds_a_room_with_run_time_arguments():
    env = env_factory(OmegaConf.to_container(OmegaConf.load(CONFIG)))(num_replicas=2, num_agents=5, device="cpu")
    assert isinstance(env, RoomEnv)
    assert (env.num_replicas, env.num_agents, env.device.type) == (2, 5, "cpu")
    assert isinstance(env.params.speed_ratios, tuple) and all(isinstance(v, float) for v in env.params.speed_ratios)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (2, 5, 28)


def test_room_config_lists_every_parameter_with_the_constructor_default():
    """The room's settings take RoomParams's defaults (its motion model: conf/motion/); the paper's room's sizes
    take paper_room's."""
    cfg = OmegaConf.to_container(OmegaConf.load(CONFIG))
    assert cfg.pop("_target_") == "pedrl.sim.RoomEnv"
    expected = {item.name: item.default for item in dataclasses.fields(RoomParams) if item.name != "motion"}
    area = inspect.signature(paper_room).parameters
    expected |= {name: area[name].default for name in AREA_SETTINGS}
    assert set(cfg) == set(expected)
    for name, default in expected.items():
        value = tuple(cfg[name]) if isinstance(cfg[name], list) else cfg[name]
        assert value == default, name


def test_every_config_value_has_a_comment_giving_its_unit():
    raw = CONFIG.read_text().splitlines()
    for index, line in enumerate(raw):
        if not line or line.startswith(("#", "_target_")):
            continue
        previous = raw[index - 1] if index else ""
        assert "#" in line or previous.startswith("#"), line

"""One source of truth for every default: the YAML files under conf/ hold them, the Python signatures follow.

A value users run is the one in the config group they compose (conf/algo/*.yaml, conf/env/room.yaml,
conf/vq/default.yaml, the top-level keys of conf/train.yaml and conf/logger/tensorboard.yaml). A class built
without that config (a test, a benchmark, a notebook) takes its signature's defaults, and these must be the same
values. Each case below compares one key of one file with the Python default of the class it configures: the
trainer classes' keyword defaults, following ``**kwargs`` up to :class:`pedrl.algos.base.Trainer` as
``pedrl.algos.registry._parameters`` does; the fields of :class:`pedrl.sim.RoomParams` (the room's settings), of the
motion models (``conf/motion/``) and of :class:`pedrl.algos.base.VQSettings`. A Python default of ``None`` meaning
"computed" agrees with a YAML ``null``.
"""

from __future__ import annotations

import dataclasses
import inspect
from pathlib import Path
from typing import Any

import pytest
from omegaconf import OmegaConf

from pedrl.algos.registry import RUN_KEYS, TRAINER_CLASSES
from pedrl.algos.run import RunSpec
from pedrl.cli import CONFIG_DIR
from pedrl.configs import AREA_SETTINGS
from pedrl.scenarios import paper_room
from pedrl.sim import RoomParams
from pedrl.sim.motion import MOTION_MODELS, motion_from_config
from pedrl.vq.settings import VQSettings

CONF = Path(CONFIG_DIR)
ALGOS = ("vqql", "it_vqql", "in_vqql")

# Python defaults that disagree with the YAML today; the YAML wins, and the signature is to change (the value in
# the YAML file is the new default). Remove an entry once its signature holds the YAML value.
AWAITING_SIGNATURE: dict[tuple[str, str], str] = {}

# Top-level keys of conf/train.yaml that are keys of the run (RunSpec), and the logger group's key.
TRAIN_KEYS = ("processes", "rooms_per_process", "checkpoint_every", "device", "seed", "progress")
RUN_DEFAULTS = {item.name: item.default for item in dataclasses.fields(RunSpec)}


def keyword_defaults(cls: type) -> dict[str, Any]:
    """Keyword parameters of ``cls`` and their defaults, following ``**kwargs`` up the MRO (the nearest class's
    default wins, as a subclass's own keyword would)."""
    defaults: dict[str, Any] = {}
    for klass in cls.__mro__:
        if "__init__" not in vars(klass) or klass is object:
            continue
        parameters = inspect.signature(klass.__init__).parameters.values()
        for p in parameters:
            if p.name != "self" and p.kind is p.KEYWORD_ONLY and p.name not in defaults:
                defaults[p.name] = p.default
        if not any(p.kind is p.VAR_KEYWORD for p in parameters):
            break
    return defaults


def load(name: str) -> dict[str, Any]:
    """A config file as plain containers, without ``_target_`` and ``defaults``."""
    cfg = OmegaConf.to_container(OmegaConf.load(CONF / name)) or {}
    cfg.pop("defaults", None)
    cfg.pop("_target_", None)
    return cfg


def plain(value: Any) -> Any:
    """Lists and tuples compare alike (YAML has lists, signatures tuples)."""
    return [plain(v) for v in value] if isinstance(value, list | tuple) else value


def algo_class(name: str) -> type:
    return TRAINER_CLASSES[OmegaConf.load(CONF / "algo" / f"{name}.yaml")["_target_"]]


def python_defaults(name: str) -> dict[str, Any]:
    """What the class configured by ``conf/<name>`` takes, and its defaults (run-time arguments left out)."""
    if name.startswith("algo/"):
        defaults = keyword_defaults(algo_class(Path(name).stem))
        return {k: v for k, v in defaults.items() if k not in RUN_KEYS}
    if name == "env/room.yaml":  # the room's settings but its motion model (conf/motion/), the paper room's sizes
        area = inspect.signature(paper_room).parameters
        defaults = {item.name: item.default for item in dataclasses.fields(RoomParams) if item.name != "motion"}
        return defaults | {name: area[name].default for name in AREA_SETTINGS}
    if name == "vq/default.yaml":
        return {field.name: field.default for field in dataclasses.fields(VQSettings)}
    raise KeyError(name)


FILES = [f"algo/{name}.yaml" for name in ALGOS] + ["env/room.yaml", "vq/default.yaml"]


def cases() -> list:
    params = []
    for name in FILES:
        for key in load(name):
            marks = ()
            if (name, key) in AWAITING_SIGNATURE:
                marks = pytest.mark.xfail(strict=True, reason=AWAITING_SIGNATURE[name, key])
            params.append(pytest.param(name, key, id=f"{name}:{key}", marks=marks))
    return params


@pytest.mark.parametrize("name", FILES)
def test_every_setting_of_the_class_is_in_its_config_file(name):
    """The file lists exactly the settings the class takes: a new parameter gets its YAML default too."""
    assert set(load(name)) == set(python_defaults(name))


@pytest.mark.parametrize(("name", "key"), cases())
def test_the_python_default_is_the_config_value(name, key):
    expected = python_defaults(name)
    assert key in expected, f"{key} is not a setting of the class conf/{name} configures"
    value = load(name)[key]
    assert plain(expected[key]) == plain(value), f"conf/{name}: {key}: {value!r}, Python default {expected[key]!r}"
    assert type(expected[key]) is type(value) or isinstance(expected[key], tuple), (key, expected[key], value)


def test_the_awaited_signature_changes_name_real_keys():
    for name, key in AWAITING_SIGNATURE:
        assert key in load(name), (name, key)


@pytest.mark.parametrize("key", TRAIN_KEYS)
def test_train_yaml_top_level_keys_are_the_trainer_defaults(key):
    train = OmegaConf.load(CONF / "train.yaml")
    assert plain(RUN_DEFAULTS[key]) == train[key], key


def test_logger_default_is_the_trainer_default():
    listed = OmegaConf.to_container(OmegaConf.load(CONF / "train.yaml").defaults)
    defaults = [d for d in listed if isinstance(d, dict) and "logger" in d]
    assert defaults == [{"logger": "tensorboard"}]
    assert load("logger/tensorboard.yaml")["tensorboard"] == RUN_DEFAULTS["tensorboard"]


@pytest.mark.parametrize("name", sorted(p.stem for p in (CONF / "rewards").glob("*.yaml")))
def test_reward_sets_hold_only_reward_settings_of_the_room(name):
    """conf/rewards/<name>.yaml (``# @package env``): each a whole set of the room's reward_* keys, or nothing (the
    room's own rewards)."""
    text = (CONF / "rewards" / f"{name}.yaml").read_text()
    assert text.startswith("# @package env\n")
    rewards = {k for k in python_defaults("env/room.yaml") if k.startswith("reward_")}
    keys = set(load(f"rewards/{name}.yaml"))
    assert keys in (set(), rewards), keys ^ rewards


@pytest.mark.parametrize("name", list(MOTION_MODELS))
def test_every_motion_model_has_its_config_file_with_its_defaults(name):
    """conf/motion/<name>.yaml is the model's config node with the dataclass's defaults (what motion=<name> gives),
    and reads back as that model; the group holds no other file."""
    node = OmegaConf.to_container(OmegaConf.load(CONF / "motion" / f"{name}.yaml"))
    assert node == MOTION_MODELS[name]().to_config()
    assert motion_from_config(node) == MOTION_MODELS[name]()
    assert sorted(path.stem for path in (CONF / "motion").glob("*.yaml")) == sorted(MOTION_MODELS)
    assert OmegaConf.load(CONF / "train.yaml").defaults[2] == {"motion": "stop"}

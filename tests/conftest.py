"""Shared fixtures: Hydra configs composed the way the entry points compose them."""

import os

import pytest
import torch
from hydra import compose as hydra_compose
from hydra import initialize_config_dir
from omegaconf import DictConfig, open_dict

from pedrl.cli import CONFIG_DIR

if os.environ.get("PYTEST_XDIST_WORKER"):
    # one torch thread per test process: `make test` runs one process per core (pytest-xdist), and two processes whose
    # OpenMP threads both spin over the same cores slow each other several times over
    torch.set_num_threads(1)


def compose_config(name: str, overrides: list[str] | tuple[str, ...] = ()) -> DictConfig:
    """Compose ``conf/<name>.yaml`` with overrides, as ``pedrl-train`` would."""
    with initialize_config_dir(version_base="1.3", config_dir=CONFIG_DIR):
        return hydra_compose(config_name=name, overrides=list(overrides))


@pytest.fixture
def compose():
    """``compose(name, overrides)``: :func:`compose_config` as a fixture."""
    return compose_config


@pytest.fixture
def train_config():
    """``train_config(*overrides)``: a debug-sized training config with progress bars off."""

    def make(*overrides: str) -> DictConfig:
        cfg = compose_config("train", ["debug=default", *overrides])
        with open_dict(cfg):
            cfg.progress = False
        return cfg

    return make

"""Where each command writes by default: the folder its config names and docs/outputs.md gives, not another
command's (``pedrl-eval``, ``pedrl-validate`` and ``pedrl-plot`` under ``outputs/eval|validate|plots/``, training
runs under ``outputs/<date>/<time>/``)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from pedrl.cli import CONFIG_DIR

OUTPUTS_PAGE = Path(CONFIG_DIR).parent / "docs" / "outputs.md"


def run_dir(config: str, overrides: tuple[str, ...] = ()) -> str:
    """The ``hydra.run.dir`` that ``conf/<config>.yaml`` composes to, as its command would run."""
    with initialize_config_dir(version_base="1.3", config_dir=CONFIG_DIR):
        cfg = compose(config_name=config, overrides=list(overrides), return_hydra_config=True)
    return str(cfg.hydra.run.dir)


@pytest.mark.parametrize(
    ("config", "folder"),
    [("eval", "outputs/eval/"), ("validate", "outputs/validate/"), ("plot", "outputs/plots/")],
)
def test_a_tool_writes_under_its_own_outputs_folder(config, folder):
    where = run_dir(config)
    assert where.startswith(folder), where
    assert re.fullmatch(re.escape(folder) + r"\d{4}-\d{2}-\d{2}/\d{2}-\d{2}-\d{2}", where), where
    assert folder.rstrip("/") in OUTPUTS_PAGE.read_text()  # the manual names the same folder


def test_training_runs_keep_their_date_folders():
    assert re.fullmatch(r"outputs/\d{4}-\d{2}-\d{2}/\d{2}-\d{2}-\d{2}", run_dir("train"))


def test_a_given_run_dir_still_wins():
    assert run_dir("eval", ("hydra.run.dir=somewhere/else",)) == "somewhere/else"

"""Every scenario trains (a seconds-long VQQL run) and evaluates; a checkpoint of one scenario runs in another."""

import csv

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import open_dict

from pedrl.cli import CONFIG_DIR
from pedrl.evaluation import evaluate
from pedrl.io import load_checkpoint
from pedrl.train import train

AGENTS = {"paper_room": 4, "bottleneck": 6, "corridor": 6, "corner": 4, "four_exits": 8, "hall": 8}


def compose_config(name, overrides):
    with initialize_config_dir(version_base="1.3", config_dir=CONFIG_DIR):
        return compose(config_name=name, overrides=overrides)


@pytest.mark.parametrize("scenario", sorted(AGENTS))
def test_scenario_trains_and_evaluates(scenario, tmp_path):
    agents = AGENTS[scenario]
    cfg = compose_config(
        "train",
        ["debug=default", f"scenario={scenario}", f"algo.num_agents={agents}", "algo.trials=4", "algo.iterations=1",
         "vq.num_prototypes=8", "logger=none", "threads=1"],
    )  # fmt: skip
    with open_dict(cfg):
        cfg.progress = False
    result = train(cfg, run_dir=tmp_path / "train")
    assert result is not None
    checkpoint = tmp_path / "train" / "checkpoints" / "last.safetensors"
    stored = load_checkpoint(checkpoint).metadata["config"]["scenario"]
    assert stored["name"] == scenario  # the checkpoint remembers where it learned
    other = "corner" if scenario != "corner" else "corridor"
    for where, overrides in ((scenario, []), (other, [f"scenario={other}"])):
        eval_cfg = compose_config(
            "eval",
            [f"checkpoint={checkpoint}", f"agents=[{min(agents, 4)}]", "trials=1", "trials_per_batch=1",
             "animation.enabled=false", "tensorboard=false", "threads=1", *overrides],
        )  # fmt: skip
        rows = evaluate(eval_cfg, run_dir=tmp_path / f"eval_{where}")
        assert [r["controller"] for r in rows] == ["learned", "greedy"]  # the greedy walker beside, same room
        assert all(0.0 <= r["fails_pct"] <= 100.0 for r in rows)
        with open(tmp_path / f"eval_{where}" / "scaling.csv") as handle:
            assert len(list(csv.DictReader(handle))) == 2
        assert (tmp_path / f"eval_{where}" / "trajectories" / "geometry.wkt").exists()

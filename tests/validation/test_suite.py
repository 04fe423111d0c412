"""The validation suite: its measures on analytic cases, the invariants recorder, and pedrl-validate end to end."""

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import open_dict
from shapely.geometry import LineString

from pedrl.algos.controllers import GreedyDoorController
from pedrl.sim import RoomEnv
from pedrl.train import train
from pedrl.validate import run
from pedrl.validation.runner import room_maker
from pedrl.validation.suite import (
    TESTS,
    WEIDMANN,
    Budget,
    Invariants,
    Recording,
    lane_order_values,
    line_flow,
    rimea_1,
    weidmann_speed,
)

CONFIG_DIR = str(Path(__file__).resolve().parents[2] / "conf")


def compose_config(name, overrides):
    with initialize_config_dir(version_base="1.3", config_dir=CONFIG_DIR):
        return compose(config_name=name, overrides=overrides)


def test_weidmann_curve_analytic_points():
    assert weidmann_speed(np.array([5.4]), **WEIDMANN)[0] == 0.0
    low = weidmann_speed(np.array([0.01]), **WEIDMANN)[0]
    assert low == pytest.approx(1.34, abs=1e-6)
    one = weidmann_speed(np.array([1.0]), **WEIDMANN)[0]
    assert one == pytest.approx(1.34 * (1 - math.exp(-1.913 * (1 - 1 / 5.4))))


def test_flow_through_a_line_is_crossings_over_time():
    """Five agents cross y = 5 one per 2 s: PedPy's N-t gives (5 - 1) / 8 s = 0.5 /s."""
    frames, agents = 20, 5
    positions = np.zeros((frames, 1, agents, 2))
    positions[..., 0] = 2.0
    for agent in range(agents):
        crossing = 2 + 2 * agent  # first frame past the line
        positions[:, 0, agent, 1] = 5.0 + (np.arange(frames) - crossing + 0.5)
    recording = Recording(
        positions=positions,
        active=np.ones((frames, 1, agents), dtype=bool),
        left_at=np.full((1, agents), -1),
        frame_rate=1.0,
    )
    flow, crossings = line_flow(recording, LineString([(0.0, 5.0), (4.0, 5.0)]))
    assert crossings == agents and flow == pytest.approx(0.5)


def test_lane_order_is_one_for_lanes_and_low_for_mixed_walkers():
    xs = np.arange(10) * 1.0
    lanes = np.zeros((1, 1, 20, 2))
    lanes[0, 0, :10] = np.stack((xs, np.full(10, 1.0)), -1)  # lane at y = 1 walking +x
    lanes[0, 0, 10:] = np.stack((xs, np.full(10, 3.0)), -1)  # lane at y = 3 walking -x
    direction = np.array([1] * 10 + [-1] * 10)
    active = np.ones((1, 1, 20), dtype=bool)
    values = lane_order_values(lanes, active, direction, lane_width=0.8, window=(0.0, 10.0))
    assert np.mean(values) == 1.0
    mixed = lanes.copy()
    mixed[0, 0, 10:, 1] = 1.0  # both groups in one lane, alternating along x
    mixed[0, 0, 10:, 0] = xs + 0.5
    assert np.mean(lane_order_values(mixed, active, direction, lane_width=0.8, window=(0.0, 11.0))) < 0.2


def test_invariants_catch_an_overlap_a_wall_crossing_and_a_jump():
    env = RoomEnv(num_agents=2, width=10.0, length=10.0, door_width=2.0)
    env.reset(seed=0)
    before, was_active = env.positions.clone(), env.active.clone()
    invariants = Invariants()
    invariants.check(env, before, was_active)
    assert invariants.result().passed
    env.positions = torch.tensor([[[5.0, 5.0], [5.5, 5.0]]])  # overlapping bodies (0.5 m apart)
    invariants.check(env, before, was_active)
    row = invariants.result()
    assert not row.passed and row.value == pytest.approx(-0.3, abs=1e-6)
    for positions, key in (([[5.0, 5.0], [-1.0, 5.0]], "outside_agent_steps"), ([[5.0, 5.0], [9.9, 9.0]], None)):
        fresh = Invariants()
        env.positions = torch.tensor([positions])
        fresh.check(env, torch.tensor([[[5.0, 5.0], [2.0, 2.0]]]), was_active)
        assert not fresh.result().passed
        if key:
            assert fresh.result().details[key] == 1


def test_rimea_1_greedy_walks_40_m_near_free_speed():
    make = room_maker({}, device=torch.device("cpu"))
    greedy = GreedyDoorController()
    row = rimea_1(make, greedy, Invariants(), Budget(quick=True))
    assert row.passed and row.value == 16.0 == row.details["ideal_s"]  # 39.5 m at 2.5 m/s: 16 decisions


def test_pedrl_validate_quick_writes_reports_for_the_checkpoint_and_the_greedy_reference(tmp_path):
    cfg = compose_config(
        "train",
        ["debug=default", "algo=vqql", "algo.num_agents=2", "algo.iterations=1", "algo.trials=2",
         "vq.num_prototypes=8", "env.max_decisions=10", "logger=none", "threads=1"],
    )  # fmt: skip
    with open_dict(cfg):
        cfg.progress = False
    train(cfg, run_dir=tmp_path / "train")
    checkpoint = tmp_path / "train" / "checkpoints" / "last.safetensors"
    cfg = compose_config("validate", [f"checkpoint={checkpoint}", "quick=true", "tensorboard=false"])
    results = run(cfg, run_dir=tmp_path / "validate")
    assert list(results) == ["learned", "greedy"]
    document = json.loads((tmp_path / "validate" / "validation.json").read_text())
    assert {row["controller"] for row in document["tests"]} == {"learned", "greedy"}
    assert len(document["tests"]) == 2 * len(TESTS)
    for row in document["tests"]:
        assert {"test", "passed", "value", "reference", "source"} <= set(row)
        assert isinstance(row["passed"], bool)
    invariants = [row for row in document["tests"] if row["test"] == "invariants"]
    assert all(row["passed"] for row in invariants)  # whatever the controller, the model keeps bodies apart
    report = (tmp_path / "validate" / "validation.md").read_text()
    assert "| test | learned | greedy |" in report and "RiMEA 9" in report
    assert (tmp_path / "validate" / "figures" / "greedy_bottleneck.png").exists()


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("controller=smart", "controller='smart' is invalid"),
        ("epsilon=2", "epsilon=2"),
        ("tests=[rimea_1,rimea_99]", "tests='rimea_99' is invalid"),
        ("quick=maybe", "quick='maybe' is invalid"),
    ],
)
def test_bad_validate_values_give_one_line_errors(tmp_path, override, message):
    cfg = compose_config("validate", ["controller=greedy", override])
    with pytest.raises(ValueError) as err:
        run(cfg, run_dir=tmp_path)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_learned_controller_needs_a_checkpoint(tmp_path):
    with pytest.raises(ValueError, match="checkpoint is missing: controller=both needs one"):
        run(compose_config("validate", []), run_dir=tmp_path)


@pytest.mark.parametrize("quick", [True, False])
def test_every_budget_fits_its_scenario(quick):
    """The crowds of the suite fit in their spawn areas at both budgets (a full run must not stop half-way)."""
    from pedrl.scenarios import build_scenario
    from pedrl.validation.suite import narrowing_corridor

    budget = Budget(quick=quick)
    radius = 0.4
    narrowing_corridor().check_capacity(max(budget.fd_agents), radius)
    for width in budget.widths:
        build_scenario({"name": "bottleneck", "opening": width}).check_capacity(budget.bottleneck_agents, radius)
    build_scenario({"name": "four_exits"}).check_capacity(budget.four_exits_agents, radius)
    build_scenario({"name": "corridor"}).check_capacity(budget.corridor_agents, radius)
    build_scenario({"name": "corner"}).check_capacity(7, radius)

"""The free-walking probe (:mod:`pedrl.trial.walking`, ``python -m pedrl.evaluation.free_walking``): the greedy walker
passes it with the analytic number of decisions, walkers that turn off the bearing or slow down fail it (its
controls), it reads every learner's files, and a training run logs it without changing what it learns."""

import math
import subprocess
import sys

import pytest
import torch

from pedrl.configs import room_keywords
from pedrl.io import load_checkpoint, read_csv
from pedrl.policy_files import load_policy, room_settings
from pedrl.sim import RoomParams
from pedrl.sim.actions import NUM_TURNS
from pedrl.sim.controllers import GreedyDoorController
from pedrl.trial.walking import SCALARS, WalkingLog, WalkingSettings, probe_learned, probe_walking
from tests.refusals import TINY_VQQL, train_checkpoint

WALKING_LAYER = {
    "agent_radius": 0.2,
    "max_speed": 1.34,
    "motion": {"name": "continuous", "contact": "yield", "time_gap": 0.4, "order": "door_first"},
    "action_frame": "goal",
    "speed_ratios": [0.0, 0.2, 0.4, 0.6, 0.7, 0.8, 0.9, 0.95, 1.0],
    "turn_ratios": [-0.5, -0.25, -0.1, -0.05, 0.0, 0.05, 0.1, 0.25, 0.5],
}
"""experiment=pedestrian_walk's room settings."""
PARAMS = RoomParams.from_settings(room_keywords(WALKING_LAYER))
SMALL = WalkingSettings(lateral=2, headings=(0.0, 90.0, 180.0), places=0)


class Fixed:
    """A walker that takes one action, whatever it sees (goal frame: speed index * 9 + turn index)."""

    def __init__(self, speed_index: int, turn_index: int) -> None:
        self.action = speed_index * NUM_TURNS + turn_index

    def act(self, env, obs, info):
        return torch.full(obs.shape[:2], self.action, dtype=torch.int64)


class Commanded:
    """A walker that gives one continuous command, whatever it sees: the speed ratio and the heading offset (rad)."""

    def __init__(self, ratio: float, offset: float) -> None:
        self.command = torch.tensor([ratio, offset])

    def act(self, env, obs, info):
        return self.command.expand(*obs.shape[:2], 2).clone()


def test_the_greedy_walker_walks_the_corridor_straight_in_the_analytic_decisions():
    probe = probe_walking(GreedyDoorController, PARAMS, settings=SMALL)
    # it starts a body radius and 5 cm from the closed end: 39.75 m at 1.34 m/s a decision
    expected = math.ceil((40.0 - 0.25) / 1.34)
    assert probe.corridor.decisions == pytest.approx(expected, abs=0.5)
    assert probe.corridor.arrived == 1.0
    assert probe.straight == 1.0 and probe.heading_offset < 0.01 and probe.speed_ratio == pytest.approx(1.0)
    assert probe.decision_ratio == pytest.approx(probe.corridor.decisions / probe.greedy_corridor.decisions)
    assert probe.passed()


@pytest.mark.parametrize(
    ("walker", "offset", "speed"),
    [
        (Fixed(8, 7), 45.0, 1.0),  # the control of the issue: top speed, always 45 degrees off the bearing
        (Fixed(4, 4), 0.0, 0.7),  # straight on at 0.7 of the top speed
        (Commanded(1.0, math.pi / 4), 45.0, 1.0),  # the same walkers by continuous command
        (Commanded(0.7, 0.0), 0.0, 0.7),
    ],
    ids=["45-degrees", "slow", "45-degrees-commanded", "slow-commanded"],
)
def test_a_walker_that_turns_off_the_bearing_or_slows_fails(walker, offset, speed):
    probe = probe_walking(lambda: walker, PARAMS, settings=SMALL)
    assert probe.straight == 0.0
    assert probe.heading_offset == pytest.approx(offset, abs=0.01)
    assert probe.speed_ratio == pytest.approx(speed, abs=1e-4)
    assert probe.corridor.decisions > probe.greedy_corridor.decisions
    assert not probe.passed()


def test_a_continuous_policy_that_commands_top_speed_straight_passes():
    """A continuous policy whose network gives (3, 0) whatever it sees: its squash commands a speed ratio above 1
    (the room clips it to the top speed) and no offset, so it walks as the greedy walker does."""
    from pedrl.rl import ContinuousPolicy
    from pedrl.rl.network import QNetwork
    from pedrl.vq.encoder import EncoderSettings, StateEncoder

    settings = EncoderSettings(num_neighbours=PARAMS.num_neighbours, num_walls=PARAMS.num_walls, max_distance=40.0,
                               max_speed=PARAMS.max_speed)  # fmt: skip
    network = QNetwork(1, settings.num_features + settings.num_neighbours, [8], 2)
    with torch.no_grad():
        for weight in network.weights:
            weight.zero_()
        network.biases[-1].copy_(torch.tensor([3.0, 0.0]).expand_as(network.biases[-1]))
    policy = ContinuousPolicy(StateEncoder(settings), network, torch.zeros(settings.num_features),
                              torch.ones(settings.num_features))  # fmt: skip
    probe = probe_walking(lambda: policy.controller(), PARAMS, settings=SMALL)
    assert probe.straight == 1.0 and probe.speed_ratio == pytest.approx(1.0) and probe.passed()


def test_a_walker_that_never_arrives_fails_with_an_infinite_ratio():
    probe = probe_walking(lambda: Fixed(0, 4), PARAMS, settings=WalkingSettings(lateral=1, headings=(0.0,),
                                                                               places=0, max_decisions=5))  # fmt: skip
    assert probe.corridor.arrived == 0.0 and math.isnan(probe.corridor.decisions)
    assert probe.decision_ratio == math.inf and not probe.passed()


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"lateral": 0}, "lateral=0 is invalid"),
        ({"headings": ()}, r"headings=\[\] is invalid"),
        ({"headings": (200.0,)}, "heading=200.0 is invalid"),
        ({"places": -1}, "places=-1 is invalid"),
        ({"corridor_length": math.nan}, "corridor_length=nan is invalid"),
        ({"max_decisions": 0}, "max_decisions=0 is invalid"),
    ],
)
def test_bad_settings_are_refused_in_one_line(settings, message):
    with pytest.raises(ValueError, match=message) as error:
        WalkingSettings(**settings)
    assert "\n" not in str(error.value)


def test_the_log_probes_evenly_and_after_the_last_trial():
    log = WalkingLog(3, 10, PARAMS, home=None)
    assert [trial for trial in range(10) if log.due(trial)] == [3, 7, 9]
    assert not any(WalkingLog(0, 10, PARAMS, home=None).due(trial) for trial in range(10))
    with pytest.raises(ValueError, match="logger.walking_probes=-1 is invalid"):
        WalkingLog(-1, 10, PARAMS, home=None)


TINY_DQN = ("debug=default", "algo=dqn", "algo.trials=4", "algo.iterations=1", "env.max_decisions=10",
            "logger=none")  # fmt: skip


@pytest.fixture(scope="module")
def network(tmp_path_factory):
    return train_checkpoint(tmp_path_factory, (*TINY_DQN, "logger.walking_probes=2"))


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    return train_checkpoint(tmp_path_factory, TINY_VQQL)


def test_training_logs_the_probe_without_changing_what_it_learns(network, tmp_path_factory):
    rows = read_csv(network.parent.parent / "learning_curve.csv")
    probed = [row for row in rows if row["walking_straight"] != ""]
    assert [int(row["global_trial"]) for row in probed] == [1, 3]
    for row in probed:
        assert set(f"walking_{name}" for name in SCALARS) <= set(row)
        assert 0.0 <= float(row["walking_straight"]) <= 1.0
    unprobed = train_checkpoint(tmp_path_factory, (*TINY_DQN, "logger.walking_probes=0"))
    first, second = load_checkpoint(network).tensors, load_checkpoint(unprobed).tensors
    assert first.keys() == second.keys()
    for name in first:
        assert torch.equal(first[name], second[name]), name
    assert all(row["walking_straight"] == "" for row in read_csv(unprobed.parent.parent / "learning_curve.csv"))


def test_the_log_walks_the_greedy_walker_once_and_reports_what_a_fresh_probe_does(network):
    policy = load_policy(network)
    params = RoomParams.from_settings(room_keywords(room_settings(policy)))
    log = WalkingLog(2, 2, params, home=None)
    first = log.measure(0, policy)
    cached = log.greedy_corridor
    assert cached is not None
    assert log.measure(1, policy) == first
    assert log.greedy_corridor is cached
    assert probe_learned(policy, params, home=None).scalars() == first


def test_the_command_reads_every_learner_and_prints_a_row_per_file(network, tables):
    result = subprocess.run(
        [sys.executable, "-m", "pedrl.evaluation.free_walking", str(network), str(tables), "--places", "2",
         "--lateral", "1"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    for checkpoint in (network, tables):
        rows = [line for line in result.stdout.splitlines() if line.startswith(f"| {checkpoint}")]
        assert len(rows) == 1 and rows[0].rstrip(" |").split("|")[-1].strip() in ("pass", "FAIL")
        assert load_policy(checkpoint) is not None


def test_the_command_refuses_a_bad_argument_in_one_line(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "pedrl.evaluation.free_walking", str(tmp_path / "none.safetensors")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert result.returncode == 2
    assert len(result.stderr.strip().splitlines()) == 1 and "error" in result.stderr

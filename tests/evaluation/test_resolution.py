"""The bearing's resolution (:mod:`pedrl.evaluation.resolution`): the prototypes an agent turning on the spot passes
through, on hand-made quantizers whose answer is known, and on a trained checkpoint through the command line."""

import math
import subprocess
import sys

import pytest
import torch

from pedrl.evaluation.resolution import distinct_counts, heading_resolution, turn_ids
from pedrl.policy_files import load_policy
from pedrl.scenarios import paper_room
from pedrl.sim import RoomEnv
from pedrl.vq import Quantizer
from pedrl.vq.encoder import EncoderSettings, StateEncoder
from tests.refusals import train_checkpoint

HEADING = 1  # the own heading feature: the angle of the velocity to the reference line


def room(agents: int = 1, positions: int = 6) -> RoomEnv:
    return paper_room(width=20.0, length=30.0).room(num_replicas=positions, num_agents=agents)


def encoder_over(column: int, values: torch.Tensor, env: RoomEnv, **choices) -> StateEncoder:
    """An encoder whose prototypes differ only in ``column`` (raw units: mean 0, std 1, every other column 0)."""
    settings = EncoderSettings.for_room(env, **choices)
    features = settings.num_features
    prototypes = torch.zeros(values.numel(), features)
    prototypes[:, column] = values
    quantizer = Quantizer(mean=torch.zeros(features), std=torch.ones(features), prototypes=prototypes)
    return StateEncoder(settings, quantizer)


@pytest.mark.parametrize("sectors", [1, 4, 8, 36])
def test_prototypes_over_the_heading_alone_are_each_passed_once(sectors):
    env = room()
    centres = -math.pi + (torch.arange(sectors) + 0.5) * (2 * math.pi / sectors)
    ids = turn_ids(encoder_over(HEADING, centres, env), env, headings=360, speed=1.0, seed=3)
    assert ids.shape == (1, 360, env.num_replicas)
    assert distinct_counts(ids).tolist() == [[sectors] * env.num_replicas]
    changes = (ids != ids.roll(1, dims=1)).sum(1)
    assert changes.tolist() == [[sectors if sectors > 1 else 0] * env.num_replicas]


def test_prototypes_over_the_door_distance_are_not_turned_through():
    # the control: prototypes that tell only the door's distance apart give one id per turn, whatever their number
    env = room()
    ids = turn_ids(encoder_over(2, torch.linspace(0.0, 40.0, 64), env), env, headings=90, speed=1.0, seed=3)
    assert distinct_counts(ids).tolist() == [[1] * env.num_replicas]


def test_a_standing_agent_has_one_state_and_random_fillings_stay_over_the_turn():
    env = room(agents=1)
    centres = torch.linspace(-math.pi, math.pi, 16)
    # at speed 0 the heading feature still turns (it is the heading's angle), so every sector is passed
    standing = turn_ids(encoder_over(HEADING, centres, env), env, headings=160, speed=0.0, seed=1)
    assert bool((distinct_counts(standing) >= 15).all())
    # prototypes over the first neighbour's distance, a void slot filled at random once per position: the turn
    # keeps its filling, so one id per position, while the positions get different fillings
    fills = torch.linspace(0.0, env.max_distance, 256)
    encoder = encoder_over(4, fills, env, void_features="random")
    ids = turn_ids(encoder, env, headings=50, speed=1.0, seed=1)
    assert distinct_counts(ids).tolist() == [[1] * env.num_replicas]
    assert ids[0, 0].unique().numel() > 1


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    return train_checkpoint(tmp_path_factory)


def test_a_trained_quantizer_resolves_more_headings_in_its_own_room_than_one_prototype(checkpoint):
    policy = load_policy(checkpoint)
    result = heading_resolution(policy, agents=2, positions=4, headings=72, seed=0)
    assert result.distinct.shape == (policy.num_processes, 4)
    assert 1 <= result.mean <= min(72, result.num_prototypes)
    assert result.degrees_per_prototype == pytest.approx(360.0 / result.mean)
    again = heading_resolution(policy, agents=2, positions=4, headings=72, seed=0)
    assert torch.equal(result.distinct, again.distinct)


def test_the_command_line_prints_a_row_per_file_and_agent_count(checkpoint):
    result = subprocess.run(
        [sys.executable, "-m", "pedrl.evaluation.resolution", str(checkpoint), "--agents", "1", "2",
         "--positions", "3", "--headings", "36"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    rows = [line for line in result.stdout.splitlines() if line.startswith(f"| {checkpoint}")]
    assert [row.split("|")[2].strip() for row in rows] == ["1", "2"]

"""What a quantizer sees of the neighbours (:mod:`pedrl.evaluation.neighbours`): hand-made quantizers whose answer is
known (one that ignores the neighbours sees 1 prototype, one that reads them alone many), and a trained checkpoint
through the command line."""

import math
import subprocess
import sys

import pytest
import torch

from pedrl.evaluation.neighbours import MEASURES, SightSettings, neighbour_sight, scenes_of, sight_of
from pedrl.policy_files import load_policy
from pedrl.scenarios import paper_room
from pedrl.sim import RoomEnv
from pedrl.sim.sensing import ANGLE, DISTANCE, NUM_OWN_FEATURES, REL_SPEED, VELOCITY_ANGLE, num_features
from pedrl.vq import Quantizer
from pedrl.vq.encoder import EncoderSettings, StateEncoder
from tests.evaluation.test_resolution import encoder_over
from tests.refusals import train_checkpoint

SPEEDS = (0.5, 1.0)


def room(places: int = 4) -> RoomEnv:
    return paper_room(width=20.0, length=30.0).room(num_replicas=places, num_agents=1)


def over_heading(env: RoomEnv, prototypes: int = 256) -> StateEncoder:
    """An encoder whose prototypes differ only in the own heading, spread over its range: the neighbours weigh 0."""
    angles = -math.pi + 2.0 * math.pi * torch.rand(prototypes, generator=torch.Generator().manual_seed(0))
    return encoder_over(VELOCITY_ANGLE, angles, env)


def over_nearest_neighbour(env: RoomEnv, prototypes: int = 256) -> StateEncoder:
    """An encoder whose prototypes differ only in the nearest neighbour's three features, spread over their ranges:
    they alone weigh."""
    settings = EncoderSettings.for_room(env)
    features = num_features(env.params.num_neighbours, env.params.num_walls)
    generator = torch.Generator().manual_seed(0)

    def uniform(low: float, high: float) -> torch.Tensor:
        return low + (high - low) * torch.rand(prototypes, generator=generator)

    spread = torch.zeros(prototypes, features)
    distances = uniform(0.3, 6.0)
    if settings.distance_transform == "log":
        distances = distances.log1p()
    spread[:, NUM_OWN_FEATURES + REL_SPEED] = uniform(-2.0, 2.0)
    spread[:, NUM_OWN_FEATURES + DISTANCE] = distances
    spread[:, NUM_OWN_FEATURES + ANGLE] = uniform(-math.pi, math.pi)
    quantizer = Quantizer(mean=torch.zeros(features), std=torch.ones(features), prototypes=spread)
    return StateEncoder(settings, quantizer)


def sight(encoder: StateEncoder, env: RoomEnv):
    scenes = scenes_of(env, speed_ratios=SPEEDS, seed=3)
    return sight_of(encoder, env, scenes, SightSettings(speed_ratios=SPEEDS, samples=36, crowds=50, seed=3))


def test_a_quantizer_that_ignores_the_neighbours_sees_one_prototype_for_every_neighbour_measure():
    env = room()
    result = sight(over_heading(env), env)
    for measure in ("circling", "head_on", "receding", "crowds"):
        assert result.counts[measure].tolist() == [[1] * 8], measure
    assert result.mean("turning") > 4  # the control: the own heading is seen
    assert not result.sees_neighbours()


def test_a_quantizer_that_reads_the_neighbours_alone_sees_them_and_not_the_heading():
    env = room()
    result = sight(over_nearest_neighbour(env), env)
    assert result.counts["turning"].tolist() == [[1] * 8]
    for measure in ("circling", "head_on", "receding", "crowds"):
        assert result.mean(measure) >= 3, measure
    assert result.sees_neighbours()
    assert result.sees_neighbours(1.0)
    assert result.counts["circling"].shape == (1, len(SPEEDS) * 4)


def test_the_crowds_are_random_but_seeded():
    env = room()
    encoder = over_nearest_neighbour(env)
    first, again = sight(encoder, env), sight(encoder, env)
    for measure in MEASURES:
        assert torch.equal(first.counts[measure], again.counts[measure])


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    return train_checkpoint(tmp_path_factory)


def test_a_trained_checkpoint_reports_every_measure(checkpoint):
    policy = load_policy(checkpoint)
    result = neighbour_sight(policy, SightSettings(places=3, speed_ratios=[1.0], samples=24, crowds=20, seed=0))
    for measure in MEASURES:
        counts = result.counts[measure]
        assert counts.shape == (policy.num_processes, 3)
        assert bool((counts >= 1).all()) and bool((counts <= min(24, result.num_prototypes)).all())


def test_the_command_line_prints_a_row_per_file_and_speed(checkpoint):
    result = subprocess.run(
        [sys.executable, "-m", "pedrl.evaluation.neighbours", str(checkpoint), "--places", "2", "--speeds", "0.5",
         "1", "--samples", "12", "--crowds", "10"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    rows = [line for line in result.stdout.splitlines() if line.startswith(f"| {checkpoint}")]
    assert [row.split("|")[2].strip() for row in rows] == ["0.5", "1"]


def test_random_void_fillings_are_kept_over_a_scene():
    # prototypes over the second neighbour's distance: with one neighbour that slot is void and filled at random, once
    # per scene; neither the circling neighbour (at a constant 1 m) nor the control's turn may be credited with the
    # spread of fresh fillings
    env = room()
    # 97 prototypes 0.375 m apart, their boundaries clear of the fillings' values here (float32 jitters them by 1e-6)
    encoder = encoder_over(NUM_OWN_FEATURES + 3 + DISTANCE, torch.linspace(0.0, 36.0, 97), env, void_features="random")
    scenes = scenes_of(env, speed_ratios=SPEEDS, seed=3)
    result = sight_of(encoder, env, scenes, SightSettings(speed_ratios=SPEEDS, samples=36, crowds=5, seed=3))
    assert result.counts["circling"].tolist() == [[1] * 8]
    assert result.counts["turning"].tolist() == [[1] * 8]

"""The eval config's memory check (:func:`pedrl.evaluation.config.check_against_room`) counts what a batch keeps:
the frames the fused trial records (one every :func:`pedrl.trial.fused.record_every` decisions) or the torch loop's
(every decision), and the nearest-prototype lists the fused trial builds for a learned policy's quantizer."""

import pytest
import torch
from omegaconf import OmegaConf

import pedrl.common.checks
from pedrl._numba import numba_available
from pedrl.common.checks import GIB
from pedrl.evaluation.config import RECORD_BYTES_PER_AGENT_FRAME, check_against_room
from pedrl.evaluation.engine import room_geometry
from pedrl.rl.policy import PolicyController, TabularPolicy
from pedrl.scenarios import paper_room
from pedrl.sim.controllers import GreedyDoorController
from pedrl.trial.fused import RECORD_BYTES, record_every
from pedrl.vq.encoder import EncoderSettings, StateEncoder
from pedrl.vq.pruned import GRAPH_BLOCK_BYTES, GRAPH_MAX_PAIRS, GRAPH_SIZE, graph_memory, graph_size
from pedrl.vq.quantizer import Quantizer

needs_numba = pytest.mark.skipif(not numba_available(), reason="the fused trial is numba's")
AGENTS, DECISIONS = 40, 10_000_000  # the longest trial allowed (MAX_DECISIONS)


def eval_config(fused=None):
    return OmegaConf.create({"measurement": {"distance": 1.0}, "density_map": {"tile_size": 0.5}, "fused": fused})


ROOM = paper_room(width=10.0, length=10.0)


def long_rooms() -> dict:
    return {AGENTS: ROOM.room(num_replicas=1, num_agents=AGENTS, max_decisions=DECISIONS)}


def free_memory(monkeypatch, gib: float) -> None:
    monkeypatch.setattr(pedrl.common.checks, "available_memory", lambda device: int(gib * GIB))


@needs_numba
def test_the_recording_check_counts_the_frames_the_fused_trial_keeps(monkeypatch):
    """``max_decisions=10000000`` at 40 agents: every frame would be 29.8 GiB, the fused trial keeps one every
    ``record_every`` decisions (7.5 GiB of frames): accepted with 16 GiB free; the torch loop, which keeps every frame,
    is refused (the control), and so is the thinned recording where less is free than it needs."""
    envs = long_rooms()
    geometry = room_geometry(envs, ROOM)
    free_memory(monkeypatch, 16)
    check_against_room(eval_config(), geometry, envs, GreedyDoorController())  # accepted
    every = record_every(1, AGENTS, DECISIONS)
    kept = RECORD_BYTES_PER_AGENT_FRAME * (-(-DECISIONS // every) + 1) * AGENTS
    assert every > 1 and kept < 80 / 17 * RECORD_BYTES + RECORD_BYTES_PER_AGENT_FRAME * AGENTS
    with pytest.raises(ValueError, match=r"^this run needs about 29.8 GiB of memory \(recorded trials 29.8 GiB") as err:
        check_against_room(eval_config(fused=False), geometry, envs, GreedyDoorController())
    assert "\n" not in str(err.value)
    free_memory(monkeypatch, 4)
    with pytest.raises(ValueError, match=rf"recorded trials {kept / GIB:.3g} GiB.*lower trials_per_batch"):
        check_against_room(eval_config(), geometry, envs, GreedyDoorController())


def test_the_nearest_prototype_lists_are_counted_and_left_out_past_their_budget():
    """The lists' build is ``T K^2`` pair distances in blocks of at most GRAPH_BLOCK_BYTES: linear memory; past
    GRAPH_MAX_PAIRS (200 000 prototypes: 4e10 pairs, 14 minutes a set) the index goes without them."""
    assert graph_size(1, 4096) == GRAPH_SIZE and graph_size(1, 3) == 2
    assert graph_memory(1, 4096) == 8 * 4096 * GRAPH_SIZE + 12 * 1024 * 4096  # lists and one block of 1024 rows
    large = 60_000  # within the budget, its blocks cut to GRAPH_BLOCK_BYTES
    assert graph_size(1, large) == GRAPH_SIZE and graph_memory(1, large) <= 8 * large * GRAPH_SIZE + GRAPH_BLOCK_BYTES
    assert GRAPH_MAX_PAIRS < 200_000**2 and graph_size(1, 200_000) == 0 and graph_memory(1, 200_000) == 0
    assert graph_size(2, 50_000) == 0 < graph_size(1, 50_000)  # every set of the index counts


@needs_numba
def test_the_eval_check_counts_a_policys_nearest_prototype_lists(monkeypatch):
    """A synthetic policy of 50 000 prototypes (nothing of K^2 is allocated): the memory check names its lists."""
    envs = {20: ROOM.room(num_replicas=1, num_agents=20)}
    settings = EncoderSettings.for_room(envs[20])
    width, prototypes = settings.num_features, 50_000
    quantizer = Quantizer(mean=torch.zeros(width), std=torch.ones(width), prototypes=torch.zeros(prototypes, width))
    policy = TabularPolicy(StateEncoder(settings, quantizer), torch.zeros(1, 1, prototypes, envs[20].num_actions))
    free_memory(monkeypatch, 1e-3)
    with pytest.raises(ValueError, match=r"nearest-prototype lists \(1 x 50000 prototypes\) 0\.2") as err:
        check_against_room(eval_config(), room_geometry(envs, ROOM), envs, PolicyController(policy))
    assert f"{graph_memory(1, prototypes) / GIB:.3g} GiB" in str(err.value)

"""A fused trial run in parts (for a progress bar) gives the numbers of one call, and a crowd too large to record
every decision is recorded every few: the same frames, fewer of them."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from pedrl._numba import numba_available
from pedrl.scenarios import paper_room
from pedrl.sim.controllers import GreedyDoorController
from pedrl.trial import fused
from pedrl.trial.crowd import run_crowd

pytestmark = pytest.mark.skipif(not numba_available(), reason="the fused trial is numba's")


def recorded(monkeypatch=None, *, progress=None, record_bytes=None, every_call=None):
    env = paper_room(width=8.0, length=10.0, door_width=1.2).room(num_replicas=3, num_agents=12)
    env.reset(seed=3)
    if monkeypatch is not None and record_bytes is not None:
        monkeypatch.setattr(fused, "RECORD_BYTES", record_bytes)
    if monkeypatch is not None and every_call is not None:
        monkeypatch.setattr(fused, "PROGRESS_EVERY", every_call)
    controller = GreedyDoorController(epsilon=0.3, generator=torch.Generator().manual_seed(5))
    return run_crowd(env, controller, fused=True, record=True, progress=progress)


def test_a_trial_in_parts_equals_one_call(monkeypatch):
    whole = recorded()
    calls = []
    parts = recorded(monkeypatch, progress=lambda done, left: calls.append((done, left)), every_call=3 * 12 * 4)
    assert len(calls) > 3  # four decisions a part
    assert [done for done, _ in calls] == sorted(done for done, _ in calls)
    assert calls[-1][1] == 0 and all(left > 0 for _, left in calls[:-1])
    for name in ("positions", "velocities", "in_room", "crashes", "speed_sum"):
        assert np.array_equal(getattr(parts.record, name), getattr(whole.record, name)), name
    assert np.array_equal(parts.record.exit_time, whole.record.exit_time, equal_nan=True)
    assert parts.stats == whole.stats


def test_a_crowd_too_large_to_record_is_recorded_every_few_decisions(monkeypatch):
    whole = recorded().record
    per_frame = 17 * 3 * 12
    sampled = recorded(monkeypatch, record_bytes=per_frame * 8).record  # 8 frames fit
    decisions = whole.positions.shape[1] - 1
    every = round(whole.frame_rate / sampled.frame_rate)  # decisions between frames
    assert every == -(-(fused_max_decisions() + 1) // 8) > 1 and sampled.frame_rate == whole.frame_rate / every
    assert sampled.positions.shape[1] == -(-decisions // every) + 1
    for frame in range(sampled.positions.shape[1] - 1):  # frame k after decision k * every
        assert np.array_equal(sampled.positions[:, frame], whole.positions[:, frame * every])
    assert np.array_equal(sampled.positions[:, -1], whole.positions[:, -1])  # and the end
    assert np.array_equal(sampled.exit_time, whole.exit_time, equal_nan=True)  # exits are counted, not sampled


def fused_max_decisions() -> int:
    return paper_room(width=8.0, length=10.0, door_width=1.2).room(num_agents=12).params.max_decisions


def test_a_placed_crowd_runs_through_the_fused_trial_only():
    """``start="placed"`` (agents placed by ``RoomEnv.place``, no observation): the fused trial walks them from where
    they stand; the torch loop, which needs a reset's observation, refuses in one line."""
    env = paper_room(width=8.0, length=10.0, door_width=1.2).room(num_replicas=1, num_agents=12)
    env.place(seed=0)
    start = env.positions.clone()
    record = run_crowd(env, GreedyDoorController(), fused=True, record=True, start="placed").record
    assert np.array_equal(record.positions[:, 0], start.numpy())
    env.place(seed=0)
    with pytest.raises(ValueError, match=r"^start='placed' is invalid here: the torch loop") as error:
        run_crowd(env, GreedyDoorController(), fused=False, start="placed")
    assert "\n" not in str(error.value)


@pytest.mark.parametrize("fused", [True, None, False])
def test_a_placed_start_in_a_room_never_placed_is_refused(fused):
    """``start="placed"`` with no agent in the room (never placed, or emptied by a trial) would be an empty trial:
    one line naming the value and ``RoomEnv.place``, on either path; the same room once placed runs (the control)."""
    env = paper_room(width=8.0, length=10.0, door_width=1.2).room(num_replicas=1, num_agents=12)
    with pytest.raises(ValueError, match=r"^start='placed' is invalid here: .*call RoomEnv\.place first") as error:
        run_crowd(env, GreedyDoorController(), fused=fused, start="placed")
    assert "\n" not in str(error.value)
    if fused is False:
        return
    env.place(seed=0)
    run = run_crowd(env, GreedyDoorController(), fused=fused, record=True, start="placed")
    assert run.record.in_room[:, 0].sum() == 12 and not env.active.any()  # the crowd walked out
    with pytest.raises(ValueError, match=r"^start='placed' is invalid here: no agent is in the room"):
        run_crowd(env, GreedyDoorController(), fused=fused, start="placed")  # emptied: place it again first

"""The lanes test against Feliciani and Nishinari (2016): its order parameter and crossing times on analytic cases,
and its verdict on walking crowds that must pass (lanes at a pedestrian's pace) and must fail (random mixing, dense
or sparse; lanes walked too fast; a crowd too small to judge; a crowd that never gets through)."""

import numpy as np
import pytest

from pedrl.analysis import Recording
from pedrl.validation.lanes import (
    FELICIANI_CROSSING,
    FELICIANI_PHI,
    LANE_ROW,
    LANES_AGENTS,
    LANES_MIN_AGENTS,
    LANES_RATIOS,
    LANES_WIDTH,
    LANES_WINDOW,
    judge_lanes,
    lanes_corridor,
    lanes_directions,
)
from pedrl.validation.measures import crossing_durations, face_to_face_share, lane_order_frames


def walkers(ratio, *, lanes, speed=1.37, spread=1.0, replicas=2, frames=90, seed=0, agents=LANES_AGENTS):
    """Feliciani's crowd at ``ratio``, scripted: every agent walks straight its way at ``speed`` from a start drawn
    in its 12 m end (stretched ``spread`` times backwards, so a larger spread is a sparser stream). In lanes, the
    two directions keep to their own half of the corridor; otherwise each agent keeps a random lateral position."""
    rng = np.random.default_rng(seed)
    direction = lanes_directions(ratio, agents)
    x0 = 11.5 - rng.uniform(0.0, 11.0, (replicas, agents)) * spread
    x0 = np.where(direction > 0, x0, 38.0 - x0)
    if lanes:
        y = np.where(direction > 0, rng.uniform(0.1, 1.4, x0.shape), rng.uniform(1.6, 2.9, x0.shape))
    else:
        y = rng.uniform(0.1, 2.9, x0.shape)
    x = x0[:, None, :] + direction * speed * np.arange(frames)[None, :, None]
    positions = np.stack([x, np.broadcast_to(y[:, None, :], x.shape)], -1)
    in_room = np.where(direction > 0, x <= 38.0, x >= 0.0)  # in the room until past the far end
    recording = Recording(
        positions=positions,
        in_room=in_room,
        exit_time=np.full(x0.shape, np.nan),
        frame_rate=1.0,
        radius=0.2,
        max_speed=2.5,
    )
    return recording, direction


def every_ratio(**crowd):
    return {label: walkers(ratio, **crowd) for label, ratio in LANES_RATIOS.items()}


def test_order_parameter_rows_by_hand():
    """Rows 0.2 m wide: two agents head-on in one row score 0; an agent alone in its row scores 1; a frame with one
    direction only, or fewer agents than the minimum, is not counted."""
    direction = np.array([1, -1, 1])
    active = np.ones((1, 1, 3), dtype=bool)
    same_row = np.array([[[[15.0, 1.05], [17.0, 1.15], [20.0, 2.5]]]])  # rows 5, 5 and 12
    phi, counts, chance = lane_order_frames(
        same_row, active, direction, window=LANES_WINDOW, width=LANES_WIDTH, row=LANE_ROW, min_agents=3
    )
    assert phi.tolist() == [pytest.approx(0.5)] and counts.tolist() == [3] and np.isnan(chance).all()  # (0 + 1) / 2
    apart = same_row.copy()
    apart[..., 1, 1] = 0.5
    phi, _, _ = lane_order_frames(
        apart, active, direction, window=LANES_WINDOW, width=LANES_WIDTH, row=LANE_ROW, min_agents=3
    )
    assert phi.tolist() == [1.0]
    one_way = lane_order_frames(
        apart, active, np.ones(3), window=LANES_WINDOW, width=LANES_WIDTH, row=LANE_ROW, min_agents=3
    )
    too_few = lane_order_frames(
        apart, active, direction, window=LANES_WINDOW, width=LANES_WIDTH, row=LANE_ROW, min_agents=4
    )
    assert one_way[0].size == 0 and too_few[0].size == 0


def test_crossing_durations_interpolate_between_frames():
    """At 1.3 m/s from x = 10 m, 10 m take 7.69 s whichever way, though frames come once a second; an agent that
    starts inside the area, or never leaves it, is left out."""
    frames = np.arange(20)[None, :, None]
    x = np.concatenate([10.0 + 1.3 * frames, 28.0 - 1.3 * frames, 15.0 + 1.3 * frames, 10.0 + 0.3 * frames], axis=2)
    positions = np.stack([x, np.ones_like(x)], -1)
    active = np.ones(x.shape, dtype=bool)
    times = crossing_durations(positions, active, np.array([1, -1, 1, 1]), window=LANES_WINDOW, frame_rate=1.0)
    assert times == pytest.approx([10 / 1.3, 10 / 1.3])


def test_face_to_face_counts_an_oncoming_walker_close_in_front_only():
    """Bodies of 0.4 m: agent 0 walks to +x at x = 15 m; one walking the other way 1.5 m in front and 0.7 m aside
    faces it (and it that one); 0.9 m aside, 3 m ahead, behind, or walking the same way, it does not; outside the
    area nobody counts."""
    direction = np.array([1, -1])
    active = np.ones((1, 1, 2), dtype=bool)

    def share(other, way=-1, at=15.0):
        positions = np.array([[[[at, 1.0], other]]])
        return face_to_face_share(positions, active, np.array([1, way]), window=LANES_WINDOW, radius=0.4)

    assert share([16.5, 1.7]) == 1.0  # both face each other
    assert share([16.5, 1.9]) == share([18.0, 1.0]) == share([13.5, 1.0]) == share([16.5, 1.3], way=1) == 0.0
    assert share([14.5, 1.3], at=13.0) == 1.0  # only the one inside the area counts: it faces agent 0
    assert face_to_face_share(np.zeros((1, 1, 2, 2)), active, direction, window=LANES_WINDOW, radius=0.4) is None


def test_lanes_at_a_pedestrians_pace_pass_at_3_3_and_every_ratio_is_reported_beside_feliciani():
    row = judge_lanes(every_ratio(lanes=True))
    assert row.passed and row.value == pytest.approx(1.0)
    assert row.details["crossing_s"]["3:3"] == pytest.approx(10 / 1.37, abs=1e-3)  # 7.30 s, Feliciani's 7.33 s
    assert row.details["phi_feliciani"] == FELICIANI_PHI and row.details["crossing_feliciani_s"] == FELICIANI_CROSSING
    assert set(row.details["phi"]) == {"5:1", "4:2", "3:3"} and row.details["agent_frames"]["3:3"] >= 300
    assert row.reference.startswith("ours:")
    # the agents in the 10 m area per counted frame: the agent-frames over the frames counted
    recording, direction = every_ratio(lanes=True)["3:3"]
    _, counts, _ = lane_order_frames(
        recording.positions, recording.in_room, direction, window=LANES_WINDOW, width=LANES_WIDTH, row=LANE_ROW,
        min_agents=LANES_MIN_AGENTS,
    )  # fmt: skip
    assert row.details["agents_in_area"]["3:3"] == pytest.approx(counts.mean(), abs=1e-3)
    assert LANES_MIN_AGENTS <= row.details["agents_in_area"]["3:3"] <= LANES_AGENTS
    lanes = row.details["face_to_face_share"]["3:3"]  # only walkers near the lanes' border (1.4-1.6 m) meet
    mixed = judge_lanes(every_ratio(lanes=False)).details["face_to_face_share"]["3:3"]
    assert lanes < 0.1 and mixed > 3 * lanes  # random lateral places: walkers meet head-on


def test_lanes_fail_random_mixing_at_the_experiments_density():
    row = judge_lanes(every_ratio(lanes=False))
    assert not row.passed and row.value < 0.8 and row.details["crossing_s"]["3:3"] == pytest.approx(7.3, abs=0.01)


def test_lanes_fail_a_sparse_random_stream_that_reaches_phi_08_by_chance():
    """Stretched four times, the stream holds about a dozen agents in the area: rows of 0.2 m hold one agent each
    and random mixing alone scores Phi >= 0.8. Only the chance rule tells it from lanes."""
    row = judge_lanes(every_ratio(lanes=False, spread=4.0))
    assert row.value >= 0.8 and row.details["crossing_s"]["3:3"] == pytest.approx(7.3, abs=0.01)
    assert not row.passed and row.value - row.details["phi_chance"]["3:3"] < 0.05
    assert judge_lanes(every_ratio(lanes=True, spread=4.0)).passed  # the same stream in lanes passes


def test_lanes_fail_when_walked_too_fast_or_too_small_or_never_through():
    fast = judge_lanes(every_ratio(lanes=True, speed=2.5))  # 4 s per 10 m: outside 7.3 s +- 20 %
    assert not fast.passed and fast.value == pytest.approx(1.0) and fast.details["crossing_s"]["3:3"] == 4.0
    tiny = judge_lanes({"3:3": walkers((3, 3), lanes=True, agents=12, replicas=1)})
    assert not tiny.passed and tiny.details["agent_frames"]["3:3"] < 300
    stuck = judge_lanes(every_ratio(lanes=True, speed=0.1, frames=40))  # in lanes, but nobody through the area
    assert not stuck.passed and stuck.details["crossed_share"]["3:3"] == 0.0
    assert not judge_lanes({"5:1": walkers((5, 1), lanes=True)}).passed  # no 3:3 run: no verdict


def test_lanes_corridor_splits_feliciani_crowd_by_ratio():
    for ratio, plus in ((5, 1), 45), ((4, 2), 36), ((3, 3), 27):
        assert (lanes_directions(ratio) > 0).sum() == plus
        scenario = lanes_corridor(ratio)
        assert [spawn.weight for spawn in scenario.spawns] == [float(r) for r in ratio]
        assert scenario.walkable.bounds == (0.0, 0.0, 38.0, 3.0)


def test_a_failed_lanes_row_names_the_criterion_that_failed():
    """Lanes walked too fast showed Phi 1.0, a passing value, beside FAIL: the row now names the crossing time as
    the criterion that failed. The control: a pass names none."""
    assert judge_lanes(every_ratio(lanes=True)).failed == []
    fast = judge_lanes(every_ratio(lanes=True, speed=2.5))
    assert fast.value == pytest.approx(1.0) and fast.failed == ["crossing time 4.0 s not in [5.84, 8.76] s"]
    sparse = judge_lanes(every_ratio(lanes=False, spread=4.0))
    assert len(sparse.failed) == 1 and sparse.failed == ["Phi 0.841 < chance 0.843 + 0.05"]  # Phi >= 0.8, by chance
    stuck = judge_lanes(every_ratio(lanes=True, speed=0.1, frames=40))
    assert "nobody crossed the area" in stuck.failed and "0% of the agents crossed < 50%" in stuck.failed
    assert judge_lanes({"5:1": walkers((5, 1), lanes=True)}).failed == ["no run at 3:3"]

"""The deictic state (Table 1): layout, hand-computed scenes, projection Gamma, void filling."""

import math

import pytest
import torch

from pedrl.scenarios import paper_room
from pedrl.sim.sensing import (
    distance_indices,
    feature_indices,
    feature_names,
    fill_void_neighbours,
    num_features,
    observe,
)

PI32 = torch.tensor(math.pi, dtype=torch.float32).item()
WIDTH, LENGTH, DOOR = 60.0, 100.0, 2.0


def _wrap(angle: float) -> float:
    return math.remainder(angle, 2 * math.pi)


def _closest_on_segment(p, a, b):
    """Closest point of segment a-b to p, by plain vector algebra."""
    abx, aby = b[0] - a[0], b[1] - a[1]
    length_sq = abx * abx + aby * aby
    t = 0.0 if length_sq == 0 else ((p[0] - a[0]) * abx + (p[1] - a[1]) * aby) / length_sq
    t = min(1.0, max(0.0, t))
    return (a[0] + t * abx, a[1] + t * aby)


def expected_state(positions, speeds, headings, agent, k=7, w=2):
    """The 3 + 3k + 2w features of one agent, computed from Table 1 with plain math."""
    px, py = positions[agent]
    phi = math.atan2(LENGTH - py, WIDTH / 2 - px)
    features = [speeds[agent], _wrap(headings[agent] - phi), math.hypot(WIDTH / 2 - px, LENGTH - py)]
    vx, vy = speeds[agent] * math.cos(headings[agent]), speeds[agent] * math.sin(headings[agent])
    others = []
    for j, (qx, qy) in enumerate(positions):
        if j == agent:
            continue
        dx, dy = qx - px, qy - py
        distance = math.hypot(dx, dy)
        wx, wy = speeds[j] * math.cos(headings[j]), speeds[j] * math.sin(headings[j])
        rel_speed = ((wx - vx) * dx + (wy - vy) * dy) / distance
        others.append((distance, rel_speed, _wrap(math.atan2(dy, dx) - phi)))
    others.sort()
    for i in range(k):
        if i < len(others):
            distance, rel_speed, angle = others[i]
            features += [rel_speed, distance, angle]
        else:
            features += [0.0, 0.0, 0.0]
    left, right = WIDTH / 2 - DOOR / 2, WIDTH / 2 + DOOR / 2
    segments = [  # in the order of the compiled paper room (shapely's, from the door's left post): ties go first
        ((left, LENGTH), (0, LENGTH)),
        ((0, LENGTH), (0, 0)),
        ((0, 0), (WIDTH, 0)),
        ((WIDTH, 0), (WIDTH, LENGTH)),
        ((WIDTH, LENGTH), (right, LENGTH)),
    ]
    walls = []
    for a, b in segments:
        cx, cy = _closest_on_segment((px, py), a, b)
        walls.append((math.hypot(cx - px, cy - py), _wrap(math.atan2(cy - py, cx - px) - phi)))
    walls.sort(key=lambda wall: wall[0])  # stable: equally near walls in the area's order
    for distance, angle in walls[:w]:
        features += [distance, angle]
    return features


SCENES = {
    "four agents": (
        [(30.2, 90.0), (32.0, 91.0), (27.0, 88.5), (50.0, 97.0)],
        [1.0, 2.0, 0.0, 2.5],
        [0.3, math.pi / 2, -2.0, 3.0],
    ),
    "nine agents, one beyond the seventh": (
        [(10.0, 10.0), (11.0, 10.5), (9.2, 11.4), (12.5, 8.0), (8.0, 8.7), (10.3, 13.0), (14.0, 12.1), (6.5, 11.0)]
        + [(20.0, 30.0)],
        [2.5, 0.5, 1.0, 0.0, 2.0, 1.5, 0.7, 1.2, 2.2],
        [0.0, 1.0, -1.0, 2.0, -2.5, 3.1, -0.4, 0.9, -1.6],
    ),
    "three agents near the door": ([(30.5, 99.0), (28.0, 98.5), (58.0, 99.1)], [0.0, 1.0, 2.0], [2.0, 0.1, -3.0]),
}


@pytest.mark.parametrize("scene", list(SCENES))
def test_features_of_a_hand_built_scene_equal_table_1(scene):
    positions, speeds, headings = SCENES[scene]
    env = paper_room(width=WIDTH, length=LENGTH, door_width=DOOR).room(num_agents=len(positions))
    obs, info = env.reset(
        options={"positions": [positions], "speeds": [speeds], "headings": [headings]},
    )
    assert obs.shape == (1, len(positions), 28) and obs.dtype == torch.float32
    expected = torch.tensor([expected_state(positions, speeds, headings, i) for i in range(len(positions))])
    torch.testing.assert_close(obs[0], expected.float(), atol=1e-4, rtol=1e-5)
    sensed = min(len(positions) - 1, 7)
    assert info["num_sensed"].tolist() == [[sensed] * len(positions)]
    assert info["neighbour_mask"].tolist() == [[[True] * sensed + [False] * (7 - sensed)] * len(positions)]
    velocity = torch.tensor([expected_velocities(positions, speeds, headings, i) for i in range(len(positions))])
    torch.testing.assert_close(info["neighbour_velocity"][0], velocity.float(), atol=1e-5, rtol=1e-5)


def expected_velocities(positions, speeds, headings, agent, k=7):
    """Each of the ``k`` nearest others' velocity along and across the agent's line to the door centre (0 past them)."""
    px, py = positions[agent]
    phi = math.atan2(LENGTH - py, WIDTH / 2 - px)
    nearest = sorted((math.dist(q, (px, py)), j) for j, q in enumerate(positions) if j != agent)[:k]
    rows = [[speeds[j] * math.cos(headings[j] - phi), speeds[j] * math.sin(headings[j] - phi)] for _, j in nearest]
    return rows + [[0.0, 0.0]] * (k - len(rows))


def test_feature_names_follow_the_layout():
    names = feature_names(7, 2)
    assert len(names) == num_features(7, 2) == 28
    assert names[:6] == ["speed", "velocity_angle", "door_distance", "neighbour0_rel_speed", "neighbour0_distance"] + [
        "neighbour0_angle"
    ]
    assert names[3 + 3 * 6 : 3 + 3 * 7] == ["neighbour6_rel_speed", "neighbour6_distance", "neighbour6_angle"]
    assert names[24:] == ["wall0_distance", "wall0_angle", "wall1_distance", "wall1_angle"]
    assert feature_names(0, 0) == ["speed", "velocity_angle", "door_distance"]
    assert paper_room().room(num_agents=2).feature_names == names


@pytest.mark.parametrize(
    ("num_sensed", "expected"),
    [
        (0, [0, 1, 2, 24, 25, 26, 27]),
        (1, [0, 1, 2, 3, 4, 5, 24, 25, 26, 27]),
        (3, [*range(12), 24, 25, 26, 27]),
        (7, list(range(28))),
    ],
)
def test_feature_indices_is_the_projection_gamma(num_sensed, expected):
    indices = feature_indices(num_sensed, 7, 2)
    assert indices.dtype == torch.int64
    assert indices.tolist() == expected
    names = feature_names(7, 2)
    assert all(not names[i].startswith(f"neighbour{num_sensed}_") for i in indices.tolist())


def test_feature_indices_other_layouts_and_errors():
    assert feature_indices(2, 3, 1).tolist() == [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 13]
    assert feature_indices(0, 0, 0).tolist() == [0, 1, 2]
    with pytest.raises(ValueError, match="num_sensed=8"):
        feature_indices(8, 7, 2)
    with pytest.raises(ValueError, match="num_sensed=-1"):
        feature_indices(-1, 7, 2)


def _scene_obs(num_agents: int, seed: int):
    env = paper_room().room(num_replicas=4, num_agents=num_agents)
    obs, info = env.reset(seed=seed)
    return env, obs, info


@pytest.mark.parametrize("num_agents", [1, 3, 8, 12])
def test_fill_void_neighbours_keeps_sensed_slots_and_fills_valid_values(num_agents):
    env, obs, info = _scene_obs(num_agents, seed=num_agents)
    num_sensed = info["num_sensed"]
    generator = torch.Generator().manual_seed(0)
    filled = fill_void_neighbours(
        obs,
        num_sensed,
        num_neighbours=7,
        num_walls=2,
        max_distance=env.max_distance,
        max_speed=env.params.max_speed,
        generator=generator,
    )
    assert filled.shape == obs.shape and filled is not obs
    slots = obs[..., 3:24].reshape(4, num_agents, 7, 3)
    new_slots = filled[..., 3:24].reshape(4, num_agents, 7, 3)
    sensed = info["neighbour_mask"]
    assert torch.equal(new_slots[sensed], slots[sensed])  # sensed slots untouched
    assert torch.equal(filled[..., :3], obs[..., :3]) and torch.equal(filled[..., 24:], obs[..., 24:])
    void = ~sensed
    rel_speed, distance, angle = new_slots[..., 0], new_slots[..., 1], new_slots[..., 2]
    assert ((rel_speed[void] >= -2 * env.params.max_speed) & (rel_speed[void] <= 2 * env.params.max_speed)).all()
    assert ((angle[void] > -PI32) & (angle[void] <= PI32)).all()
    assert (distance[void] >= 0.8 - 1e-6).all() and (distance[void] <= env.max_distance + 1e-4).all()
    assert (distance.diff(dim=-1) >= 0).all()  # still sorted nearest first
    if void.any():
        assert (distance[void] > 0).all() and not torch.equal(new_slots[void], slots[void])
    # reproducible with the same generator seed
    again = fill_void_neighbours(
        obs,
        num_sensed,
        num_neighbours=7,
        num_walls=2,
        max_distance=env.max_distance,
        max_speed=env.params.max_speed,
        generator=torch.Generator().manual_seed(0),
    )
    assert torch.equal(again, filled)


def test_fill_void_neighbours_starts_after_the_last_sensed_distance():
    obs = torch.zeros(2, 28)
    obs[0, 3:9] = torch.tensor([0.5, 3.0, 0.1, -0.5, 40.0, 0.2])  # two neighbours, the second at 40 m
    filled = fill_void_neighbours(
        obs,
        torch.tensor([2, 0]),
        num_neighbours=7,
        num_walls=2,
        max_distance=50.0,
        max_speed=2.5,
        generator=torch.Generator().manual_seed(1),
        min_distance=1.0,
    )
    distances = filled[:, 4:24:3]
    assert distances[0, :2].tolist() == [3.0, 40.0]
    assert ((distances[0, 2:] >= 40.0) & (distances[0, 2:] <= 50.0)).all()
    assert ((distances[1] >= 1.0) & (distances[1] <= 50.0)).all()
    assert (distances.diff(dim=-1) >= 0).all()


def test_fill_void_neighbours_rejects_a_wrong_layout():
    with pytest.raises(ValueError, match="obs.shape"):
        fill_void_neighbours(
            torch.zeros(3, 27),
            torch.zeros(3, dtype=torch.int64),
            num_neighbours=7,
            num_walls=2,
            max_distance=1.0,
            max_speed=1.0,
        )


def test_inactive_agents_are_neither_observers_nor_sensed():
    room = paper_room(width=WIDTH, length=LENGTH, door_width=DOOR).geometry()
    positions = torch.tensor([[[10.0, 10.0], [11.0, 10.0], [13.0, 10.0], [30.0, 50.0]]])
    sensed = torch.tensor([[True, False, True, True]])
    observation = observe(
        positions=positions,
        velocities=torch.zeros(1, 4, 2),
        headings=torch.zeros(1, 4),
        speeds=torch.zeros(1, 4),
        observers=sensed,
        sensed=sensed,
        geometry=room,
        num_neighbours=7,
        num_walls=2,
    )
    assert observation.num_sensed.tolist() == [[2, 0, 2, 2]]
    assert torch.equal(observation.features[0, 1], torch.zeros(28))
    assert observation.neighbour_mask[0, 1].sum() == 0
    # agent 0's nearest sensed neighbour is agent 2 at 3 m (agent 1, at 1 m, is not sensed)
    assert observation.features[0, 0, 4].item() == pytest.approx(3.0)


@pytest.mark.parametrize(("num_neighbours", "num_walls"), [(0, 0), (2, 5), (10, 1)])
def test_other_numbers_of_neighbours_and_walls(num_neighbours, num_walls):
    env = paper_room().room(num_replicas=2, num_agents=5, num_neighbours=num_neighbours, num_walls=num_walls)
    obs, info = env.reset(seed=0)
    assert obs.shape == (2, 5, 3 + 3 * num_neighbours + 2 * num_walls)
    assert info["neighbour_mask"].shape == (2, 5, num_neighbours)
    assert info["num_sensed"].tolist() == [[min(4, num_neighbours)] * 5] * 2
    wall_distances = obs[..., 3 + 3 * num_neighbours :: 2]
    assert (wall_distances.diff(dim=-1) >= 0).all()
    assert (wall_distances >= env.params.agent_radius - 1e-4).all()


def test_filled_distances_are_uniform_order_statistics():
    """Slot j of m void slots has mean low + (j + 1) / (m + 1) * (high - low), as sorted uniforms do."""
    rows = 20000
    obs = torch.zeros(rows, 28)
    obs[:, 4:13:3] = torch.tensor([2.0, 3.0, 5.0])  # three sensed neighbours, the last at 5 m
    filled = fill_void_neighbours(
        obs,
        torch.full((rows,), 3),
        num_neighbours=7,
        num_walls=2,
        max_distance=13.0,
        max_speed=2.5,
        generator=torch.Generator().manual_seed(2),
    )
    distances = filled[:, 13:24:3]  # the four void slots
    expected = torch.tensor([5.0 + 8.0 * (j + 1) / 5 for j in range(4)])
    torch.testing.assert_close(distances.mean(0), expected, atol=0.05, rtol=0)
    angles, rel_speeds = filled[:, 14:24:3], filled[:, 12:24:3]
    assert abs(angles.mean().item()) < 0.05 and abs(rel_speeds.mean().item()) < 0.05


@pytest.mark.parametrize(("num_neighbours", "num_walls"), [(7, 2), (0, 0), (3, 5)])
def test_distance_indices_name_exactly_the_distance_features(num_neighbours, num_walls):
    names = feature_names(num_neighbours, num_walls)
    expected = [i for i, name in enumerate(names) if name.endswith("distance")]
    assert distance_indices(num_neighbours, num_walls).tolist() == expected

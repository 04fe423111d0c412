"""The room: walls, door, point-segment distances, angle wrapping."""

import math

import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from pedrl.sim.geometry import (
    NUM_WALLS,
    WALL_NAMES,
    RoomGeometry,
    build_walls,
    closest_points_on_segments,
    distances_to_segments,
    wrap_angle,
)

PI32 = torch.tensor(math.pi, dtype=torch.float32).item()


def test_walls_are_the_five_documented_segments_in_order():
    walls = build_walls(width=60.0, length=100.0, door_width=2.0)
    expected = [
        [[0, 0], [60, 0]],
        [[60, 0], [60, 100]],
        [[60, 100], [31, 100]],
        [[29, 100], [0, 100]],
        [[0, 100], [0, 0]],
    ]
    assert walls.shape == (NUM_WALLS, 2, 2) and walls.dtype == torch.float32
    assert walls.tolist() == expected
    assert WALL_NAMES == ("bottom", "right", "top_right", "top_left", "left")


def test_room_geometry_describes_door_and_goal():
    room = RoomGeometry.build(width=60.0, length=100.0, door_width=2.0)
    assert (room.door_left, room.door_right) == (29.0, 31.0)
    assert room.goal == (30.0, 100.0)
    assert room.diagonal == math.hypot(60.0, 100.0)
    assert torch.equal(room.walls, build_walls(width=60.0, length=100.0, door_width=2.0))


def test_point_segment_distance_and_closest_point_analytic():
    segments = torch.tensor([[[0.0, 0.0], [4.0, 0.0]], [[1.0, 1.0], [1.0, 1.0]]])  # a segment and a point
    points = torch.tensor([[2.0, 3.0], [-3.0, 4.0], [7.0, -4.0], [1.0, 1.0]])
    closest = closest_points_on_segments(points, segments)
    assert closest.shape == (4, 2, 2)
    assert closest[:, 0].tolist() == [[2.0, 0.0], [0.0, 0.0], [4.0, 0.0], [1.0, 0.0]]
    assert closest[:, 1].tolist() == [[1.0, 1.0]] * 4
    distance = distances_to_segments(points, segments)
    expected = [[3.0, math.sqrt(5)], [5.0, 5.0], [5.0, math.sqrt(61)], [1.0, 0.0]]
    torch.testing.assert_close(distance, torch.tensor(expected))


def test_distances_broadcast_over_batches():
    segments = build_walls(width=60.0, length=100.0, door_width=2.0)
    points = torch.tensor([[[30.0, 10.0], [5.0, 99.0]], [[59.0, 50.0], [30.0, 99.5]]])  # (R=2, N=2, 2)
    distance = distances_to_segments(points, segments)
    assert distance.shape == (2, 2, NUM_WALLS)
    torch.testing.assert_close(distance[0, 0], torch.tensor([10.0, 30.0, math.hypot(1, 90), math.hypot(1, 90), 30.0]))
    # a point in the doorway sees the door posts, not the wall line
    torch.testing.assert_close(distance[1, 1, 2:4], torch.tensor([math.hypot(1.0, 0.5)] * 2))


def test_room_wall_queries_equal_the_general_segment_functions():
    room = RoomGeometry.build(width=10.0, length=12.0, door_width=3.0)
    generator = torch.Generator().manual_seed(1)
    points = torch.rand(3, 50, 2, generator=generator) * torch.tensor([14.0, 16.0]) - 2.0
    torch.testing.assert_close(room.closest_wall_points(points), closest_points_on_segments(points, room.walls))
    distance = distances_to_segments(points, room.walls)
    torch.testing.assert_close(room.squared_wall_distances(points), distance**2, atol=1e-4, rtol=1e-5)
    offsets = room.wall_offsets(points)
    torch.testing.assert_close(offsets, room.closest_wall_points(points) - points.unsqueeze(-2))


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-50.0, 50.0, allow_nan=False), min_size=1, max_size=20))
def test_wrap_angle_range_and_equivalence(values):
    angles = torch.tensor(values, dtype=torch.float32)
    wrapped = wrap_angle(angles)
    assert ((wrapped > -PI32) & (wrapped <= PI32)).all()
    # same direction
    torch.testing.assert_close(torch.cos(wrapped), torch.cos(angles), atol=1e-4, rtol=0)
    torch.testing.assert_close(torch.sin(wrapped), torch.sin(angles), atol=1e-4, rtol=0)


def test_wrap_angle_boundaries():
    wrapped = wrap_angle(torch.tensor([math.pi, -math.pi, 3 * math.pi, 0.0, -1e-9, 2 * math.pi]))
    assert wrapped[0] == PI32 and wrapped[1] == PI32  # -pi is the same direction: reported as pi
    assert abs(float(wrapped[2]) - math.pi) < 1e-6
    torch.testing.assert_close(wrapped[3:], torch.zeros(3), atol=1e-6, rtol=0)

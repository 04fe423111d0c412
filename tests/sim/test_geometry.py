"""The compiled walkable area: walls, exits, goal points, point-segment distances, angle wrapping."""

import math
from dataclasses import replace

import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from pedrl.scenarios import paper_room
from pedrl.sim.geometry import (
    FAR,
    WALL_PADDING,
    Geometry,
    SpawnArea,
    closest_points_on_segments,
    distances_to_segments,
    inside_polygon,
    spawn_counts,
    wrap_angle,
)

PI32 = torch.tensor(math.pi, dtype=torch.float32).item()


NUM_WALLS = 5
"""Walls of the paper's room."""


def paper_walls(*, width: float, length: float, door_width: float) -> torch.Tensor:
    """The paper's room written out by hand ``(5, 2, 2)``: bottom, right, top right of the door, top left, left."""
    left, right = width / 2 - door_width / 2, width / 2 + door_width / 2
    return torch.tensor(
        [
            [[0.0, 0.0], [width, 0.0]],
            [[width, 0.0], [width, length]],
            [[width, length], [right, length]],
            [[left, length], [0.0, length]],
            [[0.0, length], [0.0, 0.0]],
        ]
    )


def rectangle(*, width: float, length: float, door_width: float, goal_depth: float = 0.0) -> Geometry:
    """The paper's room compiled, as every room has it: through its scenario."""
    return paper_room(width=width, length=length, door_width=door_width).geometry(goal_depth=goal_depth)


def test_the_paper_room_compiles_to_its_walls_door_goal_and_padding():
    """The scenario's walls are the five written out by hand (in shapely's order, from the door's left post)."""
    room = rectangle(width=60.0, length=100.0, door_width=2.0, goal_depth=1.5)
    assert room.num_walls == NUM_WALLS and room.walls.shape == (WALL_PADDING, 2, 2) and room.name == "paper_room"
    walls = paper_walls(width=60.0, length=100.0, door_width=2.0)
    assert torch.equal(room.walls[:NUM_WALLS], walls.roll(2, dims=0))
    assert (room.walls[NUM_WALLS:] == FAR).all()  # padding: far-away points
    assert room.exits.tolist() == [[[31.0, 100.0], [29.0, 100.0]]] and room.exit_normals.tolist() == [[0.0, 1.0]]
    assert room.exit_goals.tolist() == [[30.0, 101.5]] and room.goal_depth == 1.5
    assert room.diagonal == math.hypot(60.0, 100.0)
    assert room.bounds == room.clear_box == (0.0, 0.0, 60.0, 100.0)
    # the padding is never touched nor among the nearest walls
    points = torch.tensor([[30.0, 50.0], [0.5, 99.5]])
    assert room.squared_wall_distances(points)[:, NUM_WALLS:].min() > 1e11


def test_another_goal_depth_moves_the_goal_points_and_nothing_else():
    """``replace(area, goal_depth=...)`` recomputes the derived goal points as if compiled with that depth."""
    room = rectangle(width=10.0, length=12.0, door_width=3.0)
    deeper = replace(room, goal_depth=2.0)
    assert torch.equal(deeper.exit_goals, rectangle(width=10.0, length=12.0, door_width=3.0, goal_depth=2.0).exit_goals)
    assert deeper.exit_goals.tolist() == [[5.0, 14.0]] and torch.equal(deeper.walls, room.walls)


def test_derived_attributes_are_public_and_follow_the_segments():
    """What the kernels read: each wall's box, whether all walls are axis-aligned, each exit's tangent and span."""
    room = rectangle(width=10.0, length=12.0, door_width=3.0)
    assert torch.equal(room.box_low, room.walls.amin(1)) and torch.equal(room.box_high, room.walls.amax(1))
    assert room.axis_aligned
    assert room.exit_tangents.tolist() == [[-3.0, 0.0]] and room.exit_spans.tolist() == [9.0]
    moved = room.to("cpu")
    assert torch.equal(moved.box_low, room.box_low) and torch.equal(moved.exit_spans, room.exit_spans)
    spawn = SpawnArea(box=(0.0, 0.0, 1.0, 1.0), edges=torch.zeros(0, 2, 2), area=1.0, perimeter=4.0)
    slanted = Geometry.build(
        walls=[[[0.0, 0.0], [4.0, 4.0]]], exits=[[[4.0, 0.0], [4.0, 4.0]]], exit_normals=[[1.0, 0.0]],
        spawns=[spawn], bounds=(0.0, 0.0, 4.0, 4.0),
    )  # fmt: skip
    assert not slanted.axis_aligned


def test_exits_are_passed_only_through_their_span_and_within_the_depth():
    room = rectangle(width=10.0, length=10.0, door_width=2.0)
    points = torch.tensor([[5.0, 10.0], [5.0, 10.3], [4.1, 10.2], [3.9, 10.2], [5.0, 9.99], [5.0, 10.6]])
    assert room.passes_exits(points, depth=0.5).tolist() == [True, True, True, False, False, False]
    assert room.inside(torch.tensor([[5.0, 5.0], [5.0, 10.5], [-1.0, 5.0], [9.9, 0.1]])).tolist() == [
        True,
        False,
        False,
        True,
    ]


def test_inside_polygon_handles_holes():
    outer = [[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [0.0, 4.0]]
    hole = [[1.0, 1.0], [1.0, 3.0], [3.0, 3.0], [3.0, 1.0]]
    rings = [torch.tensor(ring) for ring in (outer, hole)]
    edges = torch.cat([torch.stack((ring, ring.roll(-1, 0)), dim=1) for ring in rings])
    points = torch.tensor([[0.5, 0.5], [2.0, 2.0], [3.5, 2.0], [5.0, 2.0]])
    assert inside_polygon(points, edges).tolist() == [True, False, True, False]


def test_general_walls_project_onto_slanted_segments():
    spawn = SpawnArea(box=(0.0, 0.0, 1.0, 1.0), edges=torch.zeros(0, 2, 2), area=1.0, perimeter=4.0)
    geometry = Geometry.build(
        walls=[[[0.0, 0.0], [4.0, 4.0]], [[0.0, 0.0], [4.0, 0.0]]],
        exits=[[[4.0, 0.0], [4.0, 4.0]]],
        exit_normals=[[1.0, 0.0]],
        spawns=[spawn],
        bounds=(0.0, 0.0, 4.0, 4.0),
    )
    distance = geometry.squared_wall_distances(torch.tensor([[3.0, 1.0]]))[0, :2].sqrt()
    torch.testing.assert_close(distance, torch.tensor([math.sqrt(2.0), 1.0]))


def test_spawn_counts_split_by_weight_with_largest_remainders():
    assert spawn_counts(10, [1.0, 1.0]) == (5, 5)
    assert spawn_counts(7, [1.0, 1.0]) == (4, 3)
    assert spawn_counts(10, [1.0, 2.0, 1.0]) == (2, 5, 3) or spawn_counts(10, [1.0, 2.0, 1.0]) == (3, 5, 2)
    assert sum(spawn_counts(101, [0.3, 0.3, 0.4])) == 101


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
    segments = paper_walls(width=60.0, length=100.0, door_width=2.0)
    points = torch.tensor([[[30.0, 10.0], [5.0, 99.0]], [[59.0, 50.0], [30.0, 99.5]]])  # (R=2, N=2, 2)
    distance = distances_to_segments(points, segments)
    assert distance.shape == (2, 2, NUM_WALLS)
    torch.testing.assert_close(distance[0, 0], torch.tensor([10.0, 30.0, math.hypot(1, 90), math.hypot(1, 90), 30.0]))
    # a point in the doorway sees the door posts, not the wall line
    torch.testing.assert_close(distance[1, 1, 2:4], torch.tensor([math.hypot(1.0, 0.5)] * 2))


def test_room_wall_queries_equal_the_general_segment_functions():
    room = rectangle(width=10.0, length=12.0, door_width=3.0)
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

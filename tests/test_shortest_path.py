"""Shortest collision-free path lengths on a world's occupancy grid (the SPL denominator)."""

import math

import pytest

from sim.geometry import clearance_m
from sim.shortest_path import (
    LIMO_CLEARANCE_M,
    NoPathError,
    free_space,
    route_shortest_length_m,
    shortest_path,
    shortest_path_length_m,
)
from sim.worlds import load_world

ROOM = """
name: room
floor: {size_m: [8.0, 6.0]}
walls:
  - {start: [0, 0], end: [8, 0]}
  - {start: [8, 0], end: [8, 6]}
  - {start: [8, 6], end: [0, 6]}
  - {start: [0, 6], end: [0, 0]}
  # a partition from the north wall down to y = 1.5: going from west to east means passing under it
  - {start: [4, 6], end: [4, 1.5]}
routes:
  walkthrough: [[2, 4], [2, 0.8], [6, 0.8], [6, 4], [6.8, 4.6], [6.8, 0.8], [2, 0.8], [2, 3.5]]
  evaluation:
    under:
      start: [2.0, 3.0, -90.0]
      waypoints: [[2.0, 0.8], [6.0, 0.8]]
      goal: [6.0, 3.0, 90.0]
      length_m: 8.4
      difficulty: easy
      description: Under the partition.
"""


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    path = tmp_path_factory.mktemp("world") / "room.yaml"
    path.write_text(ROOM)
    return load_world(path)


def test_open_space_is_nearly_the_straight_line(room):
    for goal in [(3.5, 1.0), (3.5, 4.5), (1.0, 2.5)]:
        length = shortest_path_length_m(room, (1.0, 1.0), goal)
        straight = math.dist((1.0, 1.0), goal)
        assert straight <= length <= straight * 1.04


def test_a_wall_forces_the_detour_below_it(room):
    length, points = shortest_path(room, (2.0, 4.0), (6.0, 4.0))
    # the straight line is 4 m; passing below the partition's end at (4, 1.5) with 0.2 m clearance
    # (plus half the wall's thickness) costs about twice the 2.5 m drop on each side
    detour = 2 * math.dist((2.0, 4.0), (4.0, 1.5 - LIMO_CLEARANCE_M))
    assert detour * 0.97 <= length <= detour * 1.08
    assert points[:, 1].min() < 1.5                      # it did go under the partition
    distance, _ = clearance_m(room, points[1:-1])
    assert distance.min() >= LIMO_CLEARANCE_M - 1e-9     # and kept the robot's clearance everywhere


def test_route_length_stays_in_the_route_corridor(room):
    free, _ = free_space(room)
    corridor, _ = free_space(room, corridor=[(2, 3), (2, 0.8), (6, 0.8), (6, 3)], corridor_half_width_m=0.5)
    assert corridor.sum() < free.sum() and not (corridor & ~free).any()
    length = route_shortest_length_m(room, "under")
    assert shortest_path_length_m(room, (2.0, 3.0), (6.0, 3.0)) <= length + 1e-9
    assert length <= 8.4
    # from another start the length changes accordingly
    assert route_shortest_length_m(room, "under", (2.0, 2.0)) < length


def test_blocked_or_unreachable_points_are_named(room):
    with pytest.raises(NoPathError, match=r"start \(4.00, 3.00\)"):
        shortest_path_length_m(room, (4.0, 3.0), (6.0, 4.0))          # on the partition
    with pytest.raises(NoPathError, match="goal"):
        shortest_path_length_m(room, (2.0, 4.0), (20.0, 4.0))         # off the floor
    free, origin = free_space(room)
    cut = free.copy()
    cut[:, 60:64] = False                # a full-height barrier at x = 3.0..3.2 m
    with pytest.raises(NoPathError, match="no free path"):
        shortest_path_length_m(room, (2.0, 4.0), (6.0, 4.0), grid=(cut, origin))


@pytest.mark.slow     # the shortest paths over the hospital, office, warehouse and garage
def test_shipped_routes_have_shortest_lengths_below_their_taught_lengths():
    for world in ("hospital", "office", "warehouse", "garage"):
        spec = load_world(world)
        for name, route in spec.routes.evaluation.items():
            length = route_shortest_length_m(spec, name)
            straight = math.dist(route.start[:2], route.goal[:2])
            assert straight - 1e-6 <= length <= route.length_m, (world, name, length)

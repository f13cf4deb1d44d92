"""The heading guard's error against the route: the target's mapped heading, or (``along_arc``)
the headings the mapping drive turned through on the arc into the target."""

import math

import pytest

from controllers.actions import Action
from controllers.config import HeadingGuardConfig
from controllers.heading_guard import HeadingGuard

# the drive turned 20 deg right from node 0 to node 1 (a jog round an obstacle), then ran on
HEADINGS = {0: 0.0, 1: math.radians(-20.0), 2: math.radians(-20.0)}
OFFSET = math.radians(30.0)          # the robot's odometry reads 30 deg more than the map's


def _deg(value: float) -> float:
    return math.radians(value) + OFFSET


@pytest.mark.parametrize("facing, error", [(0.0, 0.0), (-10.0, 0.0), (-20.0, 0.0), (5.0, 5.0),
                                           (-26.0, -6.0), (150.0, 150.0), (-175.0, -155.0)])
def test_between_the_arcs_end_headings_the_error_is_zero_outside_it_counts_from_the_nearer(facing, error):
    guard = HeadingGuard(HeadingGuardConfig(along_arc=True), HEADINGS)
    assert math.degrees(guard.error_rad(1, _deg(facing), OFFSET, source=0)) == pytest.approx(error, abs=1e-9)
    # without the arc's start, from the target's heading alone
    assert math.degrees(guard.error_rad(1, _deg(facing), OFFSET)) == pytest.approx(
        math.degrees(math.remainder(math.radians(facing + 20.0), math.tau)), abs=1e-9)


def test_a_robot_facing_the_arcs_start_heading_is_not_turned_into_the_jog():
    # just past node 0, facing the way the drive faced there: 20 deg left of node 1's heading,
    # past the 15 deg limit. The target's heading alone turns it right at once; along the arc not
    plain = HeadingGuard(HeadingGuardConfig(), HEADINGS)
    turn = plain.check(1, _deg(0.0), OFFSET, source=0)
    assert turn is not None and turn[0] is Action.RIGHT and "node 1" in turn[1]
    along = HeadingGuard(HeadingGuardConfig(along_arc=True), HEADINGS)
    assert along.check(1, _deg(0.0), OFFSET, source=0) is None
    # facing beyond the arc's headings it still turns back, to within release_deg of the arc
    turn = along.check(1, _deg(-40.0), OFFSET, source=0)
    assert turn is not None and turn[0] is Action.LEFT and "nodes 0 -> 1" in turn[1]
    assert along.check(1, _deg(-26.0), OFFSET, source=0) is not None      # hysteresis: not yet released
    assert along.check(1, _deg(-24.0), OFFSET, source=0) is None
    # on a straight arc it is the target's heading, as before
    assert along.check(2, _deg(-24.0), OFFSET, source=1) is None
    assert along.check(2, _deg(-38.0), OFFSET, source=1)[0] is Action.LEFT


def test_along_arc_is_checked():
    with pytest.raises(ValueError, match="along_arc"):
        HeadingGuardConfig(along_arc="yes")

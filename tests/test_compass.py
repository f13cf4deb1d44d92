"""The heading offset from a look round (controllers/compass.py), alone and in the navigator."""

import math
from dataclasses import replace

import numpy as np
import pytest

from controllers.actions import Action
from controllers.compass import LookCompass
from controllers.config import HeadingGuardConfig
from controllers.heading_guard import HeadingGuard, offset_votes
from controllers.navigator import Navigator, NavState
from core.angles import wrap_angle
from core.hal import Pose2D
from tests.synthetic_places import SyntheticPlaces, chain
from tests.test_navigator import _belief_config, _snapshot


def _look(compass: LookCompass, mapped, offset_rad: float, seed: int = 0, ticks: int = 126) -> None:
    """A full turn in place: node j matches best facing its mapped heading turned by the offset
    (a broad peak, noisy views, headings in a frame that wraps)."""
    rng = np.random.default_rng(seed)
    for k in range(ticks):
        heading = 2.0 + k * 2.0 * math.pi / ticks
        peak = np.array(mapped) + offset_rad
        row = 0.3 + 0.5 * np.exp(-np.angle(np.exp(1j * (heading - peak))) ** 2 / (2 * 0.6 ** 2))
        compass.add(heading, row + rng.normal(0.0, 0.03, len(mapped)))


@pytest.mark.parametrize("offset_deg", [0.0, 17.0, -40.0, 179.0])
def test_the_offset_is_where_the_nodes_matched_best(offset_deg):
    mapped = [0.1, 0.15, 0.05, 1.6]
    compass = LookCompass(math.radians(10.0))
    _look(compass, mapped, math.radians(offset_deg))
    got = compass.offset([0, 1, 2, 3], mapped)
    assert abs(math.degrees(wrap_angle(got - math.radians(offset_deg)))) < 3.0
    assert abs(wrap_angle(compass.peak_rad(3) - (1.6 + math.radians(offset_deg)))) < math.radians(5.0)


def test_no_views_no_offset_and_bad_bandwidth():
    compass = LookCompass(0.2)
    assert compass.offset([0], [0.0]) is None and compass.peak_rad(0) is None
    compass.add(None, np.array([0.5]))                  # no heading: not a view of the look
    assert len(compass) == 0
    _look(compass, [0.0], 0.3)
    assert len(compass) > 0 and compass.offset([], []) is None
    compass.clear()
    assert len(compass) == 0
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="bandwidth_rad"):
            LookCompass(bad)
    with pytest.raises(ValueError, match="compass_bandwidth_deg"):
        replace(_belief_config("initial").localiser, compass_bandwidth_deg=-1.0)


def _placed_after_a_look(bandwidth_deg: float, frame_rad: float = 0.7, standing_rad: float = 0.3):
    """Chain mapped facing 0 rad; the robot stands on node 1 turned ``standing_rad`` off the route,
    its odometry frame ``frame_rad`` off the map's; a full look round, then the belief places it."""
    graph, poses = chain(6)
    config = _belief_config("initial", hold=0)
    config = replace(config, localiser=replace(config.localiser, belief_min_turn_deg=360.0,
                                               compass_bandwidth_deg=bandwidth_deg))
    nav = Navigator(graph, sorted(poses), 5, config, node_headings={n: p.yaw_rad for n, p in poses.items()})
    places = SyntheticPlaces(poses, seed=2)
    yaw = standing_rad
    for _ in range(400):
        pose = Pose2D(poses[1].x_m, poses[1].y_m, yaw)
        step = nav.tick(places.similarities(pose), heading_rad=yaw + frame_rad, belief=_snapshot(1, 0.95))
        if step.state is not NavState.LOCALISING:
            break
        assert step.action in (Action.NONE, Action.SEARCH_ROTATE)
        yaw += step.velocity.w_radps * 0.1
    return nav, step


def test_the_navigator_takes_the_offset_from_the_look_not_from_the_heading_it_stood_at():
    nav, step = _placed_after_a_look(10.0)
    assert step.state is NavState.NAVIGATING and "heading offset" in step.reason
    assert abs(math.degrees(wrap_angle(nav.heading_offset() - 0.7))) < 4.0
    # without the compass the offset is the heading it was placed at: 0.3 rad (17 deg) off
    plain, step = _placed_after_a_look(0.0)
    assert step.state is NavState.NAVIGATING and "heading offset" not in step.reason
    assert abs(math.degrees(wrap_angle(plain.heading_offset() - 0.7))) > 15.0


def test_the_look_stays_one_vote_of_the_confirmations_median():
    """The look's offset counts alone at first; confirmations after it, newest last, outvote it
    once they agree (the odometry drifts), but one stray confirmation does not."""
    guard = HeadingGuard(HeadingGuardConfig(confirmations=5, min_confirmations=2), {0: 0.0})
    look = math.radians(10.0)
    assert guard.offset([]) is None and guard.offset([], look) == pytest.approx(look)
    stray = [math.radians(40.0)]
    assert guard.offset(stray) is None                                   # one confirmation: too few
    assert math.degrees(guard.offset(stray + [look], look)) == pytest.approx(10.0)
    drifted = [math.radians(d) for d in (60.0, 16.0, 17.0, 18.0, 19.0, 20.0)]
    assert math.degrees(guard.offset(drifted, look)) == pytest.approx(18.0)   # 10, 17, 18, 19, 20
    assert offset_votes(drifted, 5, look) == [look] + drifted[-4:]
    assert offset_votes(drifted, 1, look) == [look] and offset_votes(drifted, 2) == drifted[-2:]
    # across +-pi: the votes average the short way round
    assert abs(math.degrees(wrap_angle(guard.offset([math.radians(-178.0)] * 2, math.radians(178.0))
                                       - math.pi))) < 3.0


def test_the_navigators_offset_follows_the_confirmations_after_the_look():
    nav, _ = _placed_after_a_look(10.0)
    look = nav.heading_offset()
    assert nav._guard_offset() == pytest.approx(look)
    for node in (2, 3, 4):           # confirmations facing 0.2 rad further left than the look says
        nav._confirmed(node, look + 0.2)
    assert nav._guard_offset() == pytest.approx(look + 0.2)

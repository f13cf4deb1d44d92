"""Initial / global localisation: accept above T_milestone, else turn counter-clockwise."""

import math

import numpy as np
import pytest

from controllers.actions import Action
from controllers.config import LocaliserConfig, NavigationConfig
from controllers.localisation import (
    GoalNotLocalisedError,
    InitialLocaliser,
    LocalisationError,
    LocaliserStatus,
    TurnMeter,
    localise,
    localise_goal_image,
)
from core.angles import wrap_angle
from tests.synthetic_places import SyntheticPlaces, chain, drive, offset

T = 0.66
NODES = (10, 11, 12, 13)


def test_accepts_the_best_node_above_threshold_only():
    hit = localise(np.array([0.30, 0.71, 0.52, 0.40]), NODES, T)
    assert hit.accepted and hit.node == 11 and hit.best_score == pytest.approx(0.71)
    miss = localise(np.array([0.30, 0.60, 0.52, 0.40]), NODES, T)
    assert not miss.accepted and miss.node is None and miss.best_node == 11
    at_threshold = localise(np.array([0.30, T, 0.52, 0.40]), NODES, T)
    assert not at_threshold.accepted   # must exceed


def test_goal_image_matching_nothing_says_how_close_it_came():
    with pytest.raises(GoalNotLocalisedError) as info:
        localise_goal_image(np.array([0.21, 0.48, 0.33, 0.30]), NODES, T)
    message = str(info.value)
    assert "goal image matches no node" in message
    assert "node 11" in message and "0.480" in message and "0.660" in message
    assert localise_goal_image(np.array([0.21, 0.48, 0.93, 0.30]), NODES, T).node == 12


@pytest.mark.parametrize("row,match", [(np.zeros(3), "one score per map node"),
                                       (np.zeros((4, 1)), "one score per map node"),
                                       (np.array([0.1, np.inf, 0.2, 0.3]), "non-finite score at column 1")])
def test_bad_rows_are_rejected(row, match):
    with pytest.raises(LocalisationError, match=match):
        localise(row, NODES, T)


def test_turn_meter_accumulates_across_the_wrap_and_counts_clockwise_negative():
    meter = TurnMeter()
    headings = [wrap_angle(0.3 * k) for k in range(30)]
    for h in headings:
        meter.update(h)
        meter.update(None)          # a tick without heading changes nothing
    assert meter.turned_rad == pytest.approx(0.3 * 29)
    back = TurnMeter()
    for k in range(5):
        back.update(-0.2 * k)
    assert back.turned_rad == pytest.approx(-0.8)


def test_localises_after_confirm_ticks_without_turning():
    loc = InitialLocaliser(NODES, T, LocaliserConfig(confirm_ticks=3))
    row = np.array([0.30, 0.40, 0.80, 0.50])
    steps = [loc.tick(row, heading_rad=0.0) for _ in range(3)]
    assert [s.status for s in steps] == [LocaliserStatus.CONFIRMING, LocaliserStatus.CONFIRMING,
                                         LocaliserStatus.LOCALISED]
    assert all(s.action is Action.NONE for s in steps)          # holds still, never rotates
    assert steps[-1].node == 12 and loc.done
    assert loc.tick(np.zeros(4)).node == 12                      # final state repeats


def test_rotates_counter_clockwise_then_gives_up_after_a_full_turn():
    loc = InitialLocaliser(NODES, T, LocaliserConfig(max_search_ticks=10_000))
    rate = 0.1
    row = np.array([0.20, 0.35, 0.31, 0.25])
    steps = []
    for k in range(1000):
        steps.append(loc.tick(row, heading_rad=math.remainder(rate * k, 2 * math.pi)))
        if loc.done:
            break
    assert all(s.action is Action.SEARCH_ROTATE and s.status is LocaliserStatus.ROTATING for s in steps[:-1])
    final = steps[-1]
    assert final.status is LocaliserStatus.FAILED and final.action is Action.STOP
    assert "cannot place itself" in final.reason and "node 11" in final.reason
    # gave up on the first tick whose accumulated heading reached 2 pi, not later
    assert final.turned_rad >= 2 * math.pi
    assert final.ticks == math.ceil(round(2 * math.pi / rate, 9)) + 1


def test_gives_up_on_the_tick_budget_without_heading():
    loc = InitialLocaliser(NODES, T, LocaliserConfig(max_search_ticks=25))
    statuses = [loc.tick(np.full(4, 0.2)).status for _ in range(30)]
    assert statuses.index(LocaliserStatus.FAILED) == 24
    assert "25 search ticks" in loc.tick(np.full(4, 0.2)).reason


def test_a_single_lucky_frame_during_the_search_does_not_localise():
    loc = InitialLocaliser(NODES, T, LocaliserConfig(confirm_ticks=3))
    low, lucky = np.full(4, 0.3), np.array([0.3, 0.9, 0.3, 0.3])
    assert loc.tick(low, 0.0).action is Action.SEARCH_ROTATE
    lucky_step = loc.tick(lucky, 0.1)
    assert lucky_step.status is LocaliserStatus.CONFIRMING and lucky_step.action is Action.NONE
    resumed = loc.tick(low, 0.2)
    assert resumed.status is LocaliserStatus.ROTATING and resumed.action is Action.SEARCH_ROTATE
    # a change of candidate restarts the streak as well
    loc.tick(lucky, 0.2)
    loc.tick(lucky, 0.2)
    other = loc.tick(np.array([0.3, 0.3, 0.9, 0.3]), 0.2)
    assert other.status is LocaliserStatus.CONFIRMING and "(1/3)" in other.reason


def test_robot_facing_away_turns_until_it_recognises_its_node():
    graph, poses = chain(5)
    places = SyntheticPlaces(poses, seed=7, noise_std=0.03)
    config = NavigationConfig()
    loc = InitialLocaliser(places.node_ids, config.thresholds.t_milestone, config.localiser)
    pose = offset(poses[2], yaw_rad=math.pi * 0.9)       # looking back along the chain
    speeds = config.speeds
    for _ in range(200):
        step = loc.tick(places.similarities(pose), heading_rad=pose.yaw_rad)
        if loc.done:
            break
        if step.action is Action.SEARCH_ROTATE:
            pose = drive(pose, speeds.search_rotate, 0.1)
    assert step.status is LocaliserStatus.LOCALISED and step.node == 2
    assert 0.5 < step.turned_rad < 2 * math.pi           # it had to turn, less than a full turn


def test_relocalisation_accepts_an_expected_node_below_t_milestone_but_not_another():
    """Re-localising, the nodes of the plan stretch the robot was driving are accepted as the
    best of the row above a lower threshold; any other node still needs t_milestone."""
    row_expected = np.array([0.2, 0.45, 0.3, 0.25])      # node 1 best, below t_milestone 0.6
    loc = InitialLocaliser(range(4), 0.6, LocaliserConfig(confirm_ticks=2), expected=[1, 2], t_expected=0.4)
    steps = [loc.tick(row_expected) for _ in range(2)]
    assert steps[-1].status is LocaliserStatus.LOCALISED and steps[-1].node == 1
    row_other = np.array([0.2, 0.3, 0.3, 0.45])          # node 3 best, not expected
    loc = InitialLocaliser(range(4), 0.6, LocaliserConfig(confirm_ticks=2), expected=[1, 2], t_expected=0.4)
    assert all(loc.tick(row_other, heading_rad=0.0).status is LocaliserStatus.ROTATING for _ in range(3))
    # without expected nodes the threshold is t_milestone as before
    loc = InitialLocaliser(range(4), 0.6, LocaliserConfig(confirm_ticks=2))
    assert loc.tick(row_expected, heading_rad=0.0).status is LocaliserStatus.ROTATING


# -- margin, second look and first view (ours, beyond the paper) ------------------------------------
# four nodes on a chain 0-1-2-3 plus a far look-alike 9; with 1 hop, 0's neighbourhood is {0, 1}
HOODS = {0: frozenset({0, 1}), 1: frozenset({0, 1, 2}), 2: frozenset({1, 2, 3}), 3: frozenset({2, 3}),
         9: frozenset({9})}
IDS = [0, 1, 2, 3, 9]


def _turn(loc, rows, rate=0.2):
    steps = []
    for k, row in enumerate(rows):
        steps.append(loc.tick(np.asarray(row, dtype=float), heading_rad=math.remainder(rate * k, 2 * math.pi)))
        if loc.done:
            break
    return steps


def test_an_ambiguous_view_is_no_match_even_above_t_milestone():
    config = LocaliserConfig(confirm_ticks=2, min_margin=0.04, second_look=False)
    ambiguous = [0.70, 0.50, 0.30, 0.20, 0.68]        # node 0 best, the look-alike 9 only 0.02 behind
    loc = InitialLocaliser(IDS, 0.6, config, neighbourhoods=HOODS, t_floor=0.4)
    steps = _turn(loc, [ambiguous] * 3)
    assert all(s.status is LocaliserStatus.ROTATING for s in steps) and "ambiguous" in steps[0].reason
    # the same row without neighbourhoods (no margin test): the paper's rule accepts it
    loc = InitialLocaliser(IDS, 0.6, config)
    assert _turn(loc, [ambiguous] * 2)[-1].status is LocaliserStatus.LOCALISED


def test_second_look_turns_back_to_the_best_view_of_a_fruitless_turn():
    config = LocaliserConfig(confirm_ticks=2, max_search_ticks=10_000)
    low = [0.30, 0.30, 0.30, 0.30, 0.30]
    good = [0.20, 0.30, 0.55, 0.45, 0.35]              # node 2 best at 0.55 < t_milestone 0.6, margin 0.2
    ticks_per_turn = math.ceil(2 * math.pi / 0.2) + 1
    first_turn = [low] * 10 + [good] * 3 + [low] * (ticks_per_turn - 13)
    loc = InitialLocaliser(IDS, 0.6, config, neighbourhoods=HOODS, t_floor=0.4)
    steps = _turn(loc, first_turn + [low] * 9 + [good] * 3)
    assert any("turning on to the best one: node 2" in s.reason for s in steps)
    final = steps[-1]
    assert final.status is LocaliserStatus.LOCALISED and final.node == 2 and "second look" in final.reason
    assert final.turned_rad > 2 * math.pi
    # without a candidate above the floor the search still fails after one turn
    loc = InitialLocaliser(IDS, 0.6, config, neighbourhoods=HOODS, t_floor=0.6)
    assert _turn(loc, first_turn + [good] * 40)[-1].status is LocaliserStatus.FAILED


def test_first_view_is_accepted_when_unambiguous_but_not_after_turning():
    config = LocaliserConfig(confirm_ticks=3, first_view_margin=0.05, first_view_slack=0.05)
    view = [0.20, 0.30, 0.42, 0.33, 0.30]              # node 2 at 0.42: below t_milestone 0.6, margin 0.12
    loc = InitialLocaliser(IDS, 0.6, config, neighbourhoods=HOODS, t_floor=0.4, first_view=True)
    steps = _turn(loc, [view] * 3, rate=0.0)
    assert [s.action for s in steps] == [Action.NONE] * 3    # held still: no turn at all
    assert steps[-1].status is LocaliserStatus.LOCALISED and steps[-1].node == 2
    # a re-localisation (first_view False) turns instead
    loc = InitialLocaliser(IDS, 0.6, config, neighbourhoods=HOODS, t_floor=0.4)
    assert loc.tick(np.asarray(view), 0.0).action is Action.SEARCH_ROTATE
    # below the floor minus the slack, or ambiguous, the first view does not count
    loc = InitialLocaliser(IDS, 0.6, config, neighbourhoods=HOODS, t_floor=0.5, first_view=True)
    assert loc.tick(np.asarray(view), 0.0).action is Action.SEARCH_ROTATE
    loc = InitialLocaliser(IDS, 0.6, config, neighbourhoods=HOODS, t_floor=0.4, first_view=True)
    assert loc.tick(np.asarray([0.20, 0.30, 0.42, 0.33, 0.40]), 0.0).action is Action.SEARCH_ROTATE
    # once the robot has turned, the same view needs t_milestone again (or a second look)
    assert loc.tick(np.asarray(view), 0.2).action is Action.SEARCH_ROTATE


def test_first_view_only_places_the_robot_where_the_goal_can_be_reached():
    config = LocaliserConfig(confirm_ticks=2)
    view = [0.20, 0.30, 0.42, 0.33, 0.30]              # node 2, unambiguous, below t_milestone
    loc = InitialLocaliser(IDS, 0.6, config, neighbourhoods=HOODS, t_floor=0.4, first_view=True,
                           first_view_nodes=frozenset({0, 1}))
    assert loc.tick(np.asarray(view), 0.0).action is Action.SEARCH_ROTATE
    loc = InitialLocaliser(IDS, 0.6, config, neighbourhoods=HOODS, t_floor=0.4, first_view=True,
                           first_view_nodes=frozenset({1, 2}))
    assert _turn(loc, [view] * 2, rate=0.0)[-1].node == 2

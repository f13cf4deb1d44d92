"""The action choosers: the voter with its weak vote and patience, steering by bearing, and a
learned policy."""

import pytest

from controllers.actions import Action
from dataclasses import replace

from controllers.choosers import BearingChooser, ChooserInputError, PolicyChooser, TargetView, VoterChooser
from controllers.config import BearingConfig, NavigationConfig
from controllers.voter import ThirdScores, VoteKind


def _view(left, middle, right, policy=None, target=7, bearing=None):
    scores = ThirdScores(left, middle, right)
    return TargetView(target, lambda: scores, lambda: None, policy, lambda: bearing)


SEEN = (0.2, 0.9, 0.3)          # the middle third sees the target
UNSEEN = (0.1, 0.2, 0.3)        # no third passes 0.5; the right one is best


def test_the_voter_votes_in_pairs_and_sees_the_target():
    chooser = VoterChooser(0.5, hold_executed=False, blind_forward_ticks=0, patience_ticks=3)
    first, second = chooser.choose(_view(*SEEN)), chooser.choose(_view(*SEEN))
    assert first.vote.kind is VoteKind.STORED and first.action is Action.NONE and first.sees_target
    assert second.vote.kind is VoteKind.EXECUTED and second.action is Action.FORWARD
    assert not second.lost_sight and second.unseen_ticks == 0 and second.thirds == ThirdScores(*SEEN)


def test_weak_votes_follow_the_best_third_then_patience_runs_out():
    chooser = VoterChooser(0.5, blind_forward_ticks=2, patience_ticks=3)
    choices = [chooser.choose(_view(*UNSEEN)) for _ in range(6)]
    assert [c.action for c in choices[:2]] == [Action.RIGHT, Action.RIGHT]
    assert all("weak vote" in c.reason for c in choices[:2])
    assert [c.action for c in choices[2:]] == [Action.NONE] * 4
    assert [c.lost_sight for c in choices] == [False] * 4 + [True] * 2      # after 2 + 3 ticks
    assert [c.unseen_ticks for c in choices] == [1, 2, 3, 4, 5, 6]
    assert not any(c.sees_target for c in choices)
    chooser.reset()                       # a new target: a fresh count, and weak votes again
    again = chooser.choose(_view(*UNSEEN))
    assert again.unseen_ticks == 1 and again.action is Action.RIGHT and not again.lost_sight


def test_a_vote_ends_the_unseen_run():
    chooser = VoterChooser(0.5, blind_forward_ticks=0, patience_ticks=2)
    chooser.choose(_view(*UNSEEN))
    assert chooser.choose(_view(*SEEN)).unseen_ticks == 0
    assert not chooser.choose(_view(*UNSEEN)).lost_sight


def test_the_voter_of_a_configuration():
    config = NavigationConfig(blind_forward_ticks=4, no_vote_patience_ticks=9)
    chooser = VoterChooser.from_config(config)
    assert (chooser.blind_forward_ticks, chooser.patience_ticks) == (4, 9)
    assert chooser.voter.t_limited_control == config.thresholds.t_limited_control
    assert chooser.uses_turn_hints and not PolicyChooser.uses_turn_hints


def test_a_policy_chooser_asks_the_policy_about_the_target():
    asked = []
    choice = PolicyChooser().choose(_view(*UNSEEN, policy=lambda node: asked.append(node) or Action.LEFT))
    assert choice.action is Action.LEFT and asked == [7] and choice.sees_target and not choice.lost_sight
    assert choice.thirds is None and choice.vote is None
    with pytest.raises(ChooserInputError, match="pass this frame's policy"):
        PolicyChooser().choose(_view(*SEEN))
    with pytest.raises(ChooserInputError, match="returned"):
        PolicyChooser().choose(_view(*SEEN, policy=lambda node: Action.SEARCH_ROTATE))


@pytest.mark.parametrize("bearing, action", [(0.0, Action.FORWARD), (0.03, Action.FORWARD),
                                             (0.1, Action.FORWARD_LEFT), (-0.1, Action.FORWARD_RIGHT),
                                             (0.3, Action.LEFT), (-0.3, Action.RIGHT)])
def test_steering_by_bearing_turns_towards_where_the_targets_view_lies(bearing, action):
    chooser = BearingChooser(VoterChooser(0.5, hold_executed=False, blind_forward_ticks=2), deadband=0.04, turn=0.25)
    # the thirds say "forward" (the middle third sees it); the bearing decides, on every tick seen
    choices = [chooser.choose(_view(*SEEN, bearing=bearing)) for _ in range(2)]
    assert [c.action for c in choices] == [action, action] and all(c.sees_target for c in choices)
    assert "of the view's width" in choices[0].reason and choices[1].vote.kind is VoteKind.EXECUTED


def test_steering_by_bearing_leaves_the_voter_where_the_target_is_not_seen_or_has_no_bearing():
    chooser = BearingChooser(VoterChooser(0.5, blind_forward_ticks=2, patience_ticks=1), deadband=0.04, turn=0.25)
    weak = [chooser.choose(_view(*UNSEEN, bearing=0.3)) for _ in range(3)]
    assert [c.action for c in weak[:2]] == [Action.RIGHT, Action.RIGHT] and weak[2].lost_sight
    chooser.reset()
    plain = chooser.choose(_view(*SEEN))
    assert plain.action is VoterChooser(0.5, blind_forward_ticks=2).choose(_view(*SEEN)).action
    assert "view's width" not in plain.reason


def test_the_chooser_of_a_configuration_with_bearing():
    from controllers.navigator import Navigator
    from tests.synthetic_places import chain

    graph, _ = chain(3)
    on = NavigationConfig(bearing=BearingConfig(enabled=True, deadband=0.05, turn=0.3))
    nav = Navigator(graph, (0, 1, 2), 2, on)
    assert isinstance(nav.chooser, BearingChooser) and nav.chooser.turn == 0.3
    assert isinstance(Navigator(graph, (0, 1, 2), 2, NavigationConfig()).chooser, BearingChooser)   # the default
    off = NavigationConfig(bearing=BearingConfig(enabled=False))
    assert type(Navigator(graph, (0, 1, 2), 2, off).chooser) is VoterChooser
    assert on.as_published().bearing.enabled is False
    for bad in ({"deadband": -0.1}, {"turn": 0.01}, {"enabled": "yes"}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            replace(BearingConfig(), **bad)

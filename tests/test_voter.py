"""The paper's two-cycle Left / Middle / Right voter, case by case."""

import itertools

import numpy as np
import pytest

from controllers.actions import Action
from controllers.voter import Third, ThirdScores, TwoCycleVoter, VoteKind, combine_votes

T = 0.35  # t_limited_control used throughout

# one clear winner per third, all above T
VOTES = {
    Third.LEFT: (0.62, 0.41, 0.20),
    Third.MIDDLE: (0.40, 0.66, 0.38),
    Third.RIGHT: (0.18, 0.44, 0.70),
}
BELOW = (0.30, 0.34, 0.12)  # best is Middle at 0.34, not above T

EXPECTED = {
    (Third.LEFT, Third.LEFT): Action.LEFT,
    (Third.MIDDLE, Third.MIDDLE): Action.FORWARD,
    (Third.RIGHT, Third.RIGHT): Action.RIGHT,
    (Third.MIDDLE, Third.LEFT): Action.FORWARD_LEFT,
    (Third.LEFT, Third.MIDDLE): Action.FORWARD_LEFT,
    (Third.MIDDLE, Third.RIGHT): Action.FORWARD_RIGHT,
    (Third.RIGHT, Third.MIDDLE): Action.FORWARD_RIGHT,
    (Third.LEFT, Third.RIGHT): Action.NONE,
    (Third.RIGHT, Third.LEFT): Action.NONE,
}


def test_expected_table_covers_every_pair():
    assert set(EXPECTED) == set(itertools.product(Third, Third))


@pytest.mark.parametrize("first,second", sorted(EXPECTED, key=lambda p: (p[0].value, p[1].value)))
def test_every_pair_of_cycles(first, second):
    voter = TwoCycleVoter(T, hold_executed=False)
    stored = voter.tick(VOTES[first])
    assert stored.kind is VoteKind.STORED
    assert stored.vote is first
    assert stored.action is Action.NONE            # storing executes nothing
    assert voter.stored is first
    result = voter.tick(VOTES[second])
    assert result.action is EXPECTED[(first, second)]
    assert result.stored is first and result.vote is second
    expected_kind = VoteKind.CONFLICT if EXPECTED[(first, second)] is Action.NONE else VoteKind.EXECUTED
    assert result.kind is expected_kind
    assert voter.stored is None                     # the pair is over
    assert combine_votes(first, second) is EXPECTED[(first, second)]


def test_left_right_conflict_does_nothing_and_holds_nothing():
    voter = TwoCycleVoter(T, hold_executed=True)
    voter.tick(VOTES[Third.MIDDLE])
    assert voter.tick(VOTES[Third.MIDDLE]).action is Action.FORWARD
    assert voter.tick(VOTES[Third.LEFT]).action is Action.FORWARD   # held through the store
    conflict = voter.tick(VOTES[Third.RIGHT])
    assert conflict.kind is VoteKind.CONFLICT and conflict.action is Action.NONE
    # after a conflict there is nothing to hold: the next storing tick stands still
    assert voter.tick(VOTES[Third.LEFT]).action is Action.NONE


def test_below_threshold_yields_no_vote():
    voter = TwoCycleVoter(T)
    result = voter.tick(BELOW)
    assert result.kind is VoteKind.NO_VOTE
    assert result.action is Action.NONE
    assert result.vote is None
    assert result.best_score == pytest.approx(0.34)
    assert voter.stored is None


def test_threshold_must_be_exceeded_not_met():
    voter = TwoCycleVoter(T)
    assert voter.tick((0.1, T, 0.1)).kind is VoteKind.NO_VOTE
    assert voter.tick((0.1, T + 1e-6, 0.1)).kind is VoteKind.STORED


def test_no_vote_drops_the_stored_vote():
    voter = TwoCycleVoter(T, hold_executed=False)
    voter.tick(VOTES[Third.LEFT])
    dropped = voter.tick(BELOW)
    assert dropped.kind is VoteKind.NO_VOTE and dropped.stored is Third.LEFT
    assert voter.stored is None
    # the Left stored before the gap must not pair with this Left: this one is a new store
    again = voter.tick(VOTES[Third.LEFT])
    assert again.kind is VoteKind.STORED and again.action is Action.NONE
    assert voter.tick(VOTES[Third.LEFT]).action is Action.LEFT


def test_cycle_resets_after_execution():
    voter = TwoCycleVoter(T, hold_executed=False)
    kinds = [voter.tick(VOTES[Third.LEFT]).kind for _ in range(5)]
    # non-overlapping pairs: store, execute, store, execute, store
    assert kinds == [VoteKind.STORED, VoteKind.EXECUTED, VoteKind.STORED, VoteKind.EXECUTED,
                     VoteKind.STORED]
    voter = TwoCycleVoter(T, hold_executed=False)
    voter.tick(VOTES[Third.LEFT])
    assert voter.tick(VOTES[Third.LEFT]).action is Action.LEFT
    # a single Right after the executed pair is only stored, never combined with the old Left
    after = voter.tick(VOTES[Third.RIGHT])
    assert after.kind is VoteKind.STORED and after.stored is None and after.action is Action.NONE
    assert voter.tick(VOTES[Third.RIGHT]).action is Action.RIGHT


def test_hold_keeps_the_executed_action_through_the_storing_tick():
    voter = TwoCycleVoter(T, hold_executed=True)
    assert voter.tick(VOTES[Third.MIDDLE]).action is Action.NONE      # nothing executed yet
    assert voter.tick(VOTES[Third.LEFT]).action is Action.FORWARD_LEFT
    held = voter.tick(VOTES[Third.RIGHT])
    assert held.kind is VoteKind.STORED and held.action is Action.FORWARD_LEFT
    assert voter.tick(VOTES[Third.RIGHT]).action is Action.RIGHT
    # a no-vote cycle cancels the hold
    assert voter.tick(BELOW).action is Action.NONE
    assert voter.tick(VOTES[Third.MIDDLE]).action is Action.NONE


def test_reset_forgets_stored_vote_and_hold():
    voter = TwoCycleVoter(T, hold_executed=True)
    voter.tick(VOTES[Third.RIGHT])
    voter.tick(VOTES[Third.RIGHT])
    voter.tick(VOTES[Third.LEFT])
    voter.reset()
    assert voter.stored is None
    first = voter.tick(VOTES[Third.LEFT])
    assert first.kind is VoteKind.STORED and first.action is Action.NONE


def test_ties_prefer_middle_then_left():
    assert ThirdScores(0.5, 0.5, 0.5).best() == (Third.MIDDLE, 0.5)
    assert ThirdScores(0.5, 0.4, 0.5).best() == (Third.LEFT, 0.5)
    assert ThirdScores(0.4, 0.4, 0.5).best() == (Third.RIGHT, 0.5)


@pytest.mark.parametrize("bad", [(0.1, float("nan"), 0.2), (0.1, 0.2), (0.1, 0.2, 0.3, 0.4)])
def test_bad_scores_are_rejected(bad):
    with pytest.raises(ValueError, match="third score|expected 3"):
        TwoCycleVoter(T).tick(bad)


def test_bad_threshold_is_rejected():
    with pytest.raises(ValueError, match="t_limited_control"):
        TwoCycleVoter(1.5)


def test_contrast_rescales_each_third_against_the_other_nodes():
    from controllers.voter import contrast_thirds
    scores = np.array([[0.30, 0.50, 0.20],    # node 0
                       [0.20, 0.30, 0.40],    # node 1
                       [0.10, 0.30, 0.20]])   # node 2
    c = contrast_thirds(scores)
    # per column: (s - median) / (max - median); the best node of each third gets 1
    assert c[0, 0] == pytest.approx(1.0) and c[1, 0] == pytest.approx(0.0) and c[2, 0] == pytest.approx(-1.0)
    assert c[0, 1] == pytest.approx(1.0) and c[1, 1] == pytest.approx(0.0)
    assert c[1, 2] == pytest.approx(1.0) and c[0, 2] == pytest.approx(0.0)
    # a global drop of every cosine (other lighting) leaves the contrast unchanged
    assert np.allclose(contrast_thirds(0.5 * scores - 0.05), c)
    # no spread: zeros, not a division by zero
    assert np.all(contrast_thirds(np.full((3, 3), 0.4)) == 0.0)
    with pytest.raises(ValueError, match="shape"):
        contrast_thirds(np.zeros((1, 3)))


def test_contrast_decides_the_vote_when_given():
    voter = TwoCycleVoter(0.5)
    # raw cosines all low (another lighting) but the middle third clearly sees the target
    raw, contrast = (0.20, 0.25, 0.22), (0.3, 0.9, 0.1)
    assert voter.tick(raw).kind is VoteKind.NO_VOTE                  # the paper's rule on cosines
    first = voter.tick(raw, contrast)
    second = voter.tick(raw, contrast)
    assert first.kind is VoteKind.STORED and first.vote is Third.MIDDLE
    assert second.action is Action.FORWARD
    assert first.scores == second.scores == ThirdScores(*contrast)    # recorded: what the vote was taken on
    assert voter.tick(raw).scores == ThirdScores(*raw)
    # a contrast below the threshold does not vote however high the cosine
    assert voter.tick((0.9, 0.9, 0.9), (0.2, 0.3, 0.1)).kind is VoteKind.NO_VOTE

"""The paper's two-cycle Left / Middle / Right action voter (local motion control).

Each tick the caller gives the similarities of the Left, Middle and Right vertical thirds of
the current image to the target node's descriptor. A third *votes* when it is the best of the
three and its score exceeds ``t_limited_control`` (ties go to Middle, then Left, so the robot
prefers going straight). Votes are taken in non-overlapping pairs of cycles:

* cycle 1 (storing): the vote is stored, nothing new is executed;
* cycle 2 (confirming): the stored vote and this vote decide, then the pair is over and the
  next tick is a storing cycle again:

  ===========================  ==========================
  votes (either order)          action
  ===========================  ==========================
  Left, Left                    LEFT
  Middle, Middle                FORWARD
  Right, Right                  RIGHT
  Middle and Left               FORWARD_LEFT
  Middle and Right              FORWARD_RIGHT
  Left and Right (conflict)     NONE (nothing is done)
  ===========================  ==========================

When no third exceeds the threshold the cycle yields **no vote**: the action is ``NONE`` and a
vote stored in the previous cycle is dropped (a pair needs two consecutive votes), so the next
tick starts a new pair. The navigator turns a run of no-vote ticks into a search rotation.

On a storing tick the output is the action executed by the previous pair when
``hold_executed`` is true (each decision lasts one two-tick vote period), else ``NONE``.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from controllers.actions import Action


class Third(enum.Enum):
    """A vertical third of the camera image."""

    LEFT = "left"
    MIDDLE = "middle"
    RIGHT = "right"


class VoteKind(enum.Enum):
    """What happened in one voter cycle."""

    STORED = "stored"        # first cycle of a pair: the vote was stored
    EXECUTED = "executed"    # second cycle: both votes combined into a moving action
    CONFLICT = "conflict"    # second cycle: Left against Right, nothing is done
    NO_VOTE = "no_vote"      # no third exceeded the threshold; any stored vote is dropped


@dataclass(frozen=True)
class ThirdScores:
    """Similarities of the Left, Middle and Right thirds to the target node (cosines)."""

    left: float
    middle: float
    right: float

    def __post_init__(self) -> None:
        for name in ("left", "middle", "right"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value)):
                raise ValueError(f"third score {name} must be a finite number, got {value!r}")

    @classmethod
    def of(cls, scores: "ThirdScores | Sequence[float]") -> "ThirdScores":
        """Accept a ThirdScores or any (left, middle, right) sequence of 3 numbers."""
        if isinstance(scores, ThirdScores):
            return scores
        values = [float(v) for v in scores]
        if len(values) != 3:
            raise ValueError(f"expected 3 third scores (left, middle, right), got {len(values)}")
        return cls(*values)

    def best(self) -> tuple[Third, float]:
        """The best third and its score; ties prefer Middle, then Left."""
        ranked = ((self.middle, 2, Third.MIDDLE), (self.left, 1, Third.LEFT),
                  (self.right, 0, Third.RIGHT))
        score, _, third = max(ranked)
        return third, score


@dataclass(frozen=True)
class VoteResult:
    """The voter's output for one tick."""

    action: Action                 # what to do this tick
    kind: VoteKind
    vote: Optional[Third]          # this cycle's vote (None: no third passed)
    stored: Optional[Third]        # the vote stored by the first cycle of the pair, if any
    best_score: float              # best third score this cycle
    reason: str
    #: the three scores the vote was taken on (the contrast when the voter was given one)
    scores: Optional[ThirdScores] = None


def contrast_thirds(scores: np.ndarray) -> np.ndarray:
    """Each third's similarity to every node, rescaled against the other nodes of the map.

    ``scores[j, k]`` is the cosine of third ``k`` (Left, Middle, Right) to node ``j``. Column by
    column, ``(s - median) / (max - median)``: 1 for the node this third resembles most, 0 for a
    typical (unrelated) node, negative below that. Why: a change of lighting or of a few props
    lowers every cosine of a view together (in the simulator a node's own view drops from ~0.9
    to ~0.5), so a fixed ``t_limited_control`` on raw cosines stops every vote exactly when the
    conditions differ from the mapping run; the contrast keeps the ranking and the relative gap,
    which is what "this third sees the target" means. It also removes the bias of a third that
    scores high against everything (a bland wall). Needs at least two nodes; a column with no
    spread (max == median) is all zeros.
    """
    s = np.asarray(scores, dtype=float)
    if s.ndim != 2 or s.shape[1] != 3 or s.shape[0] < 2:
        raise ValueError(f"expected thirds scores of shape (nodes >= 2, 3), got {s.shape}")
    median = np.median(s, axis=0)
    spread = s.max(axis=0) - median
    safe = np.where(spread > 1e-9, spread, 1.0)
    return np.where(spread > 1e-9, (s - median) / safe, 0.0)


_AGREE = {Third.LEFT: Action.LEFT, Third.MIDDLE: Action.FORWARD, Third.RIGHT: Action.RIGHT}


def combine_votes(first: Third, second: Third) -> Action:
    """The paper's rule for a pair of votes (order does not matter)."""
    if first is second:
        return _AGREE[first]
    pair = {first, second}
    if pair == {Third.MIDDLE, Third.LEFT}:
        return Action.FORWARD_LEFT
    if pair == {Third.MIDDLE, Third.RIGHT}:
        return Action.FORWARD_RIGHT
    return Action.NONE  # Left against Right


class TwoCycleVoter:
    """Tick-based two-cycle voter. Call :meth:`reset` when the target node changes."""

    def __init__(self, t_limited_control: float, hold_executed: bool = True):
        if not (math.isfinite(t_limited_control) and -1.0 <= t_limited_control <= 1.0):
            raise ValueError(f"t_limited_control must be in [-1, 1], got {t_limited_control!r}")
        self.t_limited_control = float(t_limited_control)
        self.hold_executed = bool(hold_executed)
        self._stored: Optional[Third] = None
        self._held = Action.NONE

    @property
    def stored(self) -> Optional[Third]:
        """The vote waiting for its confirming cycle, if any."""
        return self._stored

    def reset(self) -> None:
        """Forget the stored vote and the held action (new target, search, re-localisation)."""
        self._stored = None
        self._held = Action.NONE

    def tick(self, scores: "ThirdScores | Sequence[float]",
             contrast: "ThirdScores | Sequence[float] | None" = None) -> VoteResult:
        """One cycle: vote from ``scores`` (left, middle, right) and return the action.

        Without ``contrast`` this is the paper's rule on cosines: the third with the highest
        similarity to the target votes when it exceeds ``t_limited_control``. With ``contrast``
        (the thirds' :func:`contrast_thirds` values for the target) the same rule runs on the
        contrast instead, which survives lighting changes and removes each third's own bias
        (a bland third that resembles everything); ``scores`` are then kept for the record only.
        """
        scores = ThirdScores.of(scores)
        if contrast is not None:
            scores = ThirdScores.of(contrast)
        third, best = scores.best()
        vote = third if best > self.t_limited_control else None
        stored = self._stored

        if vote is None:
            self._stored = None
            self._held = Action.NONE
            dropped = f"; dropped stored {stored.value}" if stored else ""
            return VoteResult(Action.NONE, VoteKind.NO_VOTE, None, stored, best,
                              f"best third {third.value} {best:.3f} <= t_limited_control "
                              f"{self.t_limited_control:.3f}{dropped}", scores)
        if stored is None:
            self._stored = vote
            action = self._held if self.hold_executed else Action.NONE
            return VoteResult(action, VoteKind.STORED, vote, None, best,
                              f"stored {vote.value} ({best:.3f}); holding {action.value}", scores)
        self._stored = None
        action = combine_votes(stored, vote)
        self._held = action
        kind = VoteKind.CONFLICT if action is Action.NONE else VoteKind.EXECUTED
        return VoteResult(action, kind, vote, stored, best,
                          f"{stored.value} then {vote.value} -> {action.value}", scores)

"""Action choosers: what picks the driving action towards the target node while the navigator
follows its plan.

The navigator (:mod:`controllers.navigator`) decides where the robot is and which node it heads
for; a chooser, given in its constructor, decides how to drive there this tick:

* :class:`VoterChooser`: the paper's two-cycle Left / Middle / Right voter
  (:class:`controllers.voter.TwoCycleVoter`), plus the weak vote (the first ticks without a vote
  follow the best third anyway) and the patience after which the navigator searches;
* :class:`BearingChooser`: the voter says whether the target is seen; while it is, the robot
  steers by the target view's bearing (the shift between the view's column profile and the
  target node's) instead of by the thirds;
* :class:`PolicyChooser`: a learned policy (the SPTM-style baseline's head), asked per tick
  through the view's ``policy``; it always sees its target, so it never searches, and it gets
  no corner turns.

A chooser is reset whenever its target changes or it missed ticks (a new plan, a node confirmed,
a corner turned, a re-localisation): the voter's pairs are per target.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Hashable, Optional, Protocol

from controllers.actions import Action
from controllers.voter import Third, ThirdScores, TwoCycleVoter, VoteKind, VoteResult

NodeId = Hashable

#: The action while no third passes t_limited_control (a weak vote, see VoterChooser).
_WEAK_ACTION = {Third.LEFT: Action.LEFT, Third.MIDDLE: Action.FORWARD, Third.RIGHT: Action.RIGHT}


class ChooserInputError(ValueError):
    """The tick's view lacks what the chooser needs (the navigator reports it as bad input)."""


@dataclass(frozen=True)
class TargetView:
    """What a chooser may look at this tick, towards ``target``. ``thirds()`` and ``contrast()``
    are lazy (the thirds are described only when a chooser asks); ``policy`` is this frame's
    learned policy, when the run loop has one. ``bearing()`` (lazy too) is where the target's
    view lies, as a fraction of the view's width, positive to the left (None: unknown)."""

    target: NodeId
    thirds: Callable[[], ThirdScores]
    contrast: Callable[[], Optional[ThirdScores]]
    policy: Optional[Callable[[NodeId], Action]] = None
    bearing: Callable[[], Optional[float]] = lambda: None


@dataclass(frozen=True)
class Choice:
    """A chooser's answer for one tick."""

    action: Action
    #: whether the view recognises the target this tick (a third voted; a policy always does)
    sees_target: bool
    #: the target has been out of sight long enough that the navigator should search for it
    lost_sight: bool
    reason: str
    thirds: Optional[ThirdScores] = None
    vote: Optional[VoteResult] = None
    #: consecutive ticks without a vote (0 for a policy)
    unseen_ticks: int = 0


class ActionChooser(Protocol):
    """What the navigator needs of a chooser."""

    #: the name the harness and the logs use ("voter", "bearing", "policy")
    name: str
    #: whether the navigator turns at corners by the map's odometry before this chooser steers
    #: (the voter's field of view misses a target beside it; a learned head does not need it)
    uses_turn_hints: bool

    def reset(self) -> None:
        """Forget what was gathered towards the old target."""

    def choose(self, view: TargetView) -> Choice:
        """The action towards ``view.target`` this tick."""


class VoterChooser:
    """The two-cycle voter (:class:`TwoCycleVoter`) with the weak vote and the search patience.

    ``blind_forward_ticks``: the first ticks without a vote follow the best third anyway (LEFT /
    FORWARD / RIGHT): between two nodes the walkthrough drove forward, so a target no third
    recognises yet is more likely ahead than behind. After ``blind_forward_ticks +
    patience_ticks`` ticks without a vote the target is out of sight (``lost_sight``).
    """

    name = "voter"
    uses_turn_hints = True

    def __init__(self, t_limited_control: float, hold_executed: bool = True, blind_forward_ticks: int = 0,
                 patience_ticks: int = 6):
        self.voter = TwoCycleVoter(t_limited_control, hold_executed=hold_executed)
        self.blind_forward_ticks = int(blind_forward_ticks)
        self.patience_ticks = int(patience_ticks)
        self._unseen = 0

    @classmethod
    def from_config(cls, config) -> "VoterChooser":
        """The voter a :class:`controllers.config.NavigationConfig` describes."""
        return cls(config.thresholds.t_limited_control, hold_executed=config.hold_action_between_votes,
                   blind_forward_ticks=config.blind_forward_ticks, patience_ticks=config.no_vote_patience_ticks)

    def reset(self) -> None:
        self.voter.reset()
        self._unseen = 0

    def choose(self, view: TargetView) -> Choice:
        scores = view.thirds()
        vote = self.voter.tick(scores, view.contrast())
        self._unseen = self._unseen + 1 if vote.kind is VoteKind.NO_VOTE else 0
        seen = vote.vote is not None
        blind = self.blind_forward_ticks
        if vote.kind is VoteKind.NO_VOTE and 0 < self._unseen <= blind:
            action = _WEAK_ACTION[scores.best()[0]]   # left and right creep forward (ActionSpeeds)
            return Choice(action, seen, False, f"{vote.reason}; {action.value} on a weak vote "
                          f"({self._unseen}/{blind})", scores, vote, self._unseen)
        lost = self._unseen >= blind + self.patience_ticks
        return Choice(vote.action, seen, lost, vote.reason, scores, vote, self._unseen)


class BearingChooser:
    """Steering by bearing (:class:`controllers.config.BearingConfig`): the voter
    (:class:`VoterChooser`) decides whether the target is seen and what to do when it is not;
    while a third votes, the action comes from ``view.bearing()`` instead: FORWARD within
    ``deadband`` of the view's width, FORWARD_LEFT / FORWARD_RIGHT beyond it, LEFT / RIGHT beyond
    ``turn``. A view without a bearing leaves the voter's action."""

    name = "bearing"
    uses_turn_hints = True

    def __init__(self, voter: VoterChooser, deadband: float, turn: float):
        self.voter = voter
        self.deadband = float(deadband)
        self.turn = float(turn)

    @classmethod
    def from_config(cls, config) -> "BearingChooser":
        """The chooser a :class:`controllers.config.NavigationConfig` with ``bearing`` describes."""
        return cls(VoterChooser.from_config(config), config.bearing.deadband, config.bearing.turn)

    def reset(self) -> None:
        self.voter.reset()

    def action_for(self, bearing: float) -> Action:
        """The action that turns the robot towards a view ``bearing`` (a fraction of the view's
        width, positive to the left)."""
        if abs(bearing) <= self.deadband:
            return Action.FORWARD
        if abs(bearing) > self.turn:
            return Action.LEFT if bearing > 0 else Action.RIGHT
        return Action.FORWARD_LEFT if bearing > 0 else Action.FORWARD_RIGHT

    def choose(self, view: TargetView) -> Choice:
        choice = self.voter.choose(view)
        if not choice.sees_target:
            return choice
        bearing = view.bearing()
        if bearing is None:
            return choice
        action = self.action_for(bearing)
        return replace(choice, action=action, reason=f"{choice.reason}; the target's view lies {bearing:+.2f} "
                                                       f"of the view's width: {action.value}")


#: actions a learned policy may not return: the navigator's own (search, backing off, retracing) and STOP
_NOT_DRIVING = (Action.STOP, Action.SEARCH_ROTATE, Action.BACKWARD, Action.RETRACE)


class PolicyChooser:
    """A learned policy picks the action: ``view.policy(target) -> Action`` (the run loop passes
    this frame's policy every tick). It never loses sight of its target."""

    name = "policy"
    uses_turn_hints = False

    def reset(self) -> None:
        pass

    def choose(self, view: TargetView) -> Choice:
        if view.policy is None:
            raise ChooserInputError("the navigator's chooser is a learned policy: pass this frame's policy "
                                    "every tick (policy=)")
        action = view.policy(view.target)
        if not isinstance(action, Action) or action in _NOT_DRIVING:
            raise ChooserInputError(f"the action policy returned {action!r} for node {view.target!r}; "
                                    "expected a driving Action")
        return Choice(action, True, False, f"policy: {action.value}")

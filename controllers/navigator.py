"""The navigator: localisation, planning, node switching and action voting in one tick.

The run loop only has to, every control period::

    row = node_descriptors @ view_descriptor              # similarity to every map node
    step = navigator.tick(row, thirds=thirds_fn, heading_rad=odometry.yaw_rad)
    base.apply(step.velocity)
    if step.finished: stop, and report step.state / step.reason

``thirds`` gives the Left / Middle / Right thirds' similarities to a node: either a callable
``thirds(node_id) -> (left, middle, right)`` (called at most once a tick, and only while
navigating, so the thirds are described only when needed) or an ``(N, 3)`` array over all
nodes in column order.

States (:class:`NavState`):

* LOCALISING: initial localisation; holds still to confirm a match, or turns
  counter-clockwise while nothing passes ``t_milestone``; FAILED after a full turn.
* (belief) with ``localiser.from_belief`` "initial" (or "always": re-localisations too), the
  belief over the map passed each tick places the robot instead: it holds still looking for
  ``localiser.belief_hold_ticks``, then turns counter-clockwise, until the belief's mode holds
  ``belief.confidence`` of the mass and the robot faces along the route there; FAILED after
  ``localiser.max_search_ticks``.
* NAVIGATING: following the planned path; the action chooser given to the constructor
  (:mod:`controllers.choosers`) picks the actions: the two-cycle voter by default (with its weak
  vote: the first ticks without a vote follow the best third), the voter steering by the
  target's bearing instead of the thirds (``bearing``; ``bearings`` passed each tick), or a
  learned policy (the SPTM-style baseline: same localisation, planning and node switching, a classifier picks the
  action; it never searches and gets no corner turns).
* TURNING: the corner turn. With ``node_headings`` (the mapping drive's odometry heading per
  node) and ``heading_hints`` on, after a node is confirmed, when the drive turned from it to
  the target by at least ``heading_hint_min_deg``, the robot drives on to where that node's view
  is best (``heading_hint_approach_ticks``), then turns by that angle (LEFT / RIGHT on the
  odometry heading) before the voter steers again: at corners the target is beside the field
  of view. Also the heading guard's turn (``heading_guard``, :mod:`controllers.heading_guard`):
  facing more than ``max_error_deg`` from the target node's mapped heading (through the
  map-to-odometry offset measured at the nodes confirmed; with
  ``localiser.compass_bandwidth_deg`` the first look round's offset stands for the placement's
  and stays one vote of the median), the robot turns back to within ``release_deg`` before
  the voter steers again. With ``heading_guard.final_approach`` (off by default), in the final
  approach (the goal node confirmed, driving on until the goal is seen best) the guard holds the
  goal node's mapped heading instead of the votes: the state stays NAVIGATING.
* (driving on) while the supervisor drives on by odometry (``supervisor.odometry_max_m``: the
  views match no node near the plan), the voter's navigator drives forward along the target
  node's mapped heading (the heading guard's offsets), or straight on without them; the state
  stays NAVIGATING (a search ends).
* RECOVERING: stalled against a wall (``recovery``, off by default; the run loop's
  :class:`controllers.stall.StallMonitor` tells, passed as ``stalled``): backs straight off for
  ``recovery.backup_ticks``, then navigates on.
* SEARCHING: the voter has not seen the target for its patience; turns counter-clockwise in
  place until a third sees it (back to NAVIGATING), or re-localises after a full turn.
  With ``turn_room`` (on by default) this turn, and that of RELOCALISING, starts after driving
  the way just come backwards (RETRACE: the last ``turn_room.retrace_ticks`` commands negated,
  newest first, back to the last turn in place): a robot that lost its way has usually driven
  up to a wall, and turning there sweeps its corners across it.
* RELOCALISING: the supervisor reported the robot lost; localisation as in LOCALISING, but
  only nodes from which the goal is reachable count, and the stretch of the old plan around
  the last node is accepted as the best of the map above ``t_lost`` (other nodes need
  ``t_milestone``); then a new plan from the node found (``relocalisations``). The search is
  local first: only nodes within ``localiser.relocalise_hops`` arcs of the anchor (the last node
  confirmed by driving, or the initial localisation) count, and only when a full turn finds
  nothing there does it go on over the whole map (then without the lower threshold for the
  plan's stretch). With ``node_headings``, a node of the local search counts only while the
  robot faces (by odometry) the way the mapping drive faced there, to within
  ``localiser.relocalise_heading_tolerance_deg``: the map-to-odometry heading offset is the
  median of those at the last ``localiser.relocalise_heading_confirmations`` confirmations (1:
  the anchor's alone); a first look round's (``localiser.compass_bandwidth_deg``) stays one of
  them (1: it alone).
* ARRIVED (final): the goal node was confirmed above ``t_milestone``; velocity zero. With a
  goal image (``goal_score`` passed to :meth:`Navigator.tick`) and
  ``supervisor.goal_image_arrival``, the settle after the goal node's confirmation stops
  where the view's similarity to the goal image itself peaked above ``t_milestone``.
* FAILED (final): cannot place itself, goal unreachable, or too many re-localisations;
  ``reason`` says which; velocity zero.

Transitions (:data:`TRANSITIONS`; the navigator refuses any other):

    ============  ===================================================  ============
    from          when                                                 to
    ============  ===================================================  ============
    LOCALISING    a node matched (or the belief settled) and a plan    NAVIGATING
    LOCALISING    nothing matched in a full turn, or no plan           FAILED
    NAVIGATING    a node confirmed where the map turns, or facing      TURNING
                  too far from the route (the heading guard)
    NAVIGATING    the chooser lost sight of the target                 SEARCHING
    NAVIGATING    stalled: turns commanded, the gyro saw none          RECOVERING
    NAVIGATING    the supervisor reports the robot lost                RELOCALISING
    NAVIGATING    the goal reached                                     ARRIVED
    NAVIGATING    lost once more than ``max_relocalisations``          FAILED
    TURNING       facing the map's heading (or no heading), a node     NAVIGATING
                  confirmed, or the guard's error within release_deg
    TURNING       stalled: turns commanded, the gyro saw none          RECOVERING
    TURNING       the supervisor reports the robot lost                RELOCALISING
    TURNING       the goal reached                                     ARRIVED
    TURNING       lost once more than ``max_relocalisations``          FAILED
    SEARCHING     a third sees the target, a node confirmed, or        NAVIGATING
                  driving on by odometry
    SEARCHING     stalled: turns commanded, the gyro saw none          RECOVERING
    SEARCHING     a full turn without it, or the supervisor's LOST     RELOCALISING
    SEARCHING     the goal reached                                     ARRIVED
    SEARCHING     lost once more than ``max_relocalisations``          FAILED
    RECOVERING    backed off for ``backup_ticks``                      NAVIGATING
    RECOVERING    the supervisor reports the robot lost                RELOCALISING
    RECOVERING    the goal reached                                     ARRIVED
    RECOVERING    lost once more than ``max_relocalisations``          FAILED
    RELOCALISING  a node matched (or the belief settled) and a plan    NAVIGATING
    RELOCALISING  nothing matched in a full turn, or no plan           FAILED
    ============  ===================================================  ============

Entry actions (one place: ``Navigator._enter``): LOCALISING and RELOCALISING start a new
localiser and a new turn of the search (RELOCALISING also counts the re-localisation, resets
the chooser, drops the plan's supervisor and the corner turn, and takes the way back to retrace);
NAVIGATING ends the turn of a search; SEARCHING starts one and takes the way back to retrace;
RECOVERING counts the recovery and starts the backing's count; TURNING none (every other state
ends a turn back of the heading guard); ARRIVED and FAILED keep their step as the final one
(velocity zero). The chooser is reset whenever its target changes or it missed ticks: a new
plan, a node confirmed, a turn ended, a wall backed off.
"""

from __future__ import annotations

import collections
import enum
import math
from dataclasses import dataclass
from typing import Callable, Hashable, Mapping, Optional, Sequence, Tuple, Union

import networkx as nx
import numpy as np

from controllers.actions import Action, action_velocity
from controllers.belief import BeliefSnapshot
from controllers.choosers import (ActionChooser, BearingChooser, ChooserInputError, PolicyChooser, TargetView,
                                  VoterChooser)
from controllers.compass import LookCompass
from controllers.config import NavigationConfig
from controllers.heading_guard import HeadingGuard, median_offset, offset_votes
from controllers.localisation import (
    InitialLocaliser,
    Localisation,
    LocalisationError,
    LocaliserStatus,
    TurnMeter,
    localise_goal_image,
    plain_node_ids,
    similarity_row,
)
from controllers.planner import GlobalPlanner, PlanningError
from controllers.similarity_filter import SimilarityFilter
from controllers.supervisor import NodeSwitchSupervisor, SupervisorDecision, SupervisorState
from controllers.voter import ThirdScores, VoteResult
from core.angles import wrap_angle
from core.hal import VelocityCommand

NodeId = Hashable
ThirdsInput = Union[Callable[[NodeId], Sequence[float]], np.ndarray, None]
#: A learned action policy for this tick: target node -> action (see the module docstring).
PolicyInput = Optional[Callable[[NodeId], "Action"]]


class NavigationInputError(ValueError):
    """The run loop passed something the navigator cannot use (wrong shapes, no thirds)."""


class NavState(enum.Enum):
    LOCALISING = "localising"
    SEARCHING = "searching"
    NAVIGATING = "navigating"
    TURNING = "turning"
    RECOVERING = "recovering"
    RELOCALISING = "relocalising"
    ARRIVED = "arrived"
    FAILED = "failed"


@dataclass(frozen=True)
class NavigationStep:
    """Everything the navigator decided in one tick (for the run loop, logs and overlays)."""

    tick: int                                  # 1 for the first tick
    state: NavState
    action: Action
    velocity: VelocityCommand                  # apply this to the base
    goal_node: NodeId
    planned_path: Tuple[NodeId, ...]           # the current plan (empty before localisation)
    path_index: Optional[int]                  # position of current_node on the plan
    current_node: Optional[NodeId]             # last confirmed / localised node
    target_node: Optional[NodeId]              # node the voter steers towards
    current_score: Optional[float]             # filtered similarity to current_node
    target_score: Optional[float]              # filtered similarity to target_node
    thirds: Optional[ThirdScores]              # thirds' scores against target_node this tick
    vote: Optional[VoteResult]
    supervisor: Optional[SupervisorDecision]
    visited_nodes: Tuple[NodeId, ...]          # localised / confirmed nodes, in order
    relocalisations: int                       # global re-localisations so far
    replans: int                               # plans made after the first one
    turned_rad: float                          # rotation of the current search (0 when none)
    reason: str

    @property
    def finished(self) -> bool:
        return self.state in (NavState.ARRIVED, NavState.FAILED)


#: a confirmation this close to the newest heading vote's pose (distance driven, heading) stood
#: still since: its offset repeats that vote (less than a tick of driving; turned less than the
#: confirmations resolve a heading)
STILL_M = 0.02
STILL_RAD = math.radians(5.0)
#: how many ticks of the way just driven the navigator remembers (``turn_room``)
_BEHIND_TICKS = 200
#: the commands before which the way just driven does not lead back (``turn_room``)
_ENDS_THE_WAY_BACK = frozenset({Action.SEARCH_ROTATE, Action.RETRACE, Action.BACKWARD})
#: the states in which the robot drives its plan (where a stall is backed off)
DRIVING_STATES = frozenset({NavState.NAVIGATING, NavState.TURNING, NavState.SEARCHING})

_FINAL = frozenset({NavState.FAILED})
#: state -> the states it may go to (the module docstring's table)
TRANSITIONS: Mapping[NavState, frozenset] = {
    NavState.LOCALISING: frozenset({NavState.NAVIGATING}) | _FINAL,
    NavState.NAVIGATING: frozenset({NavState.TURNING, NavState.SEARCHING, NavState.RECOVERING, NavState.RELOCALISING,
                                    NavState.ARRIVED}) | _FINAL,
    NavState.TURNING: frozenset({NavState.NAVIGATING, NavState.RECOVERING, NavState.RELOCALISING,
                                 NavState.ARRIVED}) | _FINAL,
    NavState.SEARCHING: frozenset({NavState.NAVIGATING, NavState.RECOVERING, NavState.RELOCALISING,
                                   NavState.ARRIVED}) | _FINAL,
    NavState.RECOVERING: frozenset({NavState.NAVIGATING, NavState.RELOCALISING, NavState.ARRIVED}) | _FINAL,
    NavState.RELOCALISING: frozenset({NavState.NAVIGATING}) | _FINAL,
    NavState.ARRIVED: frozenset(),
    NavState.FAILED: frozenset(),
}


class Navigator:
    """Tick-based navigation from wherever the robot is to ``goal_node`` of the map.

    ``graph`` is the map's directed graph (arc attribute ``weight``), ``node_ids[j]`` the node
    of column ``j`` of every similarity row (every graph node needs a column). ``chooser``: what
    picks the actions while navigating (default: the two-cycle voter of ``config``,
    :class:`controllers.choosers.VoterChooser`; :class:`controllers.choosers.PolicyChooser` for a
    learned policy passed to every :meth:`tick`). ``arc_lengths_m[(src, dst)]``: the arcs' mapped
    lengths, for driving on by odometry (``supervisor.odometry_max_m``).
    """

    def __init__(self, graph: nx.DiGraph, node_ids: Sequence[NodeId], goal_node: NodeId,
                 config: NavigationConfig = NavigationConfig(),
                 node_headings: Optional[Mapping[NodeId, float]] = None,
                 chooser: Optional[ActionChooser] = None,
                 arc_lengths_m: Optional[Mapping[tuple, float]] = None):
        self.planner = GlobalPlanner(graph)
        self.node_ids = plain_node_ids(node_ids)
        if len(set(self.node_ids)) != len(self.node_ids):
            raise NavigationInputError("node_ids must not repeat a node")
        columns = set(self.node_ids)
        without_column = [n for n in graph.nodes if n not in columns]
        if without_column:
            raise NavigationInputError(f"map node {without_column[0]!r} has no column in the "
                                       "similarity rows (node_ids)")
        not_in_graph = [n for n in self.node_ids if n not in graph]
        if not_in_graph:
            raise NavigationInputError(f"node_ids names node {not_in_graph[0]!r}, which is not a "
                                       "node of the map graph")
        goal_node = plain_node_ids([goal_node])[0]
        self.planner.check_node(goal_node, "goal node")
        self.goal_node = goal_node
        self.config = config
        self._column = {node: j for j, node in enumerate(self.node_ids)}
        self.filter = SimilarityFilter(len(self.node_ids), config.filter)
        if chooser is None:
            chooser = BearingChooser.from_config(config) if config.bearing.enabled else VoterChooser.from_config(config)
        self.chooser: ActionChooser = chooser
        undirected = self._undirected = graph.to_undirected(as_view=True)
        hops = config.localiser.neighbourhood_hops
        self._neighbourhoods = {n: frozenset(nx.single_source_shortest_path_length(undirected, n, cutoff=hops))
                                for n in self.node_ids}
        self._goal_reachers = frozenset(nx.ancestors(graph, goal_node) | {goal_node})
        self._state = NavState.LOCALISING
        self._localiser = self._new_localiser()
        self._search: Optional[TurnMeter] = TurnMeter()    # the turn of the current search
        self._search_ticks = 0
        self._supervisor: Optional[NodeSwitchSupervisor] = None
        self._plan: Tuple[NodeId, ...] = ()
        self._visited: list = []
        self._ticks = 0
        self._relocalisations = 0
        self._plans = 0
        self._final: Optional[NavigationStep] = None
        self._planning_error: Optional[PlanningError] = None
        self._contrast: Optional[np.ndarray] = None
        self._bearings: Optional[Callable[[NodeId], Optional[float]]] = None   # this tick's (bearing chooser)
        reaching = self._goal_reachers
        self._reaches_goal = np.array([n in reaching for n in self.node_ids])
        self._headings: Optional[dict] = None
        if node_headings is not None:
            headings = {n: node_headings.get(n) for n in self.node_ids}
            bad = [n for n, h in headings.items() if h is None or not math.isfinite(float(h))]
            if bad:
                raise NavigationInputError(f"node_headings has no finite heading for node {bad[0]!r}")
            self._headings = {n: float(h) for n, h in headings.items()}
        self._heading_of_column = (None if self._headings is None else
                                   np.array([self._headings[n] for n in self.node_ids]))
        self._anchor: Optional[NodeId] = None     # last node confirmed by driving (or the first localisation)
        self._local: Optional[np.ndarray] = None  # columns a local re-localisation may choose, or None (global)
        # odometry heading minus the map's at the last confirmations (the first localisation and
        # nodes confirmed by driving), newest last: the heading gate's map-to-odometry offset
        self._offsets: collections.deque = collections.deque(
            maxlen=max(self.config.localiser.relocalise_heading_confirmations, self.config.heading_guard.confirmations))
        # where the newest offset was measured: (distance driven, odometry heading); None: unknown
        self._vote_pose: Optional[tuple] = None
        self._travelled_m: Optional[float] = None   # the distance driven at this tick (for the vote)
        self._guard = None if self._headings is None else HeadingGuard(self.config.heading_guard, self._headings)
        bandwidth = self.config.localiser.compass_bandwidth_deg
        # the first look round's views, for the heading offset (``localiser.compass_bandwidth_deg``)
        self._compass = (LookCompass(math.radians(bandwidth)) if self._headings is not None and bandwidth > 0
                         else None)
        self._look_offset: Optional[float] = None   # the look's offset: one vote for the episode
        self._hint: Optional[tuple] = None        # (confirmed node, odometry heading then)
        self._hint_done: Optional[tuple] = None   # the (node, target) pair already turned for
        # the corner node's view on the way to it: [best filtered score, ticks, ticks since the best]
        self._corner_view = [-math.inf, 0, 0]
        self._turned_towards: Optional[NodeId] = None   # the target of the last corner turn made
        self._belief: Optional[BeliefSnapshot] = None   # this tick's belief over the map, if given
        self._arcs = None if arc_lengths_m is None else dict(arc_lengths_m)
        self._backing = 0                         # ticks backed off in this recovery
        self._recoveries = 0
        # the way just driven, newest last: (action, velocity commanded); and the commands left
        # to drive backwards before a turn in place, next first
        self._behind: collections.deque = collections.deque(maxlen=_BEHIND_TICKS)
        self._retrace: list = []

    @classmethod
    def to_goal_image(cls, graph: nx.DiGraph, node_ids: Sequence[NodeId],
                      goal_similarities: np.ndarray,
                      config: NavigationConfig = NavigationConfig()) -> "Navigator":
        """A navigator to the node the goal image matches; raises
        :class:`controllers.localisation.GoalNotLocalisedError` when it matches none."""
        goal = cls.locate_goal_image(node_ids, goal_similarities, config)
        return cls(graph, node_ids, goal.node, config)

    @staticmethod
    def locate_goal_image(node_ids: Sequence[NodeId], goal_similarities: np.ndarray,
                          config: NavigationConfig = NavigationConfig()) -> Localisation:
        """The goal image's node above ``t_milestone`` (raises GoalNotLocalisedError)."""
        return localise_goal_image(goal_similarities, node_ids, config.thresholds.t_milestone)

    @property
    def state(self) -> NavState:
        return self._state

    @property
    def planned_path(self) -> Tuple[NodeId, ...]:
        return self._plan

    @property
    def visited_nodes(self) -> Tuple[NodeId, ...]:
        return tuple(self._visited)

    @property
    def planning_error(self) -> Optional[PlanningError]:
        """The planner's exception when the navigator FAILED because no plan exists (e.g.
        :class:`controllers.planner.UnreachableGoalError` naming both nodes), so a run loop can
        re-raise it as a specific error; None otherwise."""
        return self._planning_error

    def tick(self, similarities: np.ndarray, thirds: ThirdsInput = None,
             heading_rad: Optional[float] = None,
             thirds_contrast: Optional[np.ndarray] = None, policy: PolicyInput = None,
             belief: Optional[BeliefSnapshot] = None,
             goal_score: Optional[float] = None, stalled: bool = False,
             travelled_m: Optional[float] = None,
             bearings: Optional[Callable[[NodeId], Optional[float]]] = None) -> NavigationStep:
        """One control tick.

        ``similarities``: the current full view's cosine similarity to every node (column order
        ``node_ids``); ``thirds``: see the module docstring; ``heading_rad``: the yaw from
        odometry or the IMU in radians (any fixed frame, may wrap; only differences are used),
        or None when the base has neither. ``thirds_contrast``: optional ``(N, 3)`` contrast of
        the thirds against all nodes (:func:`controllers.voter.contrast_thirds`); when given, a
        third votes when its contrast, not its cosine, exceeds ``t_limited_control``.
        ``policy``: ``policy(target_node) -> Action`` for this tick's view, which a
        :class:`controllers.choosers.PolicyChooser` asks (a learned baseline; ``thirds`` are not
        needed then).
        ``belief``: the belief over the map after this view (:meth:`controllers.belief.NodeBelief.snapshot`),
        which places the robot when ``localiser.from_belief`` asks for it. ``goal_score``: the
        view's cosine similarity to the goal image, when the goal is an image: the final approach
        stops where the view matches it best (``supervisor.goal_image_arrival``). ``stalled``: the
        robot is pressed against a wall (:class:`controllers.stall.StallMonitor`); with
        ``recovery.enabled`` it backs off. ``travelled_m``: the distance the odometry has driven so
        far (metres along the robot's heading, less when reversing), for driving on by odometry
        where the views match nothing (``supervisor.odometry_max_m``). ``bearings``: ``bearings(node)``
        is where that node's view lies in this view, as a fraction of its width, positive to the
        left (None: unknown), for a :class:`controllers.choosers.BearingChooser`.
        """
        try:
            row = similarity_row(similarities, len(self.node_ids), "similarities")
        except LocalisationError as exc:
            raise NavigationInputError(str(exc)) from None
        if self._final is not None:
            return self._final
        if policy is not None and not isinstance(self.chooser, PolicyChooser):
            raise NavigationInputError(f"a policy was passed, but this navigator's actions come from its "
                                       f"{self.chooser.name}: build it with chooser=PolicyChooser()")
        self._ticks += 1
        self._belief = belief
        self._travelled_m = travelled_m
        if self._state in (NavState.LOCALISING, NavState.RELOCALISING):
            return self._localise_tick(row, heading_rad)
        self._contrast, self._bearings = thirds_contrast, bearings
        return self._navigate_tick(row, thirds, heading_rad, policy, goal_score, stalled, travelled_m)

    # -- states ---------------------------------------------------------------------------

    def _enter(self, state: NavState, heading_rad: Optional[float] = None,
               expected: Sequence[NodeId] = ()) -> None:
        """Go to ``state`` (one of :data:`TRANSITIONS` from the current one) and run its entry
        action; ``heading_rad`` starts a search's turn, ``expected`` is a re-localisation's plan
        stretch."""
        if state not in TRANSITIONS[self._state]:
            raise RuntimeError(f"navigator: no transition from {self._state.name} to {state.name}")
        self._state = state
        if self._guard is not None and state is not NavState.TURNING:
            self._guard.reset()
        if state is NavState.NAVIGATING:
            self._search = None
        elif state is NavState.SEARCHING:
            self._search, self._search_ticks = TurnMeter(), 0
            self._search.update(heading_rad)
            self._retrace = self._way_back()
        elif state is NavState.RECOVERING:
            self._recoveries += 1
            self._backing = 0
        elif state is NavState.RELOCALISING:
            self._relocalisations += 1
            self.chooser.reset()
            self._supervisor = None
            self._hint = self._turned_towards = None
            self._local = self._local_columns()
            self._localiser = self._new_localiser(expected, first_view=False)
            self._search, self._search_ticks = TurnMeter(), 0
            self._retrace = self._way_back()

    # -- localisation ---------------------------------------------------------------------

    def _new_localiser(self, expected: Sequence[NodeId] = (), first_view: bool = True) -> InitialLocaliser:
        return InitialLocaliser(self.node_ids, self.config.thresholds.t_milestone,
                                self.config.localiser, expected=expected,
                                t_expected=self.config.thresholds.t_lost,
                                neighbourhoods=self._neighbourhoods, t_floor=self.config.thresholds.t_lost,
                                first_view=first_view and self.config.localiser.first_view,
                                first_view_nodes=self._goal_reachers)

    def _by_belief(self) -> bool:
        """Whether this (re-)localisation places the robot from the belief (``from_belief``)."""
        mode = self.config.localiser.from_belief
        return mode == "always" or (mode == "initial" and self._state is NavState.LOCALISING)

    def _localise_tick(self, row: np.ndarray, heading_rad: Optional[float]) -> NavigationStep:
        self.filter.update(row)  # keep the filter warm for the supervisor that follows
        if self._retrace:
            return self._clear(f"re-localisation {self._relocalisations}")
        if self._by_belief():
            return self._localise_by_belief(row, heading_rad)
        if self._state is NavState.RELOCALISING:
            # A re-localisation only accepts nodes from which the goal can still be reached:
            # the robot was on its way there, so a node with no arc chain to the goal is a
            # look-alike (the first localisation keeps every node, so that an unreachable goal
            # is reported as such).
            row = np.where(self._reaches_goal, row, -1.0)
            if self._local is not None:
                row = np.where(self._local & self._facing_as_mapped(heading_rad), row, -1.0)
        result = self._localiser.tick(row, heading_rad)
        if result.status is LocaliserStatus.FAILED and self._local is not None:
            # nothing near the anchor in a full turn: search the whole map from here on, without
            # the lower threshold for the plan's stretch: the stretch near the anchor was just
            # searched, and a stretch of a plan made after a wrong re-localisation is no evidence
            self._local = None
            self._localiser = self._new_localiser((), first_view=False)
            return self._step(Action.SEARCH_ROTATE, turned_rad=result.turned_rad,
                              reason=f"no node within {self.config.localiser.relocalise_hops} arcs of node "
                                     f"{self._anchor!r} matched ({result.reason}); searching the whole map")
        if result.status is LocaliserStatus.FAILED:
            return self._fail(result.reason, turned_rad=result.turned_rad)
        if result.status is not LocaliserStatus.LOCALISED:
            return self._step(result.action, reason=result.reason, turned_rad=result.turned_rad)
        return self._start(result.node, result.reason, heading_rad)

    def _localise_by_belief(self, row: np.ndarray, heading_rad: Optional[float]) -> NavigationStep:
        """Look for ``belief_hold_ticks``, then turn in place (the belief keeps each view with the
        heading it was taken at), until the belief's mode is trusted and the robot faces along the
        route there; see ``from_belief``."""
        belief = self._belief
        if belief is None:
            raise NavigationInputError("localiser.from_belief needs the belief over the map every tick (belief=)")
        turned = self._search.update(heading_rad)
        self._search_ticks += 1
        if self._compass is not None and self._state is NavState.LOCALISING:
            self._compass.add(heading_rad, row)
        node, level = belief.mode, self.config.belief.confidence
        tolerance = self.config.localiser.relocalise_heading_tolerance_deg
        facing = belief.facing_deg is None or abs(belief.facing_deg) <= tolerance
        reachable = self._state is NavState.LOCALISING or node in self._goal_reachers
        looked = abs(turned) >= math.radians(self.config.localiser.belief_min_turn_deg) - 1e-9
        if belief.confidence >= level and facing and reachable and looked:
            where = "" if belief.facing_deg is None else ", facing along the route"
            compass = self._measure_offset(node, turned)
            return self._start(node, f"belief: node {node!r} holds {belief.confidence:.2f} of the mass "
                                     f"(>= {level:g}){where}{compass}", heading_rad)
        if self._search_ticks >= self.config.localiser.max_search_ticks:
            return self._fail(f"the belief did not settle in {self._search_ticks} ticks (mode {node!r} with "
                              f"{belief.confidence:.2f} of the mass)", turned_rad=turned)
        why = ("not trusted yet" if belief.confidence < level else
               "facing away from the route there" if not facing else
               "the goal is not reachable from it" if not reachable else
               f"turned {math.degrees(abs(turned)):.0f} of {self.config.localiser.belief_min_turn_deg:g} deg")
        if self._search_ticks <= self.config.localiser.belief_hold_ticks:
            return self._step(Action.NONE, reason=f"belief: node {node!r} with {belief.confidence:.2f} of the mass, "
                                                  f"{why}; looking")
        return self._step(Action.SEARCH_ROTATE, turned_rad=turned,
                          reason=f"belief: node {node!r} with {belief.confidence:.2f} of the mass, {why}; turning")

    def _measure_offset(self, node: NodeId, turned_rad: float) -> str:
        """After a full look round, the heading offset from where ``node`` and its neighbours
        matched best (:mod:`controllers.compass`); the words for the reason."""
        if self._compass is None or abs(turned_rad) < 2.0 * math.pi - 1e-9:
            return ""
        near = [node] + sorted((n for n in self._undirected.neighbors(node) if n != node), key=repr)
        columns = [self._column[n] for n in near]
        self._look_offset = self._compass.offset(columns, [self._headings[n] for n in near])
        self._compass = None
        if self._look_offset is None:
            return ""
        return f"; heading offset {math.degrees(self._look_offset):+.0f} deg from the look"

    def _start(self, start: NodeId, reason: str, heading_rad: Optional[float]) -> NavigationStep:
        """Placed at ``start``: plan to the goal and navigate (FAILED when no plan exists)."""
        if self._state is NavState.LOCALISING:   # a look's offset stands for the placement's
            self._set_anchor(start, heading_rad if self._look_offset is None else None)
        self._local = None
        self._remember(start)
        try:
            plan = self.planner.plan(start, self.goal_node)
        except PlanningError as exc:
            self._planning_error = exc
            return self._fail(f"{reason}; {exc}")
        self._plans += 1
        self._plan = plan.nodes
        self._supervisor = NodeSwitchSupervisor(plan.nodes, self.node_ids, self.config, self.filter, self._arcs)
        self.chooser.reset()
        self._enter(NavState.NAVIGATING)
        return self._step(Action.NONE, reason=f"{reason}; planned "
                          f"{len(plan.nodes)} nodes (cost {plan.cost:g}) to goal {self.goal_node!r}")

    def _relocalise(self, why: str, decision: Optional[SupervisorDecision]) -> NavigationStep:
        if self._relocalisations >= self.config.max_relocalisations:
            self._relocalisations += 1          # the one too many: the final step reports it
            return self._fail(f"{why}; gave up after {self.config.max_relocalisations} "
                              "re-localisations", decision=decision)
        # Prefer the stretch of the plan the robot was driving: those nodes are accepted as the
        # best of the map above t_lost, any other node needs t_milestone (see InitialLocaliser).
        expected: Tuple[NodeId, ...] = ()
        if decision is not None and self._plan and self.config.localiser.relocalise_expected:
            sup = self.config.supervisor
            i = decision.path_index
            expected = self._plan[max(0, i - sup.window_behind): i + sup.window_ahead + 2]
        self._enter(NavState.RELOCALISING, expected=expected)
        where = ("globally" if self._local is None else
                 f"near node {self._anchor!r} ({int(self._local.sum())} nodes within "
                 f"{self.config.localiser.relocalise_hops} arcs)")
        return self._step(Action.NONE, decision=decision,
                          reason=f"{why}; re-localising {where} ({self._relocalisations})")

    def _set_anchor(self, node: NodeId, heading_rad: Optional[float]) -> None:
        """``node`` is the new anchor; with a heading, its offset is one more vote, unless the
        robot stands where the newest vote was taken: nodes confirmed one after another while it
        stands still (after a look round) measure one heading, not several."""
        self._anchor = node
        if self._headings is None or heading_rad is None:
            return
        heading, driven, last = float(heading_rad), self._travelled_m, self._vote_pose
        if (last is not None and driven is not None and abs(driven - last[0]) < STILL_M
                and abs(wrap_angle(heading - last[1])) < STILL_RAD):
            return
        self._vote_pose = None if driven is None else (driven, heading)
        self._offsets.append(wrap_angle(heading - self._headings[node]))

    def heading_offset(self) -> Optional[float]:
        """The map-to-odometry heading offset the heading gate uses (radians; odometry heading
        minus the map's): the median of the offsets at the last
        ``localiser.relocalise_heading_confirmations`` confirmations, the first look round's
        (``localiser.compass_bandwidth_deg``) always one of them, taken as differences from
        the newest so that offsets either side of +-pi average right; None before the first
        confirmation with a heading (or on a map without headings)."""
        return median_offset(offset_votes(self._offsets, self.config.localiser.relocalise_heading_confirmations,
                                          self._look_offset))

    def _guard_offset(self) -> Optional[float]:
        """The heading guard's offset: the median of its last confirmations, the look's among them."""
        return self._guard.offset(self._offsets, self._look_offset)

    def _facing_as_mapped(self, heading_rad: Optional[float]) -> np.ndarray:
        """Per column: whether the robot faces the way the mapping drive faced at that node,
        given the map-to-odometry heading offset (all True without headings, or with the gate
        off)."""
        tolerance = self.config.localiser.relocalise_heading_tolerance_deg
        offset = self.heading_offset()
        if heading_rad is None or offset is None or tolerance >= 180.0:
            return np.ones(len(self.node_ids), dtype=bool)
        expected = self._heading_of_column + offset
        error = np.angle(np.exp(1j * (float(heading_rad) - expected)))     # wrapped to (-pi, pi]
        return np.abs(error) <= math.radians(tolerance)

    def _local_columns(self) -> Optional[np.ndarray]:
        """The columns within ``relocalise_hops`` arcs of the anchor (None: search globally)."""
        hops = self.config.localiser.relocalise_hops
        if hops == 0 or self._anchor is None:
            return None
        near = nx.single_source_shortest_path_length(self._undirected, self._anchor, cutoff=hops)
        return np.array([n in near for n in self.node_ids])

    # -- navigation -----------------------------------------------------------------------

    def _navigate_tick(self, row: np.ndarray, thirds: ThirdsInput,
                       heading_rad: Optional[float], policy: PolicyInput = None,
                       goal_score: Optional[float] = None, stalled: bool = False,
                       travelled_m: Optional[float] = None) -> NavigationStep:
        goal_mass = None if self._belief is None else dict(self._belief.top).get(self.goal_node, 0.0)
        decision = self._supervisor.tick(row, goal_score=goal_score, travelled_m=travelled_m, goal_mass=goal_mass,
                                         belief_mode=None if self._belief is None else self._belief.mode)
        if decision.confirmed_node is not None:
            self._confirmed(decision.confirmed_node, heading_rad, seen=not decision.by_odometry)
        if decision.state is SupervisorState.GOAL_REACHED:
            self._enter(NavState.ARRIVED)
            self._final = self._step(Action.STOP, decision=decision, reason=decision.reason)
            return self._final
        if decision.state is SupervisorState.LOST:
            return self._relocalise(decision.reason, decision)

        if self._state is NavState.RECOVERING:
            backing = self._back_off(decision)
            if backing is not None:
                return backing
        elif stalled and self.config.recovery.enabled and self._state in DRIVING_STATES:
            self._enter(NavState.RECOVERING)
            return self._back_off(decision)

        if self.chooser.uses_turn_hints and self._state in (NavState.NAVIGATING, NavState.TURNING):
            turn = self._corner_turn(decision, heading_rad) or self._guard_turn(decision, heading_rad)
            if turn is not None:
                if self._state is NavState.NAVIGATING:
                    self._enter(NavState.TURNING)
                return self._step(turn[0], decision, reason=turn[1])
            if self._state is NavState.TURNING:
                self.chooser.reset()              # it missed the ticks of the turn
                self._enter(NavState.NAVIGATING)
            if self._supervisor.settling and self._guard is not None:
                hold = self._guard.hold(self.goal_node, heading_rad, self._guard_offset())
                if hold is not None:
                    self.chooser.reset()          # it steers again only if the approach ends otherwise
                    return self._step(hold[0], decision, reason=f"{decision.reason}; {hold[1]}")

        if decision.driving_on and self.chooser.uses_turn_hints:
            # the views match nothing: no third can steer (nor find the target turning in place),
            # the map's heading can
            along = None if self._guard is None else self._guard.along(
                decision.target_node, heading_rad, self._guard_offset(), "driving on")
            action, why = along if along is not None else (Action.FORWARD, "forward")
            self.chooser.reset()
            if self._state is NavState.SEARCHING:
                self._enter(NavState.NAVIGATING)
            return self._step(action, decision, reason=f"{decision.reason}; {why}")

        target = decision.target_node
        view = TargetView(target, lambda: self._thirds_for(target, thirds),
                          lambda: None if self._contrast is None else self._thirds_for(target, self._contrast),
                          policy, lambda: None if self._bearings is None else self._bearings(target))
        try:
            choice = self.chooser.choose(view)
        except ChooserInputError as exc:
            raise NavigationInputError(str(exc)) from None

        if self._state is NavState.SEARCHING:
            if choice.sees_target:
                self._enter(NavState.NAVIGATING)
                return self._step(choice.action, decision, choice.thirds, choice.vote,
                                  f"target {target!r} back in view; {choice.reason}")
            if self._retrace:
                return self._clear(f"searching for target {target!r}", decision)
            turned = self._search.update(heading_rad)
            self._search_ticks += 1
            loc = self.config.localiser
            if turned >= loc.full_turn_rad or self._search_ticks >= loc.max_search_ticks:
                return self._relocalise(f"target {target!r} not seen by any third "
                                        f"during a full search turn", decision)
            return self._step(Action.SEARCH_ROTATE, decision, choice.thirds, choice.vote,
                              f"searching for target {target!r}: {choice.reason}", turned_rad=turned)

        if choice.lost_sight:
            self._enter(NavState.SEARCHING, heading_rad)
            if self._retrace:
                return self._clear(f"target {target!r} out of sight for {choice.unseen_ticks} ticks", decision)
            return self._step(Action.SEARCH_ROTATE, decision, choice.thirds, choice.vote,
                              f"target {target!r} out of sight for {choice.unseen_ticks} ticks; "
                              "turning counter-clockwise to find it")
        return self._step(choice.action, decision, choice.thirds, choice.vote, f"{decision.reason}; {choice.reason}")

    def _back_off(self, decision: SupervisorDecision) -> Optional[NavigationStep]:
        """RECOVERING: back off for ``recovery.backup_ticks``, then None: navigating again, with a
        fresh chooser (it missed the ticks)."""
        ticks = self.config.recovery.backup_ticks
        if self._backing < ticks:
            self._backing += 1
            return self._step(Action.BACKWARD, decision, reason=f"{decision.reason}; stalled against a wall: "
                              f"backing off ({self._backing}/{ticks}, recovery {self._recoveries})")
        self.chooser.reset()
        self._enter(NavState.NAVIGATING)
        return None

    def _way_back(self) -> list:
        """The commands that drive the way just driven backwards (``turn_room``), next first: the
        last ``turn_room.retrace_ticks`` moving commands negated, newest first, back to the last
        turn in place or drive backwards (before it the way behind is not where the robot came
        from)."""
        room = self.config.turn_room
        back: list = []
        if not room.enabled:
            return back
        for action, velocity in reversed(self._behind):
            if len(back) >= room.retrace_ticks or action in _ENDS_THE_WAY_BACK or velocity.v_mps < 0:
                break
            if not velocity.is_zero:
                back.append(VelocityCommand(-velocity.v_mps, -velocity.w_radps))
        return back

    def _clear(self, why: str, decision: Optional[SupervisorDecision] = None) -> NavigationStep:
        """One tick of the way back before a turn in place (``turn_room``)."""
        velocity = self._retrace.pop(0)
        return self._step(Action.RETRACE, decision, velocity=velocity,
                          reason=f"{why}: driving the way just driven backwards to turn in place "
                                 f"({len(self._retrace)} ticks to go)")

    def _confirmed(self, node: NodeId, heading_rad: Optional[float], seen: bool = True) -> None:
        """The supervisor confirmed ``node`` by driving: the new anchor, a corner turn to check,
        a new target for the chooser; a search or a corner turn is over. A node reached by
        odometry (not ``seen``) gives no heading offset: the robot is only about there."""
        self._set_anchor(node, heading_rad if seen else None)
        self._hint = None if heading_rad is None else (node, float(heading_rad))
        self._corner_view = [-math.inf, 0, 0]
        self._remember(node)
        self.chooser.reset()
        if self._state in (NavState.SEARCHING, NavState.TURNING):
            self._enter(NavState.NAVIGATING)

    def _corner_turn(self, decision: SupervisorDecision, heading_rad: Optional[float]) -> Optional[tuple]:
        """``(action, reason)`` of the turn the map's odometry asks for at a corner (see TURNING
        in the module docstring), or None when there is none to make now (a turn just completed
        resets the chooser: it missed the ticks of the turn)."""
        if (self._headings is None or not self.config.heading_hints or self._hint is None or heading_rad is None
                or decision.target_node is None):
            return None
        node, heading_then = self._hint
        target = decision.target_node
        if (node, target) == self._hint_done or node == target:
            return None
        turn = wrap_angle(self._headings[target] - self._headings[node])
        if abs(turn) < math.radians(self.config.heading_hint_min_deg):
            return None
        approach = self._approach_corner(decision, node)
        if approach is not None:
            return approach
        error = wrap_angle(heading_then + turn - float(heading_rad))
        if abs(error) <= math.radians(self.config.heading_hint_tolerance_deg):
            self._hint_done, self._turned_towards = (node, target), target
            self.chooser.reset()
            return None
        action = Action.LEFT if error > 0 else Action.RIGHT
        return action, (f"{decision.reason}; the map turned {math.degrees(turn):+.0f} deg from {node!r} to "
                        f"{target!r}: {action.value}, {math.degrees(error):+.0f} deg to go")

    def _guard_turn(self, decision: SupervisorDecision, heading_rad: Optional[float]) -> Optional[tuple]:
        """``(action, reason)`` of the heading guard's turn back towards the route (see
        ``heading_guard``), or None."""
        if self._guard is None:
            return None
        turn = self._guard.check(decision.target_node, heading_rad, self._guard_offset())
        return None if turn is None else (turn[0], f"{decision.reason}; {turn[1]}")

    def _approach_corner(self, decision: SupervisorDecision, node: NodeId) -> Optional[tuple]:
        """``(FORWARD, reason)`` while the corner node ``node``'s view still gets better (see
        ``heading_hint_approach_ticks``), None once the turn should begin, or at once when the
        robot turned towards ``node`` at the corner before it (a corner of several nodes: it
        stands at the corner already)."""
        view = self._corner_view
        limit, patience = self.config.heading_hint_approach_ticks, self.config.heading_hint_peak_ticks
        if view[1] < 0 or node == self._turned_towards:
            return None                       # the turn has begun: no more approach
        score = decision.current_score
        if score is not None and score > view[0]:
            view[0], view[2] = float(score), 0
        else:
            view[2] += 1
        view[1] += 1
        if view[1] > limit or view[2] >= patience:
            view[1] = -1
            return None
        return Action.FORWARD, (f"{decision.reason}; approaching corner node {node!r}: its view is best "
                                f"{view[2]} ticks ago ({view[0]:.3f}), {view[1]}/{limit} ticks")

    def _thirds_for(self, node: NodeId, thirds: ThirdsInput) -> ThirdScores:
        if thirds is None:
            raise NavigationInputError("thirds scores are needed while navigating: pass a "
                                       "callable node_id -> (left, middle, right) or an (N, 3) array")
        try:
            if callable(thirds):
                return ThirdScores.of(thirds(node))
            matrix = np.asarray(thirds, dtype=float)
            if matrix.shape != (len(self.node_ids), 3):
                raise NavigationInputError(f"thirds array must have shape ({len(self.node_ids)}, 3) "
                                           f"(one row per node), got {matrix.shape}")
            return ThirdScores.of(matrix[self._column[node]])
        except (TypeError, ValueError) as exc:
            if isinstance(exc, NavigationInputError):
                raise
            raise NavigationInputError(f"bad thirds scores for node {node!r}: {exc}") from None

    # -- output ---------------------------------------------------------------------------

    def _remember(self, node: NodeId) -> None:
        if not self._visited or self._visited[-1] != node:
            self._visited.append(node)

    def _fail(self, reason: str, decision: Optional[SupervisorDecision] = None,
              turned_rad: float = 0.0) -> NavigationStep:
        self._enter(NavState.FAILED)
        self._final = self._step(Action.STOP, decision, reason=reason, turned_rad=turned_rad)
        return self._final

    def _step(self, action: Action, decision: Optional[SupervisorDecision] = None,
              thirds: Optional[ThirdScores] = None, vote: Optional[VoteResult] = None,
              reason: str = "", turned_rad: float = 0.0,
              velocity: Optional[VelocityCommand] = None) -> NavigationStep:
        current = decision.current_node if decision else (self._visited[-1] if self._visited else None)
        if velocity is None:
            velocity = action_velocity(action, self.config.speeds)
        self._behind.append((action, velocity))     # the way just driven (turn_room)
        return NavigationStep(
            tick=self._ticks, state=self._state, action=action,
            velocity=velocity, goal_node=self.goal_node,
            planned_path=self._plan,
            path_index=decision.path_index if decision else None,
            current_node=current,
            target_node=decision.target_node if decision else None,
            current_score=decision.current_score if decision else None,
            target_score=decision.target_score if decision else None,
            thirds=thirds, vote=vote, supervisor=decision, visited_nodes=tuple(self._visited),
            relocalisations=self._relocalisations, replans=max(0, self._plans - 1),
            turned_rad=turned_rad, reason=reason)

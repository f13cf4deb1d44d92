"""Configuration of the navigation controller: thresholds, filter, window, search, speeds.

One frozen dataclass per concern, gathered in :class:`NavigationConfig`. Every field is checked
in ``__post_init__`` and a bad value raises ``ValueError`` naming the field, which
``core.configfile.load_config`` turns into an error naming the YAML file and the dotted field.

All similarities are cosines of L2-normalised descriptors (AnyLoc-style VLAD), in [-1, 1];
in practice they are in [0, 1]. The paper gives no threshold values; the defaults below are
placeholders for VLAD cosines (unrelated indoor places around 0.2-0.4, the same place under
another lighting around 0.7-0.9) and apply only with ``episode.thresholds_from_map: false``; by
default the thresholds are derived from the map with :meth:`Thresholds.from_map`, placed by the
fractions of :class:`ThresholdFractions` (``navigation.threshold_fractions``), the one place
those fractions live.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Optional

from core.hal import VelocityCommand
from core.validate import check_bool, check_choice, check_count, check_positive, check_range, check_similarity
from core.yaw_rate import HEADING_SOURCES


@dataclass(frozen=True)
class Thresholds:
    """The similarity thresholds of the paper's Navigation section, plus the lost threshold.

    Comparisons follow the paper's words: a score must *exceed* ``t_milestone`` and
    ``t_limited_control`` (strictly greater) and *drop below* ``t_change_node`` (strictly less).
    """

    #: A node is accepted as "the robot is here" only when its similarity exceeds this: initial
    #: and global localisation, and confirming that the next node of the path has been reached
    #: (the goal node included). Too low: wrong places are accepted; too high: the robot never
    #: confirms nodes under changed lighting and gets lost.
    t_milestone: float = 0.66
    #: The robot has left its current node once the similarity to it drops below this; only
    #: then can the next node be confirmed. It keeps a node that is still close from being
    #: skipped over on a noisy frame.
    t_change_node: float = 0.61
    #: A third of the camera image (Left / Middle / Right) votes for its action only when its
    #: similarity to the target node exceeds this. Thirds score lower than full views, hence
    #: a lower value than ``t_milestone``.
    t_limited_control: float = 0.35
    #: Not in the paper. When the best filtered similarity inside the matching window stays
    #: below this, the view shows none of the nearby nodes: after ``lost_patience_ticks`` of it
    #: the robot re-localises globally. Must be below ``t_change_node`` and ``t_milestone``,
    #: because between two nodes the scores legitimately fall under both.
    t_lost: float = 0.40

    def __post_init__(self) -> None:
        for name in ("t_milestone", "t_change_node", "t_limited_control", "t_lost"):
            check_similarity(name, getattr(self, name))
        if not self.t_lost < min(self.t_change_node, self.t_milestone):
            raise ValueError(
                f"t_lost ({self.t_lost}) must be below t_change_node ({self.t_change_node}) and "
                f"t_milestone ({self.t_milestone}): between nodes the scores fall under those, "
                "which is not being lost")

    @classmethod
    def from_map(cls, t_add_new_node: float, self_similarity: float = 1.0,
                 fractions: Optional["ThresholdFractions"] = None, *,
                 t_limited_control: Optional[float] = None) -> "Thresholds":
        """Thresholds derived from the map's own statistics.

        The mapper adds a node when the similarity to the last node drops below
        ``t_add_new_node``, so two consecutive nodes score about ``t_add_new_node`` against each
        other, while a view taken at a node scores about ``self_similarity`` against it (1.0
        under identical conditions; under other lighting measure it, e.g. as the median
        similarity between each keyframe and the frames recorded right after it). Between two
        nodes the similarity to a node therefore moves within the band
        ``[t_add_new_node, self_similarity]``, and the thresholds are placed as fractions of that
        band (``fractions``, default :class:`ThresholdFractions`):

        * ``t_milestone``   = add + ``milestone`` x band: confirm a node when the view is
          clearly closer to it than a neighbouring node is;
        * ``t_change_node`` = add + ``change_node`` x band: the robot has left a node
          (below ``t_milestone``, a hysteresis band against noise);
        * ``t_lost``        = add - ``lost`` x band: worse than the view from the
          neighbouring node, so no nearby node is in view.

        ``t_limited_control``: the thirds' threshold, which does not follow the node spacing;
        default ``fractions.control_contrast`` (the contrast scale of
        :func:`controllers.voter.contrast_thirds`).
        """
        fractions = ThresholdFractions() if fractions is None else fractions
        check_similarity("t_add_new_node", t_add_new_node)
        check_similarity("self_similarity", self_similarity)
        if not self_similarity > t_add_new_node:
            raise ValueError(f"self_similarity ({self_similarity}) must exceed t_add_new_node "
                             f"({t_add_new_node}); otherwise no band is left for the thresholds")
        band = self_similarity - t_add_new_node
        return cls(t_milestone=t_add_new_node + fractions.milestone * band,
                   t_change_node=t_add_new_node + fractions.change_node * band,
                   t_limited_control=fractions.control_contrast if t_limited_control is None else t_limited_control,
                   t_lost=max(-1.0, t_add_new_node - fractions.lost * band))


@dataclass(frozen=True)
class ThresholdFractions:
    """Where :meth:`Thresholds.from_map` places the thresholds in the band between the
    similarity of two consecutive nodes (``T_add_new_node``) and that of a view taken at a node
    (the map's self-similarity). The fractions' defaults are the values the paper harness runs
    with; ``reference_sparsity`` is neutral here (None) and set in ``configs/default.yaml``."""

    #: t_milestone = T_add_new_node + milestone x band: low, because under other lighting than
    #: the mapping run a view at a node often scores little above its neighbours' level
    milestone: float = 0.25
    #: t_change_node = T_add_new_node + change_node x band (below milestone: hysteresis)
    change_node: float = 0.15
    #: t_lost = T_add_new_node - lost x band
    lost: float = 0.1
    #: t_limited_control when the voter sees contrast scores (episode.thirds_contrast): a third
    #: votes when the target is closer to the node it resembles most than to a typical node
    control_contrast: float = 0.5
    #: the band's lower edge is the similarity of two consecutive nodes of a map of this sparsity
    #: (from the map's calibration), not the map's own T_add_new_node: how alike a view must be to
    #: a node to be there does not change with the node spacing the map was built at. None: the
    #: map's own T_add_new_node (also for maps without calibration statistics)
    reference_sparsity: Optional[float] = None

    def __post_init__(self) -> None:
        for name in ("milestone", "change_node", "lost", "control_contrast"):
            check_range(name, getattr(self, name), 0.0, 1.0, low_open=True, high_open=True)
        if self.reference_sparsity is not None:
            check_range("reference_sparsity", self.reference_sparsity, 0.0, 1.0)
        if not self.change_node < self.milestone:
            raise ValueError(f"change_node ({self.change_node}) must be below milestone ({self.milestone}): "
                             "a node is left below the level at which it is confirmed")


@dataclass(frozen=True)
class SimilarityFilterConfig:
    """A scalar random-walk Kalman filter per node smooths the similarity signals.

    The model is ``s_k = s_(k-1) + w`` (process noise std ``process_std`` per tick) observed as
    ``z_k = s_k + v`` (measurement noise std ``measurement_std``). The steady-state gain is
    about ``process_std / measurement_std`` for small ratios: the defaults give a gain near
    0.18, so a single-frame spike moves the filtered score by under a fifth of its height,
    while a real change is followed within about five ticks.
    """

    #: How fast the true similarity may change per control tick (std). Larger: faster
    #: response, less smoothing.
    process_std: float = 0.01
    #: Frame-to-frame noise of one similarity score (std), e.g. from lighting flicker or
    #: people walking by. Larger: more smoothing.
    measurement_std: float = 0.05

    def __post_init__(self) -> None:
        check_positive("process_std", self.process_std)
        check_positive("measurement_std", self.measurement_std)


@dataclass(frozen=True)
class SupervisorConfig:
    """Node switching: the matching window and the patience before declaring the robot lost."""

    #: Path positions behind the current node that still count as "nearby" (only for the lost
    #: check: seeing the node just passed is not being lost).
    window_behind: int = 1
    #: Path positions ahead of the current node that may be matched. Nodes further ahead or
    #: off the path are never matched, so far-away look-alikes cannot pull the robot forward
    #: (the paper's boundaries; ViNT uses +-4).
    window_ahead: int = 3
    #: Consecutive ticks with the best filtered score in the window below ``t_lost`` before
    #: the robot counts as lost and re-localises globally. Bridges short occlusions.
    lost_patience_ticks: int = 15
    #: Ticks without confirming any new node before the robot counts as lost (stuck against
    #: an obstacle, or hovering between two nodes without ever passing ``t_milestone``).
    progress_patience_ticks: int = 600
    #: Also confirm a node ahead (once L_i is left) when its filtered score is the best of the
    #: whole map and above ``t_lost``, not only above ``t_milestone``: under other lighting than
    #: the mapping run a node may never pass ``t_milestone`` although the robot stands at it.
    #: False: the paper's rule alone. Meaningless on maps of a handful of nodes (some node is
    #: always the best), so synthetic three-node tests of the paper's rule switch it off.
    confirm_best_of_map: bool = True
    #: Once the goal node is confirmed, keep steering at it until its filtered score has not
    #: improved for this many ticks (or falls clearly below its peak): a view well before the
    #: goal node may already pass ``t_milestone``. 0: arrive at the first confirmation.
    goal_settle_ticks: int = 10
    #: Not in the paper. With a goal image, the settle after the goal node's confirmation
    #: stops where the view matches the goal image itself best, not where the goal node's
    #: picture does: that picture was taken up to half an arc from the goal. False: the goal
    #: node's score alone decides arrival.
    goal_image_arrival: bool = True
    #: Not in the paper. The goal node, once it is the target, is also confirmed when the
    #: belief over the map holds ``belief.confidence`` of its mass at it: a goal node whose view
    #: never passes under the day's light is otherwise driven past (nothing after the goal
    #: confirms it). False: its score alone (the paper).
    goal_by_belief: bool = True
    #: Not in the paper. The goal is neither confirmed by the belief (``goal_by_belief``) nor, without
    #: a goal image past ``t_milestone``, settled before the odometry has driven the goal's incoming
    #: arc, less this many metres, since the goal's predecessor was confirmed: a node's mass, and a
    #: goal node's best-of-map score, reach up to half an arc before it, so on a long arc the robot
    #: stopped metres short. None: no odometry check (also on maps without arc lengths).
    goal_odometry_short_m: Optional[float] = None
    #: Not in the paper. The settled goal node waits while the belief's mode is a path node
    #: before the goal, for at most the goal's incoming arc of driving since its confirmation:
    #: a node confirmed as the best of the map can be a metre short, where the belief, which
    #: has the odometry since the previous nodes, still places the robot. False: the scores
    #: alone settle.
    goal_waits_for_belief: bool = True
    #: Not in the paper. When the window has been below ``t_lost`` for ``lost_patience_ticks``
    #: (the views match no node near the plan), the robot drives on by odometry instead of
    #: re-localising: the target counts as reached once the robot has driven the arc's mapped
    #: length from the current node, for at most this many metres since the last node
    #: confirmed by its view. A moved prop can hide a stretch that the robot stands on; turning
    #: to re-localise there found the same node again and again. 0: off (the map needs arc
    #: lengths from a drive, and the run loop the distance driven).
    odometry_max_m: float = 0.0

    def __post_init__(self) -> None:
        check_count("window_behind", self.window_behind, 0)
        check_count("window_ahead", self.window_ahead, 1)
        check_count("lost_patience_ticks", self.lost_patience_ticks, 1)
        check_count("progress_patience_ticks", self.progress_patience_ticks, 1)
        check_count("goal_settle_ticks", self.goal_settle_ticks, 0)
        check_bool("confirm_best_of_map", self.confirm_best_of_map)
        check_bool("goal_image_arrival", self.goal_image_arrival)
        check_bool("goal_by_belief", self.goal_by_belief)
        check_bool("goal_waits_for_belief", self.goal_waits_for_belief)
        if self.goal_odometry_short_m is not None:
            check_range("goal_odometry_short_m", self.goal_odometry_short_m, 0.0, 100.0, what="a distance in metres")
        check_range("odometry_max_m", self.odometry_max_m, 0.0, 100.0, what="a distance in metres")


#: the values of ``LocaliserConfig.from_belief``
BELIEF_LOCALISATION = ("off", "initial", "always")


@dataclass(frozen=True)
class LocaliserConfig:
    """Initial / global localisation: confirm a match, otherwise turn counter-clockwise."""

    #: The same node must be the best match above ``t_milestone`` for this many consecutive
    #: ticks (the robot holds still meanwhile), so one lucky frame cannot place the robot.
    confirm_ticks: int = 3
    #: Counter-clockwise rotation (accumulated from the heading the caller supplies) after
    #: which the search gives up: a full turn showed nothing the map knows.
    full_turn_rad: float = 2.0 * math.pi
    #: Tick budget of one search, for bases without a heading and for a robot that is stuck
    #: and cannot turn. Default: 2 pi at 0.5 rad/s and 10 Hz is 126 ticks, plus margin.
    max_search_ticks: int = 300
    #: Not in the paper. A match must beat every node outside its own neighbourhood (nodes
    #: within ``neighbourhood_hops`` arcs, either direction) by this margin. Corridors with
    #: identical doors and blank walls make distant look-alikes score as high as the right
    #: node; a margin (a ratio test, as in feature matching) rejects those ambiguous views.
    #: Applies when the caller gives the map's neighbourhoods (the navigator does).
    min_margin: float = 0.04
    neighbourhood_hops: int = 2
    #: Not in the paper. A goal image is placed by the belief's likelihood (the map's own
    #: keyframes' fit, against every node): its best node when the posterior mass within
    #: ``belief.confidence_hops`` arcs of it reaches ``belief.confidence`` and it scores above
    #: ``t_lost``. The goal picture is one look under the day's light, taken between two
    #: keyframes, so its right node often scores below ``t_milestone``; what says it is the
    #: goal is that nothing elsewhere comes close. False: above ``t_milestone`` only (the paper).
    goal_by_likelihood: bool = True
    #: Not in the paper. After a full turn in which no view passed, turn on to the best view
    #: of that turn (above the floor, with the margin, best for at least two ticks in a row)
    #: and localise there when it matches again within ``second_look_tolerance``: under other
    #: lighting than the mapping run the right node may score below ``t_milestone`` at every
    #: heading, while it is still clearly the best. False: give up after one turn (the paper).
    second_look: bool = True
    second_look_tolerance: float = 0.03
    #: Not in the paper. The first view of an initial localisation (the robot as it was
    #: placed, facing along its way, where the walkthrough's views were taken) is accepted
    #: below ``t_milestone`` when it is unambiguous: a margin of at least ``first_view_margin``
    #: and a score above the floor (``t_lost``) minus ``first_view_slack``. Turning in place
    #: first would show walls the walkthrough never faced, and those match other walls
    #: confidently (measured: a wall view scored 0.68 against a node 10 m away, while the first
    #: view's right node scored 0.41 with a 0.11 margin).
    first_view_margin: float = 0.05
    first_view_slack: float = 0.05
    #: False: no first-view rule (the paper).
    first_view: bool = True
    #: Not in the paper. A re-localisation first searches only the nodes within this many arcs
    #: (either direction) of the *anchor*, the last node the robot confirmed by driving along its
    #: plan (or its initial localisation): it has not moved far since, and under other lighting
    #: than the mapping run a look-alike elsewhere in the map often outscores the right place
    #: (measured in the office: a view 14 m from its look-alike node scored 0.56 against it,
    #: above t_milestone, while every node near the robot scored under t_lost). Only when a full
    #: turn (and the second look) finds nothing there does the search go on over the whole map,
    #: where every node needs ``t_milestone`` (the plan's stretch gets no lower threshold there).
    #: 0: search the whole map at once (the paper's global localisation).
    relocalise_hops: int = 4
    #: Not in the paper. A re-localisation accepts a node of the plan's stretch around where the
    #: robot got lost above ``t_lost`` instead of ``t_milestone``: it has not moved far, and other
    #: lighting lowers every score. False: ``t_milestone`` for every node (the paper).
    relocalise_expected: bool = True
    #: Not in the paper; needs the map's odometry headings (maps made from a recording). During
    #: the local search a node counts only while the robot faces the way the mapping drive faced
    #: there, to within this many degrees: the heading the robot had when it confirmed the anchor,
    #: turned by the map's heading change from the anchor to the node. A view of a wall the drive
    #: never faced can otherwise match a node nearby (measured in the office: a view facing a
    #: side wall, 120 deg off the aisle, matched the node two arcs ahead three ticks in a row).
    #: The default covers the heading error of 99 % of node confirmations measured in the paper
    #: harness's step logs (428 confirmations, hospital and office: median 6, p95 23, p99 39 deg).
    #: 180: no gate.
    relocalise_heading_tolerance_deg: float = 40.0
    #: The gate's map-to-odometry heading offset (odometry heading minus the map's at a node) is
    #: the median over the last this many confirmations (the first localisation and nodes
    #: confirmed by driving). 1: the anchor's offset alone, so one node confirmed early at a
    #: corner, facing the wrong way, turns the gate with it.
    relocalise_heading_confirmations: int = 1
    #: Not in the paper. Where the robot places itself: "off", the thresholded match above
    #: (confirm, margins, first view, second look, local search, heading gate); "initial", the
    #: belief over the map (``navigation.belief``) for the first localisation: it looks, then
    #: turns in place, until the belief's mode holds ``belief.confidence`` of the mass, facing
    #: along the route there within ``relocalise_heading_tolerance_deg``; "always", the belief for
    #: re-localisations too (then only a mode from which the goal is reachable counts).
    from_belief: str = "off"
    #: With ``from_belief``: hold still for up to this many ticks, looking, before turning. The
    #: robot is placed facing along its way, where the mapping drive's views were taken, and a
    #: turn shows walls the drive never faced, which match look-alikes elsewhere.
    belief_hold_ticks: int = 10
    #: With ``from_belief``: the belief places the robot only once the search has turned at least
    #: this far (degrees). Views a few ticks apart are one look, and one look can match a
    #: look-alike; views all round agree only at the true place.
    belief_min_turn_deg: float = 0.0
    #: Not in the paper; needs the map's odometry headings. After a full look round places the
    #: robot (``from_belief``, ``belief_min_turn_deg`` 360), the map-to-odometry heading offset is
    #: where the placed node and its neighbours within one arc matched best during the turn
    #: (:mod:`controllers.compass`, each node's similarity smoothed over the heading with a kernel
    #: of this many degrees), not the heading the robot faced when placed; it stays one vote of
    #: the median over the confirmations that follow (they track the odometry's drift).
    #: 0: the placed heading and the confirmations.
    compass_bandwidth_deg: float = 0.0

    def __post_init__(self) -> None:
        check_count("confirm_ticks", self.confirm_ticks, 1)
        check_range("compass_bandwidth_deg", self.compass_bandwidth_deg, 0.0, 180.0, high_open=True,
                    what="a number of degrees")
        check_choice("from_belief", self.from_belief, BELIEF_LOCALISATION)
        check_count("belief_hold_ticks", self.belief_hold_ticks, 0)
        check_range("belief_min_turn_deg", self.belief_min_turn_deg, 0.0, 720.0, what="a number of degrees")
        check_count("relocalise_hops", self.relocalise_hops, 0)
        check_count("relocalise_heading_confirmations", self.relocalise_heading_confirmations, 1)
        check_range("relocalise_heading_tolerance_deg", self.relocalise_heading_tolerance_deg, 0.0, 180.0,
                    low_open=True, what="a number of degrees")
        check_positive("full_turn_rad", self.full_turn_rad)
        check_count("max_search_ticks", self.max_search_ticks, 1)
        check_count("neighbourhood_hops", self.neighbourhood_hops, 0)
        for name in ("min_margin", "second_look_tolerance", "first_view_margin", "first_view_slack"):
            check_range(name, getattr(self, name), 0.0, 1.0, high_open=True)
        for name in ("second_look", "first_view", "relocalise_expected", "goal_by_likelihood"):
            check_bool(name, getattr(self, name))


@dataclass(frozen=True)
class ActionSpeeds:
    """Body velocity of each action (counter-clockwise yaw rate positive).

    The paper's actions: Left / Middle / Right turn left, go forward, turn right; a vote
    conflict that involves Middle gives forward-left / forward-right (forward with a turn).
    The rotate-search turns counter-clockwise in place, as the paper's localisation does.
    """

    forward: VelocityCommand = field(default_factory=lambda: VelocityCommand(0.25, 0.0))
    # Left / right creep forward: a camera-only robot turning in place sees the same two
    # views again and again, so a left-right vote flip-flop (the sides score alike when the
    # target is straight ahead but still far) would be a limit cycle; creeping breaks it.
    left: VelocityCommand = field(default_factory=lambda: VelocityCommand(0.08, 0.5))
    right: VelocityCommand = field(default_factory=lambda: VelocityCommand(0.08, -0.5))
    forward_left: VelocityCommand = field(default_factory=lambda: VelocityCommand(0.2, 0.3))
    forward_right: VelocityCommand = field(default_factory=lambda: VelocityCommand(0.2, -0.3))
    search_rotate: VelocityCommand = field(default_factory=lambda: VelocityCommand(0.0, 0.5))
    #: Backing off a wall the robot is pinned against (``recovery``): straight back, slowly,
    #: along the way it just came.
    backward: VelocityCommand = field(default_factory=lambda: VelocityCommand(-0.1, 0.0))

    def __post_init__(self) -> None:
        # (name, required sign of v, required sign of w; 0 = not checked). Only the part
        # that defines the action is checked, so an in-place turn may creep forward.
        rules = (("forward", 1, 0), ("left", 0, 1), ("right", 0, -1),
                 ("forward_left", 1, 1), ("forward_right", 1, -1), ("search_rotate", 0, 1))
        if not isinstance(self.backward, VelocityCommand) or not self.backward.v_mps < 0:
            raise ValueError(f"backward must be a VelocityCommand(v_mps, w_radps) with v_mps < 0, got "
                             f"{self.backward!r}")
        for name, v_sign, w_sign in rules:
            cmd = getattr(self, name)
            if not isinstance(cmd, VelocityCommand):
                raise ValueError(f"{name} must be a VelocityCommand(v_mps, w_radps), got {cmd!r}")
            if cmd.v_mps < 0:
                raise ValueError(f"{name}.v_mps must not be negative (the camera looks forward), "
                                 f"got {cmd.v_mps}")
            if v_sign > 0 and not cmd.v_mps > 0:
                raise ValueError(f"{name}.v_mps must be positive, got {cmd.v_mps}")
            if w_sign and not cmd.w_radps * w_sign > 0:
                side = "positive (counter-clockwise)" if w_sign > 0 else "negative (clockwise)"
                raise ValueError(f"{name}.w_radps must be {side}, got {cmd.w_radps}")


@dataclass(frozen=True)
class RecoveryConfig:
    """Not in the paper. Backing off a wall: a robot pressed against a wall turns its wheels but
    not its body, and its wheel odometry counts on, so the gyro tells. Over the last
    ``window_s`` of driving, when the commanded turns add up to at least ``min_turn_deg`` and the
    gyro measured less than ``turn_ratio`` of that, the robot is stalled
    (:class:`controllers.stall.StallMonitor`); it backs straight off (``speeds.backward``) for
    ``backup_ticks``, then drives on. A camera that looks forward sees no obstacle; the robot
    backs along the way it came, which was free a moment before. A robot stalled driving
    straight ahead, with no turn commanded, is not told."""

    enabled: bool = False
    window_s: float = 2.0
    min_turn_deg: float = 30.0
    turn_ratio: float = 0.25
    backup_ticks: int = 15

    def __post_init__(self) -> None:
        check_bool("enabled", self.enabled)
        check_positive("window_s", self.window_s)
        check_range("min_turn_deg", self.min_turn_deg, 0.0, 360.0, low_open=True, what="a number of degrees")
        check_range("turn_ratio", self.turn_ratio, 0.0, 1.0, low_open=True, high_open=True, what="a fraction")
        check_count("backup_ticks", self.backup_ticks, 1)


@dataclass(frozen=True)
class TurnRoomConfig:
    """Not in the paper. Room to turn in place: before the turn of a search or a re-localisation
    the robot drives the way it just came backwards, for at most ``retrace_ticks`` (its last
    commands negated, newest first, back to its last turn in place), so that it turns where it
    was a moment before. Why: a robot that lost its target has usually driven up to a wall, and
    the Limo's corners sweep 0.19 m around its centre as it turns; the way just driven was free,
    and a camera that looks forward cannot see any other free space."""

    enabled: bool = True
    retrace_ticks: int = 20

    def __post_init__(self) -> None:
        check_bool("enabled", self.enabled)
        check_count("retrace_ticks", self.retrace_ticks, 1)


@dataclass(frozen=True)
class HeadingGuardConfig:
    """Not in the paper. Keeping the robot facing along the route (:mod:`controllers.heading_guard`):
    while it navigates, when its odometry heading is more than ``max_error_deg`` away from the way
    the mapping drive faced at the target node (the map's node headings, through the
    map-to-odometry offset: the median over the last ``confirmations`` nodes confirmed), it turns
    back until it is within ``release_deg``, and the voter steers again. Why: the thirds say which
    way the target looks most alike, which says little when the view is of a wall; a robot angled
    off a corridor's axis drifts into the wall it faces. Acts once ``min_confirmations`` offsets
    are known; the voter only, and only on maps with node headings.

    ``final_approach`` (off by default): once the goal node is confirmed and the robot drives on
    until the goal is seen best, it holds the goal node's mapped heading (FORWARD within
    ``final_tolerance_deg``, else FORWARD_LEFT / FORWARD_RIGHT) instead of following the votes,
    where a weakly matching goal once made the voter weave in place. Off: no measurable effect in
    its ablation (docs/results.md); kept as an option so that runs made with it replay. ``final_tolerance_deg`` also bounds driving on
    by odometry along the mapped heading."""

    enabled: bool = True
    max_error_deg: float = 15.0
    release_deg: float = 5.0
    confirmations: int = 5
    min_confirmations: int = 2
    final_approach: bool = False
    final_tolerance_deg: float = 5.0

    def __post_init__(self) -> None:
        check_bool("enabled", self.enabled)
        check_range("max_error_deg", self.max_error_deg, 0.0, 180.0, low_open=True, high_open=True,
                    what="a number of degrees")
        check_range("release_deg", self.release_deg, 0.0, self.max_error_deg, high_open=True, what="a number of degrees")
        check_count("confirmations", self.confirmations, 1)
        check_count("min_confirmations", self.min_confirmations, 1)
        check_bool("final_approach", self.final_approach)
        check_range("final_tolerance_deg", self.final_tolerance_deg, 0.0, 180.0, high_open=True,
                    what="a number of degrees")
        if self.min_confirmations > self.confirmations:
            raise ValueError(f"min_confirmations ({self.min_confirmations}) must not exceed confirmations "
                             f"({self.confirmations})")


@dataclass(frozen=True)
class BeliefConfig:
    """The discrete Bayes filter over the map (:mod:`controllers.belief`)."""

    #: length of a cell along a metric arc (the odometry resolution the motion update works in)
    cell_m: float = 0.25
    #: cells per arc on a map without metric arc lengths (from a video): node units
    cells_per_arc: int = 1
    #: each cell-length advance leaves this share of the mass where it was (slip, bumps) ...
    stay: float = 0.1
    #: ... and moves this share two cells (arcs a little shorter than measured)
    skip: float = 0.1
    #: share of the mass spread over every cell after each update, so that a robot carried
    #: elsewhere (kidnapped) is found again; small, so that it does not drown the evidence
    mixing: float = 0.002
    #: the mode is trusted once this much mass lies within confidence_hops arcs of it
    confidence: float = 0.6
    confidence_hops: int = 1
    #: the exponent of each view's likelihood: successive views are not independent evidence (at
    #: 10 Hz and 0.25 m/s a camera looks about ten times per 0.25 m cell); the stack's
    #: configs/default.yaml sets what replayed hospital episodes chose (docs/results.md)
    weight: float = 0.1
    #: directions per cell, relative to the route there (1: none, the robot assumed to face along
    #: the route); more need the mapping drive's node headings (a map from a video has none)
    heading_bins: int = 1
    #: a view's score for a node is the mean of its contrast over the node and the nodes within
    #: this many arcs: a real place matches a stretch of route, a chance look-alike one keyframe
    smoothing_hops: int = 0
    #: share of the mass landing one direction bin short, and as much one over, per bin turned
    #: (skid-steer odometry turns less or more than it reports)
    turn_slip: float = 0.1

    def __post_init__(self) -> None:
        check_positive("cell_m", self.cell_m)
        check_count("cells_per_arc", self.cells_per_arc, 1)
        for name in ("stay", "skip", "mixing"):
            check_range(name, getattr(self, name), 0.0, 1.0, high_open=True)
        if not self.stay + self.skip < 1.0:
            raise ValueError(f"stay + skip must be below 1 (the rest advances one cell), got {self.stay + self.skip}")
        check_range("confidence", self.confidence, 0.0, 1.0, low_open=True)
        check_count("confidence_hops", self.confidence_hops, 0)
        check_range("weight", self.weight, 0.0, 1.0, low_open=True)
        check_count("heading_bins", self.heading_bins, 1)
        check_count("smoothing_hops", self.smoothing_hops, 0)
        check_range("turn_slip", self.turn_slip, 0.0, 0.5, high_open=True)


@dataclass(frozen=True)
class BearingConfig:
    """Not in the paper. Steering by bearing (``enabled``; :class:`controllers.choosers.BearingChooser`):
    while the voter sees the target (a third votes), the direction comes from the shift that best
    aligns the view's column profile with the target node's (:mod:`descriptors.columns`, a
    fraction of the view's width, positive to the left) instead of from the thirds: within
    ``deadband`` FORWARD, beyond it FORWARD_LEFT / FORWARD_RIGHT, beyond ``turn`` LEFT / RIGHT.
    The voter still says whether the target is seen (its weak vote, its patience, the search).
    Why: the thirds say which third looks most like the target, and under another day's light
    that flips between left and right from one vote to the next; the shift grows steadily with
    the heading error (about 0.15 of the view per 10 deg with the Limo's 65 deg camera) and with
    the distance beside the mapped line (about 0.1 per half metre), so nulling it brings the
    robot back onto the drive's heading and towards its line (bearing-only teach and repeat).
    Needs a map with column profiles (made since 2026-12-07); an older map is steered by the
    thirds, with a note (:func:`robot.episode.setup.configure_bearing`)."""

    enabled: bool = True
    deadband: float = 0.04
    turn: float = 0.25

    def __post_init__(self) -> None:
        check_bool("enabled", self.enabled)
        check_range("deadband", self.deadband, 0.0, 0.5, high_open=True, what="a fraction of the view's width")
        check_range("turn", self.turn, self.deadband, 1.0, low_open=True, what="a fraction of the view's width")


@dataclass(frozen=True)
class NavigationConfig:
    """Everything the navigator needs besides the map. Load from YAML with
    ``core.configfile.load_config(NavigationConfig, path)``; use :meth:`with_thresholds` to
    plug in thresholds derived from a map (:meth:`Thresholds.from_map`)."""

    thresholds: Thresholds = field(default_factory=Thresholds)
    #: how the thresholds are derived from a map (with episode.thresholds_from_map, the default)
    threshold_fractions: ThresholdFractions = field(default_factory=ThresholdFractions)
    filter: SimilarityFilterConfig = field(default_factory=SimilarityFilterConfig)
    supervisor: SupervisorConfig = field(default_factory=SupervisorConfig)
    localiser: LocaliserConfig = field(default_factory=LocaliserConfig)
    #: the belief over the map; tracked and logged every step (it does not steer yet)
    belief: BeliefConfig = field(default_factory=BeliefConfig)
    speeds: ActionSpeeds = field(default_factory=ActionSpeeds)
    #: backing off when pinned against a wall (off by default)
    recovery: RecoveryConfig = field(default_factory=RecoveryConfig)
    #: backing off along the way just driven before turning in place
    turn_room: TurnRoomConfig = field(default_factory=TurnRoomConfig)
    #: turning back when the robot faces away from the route (the voter only)
    heading_guard: HeadingGuardConfig = field(default_factory=HeadingGuardConfig)
    #: steering by the bearing of the target's view instead of the thirds
    bearing: BearingConfig = field(default_factory=BearingConfig)
    #: The two-cycle voter executes on every second tick. True: the executed action is held
    #: through the next (storing) tick, i.e. each decision lasts one two-tick vote period
    #: (a zero-order hold; smooth motion). False: the robot stands still on storing ticks,
    #: the literal reading of "the first cycle stores, the second executes".
    hold_action_between_votes: bool = True
    #: Consecutive ticks in which no third exceeds ``t_limited_control`` (the target is out of
    #: sight) before the robot turns counter-clockwise in place to look for it.
    no_vote_patience_ticks: int = 6
    #: Before that patience starts, the first ticks without a vote follow the third that scores
    #: best anyway (LEFT / FORWARD / RIGHT, a weak vote; left and right creep forward):
    #: between two nodes the walkthrough went forward, so a target that no third recognises
    #: clearly is more likely ahead than behind (under other lighting the thirds often miss it
    #: until closer), and turning in place away from it makes it worse.
    #: 0: the paper's literal behaviour (nothing happens). The supervisor still watches: if the
    #: view leaves the window's nodes the robot is lost and re-localises.
    blind_forward_ticks: int = 20
    #: Global re-localisations allowed in one episode before giving up (FAILED); bounds a
    #: robot that keeps getting lost.
    max_relocalisations: int = 5
    #: Turn hints from the mapping drive's odometry (maps recorded with odometry; a map without
    #: headings, e.g. from a video, gets none). At a corner the target node's view lies beside the camera's field of view,
    #: so no third recognises it and the voter turns late; with hints, once a node is confirmed
    #: and the map says the drive turned by at least ``heading_hint_min_deg`` from it to the
    #: target, the robot first turns (LEFT / RIGHT, odometry heading) by that angle to within
    #: ``heading_hint_tolerance_deg``, then the voter steers again. The voter only; not the
    #: learned policy.
    heading_hints: bool = True
    heading_hint_min_deg: float = 25.0
    heading_hint_tolerance_deg: float = 10.0
    #: The corner turn begins where the corner node is seen best, not where it is confirmed:
    #: a node's view passes ``t_milestone`` about half a metre before the node, and turning
    #: there cuts the corner into its inner wall. After the confirmation the robot drives on
    #: (FORWARD) until the node's filtered similarity has not improved for
    #: ``heading_hint_peak_ticks``, at most ``heading_hint_approach_ticks`` (0: turn at once).
    heading_hint_approach_ticks: int = 24
    heading_hint_peak_ticks: int = 2
    #: Not in the paper. Where the heading of the turn hints, the heading guard, the heading gate
    #: and the look's offset comes from, in the mapping drive (the map's node headings) and in
    #: navigation alike: ``odometry`` (the wheels' yaw) or ``gyro`` (the gyro's yaw rate
    #: integrated; a wheel scrubbing along a wall turns the wheels' yaw, not the gyro's). The
    #: belief keeps the wheel odometry's. A map made before gyro headings were kept has none:
    #: it is navigated on the wheels' (with a note; rebuild it for the gyro's).
    heading_source: str = "odometry"

    def __post_init__(self) -> None:
        check_bool("heading_hints", self.heading_hints)
        check_choice("heading_source", self.heading_source, HEADING_SOURCES)
        for name in ("heading_hint_min_deg", "heading_hint_tolerance_deg"):
            check_range(name, getattr(self, name), 0.0, 180.0, low_open=True, high_open=True, what="a number of degrees")
        check_count("heading_hint_approach_ticks", self.heading_hint_approach_ticks, 0)
        check_count("heading_hint_peak_ticks", self.heading_hint_peak_ticks, 1)
        check_bool("hold_action_between_votes", self.hold_action_between_votes)
        check_count("no_vote_patience_ticks", self.no_vote_patience_ticks, 1)
        check_count("blind_forward_ticks", self.blind_forward_ticks, 0)
        check_count("max_relocalisations", self.max_relocalisations, 0)

    def as_published(self) -> "NavigationConfig":
        """The paper's method as published: every option marked "not in the paper" off, the
        rest (thresholds, filter, speeds, windows, patience) as configured. The harness's
        ``paper`` method, so the table compares the paper's method, ours and the baseline on the
        same trials. Its "rotate and retry until something does" stays bounded by
        ``full_turn_rad``: a second turn shows the same views."""
        return replace(
            self,
            localiser=replace(self.localiser, min_margin=0.0, goal_by_likelihood=False, second_look=False,
                              first_view=False,
                              relocalise_hops=0, relocalise_expected=False,
                              relocalise_heading_tolerance_deg=180.0, from_belief="off",
                              compass_bandwidth_deg=0.0),
            supervisor=replace(self.supervisor, confirm_best_of_map=False, goal_settle_ticks=0,
                               goal_image_arrival=False, goal_by_belief=False, goal_waits_for_belief=False,
                               goal_odometry_short_m=None,
                               odometry_max_m=0.0),
            recovery=replace(self.recovery, enabled=False), turn_room=replace(self.turn_room, enabled=False),
            heading_guard=replace(self.heading_guard, enabled=False), bearing=replace(self.bearing, enabled=False),
            hold_action_between_votes=False, blind_forward_ticks=0, heading_hints=False)

    def with_thresholds(self, thresholds: Thresholds) -> "NavigationConfig":
        """The same configuration with other thresholds (e.g. ``Thresholds.from_map(...)``)."""
        return replace(self, thresholds=thresholds)

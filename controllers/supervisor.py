"""The node-switch supervisor: where on the planned path L0..Ln the robot is, tick by tick.

The robot's *current node* is the last path node it confirmed, L_i; its *target node* is the
next one, L_i+1, whose image the action voter steers towards. Per the paper:

* LEAVING L_i: driving from L_i towards L_i+1, the similarity to L_i falls; once it drops below
  ``t_change_node`` the robot has left L_i and switches to L_i+1 (APPROACHING);
* APPROACHING L_i+1: the robot has reached L_i+1 when the similarity to it exceeds
  ``t_milestone``; it becomes the current node (LEAVING it towards L_i+2). When it is the last
  node Ln, the goal is reached (GOAL_REACHED, final).

Additions, each for a failure seen in practice:

* **Filtering.** All decisions use Kalman-filtered similarities
  (:class:`controllers.similarity_filter.SimilarityFilter`), so one noisy frame can neither
  confirm a node, nor switch away from one, nor hide the goal from a robot standing at it.
* **Window.** Only path positions ``i - window_behind .. i + window_ahead`` are matched;
  far-away look-alikes and nodes off the path are ignored (the paper's boundaries).
* **Nodes passed unnoticed.** A node ahead inside the window (L_i+1 or further) is confirmed
  as soon as its filtered score exceeds ``t_milestone`` and is the best of the nodes ahead -
  while LEAVING it must also beat the current node's score (the view resembles it more than
  L_i). This is the paper's "general localisation" limited to the window; it lets a robot
  that missed a milestone, or a dense map, keep going.
* **Best of the map.** Under other lighting than the mapping run every cosine drops (a node's
  own view from ~0.9 to ~0.5), and a node may never pass ``t_milestone`` although the robot
  stands at it. Once the robot has left L_i (APPROACHING), a node ahead in the window is
  therefore also confirmed when its filtered score
  is the highest of the *whole map* (no other place explains the view better) and above
  ``t_lost`` (it is not a view of nothing). The rule adapts to the conditions of the day
  because it compares nodes under the same conditions instead of against a fixed level.
* **The goal by the belief** (``goal_by_belief``, with the belief's mass at the goal node
  passed to :meth:`NodeSwitchSupervisor.tick`). Once the robot has left L_i (APPROACHING)
  for the goal node (the target), the goal node is also confirmed when the belief over the map holds at
  least ``belief.confidence`` of its mass at it: its views have matched the goal's stretch of
  route, in the order and at the distances the odometry drove, better than any other place. Only
  the target: from further back it skipped nodes and stopped short. Nodes before the goal that the views miss
  are confirmed by later ones; nothing lies after the goal, and a robot whose goal node never
  passes by score drove past it and was lost a node later. With ``goal_odometry_short_m``, only
  once the odometry has driven the goal's incoming arc, less that many metres, since the
  predecessor was confirmed: a node's mass gathers the cells up to half an arc before it, so on a
  long arc the belief alone confirmed the goal metres short. The settle that follows decides
  where to stop, as after any confirmation.
* **Lost.** When the best filtered score inside the window stays below ``t_lost`` while some
  node outside the window scores higher (the view shows another place, not merely a poor view
  of this one) for ``lost_patience_ticks`` ticks, or no node is confirmed for
  ``progress_patience_ticks`` ticks, the state is LOST (final for this supervisor): the caller must re-localise globally
  and re-plan, then build a new supervisor (passing the same filter keeps its state).
* **Driving on by odometry** (``odometry_max_m``, with the map's arc lengths and the distance
  driven passed to :meth:`NodeSwitchSupervisor.tick`). When the window has been below
  ``t_lost`` for the lost patience, the robot is not declared lost while it has driven less
  than ``odometry_max_m`` since the last node its view confirmed: the target is confirmed by
  odometry once the robot has driven the arc's mapped length from the current node (the goal
  never is: arrival needs its view); a robot that has driven more than ``odometry_max_m``
  since that node when the patience runs out is lost (where it went is unknown). Views of a
  stretch a moved prop changed match nothing; re-localising there found the same node again
  and again and gave up.

GOAL_REACHED and LOST are final: later ticks still update the filter but repeat the final
decision (with ``confirmed_node`` None).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, replace
from typing import Hashable, Mapping, Optional, Sequence, Tuple

import numpy as np

from controllers.config import NavigationConfig
from controllers.localisation import plain_node_ids, similarity_row
from controllers.similarity_filter import SimilarityFilter

NodeId = Hashable


class SupervisorState(enum.Enum):
    """The supervisor's state after a tick."""

    LEAVING = "leaving"            # at the current node, heading for the target node
    APPROACHING = "approaching"    # left the current node, waiting to confirm the target
    GOAL_REACHED = "goal_reached"  # final: the last path node was confirmed
    LOST = "lost"                  # final: re-localise globally and re-plan


@dataclass(frozen=True)
class SupervisorDecision:
    """The supervisor's output for one tick. Scores are filtered similarities (cosines)."""

    state: SupervisorState
    path_index: int                        # i: position of the current node on the path
    current_node: NodeId                   # L_i, the last confirmed node
    target_node: Optional[NodeId]          # L_i+1, steered towards; None once the goal is reached
    current_score: float                   # filtered similarity to L_i
    target_score: Optional[float]          # filtered similarity to L_i+1
    window_nodes: Tuple[NodeId, ...]       # the path nodes matched this tick, in path order
    window_scores: Tuple[float, ...]       # their filtered similarities
    confirmed_node: Optional[NodeId]       # a node confirmed (reached) this tick, if any
    lost_ticks: int                        # consecutive ticks with the window below t_lost
    reason: str
    goal_image_score: Optional[float] = None   # filtered similarity to the goal image (image goals)
    driving_on: bool = False               # the views match nothing: driving on by odometry
    by_odometry: bool = False              # confirmed_node was reached by odometry, not by its view

    @property
    def relocalise(self) -> bool:
        """True when the caller must re-localise globally and re-plan."""
        return self.state is SupervisorState.LOST

    @property
    def target_changed(self) -> bool:
        """True when this tick confirmed a node, so the target node moved on."""
        return self.confirmed_node is not None

    @property
    def best_window_score(self) -> float:
        return max(self.window_scores)


class NodeSwitchSupervisor:
    """Tick-based node switching along one planned path.

    ``node_ids[j]`` names the node of column ``j`` of every similarity row. The path starts at
    a node the caller has already localised (the current node at construction).
    ``arc_lengths_m[(src, dst)]``: the mapped length of the path's arcs (metres), for driving
    on by odometry (``supervisor.odometry_max_m``); None: a map without them.
    """

    def __init__(self, path: Sequence[NodeId], node_ids: Sequence[NodeId],
                 config: NavigationConfig = NavigationConfig(),
                 similarity_filter: Optional[SimilarityFilter] = None,
                 arc_lengths_m: Optional[Mapping[tuple, float]] = None):
        if len(path) == 0:
            raise ValueError("the path must hold at least one node")
        self.node_ids = plain_node_ids(node_ids)
        self._column = {node: j for j, node in enumerate(self.node_ids)}
        missing = [node for node in path if node not in self._column]
        if missing:
            raise ValueError(f"path node {missing[0]!r} has no column in the similarity rows")
        self.path = plain_node_ids(path)
        self._path_columns = np.array([self._column[node] for node in self.path])
        self.config = config
        self.filter = similarity_filter or SimilarityFilter(len(self.node_ids), config.filter)
        if self.filter.size != len(self.node_ids):
            raise ValueError(f"the similarity filter has {self.filter.size} columns, the map "
                             f"{len(self.node_ids)} nodes")
        self._index = 0
        self._state = SupervisorState.LEAVING
        self._lost_ticks = 0
        self._ticks_since_progress = 0
        self._final: Optional[SupervisorDecision] = None
        self._map_best = -1.0
        self._goal_peak: Optional[float] = None
        self._goal_flat = 0
        self._goal_reason = ""
        self._goal_seen_m: Optional[float] = None   # odometry distance at the goal's confirmation
        self._goal_from_m: Optional[float] = None   # ... and at its predecessor's (None: skipped)
        # the goal image's filtered score and its peak during the final approach (image goals)
        self._image_filter = SimilarityFilter(1, config.filter)
        self._image: Optional[float] = None
        self._image_peak: Optional[float] = None
        self._image_flat = 0
        # why the goal node's score, and the goal image's, said the robot is there ("": not yet)
        self._node_settled = ""
        self._image_settled = ""
        self._arcs = arc_lengths_m
        # odometry distance driven when the current node was confirmed, and when a node was last
        # confirmed by its view (driving on by odometry); None until the first distance arrives
        self._at_node_m: Optional[float] = None
        self._at_sight_m: Optional[float] = None
        self._driving_on = False   # whether this spell of matching nothing is driven on by odometry

    @property
    def index(self) -> int:
        """Position of the current node on the path."""
        return self._index

    @property
    def settling(self) -> bool:
        """Whether the goal node is confirmed and the robot is in its final approach (arrival
        not yet declared)."""
        return self._goal_peak is not None and self._final is None

    @property
    def state(self) -> SupervisorState:
        return self._state

    @property
    def target_node(self) -> Optional[NodeId]:
        """The node the robot steers towards (None once at the last node)."""
        return self.path[self._index + 1] if self._index + 1 < len(self.path) else None

    def window(self) -> range:
        """The path positions matched at the current node."""
        cfg = self.config.supervisor
        last = len(self.path) - 1
        return range(max(0, self._index - cfg.window_behind),
                     min(last, self._index + cfg.window_ahead) + 1)

    def tick(self, similarities: np.ndarray, goal_score: Optional[float] = None,
             travelled_m: Optional[float] = None, goal_mass: Optional[float] = None,
             belief_mode: Optional[NodeId] = None) -> SupervisorDecision:
        """Filter one similarity row (current view against every node) and decide.

        ``goal_score``: the view's similarity to the goal image, when the goal is an image (see
        :meth:`_image_arrival`). ``travelled_m``: the distance the odometry has driven so far
        (metres along the robot's heading, less when reversing; any fixed origin), for driving
        on by odometry. ``goal_mass``: the belief's probability mass at the goal node (the
        path's last node), for confirming the goal by the belief. ``belief_mode``: the belief's
        most probable node (None: no belief), for the settled goal's wait (see
        :meth:`_settle_at_goal`)."""
        row = similarity_row(similarities, len(self.node_ids))
        if travelled_m is not None:
            if not math.isfinite(travelled_m):
                raise ValueError(f"travelled_m must be finite, got {travelled_m!r}")
            if self._at_node_m is None:
                self._at_node_m = self._at_sight_m = float(travelled_m)
        filtered = self.filter.update(row)
        if goal_score is not None and self.config.supervisor.goal_image_arrival:
            score = float(goal_score)
            if not np.isfinite(score):
                raise ValueError(f"goal_score must be finite, got {goal_score!r}")
            self._image = float(self._image_filter.update(np.array([score]))[0])
        if self._final is not None:
            return replace(self._final, confirmed_node=None)
        path_scores = filtered[self._path_columns]
        self._map_best = float(filtered.max())
        thresholds = self.config.thresholds
        last = len(self.path) - 1
        self._ticks_since_progress += 1
        confirmed: Optional[NodeId] = None
        reason = ""

        if last == 0:
            return self._finish(SupervisorState.GOAL_REACHED, path_scores, self.path[0],
                                "the start node is the goal node")

        if self._goal_peak is not None:
            return self._settle_at_goal(path_scores, travelled_m, belief_mode)
        here = float(path_scores[self._index])
        ahead = self._confirmable_ahead(path_scores, here)
        by_belief = ahead is None and self._goal_by_belief(goal_mass, travelled_m)
        if by_belief:
            ahead = last
        if ahead is not None:
            from_m = self._at_node_m if self._index == last - 1 else None
            passed = self.path[self._index + 1:ahead]
            confirmed = self.path[ahead]
            self._index, self._state = ahead, SupervisorState.LEAVING
            self._ticks_since_progress = 0
            if travelled_m is not None:
                self._at_node_m = self._at_sight_m = float(travelled_m)
            score = float(path_scores[ahead])
            reason = (f"reached node {confirmed!r}: the belief holds {goal_mass:.2f} of its mass there "
                      f"(>= confidence {self.config.belief.confidence:g}; filtered {score:.3f})" if by_belief else
                      f"reached node {confirmed!r}: filtered {score:.3f} > t_milestone "
                      f"{thresholds.t_milestone:.3f}" if score > thresholds.t_milestone else
                      f"reached node {confirmed!r}: filtered {score:.3f} is the best of the map "
                      f"(> t_lost {thresholds.t_lost:.3f})")
            if passed:
                reason += f" (skipped {', '.join(map(repr, passed))}, passed unnoticed)"
            if ahead == last:
                if self.config.supervisor.goal_settle_ticks == 0:
                    return self._finish(SupervisorState.GOAL_REACHED, path_scores, confirmed,
                                        "goal " + reason)
                # Keep steering at the goal until its score stops rising (see _settle_at_goal).
                self._index = last - 1
                self._state = SupervisorState.APPROACHING
                self._goal_peak, self._goal_flat, self._goal_reason = score, 0, "goal " + reason
                self._goal_seen_m, self._goal_from_m = travelled_m, from_m
                return self._decision(self._state, path_scores, None,
                                      f"goal in sight: {reason}; driving on while it improves")
        elif self._state is SupervisorState.LEAVING and here < thresholds.t_change_node:
            self._state = SupervisorState.APPROACHING
            reason = (f"left node {self.path[self._index]!r}: filtered {here:.3f} < t_change_node "
                      f"{thresholds.t_change_node:.3f}; switching to {self.target_node!r}")

        window = self.window()
        best = float(path_scores[window.start:window.stop].max())
        elsewhere = self._map_best > best   # the best node of the map lies outside the window
        self._lost_ticks = self._lost_ticks + 1 if (best < thresholds.t_lost and elsewhere) else 0
        if self._lost_ticks == 0:
            self._driving_on = False
        cfg = self.config.supervisor
        if self._lost_ticks >= cfg.lost_patience_ticks:
            why = f"best filtered score in the window {best:.3f} < t_lost {thresholds.t_lost:.3f} for " \
                  f"{self._lost_ticks} ticks"
            on = self._drive_on(path_scores, confirmed, travelled_m, why)
            if on is not None:
                return on
            return self._finish(SupervisorState.LOST, path_scores, confirmed, f"lost: {why}" + (
                "" if not self._odometry_on(travelled_m) else
                f"; drove {travelled_m - self._at_sight_m:.2f} m since the last node seen "
                f"(odometry_max_m {cfg.odometry_max_m:g})"))
        if self._ticks_since_progress >= cfg.progress_patience_ticks:
            return self._finish(SupervisorState.LOST, path_scores, confirmed,
                                f"lost: no node confirmed for {self._ticks_since_progress} ticks")
        if not reason:
            target = self.path[self._index + 1]
            reason = (f"{self._state.value} {self.path[self._index]!r} -> {target!r}: filtered "
                      f"{here:.3f} / {path_scores[self._index + 1]:.3f}")
        return self._decision(self._state, path_scores, confirmed, reason)

    def _odometry_on(self, travelled_m: Optional[float]) -> bool:
        """Whether this tick may drive on by odometry (the setting, the distance, arc lengths)."""
        return (self.config.supervisor.odometry_max_m > 0 and travelled_m is not None and self._arcs is not None
                and self._at_node_m is not None)

    def _drive_on(self, path_scores: np.ndarray, confirmed: Optional[NodeId], travelled_m: Optional[float],
                  why: str) -> Optional[SupervisorDecision]:
        """The decision of driving on by odometry while the window matches nothing (see the module
        docstring), or None: lost."""
        if not self._odometry_on(travelled_m) or confirmed is not None:
            return None
        limit = self.config.supervisor.odometry_max_m
        blind = travelled_m - self._at_sight_m
        target = self.target_node
        arc = self._arcs.get((self.path[self._index], target))
        if arc is None or not arc > 0:
            return None
        driven = travelled_m - self._at_node_m
        if not self._driving_on and blind > limit:   # the lost check came late: where it went is unknown
            return None
        self._driving_on = True
        # the budget counts to where the map puts a node, not to the tick that finds it passed
        within = self._at_node_m + arc - self._at_sight_m <= limit
        if driven >= arc and within and self._index + 1 < len(self.path) - 1:   # the goal needs its view
            self._index, self._state = self._index + 1, SupervisorState.LEAVING
            self._at_node_m += arc
            self._ticks_since_progress = 0
            return replace(self._decision(self._state, path_scores, target,
                                          f"{why}; reached node {target!r} by odometry: drove {driven:.2f} m of "
                                          f"its {arc:.2f} m arc ({blind:.2f} of {limit:g} m since the last node "
                                          "seen)"),
                           driving_on=True, by_odometry=True)
        if driven >= arc or blind > limit:
            return None
        return replace(self._decision(self._state, path_scores, None,
                                      f"{why}; driving on by odometry: {driven:.2f} of {arc:.2f} m to node "
                                      f"{target!r} ({blind:.2f} of {limit:g} m since the last node seen)"),
                       driving_on=True)

    def _settle_at_goal(self, path_scores: np.ndarray, travelled_m: Optional[float],
                        belief_mode: Optional[NodeId]) -> SupervisorDecision:
        """The goal passed its confirmation; arrive once its filtered score stops improving.

        A view some way before the goal node may already pass ``t_milestone`` (the band is
        wide), and a node may be confirmed as the best of the map a metre short of it, so
        stopping at the confirmation stops short. The robot keeps steering at the goal while the
        score sets new highs; the goal node is settled when the score has not improved for
        ``goal_settle_ticks`` ticks or has fallen clearly below its peak (it is passing the
        node). Standing still at the goal settles after ``goal_settle_ticks``. With a goal image
        (``supervisor.goal_image_arrival``) whose score passed ``t_milestone``, the view being
        where the image was taken (:meth:`_image_arrival`) decides instead, once the goal node's
        own score has passed ``t_milestone`` since its confirmation (the robot stands at the
        node's place); while it has not (the node was confirmed as the best of the map, which
        can happen a metre short), the goal node must settle too. The node alone stops up to
        half an arc from the goal; the image alone stopped a metre short when a turn lowered its
        score there. A goal image below ``t_milestone`` does not decide, but the settled node
        waits while it still sets new highs (within ``goal_settle_ticks``): the robot is
        closing in on the place it shows. Without a goal image in play, the settled node also
        waits (``goal_waits_for_belief``) while the belief's mode is a path node before the goal,
        for at most the goal's incoming arc of driving since its confirmation: a node confirmed
        as the best of the map can be a metre short, where the belief, which has the odometry
        since the previous nodes, still places the robot. With ``goal_odometry_short_m`` it also
        waits until the odometry has driven the goal's arc, less that setting, since the goal's
        predecessor: on a long arc the best-of-map score and the belief's mode both reach the
        goal node half an arc before it.
        """
        last = len(self.path) - 1
        score = float(path_scores[last])
        cfg = self.config.supervisor
        if score > self._goal_peak + 0.005:
            self._goal_peak, self._goal_flat = score, 0
        else:
            self._goal_flat += 1
        if not self._node_settled and (self._goal_flat >= cfg.goal_settle_ticks or score < self._goal_peak - 0.03):
            self._node_settled = f"settled at filtered {score:.3f} (peak {self._goal_peak:.3f})"
        self._image_settled = self._image_settled or self._image_arrival()
        image_in_play = self._image_peak is not None and self._image_peak > self.config.thresholds.t_milestone
        at_node = self._goal_peak > self.config.thresholds.t_milestone
        # below t_milestone the goal image does not decide, but while it still sets new highs the
        # robot is closing in on the place it shows: the node alone stopped a metre short there
        image_rising = (not image_in_play and self._image_peak is not None
                        and self._image_flat < cfg.goal_settle_ticks)
        short = "" if image_in_play else (self._belief_short(travelled_m, belief_mode)
                                          or self._odometry_short(travelled_m, self._goal_from_m))
        if (self._image_settled and (at_node or self._node_settled)) or (
                self._node_settled and not image_in_play and not image_rising and not short):
            why = "; ".join(w for w in (self._node_settled, self._image_settled) if w)
            return self._finish(SupervisorState.GOAL_REACHED, path_scores, self.path[last],
                                f"{self._goal_reason}; {why}")
        node = (self._node_settled or f"filtered {score:.3f}, peak {self._goal_peak:.3f}, "
                f"{self._goal_flat}/{cfg.goal_settle_ticks} ticks without improving")
        image = ("" if not (image_in_play or image_rising) else "; the goal image " + (
            "settled" if self._image_settled else
            f"scores {self._image:.3f}, peak {self._image_peak:.3f}, {self._image_flat}/{cfg.goal_settle_ticks} "
            "ticks without improving" + ("" if image_in_play else " (below t_milestone, still rising)")))
        return self._decision(self._state, path_scores, None, f"goal in sight: {node}{image}{short}")

    def _belief_short(self, travelled_m: Optional[float], belief_mode: Optional[NodeId]) -> str:
        """Why the settled goal waits for the belief (see :meth:`_settle_at_goal`), or ""."""
        arc = self._goal_arc_m()
        if not (self.config.supervisor.goal_waits_for_belief and belief_mode in self.path[:-1]
                and travelled_m is not None and self._goal_seen_m is not None):
            return ""
        driven = travelled_m - self._goal_seen_m
        if arc is None or not driven < arc:
            return ""
        return (f"; the belief still places the robot at node {belief_mode!r}, before the goal "
                f"(drove {driven:.2f} of the goal arc's {arc:.2f} m since its confirmation)")

    def _odometry_short(self, travelled_m: Optional[float], from_m: Optional[float]) -> str:
        """Why the goal waits for the odometry (``goal_odometry_short_m``), or "": driven less
        than the goal's incoming arc, less that setting, since its predecessor (at ``from_m``)."""
        short, arc = self.config.supervisor.goal_odometry_short_m, self._goal_arc_m()
        if short is None or travelled_m is None or from_m is None or arc is None:
            return ""
        driven = travelled_m - from_m
        if driven >= arc - short:
            return ""
        return (f"; the odometry has driven {driven:.2f} m of the goal arc's {arc:.2f} m since node "
                f"{self.path[-2]!r} (arrival from {arc - short:.2f} m)")

    def _goal_arc_m(self) -> Optional[float]:
        """The mapped length of the arc into the goal node (None: no arc lengths, or none there)."""
        if self._arcs is None or len(self.path) < 2:
            return None
        return self._arcs.get((self.path[-2], self.path[-1]))

    def _image_arrival(self) -> str:
        """Whether the view has passed the place the goal image shows (a reason), or "".

        The goal node's picture was taken somewhere near the goal, not at it, so once the goal
        node is confirmed the final approach follows the view's filtered similarity to the goal
        image itself: it arrives once that score has passed ``t_milestone`` (the view matches
        the goal image as well as a view matches the node it stands at) and has not improved
        for ``goal_settle_ticks`` ticks or has fallen clearly below its peak (the robot is
        passing the place). Its peak is tracked from the confirmation on: before it, a view of
        the corridor a metre short of the goal can score a passing high (identical doors).
        """
        if self._image is None:
            return ""
        score, cfg = self._image, self.config.supervisor
        if self._image_peak is None or score > self._image_peak + 0.005:
            self._image_peak, self._image_flat = score, 0
            return ""
        self._image_flat += 1
        level = self.config.thresholds.t_milestone
        if self._image_peak <= level:
            return ""
        if self._image_flat >= cfg.goal_settle_ticks or score < self._image_peak - 0.03:
            return (f"the goal image: filtered {score:.3f}, peak {self._image_peak:.3f} "
                    f"(> t_milestone {level:.3f}), the view is at the place it shows")
        return ""

    def _confirmable_ahead(self, path_scores: np.ndarray, here: float) -> Optional[int]:
        """The path position ahead (inside the window) to confirm this tick, if any."""
        window = self.window()
        first = self._index + 1
        if first >= window.stop:
            return None
        scores = path_scores[first:window.stop]
        k = int(np.argmax(scores))  # ties: the nearest node
        score = float(scores[k])
        thresholds = self.config.thresholds
        # only once the robot has left L_i (APPROACHING), so the paper's order is kept
        best_of_map = (self.config.supervisor.confirm_best_of_map
                       and self._state is SupervisorState.APPROACHING and score >= self._map_best
                       and score > thresholds.t_lost)
        if score <= thresholds.t_milestone and not best_of_map:
            return None
        if self._state is SupervisorState.LEAVING and score <= here:
            return None
        return first + k

    def _goal_by_belief(self, goal_mass: Optional[float], travelled_m: Optional[float]) -> bool:
        """Whether the belief confirms the goal node this tick (see the module docstring)."""
        cfg = self.config.supervisor
        if not cfg.goal_by_belief or goal_mass is None:
            return False
        if not math.isfinite(goal_mass):
            raise ValueError(f"goal_mass must be finite, got {goal_mass!r}")
        if not (goal_mass >= self.config.belief.confidence and self._state is SupervisorState.APPROACHING
                and self._index + 1 == len(self.path) - 1):
            return False
        return not self._odometry_short(travelled_m, self._at_node_m)

    def _decision(self, state: SupervisorState, path_scores: np.ndarray,
                  confirmed: Optional[NodeId], reason: str) -> SupervisorDecision:
        window = self.window()
        i = self._index
        target = self.target_node
        return SupervisorDecision(
            state=state, path_index=i, current_node=self.path[i], target_node=target,
            current_score=float(path_scores[i]),
            target_score=float(path_scores[i + 1]) if target is not None else None,
            window_nodes=tuple(self.path[p] for p in window),
            window_scores=tuple(float(path_scores[p]) for p in window),
            confirmed_node=confirmed, lost_ticks=self._lost_ticks, reason=reason,
            goal_image_score=self._image)

    def _finish(self, state: SupervisorState, path_scores: np.ndarray,
                confirmed: Optional[NodeId], reason: str) -> SupervisorDecision:
        self._state = state
        if state is SupervisorState.GOAL_REACHED:
            self._index = len(self.path) - 1
        self._final = self._decision(state, path_scores, confirmed, reason)
        return self._final

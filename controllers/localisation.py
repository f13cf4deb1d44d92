"""Initial and global localisation against every node of the map.

A view (or the goal image) is placed at the node with the highest similarity, but only when
that similarity exceeds ``t_milestone`` (paper, "Initial Localization"). When nothing passes,
the robot turns counter-clockwise in place and tries again; after a full turn, measured by
accumulating the heading the caller supplies (odometry or IMU yaw), or after a tick budget,
the :class:`InitialLocaliser` reports that the robot cannot place itself.

Two additions of ours (``LocaliserConfig``): with the map's neighbourhoods, a match must beat
every node outside its neighbourhood by ``min_margin`` (an ambiguous view is no match), and
after a fruitless full turn the robot turns on to the best view of that turn (the *second
look*) and localises there when it matches again.

A goal image, one fixed look, is placed by the map's likelihood instead
(:func:`localise_by_likelihood`): the posterior mass near its best node, not one threshold.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Hashable, Mapping, Optional, Sequence

import networkx as nx
import numpy as np

from controllers.actions import Action
from controllers.belief import SimilarityModel, contrast
from controllers.config import LocaliserConfig
from core.angles import wrap_angle

NodeId = Hashable


class LocalisationError(ValueError):
    """Bad input to localisation (a similarity row of the wrong length, non-finite scores)."""


class GoalNotLocalisedError(LocalisationError):
    """The goal image matches no node of the map above ``t_milestone``."""


@dataclass(frozen=True)
class Localisation:
    """The best node for one similarity row, and whether it passes ``t_milestone``; or, placed
    by the likelihood (:func:`localise_by_likelihood`), the posterior mass near it
    (``confidence``) against the ``needed`` level, ``t_milestone`` then being the floor."""

    best_node: NodeId
    best_score: float
    accepted: bool
    t_milestone: float
    confidence: Optional[float] = None
    needed: Optional[float] = None

    @property
    def node(self) -> Optional[NodeId]:
        """The accepted node, or None when the best score does not exceed ``t_milestone``."""
        return self.best_node if self.accepted else None

    def describe(self) -> str:
        if self.confidence is not None:
            verdict = ">=" if self.confidence >= self.needed else "<"
            floor = ">" if self.best_score > self.t_milestone else "<="
            return (f"best node {self.best_node!r} with similarity {self.best_score:.3f} ({floor} floor "
                    f"{self.t_milestone:.3f}), posterior mass {self.confidence:.2f} near it {verdict} "
                    f"{self.needed:.2f}")
        verdict = ">" if self.accepted else "<="
        return (f"best node {self.best_node!r} with similarity {self.best_score:.3f} "
                f"{verdict} t_milestone {self.t_milestone:.3f}")


def plain_node_ids(node_ids: Sequence[NodeId]) -> tuple:
    """Node ids as a tuple of plain Python values (a map may hand over an int64 array; numpy
    scalars would leak into messages as ``np.int64(7)``)."""
    return tuple(n.item() if isinstance(n, np.generic) else n for n in node_ids)


def similarity_row(similarities: np.ndarray, size: int, what: str = "similarity row") -> np.ndarray:
    """Check that ``similarities`` is a finite 1-D row of ``size`` scores; return it as floats."""
    row = np.asarray(similarities, dtype=float)
    if row.ndim != 1 or row.shape[0] != size:
        raise LocalisationError(f"{what} must have one score per map node ({size}), got shape "
                                f"{row.shape}")
    if not np.all(np.isfinite(row)):
        bad = int(np.flatnonzero(~np.isfinite(row))[0])
        raise LocalisationError(f"{what} has a non-finite score at column {bad}")
    return row


def localise(similarities: np.ndarray, node_ids: Sequence[NodeId],
             t_milestone: float) -> Localisation:
    """Place one view: the best node of the row, accepted only above ``t_milestone``.

    ``similarities[j]`` is the cosine similarity of the view to node ``node_ids[j]``; ties go
    to the first column.
    """
    row = similarity_row(similarities, len(node_ids))
    j = int(np.argmax(row))
    score = float(row[j])
    node = plain_node_ids([node_ids[j]])[0]
    return Localisation(node, score, score > t_milestone, float(t_milestone))


def localise_by_likelihood(similarities: np.ndarray, node_ids: Sequence[NodeId], graph: nx.DiGraph,
                           model: SimilarityModel, *, confidence: float, hops: int,
                           floor: float) -> Localisation:
    """Place one view the belief's way: the posterior over the nodes from a uniform prior and the
    view's likelihood ratio (``model``, fitted on the map's own keyframes, uncapped: this view is
    the only evidence). The best node is accepted when the posterior mass within ``hops`` arcs
    of it reaches ``confidence`` and its similarity exceeds ``floor`` (``t_lost``: below it a
    view matches no node at all). A view between two keyframes scores below ``t_milestone``
    and is still placed when nothing elsewhere comes close; a look-alike elsewhere splits the
    mass and refuses it."""
    row = similarity_row(similarities, len(node_ids))
    log_ratio = model.log_ratio(contrast(row), capped=False)
    p = np.exp(log_ratio - log_ratio.max())
    p /= p.sum()
    j = int(np.argmax(row))
    node = plain_node_ids([node_ids[j]])[0]
    column = {n: k for k, n in enumerate(plain_node_ids(node_ids))}
    near = nx.single_source_shortest_path_length(graph.to_undirected(as_view=True), node_ids[j], cutoff=hops)
    mass = float(sum(p[column[n]] for n in plain_node_ids(list(near))))
    score = float(row[j])
    return Localisation(node, score, mass >= confidence and score > floor, float(floor), confidence=mass,
                        needed=float(confidence))


def localise_goal_image(similarities: np.ndarray, node_ids: Sequence[NodeId],
                        t_milestone: float) -> Localisation:
    """Place the goal image, or raise :class:`GoalNotLocalisedError` saying how close it came.

    The goal image is fixed, so turning the robot cannot help: no match is final.
    """
    result = localise(similarities, node_ids, t_milestone)
    if not result.accepted:
        raise GoalNotLocalisedError(f"the goal image matches no node of the map: {result.describe()}")
    return result


class TurnMeter:
    """Counter-clockwise rotation accumulated from successive headings (radians).

    Each heading difference is wrapped to (-pi, pi], so headings may wrap freely; the caller
    must supply headings often enough that the robot turns less than pi between two of them.
    Clockwise motion counts negative. ``None`` headings (no odometry / IMU) are ignored.
    """

    def __init__(self) -> None:
        self._last: Optional[float] = None
        self.turned_rad = 0.0

    def update(self, heading_rad: Optional[float]) -> float:
        if heading_rad is not None:
            if not math.isfinite(heading_rad):
                raise LocalisationError(f"heading_rad must be finite, got {heading_rad!r}")
            if self._last is not None:
                delta = heading_rad - self._last
                self.turned_rad += wrap_angle(delta)
            self._last = float(heading_rad)
        return self.turned_rad


class LocaliserStatus(enum.Enum):
    """Where an :class:`InitialLocaliser` stands after a tick."""

    CONFIRMING = "confirming"   # a node passes; holding still until it passed confirm_ticks times
    ROTATING = "rotating"       # nothing passes; turning counter-clockwise in place
    LOCALISED = "localised"     # final: ``node`` is where the robot is
    FAILED = "failed"           # final: a full turn (or the tick budget) found nothing


@dataclass(frozen=True)
class LocaliserStep:
    """The localiser's output for one tick."""

    status: LocaliserStatus
    action: Action              # NONE while confirming, SEARCH_ROTATE while rotating, STOP at the end
    node: Optional[NodeId]      # the localised node (LOCALISED only)
    best: Localisation          # this tick's best match
    turned_rad: float           # counter-clockwise rotation accumulated so far
    ticks: int                  # ticks spent in this search
    reason: str


class InitialLocaliser:
    """Tick-based global localisation of the current view with a counter-clockwise search.

    Each tick: if the best node exceeds ``t_milestone`` the robot holds still (``NONE``) until
    the same node has been best and above threshold for ``confirm_ticks`` consecutive ticks,
    then it is LOCALISED. Otherwise it asks for ``SEARCH_ROTATE``; once the accumulated turn
    reaches ``full_turn_rad`` or ``max_search_ticks`` ticks have passed, it is FAILED: the
    robot cannot place itself. Final states repeat on further ticks.
    """

    def __init__(self, node_ids: Sequence[NodeId], t_milestone: float,
                 config: LocaliserConfig = LocaliserConfig(), *,
                 expected: Sequence[NodeId] = (), t_expected: Optional[float] = None,
                 neighbourhoods: Optional[Mapping[NodeId, frozenset]] = None,
                 t_floor: Optional[float] = None, first_view: bool = False,
                 first_view_nodes: Optional[frozenset] = None):
        """``expected`` / ``t_expected``: nodes where the robot is likely to be (a re-localisation:
        the stretch of the plan it was driving) are accepted when they are the best node of the
        whole row above the lower ``t_expected``; any other node needs ``t_milestone``. Under
        other lighting than the mapping run no view may pass ``t_milestone`` at all, while the
        best match near the last known place is still the right answer.

        ``neighbourhoods``: node -> the nodes within ``config.neighbourhood_hops`` arcs of it
        (itself included); given, every acceptance also needs ``config.min_margin`` over the
        best node outside the neighbourhood. ``t_floor``: the least score a second-look
        candidate needs (default ``t_expected``). ``first_view``: accept the view the robot has
        before it turns on the relaxed terms of ``LocaliserConfig.first_view_margin`` (an
        initial localisation; needs ``neighbourhoods``). ``first_view_nodes``: the only nodes
        the first view may be placed at on those terms (the navigator passes the nodes from
        which the goal can be reached: a relaxed match that leaves the goal unreachable is
        more likely a look-alike than a real dead end, so the robot searches on instead)."""
        if len(node_ids) == 0:
            raise LocalisationError("the map has no nodes to localise against")
        self.node_ids = plain_node_ids(node_ids)
        self.t_milestone = float(t_milestone)
        self.expected = frozenset(plain_node_ids(expected)) if len(expected) else frozenset()
        self.t_expected = float(t_milestone if t_expected is None else t_expected)
        self.config = config
        self._turn = TurnMeter()
        self._ticks = 0
        self._candidate: Optional[NodeId] = None
        self._streak = 0
        self._final: Optional[LocaliserStep] = None
        self._column = {n: j for j, n in enumerate(self.node_ids)}
        self._neighbourhoods = neighbourhoods
        self.t_floor = float(self.t_expected if t_floor is None else t_floor)
        # the first turn's views: (node, score) of ticks that could be second-look candidates
        self._previous: Optional[tuple] = None
        self._best_view: Optional[tuple] = None    # the first turn's best candidate (node, score)
        self._look: Optional[tuple] = None         # (node, score) of the second look's target
        self._look_start = 0.0
        self._first_view = bool(first_view) and neighbourhoods is not None   # until the robot turns
        self._first_view_nodes = None if first_view_nodes is None else frozenset(first_view_nodes)

    @property
    def done(self) -> bool:
        return self._final is not None

    def margin(self, row: np.ndarray, node: NodeId) -> float:
        """How much ``node`` beats the best node outside its neighbourhood (inf without
        neighbourhoods or when every node is a neighbour)."""
        if self._neighbourhoods is None:
            return math.inf
        near = self._neighbourhoods.get(node, frozenset((node,)))
        others = [row[j] for n, j in self._column.items() if n not in near]
        return float(row[self._column[node]] - max(others)) if others else math.inf

    def tick(self, similarities: np.ndarray, heading_rad: Optional[float] = None) -> LocaliserStep:
        """One localisation tick: the current view's similarity to every node, and the heading."""
        if self._final is not None:
            return self._final
        row = similarity_row(similarities, len(self.node_ids))
        best = localise(row, self.node_ids, self.t_milestone)
        margin = self.margin(row, best.best_node)
        distinct = margin >= self.config.min_margin
        if not best.accepted and best.best_node in self.expected and best.best_score > self.t_expected:
            best = Localisation(best.best_node, best.best_score, True, self.t_expected)
        if best.accepted and not distinct:
            best = Localisation(best.best_node, best.best_score, False, best.t_milestone)
        if self._first_view and not best.accepted:
            floor = self.t_floor - self.config.first_view_slack
            allowed = self._first_view_nodes is None or best.best_node in self._first_view_nodes
            if allowed and margin >= self.config.first_view_margin and best.best_score > floor:
                best = Localisation(best.best_node, best.best_score, True, floor)
            else:
                self._first_view = False
        if self._look is not None and not best.accepted and distinct:
            node, score = self._look          # the second look: the best view of the first turn again
            near = self._neighbourhoods.get(node, frozenset((node,))) if self._neighbourhoods else {node}
            if best.best_node in near and best.best_score >= score - self.config.second_look_tolerance:
                best = Localisation(best.best_node, best.best_score, True, score - self.config.second_look_tolerance)
        turned = self._turn.update(heading_rad)
        self._ticks += 1

        if best.accepted:
            self._streak = self._streak + 1 if best.best_node == self._candidate else 1
            self._candidate = best.best_node
            if self._streak >= self.config.confirm_ticks:
                how = "" if self._look is None else f" (second look at the best view of a full turn, node {self._look[0]!r})"
                return self._finish(LocaliserStatus.LOCALISED, best.best_node, best, turned,
                                    f"localised at node {best.best_node!r}: {best.describe()}, "
                                    f"{self._streak} ticks in a row{how}")
            return LocaliserStep(LocaliserStatus.CONFIRMING, Action.NONE, None, best, turned,
                                 self._ticks, f"confirming node {best.best_node!r} "
                                 f"({self._streak}/{self.config.confirm_ticks}): {best.describe()}")
        self._candidate, self._streak = None, 0
        self._first_view = False              # the robot turns from here on
        if self._look is None and distinct and best.best_score > self.t_floor:
            # a second-look candidate needs the same node best on two ticks in a row
            if self._previous is not None and self._previous[0] == best.best_node:
                score = min(self._previous[1], best.best_score)
                if self._best_view is None or score > self._best_view[1]:
                    self._best_view = (best.best_node, score)
            self._previous = (best.best_node, best.best_score)
        else:
            self._previous = None
        full = self.config.full_turn_rad
        if self._look is None and turned >= full and self.config.second_look and self._best_view is not None:
            self._look, self._look_start = self._best_view, turned
            return LocaliserStep(LocaliserStatus.ROTATING, Action.SEARCH_ROTATE, None, best, turned, self._ticks,
                                 f"no view passed in a full turn; turning on to the best one: node "
                                 f"{self._look[0]!r} at {self._look[1]:.3f}")
        limit = full if self._look is None else self._look_start + full
        if turned >= limit or self._ticks >= self.config.max_search_ticks * (1 if self._look is None else 2):
            spent = (f"a full counter-clockwise turn ({math.degrees(turned):.0f} deg)"
                     if turned >= limit else f"{self._ticks} search ticks")
            second = "" if self._look is None else f" (nor the best view of the first turn again, node {self._look[0]!r})"
            return self._finish(LocaliserStatus.FAILED, None, best, turned,
                                f"the robot cannot place itself: after {spent} no view matched a "
                                f"node{second}; last {best.describe()}")
        return LocaliserStep(LocaliserStatus.ROTATING, Action.SEARCH_ROTATE, None, best, turned,
                             self._ticks, f"rotating counter-clockwise: {best.describe()}"
                             + ("" if distinct else f" (ambiguous: margin {margin:.3f} < {self.config.min_margin})"))

    def _finish(self, status: LocaliserStatus, node: Optional[NodeId], best: Localisation,
                turned: float, reason: str) -> LocaliserStep:
        self._final = LocaliserStep(status, Action.STOP if status is LocaliserStatus.FAILED
                                    else Action.NONE, node, best, turned, self._ticks, reason)
        return self._final

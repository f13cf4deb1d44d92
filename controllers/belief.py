"""Where the robot is on the map, as a probability: a discrete Bayes filter along the map's arcs.

The paper's navigator commits to one thresholded arg-max from a standing start; a corridor that
looks alike in both directions, or a look-alike a few metres away, then places the robot wrongly
for good. This filter keeps every place in play until the evidence of several views *and of the
motion between them* singles one out (the robot's version of sequence matching, SeqSLAM; the
discrete filter over a topological map of PlaceNav), and recovers when it was wrong.

**State.** Cells along the graph: one cell per node, and ``cells - 1`` interior cells on each arc
(``cells = round(length / cell_m)``, at least 1): a robot between two nodes is between them. On a
map with metric arc lengths (the mapping drive's odometry) a cell is about ``cell_m`` metres; on a
map without (from a video) every arc is one unit long and :meth:`NodeBelief.advance` steps in
node units. Where the map has the mapping drive's heading at every node, each cell is split into
``heading_bins`` directions: the robot's heading *relative to the way the route ran there*
(bin 0: facing along the route; with 8 bins, bin 4: facing back). A standing start in a
corridor that looks alike both ways, or a turn in place, then keeps what the views said before
instead of smearing it: the direction is part of what a view's match explains.

**Motion.** :meth:`NodeBelief.move` takes the odometry's distance along the robot's heading
(negative: reversing) and its turn. Each direction bin moves along the arcs by the distance
times the cosine of its angle to the route (forward at bin 0, backward facing back, nowhere
side-on); each time a bin passes a cell length its mass moves one cell (two with probability
``skip``, none with ``stay``: wheel slip, a bumper, arcs of odd lengths), splitting evenly at a
node with several arcs, and turning with the route (a cell whose route heading differs keeps the
robot's heading, so the relative bin changes). A turn rolls every cell's direction bins, a
``turn_slip`` share landing one bin short or over.

**Measurement.** :meth:`NodeBelief.observe` takes the view's similarity to every node, turns it
into contrast scores (:func:`contrast`: robust to a global drop of every cosine under other
lighting) and multiplies each state's mass by the likelihood ratio of its score,
``p(c | here) / p(c | elsewhere)``, from two normal densities fitted on the map's own walkthrough
(:meth:`SimilarityModel.from_references`: how a keyframe scores against its neighbours on the
route versus far places), raised to a ``weight`` below one when successive views are not
independent (a camera that looks many times per cell). A cell between two nodes takes the ratios
of both, weighted by its position. With ``smoothing_hops``, a node's score is first averaged
over the node and its neighbours (:func:`neighbourhood_mean`; the fit uses the same average): a
real place matches a stretch of route, a chance look-alike one keyframe. A state facing away
from the route (bin not 0) expects no node's view, so its ratio is one: a poor match of a node's
view is evidence against facing along the route there. No hand threshold enters the update.

**Recovery.** After every update a ``mixing`` share of the mass is spread over all states: a
robot carried elsewhere (kidnapped) is found again once its views say so.

The filter answers: the most probable node (:attr:`mode`), the mass within ``confidence_hops`` of
it (:attr:`confidence`), the entropy, the direction at the mode (:attr:`facing_deg`), and the
top nodes with their mass (for logs).

On a loop with one cell per arc and one direction bin the two steps are filterpy's
``discrete_bayes.predict`` (kernel stay / advance / skip) and ``update`` (a test holds them
equal); the filter is numpy because a map's graph branches where filterpy convolves a 1-D array,
and the update runs in log space.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Hashable, Mapping, Optional, Sequence

import networkx as nx
import numpy as np

from controllers.config import BeliefConfig

NodeId = Hashable
_EPS = 1e-12


def contrast(row: np.ndarray) -> np.ndarray:
    """Similarities as contrast scores: minus the row's median, over its spread (1.4826 x the
    median absolute deviation, the normal-consistent estimate), the spread at least a tenth of
    the best score's lead over the median, so that no score exceeds 10 where most places score
    alike. A global change of every cosine (lighting) leaves them alike."""
    row = np.asarray(row, dtype=float)
    centre = np.median(row)
    spread = max(1.4826 * float(np.median(np.abs(row - centre))), 0.1 * float(row.max() - centre), 1e-9)
    return (row - centre) / spread


def neighbourhood_mean(graph: nx.DiGraph, node_ids: Sequence[NodeId], hops: int) -> Optional[np.ndarray]:
    """The ``(N, N)`` matrix that averages a score row over each node and the nodes within
    ``hops`` arcs of it (either direction); None for ``hops`` 0 (no averaging)."""
    if hops == 0:
        return None
    column = {n: k for k, n in enumerate(node_ids)}
    undirected = graph.to_undirected(as_view=True)
    m = np.zeros((len(node_ids), len(node_ids)))
    for k, node in enumerate(node_ids):
        near = [column[n] for n in nx.single_source_shortest_path_length(undirected, node, cutoff=hops)]
        m[k, near] = 1.0 / len(near)
    return m


class LikelihoodError(ValueError):
    """The references do not support a likelihood (neighbouring places no more alike than far ones)."""


@dataclass(frozen=True)
class SimilarityModel:
    """The likelihood ratio of a contrast score: normal densities of the score of a view against
    the place it was taken at (``same``) and against far places (``other``), with one pooled
    spread, so that the log-ratio is linear in the score: ``slope * (c - midpoint)``, the midpoint
    halfway between the two means (a score there says as much for here as for elsewhere). Scores
    below ``mean_other`` count as ``mean_other`` (most places score there: a low score says
    little), scores above ``mean_same + CAP_STDS * std`` as that (one look-alike, however alike,
    must not outweigh the views before it)."""

    mean_same: float
    mean_other: float
    std: float

    #: the least separation of the two means, in pooled spreads, that makes a usable likelihood
    MIN_SEPARATION = 0.25
    CAP_STDS = 2.0

    def __post_init__(self) -> None:
        for name in ("mean_same", "mean_other", "std"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name} must be finite, got {getattr(self, name)!r}")
        if not self.std > 0:
            raise ValueError(f"std must be positive, got {self.std}")
        if not self.mean_same - self.mean_other >= self.MIN_SEPARATION * self.std:
            raise LikelihoodError(
                f"same-place scores (mean {self.mean_same:.2f}) must exceed other-place scores (mean "
                f"{self.mean_other:.2f}) by {self.MIN_SEPARATION} spreads ({self.std:.2f}): neighbouring places "
                "look no more alike than far ones, so views cannot tell places apart")

    @property
    def slope(self) -> float:
        return (self.mean_same - self.mean_other) / (self.std * self.std)

    @classmethod
    def fit(cls, same: Sequence[float], other: Sequence[float]) -> "SimilarityModel":
        """Fit on samples of contrast scores (at least 5 of each)."""
        s, o = np.asarray(same, dtype=float), np.asarray(other, dtype=float)
        s, o = s[np.isfinite(s)], o[np.isfinite(o)]
        if s.size < 5 or o.size < 5:
            raise LikelihoodError(f"need at least 5 same-place and 5 other-place scores, got {s.size} and {o.size}")
        pooled = math.sqrt((s.var() * s.size + o.var() * o.size) / (s.size + o.size))
        return cls(float(s.mean()), float(o.mean()), max(pooled, 0.05))

    @classmethod
    def from_references(cls, descriptors: np.ndarray, graph: nx.DiGraph, node_ids: Sequence[NodeId], *,
                        same_hops: int = 1, far_hops: int = 4, smoothing_hops: int = 0) -> "SimilarityModel":
        """Fit on the map's own keyframes (L2-normalised rows of ``descriptors``, column order
        ``node_ids``), leaving each one out of its own row: ``same`` is its contrast score against
        the nodes within ``same_hops`` arcs (a view is never farther than that from the node it is
        at), ``other`` against nodes more than ``far_hops`` arcs away (or unconnected). With
        ``smoothing_hops``, the scores are first averaged over each node's neighbourhood
        (:func:`neighbourhood_mean`), as the filter will average them."""
        x = np.asarray(descriptors, dtype=float)
        n = len(node_ids)
        if x.ndim != 2 or x.shape[0] != n or not np.all(np.isfinite(x)):
            raise ValueError(f"descriptors must be {n} finite rows (one per node), got shape {x.shape}")
        if not 0 < same_hops < far_hops:
            raise ValueError(f"need 0 < same_hops < far_hops, got {same_hops} and {far_hops}")
        column = {node: k for k, node in enumerate(node_ids)}
        undirected = graph.to_undirected(as_view=True)
        similarity = x @ x.T
        smooth = neighbourhood_mean(graph, node_ids, smoothing_hops)
        same, other = [], []
        for k, node in enumerate(node_ids):
            hops = np.full(n, np.inf)
            for m, h in nx.single_source_shortest_path_length(undirected, node, cutoff=far_hops).items():
                hops[column[m]] = h
            keep = np.arange(n) != k
            scores = np.full(n, np.nan)
            scores[keep] = contrast(similarity[k, keep])
            if smooth is not None:            # the mean over the neighbourhood, without the left-out column
                weights = smooth * keep
                scores = (weights @ np.where(keep, scores, 0.0)) / np.maximum(weights.sum(axis=1), _EPS)
                scores[~keep] = np.nan
            same.extend(scores[(hops >= 1) & (hops <= same_hops)])
            other.extend(scores[hops > far_hops])
        return cls.fit(same, other)

    def log_ratio(self, scores: np.ndarray, capped: bool = True) -> np.ndarray:
        """``log p(c | same) - log p(c | other)``, the scores clipped to ``[mean_other, mean_same +
        CAP_STDS * std]``: between ``-slope * gap / 2`` and ``slope * (gap / 2 + CAP_STDS * std)``
        for ``gap = mean_same - mean_other``. ``capped=False`` keeps the upper end: for a single
        view placed on its own (a goal image), where no earlier views stand to be outweighed and
        the best of two look-alikes must still win."""
        upper = self.mean_same + self.CAP_STDS * self.std if capped else math.inf
        c = np.clip(np.asarray(scores, dtype=float), self.mean_other, upper)
        return self.slope * (c - 0.5 * (self.mean_same + self.mean_other))


@dataclass(frozen=True)
class BeliefSnapshot:
    """The belief at one step: the top nodes with their mass (the mode first), the mass within
    ``confidence_hops`` of the mode, the entropy over nodes, and the robot's most probable
    heading at the mode relative to the route there (degrees, 0: along the route; None: the
    belief has no directions)."""

    top: tuple[tuple[NodeId, float], ...]
    confidence: float
    entropy_bits: float
    facing_deg: Optional[float] = None

    @property
    def mode(self) -> NodeId:
        return self.top[0][0]


class NodeBelief:
    """The filter (see the module docstring). ``arc_lengths_m[(src, dst)]``: metric arc lengths
    (None: a map without odometry, every arc one unit). ``node_headings[node]``: the mapping
    drive's heading at every node (radians, any common frame); with ``config.heading_bins`` > 1
    the state holds the robot's direction relative to the route, which needs them."""

    def __init__(self, graph: nx.DiGraph, node_ids: Sequence[NodeId], model: SimilarityModel,
                 config: BeliefConfig = BeliefConfig(), arc_lengths_m: Optional[Mapping[tuple, float]] = None,
                 node_headings: Optional[Mapping[NodeId, float]] = None):
        self.node_ids = tuple(node_ids)
        if len(set(self.node_ids)) != len(self.node_ids) or not self.node_ids:
            raise ValueError("node_ids must name each map node once")
        self.config = config
        self.model = model
        self.weight = config.weight
        self.metric = arc_lengths_m is not None
        self.cell_m = config.cell_m if self.metric else 1.0 / config.cells_per_arc
        self.bins = config.heading_bins
        column = {n: k for k, n in enumerate(self.node_ids)}
        missing = [n for n in graph.nodes if n not in column]
        if missing:
            raise ValueError(f"map node {missing[0]!r} is not in node_ids")
        if self.bins > 1:
            if node_headings is None:
                raise ValueError(f"heading_bins {self.bins} needs the mapping drive's heading at every node")
            bad = [n for n in self.node_ids if not math.isfinite(float(node_headings.get(n, math.nan)))]
            if bad:
                raise ValueError(f"node {bad[0]!r} has no finite heading (heading_bins {self.bins})")
        # cells: 0..N-1 the nodes, then the interior cells of every arc; nexts: one cell forward
        n_nodes = len(self.node_ids)
        node_a, node_b, frac = list(range(n_nodes)), list(range(n_nodes)), [0.0] * n_nodes
        nexts: list[list[int]] = [[] for _ in range(n_nodes)]
        for src, dst in sorted(graph.edges, key=lambda e: (column[e[0]], column[e[1]])):
            a, b = column[src], column[dst]
            length = float(arc_lengths_m[(src, dst)]) if self.metric else 1.0
            if not (math.isfinite(length) and length > 0):
                raise ValueError(f"arc {src!r} -> {dst!r} has no positive length ({length!r})")
            n = max(1, int(round(length / self.cell_m))) if self.metric else config.cells_per_arc
            previous = a
            for k in range(1, n):
                cell = len(node_a)
                node_a.append(a)
                node_b.append(b)
                frac.append(k / n)
                nexts.append([])
                nexts[previous].append(cell)
                previous = cell
            nexts[previous].append(b)
        self._node_a, self._node_b, self._frac = np.asarray(node_a), np.asarray(node_b), np.asarray(frac)
        self._nearer = np.where(self._frac < 0.5, self._node_a, self._node_b)   # the node a cell counts for
        self.n_cells = len(node_a)
        self._next = nexts
        self._bin_of_cell = self._cell_bins(node_headings)
        self._build_step_matrices()
        hops = config.confidence_hops
        undirected = graph.to_undirected(as_view=True)
        self._near = [np.array([column[m] for m in nx.single_source_shortest_path_length(undirected, n, cutoff=hops)])
                      for n in self.node_ids]
        self._bin_cos = np.cos(2.0 * math.pi * np.arange(self.bins) / self.bins)
        self._smooth = neighbourhood_mean(graph, self.node_ids, config.smoothing_hops)
        self.reset()

    # -- set-up -----------------------------------------------------------------------------

    def _cell_bins(self, node_headings: Optional[Mapping[NodeId, float]]) -> np.ndarray:
        """The route's heading at every cell, in direction bins (interior cells: turning evenly
        from one end's heading to the other's); differences of these move the relative bins."""
        if self.bins == 1:
            return np.zeros(self.n_cells, dtype=int)
        yaw = np.array([float(node_headings[n]) for n in self.node_ids])
        a, b = yaw[self._node_a], yaw[self._node_b]
        turn = np.remainder(b - a + math.pi, 2.0 * math.pi) - math.pi
        heading = a + self._frac * turn
        return np.round(heading / (2.0 * math.pi / self.bins)).astype(int) % self.bins

    def _build_step_matrices(self) -> None:
        """Sparse one-cell moves forward and backward as (source, target, share, bin shift)
        arrays; a dead end keeps its mass."""
        prevs: list[list[int]] = [[] for _ in range(self.n_cells)]
        for cell, targets in enumerate(self._next):
            for t in targets:
                prevs[t].append(cell)

        def moves(links: list[list[int]]):
            src, dst, share = [], [], []
            for cell, targets in enumerate(links):
                for t in targets or [cell]:
                    src.append(cell)
                    dst.append(t)
                    share.append(1.0 / max(1, len(targets)))
            src, dst = np.asarray(src), np.asarray(dst)
            return src, dst, np.asarray(share), (self._bin_of_cell[src] - self._bin_of_cell[dst]) % self.bins

        self._forward = moves(self._next)
        self._backward = moves(prevs)

    # -- state ------------------------------------------------------------------------------

    def reset(self, prior: Optional[Mapping[NodeId, float]] = None) -> None:
        """Uniform over every state, or ``prior`` (node -> weight) on the node cells, every
        direction alike."""
        self._along = np.zeros(self.bins)
        self._turned = 0.0
        if prior is None:
            self._p = np.full((self.n_cells, self.bins), 1.0 / (self.n_cells * self.bins))
            return
        p = np.zeros((self.n_cells, self.bins))
        column = {n: k for k, n in enumerate(self.node_ids)}
        for node, w in prior.items():
            p[column[node]] += float(w)
        if not p.sum() > 0:
            raise ValueError("prior holds no mass")
        self._p = p / p.sum()

    @property
    def state_probabilities(self) -> np.ndarray:
        """Mass per cell and direction bin, ``(n_cells, heading_bins)``."""
        return self._p.copy()

    @property
    def cell_probabilities(self) -> np.ndarray:
        """Mass per cell, every direction together."""
        return self._p.sum(axis=1)

    @property
    def node_probabilities(self) -> np.ndarray:
        """Mass per node (column order ``node_ids``): each cell's mass goes to the nearer end of its arc."""
        return np.bincount(self._nearer, weights=self.cell_probabilities, minlength=len(self.node_ids))

    @property
    def mode(self) -> NodeId:
        return self.node_ids[int(np.argmax(self.node_probabilities))]

    @property
    def confidence(self) -> float:
        """The mass within ``confidence_hops`` arcs of the mode."""
        return self._confidence(self.node_probabilities)

    @property
    def entropy_bits(self) -> float:
        return self._entropy_bits(self.node_probabilities)

    @property
    def facing_deg(self) -> Optional[float]:
        """The most probable direction at the mode, relative to the route there (degrees in
        (-180, 180]; None without direction bins)."""
        return self._facing_deg(self.node_probabilities)

    def top(self, k: int = 3) -> list[tuple[NodeId, float]]:
        return self._top(self.node_probabilities, k)

    def snapshot(self, k: int = 3) -> "BeliefSnapshot":
        """What a log shows of the belief now (the node masses summed once)."""
        nodes = self.node_probabilities
        return BeliefSnapshot(top=tuple(self._top(nodes, k)), confidence=self._confidence(nodes),
                              entropy_bits=self._entropy_bits(nodes), facing_deg=self._facing_deg(nodes))

    def _confidence(self, nodes: np.ndarray) -> float:
        return float(nodes[self._near[int(np.argmax(nodes))]].sum())

    @staticmethod
    def _entropy_bits(nodes: np.ndarray) -> float:
        nz = nodes[nodes > 0]
        return float(-(nz * np.log2(nz)).sum())

    def _facing_deg(self, nodes: np.ndarray) -> Optional[float]:
        if self.bins == 1:
            return None
        at_mode = self._p[self._nearer == int(np.argmax(nodes))].sum(axis=0)
        angle = 360.0 * int(np.argmax(at_mode)) / self.bins
        return angle - 360.0 if angle > 180.0 else angle

    def _top(self, nodes: np.ndarray, k: int) -> list[tuple[NodeId, float]]:
        order = np.argsort(-nodes, kind="stable")[:k]
        return [(self.node_ids[int(j)], float(nodes[j])) for j in order]

    # -- updates ----------------------------------------------------------------------------

    def move(self, along: float, turned_rad: float = 0.0) -> None:
        """Add a motion: ``along`` the robot's heading (metres on a metric map, arcs otherwise;
        negative when reversing) and a turn (radians, counter-clockwise positive). Each direction
        advances one cell for every cell length it passes along the route (module docstring)."""
        for name, value in (("along", along), ("turned_rad", turned_rad)):
            if not math.isfinite(value):
                raise ValueError(f"{name} must be a finite number, got {value!r}")
        self._turn(turned_rad)
        self._along += along * self._bin_cos
        while True:
            forward, backward = self._along >= self.cell_m - 1e-12, self._along <= -self.cell_m + 1e-12
            if not (forward.any() or backward.any()):
                break
            self._along[forward] -= self.cell_m
            self._along[backward] += self.cell_m
            self._advance(forward, backward)

    def advance(self) -> None:
        """Every direction one cell along its way (node units: one arc's cell), then mixing."""
        forward = self._bin_cos > 1e-9
        self._advance(forward, self._bin_cos < -1e-9)

    def _advance(self, forward: np.ndarray, backward: np.ndarray) -> None:
        """The mass of the ``forward`` direction bins one cell along the arcs, of the ``backward``
        bins one cell back, with ``stay`` and ``skip`` (module docstring), then mixing."""
        c = self.config
        p = self._p.copy()
        for bins, links in ((forward, self._forward), (backward, self._backward)):
            if not bins.any():
                continue
            moving = np.where(bins, p, 0.0)
            one = self._shift(moving, links)
            p = p - moving + c.stay * moving + (1.0 - c.stay - c.skip) * one
            if c.skip > 0:
                p = p + c.skip * self._shift(one, links)
        self._p = self._mixed(p)

    def _turn(self, turned_rad: float) -> None:
        """Roll the direction bins by the turn, a whole bin at a time (the rest is kept for the next
        turn), ``turn_slip`` landing one bin short or over."""
        if self.bins == 1:
            return
        width = 2.0 * math.pi / self.bins
        self._turned += turned_rad
        k = int(math.floor(self._turned / width + 0.5))
        if k == 0:
            return
        self._turned -= k * width
        slip = self.config.turn_slip
        sign = 1 if k > 0 else -1
        for _ in range(abs(k)):
            p = self._p
            self._p = (1.0 - 2.0 * slip) * np.roll(p, sign, axis=1) + slip * p + slip * np.roll(p, 2 * sign, axis=1)

    def observe(self, similarities: np.ndarray) -> None:
        """Multiply by the likelihood of the view's similarity to every node (column order)."""
        row = np.asarray(similarities, dtype=float)
        if row.shape != (len(self.node_ids),) or not np.all(np.isfinite(row)):
            raise ValueError(f"expected {len(self.node_ids)} finite similarities, got shape {row.shape}")
        scores = contrast(row)
        if self._smooth is not None:
            scores = self._smooth @ scores
        ratio = self.model.log_ratio(scores)
        cell = (1.0 - self._frac) * ratio[self._node_a] + self._frac * ratio[self._node_b]
        logp = np.log(np.maximum(self._p, _EPS))
        logp[:, 0] += self.weight * cell           # only facing along the route expects the node's view
        logp -= logp.max()
        p = np.exp(logp)
        self._p = self._mixed(p / p.sum())

    def _shift(self, p: np.ndarray, links: tuple) -> np.ndarray:
        src, dst, share, shift = links
        bins = np.arange(self.bins)
        target = dst[:, None] * self.bins + (bins[None, :] + shift[:, None]) % self.bins
        moved = np.bincount(target.ravel(), weights=(p[src] * share[:, None]).ravel(), minlength=p.size)
        return moved.reshape(p.shape)

    def _mixed(self, p: np.ndarray) -> np.ndarray:
        eps = self.config.mixing
        p = (1.0 - eps) * p + eps / p.size
        return p / p.sum()

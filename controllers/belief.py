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
node units.

**Motion.** The robot drives forward along the directed arcs. :meth:`NodeBelief.move` adds the
odometry distance travelled; each time it passes a cell length, the mass advances one cell (two
with probability ``skip``, none with ``stay``: wheel slip, a bumper, arcs of odd lengths). At a
node the mass splits evenly over its outgoing arcs. Turning in place moves nothing.

**Measurement.** :meth:`NodeBelief.observe` takes the view's similarity to every node, turns it
into contrast scores (:func:`contrast`: robust to a global drop of every cosine under other
lighting) and multiplies each node's mass by the likelihood ratio of its score,
``p(c | here) / p(c | elsewhere)``, from two normal densities fitted on the map's own walkthrough
(:meth:`SimilarityModel.from_references`: how a keyframe scores against its neighbours on the
route versus far places), raised to a ``weight`` below one when successive views are not
independent (a camera that looks many times per cell). A cell between two nodes takes the ratios
of both, weighted by its position. No hand threshold enters the update.

**Recovery.** After every update a ``mixing`` share of the mass is spread over all cells: a robot
carried elsewhere (kidnapped) is found again once its views say so.

The filter answers: the most probable node (:attr:`mode`), the mass within ``confidence_hops`` of
it (:attr:`confidence`), the entropy, and the top nodes with their mass (for logs).

On a loop with one cell per arc the two steps are filterpy's ``discrete_bayes.predict`` (kernel
stay / advance / skip) and ``update`` (a test holds them equal); the filter is numpy because a
map's graph branches where filterpy convolves a 1-D array, and the update runs in log space.
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


class LikelihoodError(ValueError):
    """The references do not support a likelihood (neighbouring places no more alike than far ones)."""


@dataclass(frozen=True)
class SimilarityModel:
    """The likelihood ratio of a contrast score: normal densities of the score of a view against
    the place it was taken at (``same``) and against far places (``other``), with one pooled
    spread, so that the log-ratio is linear in the score: ``slope * (c - mean_other)``. Scores
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
                        same_hops: int = 1, far_hops: int = 4) -> "SimilarityModel":
        """Fit on the map's own keyframes (L2-normalised rows of ``descriptors``, column order
        ``node_ids``), leaving each one out of its own row: ``same`` is its contrast score against
        the nodes within ``same_hops`` arcs (a view is never farther than that from the node it is
        at), ``other`` against nodes more than ``far_hops`` arcs away (or unconnected)."""
        x = np.asarray(descriptors, dtype=float)
        n = len(node_ids)
        if x.ndim != 2 or x.shape[0] != n or not np.all(np.isfinite(x)):
            raise ValueError(f"descriptors must be {n} finite rows (one per node), got shape {x.shape}")
        if not 0 < same_hops < far_hops:
            raise ValueError(f"need 0 < same_hops < far_hops, got {same_hops} and {far_hops}")
        column = {node: k for k, node in enumerate(node_ids)}
        undirected = graph.to_undirected(as_view=True)
        similarity = x @ x.T
        same, other = [], []
        for k, node in enumerate(node_ids):
            hops = np.full(n, np.inf)
            for m, h in nx.single_source_shortest_path_length(undirected, node, cutoff=far_hops).items():
                hops[column[m]] = h
            keep = np.arange(n) != k
            scores = np.full(n, np.nan)
            scores[keep] = contrast(similarity[k, keep])
            same.extend(scores[(hops >= 1) & (hops <= same_hops)])
            other.extend(scores[hops > far_hops])
        return cls.fit(same, other)

    def log_ratio(self, scores: np.ndarray) -> np.ndarray:
        """``log p(c | same) - log p(c | other)`` up to a constant, in ``[0, slope * (mean_same +
        CAP_STDS * std - mean_other)]``."""
        c = np.clip(np.asarray(scores, dtype=float), self.mean_other, self.mean_same + self.CAP_STDS * self.std)
        return self.slope * (c - self.mean_other)


@dataclass(frozen=True)
class BeliefSnapshot:
    """The belief at one step: the top nodes with their mass (the mode first), the mass within
    ``confidence_hops`` of the mode, and the entropy over nodes."""

    top: tuple[tuple[NodeId, float], ...]
    confidence: float
    entropy_bits: float

    @property
    def mode(self) -> NodeId:
        return self.top[0][0]


class NodeBelief:
    """The filter (see the module docstring). ``arc_lengths_m[(src, dst)]``: metric arc lengths
    (None: a map without odometry, every arc one unit). ``weight``: the exponent of the
    likelihood, calibrated per map (:func:`robot.episode.belief.calibrate`)."""

    def __init__(self, graph: nx.DiGraph, node_ids: Sequence[NodeId], model: SimilarityModel,
                 config: BeliefConfig = BeliefConfig(), arc_lengths_m: Optional[Mapping[tuple, float]] = None,
                 weight: float = 0.1):
        if not (math.isfinite(weight) and weight > 0):
            raise ValueError(f"weight must be a positive number, got {weight!r}")
        self.node_ids = tuple(node_ids)
        if len(set(self.node_ids)) != len(self.node_ids) or not self.node_ids:
            raise ValueError("node_ids must name each map node once")
        self.config = config
        self.model = model
        self.weight = config.weight
        self.metric = arc_lengths_m is not None
        self.cell_m = config.cell_m if self.metric else 1.0 / config.cells_per_arc
        column = {n: k for k, n in enumerate(self.node_ids)}
        missing = [n for n in graph.nodes if n not in column]
        if missing:
            raise ValueError(f"map node {missing[0]!r} is not in node_ids")
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
        self.n_cells = len(node_a)
        self._next = nexts
        self._build_step_matrices()
        hops = config.confidence_hops
        undirected = graph.to_undirected(as_view=True)
        self._near = [np.array([column[m] for m in nx.single_source_shortest_path_length(undirected, n, cutoff=hops)])
                      for n in self.node_ids]
        self._p = np.full(self.n_cells, 1.0 / self.n_cells)
        self._travelled = 0.0

    # -- set-up -----------------------------------------------------------------------------

    def _build_step_matrices(self) -> None:
        """Sparse one-cell and two-cell moves as (source, target, share) arrays."""
        src1, dst1, w1 = [], [], []
        for cell, targets in enumerate(self._next):
            if not targets:                       # a dead end: the mass stays
                targets = [cell]
            for t in targets:
                src1.append(cell)
                dst1.append(t)
                w1.append(1.0 / len(targets))
        self._one = (np.asarray(src1), np.asarray(dst1), np.asarray(w1))

    # -- state ------------------------------------------------------------------------------

    def reset(self, prior: Optional[Mapping[NodeId, float]] = None) -> None:
        """Uniform over every cell, or ``prior`` (node -> weight) on the node cells."""
        self._travelled = 0.0
        if prior is None:
            self._p = np.full(self.n_cells, 1.0 / self.n_cells)
            return
        p = np.zeros(self.n_cells)
        column = {n: k for k, n in enumerate(self.node_ids)}
        for node, w in prior.items():
            p[column[node]] += float(w)
        if not p.sum() > 0:
            raise ValueError("prior holds no mass")
        self._p = p / p.sum()

    @property
    def cell_probabilities(self) -> np.ndarray:
        return self._p.copy()

    @property
    def node_probabilities(self) -> np.ndarray:
        """Mass per node (column order ``node_ids``): each cell's mass goes to the nearer end of its arc."""
        nearer = np.where(self._frac < 0.5, self._node_a, self._node_b)
        return np.bincount(nearer, weights=self._p, minlength=len(self.node_ids))

    @property
    def mode(self) -> NodeId:
        return self.node_ids[int(np.argmax(self.node_probabilities))]

    @property
    def confidence(self) -> float:
        """The mass within ``confidence_hops`` arcs of the mode."""
        nodes = self.node_probabilities
        return float(nodes[self._near[int(np.argmax(nodes))]].sum())

    @property
    def entropy_bits(self) -> float:
        nodes = self.node_probabilities
        nz = nodes[nodes > 0]
        return float(-(nz * np.log2(nz)).sum())

    def top(self, k: int = 3) -> list[tuple[NodeId, float]]:
        nodes = self.node_probabilities
        order = np.argsort(-nodes, kind="stable")[:k]
        return [(self.node_ids[int(j)], float(nodes[j])) for j in order]

    def snapshot(self, k: int = 3) -> "BeliefSnapshot":
        """What a log shows of the belief now."""
        return BeliefSnapshot(top=tuple(self.top(k)), confidence=self.confidence, entropy_bits=self.entropy_bits)

    # -- updates ----------------------------------------------------------------------------

    def move(self, travelled: float) -> None:
        """Add a distance travelled forward (metres on a metric map, arcs otherwise); the mass
        advances one cell for every cell length passed."""
        if not (math.isfinite(travelled) and travelled >= 0):
            raise ValueError(f"travelled must be a finite distance >= 0, got {travelled!r}")
        self._travelled += travelled
        while self._travelled >= self.cell_m:
            self._travelled -= self.cell_m
            self.advance()

    def advance(self) -> None:
        """One cell forward, with ``stay`` and ``skip`` (see the module docstring), then mixing."""
        c = self.config
        one = self._shift(self._p)
        p = c.stay * self._p + (1.0 - c.stay - c.skip) * one
        if c.skip > 0:
            p = p + c.skip * self._shift(one)
        self._p = self._mixed(p)

    def observe(self, similarities: np.ndarray) -> None:
        """Multiply by the likelihood of the view's similarity to every node (column order)."""
        row = np.asarray(similarities, dtype=float)
        if row.shape != (len(self.node_ids),) or not np.all(np.isfinite(row)):
            raise ValueError(f"expected {len(self.node_ids)} finite similarities, got shape {row.shape}")
        ratio = self.model.log_ratio(contrast(row))
        cell = (1.0 - self._frac) * ratio[self._node_a] + self._frac * ratio[self._node_b]
        logp = np.log(np.maximum(self._p, _EPS)) + self.weight * cell
        logp -= logp.max()
        p = np.exp(logp)
        self._p = self._mixed(p / p.sum())

    def _shift(self, p: np.ndarray) -> np.ndarray:
        src, dst, w = self._one
        return np.bincount(dst, weights=p[src] * w, minlength=self.n_cells)

    def _mixed(self, p: np.ndarray) -> np.ndarray:
        eps = self.config.mixing
        p = (1.0 - eps) * p + eps / self.n_cells
        return p / p.sum()

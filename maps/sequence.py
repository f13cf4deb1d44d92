"""Sequence verification (SeqSLAM-like): does a stretch of frames keep following one stretch of
the map? One frame cannot tell two corners with bare walls apart, a stretch of route can. The
builder checks loop-closure candidates with it and the merge pass checks near-duplicate pairs.
:func:`check_sequence` compares the frames with the map's nodes; :func:`check_sequence_on_frames`
with the walkthrough's own frames, for a stretch too short to average out node spacing."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Collection, Optional

import numpy as np

from maps.graph import MapBuildError, TopoMap


@dataclass(frozen=True)
class SequenceCheck:
    """The outcome of :func:`check_sequence`.

    ``frames``: descriptors compared (the candidate's frame included). ``support``: their mean
    similarity to the tracked node of the candidate's stretch of route; ``rival``: their mean best
    similarity to any other eligible node (``None`` when there is none); ``wins``: the fraction of
    them whose best match lies on the tracked stretch. ``path``: the tracked nodes, in order.
    """

    frames: int
    support: float
    rival: Optional[float]
    wins: float
    path: tuple[int, ...]
    accepted: bool


def route_region(topomap: TopoMap, node: int, hops: int, forward: bool = True,
                 exclude: Collection[int] = ()) -> list[int]:
    """``node`` and the nodes up to ``hops`` arcs after it (``forward``) or before it, following
    arc directions (the stretch of route a robot at ``node`` drives into, or came from), minus
    ``exclude``, in breadth-first order (``node`` first unless excluded)."""
    g = topomap.graph
    seen, frontier = [node], [node]
    for _ in range(hops):
        nxt = []
        for n in frontier:
            for m in (g.successors(n) if forward else g.predecessors(n)):
                if m not in seen:
                    seen.append(m)
                    nxt.append(m)
        frontier = nxt
    skip = set(exclude)
    return [n for n in seen if n not in skip]


def check_sequence(window: np.ndarray, topomap: TopoMap, start: int, *, eligible: Collection[int],
                   hops: int, min_support: float, forward: bool = True) -> SequenceCheck:
    """Does a stretch of frames keep following one stretch of the map? (SeqSLAM-like)

    ``window`` (K, D): the candidate frame first, then the frames after it (or, with
    ``forward=False``, the frames before it, latest first). The check tracks a position along
    the map's arcs: it starts at ``start`` and, frame by frame, moves to whichever node within
    ``hops`` arcs ahead (behind, when not ``forward``) of it matches the frame best, so a real
    revisit is followed as the robot drives on. Each frame's score on the stretch is compared
    with its best score at any other node of ``eligible`` (the nodes a loop closure could go to).

    Accepted when the mean score on the stretch is at least ``min_support``, above the mean best
    score elsewhere, and the stretch has the best match for at least half of the frames. Two
    look-alike corners match each other for a while, but once the routes through them part the
    true place wins; a real revisit keeps matching.
    """
    w = np.asarray(window, dtype=np.float32)
    if w.ndim != 2 or w.shape[0] == 0:
        raise MapBuildError(f"check_sequence needs (K >= 1, D) frames, got shape {w.shape}")
    ids = topomap.node_ids.tolist()
    row = {n: k for k, n in enumerate(ids)}
    eligible = set(int(n) for n in eligible)
    if start not in eligible:
        raise MapBuildError(f"check_sequence: start node {start} is not among the eligible nodes")
    sims = w @ topomap.descriptors.T                                   # (K, N)
    pos, path, on_route = start, [start], {start}
    own, best_other = [], []
    for k in range(w.shape[0]):
        reach = [n for n in route_region(topomap, pos, hops, forward=forward) if n in eligible]
        on_route.update(reach)
        scores = sims[k, [row[n] for n in reach]]
        pos = reach[int(np.argmax(scores))]
        if pos != path[-1]:
            path.append(pos)
        own.append(float(scores.max()))
        others = [row[n] for n in eligible if n not in on_route]
        best_other.append(float(sims[k, others].max()) if others else -np.inf)
    return _judge(own, best_other, min_support, tuple(path))


def _judge(own: list[float], best_other: list[float], min_support: float, path: tuple[int, ...]) -> SequenceCheck:
    own_a, other_a = np.asarray(own), np.asarray(best_other)
    support = float(own_a.mean())
    has_rivals = bool(np.isfinite(other_a).all())
    rival = float(other_a.mean()) if has_rivals else None
    wins = float(np.mean(own_a > other_a))
    accepted = support >= min_support and (rival is None or (support > rival and wins >= 0.5))
    return SequenceCheck(frames=len(own), support=support, rival=rival, wins=wins,
                         path=path, accepted=bool(accepted))


def check_sequence_on_frames(window: np.ndarray, topomap: TopoMap, start: int, *, frames: np.ndarray,
                             frame_nodes: np.ndarray, eligible: Collection[int], hops: int,
                             min_support: float) -> SequenceCheck:
    """:func:`check_sequence` against the walkthrough's frames instead of the map's nodes.

    ``frames`` (M, D): earlier walkthrough frames; ``frame_nodes`` (M,): the node the builder
    stood at for each. A window frame's score on the route is its best similarity to a frame
    taken at ``start``, at a node up to ``hops`` arcs after it, or at the node before it (a
    revisit may begin half a spacing early); its rival score the best over frames of the other
    ``eligible`` nodes. Judged by the same rule as :func:`check_sequence`. Why: on a real revisit
    every frame lies within one frame step of an old frame but up to half a node spacing from a
    node, and a short window (the walkthrough ended) cannot average that offset out.
    """
    w = np.asarray(window, dtype=np.float32)
    if w.ndim != 2 or w.shape[0] == 0:
        raise MapBuildError(f"check_sequence_on_frames needs (K >= 1, D) frames, got shape {w.shape}")
    f = np.asarray(frames)
    nodes = np.asarray(frame_nodes)
    if f.ndim != 2 or nodes.shape != (f.shape[0],):
        raise MapBuildError(f"check_sequence_on_frames: frames {f.shape} and frame_nodes {nodes.shape} disagree")
    eligible = set(int(n) for n in eligible)
    if start not in eligible:
        raise MapBuildError(f"check_sequence_on_frames: start node {start} is not among the eligible nodes")
    region = set(route_region(topomap, start, hops)) | set(topomap.graph.predecessors(start))
    region &= eligible
    on_route = np.isin(nodes, sorted(region))
    elsewhere = np.isin(nodes, sorted(eligible - region))
    sims = w @ f.astype(np.float32).T                                   # (K, M)
    own = sims[:, on_route].max(axis=1) if on_route.any() else np.full(w.shape[0], -np.inf)
    other = sims[:, elsewhere].max(axis=1) if elsewhere.any() else np.full(w.shape[0], -np.inf)
    return _judge(own.tolist(), other.tolist(), min_support, tuple(sorted(region)))

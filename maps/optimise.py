"""The optimisation pass: merge near-duplicate nodes and rewire their arcs.

The paper's map optimisation, case (b): two nodes that show the same place (the builder missed
the loop closure because the revisit frame was not quite similar enough, or came between two
node decisions) are merged by a second loop-closure threshold ``T_merge``, no lower than the
similarity different places reach, and only with the same sequence evidence a loop closure needs.

Rules:

* a pair is merged when its descriptor similarity is at least ``T_merge`` and the two nodes are
  not route neighbours. Taking the graph as undirected, neighbours are at most
  ``loop_exclude_recent_nodes`` arcs apart (at least 1), or joined by a path spanning fewer than
  ``loop_min_gap_frames`` frames (the sum of the arcs' ``n_frames``): the builder's loop-closure
  exclusion rule, in map terms. Neighbours are similar because they are near, not because the
  route came back;
* with sequence verification on (``loop_verify_frames > 0``) a pair must also pass the builder's
  check (:func:`maps.sequence.check_sequence`), the "their neighbours are alike too" test: the
  later node's keyframe and the ``loop_verify_frames`` walkthrough frames after it (or, without
  the walkthrough's frames, the later node and its successors) must follow the earlier node and
  the route on from it better than anything else, at least ``T_loop_verify`` on average; and the same
  backwards, with predecessors, unless the earlier node starts the route. A lone look-alike pair
  of corners fails it: the approaches to two bare walls may look alike, but the routes part;
* pairs are taken from the most similar down; a node joins a group only when it is also at least
  ``T_merge`` similar to the group's kept node, so chains of look-alikes do not snowball;
* the kept node is the earliest one (lowest descriptor row, i.e. first built); it keeps its id,
  descriptor and keyframe;
* every arc is redirected to the kept nodes, keeping its direction; arcs that would become
  self-loops are dropped; of parallel arcs the cheaper one is kept (an untouched arc wins a
  tie); a redirected arc gets kind ``merged``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Optional

import networkx as nx
import numpy as np

from maps.config import MapThresholds
from maps.graph import MapError, TopoMap
from maps.sequence import SequenceCheck, check_sequence, route_region


@dataclass(frozen=True)
class MergeResult:
    """The optimised map; ``merged`` maps each removed node to the node it was merged into;
    ``pairs`` lists (removed, kept, similarity) in merge order; ``rejected`` the pairs above
    ``T_merge`` that failed sequence verification, as (later, earlier, similarity, support)."""

    topomap: TopoMap
    merged: dict
    pairs: tuple[tuple[int, int, float], ...]
    dropped_self_loops: int
    rejected: tuple[tuple[int, int, float, float], ...] = ()

    def summary(self) -> dict:
        return {"merged_nodes": len(self.merged), "pairs": [list(p) for p in self.pairs],
                "dropped_self_loops": self.dropped_self_loops,
                "rejected_pairs": [list(p) for p in self.rejected]}


def _nearby_pairs(topomap: TopoMap, hops: int, gap_frames: int) -> set[tuple[int, int]]:
    """Node pairs (a < b) at most ``hops`` arcs apart or joined by a path of fewer than
    ``gap_frames`` frames, ignoring arc direction."""
    g = nx.Graph()
    g.add_nodes_from(topomap.graph.nodes)
    for arc in topomap.arcs():
        frames = arc.n_frames
        if g.has_edge(arc.src, arc.dst):
            frames = min(frames, g.edges[arc.src, arc.dst]["n_frames"])
        g.add_edge(arc.src, arc.dst, n_frames=frames)
    near = set()
    for a in g.nodes:
        within = set(nx.single_source_shortest_path_length(g, a, cutoff=hops))
        if gap_frames > 0:
            lengths = nx.single_source_dijkstra_path_length(g, a, cutoff=gap_frames, weight="n_frames")
            within.update(b for b, frames in lengths.items() if frames < gap_frames)
        near.update((a, b) for b in within if a < b)
    return near


def _verify_pair(topomap: TopoMap, earlier: int, later: int, near: set, thresholds: MapThresholds,
                 frames: Optional[np.ndarray], keyframe_seq: Optional[Mapping[int, int]]) -> SequenceCheck:
    """The builder's sequence check for merging ``later`` into ``earlier``: forwards (what
    follows ``later`` must follow the route on from ``earlier``) and, when ``earlier`` has
    predecessors, backwards too. Returns the first check that fails, else the forward one."""
    ids = topomap.node_ids.tolist()
    row = {n: k for k, n in enumerate(ids)}
    exclude = {later} | {b if a == later else a for a, b in near if later in (a, b)}
    eligible = [n for n in ids if n not in exclude]
    k, hops = thresholds.loop_verify_frames, thresholds.loop_verify_hops
    checks = []
    for forward in (True, False):
        if not forward and not any(n in eligible for n in topomap.graph.predecessors(earlier)):
            break                     # the route starts at ``earlier``: nothing came before it
        if frames is not None:
            s = keyframe_seq[later]
            window = frames[s:s + k + 1] if forward else frames[max(0, s - k):s + 1][::-1]
        else:
            window = topomap.descriptors[[row[n] for n in route_region(topomap, later, hops, forward=forward)]]
        checks.append(check_sequence(window, topomap, earlier, eligible=eligible, hops=hops,
                                     min_support=thresholds.T_loop_verify, forward=forward))
        if not checks[-1].accepted:
            return checks[-1]
    return checks[0]


def merge_near_duplicates(topomap: TopoMap, thresholds: MapThresholds, *, frames: Optional[np.ndarray] = None,
                          keyframe_seq: Optional[Mapping[int, int]] = None) -> MergeResult:
    """Return a new map with near-duplicate nodes merged (see the module docstring).

    ``frames`` (N, D): the walkthrough's descriptors in the order they were fed, with
    ``keyframe_seq`` (node id -> its keyframe's position in ``frames``): sequence verification
    then looks at the frames after (and before) the later node instead of at its graph
    neighbours, which is finer and also works at the ends of the route.
    """
    ids = topomap.node_ids
    n = len(ids)
    x = topomap.descriptors
    sim = x @ x.T
    if frames is not None:
        if keyframe_seq is None:
            raise MapError("merge_near_duplicates: frames need keyframe_seq (node id -> frame position)")
        missing = [int(i) for i in ids if int(i) not in keyframe_seq]
        if missing:
            raise MapError(f"merge_near_duplicates: keyframe_seq has no entry for node {missing[0]}")
        frames = np.asarray(frames, dtype=np.float32)
    near = _nearby_pairs(topomap, max(1, thresholds.loop_exclude_recent_nodes), thresholds.loop_min_gap_frames)
    rows_i, rows_j = np.nonzero(np.triu(sim >= thresholds.T_merge, k=1))
    order = np.argsort(-sim[rows_i, rows_j], kind="stable")

    parent = list(range(n))          # union-find over rows; the root is the lowest row

    def find(r: int) -> int:
        while parent[r] != r:
            parent[r] = parent[parent[r]]
            r = parent[r]
        return r

    def is_near(ra: int, rb: int) -> bool:
        a, b = int(ids[ra]), int(ids[rb])
        return (min(a, b), max(a, b)) in near

    pairs, rejected = [], []
    for k in order:
        i, j = int(rows_i[k]), int(rows_j[k])
        ri, rj = find(i), find(j)
        if ri == rj or is_near(i, j) or is_near(ri, rj) or sim[ri, rj] < thresholds.T_merge:
            continue
        if thresholds.loop_verify_frames > 0:
            check = _verify_pair(topomap, int(ids[i]), int(ids[j]), near, thresholds, frames, keyframe_seq)
            if not check.accepted:
                rejected.append((int(ids[j]), int(ids[i]), float(sim[i, j]), check.support))
                continue
        keep, drop = min(ri, rj), max(ri, rj)
        parent[drop] = keep
        pairs.append((int(ids[drop]), int(ids[keep]), float(sim[i, j])))

    root_id = {int(ids[r]): int(ids[find(r)]) for r in range(n)}
    out = TopoMap(topomap.dim)
    for node in topomap.nodes():
        if root_id[node.node_id] == node.node_id:
            out.add_node(x[node.row], node.keyframe_index, node.stamp_s, node.true_pose, node_id=node.node_id)

    arcs = topomap.arcs()
    untouched = [a for a in arcs if root_id[a.src] == a.src and root_id[a.dst] == a.dst]
    moved = [a for a in arcs if not (root_id[a.src] == a.src and root_id[a.dst] == a.dst)]
    dropped = 0
    for arc in untouched:
        out.add_arc(arc.src, arc.dst, arc.weight, arc.kind, arc.n_frames, arc.length_m)
    for arc in moved:
        src, dst = root_id[arc.src], root_id[arc.dst]
        if src == dst:
            dropped += 1
            continue
        out.add_arc(src, dst, arc.weight, "merged", arc.n_frames, arc.length_m)
    merged = {drop: keep for drop, keep in ((i, root_id[i]) for i in root_id) if drop != keep}
    return MergeResult(topomap=out, merged=merged, pairs=tuple(pairs), dropped_self_loops=dropped,
                       rejected=tuple(rejected))

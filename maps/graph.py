"""The topological map: a directed graph of keyframe nodes with relative-distance arcs.

A node stands for one keyframe of the walkthrough: its index (the caller's frame label), its
timestamp, its descriptor (a row of :attr:`TopoMap.descriptors`) and, on simulator maps only,
the true pose where it was taken. An arc ``a -> b`` says the robot drove from ``a`` to ``b``;
direction matters because a node's image faces the way the robot drove. Its ``weight`` is the
paper's relative distance ``M_distance`` (frames that showed motion), its ``kind`` says where it
came from: ``sequential`` (driven), ``loop_closure`` (the builder recognised an earlier node) or
``merged`` (rewired by the optimisation pass).

Node ids are stable integers. The optimisation pass removes nodes without renumbering, so ids
may have gaps; :attr:`TopoMap.node_ids` lists them in descriptor-row order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import networkx as nx
import numpy as np

from core.hal import Pose2D
from core.yaw_rate import HEADING_SOURCES

ARC_KINDS = ("sequential", "loop_closure", "merged")


class MapError(ValueError):
    """A map is invalid or cannot be built, saved or loaded. The message says what and where."""


class MapBuildError(MapError):
    """Bad input to the builder (wrong shape, not normalised, frames out of order)."""


#: where the mapping drive's heading at a node came from -> the node's field
HEADING_FIELDS = dict(zip(HEADING_SOURCES, ("odom_yaw_rad", "gyro_yaw_rad")))


@dataclass(frozen=True)
class MapNode:
    """One node: ``row`` is its row in :attr:`TopoMap.descriptors`."""

    node_id: int
    keyframe_index: int
    stamp_s: float
    row: int
    true_pose: Optional[Pose2D] = None
    odom_yaw_rad: Optional[float] = None   # the mapping drive's odometry heading here (rad), if recorded
    gyro_yaw_rad: Optional[float] = None   # the mapping drive's integrated gyro heading here (rad), if recorded


@dataclass(frozen=True)
class MapArc:
    """One directed arc. ``weight`` is ``M_distance``; ``n_frames`` the frames it spans;
    ``length_m`` the true path length driven, only on simulator maps."""

    src: int
    dst: int
    weight: float
    kind: str
    n_frames: int = 0
    length_m: Optional[float] = None


class TopoMap:
    """A networkx ``DiGraph`` plus a float32 descriptor matrix, with checked mutation.

    Read the graph through :attr:`graph` (a read-only view, ready for ``nx.dijkstra_path(...,
    weight="weight")``); change it only through :meth:`add_node` and :meth:`add_arc`.
    """

    def __init__(self, dim: int):
        if isinstance(dim, bool) or not isinstance(dim, int) or dim < 1:
            raise MapError(f"descriptor dimension must be a positive integer, got {dim!r}")
        self._dim = dim
        self._g = nx.DiGraph()
        self._desc = np.zeros((16, dim), dtype=np.float32)
        self._ids: list[int] = []
        self._next_id = 0

    # -- reading -------------------------------------------------------------------------
    @property
    def dim(self) -> int:
        return self._dim

    @property
    def graph(self) -> nx.DiGraph:
        """Read-only view of the graph; node attributes are those of :class:`MapNode`, arc
        attributes those of :class:`MapArc` (``weight``, ``kind``, ``n_frames``, ``length_m``)."""
        return self._g.copy(as_view=True)

    @property
    def descriptors(self) -> np.ndarray:
        """(N, D) float32, row ``k`` belongs to ``node_ids[k]``. A read-only view."""
        view = self._desc[: len(self._ids)]
        view = view.view()
        view.flags.writeable = False
        return view

    @property
    def node_ids(self) -> np.ndarray:
        """Node ids in descriptor-row order (int64)."""
        return np.asarray(self._ids, dtype=np.int64)

    def __len__(self) -> int:
        return len(self._ids)

    def __contains__(self, node_id: object) -> bool:
        return node_id in self._g

    @property
    def n_arcs(self) -> int:
        return self._g.number_of_edges()

    def node(self, node_id: int) -> MapNode:
        if node_id not in self._g:
            raise MapError(f"no node {node_id!r} in the map")
        a = self._g.nodes[node_id]
        return MapNode(node_id=node_id, keyframe_index=a["keyframe_index"], stamp_s=a["stamp_s"],
                       row=a["row"], true_pose=a["true_pose"], odom_yaw_rad=a.get("odom_yaw_rad"),
                       gyro_yaw_rad=a.get("gyro_yaw_rad"))

    def nodes(self) -> list[MapNode]:
        """All nodes in descriptor-row order."""
        return [self.node(i) for i in self._ids]

    def has_arc(self, src: int, dst: int) -> bool:
        return self._g.has_edge(src, dst)

    def arc(self, src: int, dst: int) -> MapArc:
        if not self._g.has_edge(src, dst):
            raise MapError(f"no arc {src} -> {dst} in the map")
        a = self._g.edges[src, dst]
        return MapArc(src=src, dst=dst, weight=a["weight"], kind=a["kind"],
                      n_frames=a["n_frames"], length_m=a["length_m"])

    def arcs(self) -> list[MapArc]:
        """All arcs, sorted by (src, dst)."""
        return [self.arc(u, v) for u, v in sorted(self._g.edges())]

    @property
    def arc_lengths_m(self) -> Optional[dict[tuple[int, int], float]]:
        """``(src, dst)`` -> the arc's driven length (metres) when every arc has a positive one (a
        map from a drive), else None (a video or an image folder: node units only)."""
        lengths = {(a.src, a.dst): a.length_m for a in self.arcs()}
        if not lengths or not all(v is not None and v > 0 for v in lengths.values()):
            return None
        return lengths

    def descriptor(self, node_id: int) -> np.ndarray:
        return self.descriptors[self.node(node_id).row]

    def similarities(self, query: np.ndarray) -> np.ndarray:
        """Cosine similarity of an L2-normalised query (D,) to every node, in row order."""
        q = np.asarray(query, dtype=np.float32)
        if q.shape != (self._dim,):
            raise MapError(f"query descriptor has shape {q.shape}, the map needs ({self._dim},)")
        return self.descriptors @ q

    @property
    def has_true_poses(self) -> bool:
        """True when every node carries a true pose (simulator maps)."""
        return len(self._ids) > 0 and all(self._g.nodes[i]["true_pose"] is not None for i in self._ids)

    @property
    def odom_headings(self) -> Optional[dict[int, float]]:
        """Node id -> the mapping drive's odometry heading (rad) when every node has one, else None
        (maps from a video or an image folder). Only differences between nodes mean anything."""
        return self.headings("odometry")

    def headings(self, source: str) -> Optional[dict[int, float]]:
        """Node id -> the mapping drive's heading from ``source`` (``odometry``: the wheels',
        ``gyro``: the gyro's rate integrated) when every node has one, else None (maps from a
        video or an image folder, or made before gyro headings were kept)."""
        if source not in HEADING_FIELDS:
            raise MapError(f"heading source must be one of {sorted(HEADING_FIELDS)}, got {source!r}")
        headings = {i: self._g.nodes[i].get(HEADING_FIELDS[source]) for i in self._ids}
        return headings if self._ids and None not in headings.values() else None

    def set_odom_yaw(self, node_id: int, yaw_rad: Optional[float]) -> None:
        """Record the mapping drive's odometry heading at a node (None: unknown)."""
        self._set_heading(node_id, "odometry", yaw_rad)

    def set_gyro_yaw(self, node_id: int, yaw_rad: Optional[float]) -> None:
        """Record the mapping drive's integrated gyro heading at a node (None: unknown)."""
        self._set_heading(node_id, "gyro", yaw_rad)

    def _set_heading(self, node_id: int, source: str, yaw_rad: Optional[float]) -> None:
        if node_id not in self._g:
            raise MapError(f"no node {node_id!r} in the map")
        if yaw_rad is not None and not (isinstance(yaw_rad, (int, float, np.floating)) and math.isfinite(yaw_rad)):
            raise MapError(f"{source} heading of node {node_id} must be a finite number, got {yaw_rad!r}")
        self._g.nodes[node_id][HEADING_FIELDS[source]] = None if yaw_rad is None else float(yaw_rad)

    def loop_closures(self) -> list[MapArc]:
        return [a for a in self.arcs() if a.kind == "loop_closure"]

    # -- changing ------------------------------------------------------------------------
    def add_node(self, descriptor: np.ndarray, keyframe_index: int, stamp_s: float,
                 true_pose: Optional[Pose2D] = None, node_id: Optional[int] = None) -> int:
        """Add a node and return its id (the next free id unless ``node_id`` is given)."""
        d = np.asarray(descriptor, dtype=np.float32)
        if d.shape != (self._dim,):
            raise MapError(f"node descriptor has shape {d.shape}, the map needs ({self._dim},)")
        if not np.all(np.isfinite(d)):
            raise MapError(f"node descriptor for keyframe {keyframe_index} has NaN or infinite values")
        if not math.isfinite(float(stamp_s)):
            raise MapError(f"node timestamp for keyframe {keyframe_index} is not finite: {stamp_s!r}")
        if true_pose is not None and not isinstance(true_pose, Pose2D):
            raise MapError(f"true_pose must be a Pose2D or None, got {type(true_pose).__name__}")
        if node_id is None:
            node_id = self._next_id
        if isinstance(node_id, bool) or not isinstance(node_id, (int, np.integer)) or node_id < 0:
            raise MapError(f"node id must be a non-negative integer, got {node_id!r}")
        node_id = int(node_id)
        if node_id in self._g:
            raise MapError(f"node {node_id} already exists")
        row = len(self._ids)
        if row == self._desc.shape[0]:
            grown = np.zeros((2 * row, self._dim), dtype=np.float32)
            grown[:row] = self._desc
            self._desc = grown
        self._desc[row] = d
        self._ids.append(node_id)
        self._g.add_node(node_id, keyframe_index=int(keyframe_index), stamp_s=float(stamp_s),
                         row=row, true_pose=true_pose)
        self._next_id = max(self._next_id, node_id + 1)
        return node_id

    def add_arc(self, src: int, dst: int, weight: float, kind: str, n_frames: int = 0,
                length_m: Optional[float] = None) -> MapArc:
        """Add ``src -> dst``; when that arc exists already the cheaper of the two is kept.

        Returns the arc now in the map. Self-loops, unknown nodes, unknown kinds and negative or
        non-finite weights raise :class:`MapError`.
        """
        for end in (src, dst):
            if end not in self._g:
                raise MapError(f"arc {src} -> {dst} refers to unknown node {end}")
        if src == dst:
            raise MapError(f"arc {src} -> {dst} would be a self-loop")
        if kind not in ARC_KINDS:
            raise MapError(f"arc kind {kind!r} is not one of {list(ARC_KINDS)}")
        weight = float(weight)
        if not (math.isfinite(weight) and weight >= 0.0):
            raise MapError(f"arc {src} -> {dst} weight must be finite and >= 0, got {weight!r}")
        if length_m is not None:
            length_m = float(length_m)
        if self._g.has_edge(src, dst) and self._g.edges[src, dst]["weight"] <= weight:
            return self.arc(src, dst)
        self._g.add_edge(src, dst, weight=weight, kind=kind, n_frames=int(n_frames), length_m=length_m)
        return self.arc(src, dst)

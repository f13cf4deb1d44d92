"""Mapping configuration: the paper's thresholds, or a request to derive them from the walkthrough.

Two objects:

* :class:`MappingConfig` is what a person writes in ``configs/`` (loaded with
  ``core.configfile.load_config(MappingConfig, path)``): explicit thresholds, plus
  ``calibrated`` and the single ``sparsity`` knob used when the thresholds are derived
  automatically (see :mod:`maps.calibration`).
* :class:`MapThresholds` is the set of numbers a map was actually built with. It is what the
  builder and the optimisation pass take, and what the map file records.

All similarities are cosines of L2-normalised descriptors, so they lie in [-1, 1]. All frame
counts are counted in frames *fed to the builder* (after any ``--every N`` sampling), not in the
caller's frame labels.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Mapping

from core.validate import check_bool, check_count, check_range, check_similarity


@dataclass(frozen=True)
class MapThresholds:
    """The numbers a map is built with (explicit or calibrated); recorded in the map file.

    See :class:`MappingConfig` for what each one does.
    """

    T_add_new_node: float
    T_interval: int
    T_add_distance: float
    T_loop_closure: float
    T_merge: float
    loop_min_gap_frames: int
    loop_exclude_recent_nodes: int
    # Sequence verification (see MappingConfig). The defaults here switch it off, which is the
    # paper's plain rule and what maps saved before verification existed were built with.
    T_loop_verify: float = -1.0
    loop_verify_frames: int = 0
    loop_verify_hops: int = 3

    def __post_init__(self) -> None:
        for name in ("T_add_new_node", "T_add_distance", "T_loop_closure", "T_merge", "T_loop_verify"):
            check_similarity(name, getattr(self, name))
        check_count("T_interval", self.T_interval, 1)
        check_count("loop_min_gap_frames", self.loop_min_gap_frames, 0)
        check_count("loop_exclude_recent_nodes", self.loop_exclude_recent_nodes, 0)
        check_count("loop_verify_frames", self.loop_verify_frames, 0)
        check_count("loop_verify_hops", self.loop_verify_hops, 0)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> "MapThresholds":
        """Rebuild from :meth:`to_dict`; raises ``ValueError`` naming a missing or bad field.

        Fields with a default (the sequence-verification ones) may be missing: maps built before
        they existed were built without verification, which is what the defaults say."""
        names = [f for f in cls.__dataclass_fields__]
        optional = {"T_loop_verify", "loop_verify_frames", "loop_verify_hops"}
        missing = [n for n in names if n not in data and n not in optional]
        if missing:
            raise ValueError(f"thresholds: missing field {missing[0]!r}")
        unknown = sorted(set(data) - set(names))
        if unknown:
            raise ValueError(f"thresholds: unknown field {unknown[0]!r}")
        return cls(**{n: data[n] for n in names if n in data})


@dataclass(frozen=True)
class MappingConfig:
    """How to turn a walkthrough into a topological map (paper section "Mapping").

    Explicit thresholds (used as they are when ``calibrated`` is false):

    * ``T_add_new_node`` -- a frame becomes a new node when its similarity to the last node drops
      below this. It is the paper's only node-addition rule and covers both of its cases: the view
      drifts away as the robot drives on (distance) or swings away as it turns (turning). Lower
      means sparser maps.
    * ``T_interval`` -- the least number of frames between a node and the next one. Stops a fast
      turn or a glitchy frame from dropping a burst of nodes. Higher means sparser maps.
    * ``T_add_distance`` -- the relative-distance counter ``M_distance`` grows by one only on a
      frame whose similarity to the previous frame is below this, so a robot standing still (or a
      paused video) adds no distance. The counter becomes the weight of the arc into the next node,
      which Dijkstra later minimises.
    * ``T_loop_closure`` -- a frame that would become a node but matches an existing (not recent)
      node above this is a loop-closure *candidate*. When sequence verification confirms it (below)
      the frame is not added; the previous node is linked to the matched one and mapping continues
      from it (the paper's rule). Too low joins different places that look alike.
    * ``T_loop_verify``, ``loop_verify_frames``, ``loop_verify_hops`` -- sequence verification
      (SeqSLAM-like): one frame cannot tell two corners with bare walls apart, a stretch of route
      can. From the candidate node on, the builder follows the old route along its arcs (each
      frame may move the tracked position up to ``loop_verify_hops`` arcs on, to the node that
      matches it best) over the candidate frame and the ``loop_verify_frames`` frames after it.
      Confirmed when, on average over those frames, the tracked stretch matches at least
      ``T_loop_verify`` and better than any other node, and it has the best match for at least
      half of them. Otherwise the candidate is rejected (logged with its scores) and the frame
      becomes a new node. ``loop_verify_frames`` should span the frames it takes the view to change
      completely (look-alike corners stay alike while the robot turns; by then the routes have
      parted). ``loop_verify_frames: 0`` is the paper's unverified rule. A natural
      ``T_loop_verify`` is how alike the walkthrough's own frames half a node spacing apart are:
      on a real revisit no frame is farther than that from a node of the old route.
    * ``T_merge`` -- the optimisation pass merges two non-neighbouring nodes whose similarity is at
      least this (the paper's "lower T_loop_closure after the fact"), rewiring their arcs, but only
      when the same sequence verification passes: the frames after the later node's keyframe
      follow the route on from the earlier node, and the frames before it the route into the
      earlier node. Never set it below the similarity that different places of the walkthrough
      reach: two different places must never merge.
    * ``loop_min_gap_frames`` -- a node is a loop-closure candidate only if its keyframe is at
      least this many frames before the current frame. Frames close in time are trivially similar;
      matching them would be a false loop.
    * ``loop_exclude_recent_nodes`` -- the current node and this many nodes visited just before it
      are never loop-closure candidates, and the optimisation pass never merges nodes this many
      arcs apart or closer, for the same reason (they are neighbours, not revisits).

    Automatic mode:

    * ``calibrated`` -- derive every threshold above except ``loop_exclude_recent_nodes`` and
      ``loop_verify_hops`` (structure, not similarity levels) from the walkthrough's own
      similarity statistics (:func:`maps.calibration.calibrate`); the explicit values are then
      ignored. This answers the paper's main limitation, manual tuning.
    * ``sparsity`` -- the one knob of the calibrated mode, 0..1: how far the similarity to the last
      node may decay, from "next frame" (0, dense) towards "unrelated place" (1, sparse), before a
      new node is added. 0.5 adds a node when the similarity has fallen half way.
    """

    # defaults: configs/default.yaml's values for the default descriptor (EfficientNet-Lite0
    # block 13 + VLAD) on 5 frames/s simulator walkthroughs
    T_add_new_node: float = 0.45
    T_interval: int = 3
    T_add_distance: float = 0.85
    T_loop_closure: float = 0.58
    T_merge: float = 0.58
    loop_min_gap_frames: int = 40
    loop_exclude_recent_nodes: int = 3
    T_loop_verify: float = 0.55
    loop_verify_frames: int = 35
    loop_verify_hops: int = 3
    calibrated: bool = True
    sparsity: float = 0.5

    def __post_init__(self) -> None:
        check_bool("calibrated", self.calibrated)
        check_range("sparsity", self.sparsity, 0.0, 1.0)
        self.explicit_thresholds()   # validates the explicit values with field names

    def explicit_thresholds(self) -> MapThresholds:
        """The explicit thresholds of this config (what ``calibrated: false`` builds with)."""
        return MapThresholds(T_add_new_node=self.T_add_new_node, T_interval=self.T_interval,
                          T_add_distance=self.T_add_distance, T_loop_closure=self.T_loop_closure,
                          T_merge=self.T_merge, loop_min_gap_frames=self.loop_min_gap_frames,
                          loop_exclude_recent_nodes=self.loop_exclude_recent_nodes,
                          T_loop_verify=self.T_loop_verify, loop_verify_frames=self.loop_verify_frames,
                          loop_verify_hops=self.loop_verify_hops)

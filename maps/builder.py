"""The incremental map builder: the paper's "Mapping" section, one frame at a time.

Feed every frame's descriptor (L2-normalised) in walkthrough order with
:meth:`MapBuilder.add_frame`; call :meth:`MapBuilder.finish` at the end to get the
:class:`~maps.graph.TopoMap` and a :class:`BuildLog` of every decision. Per frame ``i``:

1. the first frame becomes node 0;
2. ``M_distance += 1`` when ``sim(frame i, frame i-1) < T_add_distance`` (a still robot adds
   nothing);
3. when ``sim(frame i, last node) < T_add_new_node`` (the view drifted away by driving or by
   turning) and at least ``T_interval`` frames passed since the last node was reached, frame ``i``
   would become a node. First it is compared with every earlier node except the trivially similar
   ones (the loop-closure exclusion rule: the last node, the ``loop_exclude_recent_nodes`` nodes
   visited before it, and nodes whose keyframe is fewer than ``loop_min_gap_frames`` frames
   old). If the best of them scores above ``T_loop_closure`` it is a loop-closure candidate,
   checked by sequence verification (:func:`check_sequence`): frame ``i`` and the
   ``loop_verify_frames`` frames after it must keep matching the old route from the candidate
   on (a position tracked along the old arcs as the robot drives), on average at least
   ``T_loop_verify`` and better than any other node, and for at least half of the frames. When
   the walkthrough ends before that many frames came (a loop drive that stops just past its
   start), the frames there are are compared with the old route's frames rather than its nodes
   (:func:`~maps.sequence.check_sequence_on_frames`): too few to average out node spacing.
   Confirmed, it is a loop closure: no node is added, the arc ``last -> matched`` gets weight
   ``M_distance`` and mapping continues from the matched node (the paper's rule). Otherwise (no
   candidate, or a rejected one, logged with its scores) frame ``i`` becomes a new node with the
   arc ``last -> new`` of weight ``M_distance``. Either way ``M_distance`` restarts from 0.

Verification looks ahead, so the decision about frame ``i`` waits until the frames after it have
been fed (or :meth:`MapBuilder.finish` is called: then the frames fed so far decide). The frames
it waited for are then processed as usual, from wherever the decision left the builder; the
result is exactly what a builder that could see ahead would make. With
``loop_verify_frames: 0`` every decision is immediate and the rule is the paper's.

Frame counts (``T_interval``, ``loop_min_gap_frames``, ``M_distance``) count frames fed to the
builder, so sampling a video with ``--every N`` changes them; ``frame_index`` is only a label
(e.g. the video frame number) stored with each node.

The walkthrough's end adds no node: its last frames are still similar to the last node (that is
why no node was added), so that node already stands for them. A loop drive that stops just past
its start may never have offered the revisit as a candidate (its few frames there came between
node decisions, or each stood half a node spacing from node 0): at :meth:`MapBuilder.finish`,
unless the last decision was a loop closure, the first of the last ``loop_verify_frames`` frames
that matches an eligible earlier *frame* above ``T_loop_closure`` starts a window to the end,
and when that window follows the old route (:func:`~maps.sequence.check_sequence_on_frames`)
the last node is linked to the matched frame's node by a loop-closure arc.

:func:`maps.pipeline.build_map` is the batch form for a recorded walkthrough: calibrate (if
asked), build, optimise. Loop-closure candidates are verified by :mod:`maps.sequence`.
"""

from __future__ import annotations

import json
import math
from collections import deque
from dataclasses import asdict, dataclass, field
from typing import Optional, Sequence

import numpy as np

from core.hal import Pose2D
from maps.config import MapThresholds
from maps.graph import MapBuildError, MapError, TopoMap
from maps.sequence import SequenceCheck, check_sequence, check_sequence_on_frames

#: a descriptor's norm may differ from 1 by this much (float16 storage, accumulated rounding)
NORM_TOLERANCE = 1e-2

EVENT_KINDS = ("first_node", "node", "loop_closure")


@dataclass(frozen=True)
class MapEvent:
    """One decision of the builder, with the scores behind it.

    ``seq`` is the frame's position in the fed sequence, ``frame_index`` the caller's label.
    ``node_id`` is the node the builder stands at afterwards: the new node, or the matched node
    of a loop closure. ``prev_node`` is the node it came from; ``m_distance`` the weight of the
    arc ``prev_node -> node_id``; ``frames_since_prev`` the frames fed since ``prev_node`` was
    reached. ``loop_candidate`` / ``loop_score``: the best eligible earlier node and its
    similarity (``None`` when there was none). ``travelled_m``: true path length since
    ``prev_node`` (simulator walkthroughs only). ``new_arc``: the event put a new (or cheaper)
    arc into the map; a loop closure that only follows an arc driven before has it false.

    Sequence verification (when the candidate scored above ``T_loop_closure``): ``verify_frames``
    frames compared, ``verify_support`` / ``verify_rival`` their mean best similarity to the
    candidate's region / to any other node (see :class:`SequenceCheck`). ``loop_rejected``: a
    ``node`` event whose candidate failed verification.
    """

    kind: str
    seq: int
    frame_index: int
    stamp_s: float
    node_id: int
    prev_node: Optional[int] = None
    score_to_prev_node: Optional[float] = None
    m_distance: int = 0
    frames_since_prev: int = 0
    loop_candidate: Optional[int] = None
    loop_score: Optional[float] = None
    travelled_m: Optional[float] = None
    new_arc: bool = True
    reason: str = ""
    verify_frames: int = 0
    verify_support: Optional[float] = None
    verify_rival: Optional[float] = None
    loop_rejected: bool = False

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> "MapEvent":
        return cls(**data)


@dataclass(frozen=True)
class BuildLog:
    """Everything the builder decided, and the per-frame scores it decided on.

    Per-frame arrays (length = frames fed, index = ``seq``): ``frame_index``, ``stamp_s``,
    ``sim_to_node`` (similarity to the node the builder stood at before the frame; NaN for the
    first frame), ``sim_to_prev`` (to the previous frame; NaN for the first), ``m_distance`` (the
    counter after the frame; 0 right after a node or loop closure) and ``node`` (the node it stands
    at after the frame).
    """

    thresholds: MapThresholds
    events: tuple[MapEvent, ...]
    frame_index: np.ndarray
    stamp_s: np.ndarray
    sim_to_node: np.ndarray
    sim_to_prev: np.ndarray
    m_distance: np.ndarray
    node: np.ndarray
    travelled_m: Optional[float] = None

    @property
    def n_frames(self) -> int:
        return int(self.frame_index.shape[0])

    def node_events(self) -> list[MapEvent]:
        return [e for e in self.events if e.kind in ("first_node", "node")]

    def loop_closure_events(self) -> list[MapEvent]:
        return [e for e in self.events if e.kind == "loop_closure"]

    def rejected_loop_events(self) -> list[MapEvent]:
        """Node events whose loop-closure candidate failed sequence verification."""
        return [e for e in self.events if e.loop_rejected]

    @property
    def deferred_frames(self) -> int:
        """Frames below ``T_add_new_node`` that had to wait for ``T_interval``."""
        t = self.thresholds
        below = np.nan_to_num(self.sim_to_node, nan=1.0) < t.T_add_new_node
        decided = sum(1 for e in self.events if e.kind in ("node", "loop_closure"))
        return int(below.sum()) - decided

    def summary(self) -> dict:
        """A JSON-able summary: frames, nodes added, loop closures, distances."""
        loops = self.loop_closure_events()
        return {
            "frames": self.n_frames,
            "nodes_added": len(self.node_events()),
            "loop_closures": [{"frame_index": e.frame_index, "from_node": e.prev_node,
                               "to_node": e.node_id, "score": e.loop_score, "new_arc": e.new_arc,
                               "verify_support": e.verify_support}
                              for e in loops],
            "loop_closures_rejected": [{"frame_index": e.frame_index, "node": e.node_id,
                                        "candidate": e.loop_candidate, "score": e.loop_score,
                                        "verify_support": e.verify_support, "verify_rival": e.verify_rival}
                                       for e in self.rejected_loop_events()],
            "deferred_by_T_interval": self.deferred_frames,
            "moving_frames": int(np.count_nonzero(np.nan_to_num(self.sim_to_prev, nan=1.0)
                                                  < self.thresholds.T_add_distance)),
            "travelled_m": self.travelled_m,
            "thresholds": self.thresholds.to_dict(),
        }

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Plain numpy arrays (events and thresholds as UTF-8 JSON bytes) for an ``.npz``."""
        meta = {"thresholds": self.thresholds.to_dict(), "travelled_m": self.travelled_m,
                "events": [e.to_dict() for e in self.events]}
        return {"frame_index": self.frame_index, "stamp_s": self.stamp_s,
                "sim_to_node": self.sim_to_node, "sim_to_prev": self.sim_to_prev,
                "m_distance": self.m_distance, "node": self.node,
                "meta_json": np.frombuffer(json.dumps(meta).encode("utf-8"), dtype=np.uint8)}

    @classmethod
    def from_arrays(cls, arrays: dict) -> "BuildLog":
        """Inverse of :meth:`to_arrays`; raises :class:`MapError` naming a missing or bad item."""
        names = ("frame_index", "stamp_s", "sim_to_node", "sim_to_prev", "m_distance", "node", "meta_json")
        for name in names:
            if name not in arrays:
                raise MapError(f"build log: missing array {name!r}")
        n = np.asarray(arrays["frame_index"]).shape
        for name in names[1:-1]:
            if np.asarray(arrays[name]).shape != n:
                raise MapError(f"build log: array {name!r} has shape {np.asarray(arrays[name]).shape}, "
                               f"expected {n}")
        try:
            meta = json.loads(bytes(np.asarray(arrays["meta_json"], dtype=np.uint8)).decode("utf-8"))
            events = tuple(MapEvent.from_dict(e) for e in meta["events"])
            thresholds = MapThresholds.from_dict(meta["thresholds"])
        except (ValueError, KeyError, TypeError) as exc:
            raise MapError(f"build log: unreadable events or thresholds ({exc})") from None
        return cls(thresholds=thresholds, events=events, travelled_m=meta.get("travelled_m"),
                   **{k: np.asarray(arrays[k]) for k in names[:-1]})


@dataclass(frozen=True)
class _Frame:
    """A checked frame waiting to be processed."""

    d: np.ndarray
    frame_index: int
    stamp_s: float
    true_pose: Optional[Pose2D]


@dataclass
class _Pending:
    """A loop-closure candidate waiting for the frames that verify it."""

    frame: _Frame
    sim_node: float
    sim_prev: float
    candidate: int
    score: float
    eligible: list[int]
    window: list[_Frame] = field(default_factory=list)


class MapBuilder:
    """Builds a :class:`TopoMap` from frames fed one at a time (see the module docstring).

    ``dim`` fixes the descriptor dimension; when ``None`` the first frame sets it.
    """

    def __init__(self, thresholds: MapThresholds, dim: Optional[int] = None):
        if not isinstance(thresholds, MapThresholds):
            raise MapBuildError(f"MapBuilder needs MapThresholds, got {type(thresholds).__name__}")
        self.thresholds = thresholds
        self._dim = dim
        self._map: Optional[TopoMap] = None
        self._events: list[MapEvent] = []
        self._trace: dict[str, list] = {k: [] for k in
                                        ("frame_index", "stamp_s", "sim_to_node", "sim_to_prev", "m_distance", "node")}
        self._node_seq: list[int] = []          # keyframe seq of each node, in row order
        self._seen: list[np.ndarray] = []       # every processed frame (float16), for short verifications
        self._recent: deque[int] = deque(maxlen=thresholds.loop_exclude_recent_nodes + 1)
        self._inbox: deque[_Frame] = deque()    # checked frames not processed yet
        self._pending: Optional[_Pending] = None
        self._fed = 0
        self._seq = -1                          # position of the last processed frame
        self._last_checked_index: Optional[int] = None
        self._last_checked_stamp_s = -math.inf
        self._with_poses: Optional[bool] = None
        self._prev_desc: Optional[np.ndarray] = None
        self._prev_pose: Optional[Pose2D] = None
        self._node = -1                         # the node the builder stands at
        self._node_desc: Optional[np.ndarray] = None
        self._anchor_seq = 0                    # seq at which the current node was reached
        self._m_distance = 0
        self._travelled_since_m = 0.0
        self._travelled_total_m = 0.0
        self._finished = False

    # -- state ---------------------------------------------------------------------------
    @property
    def current_node(self) -> Optional[int]:
        """The node the builder stands at (``None`` before the first frame). While a loop
        closure waits for verification it is the node before the candidate frame."""
        return None if self._node < 0 else self._node

    @property
    def n_frames(self) -> int:
        """Frames fed so far (some may wait for a verification to be processed)."""
        return self._fed

    @property
    def n_nodes(self) -> int:
        return 0 if self._map is None else len(self._map)

    # -- feeding -------------------------------------------------------------------------
    def add_frame(self, descriptor: np.ndarray, frame_index: int, stamp_s: float,
                  true_pose: Optional[Pose2D] = None) -> list[MapEvent]:
        """Feed the next frame; return the decisions this frame completed (usually none or one,
        see :class:`MapEvent`). A decision that needs sequence verification comes out
        ``loop_verify_frames`` frames later, followed by those of the frames that waited for it.

        ``descriptor``: (D,) L2-normalised. ``frame_index``: strictly increasing label.
        ``stamp_s``: non-decreasing seconds. ``true_pose``: simulator ground truth, given for
        every frame or for none.
        """
        if self._finished:
            raise MapBuildError("add_frame after finish(): start a new MapBuilder")
        d = self._check_frame(descriptor, frame_index, stamp_s, true_pose)
        self._fed += 1
        self._inbox.append(_Frame(d, int(frame_index), float(stamp_s), true_pose))
        return self._drain(final=False)

    def add_frames(self, descriptors: np.ndarray, frame_indices: Optional[Sequence[int]] = None,
                   stamps_s: Optional[Sequence[float]] = None,
                   true_poses: Optional[Sequence[Pose2D]] = None, progress: bool = False) -> list[MapEvent]:
        """Feed (N, D) descriptors in order (labels default to 0..N-1, stamps to the labels)."""
        x = np.asarray(descriptors)
        if x.ndim != 2:
            raise MapBuildError(f"descriptors must be (N, D), got shape {x.shape}")
        n = x.shape[0]
        start = self.n_frames
        idx = list(range(start, start + n)) if frame_indices is None else list(frame_indices)
        st = [float(i) for i in idx] if stamps_s is None else list(stamps_s)
        for name, seq in (("frame_indices", idx), ("stamps_s", st)) + (
                (("true_poses", true_poses),) if true_poses is not None else ()):
            if len(seq) != n:
                raise MapBuildError(f"{name} has {len(seq)} entries for {n} descriptors")
        rows = range(n)
        if progress:
            from tqdm import tqdm
            rows = tqdm(rows, desc="mapping", unit="frame")
        events = []
        for k in rows:
            events.extend(self.add_frame(x[k], idx[k], st[k], None if true_poses is None else true_poses[k]))
        return events

    def finish(self) -> tuple[TopoMap, BuildLog]:
        """Stop feeding: decide a waiting verification on the frames there are, process the
        rest, and return the map and the log of decisions."""
        if self._finished:
            raise MapBuildError("finish() was called already")
        if self._fed == 0:
            raise MapBuildError("no frames were fed: a map needs at least one frame")
        self._drain(final=True)
        self._close_at_end()
        self._finished = True
        log = BuildLog(
            thresholds=self.thresholds, events=tuple(self._events),
            frame_index=np.asarray(self._trace["frame_index"], dtype=np.int64),
            stamp_s=np.asarray(self._trace["stamp_s"], dtype=np.float64),
            sim_to_node=np.asarray(self._trace["sim_to_node"], dtype=np.float32),
            sim_to_prev=np.asarray(self._trace["sim_to_prev"], dtype=np.float32),
            m_distance=np.asarray(self._trace["m_distance"], dtype=np.int32),
            node=np.asarray(self._trace["node"], dtype=np.int32),
            travelled_m=self._travelled_total_m if self._with_poses else None)
        return self._map, log

    # -- the queue: frames wait while a loop closure is being verified -----------------
    def _drain(self, final: bool) -> list[MapEvent]:
        first_new = len(self._events)
        while True:
            if self._pending is not None:
                if len(self._pending.window) >= self.thresholds.loop_verify_frames:
                    self._resolve()
                elif self._inbox:
                    self._pending.window.append(self._inbox.popleft())
                elif final:
                    self._resolve(cut_short=True)
                else:
                    break
            elif self._inbox:
                self._process(self._inbox.popleft())
            else:
                break
        return self._events[first_new:]

    def _process(self, f: _Frame) -> None:
        self._seq += 1
        self._seen.append(f.d.astype(np.float16))
        if self._prev_pose is not None and f.true_pose is not None:
            step = self._prev_pose.distance_to(f.true_pose)
            self._travelled_since_m += step
            self._travelled_total_m += step
        if self._map is None:
            self._start(f)
            self._done_with(f, math.nan, math.nan)
            return
        sim_prev = float(f.d @ self._prev_desc)
        if sim_prev < self.thresholds.T_add_distance:
            self._m_distance += 1
        sim_node = float(f.d @ self._node_desc)
        t = self.thresholds
        if sim_node < t.T_add_new_node and self._seq - self._anchor_seq >= t.T_interval:
            cand, score, eligible_rows = self._best_loop_candidate(f.d)
            if cand is not None and score > t.T_loop_closure:
                # a candidate: wait for the frames that confirm or refute it
                self._pending = _Pending(frame=f, sim_node=sim_node, sim_prev=sim_prev,
                                         candidate=cand, score=score,
                                         eligible=self._map.node_ids[eligible_rows].tolist())
                return
            self._add_node(f, sim_node, cand, score, None)
        self._done_with(f, sim_node, sim_prev)

    def _resolve(self, cut_short: bool = False) -> None:
        """Decide the waiting candidate, then put the frames it waited for back in line.
        ``cut_short``: the walkthrough ended before ``loop_verify_frames`` frames came."""
        p, self._pending = self._pending, None
        window = np.stack([p.frame.d] + [w.d for w in p.window])
        t = self.thresholds
        if cut_short:
            earlier = len(self._trace["node"])          # frames processed before the candidate's
            check = check_sequence_on_frames(
                window, self._map, p.candidate, frames=np.stack(self._seen[:earlier]),
                frame_nodes=np.asarray(self._trace["node"]), eligible=p.eligible,
                hops=t.loop_verify_hops, min_support=t.T_loop_verify)
        else:
            check = check_sequence(window, self._map, p.candidate, eligible=p.eligible,
                                   hops=t.loop_verify_hops, min_support=t.T_loop_verify)
        if check.accepted:
            self._close_loop(p.frame, p.sim_node, p.candidate, p.score, check)
        else:
            self._add_node(p.frame, p.sim_node, p.candidate, p.score, check)
        self._done_with(p.frame, p.sim_node, p.sim_prev)
        self._inbox.extendleft(reversed(p.window))

    def _done_with(self, f: _Frame, sim_node: float, sim_prev: float) -> None:
        self._prev_desc = f.d
        self._prev_pose = f.true_pose
        for key, value in (("frame_index", f.frame_index), ("stamp_s", f.stamp_s),
                           ("sim_to_node", sim_node), ("sim_to_prev", sim_prev),
                           ("m_distance", self._m_distance), ("node", self._node)):
            self._trace[key].append(value)

    # -- the rules -----------------------------------------------------------------------
    def _start(self, f: _Frame) -> None:
        self._map = TopoMap(f.d.shape[0])
        node = self._map.add_node(f.d, f.frame_index, f.stamp_s, f.true_pose)
        self._node_seq.append(self._seq)
        self._reach(node, f.d)
        self._events.append(MapEvent(kind="first_node", seq=self._seq, frame_index=f.frame_index,
                                     stamp_s=f.stamp_s, node_id=node, reason="the first frame starts the map"))

    def _common(self, f: _Frame, sim_node: float, cand: Optional[int], score: Optional[float],
                check: Optional[SequenceCheck]) -> tuple[dict, str]:
        t = self.thresholds
        prev, since = self._node, self._seq - self._anchor_seq
        common = dict(seq=self._seq, frame_index=f.frame_index, stamp_s=f.stamp_s, prev_node=prev,
                      score_to_prev_node=sim_node, m_distance=self._m_distance, frames_since_prev=since,
                      loop_candidate=cand, loop_score=score,
                      travelled_m=self._travelled_since_m if self._with_poses else None)
        if check is not None:
            common.update(verify_frames=check.frames, verify_support=check.support, verify_rival=check.rival)
        why = (f"similarity to node {prev} fell to {sim_node:.3f} < T_add_new_node {t.T_add_new_node:.3f}, "
               f"{since} frames after it (T_interval {t.T_interval})")
        return common, why

    @staticmethod
    def _check_note(check: SequenceCheck, t: MapThresholds) -> str:
        rival = "no other node" if check.rival is None else f"{check.rival:.3f} elsewhere"
        return (f"over {check.frames} frames the route stretch {list(check.path)} matched "
                f"{check.support:.3f} (T_loop_verify {t.T_loop_verify:.3f}) vs {rival}, best in "
                f"{check.wins:.0%} of them")

    def _close_loop(self, f: _Frame, sim_node: float, cand: int, score: float, check: SequenceCheck,
                    why: Optional[str] = None) -> None:
        t = self.thresholds
        common, node_why = self._common(f, sim_node, cand, score, check)
        why = why or node_why
        prev, m = self._node, self._m_distance
        had = self._map.arc(prev, cand) if self._map.has_arc(prev, cand) else None
        now = self._map.add_arc(prev, cand, weight=m, kind="loop_closure", n_frames=common["frames_since_prev"],
                                length_m=common["travelled_m"])
        self._reach(cand, self._map.descriptor(cand))
        self._events.append(MapEvent(
            kind="loop_closure", node_id=cand, new_arc=now != had, **common,
            reason=f"{why}; matches earlier node {cand} at {score:.3f} > T_loop_closure {t.T_loop_closure:.3f}, "
                   f"confirmed: {self._check_note(check, t)}; linked {prev} -> {cand} (weight {m}) and "
                   f"continued from {cand}"))

    def _add_node(self, f: _Frame, sim_node: float, cand: Optional[int], score: Optional[float],
                  check: Optional[SequenceCheck]) -> None:
        t = self.thresholds
        common, why = self._common(f, sim_node, cand, score, check)
        prev, m = self._node, self._m_distance
        node = self._map.add_node(f.d, f.frame_index, f.stamp_s, f.true_pose)
        self._node_seq.append(self._seq)
        self._map.add_arc(prev, node, weight=m, kind="sequential", n_frames=common["frames_since_prev"],
                          length_m=common["travelled_m"])
        self._reach(node, f.d)
        if cand is None:
            note = "no earlier node was eligible for loop closure"
        elif check is None:
            note = f"best earlier node {cand} scored {score:.3f} <= T_loop_closure {t.T_loop_closure:.3f}"
        else:
            note = (f"earlier node {cand} scored {score:.3f} > T_loop_closure {t.T_loop_closure:.3f} but "
                    f"was rejected: {self._check_note(check, t)}")
        self._events.append(MapEvent(kind="node", node_id=node, loop_rejected=check is not None, **common,
                                     reason=f"{why}; {note}: added node {node} (arc weight {m})"))

    def _close_at_end(self) -> None:
        """The end-of-walk loop closure (module docstring): the walk ended on its own route."""
        t = self.thresholds
        if t.loop_verify_frames == 0 or not self._events or self._events[-1].kind == "loop_closure":
            return
        first_tail = max(self._seq + 1 - t.loop_verify_frames, 0)
        before = first_tail - t.loop_min_gap_frames        # earlier frames count from here back
        node_seq = np.asarray(self._node_seq)
        ids = self._map.node_ids
        eligible = ids[(node_seq <= before) & ~np.isin(ids, np.asarray(self._recent))]
        frame_nodes = np.asarray(self._trace["node"])
        old = np.isin(frame_nodes, eligible)
        old[max(before + 1, 0):] = False
        if not old.any():
            return
        seen = np.stack(self._seen)
        sims = seen[first_tail:].astype(np.float32) @ seen[old].astype(np.float32).T
        best = sims.max(axis=1)
        above = np.nonzero(best > t.T_loop_closure)[0]
        if above.size == 0:
            return
        k = int(above[0])
        cand = int(frame_nodes[old][int(np.argmax(sims[k]))])
        check = check_sequence_on_frames(seen[first_tail + k:], self._map, cand, frames=seen[:first_tail],
                                         frame_nodes=frame_nodes[:first_tail], eligible=eligible.tolist(),
                                         hops=t.loop_verify_hops, min_support=t.T_loop_verify)
        if not check.accepted:
            return
        last = _Frame(self._prev_desc, int(self._trace["frame_index"][-1]), float(self._trace["stamp_s"][-1]),
                      self._prev_pose)
        self._close_loop(last, float(self._trace["sim_to_node"][-1]), cand, float(best[k]), check,
                         why=f"the walkthrough ended on its own route: from its frame "
                             f"{self._trace['frame_index'][first_tail + k]} on, its last frames match earlier "
                             f"frames at node {cand}")

    def _best_loop_candidate(self, d: np.ndarray) -> tuple[Optional[int], Optional[float], np.ndarray]:
        """The most similar node allowed by the exclusion rule, its score, and the rows of all
        eligible nodes."""
        t = self.thresholds
        node_seq = np.asarray(self._node_seq)
        ids = self._map.node_ids
        eligible = node_seq <= self._seq - t.loop_min_gap_frames
        eligible &= ~np.isin(ids, np.asarray(self._recent))
        rows = np.nonzero(eligible)[0]
        if rows.size == 0:
            return None, None, rows
        scores = np.where(eligible, self._map.descriptors @ d, -np.inf)   # no copy of the matrix
        k = int(np.argmax(scores))
        return int(ids[k]), float(scores[k]), rows

    def _reach(self, node: int, desc: np.ndarray) -> None:
        """Stand at ``node`` from this frame on; restart the distance counter."""
        self._node = node
        self._node_desc = np.asarray(desc, dtype=np.float32)
        self._recent.append(node)
        self._anchor_seq = self._seq
        self._m_distance = 0
        self._travelled_since_m = 0.0

    def _check_frame(self, descriptor, frame_index, stamp_s, true_pose) -> np.ndarray:
        where = f"frame {frame_index!r}"
        d = np.array(descriptor, dtype=np.float32)     # a copy: callers may reuse their buffer
        if self._dim is None:
            if d.ndim != 1 or d.shape[0] < 1:
                raise MapBuildError(f"{where}: descriptor must be a 1-D vector, got shape {d.shape}")
            self._dim = int(d.shape[0])
        if d.shape != (self._dim,):
            raise MapBuildError(f"{where}: descriptor has shape {d.shape}, expected ({self._dim},)")
        if not np.all(np.isfinite(d)):
            raise MapBuildError(f"{where}: descriptor has NaN or infinite values")
        norm = float(np.linalg.norm(d))
        if abs(norm - 1.0) > NORM_TOLERANCE:
            raise MapBuildError(f"{where}: descriptor norm is {norm:.4f}; descriptors must be L2-normalised")
        if isinstance(frame_index, bool) or not isinstance(frame_index, (int, np.integer)):
            raise MapBuildError(f"{where}: frame_index must be an integer")
        if self._last_checked_index is not None and frame_index <= self._last_checked_index:
            raise MapBuildError(f"{where}: frame_index must increase (previous was {self._last_checked_index})")
        stamp_s = float(stamp_s)
        if not math.isfinite(stamp_s) or stamp_s < self._last_checked_stamp_s:
            raise MapBuildError(f"{where}: stamp_s {stamp_s!r} must be finite and not earlier than "
                                f"the previous frame's {self._last_checked_stamp_s!r}")
        has_pose = true_pose is not None
        if has_pose and not isinstance(true_pose, Pose2D):
            raise MapBuildError(f"{where}: true_pose must be a Pose2D, got {type(true_pose).__name__}")
        if self._with_poses is None:
            self._with_poses = has_pose
        elif has_pose != self._with_poses:
            raise MapBuildError(f"{where}: true_pose must be given for every frame or for none")
        self._last_checked_index = int(frame_index)
        self._last_checked_stamp_s = stamp_s
        return d

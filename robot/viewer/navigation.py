"""One navigation episode in the viewer, on the control tick's timeline (and the base's clock).

What each step logs (entity paths, :mod:`robot.viewer.scene`):

* ``camera/image`` the camera frame (JPEG), ``camera/thirds`` the Left / Middle / Right thirds
  with their scores against the target node (the voted third highlighted);
* ``goal/image`` the goal image (once);
* ``map/arcs`` and ``map/nodes`` the map, the nodes coloured by the view's similarity to them;
  ``map/belief`` the belief's top nodes (area by mass), ``map/current``, ``map/target``,
  ``map/goal`` and ``map/plan``; ``map/estimate`` where the robot believes it is (the belief's
  mode, else the current node); ``map/true_pose`` the true pose (simulator only);
* ``navigator/decision`` the state, action and reason as text; ``navigator/events`` a line per
  change of state, confirmed node, re-plan and the end;
* time series: ``scores/*`` (filtered current and target, thirds, vote, goal image, best raw
  match), ``command/*`` (applied velocity), ``timing/*`` (ms per stage), ``belief/*``.

It runs on the control thread (``python -m robot.bench perf --rerun`` measures what a step costs):
Rerun batches and sends from its own threads.
"""

from __future__ import annotations

import contextlib
import time
from typing import Any, Iterator, Optional

import numpy as np

from core.hal import Pose2D
from maps.graph import TopoMap
from robot.episode.loop import StepRecord
from robot.viewer import scene
from robot.viewer.stream import Recording, ViewerTarget, rerun_sdk

#: colours (RGB) of the marks
_CURRENT = (40, 120, 255)
_TARGET = (255, 160, 0)
_GOAL = (230, 30, 60)
_TRUE = (20, 20, 20)
_BELIEF = (160, 60, 220)
_VOTED = (255, 160, 0)
_THIRD = (200, 200, 200)
_JPEG_QUALITY = 80


def similarity_colours(scores: np.ndarray) -> np.ndarray:
    """(N, 3) uint8: dark blue (least alike of this view) to yellow (most alike)."""
    s = np.asarray(scores, dtype=np.float32)
    lo, hi = float(np.min(s)), float(np.max(s))
    t = (s - lo) / (hi - lo) if hi > lo else np.zeros_like(s)
    low, high = np.array([30, 40, 110], np.float32), np.array([250, 230, 40], np.float32)
    return (low + t[:, None] * (high - low)).astype(np.uint8)


class NavigationLogger:
    """Logs one episode to ``stream`` (a ``rerun.RecordingStream``); :meth:`setup` once before
    the loop, :meth:`step` after every step (the run's observer calls it)."""

    def __init__(self, rr: Any, stream: Any, topomap: TopoMap):
        self.rr, self.stream = rr, stream
        self.node_ids = [int(n) for n in topomap.node_ids]
        self._row = {n: k for k, n in enumerate(self.node_ids)}
        self.positions, self.true_positions = scene.node_positions(topomap)
        self._arcs = scene.arc_strips(topomap, self.positions)
        self._last_event: Optional[tuple] = None
        self._plan: tuple = ()
        #: wall time of each :meth:`step` (ms): what the viewer costs the control loop
        self.step_ms: list[float] = []

    def _xy(self, node: Optional[int]) -> Optional[list[float]]:
        return None if node is None or int(node) not in self._row else self.positions[self._row[int(node)]].tolist()

    def setup(self, goal_node: int, goal_image: Optional[np.ndarray], goal_source: str,
              start_pose: Optional[Pose2D] = None, goal_pose: Optional[Pose2D] = None) -> None:
        """The static part: the map, the goal (node and image), and the true start and goal poses
        when known (simulator)."""
        rr, log = self.rr, self.stream.log
        log(f"{scene.MAP}/arcs", rr.LineStrips2D(self._arcs, colors=[(150, 150, 150)], radii=0.03), static=True)
        log(f"{scene.MAP}/goal", rr.Points2D([self._xy(goal_node)], colors=[_GOAL], radii=0.25,
                                             labels=[f"goal node {goal_node}"]), static=True)
        if goal_pose is not None and self.true_positions:
            log(f"{scene.MAP}/goal_pose", rr.Points2D([scene.view_xy(goal_pose.x_m, goal_pose.y_m)], colors=[_GOAL],
                                                      radii=0.12, labels=["goal (true)"]), static=True)
        if start_pose is not None and self.true_positions:
            log(f"{scene.MAP}/start_pose", rr.Points2D([scene.view_xy(start_pose.x_m, start_pose.y_m)],
                                                       colors=[(0, 160, 80)], radii=0.12, labels=["start"]),
                static=True)
        if goal_image is not None:
            log(f"{scene.GOAL}/image", rr.Image(np.ascontiguousarray(goal_image)).compress(jpeg_quality=_JPEG_QUALITY),
                static=True)
        log(f"{scene.NAVIGATOR}/events", rr.TextLog(f"goal: node {goal_node} ({goal_source})"), static=True)

    def step(self, record: StepRecord, true_pose: Optional[Pose2D] = None) -> None:
        """Everything of one step (see the module docstring)."""
        started = time.perf_counter()
        rr, stream = self.rr, self.stream
        log = stream.log
        s = record.step
        stream.set_time(scene.TICK, sequence=record.index)
        stream.set_time(scene.SIM_TIME, duration=float(record.frame.stamp_s))
        self._camera(record)

        log(f"{scene.MAP}/nodes", rr.Points2D(self.positions, colors=similarity_colours(record.similarities),
                                              radii=0.12))
        estimate = s.current_node
        if record.belief is not None and record.belief.top:
            top = [(n, m) for n, m in record.belief.top if int(n) in self._row]
            estimate = record.belief.mode
            log(f"{scene.MAP}/belief", rr.Points2D([self._xy(n) for n, _ in top], colors=[_BELIEF],
                                                   radii=[0.1 + 0.5 * float(m) ** 0.5 for _, m in top]))
            log(f"{scene.BELIEF}/confidence", rr.Scalars(record.belief.confidence))
            log(f"{scene.BELIEF}/entropy_bits", rr.Scalars(record.belief.entropy_bits))
        for name, node, colour in (("current", s.current_node, _CURRENT), ("target", s.target_node, _TARGET),
                                   ("estimate", estimate, _CURRENT)):
            xy = self._xy(node)
            if xy is None:
                log(f"{scene.MAP}/{name}", rr.Clear(recursive=False))
            else:
                log(f"{scene.MAP}/{name}", rr.Points2D([xy], colors=[colour], radii=0.2 if name != "estimate" else 0.35,
                                                       labels=[f"{name} {node}"]))
        if tuple(s.planned_path) != self._plan:
            self._plan = tuple(s.planned_path)
            points = [p for p in (self._xy(n) for n in self._plan) if p is not None]
            log(f"{scene.MAP}/plan", rr.LineStrips2D([points], colors=[_TARGET], radii=0.06) if len(points) > 1
                else rr.Clear(recursive=False))
        if true_pose is not None and self.true_positions:
            x, y = scene.view_xy(true_pose.x_m, true_pose.y_m)
            heading = [0.5 * np.cos(true_pose.yaw_rad), -0.5 * np.sin(true_pose.yaw_rad)]
            log(f"{scene.MAP}/true_pose", rr.Arrows2D(origins=[[x, y]], vectors=[heading], colors=[_TRUE], radii=0.05))

        self._scalars(record)
        log(f"{scene.NAVIGATOR}/decision", rr.TextDocument(
            f"step {record.index}: {s.state.value}, {s.action.value}\n"
            f"node {s.current_node} -> {s.target_node} (goal {s.goal_node}), "
            f"re-localisations {s.relocalisations}\n{s.reason}"))
        self._events(record)
        self.step_ms.append((time.perf_counter() - started) * 1000.0)

    def observer(self, record: StepRecord) -> None:
        """:meth:`step` as a run loop observer (a real base: no true pose); never aborts."""
        self.step(record)

    def _camera(self, record: StepRecord) -> None:
        rr, log = self.rr, self.stream.log
        rgb = record.frame.rgb
        if rgb is None:
            return
        log(f"{scene.CAMERA}/image", rr.Image(np.ascontiguousarray(rgb)).compress(jpeg_quality=_JPEG_QUALITY))
        h, w = rgb.shape[:2]
        third = w / 3.0
        s = record.step
        if s.thirds is None:
            log(f"{scene.CAMERA}/thirds", rr.Clear(recursive=False))
            return
        voted = None if s.vote is None or s.vote.vote is None else s.vote.vote.value
        names = ("left", "middle", "right")
        scores = (s.thirds.left, s.thirds.middle, s.thirds.right)
        log(f"{scene.CAMERA}/thirds", rr.Boxes2D(
            mins=[[k * third, 0.0] for k in range(3)], sizes=[[third, float(h)]] * 3,
            colors=[_VOTED if n == voted else _THIRD for n in names],
            labels=[f"{n[0].upper()} {v:.3f}" for n, v in zip(names, scores)]))

    def _scalars(self, record: StepRecord) -> None:
        rr, log = self.rr, self.stream.log
        s = record.step
        values = {"current": s.current_score, "target": s.target_score,
                  "best_raw": float(np.max(record.similarities)) if record.similarities.size else None,
                  "goal_image": record.goal_score,
                  "goal_image_filtered": None if s.supervisor is None else s.supervisor.goal_image_score}
        if s.thirds is not None:
            values.update({"thirds/left": s.thirds.left, "thirds/middle": s.thirds.middle,
                           "thirds/right": s.thirds.right})
        if s.vote is not None and s.vote.scores is not None:
            values.update({"vote/left": s.vote.scores.left, "vote/middle": s.vote.scores.middle,
                           "vote/right": s.vote.scores.right})
        for name, value in values.items():
            if value is not None:
                log(f"{scene.SCORES}/{name}", rr.Scalars(float(value)))
        log(f"{scene.COMMAND}/v_mps", rr.Scalars(record.applied.v_mps))
        log(f"{scene.COMMAND}/w_radps", rr.Scalars(record.applied.w_radps))
        t = record.timing
        for name in ("read_ms", "describe_ms", "decide_ms", "tick_ms"):
            log(f"{scene.TIMING}/{name}", rr.Scalars(float(getattr(t, name))))

    def _events(self, record: StepRecord) -> None:
        s = record.step
        confirmed = None if s.supervisor is None else s.supervisor.confirmed_node
        key = (s.state, s.current_node, len(self._plan), s.relocalisations)
        if key == self._last_event and confirmed is None and not s.finished:
            return
        self._last_event = key
        level = "WARN" if s.state.value in ("relocalising", "searching") else \
            "ERROR" if s.state.value == "failed" else "INFO"
        self.stream.log(f"{scene.NAVIGATOR}/events", self.rr.TextLog(
            f"step {record.index}: {s.state.value}, node {s.current_node} -> {s.target_node}: {s.reason}",
            level=level))


@contextlib.contextmanager
def navigation_viewer(target: Optional[ViewerTarget], name: str, topomap: TopoMap) -> Iterator[Optional[NavigationLogger]]:
    """A :class:`NavigationLogger` on a recording for ``target`` (None: no viewer, yields None);
    the recording is closed, its file in place, however the block ends."""
    if target is None:
        yield None
        return
    with Recording(target, name, blueprint=scene.navigation_blueprint(rerun_sdk())) as recording:
        yield NavigationLogger(recording.rr, recording.stream, topomap)

"""Pictures of a navigation episode: a top-down trace (simulator) and a camera video with overlays.

* :func:`draw_trace` draws on a world's top-down picture (:func:`sim.topdown.render_topdown`):
  the map's nodes at their true poses (grey, arcs as thin lines), the planned node path (orange),
  the nodes the robot confirmed (blue), the driven trace (red), start / goal / end markers, the
  1.0 m success circle around the goal and a one-line verdict.
* :class:`NavigationVideo` writes an MP4 (OpenCV ``mp4v``) of the camera view, with the current
  and target nodes' thumbnails beside it and the scores, the chosen action and the state under
  them: one video frame per control step.

Colours are RGB tuples (the pictures are RGB and converted to BGR only when written).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Callable, Optional, Sequence

import cv2
import numpy as np

from controllers.navigator import NavigationStep
from core.atomic import move_into_place, temporary_sibling
from core.hal import Pose2D
from maps.graph import TopoMap
from sim.topdown import TopDown

NODE_COLOR = (150, 150, 150)
ARC_COLOR = (175, 175, 175)
PLAN_COLOR = (255, 150, 0)
VISITED_COLOR = (40, 90, 220)
TRACE_COLOR = (220, 30, 30)
START_COLOR = (46, 160, 67)
GOAL_COLOR = (214, 39, 40)
END_COLOR = (30, 30, 30)
_FONT = cv2.FONT_HERSHEY_SIMPLEX


def _xy(topomap: TopoMap, node: int) -> Optional[tuple[float, float]]:
    pose = topomap.node(node).true_pose if node in topomap else None
    return None if pose is None else (pose.x_m, pose.y_m)


def draw_trace(picture: TopDown, topomap: TopoMap, trace: Sequence[Pose2D], *,
               plans: Sequence[Sequence[int]] = (), visited: Sequence[int] = (),
               start: Optional[Pose2D] = None, goal: Optional[Pose2D] = None,
               goal_node: Optional[int] = None, success_radius_m: float = 1.0,
               title: str = "") -> TopDown:
    """Draw an episode onto a copy of ``picture``; returns the copy. Nodes without a true pose
    (maps from a video) are left out."""
    td = picture.copy()
    for u, v in topomap.graph.edges():
        a, b = _xy(topomap, u), _xy(topomap, v)
        if a and b:
            cv2.line(td.image, td.to_pixel(*a), td.to_pixel(*b), ARC_COLOR, 1, cv2.LINE_AA)
    for node in topomap.node_ids.tolist():
        p = _xy(topomap, node)
        if p:
            cv2.circle(td.image, td.to_pixel(*p), 3, NODE_COLOR, -1, cv2.LINE_AA)
    for k, plan in enumerate(plans):
        pts = [q for q in (_xy(topomap, n) for n in plan) if q]
        td.draw_polyline(pts, PLAN_COLOR, thickness=3 if k == 0 else 1)
    for node in visited:
        p = _xy(topomap, node)
        if p:
            cv2.circle(td.image, td.to_pixel(*p), 5, VISITED_COLOR, 2, cv2.LINE_AA)
    if trace:
        td.draw_polyline([(p.x_m, p.y_m) for p in trace], TRACE_COLOR, thickness=2)
    if goal is not None:
        radius = max(1, int(round(success_radius_m * td.px_per_m)))
        cv2.circle(td.image, td.to_pixel(goal.x_m, goal.y_m), radius, GOAL_COLOR, 1, cv2.LINE_AA)
        label = "goal" if goal_node is None else f"goal (node {goal_node})"
        td.draw_marker(goal.x_m, goal.y_m, GOAL_COLOR, label=label, shape="diamond", yaw_rad=goal.yaw_rad)
    elif goal_node is not None and _xy(topomap, goal_node):
        td.draw_marker(*_xy(topomap, goal_node), GOAL_COLOR, label=f"goal node {goal_node}", shape="diamond")
    if start is not None:
        td.draw_marker(start.x_m, start.y_m, START_COLOR, label="start", shape="square", yaw_rad=start.yaw_rad)
    if trace:
        end = trace[-1]
        td.draw_marker(end.x_m, end.y_m, END_COLOR, label="end", yaw_rad=end.yaw_rad, size_px=5)
    if title:
        # on a white band: the world picture has labels of its own at the top left
        (w, h), _ = cv2.getTextSize(title, _FONT, 0.55, 1)
        cv2.rectangle(td.image, (4, 4), (16 + w, 30), (255, 255, 255), -1)
        cv2.putText(td.image, title, (10, 22), _FONT, 0.55, (15, 15, 15), 1, cv2.LINE_AA)
    return td


# -- the camera video -------------------------------------------------------------------------
VIDEO_CAMERA_SIZE = (480, 360)   # width, height of the camera part of a video frame
THUMB_SIZE = (160, 120)
PANEL_W = 200


def _put(img: np.ndarray, text: str, org: tuple[int, int], scale: float = 0.45,
         color=(235, 235, 235)) -> None:
    cv2.putText(img, text, org, _FONT, scale, color, 1, cv2.LINE_AA)


def _fmt(score: Optional[float]) -> str:
    return "-" if score is None or not math.isfinite(score) else f"{score:.3f}"


def compose_video_frame(rgb: np.ndarray, step: NavigationStep,
                        thumbnail: Callable[[int], Optional[np.ndarray]], stamp_s: float) -> np.ndarray:
    """One RGB video frame: the camera view with its Left / Middle / Right thirds marked, the
    current and target node thumbnails, and the scores, action and state as text."""
    cw, ch = VIDEO_CAMERA_SIZE
    frame = np.zeros((ch, cw + PANEL_W, 3), np.uint8)
    cam = cv2.resize(rgb, (cw, ch), interpolation=cv2.INTER_AREA if rgb.shape[1] > cw else cv2.INTER_LINEAR)
    frame[:, :cw] = cam
    for k in (1, 2):
        x = round(cw * k / 3)
        cv2.line(frame, (x, 0), (x, ch - 1), (255, 255, 255), 1)
    if step.thirds is not None:
        for k, score in enumerate((step.thirds.left, step.thirds.middle, step.thirds.right)):
            _put(frame, f"{score:.2f}", (round(cw * k / 3) + 6, ch - 10), 0.5, (255, 255, 0))
    _put(frame, f"t={stamp_s:6.1f}s  {step.state.value}  {step.action.value}", (8, 20), 0.55, (255, 255, 0))
    x0 = cw + (PANEL_W - THUMB_SIZE[0]) // 2
    y = 4
    for label, node, score in (("current", step.current_node, step.current_score),
                               ("target", step.target_node, step.target_score)):
        _put(frame, f"{label} {node if node is not None else '-'}  {_fmt(score)}", (cw + 6, y + 12))
        thumb = thumbnail(int(node)) if node is not None else None
        if thumb is not None:
            frame[y + 18:y + 18 + THUMB_SIZE[1], x0:x0 + THUMB_SIZE[0]] = cv2.resize(thumb, THUMB_SIZE)
        y += 18 + THUMB_SIZE[1] + 6
    _put(frame, f"goal {step.goal_node}  reloc {step.relocalisations}", (cw + 6, y + 12))
    reason = step.reason[:60]
    _put(frame, reason[:30], (cw + 6, y + 30), 0.38)
    _put(frame, reason[30:], (cw + 6, y + 46), 0.38)
    return frame


class NavigationVideo:
    """An MP4 of the camera view with overlays, one frame per control step.

    ``thumbnail(node_id)`` returns a node's RGB thumbnail (e.g. ``LoadedMap.thumbnail``); results
    are cached. Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, path: str | Path, thumbnail: Callable[[int], np.ndarray], fps: float = 10.0):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = temporary_sibling(self.path)      # moved into place by close()
        self._thumbnail = thumbnail
        self._cache: dict[int, Optional[np.ndarray]] = {}
        size = (VIDEO_CAMERA_SIZE[0] + PANEL_W, VIDEO_CAMERA_SIZE[1])
        self._writer = cv2.VideoWriter(str(self._tmp), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), size)
        if not self._writer.isOpened():
            self._tmp.unlink(missing_ok=True)
            raise OSError(f"{self.path}: OpenCV cannot write an mp4v video here")
        self.frames = 0

    def _thumb(self, node: int) -> Optional[np.ndarray]:
        if node not in self._cache:
            self._cache[node] = self._thumbnail(node)
        return self._cache[node]

    def add(self, rgb: np.ndarray, step: NavigationStep, stamp_s: float) -> None:
        frame = compose_video_frame(rgb, step, self._thumb, stamp_s)
        self._writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
        self.frames += 1

    def close(self) -> None:
        """Finish the video and move it into place (also after an interruption: the frames so far)."""
        if self._writer is not None:
            self._writer.release()
            self._writer = None
            move_into_place(self._tmp, self.path)

    def __enter__(self) -> "NavigationVideo":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

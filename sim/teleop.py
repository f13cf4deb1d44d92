"""A scripted teleoperator: the stand-in for a person driving the Limo with a joystick.

It follows a polyline of waypoints using the simulator's ground-truth pose (pure pursuit with a
look-ahead point that advances monotonically along the path, so it never skips a stretch of the
route at a crossing). It is part of the simulator, not of the product: controllers never see
ground truth, only this stand-in and the evaluation code do.

Turning behaviour imitates a careful driver: it slows down in proportion to the heading error
and turns in place when the path bends sharply, which also gives the mapping run the paper's
"case 2" (the view turns while the robot barely moves).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from core.angles import wrap_angle
from core.hal import Pose2D, VelocityCommand
from core.validate import check_positive


@dataclass(frozen=True)
class TeleopConfig:
    cruise_v_mps: float = 0.4          # forward speed on straight stretches (Limo nav configs use 0.5-0.6)
    max_w_radps: float = 0.8           # yaw-rate cap, below the base's 1.0 rad/s limit
    lookahead_m: float = 0.45          # pure-pursuit look-ahead: shorter hugs the path, longer smooths it
    turn_in_place_rad: float = 1.0     # heading errors above this (57 deg) are turned on the spot
    heading_gain: float = 1.8          # yaw rate per radian of heading error toward the look-ahead point
    goal_tolerance_m: float = 0.15     # the drive ends this close to the last waypoint

    def __post_init__(self) -> None:
        for name in ("cruise_v_mps", "max_w_radps", "lookahead_m", "turn_in_place_rad",
                     "heading_gain", "goal_tolerance_m"):
            check_positive(name, getattr(self, name))


class WaypointTeleop:
    """Drives along ``waypoints`` ([(x, y), ...], metres, world frame) from ground-truth poses."""

    def __init__(self, waypoints: Sequence[Sequence[float]], config: TeleopConfig = TeleopConfig()):
        pts = np.asarray(waypoints, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
            raise ValueError(f"waypoints must be a list of at least two [x, y] pairs, got shape {pts.shape}")
        seg = np.diff(pts, axis=0)
        seg_len = np.hypot(seg[:, 0], seg[:, 1])
        keep = np.concatenate([[True], seg_len > 1e-9])
        self._pts = pts[keep]
        seg = np.diff(self._pts, axis=0)
        self._seg_len = np.hypot(seg[:, 0], seg[:, 1])
        self._cum = np.concatenate([[0.0], np.cumsum(self._seg_len)])
        self.config = config
        self._progress_m = 0.0

    @property
    def length_m(self) -> float:
        return float(self._cum[-1])

    @property
    def progress_m(self) -> float:
        """Arc length of the path already passed (the projection of the robot, never decreasing)."""
        return self._progress_m

    def point_at(self, s_m: float) -> np.ndarray:
        s = min(max(s_m, 0.0), self.length_m)
        i = int(np.searchsorted(self._cum, s, side="right") - 1)
        i = min(i, len(self._seg_len) - 1)
        t = (s - self._cum[i]) / self._seg_len[i]
        return self._pts[i] + t * (self._pts[i + 1] - self._pts[i])

    def _project(self, xy: np.ndarray) -> float:
        """Arc length of the closest path point within a window ahead of the current progress."""
        window_end = self._progress_m + 1.5
        best_s, best_d = self._progress_m, math.inf
        for i, length in enumerate(self._seg_len):
            s0 = self._cum[i]
            if s0 > window_end:
                break
            if s0 + length < self._progress_m:
                continue
            a, b = self._pts[i], self._pts[i + 1]
            t = float(np.clip(np.dot(xy - a, b - a) / (length * length), 0.0, 1.0))
            s = s0 + t * length
            if s < self._progress_m or s > window_end:
                continue
            d = float(np.hypot(*(a + t * (b - a) - xy)))
            if d < best_d:
                best_s, best_d = s, d
        return best_s

    def done(self, pose: Pose2D) -> bool:
        end = self._pts[-1]
        near_end = math.hypot(pose.x_m - end[0], pose.y_m - end[1]) < self.config.goal_tolerance_m
        return near_end and self._progress_m > self.length_m - 2.0 * self.config.lookahead_m

    def command(self, pose: Pose2D) -> VelocityCommand:
        """The joystick command for the robot at ``pose`` (zero once :meth:`done`)."""
        if self.done(pose):
            return VelocityCommand(0.0, 0.0)
        cfg = self.config
        xy = np.array([pose.x_m, pose.y_m])
        self._progress_m = max(self._progress_m, self._project(xy))
        target = self.point_at(self._progress_m + cfg.lookahead_m)
        to_end = math.hypot(*(self._pts[-1] - xy))
        bearing = math.atan2(target[1] - pose.y_m, target[0] - pose.x_m)
        err = wrap_angle(bearing - pose.yaw_rad)
        w = max(-cfg.max_w_radps, min(cfg.max_w_radps, cfg.heading_gain * err))
        if abs(err) > cfg.turn_in_place_rad:
            return VelocityCommand(0.0, w)
        v = cfg.cruise_v_mps * max(0.0, math.cos(err)) ** 2
        v = min(v, max(0.08, to_end))  # ease into the last waypoint
        return VelocityCommand(v, w)

"""Progress along a world's walkthrough: arc length of a point, and what lies ahead of it.

The expert of the learned baseline needs "the map node a bit ahead of the robot". Map nodes of a
simulator map carry the true pose of their keyframe, and the walkthrough polyline is the route
the map was driven along, so "ahead" is measured as arc length along that polyline. A
walkthrough that comes back to its start (every world's does, see ``sim.world_spec``) is a loop:
arc lengths are taken modulo the loop's length, so the stretch after the seam follows the one
before it.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from sim.geometry import sample_polyline
from sim.route_along import WALKTHROUGH_CLOSE_M

#: spacing of the polyline samples used for projection (metres)
SAMPLE_STEP_M = 0.05


class TrackError(ValueError):
    """The walkthrough cannot serve as a track (too few points, zero length)."""


class WalkthroughTrack:
    """A walkthrough polyline sampled every :data:`SAMPLE_STEP_M` metres.

    ``loop_m`` is the length of the closed loop (the arc length where the drive comes back
    nearest its start) or ``None`` for an open walkthrough.
    """

    def __init__(self, walkthrough: Sequence[Sequence[float]], step_m: float = SAMPLE_STEP_M):
        pts = np.asarray(walkthrough, dtype=float)
        if pts.ndim != 2 or pts.shape[0] < 2 or pts.shape[1] != 2:
            raise TrackError(f"a walkthrough needs at least 2 (x, y) points, got shape {pts.shape}")
        samples = sample_polyline(pts, step_m)
        arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(samples, axis=0).T))])
        if arc[-1] <= 0.0:
            raise TrackError("the walkthrough has zero length")
        self.loop_m = None
        if float(np.hypot(*(pts[-1] - pts[0]))) <= WALKTHROUGH_CLOSE_M:
            late = np.flatnonzero(arc > arc[-1] / 2.0)
            back = late[int(np.argmin(np.hypot(*(samples[late] - samples[0]).T)))]
            self.loop_m = float(arc[back])
            samples, arc = samples[:back], arc[:back]     # one lap: every place once
        self.samples = samples
        self.arc_m = arc
        d = np.diff(samples, axis=0)
        d = np.vstack([d, samples[0] - samples[-1] if self.loop_m is not None else d[-1]])
        self.heading_rad = np.arctan2(d[:, 1], d[:, 0])
        self.length_m = self.loop_m if self.loop_m is not None else float(arc[-1])

    def _nearest(self, x_m: float, y_m: float) -> int:
        return int(np.argmin(np.hypot(self.samples[:, 0] - x_m, self.samples[:, 1] - y_m)))

    def project(self, x_m: float, y_m: float) -> tuple[float, float]:
        """(arc length in m of the nearest track point, distance in m from the track)."""
        k = self._nearest(x_m, y_m)
        return float(self.arc_m[k]), float(math.hypot(self.samples[k, 0] - x_m, self.samples[k, 1] - y_m))

    def heading_at(self, s_m: float) -> float:
        """Direction of travel (rad) at arc length ``s_m``."""
        return float(self.heading_rad[self._index(s_m)])

    def point_at(self, s_m: float) -> tuple[float, float]:
        """The track point (x_m, y_m) at arc length ``s_m``."""
        x, y = self.samples[self._index(s_m)]
        return float(x), float(y)

    def _index(self, s_m: float) -> int:
        if self.loop_m is not None:
            s_m = s_m % self.loop_m
        return int(np.clip(np.searchsorted(self.arc_m, s_m, side="right") - 1, 0, len(self.arc_m) - 1))

    def ahead_m(self, s_from_m: float, s_to_m: float | np.ndarray) -> float | np.ndarray:
        """How far ``s_to_m`` lies ahead of ``s_from_m`` along the track (modulo the loop); on a
        loop the result is in [-loop/2, loop/2): a point just behind is negative, not a lap ahead."""
        d = np.asarray(s_to_m, dtype=float) - s_from_m
        if self.loop_m is not None:
            d = (d + self.loop_m / 2.0) % self.loop_m - self.loop_m / 2.0
        return float(d) if np.ndim(d) == 0 else d

"""Telling a robot pressed against a wall: the turns it commanded against the turns its gyro measured.

Pressed against a wall, a skid-steer robot spins its wheels and its wheel odometry counts on, so
odometry cannot tell; its body does not turn, so the gyro can. :class:`StallMonitor` keeps the
last ``window_s`` seconds of driving (the yaw rate applied over each control period and the
gyro's) and reports a stall when the commanded turns add up to at least ``min_turn_deg`` while
the gyro measured less than ``turn_ratio`` of that, in the commanded direction
(:class:`controllers.config.RecoveryConfig`).
"""

from __future__ import annotations

import collections
import math
from typing import Optional

from controllers.config import RecoveryConfig


class StallMonitor:
    """Feed :meth:`update` once a control period; :meth:`reset` when the robot stops driving."""

    def __init__(self, config: RecoveryConfig = RecoveryConfig()):
        self.config = config
        self._window: collections.deque = collections.deque()   # (dt_s, commanded, measured) yaw rates
        self._span_s = 0.0
        self._stamp: Optional[float] = None

    def reset(self) -> None:
        self._window.clear()
        self._span_s = 0.0
        self._stamp = None

    def update(self, stamp_s: float, commanded_w_radps: float, gyro_w_radps: Optional[float]) -> bool:
        """Add the period that ended at ``stamp_s`` (the yaw rate applied during it, and the
        gyro's now); True when the window shows a stall. No gyro: never."""
        if gyro_w_radps is None:
            self.reset()
            return False
        last, self._stamp = self._stamp, float(stamp_s)
        if last is None or not self._stamp > last:
            return False
        dt = self._stamp - last
        self._window.append((dt, float(commanded_w_radps), float(gyro_w_radps)))
        self._span_s += dt
        while self._window and self._span_s - self._window[0][0] >= self.config.window_s:
            self._span_s -= self._window.popleft()[0]
        if self._span_s < self.config.window_s * 0.999:
            return False
        commanded = sum(d * c for d, c, _ in self._window)
        measured = sum(d * g for d, _, g in self._window)
        if abs(commanded) < math.radians(self.config.min_turn_deg):
            return False
        return measured * math.copysign(1.0, commanded) < self.config.turn_ratio * abs(commanded)

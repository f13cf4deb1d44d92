"""A heading from a gyro: the yaw rate integrated over time (trapezoid rule).

Wheel odometry's yaw drifts with every wheel's slip and jumps when a wheel scrubs along a wall;
a gyro's integrated rate drifts only with its own small bias and noise. The heading starts at 0
(any fixed frame): only differences mean anything, as with odometry.
"""

from __future__ import annotations

import math
from typing import Optional

#: where a robot's heading can come from: the wheels' odometry, or the gyro's rate integrated
HEADING_SOURCES = ("odometry", "gyro")


class YawRateIntegrator:
    """Integrates yaw-rate samples into a heading (radians, not wrapped)."""

    def __init__(self) -> None:
        self._yaw: Optional[float] = None
        self._last: Optional[tuple[float, float]] = None   # (stamp_s, rate) of the previous sample

    @property
    def yaw_rad(self) -> Optional[float]:
        """The heading so far; None before the first sample."""
        return self._yaw

    def update(self, stamp_s: float, rate_radps: float) -> float:
        """Add one sample (a stamp in seconds, the yaw rate then); the heading at ``stamp_s``.
        A stamp that goes back raises ValueError; the first sample starts the heading at 0."""
        stamp, rate = float(stamp_s), float(rate_radps)
        if not (math.isfinite(stamp) and math.isfinite(rate)):
            raise ValueError(f"a gyro sample must be finite, got stamp {stamp_s!r}, rate {rate_radps!r}")
        if self._last is None:
            self._yaw = 0.0
        else:
            dt = stamp - self._last[0]
            if dt < 0:
                raise ValueError(f"gyro stamps must not go back: {stamp:g} s after {self._last[0]:g} s")
            self._yaw += 0.5 * (rate + self._last[1]) * dt
        self._last = (stamp, rate)
        return self._yaw

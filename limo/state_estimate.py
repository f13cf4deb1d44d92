"""Planar state estimate of a skid-steer base from wheel odometry and a gyro (filterpy).

A two-state Kalman filter tracks ``[yaw_rad, w_radps]`` with a constant-yaw-rate motion model
(white yaw acceleration). Two sensors measure the yaw rate:

* the wheels: ``(d_right - d_left) / track / dt``; a skid-steer base slips sideways when it
  turns, so this is trusted less (``odom_yaw_rate_std_radps``);
* the gyro's z axis, which does not slip (``gyro_yaw_rate_std_radps``).

Position is dead-reckoned outside the filter: each wheel update moves ``(x, y)`` by the mean
wheel travel along the mid-interval heading. Heading from this estimate is what the initial
localisation's rotate-in-place uses on a real robot, where there is no ground truth.

Stamps are host monotonic seconds. Serial frames arrive in bursts, so wheel deltas are
accumulated until at least ``min_odom_interval_s`` has passed before they are turned into a rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from core.angles import wrap_angle
from core.validate import check_positive
from limo.geometry import TRACK_M


@dataclass(frozen=True)
class StateEstimateConfig:
    """Noise levels and geometry of the estimate."""

    #: effective track of the base (skid steer turns as if wider; calibrate it on the real base)
    track_m: float = TRACK_M
    #: wheel-derived yaw rate noise; large because skid steer slips when it turns
    odom_yaw_rate_std_radps: float = 0.3
    #: gyro yaw rate noise (the protocol's resolution is 0.01 deg/s; real noise is larger)
    gyro_yaw_rate_std_radps: float = 0.02
    #: process noise: how fast the yaw rate may change (AgileX configs allow 3.2 rad/s^2)
    yaw_accel_std_radps2: float = 3.0
    #: wheel deltas are accumulated at least this long before being turned into a rate
    min_odom_interval_s: float = 0.035
    #: a wheel step larger than this between two frames is a counter reset, not motion
    max_wheel_step_m: float = 0.5

    def __post_init__(self) -> None:
        for name in ("track_m", "odom_yaw_rate_std_radps", "gyro_yaw_rate_std_radps",
                     "yaw_accel_std_radps2", "min_odom_interval_s", "max_wheel_step_m"):
            check_positive(name, getattr(self, name))


@dataclass(frozen=True)
class PlanarEstimate:
    """The fused planar state at ``stamp_s`` (x, y, yaw in the frame where the estimate began)."""

    stamp_s: float
    x_m: float
    y_m: float
    yaw_rad: float
    v_mps: float
    w_radps: float
    yaw_std_rad: float


class StateEstimator:
    """Fuses wheel odometry and gyro yaw rate; feed it with :meth:`update_wheels` and
    :meth:`update_gyro` in any order as frames arrive, read it with :meth:`estimate`."""

    def __init__(self, config: StateEstimateConfig = StateEstimateConfig()) -> None:
        self.config = config
        self.reset()

    def reset(self) -> None:
        """Start again at the origin, heading 0, at rest."""
        # filterpy pulls in scipy.stats (about a second): import it when an estimator is made,
        # not when limo.emulator or the HAL is merely imported
        from filterpy.common import Q_discrete_white_noise  # noqa: PLC0415
        from filterpy.kalman import KalmanFilter  # noqa: PLC0415

        self._q_white_noise = Q_discrete_white_noise
        kf = KalmanFilter(dim_x=2, dim_z=1)
        kf.x = np.zeros(2)
        kf.P = np.diag([1e-6, 0.1])  # the frame is defined by where we start: yaw is exact
        kf.H = np.array([[0.0, 1.0]])
        self._kf = kf
        self._stamp_s: Optional[float] = None
        self._x_m = 0.0
        self._y_m = 0.0
        self._v_mps = 0.0
        self._last_wheels: Optional[tuple] = None  # (left_m, right_m) of the previous frame
        self._acc_stamp_s: Optional[float] = None  # start of the wheel accumulation interval
        self._acc_left_m = 0.0
        self._acc_right_m = 0.0

    def _predict_to(self, stamp_s: float) -> None:
        if self._stamp_s is None:
            self._stamp_s = stamp_s
            return
        dt = stamp_s - self._stamp_s
        if dt <= 0:  # out-of-order or same-instant frames: update without moving time
            return
        F = np.array([[1.0, dt], [0.0, 1.0]])
        Q = self._q_white_noise(dim=2, dt=dt, var=self.config.yaw_accel_std_radps2 ** 2)
        self._kf.predict(F=F, Q=Q)
        self._stamp_s = stamp_s

    def update_gyro(self, stamp_s: float, yaw_rate_radps: float) -> None:
        """A gyro z-axis reading (counter-clockwise positive)."""
        if not math.isfinite(yaw_rate_radps):
            return
        self._predict_to(stamp_s)
        self._kf.update(np.array([yaw_rate_radps]), R=np.array([[self.config.gyro_yaw_rate_std_radps ** 2]]))

    def update_wheels(self, stamp_s: float, left_m: float, right_m: float) -> None:
        """Cumulative wheel travel (any origin); the first call only sets the reference."""
        if self._last_wheels is None:
            self._last_wheels = (left_m, right_m)
            self._acc_stamp_s = stamp_s
            self._predict_to(stamp_s)
            return
        d_left = left_m - self._last_wheels[0]
        d_right = right_m - self._last_wheels[1]
        self._last_wheels = (left_m, right_m)
        limit = self.config.max_wheel_step_m
        if abs(d_left) > limit or abs(d_right) > limit:
            # the counters jumped (firmware restart): re-reference, do not move
            self._acc_left_m = self._acc_right_m = 0.0
            self._acc_stamp_s = stamp_s
            return
        yaw_before = float(self._kf.x[0])
        self._predict_to(stamp_s)
        yaw_after = float(self._kf.x[0])
        step_m = 0.5 * (d_left + d_right)
        heading = 0.5 * (yaw_before + yaw_after)
        self._x_m += step_m * math.cos(heading)
        self._y_m += step_m * math.sin(heading)

        self._acc_left_m += d_left
        self._acc_right_m += d_right
        interval = stamp_s - self._acc_stamp_s
        if interval >= self.config.min_odom_interval_s:
            w_odom = (self._acc_right_m - self._acc_left_m) / self.config.track_m / interval
            self._v_mps = 0.5 * (self._acc_left_m + self._acc_right_m) / interval
            self._kf.update(np.array([w_odom]), R=np.array([[self.config.odom_yaw_rate_std_radps ** 2]]))
            self._acc_left_m = self._acc_right_m = 0.0
            self._acc_stamp_s = stamp_s

    def estimate(self) -> PlanarEstimate:
        """The current estimate; yaw is wrapped to [-pi, pi)."""
        wrapped = wrap_angle(float(self._kf.x[0]))
        return PlanarEstimate(stamp_s=self._stamp_s if self._stamp_s is not None else 0.0,
                              x_m=self._x_m, y_m=self._y_m, yaw_rad=wrapped, v_mps=self._v_mps,
                              w_radps=float(self._kf.x[1]), yaw_std_rad=math.sqrt(max(float(self._kf.P[0, 0]), 0.0)))

    @property
    def yaw_unwrapped_rad(self) -> float:
        """Total heading change since the start, not wrapped (useful to count full turns)."""
        return float(self._kf.x[0])

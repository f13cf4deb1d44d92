"""The physics behind the emulated firmware: a :class:`BaseModel` (``reset()``,
``step(dt_s, v_cmd_mps, w_cmd_radps) -> BaseState``); a PyBullet-backed Limo can replace the
kinematic unicycle (:class:`sim.serial_twin.PyBulletBaseModel`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Dict, Protocol

from core.angles import wrap_angle
from limo.geometry import MAX_ANGULAR_ACCEL_RADPS2, MAX_LINEAR_ACCEL_MPS2, TRACK_M


@dataclass(frozen=True)
class BaseState:
    """What a model reports after a step: pose, body velocity, cumulative wheel travel, accel."""

    x_m: float = 0.0
    y_m: float = 0.0
    yaw_rad: float = 0.0
    v_mps: float = 0.0
    w_radps: float = 0.0
    left_m: float = 0.0
    right_m: float = 0.0
    accel_mps2: float = 0.0


class BaseModel(Protocol):
    """The physics behind the emulated firmware (kinematic here; PyBullet can implement it too)."""

    def reset(self) -> BaseState:
        """Back to the origin at rest; returns that state."""

    def step(self, dt_s: float, v_cmd_mps: float, w_cmd_radps: float) -> BaseState:
        """Advance ``dt_s`` seconds under the commanded body velocity; return the new state."""


@dataclass(frozen=True)
class KinematicModelConfig:
    """A unicycle with acceleration and speed limits (AgileX navigation values by default)."""

    max_accel_mps2: float = MAX_LINEAR_ACCEL_MPS2
    max_yaw_accel_radps2: float = MAX_ANGULAR_ACCEL_RADPS2
    max_v_mps: float = 1.0
    max_w_radps: float = 2.5
    #: wheel separation used to turn (v, w) into left/right wheel travel (driver value)
    track_m: float = TRACK_M


class KinematicUnicycle:
    """Unicycle kinematics: velocity slews toward the command at the accel limits, then integrates."""

    def __init__(self, config: KinematicModelConfig = KinematicModelConfig()) -> None:
        self.config = config
        self._state = BaseState()

    def reset(self) -> BaseState:
        self._state = BaseState()
        return self._state

    @staticmethod
    def _slew(current: float, target: float, max_rate: float, dt: float) -> float:
        step = max_rate * dt
        return current + min(max(target - current, -step), step)

    def step(self, dt_s: float, v_cmd_mps: float, w_cmd_radps: float) -> BaseState:
        c, s = self.config, self._state
        if dt_s <= 0:
            return s
        v_target = min(max(v_cmd_mps, -c.max_v_mps), c.max_v_mps)
        w_target = min(max(w_cmd_radps, -c.max_w_radps), c.max_w_radps)
        v = self._slew(s.v_mps, v_target, c.max_accel_mps2, dt_s)
        w = self._slew(s.w_radps, w_target, c.max_yaw_accel_radps2, dt_s)
        # integrate with the mean velocities over the step (exact for constant acceleration in v)
        v_mid, w_mid = 0.5 * (s.v_mps + v), 0.5 * (s.w_radps + w)
        yaw_mid = s.yaw_rad + 0.5 * w_mid * dt_s
        yaw = wrap_angle(s.yaw_rad + w_mid * dt_s)
        half_track = 0.5 * c.track_m
        self._state = BaseState(
            x_m=s.x_m + v_mid * math.cos(yaw_mid) * dt_s,
            y_m=s.y_m + v_mid * math.sin(yaw_mid) * dt_s,
            yaw_rad=yaw, v_mps=v, w_radps=w,
            left_m=s.left_m + (v_mid - w_mid * half_track) * dt_s,
            right_m=s.right_m + (v_mid + w_mid * half_track) * dt_s,
            accel_mps2=(v - s.v_mps) / dt_s)
        return self._state


MODELS: Dict[str, Callable[[], BaseModel]] = {"kinematic": KinematicUnicycle}

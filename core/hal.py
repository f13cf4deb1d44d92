"""The hardware abstraction layer: one small interface for a robot base with a camera.

Every backend (the simulated Limo in PyBullet, the Limo base over its serial port) implements
:class:`RobotBase`. Controllers and the run loop only ever see this interface and the frozen
messages below; ground truth lives behind the separate, simulator-only :class:`GroundTruth`.

Life cycle, in the manner of py_trees / LeRobot:

* ``__init__`` only stores configuration, it opens nothing;
* ``connect()`` opens the device (starts the physics client, opens the serial port);
* ``read()`` returns the latest :class:`SensorFrame` without blocking for long;
* ``apply(cmd)`` sets the velocity command and returns the command actually applied after
  limits (it is held until the next ``apply``);
* ``tick()`` lets one control period pass: a simulated base steps its physics by exactly one
  control period, a real base sleeps until the next period starts. The run loop calls it once per
  cycle, so the same loop drives both;
* ``stop()`` commands zero velocity; ``close()`` stops the base, then releases the device.
  Used as a context manager, a base is connected on entry and stopped and closed on exit,
  also on an exception or Ctrl-C.
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass
from typing import Optional

import numpy as np


class HalError(RuntimeError):
    """A base cannot do what was asked (not connected, device lost, closed)."""


@dataclass(frozen=True)
class VelocityCommand:
    """Body-frame velocity: forward speed and yaw rate (counter-clockwise positive)."""

    v_mps: float = 0.0
    w_radps: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.v_mps) and math.isfinite(self.w_radps)):
            raise ValueError(f"velocity command must be finite, got v_mps={self.v_mps}, w_radps={self.w_radps}")

    @property
    def is_zero(self) -> bool:
        return self.v_mps == 0.0 and self.w_radps == 0.0


STOP = VelocityCommand(0.0, 0.0)


@dataclass(frozen=True)
class VelocityLimits:
    """What a base accepts; :meth:`clip` is applied to every command."""

    max_v_mps: float = 0.5
    max_w_radps: float = 1.0

    def clip(self, cmd: VelocityCommand) -> VelocityCommand:
        v = min(max(cmd.v_mps, -self.max_v_mps), self.max_v_mps)
        w = min(max(cmd.w_radps, -self.max_w_radps), self.max_w_radps)
        return VelocityCommand(v, w)


@dataclass(frozen=True)
class Odometry:
    """Wheel odometry as the base integrates it (not ground truth).

    ``x_m, y_m, yaw_rad`` are dead-reckoned in the frame where the base connected;
    ``v_mps, w_radps`` the measured body velocity; ``left_m, right_m`` the cumulative wheel
    travel of each side.
    """

    x_m: float
    y_m: float
    yaw_rad: float
    v_mps: float
    w_radps: float
    left_m: float
    right_m: float


@dataclass(frozen=True)
class SensorFrame:
    """One reading of every sensor a base has. Fields a base lacks are ``None``.

    ``rgb`` is an (H, W, 3) uint8 image, row 0 at the top. ``stamp_s`` is the base's clock
    (simulated time for the simulator, monotonic seconds for a real base).
    """

    stamp_s: float
    rgb: Optional[np.ndarray]
    odometry: Optional[Odometry] = None
    imu_yaw_rate_radps: Optional[float] = None
    battery_v: Optional[float] = None
    error_bits: int = 0
    fault: Optional[str] = None


@dataclass(frozen=True)
class Pose2D:
    """A planar pose in the world frame: metres and radians (yaw counter-clockwise from +x)."""

    x_m: float
    y_m: float
    yaw_rad: float

    def distance_to(self, other: "Pose2D") -> float:
        return math.hypot(self.x_m - other.x_m, self.y_m - other.y_m)


class RobotBase(abc.ABC):
    """A robot base with a camera. See the module docstring for the life cycle."""

    #: limits applied to every command by :meth:`apply`
    limits: VelocityLimits
    #: the control period that :meth:`tick` lets pass
    control_period_s: float

    @abc.abstractmethod
    def connect(self) -> None:
        """Open the device. Calling it twice is an error (:class:`HalError`)."""

    @property
    @abc.abstractmethod
    def connected(self) -> bool:
        """True between ``connect()`` and ``close()``."""

    @abc.abstractmethod
    def read(self) -> SensorFrame:
        """The latest sensor frame. Raises :class:`HalError` when not connected."""

    @abc.abstractmethod
    def apply(self, cmd: VelocityCommand) -> VelocityCommand:
        """Command a body velocity; returns what was actually applied after limits."""

    @abc.abstractmethod
    def tick(self) -> None:
        """Let one control period pass (simulated: step physics; real: sleep to the next period)."""

    def stop(self) -> None:
        """Command zero velocity."""
        if self.connected:
            self.apply(STOP)

    @abc.abstractmethod
    def close(self) -> None:
        """Stop the base, then release the device. Safe to call more than once."""

    def __enter__(self) -> "RobotBase":
        self.connect()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            self.stop()
        finally:
            self.close()


class GroundTruth(abc.ABC):
    """Simulator-only truth, for metrics, pictures and the scripted teleoperator.

    Controllers never receive this object; only the run loop and the evaluation code do.
    """

    @abc.abstractmethod
    def true_pose(self) -> Pose2D:
        """The robot's true planar pose in the world frame."""

    @abc.abstractmethod
    def collision_count(self) -> int:
        """How many separate contacts with walls or props began since connect."""

    @abc.abstractmethod
    def teleport(self, pose: Pose2D) -> None:
        """Place the robot at ``pose`` at rest (trial starts, kidnapped starts)."""

    @abc.abstractmethod
    def toppled(self) -> bool:
        """True when the body is no longer upright."""

"""A robot base that lives in memory: a unicycle whose camera shows which map node it stands
nearest, for fast tests of the episode loop (no simulator, no serial port).

``MemoryBase`` implements :class:`core.hal.RobotBase` and passes :mod:`core.hal_check`; it mirrors
every applied command into its state (as ros2_control's generic mock system does) and records
them. Scripted trouble: ``fault_at`` (a step from which ``read()`` reports a fault),
``no_image_at`` (a frame without a camera image), ``raise_in_tick_at`` (an exception raised
inside ``tick()``, e.g. ``KeyboardInterrupt`` for Ctrl-C).

``ChainDescriptor`` is the matching descriptor: a camera image encodes the robot's position along
a straight chain of nodes one metre apart, and the descriptor of a view is the normalised blend
of the two nodes it lies between (one-hot node descriptors), so a view at a node scores 1.0
against it and about 0 against the others. The middle third looks half a metre ahead; the side
thirds mostly see walls (one more dimension that no node has).
"""

from __future__ import annotations

import math
from typing import Optional, Sequence

import numpy as np

from core.hal import STOP, HalError, Odometry, Pose2D, RobotBase, SensorFrame, VelocityCommand, VelocityLimits


class MemoryBase(RobotBase):
    def __init__(self, start: Pose2D = Pose2D(0.0, 0.0, 0.0), control_period_s: float = 0.1,
                 fault_at: Optional[int] = None, no_image_at: Optional[int] = None,
                 raise_in_tick_at: Optional[int] = None, exception: type = RuntimeError):
        self.limits = VelocityLimits(0.5, 1.0)
        self.control_period_s = control_period_s
        self.pose = start
        self.fault_at, self.no_image_at = fault_at, no_image_at
        self.raise_in_tick_at, self.exception = raise_in_tick_at, exception
        self.applied: list[VelocityCommand] = []
        self.ticks = 0
        self._command = STOP
        self._connected = False
        self._closed = False

    def connect(self) -> None:
        if self._connected:
            raise HalError("MemoryBase is already connected")
        self._connected = True

    @property
    def connected(self) -> bool:
        return self._connected

    def read(self) -> SensorFrame:
        if not self._connected:
            raise HalError("MemoryBase is not connected")
        step = self.ticks
        rgb = None if step == self.no_image_at else encode_position(self.pose.x_m)
        odo = Odometry(self.pose.x_m, self.pose.y_m, self.pose.yaw_rad, self._command.v_mps,
                       self._command.w_radps, 0.0, 0.0)
        fault = "motor driver over temperature" if self.fault_at is not None and step >= self.fault_at else None
        return SensorFrame(stamp_s=step * self.control_period_s, rgb=rgb, odometry=odo, fault=fault)

    def apply(self, cmd: VelocityCommand) -> VelocityCommand:
        if not self._connected:
            raise HalError("MemoryBase is not connected")
        self._command = self.limits.clip(cmd)
        self.applied.append(self._command)
        return self._command

    def tick(self) -> None:
        if not self._connected:
            raise HalError("MemoryBase is not connected")
        if self.ticks == self.raise_in_tick_at:
            raise self.exception("raised inside tick()")
        dt, c, p = self.control_period_s, self._command, self.pose
        yaw_mid = p.yaw_rad + 0.5 * c.w_radps * dt
        self.pose = Pose2D(p.x_m + c.v_mps * dt * math.cos(yaw_mid), p.y_m + c.v_mps * dt * math.sin(yaw_mid),
                           p.yaw_rad + c.w_radps * dt)
        self.ticks += 1

    def close(self) -> None:
        if self._connected:
            self.stop()
        self._connected = False
        self._closed = True

    @property
    def last_command(self) -> VelocityCommand:
        return self.applied[-1] if self.applied else STOP


def encode_position(x_m: float) -> np.ndarray:
    """A tiny camera image that carries the position along the chain (centimetres in two bytes)."""
    cm = int(round(min(max(x_m, 0.0), 600.0) * 100))
    img = np.zeros((4, 6, 3), dtype=np.uint8)
    img[0, 0, 0], img[0, 0, 1] = cm // 256, cm % 256
    return img


class ChainDescriptor:
    """Descriptors for a chain of ``n_nodes`` nodes one metre apart along +x (see the module)."""

    def __init__(self, n_nodes: int):
        self.n = n_nodes

    def node_descriptors(self) -> np.ndarray:
        return np.eye(self.n, self.n + 1, dtype=np.float32)

    def _view(self, x_m: float) -> np.ndarray:
        x_m = min(max(x_m, 0.0), self.n - 1.0)
        k = min(int(math.floor(x_m)), self.n - 1)
        t = min(max(x_m - k, 0.0), 1.0)
        v = np.zeros(self.n + 1, dtype=np.float32)
        v[k] = 1.0 - t
        if k + 1 < self.n:
            v[k + 1] = t
        return v / np.linalg.norm(v)

    def describe(self, images: Sequence[np.ndarray]) -> np.ndarray:
        return np.stack([self._view(_decode(img)) for img in images])

    def describe_thirds(self, images: Sequence[np.ndarray]) -> np.ndarray:
        """(B, 4, N + 1): the full view, then Left / Middle / Right."""
        wall = np.zeros(self.n + 1, dtype=np.float32)
        wall[-1] = 1.0
        out = []
        for img in images:
            x = _decode(img)
            full, ahead = self._view(x), self._view(x + 0.5)
            side = 0.3 * full + wall
            side = side / np.linalg.norm(side)
            out.append(np.stack([full, side, ahead, side]))
        return np.stack(out).astype(np.float32)


def _decode(img: np.ndarray) -> float:
    return (int(img[0, 0, 0]) * 256 + int(img[0, 0, 1])) / 100.0

"""The serial Limo base's settings (the ``serial`` section of the stack config): plain data, no
pyserial, so reading the settings loads nothing of the driver."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from core.hal import VelocityLimits
from core.validate import check_at_least, check_choice, check_count, check_positive
from limo.state_estimate import StateEstimateConfig


@dataclass(frozen=True)
class LimoSerialConfig:
    """Everything the serial backend needs; loadable from YAML with :func:`core.configfile.load_config`."""

    #: device path or any pyserial URL (``loop://``, ``/dev/pts/N`` from the emulator)
    port: str = "/dev/ttyTHS1"
    #: the Limo base talks 460800 8N1
    baud: int = 460800
    #: motion frames per second, sent even when unchanged (>= 20; AgileX's SDK sends at 50)
    command_rate_hz: float = 50.0
    #: silence on the link longer than this is a fault: report it and command zero
    feedback_timeout_s: float = 0.5
    #: connect() waits this long for the first feedback frame and fails otherwise (0: do not wait)
    connect_timeout_s: float = 1.0
    #: the period tick() lets pass (the controller's cycle)
    control_period_s: float = 0.1
    limits: VelocityLimits = field(default_factory=VelocityLimits)
    #: metres per odometry count of 0x311 (AgileX bases report mm; change if the wheels disagree)
    odometry_unit_m: float = 0.001
    #: +1 if the gyro's z axis is counter-clockwise positive on this base, -1 otherwise
    gyro_yaw_sign: int = 1
    #: zero-velocity frames sent on close before the port is released
    stop_frames: int = 3
    #: camera for SensorFrame.rgb: device index ("0"), URL or video file; None: no camera
    camera: Optional[str] = None
    camera_width: Optional[int] = None
    camera_height: Optional[int] = None
    #: connect() waits this long for the camera's first frame and fails naming the camera
    #: otherwise (a UVC camera takes a moment to open; navigation needs an image from the start)
    camera_timeout_s: float = 5.0
    estimate: StateEstimateConfig = field(default_factory=StateEstimateConfig)

    def __post_init__(self) -> None:
        if not self.port:
            raise ValueError("port must name a device or pyserial URL, e.g. /dev/ttyTHS1")
        check_count("baud", self.baud, 1)
        check_at_least("command_rate_hz", self.command_rate_hz, 20.0)    # the base needs a steady stream
        for name in ("feedback_timeout_s", "control_period_s", "odometry_unit_m", "camera_timeout_s"):
            check_positive(name, getattr(self, name))
        check_at_least("connect_timeout_s", self.connect_timeout_s, 0.0)
        check_choice("gyro_yaw_sign", self.gyro_yaw_sign, (1, -1))
        check_count("stop_frames", self.stop_frames, 1)

"""Settings of the simulated Limo and of its camera: plain data, no PyBullet (reading the stack's
settings never loads the simulator)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from core.hal import VelocityLimits
from core.validate import check_at_least, check_bool, check_count, check_positive, check_range


class CameraError(ValueError):
    """A camera setting is invalid; the message names the field."""


def _check_camera(prefix: str, hfov_deg, width_px, height_px, error: type[Exception]) -> None:
    check_range(f"{prefix}hfov_deg", hfov_deg, 1.0, 170.0, what="a number of degrees", error=error)
    for name, value in (("width_px", width_px), ("height_px", height_px)):
        check_count(f"{prefix}{name}", value, 8, error=error)
        check_range(f"{prefix}{name}", value, 8, 4096, error=error)


@dataclass(frozen=True)
class CameraSpec:
    """Mounting and optics of the camera (defaults: the paper's simulated Limo, limo.md)."""

    hfov_deg: float = 65.0        # horizontal field of view; the paper used 65 deg (the Dabai has ~71)
    width_px: int = 320           # image width; small images keep rendering and descriptors cheap
    height_px: int = 240          # image height (4:3 like the Dabai's 640x480)
    height_m: float = 0.18        # lens height above the floor (ROS 1 URDF of the Limo)
    forward_m: float = 0.084      # lens position ahead of the base centre (ROS 1 URDF)
    near_m: float = 0.03          # near clipping plane: the front bumper is ~0.08 m ahead of the lens
    far_m: float = 40.0           # far clipping plane: longer than any corridor in our worlds

    def __post_init__(self) -> None:
        _check_camera("", self.hfov_deg, self.width_px, self.height_px, CameraError)
        if not 0.0 < self.near_m < self.far_m:
            raise CameraError(f"near_m and far_m must satisfy 0 < near_m < far_m, got {self.near_m}, {self.far_m}")
        check_positive("height_m", self.height_m, error=CameraError)

    @property
    def vfov_deg(self) -> float:
        """Vertical field of view derived from the horizontal one and the aspect ratio."""
        return vertical_fov_deg(self.hfov_deg, self.width_px, self.height_px)

    def column_of_bearing(self, bearing_rad: float) -> float:
        """Pinhole prediction of the image column (pixel centres 0..W-1) of a bearing, left positive."""
        focal_px = (self.width_px / 2.0) / math.tan(math.radians(self.hfov_deg) / 2.0)
        return (self.width_px - 1) / 2.0 - math.tan(bearing_rad) * focal_px


def vertical_fov_deg(hfov_deg: float, width_px: int, height_px: int) -> float:
    """Vertical FOV (degrees) of a pinhole camera with square pixels."""
    half = math.atan(math.tan(math.radians(hfov_deg) / 2.0) * height_px / width_px)
    return math.degrees(2.0 * half)


class SimConfigError(ValueError):
    """A :class:`SimConfig` field is invalid; the message names the field."""


@dataclass(frozen=True)
class SimConfig:
    """Settings of the simulated Limo. Every field is checked in ``__post_init__``."""

    physics_dt_s: float = 1.0 / 240.0      # physics step; PyBullet's default, stable for a 4.8 kg body on 45 mm wheels
    control_period_s: float = 0.1          # one tick() of the run loop (10 Hz, the paper's camera/decision rate)
    hfov_deg: float = 65.0                 # camera horizontal FOV; the paper's simulated Limo used 65 deg
    width_px: int = 320                    # camera image width in pixels
    height_px: int = 240                   # camera image height in pixels
    camera_enabled: bool = True            # False: read() returns rgb=None (runs that need no image are ~10x faster)
    max_v_mps: float = 0.5                 # forward speed limit applied by apply(); Limo nav configs use 0.5-0.6
    max_w_radps: float = 1.0               # yaw-rate limit applied by apply(); AgileX nav configs use 1.0
    odom_scale_noise: float = 0.01         # std of the per-period relative error of each side's wheel travel (slip)
    imu_yaw_rate_noise_radps: float = 0.005  # std of the Gaussian noise on the IMU yaw rate (HI226 class gyro)
    collision_debounce_s: float = 0.25     # a touch this soon after the last one with the same body is the same collision
    seed: int = 0                          # seeds every random draw of the simulator (noise)
    gui: bool = False                      # open the PyBullet window instead of headless DIRECT mode

    def __post_init__(self) -> None:
        for name in ("physics_dt_s", "control_period_s", "max_v_mps", "max_w_radps"):
            check_positive(f"SimConfig.{name}", getattr(self, name), error=SimConfigError)
        for name in ("odom_scale_noise", "imu_yaw_rate_noise_radps", "collision_debounce_s"):
            check_at_least(f"SimConfig.{name}", getattr(self, name), 0.0, error=SimConfigError)
        if self.physics_dt_s > 0.02:
            raise SimConfigError(f"SimConfig.physics_dt_s must be <= 0.02 s for stable contacts, got {self.physics_dt_s}")
        ratio = self.control_period_s / self.physics_dt_s
        if abs(ratio - round(ratio)) > 1e-6 or round(ratio) < 1:
            raise SimConfigError(
                f"SimConfig.control_period_s ({self.control_period_s}) must be a whole multiple of "
                f"physics_dt_s ({self.physics_dt_s}), got ratio {ratio:.6f}")
        _check_camera("SimConfig.", self.hfov_deg, self.width_px, self.height_px, SimConfigError)
        for name in ("camera_enabled", "gui"):
            check_bool(f"SimConfig.{name}", getattr(self, name), error=SimConfigError)
        check_count("SimConfig.seed", self.seed, 0, error=SimConfigError)

    @property
    def steps_per_tick(self) -> int:
        """Physics steps in one control period."""
        return int(round(self.control_period_s / self.physics_dt_s))

    @property
    def camera(self) -> CameraSpec:
        return CameraSpec(hfov_deg=self.hfov_deg, width_px=self.width_px, height_px=self.height_px)

    @property
    def limits(self) -> VelocityLimits:
        return VelocityLimits(max_v_mps=self.max_v_mps, max_w_radps=self.max_w_radps)

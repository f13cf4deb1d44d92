"""The Limo's forward monocular camera, rendered with PyBullet's TinyRenderer.

The camera sits ``height_m`` above the floor and ``forward_m`` ahead of the base centre, looking
along the robot's x axis, level when the robot is level (it tilts with the body). PyBullet's
``computeProjectionMatrixFOV`` takes the *vertical* field of view, so the configured horizontal
FOV is converted with the image's aspect ratio: ``tan(vfov/2) = tan(hfov/2) * height / width``.
Square pixels, principal point at the image centre: a point at bearing ``b`` (left positive)
lands at column ``u = (W - 1) / 2 - tan(b) * (W / 2) / tan(hfov / 2)``.

TinyRenderer works in DIRECT mode without a display or GPU and gives the same image on every
machine, which the determinism tests rely on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np
import pybullet as p

# The lighting keyword arguments of getCameraImage that a world may set (sim/world.py supplies
# them as ``render_light``); anything else is rejected so a typo does not silently do nothing.
LIGHT_KEYS = frozenset({"lightDirection", "lightColor", "lightDistance", "lightAmbientCoeff",
                        "lightDiffuseCoeff", "lightSpecularCoeff", "shadow"})


class CameraError(ValueError):
    """A camera setting is invalid; the message names the field."""


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
        if not 1.0 <= self.hfov_deg <= 170.0:
            raise CameraError(f"hfov_deg must be within [1, 170] degrees, got {self.hfov_deg}")
        for name in ("width_px", "height_px"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not 8 <= value <= 4096:
                raise CameraError(f"{name} must be an integer within [8, 4096], got {value!r}")
        if not 0.0 < self.near_m < self.far_m:
            raise CameraError(f"near_m and far_m must satisfy 0 < near_m < far_m, got {self.near_m}, {self.far_m}")
        if not self.height_m > 0.0:
            raise CameraError(f"height_m must be > 0, got {self.height_m}")

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


def check_light(light: Mapping[str, Any] | None) -> dict:
    """Validate render-light keyword arguments; returns a plain dict."""
    light = dict(light or {})
    unknown = sorted(set(light) - LIGHT_KEYS)
    if unknown:
        raise CameraError(f"unknown render-light argument(s) {unknown}; allowed: {sorted(LIGHT_KEYS)}")
    return light


class Camera:
    """Renders what the camera on a body sees. ``base_height_m``: base-frame origin above the floor."""

    def __init__(self, spec: CameraSpec, base_height_m: float):
        self.spec = spec
        # Lens position in the base frame: the base origin is base_height_m above the floor.
        self._lens_in_base = np.array([spec.forward_m, 0.0, spec.height_m - base_height_m])
        self._projection = p.computeProjectionMatrixFOV(fov=spec.vfov_deg, aspect=spec.width_px / spec.height_px,
                                                        nearVal=spec.near_m, farVal=spec.far_m)

    def view_matrix(self, base_position, base_orientation) -> tuple:
        """OpenGL view matrix for a base at ``base_position`` (m) with quaternion ``base_orientation``."""
        rot = np.asarray(p.getMatrixFromQuaternion(base_orientation)).reshape(3, 3)
        eye = np.asarray(base_position) + rot @ self._lens_in_base
        forward, up = rot[:, 0], rot[:, 2]
        return p.computeViewMatrix(cameraEyePosition=eye.tolist(), cameraTargetPosition=(eye + forward).tolist(),
                                   cameraUpVector=up.tolist())

    def render(self, client_id: int, base_position, base_orientation, **light: Any) -> np.ndarray:
        """(H, W, 3) uint8 RGB image, row 0 at the top. ``light``: see :data:`LIGHT_KEYS`."""
        light = check_light(light)
        spec = self.spec
        _, _, rgba, _, _ = p.getCameraImage(
            spec.width_px, spec.height_px,
            viewMatrix=self.view_matrix(base_position, base_orientation),
            projectionMatrix=self._projection,
            renderer=p.ER_TINY_RENDERER,
            flags=p.ER_NO_SEGMENTATION_MASK,
            physicsClientId=client_id,
            **light,
        )
        image = np.asarray(rgba, dtype=np.uint8).reshape(spec.height_px, spec.width_px, 4)
        return np.ascontiguousarray(image[:, :, :3])

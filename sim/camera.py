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

from typing import Any, Mapping

import numpy as np

from sim.bullet import p
from sim.config import CameraError, CameraSpec

# The lighting keyword arguments of getCameraImage that a world may set (sim/world.py supplies
# them as ``render_light``); anything else is rejected so a typo does not silently do nothing.
LIGHT_KEYS = frozenset({"lightDirection", "lightColor", "lightDistance", "lightAmbientCoeff",
                        "lightDiffuseCoeff", "lightSpecularCoeff", "shadow"})


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

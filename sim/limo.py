"""The simulated AgileX Limo: geometry from ``shared/docs/limo.md`` and a base that turns as commanded.

Approach: a *velocity-driven* rigid base on free-rolling wheels.

The body is a real dynamic multibody (4.8 kg: a box body plus four cylinder wheels on revolute
joints), so gravity, the floor and every wall or prop act on it through PyBullet's contact solver.
Before each physics step :meth:`Limo.pre_step` sets the base's *planar* velocity (forward speed
along its heading and yaw rate) to the acceleration-limited command with ``resetBaseVelocity``,
keeping the vertical, roll and pitch velocities the physics produced. The contact solver then
removes any velocity into an obstacle during the step, so the robot stops at a wall instead of
passing through it, and ``getContactPoints`` reports the contact. The wheels are frictionless on
every surface and are spun by velocity motors at the skid-steer wheel speeds
``(v -/+ w * track / 2) / r``, so they rotate for the picture and the wheel joint states give
wheel odometry (which, as on the real base, keeps counting when a wall blocks the body).

Why not pure friction-driven skid steer: with a Limo-sized model PyBullet reaches only about a
third of the commanded spin rate with default friction; anisotropic wheel friction fixes spinning
but then arcs lose forward speed (measurements in ``limo.md``). The real Limo's firmware closes
the loop on body velocity anyway, so a base that tracks (v, w) up to its acceleration limits is
the faithful model for the controller; what the controller must still cope with (blocked wheels,
odometry drift, camera lag behind the command) is kept.

Frames: the base frame origin lies midway between the four wheel axles at axle height
(``WHEEL_RADIUS_M`` above the floor), x forward, y left, z up; this is also the centre of mass,
so yaw turns the robot about its geometric centre. The floor's top surface is at z = 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from core.hal import Pose2D
from limo.geometry import (
    BODY_LENGTH_M,
    BODY_WIDTH_M,
    GROUND_CLEARANCE_M,
    MAX_ANGULAR_ACCEL_RADPS2,
    MAX_LINEAR_ACCEL_MPS2,
    TOTAL_MASS_KG,
    TRACK_M,
    WHEEL_RADIUS_M,
    WHEEL_WIDTH_M,
    WHEELBASE_M,
    wheel_speeds_radps,
)
from sim.bullet import p

# The body box is lower than the 251 mm overall height (that counts the sensor mast) so the
# forward camera at 0.18 m does not see the robot's own deck below ~80 deg HFOV.
WHEEL_MASS_KG = 0.25
BODY_TOP_M = 0.13                 # deck height above the floor; the camera sits higher, at 0.18 m
MAST_TOP_M = 0.20                 # visual-only sensor mast behind the camera (not collidable)

# The robot counts as toppled once its up axis leans more than this from vertical.
TOPPLE_TILT_RAD = math.radians(45.0)

# Spawn this much above resting height so the wheels settle onto the floor instead of starting
# interpenetrated (the solver would otherwise pop the body upward).
_SPAWN_DROP_M = 0.002
_WHEEL_MOTOR_FORCE_N = 50.0       # ample for a frictionless wheel: it reaches its target in one step

# Wheel order everywhere: front-left, rear-left, front-right, rear-right.
WHEEL_NAMES = ("front_left", "rear_left", "front_right", "rear_right")
_WHEEL_XY = (
    (WHEELBASE_M / 2, TRACK_M / 2),
    (-WHEELBASE_M / 2, TRACK_M / 2),
    (WHEELBASE_M / 2, -TRACK_M / 2),
    (-WHEELBASE_M / 2, -TRACK_M / 2),
)
LEFT_WHEELS = (0, 1)
RIGHT_WHEELS = (2, 3)


def _ramp(current: float, target: float, max_step: float) -> float:
    return current + min(max(target - current, -max_step), max_step)


@dataclass
class _Ramp:
    """The acceleration-limited command the base is actually following."""

    v_mps: float = 0.0
    w_radps: float = 0.0


class Limo:
    """One Limo body in one PyBullet client.

    ``Limo(client_id, start)`` creates the body resting on the floor (z = 0) at ``start``.
    Call :meth:`set_command` with the target body velocity, and :meth:`pre_step` with the
    physics time step before every ``stepSimulation``.
    """

    def __init__(self, client_id: int, start: Pose2D = Pose2D(0.0, 0.0, 0.0)):
        self.client_id = client_id
        self.body_id = self._create_body(start)
        self._target = _Ramp()
        self._ramp = _Ramp()
        self._wheels_dirty = True

    # ------------------------------------------------------------------ construction
    def _create_body(self, start: Pose2D) -> int:
        cid = self.client_id
        body_bottom = GROUND_CLEARANCE_M - WHEEL_RADIUS_M        # relative to the axle-height origin
        body_height = BODY_TOP_M - GROUND_CLEARANCE_M
        body_half = [BODY_LENGTH_M / 2, BODY_WIDTH_M / 2, body_height / 2]
        body_centre = [0.0, 0.0, body_bottom + body_height / 2]
        body_col = p.createCollisionShape(p.GEOM_BOX, halfExtents=body_half,
                                          collisionFramePosition=body_centre, physicsClientId=cid)
        mast_height = MAST_TOP_M - BODY_TOP_M
        body_vis = p.createVisualShapeArray(
            shapeTypes=[p.GEOM_BOX, p.GEOM_BOX],
            halfExtents=[body_half, [0.02, 0.05, mast_height / 2]],
            visualFramePositions=[body_centre, [0.03, 0.0, BODY_TOP_M - WHEEL_RADIUS_M + mast_height / 2]],
            rgbaColors=[[0.25, 0.27, 0.30, 1.0], [0.1, 0.1, 0.1, 1.0]],
            physicsClientId=cid,
        )
        # Cylinders are built along z; turn them so the axle is the link's y axis.
        axle_orn = p.getQuaternionFromEuler([math.pi / 2, 0.0, 0.0])
        wheel_col = p.createCollisionShape(p.GEOM_CYLINDER, radius=WHEEL_RADIUS_M, height=WHEEL_WIDTH_M,
                                           collisionFrameOrientation=axle_orn, physicsClientId=cid)
        wheel_vis = p.createVisualShape(p.GEOM_CYLINDER, radius=WHEEL_RADIUS_M, length=WHEEL_WIDTH_M,
                                        visualFrameOrientation=axle_orn, rgbaColor=[0.05, 0.05, 0.05, 1.0],
                                        physicsClientId=cid)
        n = len(_WHEEL_XY)
        body_id = p.createMultiBody(
            baseMass=TOTAL_MASS_KG - n * WHEEL_MASS_KG,
            baseCollisionShapeIndex=body_col,
            baseVisualShapeIndex=body_vis,
            basePosition=[start.x_m, start.y_m, WHEEL_RADIUS_M + _SPAWN_DROP_M],
            baseOrientation=p.getQuaternionFromEuler([0.0, 0.0, start.yaw_rad]),
            linkMasses=[WHEEL_MASS_KG] * n,
            linkCollisionShapeIndices=[wheel_col] * n,
            linkVisualShapeIndices=[wheel_vis] * n,
            linkPositions=[[x, y, 0.0] for x, y in _WHEEL_XY],
            linkOrientations=[[0, 0, 0, 1]] * n,
            linkInertialFramePositions=[[0, 0, 0]] * n,
            linkInertialFrameOrientations=[[0, 0, 0, 1]] * n,
            linkParentIndices=[0] * n,
            linkJointTypes=[p.JOINT_REVOLUTE] * n,
            linkJointAxis=[[0, 1, 0]] * n,
            physicsClientId=cid,
        )
        # Frictionless wheels: the base is driven by its velocity (module docstring), so wheel
        # friction would only fight the commanded yaw the way it does on a real skid-steer.
        for link in range(n):
            p.changeDynamics(body_id, link, lateralFriction=0.0, spinningFriction=0.0,
                             rollingFriction=0.0, physicsClientId=cid)
        # A little friction on the body lets it slide along a wall it grazes instead of sticking.
        p.changeDynamics(body_id, -1, lateralFriction=0.3, linearDamping=0.0, angularDamping=0.0,
                         physicsClientId=cid)
        return body_id

    # ------------------------------------------------------------------ driving
    def set_command(self, v_mps: float, w_radps: float) -> None:
        """The body velocity to reach (already clipped to the base's limits by the caller)."""
        self._target = _Ramp(float(v_mps), float(w_radps))

    @property
    def ramped_command(self) -> tuple[float, float]:
        """The acceleration-limited (v_mps, w_radps) the base follows right now."""
        return self._ramp.v_mps, self._ramp.w_radps

    def pre_step(self, dt_s: float) -> None:
        """Advance the acceleration ramp by ``dt_s`` and impose the planar velocity for one step."""
        cid, body = self.client_id, self.body_id
        prev = (self._ramp.v_mps, self._ramp.w_radps)
        self._ramp.v_mps = _ramp(self._ramp.v_mps, self._target.v_mps, MAX_LINEAR_ACCEL_MPS2 * dt_s)
        self._ramp.w_radps = _ramp(self._ramp.w_radps, self._target.w_radps, MAX_ANGULAR_ACCEL_RADPS2 * dt_s)
        v, w = self._ramp.v_mps, self._ramp.w_radps

        _, orn = p.getBasePositionAndOrientation(body, physicsClientId=cid)
        yaw = p.getEulerFromQuaternion(orn)[2]
        (_, _, vz), (wx, wy, _) = p.getBaseVelocity(body, physicsClientId=cid)
        p.resetBaseVelocity(body, linearVelocity=[v * math.cos(yaw), v * math.sin(yaw), vz],
                            angularVelocity=[wx, wy, w], physicsClientId=cid)

        if self._wheels_dirty or (v, w) != prev:
            left, right = wheel_speeds_radps(v, w)
            p.setJointMotorControlArray(body, list(range(4)), p.VELOCITY_CONTROL,
                                        targetVelocities=[left, left, right, right],
                                        forces=[_WHEEL_MOTOR_FORCE_N] * 4, physicsClientId=cid)
            self._wheels_dirty = False

    def wheel_angles_rad(self) -> tuple[float, float, float, float]:
        """Joint angles of the four wheels (order of ``WHEEL_NAMES``), radians, unwrapped."""
        states = p.getJointStates(self.body_id, list(range(4)), physicsClientId=self.client_id)
        return tuple(s[0] for s in states)  # type: ignore[return-value]

    # ------------------------------------------------------------------ truth
    def pose(self) -> Pose2D:
        """True planar pose of the base frame."""
        pos, orn = p.getBasePositionAndOrientation(self.body_id, physicsClientId=self.client_id)
        return Pose2D(pos[0], pos[1], p.getEulerFromQuaternion(orn)[2])

    def base_state(self) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        """Base position (m) and orientation quaternion (x, y, z, w) in the world frame."""
        pos, orn = p.getBasePositionAndOrientation(self.body_id, physicsClientId=self.client_id)
        return tuple(pos), tuple(orn)  # type: ignore[return-value]

    def yaw_rate_radps(self) -> float:
        """True angular velocity about the world z axis."""
        return p.getBaseVelocity(self.body_id, physicsClientId=self.client_id)[1][2]

    def tilt_rad(self) -> float:
        """Angle between the body's up axis and the world's up axis."""
        _, orn = p.getBasePositionAndOrientation(self.body_id, physicsClientId=self.client_id)
        up_z = p.getMatrixFromQuaternion(orn)[8]
        return math.acos(max(-1.0, min(1.0, up_z)))

    def toppled(self) -> bool:
        """True once the body leans more than ``TOPPLE_TILT_RAD`` from upright."""
        return self.tilt_rad() > TOPPLE_TILT_RAD

    def teleport(self, pose: Pose2D) -> None:
        """Put the robot at ``pose`` on the floor, at rest, with a zero command."""
        cid, body = self.client_id, self.body_id
        p.resetBasePositionAndOrientation(body, [pose.x_m, pose.y_m, WHEEL_RADIUS_M + _SPAWN_DROP_M],
                                          p.getQuaternionFromEuler([0.0, 0.0, pose.yaw_rad]),
                                          physicsClientId=cid)
        p.resetBaseVelocity(body, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], physicsClientId=cid)
        for j in range(4):
            angle = p.getJointState(body, j, physicsClientId=cid)[0]
            p.resetJointState(body, j, angle, 0.0, physicsClientId=cid)
        self._target = _Ramp()
        self._ramp = _Ramp()
        self._wheels_dirty = True

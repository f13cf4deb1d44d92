"""The PyBullet backend of the HAL: :class:`SimLimo` (a :class:`core.hal.RobotBase`) and its
simulator-only :class:`SimGroundTruth`.

Time is simulated: ``tick()`` steps the physics exactly ``control_period_s / physics_dt_s`` times
and ``SensorFrame.stamp_s`` is the simulated time. Everything random (odometry and IMU noise) comes
from one generator seeded with ``SimConfig.seed`` at every ``connect()``, and PyBullet itself is
deterministic, so the same seed and the same commands give the same poses and images.

Sensors, as the real base has them:

* wheel odometry is integrated from the wheel joint angles (not from ground truth), with a
  seeded per-period scale error on each side, so it drifts and keeps counting when a wall blocks
  the body while the wheels turn;
* the IMU yaw rate is the body's true angular velocity about z plus seeded Gaussian noise (one
  draw per control period);
* the camera image is rendered lazily on ``read()`` (once per simulated instant).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np
import pybullet_data

from core.angles import wrap_angle
from core.hal import STOP, GroundTruth, HalError, Odometry, Pose2D, RobotBase, SensorFrame, VelocityCommand
from limo.geometry import TRACK_M, WHEEL_RADIUS_M, body_twist
from sim.bullet import p
from sim.camera import Camera, check_light
from sim.config import SimConfig
from sim.limo import LEFT_WHEELS, RIGHT_WHEELS, Limo

GRAVITY_MPS2 = 9.81


@dataclass
class _OdometryState:
    """Dead-reckoned pose in the frame where the base connected, plus wheel totals."""

    x_m: float = 0.0
    y_m: float = 0.0
    yaw_rad: float = 0.0
    left_m: float = 0.0
    right_m: float = 0.0
    v_mps: float = 0.0
    w_radps: float = 0.0


class _Session:
    """Everything that exists only while connected (one PyBullet client and its bodies)."""

    def __init__(self, client_id: int, limo: Limo, camera: Camera, floor_ids: tuple[int, ...],
                 render_light: dict, seed: int):
        self.client_id = client_id
        self.limo = limo
        self.camera = camera
        self.floor_ids = floor_ids
        self.render_light = render_light
        # One stream per sensor, drawn only in tick(): how often read() is called changes nothing.
        odom_seed, imu_seed = np.random.SeedSequence(seed).spawn(2)
        self.odom_rng = np.random.default_rng(odom_seed)
        self.imu_rng = np.random.default_rng(imu_seed)
        self.imu_noise_radps = 0.0
        self.step_count = 0
        self.odom = _OdometryState()
        self.last_wheel_angles = limo.wheel_angles_rad()
        self.applied = STOP
        self.cached_frame: Optional[SensorFrame] = None
        self.cached_step = -1
        self.collisions = 0
        self.last_touch_step: dict[int, int] = {}


class SimLimo(RobotBase):
    """The simulated Limo behind the HAL.

    ``world``: ``None`` for a plain floor, or a world description handed to
    ``sim.world.build_world(client_id, world, appearance_seed)`` in :meth:`connect`.
    ``start``: where the robot is spawned (world frame).
    """

    def __init__(self, config: SimConfig = SimConfig(), start: Pose2D = Pose2D(0.0, 0.0, 0.0),
                 world: Any = None, appearance_seed: int = 0):
        self.config = config
        self.start = start
        self.world = world
        self.appearance_seed = appearance_seed
        self.limits = config.limits
        self.control_period_s = config.control_period_s
        self._session: Optional[_Session] = None
        self._ground_truth = SimGroundTruth(self)

    # ------------------------------------------------------------------ life cycle
    @property
    def connected(self) -> bool:
        return self._session is not None

    def connect(self) -> None:
        if self._session is not None:
            raise HalError("SimLimo.connect(): already connected; close() it first")
        cfg = self.config
        client_id = p.connect(p.GUI if cfg.gui else p.DIRECT)
        if client_id < 0:
            raise HalError("SimLimo.connect(): PyBullet could not start a physics client"
                           + (" (gui=True needs a display)" if cfg.gui else ""))
        try:
            p.resetSimulation(physicsClientId=client_id)
            p.setGravity(0.0, 0.0, -GRAVITY_MPS2, physicsClientId=client_id)
            p.setPhysicsEngineParameter(fixedTimeStep=cfg.physics_dt_s, numSubSteps=0,
                                        deterministicOverlappingPairs=1, physicsClientId=client_id)
            floor_ids, render_light = self._build_world(client_id)
            limo = Limo(client_id, self.start)
            camera = Camera(cfg.camera, base_height_m=WHEEL_RADIUS_M)
            self._session = _Session(client_id, limo, camera, floor_ids, render_light, cfg.seed)
        except BaseException:
            p.disconnect(physicsClientId=client_id)
            raise

    def _build_world(self, client_id: int) -> tuple[tuple[int, ...], dict]:
        """Load the floor (and walls and props of ``self.world``); returns (floor ids, render light)."""
        if self.world is None:
            p.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=client_id)
            plane = p.loadURDF("plane.urdf", physicsClientId=client_id)
            return (plane,), {}
        # The world side is built by sim.world (imported here only, so a plain-floor sim needs none of it).
        from sim.world import build_world

        built = build_world(client_id, self.world, self.appearance_seed)
        return tuple(built.floor_ids), check_light(built.render_light)

    def close(self) -> None:
        session = self._session
        if session is None:
            return
        try:
            self.stop()
        finally:
            self._session = None
            if p.isConnected(physicsClientId=session.client_id):
                p.disconnect(physicsClientId=session.client_id)

    # ------------------------------------------------------------------ HAL
    def _require(self, what: str) -> _Session:
        if self._session is None:
            raise HalError(f"SimLimo.{what}: not connected; call connect() first (or use 'with SimLimo(...)')")
        return self._session

    @property
    def client_id(self) -> int:
        """The PyBullet client of the running simulation (for world building and pictures)."""
        return self._require("client_id").client_id

    @property
    def robot_id(self) -> int:
        """The PyBullet body id of the Limo."""
        return self._require("robot_id").limo.body_id

    @property
    def sim_time_s(self) -> float:
        session = self._require("sim_time_s")
        return session.step_count * self.config.physics_dt_s

    @property
    def applied_command(self) -> VelocityCommand:
        """The command held since the last :meth:`apply` (after limits; STOP after connect)."""
        return self._require("applied_command").applied

    @property
    def ground_truth(self) -> "SimGroundTruth":
        """Simulator-only truth (poses, collisions); never hand this to a controller."""
        return self._ground_truth

    def apply(self, cmd: VelocityCommand) -> VelocityCommand:
        session = self._require("apply()")
        applied = self.limits.clip(cmd)
        session.limo.set_command(applied.v_mps, applied.w_radps)
        session.applied = applied
        return applied

    def tick(self) -> None:
        session = self._require("tick()")
        cfg = self.config
        # One odometry scale error per side per control period: slip varies slowly, not per step.
        scale_l, scale_r = (1.0 + cfg.odom_scale_noise * float(z) for z in session.odom_rng.standard_normal(2))
        dist_l = dist_r = 0.0
        for _ in range(cfg.steps_per_tick):
            session.limo.pre_step(cfg.physics_dt_s)
            p.stepSimulation(physicsClientId=session.client_id)
            session.step_count += 1
            dl, dr = self._integrate_odometry(session, scale_l, scale_r)
            dist_l += dl
            dist_r += dr
            self._update_collisions(session)
        session.odom.v_mps, session.odom.w_radps = body_twist(dist_l / cfg.control_period_s,
                                                              dist_r / cfg.control_period_s)
        session.imu_noise_radps = cfg.imu_yaw_rate_noise_radps * float(session.imu_rng.standard_normal())

    def read(self) -> SensorFrame:
        session = self._require("read()")
        if session.cached_step == session.step_count and session.cached_frame is not None:
            return session.cached_frame
        cfg = self.config
        rgb = None
        if cfg.camera_enabled:
            pos, orn = session.limo.base_state()
            rgb = session.camera.render(session.client_id, pos, orn, **session.render_light)
        o = session.odom
        odometry = Odometry(x_m=o.x_m, y_m=o.y_m, yaw_rad=o.yaw_rad, v_mps=o.v_mps, w_radps=o.w_radps,
                            left_m=o.left_m, right_m=o.right_m)
        yaw_rate = session.limo.yaw_rate_radps() + session.imu_noise_radps
        frame = SensorFrame(stamp_s=session.step_count * cfg.physics_dt_s, rgb=rgb, odometry=odometry,
                            imu_yaw_rate_radps=yaw_rate)
        session.cached_frame, session.cached_step = frame, session.step_count
        return frame

    # ------------------------------------------------------------------ internals
    @staticmethod
    def _integrate_odometry(session: _Session, scale_l: float, scale_r: float) -> tuple[float, float]:
        """Dead-reckon one physics step from the wheel angles; returns the (left, right) travel in m."""
        angles = session.limo.wheel_angles_rad()
        prev = session.last_wheel_angles
        session.last_wheel_angles = angles
        dl = scale_l * WHEEL_RADIUS_M * sum(angles[i] - prev[i] for i in LEFT_WHEELS) / len(LEFT_WHEELS)
        dr = scale_r * WHEEL_RADIUS_M * sum(angles[i] - prev[i] for i in RIGHT_WHEELS) / len(RIGHT_WHEELS)
        o = session.odom
        ds, dyaw = (dl + dr) / 2.0, (dr - dl) / TRACK_M
        mid = o.yaw_rad + dyaw / 2.0          # midpoint rule: exact for a constant arc
        o.x_m += ds * math.cos(mid)
        o.y_m += ds * math.sin(mid)
        o.yaw_rad = wrap_angle(o.yaw_rad + dyaw)
        o.left_m += dl
        o.right_m += dr
        return dl, dr

    def _update_collisions(self, session: _Session) -> None:
        """Count a collision when a non-floor body is touched after ``collision_debounce_s`` without touching."""
        robot = session.limo.body_id
        debounce_steps = int(round(self.config.collision_debounce_s / self.config.physics_dt_s))
        touching = {c[2] for c in p.getContactPoints(bodyA=robot, physicsClientId=session.client_id)
                    if c[8] <= _CONTACT_DISTANCE_M}
        touching.difference_update(session.floor_ids)
        touching.discard(robot)
        for body in touching:
            last = session.last_touch_step.get(body)
            if last is None or session.step_count - last > debounce_steps:
                session.collisions += 1
            session.last_touch_step[body] = session.step_count


# Contact points within this distance count as touching (the solver keeps points up to a few mm apart).
_CONTACT_DISTANCE_M = 1e-3


class SimGroundTruth(GroundTruth):
    """Simulator-only truth about a :class:`SimLimo`; valid while that base is connected."""

    def __init__(self, base: SimLimo):
        self._base = base

    def _session(self, what: str) -> _Session:
        return self._base._require(f"ground_truth.{what}")

    def true_pose(self) -> Pose2D:
        return self._session("true_pose()").limo.pose()

    def collision_count(self) -> int:
        return self._session("collision_count()").collisions

    def teleport(self, pose: Pose2D) -> None:
        session = self._session("teleport()")
        session.limo.teleport(pose)
        session.applied = STOP
        session.last_wheel_angles = session.limo.wheel_angles_rad()
        session.last_touch_step.clear()
        session.cached_frame, session.cached_step = None, -1

    def toppled(self) -> bool:
        return self._session("toppled()").limo.toppled()

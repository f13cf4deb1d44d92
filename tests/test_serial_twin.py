"""The serial twin: the PyBullet Limo behind the emulated firmware, driven over a real pseudo-terminal."""

import math
import os
import threading
import time

import numpy as np
import pybullet as p
import pytest

from core.angles import wrap_angle
from core.hal import HalError, Pose2D, RobotBase, VelocityCommand
from core.hal_check import check_base
from limo.camera import CameraError
from limo.config import LimoSerialConfig
from limo.emulator.firmware import EmulatorConfig, EmulatorError
from sim.config import CameraSpec, SimConfig
from sim.hal import SimLimo
from sim.serial_twin import PyBulletBaseModel, SerialTwinConfig, SerialTwinError, SerialTwinLimo, SimCameraSource
from sim.worlds import load_world

pytestmark = pytest.mark.slow      # the PyBullet Limo behind a serial link, in real time

# a start off the origin and heading, so frame mix-ups (world vs start frame) show
START = Pose2D(1.0, -2.0, 0.6)
SERIAL = LimoSerialConfig(control_period_s=0.05)
TWIN_THREADS = {"limo-emulator", "limo-serial-reader", "limo-serial-writer", "sim-camera"}


def walkthrough_start(world) -> Pose2D:
    (x0, y0), (x1, y1) = world.routes.walkthrough[:2]
    return Pose2D(x0, y0, math.atan2(y1 - y0, x1 - x0))


def serial_twin_in_hospital() -> RobotBase:
    """The factory for tests/test_hal_conformance.py BACKENDS (key "serial-twin-hospital")."""
    world = load_world("hospital")
    return SerialTwinLimo(world, SimConfig(width_px=64, height_px=48), walkthrough_start(world),
                          serial_config=LimoSerialConfig(control_period_s=0.05))


def drive(base: RobotBase, cmd: VelocityCommand, seconds: float) -> float:
    """Apply ``cmd`` every control period for ``seconds`` of wall time; returns the time it ran."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        base.apply(cmd)
        base.tick()
    return time.monotonic() - t0


def settle(base: RobotBase, seconds: float = 0.4) -> None:
    base.stop()
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        base.tick()


def in_start_frame(pose: Pose2D, start: Pose2D) -> tuple[float, float, float]:
    c, s = math.cos(start.yaw_rad), math.sin(start.yaw_rad)
    dx, dy = pose.x_m - start.x_m, pose.y_m - start.y_m
    dyaw = wrap_angle(pose.yaw_rad - start.yaw_rad)
    return c * dx + s * dy, -s * dx + c * dy, dyaw


# ------------------------------------------------------------------------- the model alone


def test_model_steps_physics_by_exactly_the_requested_time():
    model = PyBulletBaseModel(SimConfig(camera_enabled=False), start=START)
    model.connect()
    try:
        assert model.reset().x_m == 0.0
        pdt = model.sim_config.physics_dt_s
        rng = np.random.default_rng(7)
        requested = 0.0
        for dt in rng.uniform(0.001, 0.03, size=60):  # jittery real-time cycles, most not whole steps
            state = model.step(float(dt), 0.3, 0.0)
            requested += float(dt)
            assert 0.0 <= requested - model.sim_time_s < pdt + 1e-12
        timing = model.timing
        assert timing.sim_time_s == pytest.approx(timing.physics_steps * pdt)
        assert timing.requested_s == pytest.approx(requested)
        # the state is the body's: forward along the start heading, in the start frame
        truth = in_start_frame(model.ground_truth.true_pose(), START)
        assert truth[0] > 0.2 and state.x_m == pytest.approx(truth[0], abs=1e-9)
        assert state.y_m == pytest.approx(truth[1], abs=1e-9) and abs(state.y_m) < 0.01
        assert state.v_mps == pytest.approx(0.3, rel=0.05)
        assert state.left_m == pytest.approx(state.x_m, rel=0.05)
        assert state.right_m == pytest.approx(state.x_m, rel=0.05)
        camera = SimCameraSource(model, CameraSpec(width_px=32, height_px=24))
        assert camera.read().rgb.shape == (24, 32, 3)
    finally:
        model.close()
    assert not model.connected
    with pytest.raises(HalError, match="not connected"):
        model.ground_truth.true_pose()
    with pytest.raises(CameraError, match="simulated camera"):
        camera.read()


# ------------------------------------------------------------------------- over the serial link


def test_serial_twin_conforms_to_hal():
    check_base(serial_twin_in_hospital)


def test_forward_over_serial_moves_the_body_and_odometry_agrees():
    with SerialTwinLimo(None, SimConfig(camera_enabled=False), START, serial_config=SERIAL) as base:
        ran_s = drive(base, VelocityCommand(0.3, 0.0), 1.0)
        settle(base)
        fwd, left, dyaw = in_start_frame(base.ground_truth.true_pose(), START)
        odo = base.read().odometry
        stats = base.emulator.stats
    # ramp-up losses and ramp-down gains cancel: about 0.3 m/s for the time it ran
    assert fwd == pytest.approx(0.3 * ran_s, rel=0.15)
    assert abs(left) < 0.02 and abs(dyaw) < 0.03
    # odometry is in the frame where the base connected: the start pose
    assert odo.x_m == pytest.approx(fwd, rel=0.15) and abs(odo.y_m) < 0.03
    assert odo.left_m == pytest.approx(fwd, rel=0.15) and odo.right_m == pytest.approx(fwd, rel=0.15)
    assert stats.enable_commands >= 1 and stats.motion_commands >= 20 * ran_s


def test_turn_in_place_over_serial_turns_the_body_and_gyro_heading_agrees():
    with SerialTwinLimo(None, SimConfig(camera_enabled=False), START, serial_config=SERIAL) as base:
        ran_s = drive(base, VelocityCommand(0.0, -0.8), 1.0)
        settle(base)
        fwd, left, dyaw = in_start_frame(base.ground_truth.true_pose(), START)
        frame = base.read()
    assert dyaw == pytest.approx(-0.8 * ran_s, rel=0.2)  # clockwise, as commanded
    assert math.hypot(fwd, left) < 0.03
    assert frame.odometry.yaw_rad == pytest.approx(dyaw, rel=0.15)
    assert abs(frame.imu_yaw_rate_radps) < 0.05  # at rest again


def test_frames_have_the_configured_size_and_show_the_world_as_the_sim_hal_does():
    world = load_world("hospital")
    start = walkthrough_start(world)
    config = SimConfig(width_px=96, height_px=72)
    with SerialTwinLimo(world, config, start, appearance_seed=2, serial_config=SERIAL) as base:
        assert base.read().rgb is not None  # an image from the first read on, as with SimLimo
        settle(base, 0.5)  # at rest: the body has settled from its spawn height as SimLimo's does
        settled = time.monotonic()
        while (frame := base.camera_source.latest()) is None or frame.stamp_s < settled:
            assert time.monotonic() - settled < 3.0, "no camera frame rendered after settling"
            base.tick()
        rgb = base.read().rgb
        first = base.camera_source.latest()
        time.sleep(0.35)
        later = base.camera_source.latest()
    assert rgb.shape == (72, 96, 3) and rgb.dtype == np.uint8
    assert later.index > first.index and later.stamp_s > first.stamp_s
    assert later.stamp_s <= time.monotonic()

    def sim_hal_image(appearance_seed: int) -> np.ndarray:
        with SimLimo(config, start=start, world=world, appearance_seed=appearance_seed) as sim:
            for _ in range(5):
                sim.tick()
            return sim.read().rgb.astype(float)

    same_light = np.abs(frame.rgb.astype(float) - sim_hal_image(2)).mean()
    other_light = np.abs(frame.rgb.astype(float) - sim_hal_image(0)).mean()
    assert same_light < 1.0, f"the twin's camera renders differently from SimLimo's ({same_light:.2f})"
    assert other_light > 3 * max(same_light, 0.5), "the world's render light must change the image"


def test_ctrl_c_while_driving_stops_over_the_wire_and_releases_everything():
    base = SerialTwinLimo(None, SimConfig(width_px=64, height_px=48), START, serial_config=SERIAL,
                          twin_config=SerialTwinConfig(camera_rate_hz=5.0))
    with pytest.raises(KeyboardInterrupt):
        with base:
            emulator, client = base.emulator, base.model._sim.client_id
            path = base.config.port
            drive(base, VelocityCommand(0.3, 0.2), 0.4)
            assert emulator.commanded == VelocityCommand(0.3, 0.2)
            raise KeyboardInterrupt
    # stop_settle_s (0.3 s) is shorter than the firmware watchdog (0.5 s): this zero came as bytes
    assert emulator.commanded.is_zero
    assert emulator.stats.motion_commands > 10
    assert not base.connected and base.emulator is None
    assert not os.path.exists(path), "the pseudo-terminal must be closed"
    assert not p.isConnected(physicsClientId=client)
    assert not TWIN_THREADS & {t.name for t in threading.enumerate()}
    with pytest.raises(HalError, match="not connected"):
        base.ground_truth.true_pose()


def test_bad_twin_config_names_the_field():
    with pytest.raises(SerialTwinError, match="SerialTwinConfig.camera_rate_hz"):
        SerialTwinConfig(camera_rate_hz=0.0)
    with pytest.raises(SerialTwinError, match="SerialTwinConfig.stop_settle_s"):
        SerialTwinConfig(stop_settle_s=float("nan"))
    with pytest.raises(EmulatorError, match="max_step_s"):
        EmulatorConfig(max_step_s=0.0)

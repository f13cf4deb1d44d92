"""The emulated Limo firmware: kinematics, and its behaviour on a real pseudo-terminal via pyserial."""

import json
import math
import subprocess
import sys
import time

import pytest
import serial

from core.hal import VelocityCommand
from limo.emulator.__main__ import parse_fault
from limo.emulator.firmware import EmulatorConfig, EmulatorError, EmulatorFaults, LimoEmulator
from limo.emulator.models import KinematicModelConfig, KinematicUnicycle
from limo.protocol import (
    FrameParser,
    ImuEuler,
    ImuGyro,
    MotionState,
    SystemState,
    WheelOdometry,
    encode_enable,
    encode_motion,
)
from tests.waiting import wait_until


def collect(port, seconds, parser=None):
    """Every message read from ``port`` for ``seconds``."""
    parser = parser or FrameParser()
    out = []
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        out += parser.feed(port.read(max(1, port.in_waiting)))
    return out


@pytest.fixture
def emu_and_port():
    emu = LimoEmulator()
    path = emu.start()
    port = serial.serial_for_url(path, baudrate=460800, timeout=0.02)
    yield emu, port
    port.close()
    emu.stop()


# -------------------------------------------------------------------------- kinematic model


def test_kinematic_model_respects_accel_limits():
    model = KinematicUnicycle(KinematicModelConfig(max_accel_mps2=2.5, max_yaw_accel_radps2=3.2))
    state = model.step(0.1, 1.0, -1.0)
    assert state.v_mps == pytest.approx(0.25) and state.w_radps == pytest.approx(-0.32)
    for _ in range(5):
        state = model.step(0.1, 1.0, -1.0)
    assert state.v_mps == pytest.approx(1.0) and state.w_radps == pytest.approx(-1.0)
    state = model.step(0.1, 0.0, 0.0)
    assert state.v_mps == pytest.approx(0.75)


def test_kinematic_model_integrates_pose_and_wheels():
    # accelerations so large that a 1 ns step reaches any speed: the rest is pure integration
    model = KinematicUnicycle(KinematicModelConfig(max_accel_mps2=1e12, max_yaw_accel_radps2=1e12, track_m=0.2))
    model.step(1e-9, 0.0, 1.0)
    for _ in range(100):  # spin at 1 rad/s for pi/2 s
        state = model.step(math.pi / 200, 0.0, 1.0)
    assert state.yaw_rad == pytest.approx(math.pi / 2, abs=1e-9)
    assert (state.x_m, state.y_m) == pytest.approx((0.0, 0.0), abs=1e-9)
    assert state.right_m == pytest.approx(0.1 * math.pi / 2) and state.left_m == pytest.approx(-state.right_m)
    model.step(1e-9, 0.5, 0.0)
    for _ in range(100):  # then 0.5 m straight along +y
        state = model.step(0.01, 0.5, 0.0)
    assert (state.x_m, state.y_m) == pytest.approx((0.0, 0.5), abs=1e-6)


# -------------------------------------------------------------------------- over the pty


def test_feedback_streams_at_its_rates_before_enable_and_motion_is_ignored(emu_and_port):
    emu, port = emu_and_port
    port.write(encode_motion(0.3, 0.0))  # not enabled yet: the firmware must ignore it
    msgs = collect(port, 0.4)
    kinds = {cls: sum(isinstance(m, cls) for m in msgs) for cls in (SystemState, MotionState, WheelOdometry,
                                                                    ImuGyro, ImuEuler)}
    # 50 Hz for 0.4 s is 20 of each, the system state at 25 Hz 10; a busy 2-core machine may lose a few
    assert all(8 <= n <= 24 for cls, n in kinds.items() if cls is not SystemState), kinds
    assert 4 <= kinds[SystemState] <= 12, kinds
    system = [m for m in msgs if isinstance(m, SystemState)][-1]
    assert system.battery_v == pytest.approx(12.2) and system.control_mode == 0 and system.error_bits == 0
    assert not emu.enabled and emu.commanded == VelocityCommand(0.0, 0.0)
    assert emu.stats.motion_commands == 1


def test_commands_move_the_base_and_odometry_comes_back(emu_and_port):
    emu, port = emu_and_port
    port.write(encode_enable())
    deadline = time.monotonic() + 0.6
    msgs = []
    parser = FrameParser()
    while time.monotonic() < deadline:
        port.write(encode_motion(0.4, 0.0))
        msgs += collect(port, 0.02, parser)
    assert emu.enabled and emu.commanded == VelocityCommand(0.4, 0.0)
    assert emu.actual.v_mps == pytest.approx(0.4)
    odo = [m for m in msgs if isinstance(m, WheelOdometry)]
    assert odo[-1].left_mm == odo[-1].right_mm  # straight line
    # 0.4 m/s for ~0.6 s minus the 0.16 s ramp: roughly 0.2 m
    assert 150 <= odo[-1].left_mm <= 260
    assert abs(odo[-1].left_mm / 1000 - emu.pose.x_m) < 0.03
    motion = [m for m in msgs if isinstance(m, MotionState)]
    assert motion[-1].linear_mps == pytest.approx(0.4)
    assert [m for m in msgs if isinstance(m, SystemState)][-1].control_mode == 1


def test_gyro_and_euler_report_a_turn(emu_and_port):
    emu, port = emu_and_port
    port.write(encode_enable())
    port.write(encode_motion(0.0, -0.8))
    msgs = collect(port, 0.5)
    gyro = [m for m in msgs if isinstance(m, ImuGyro)][-1]
    euler = [m for m in msgs if isinstance(m, ImuEuler)][-1]
    assert gyro.z_degps == pytest.approx(math.degrees(-0.8), abs=0.01)
    assert euler.yaw_deg < -5.0
    assert euler.yaw_deg == pytest.approx(math.degrees(emu.pose.yaw_rad), abs=2.0)


def test_base_stops_by_itself_without_commands(emu_and_port):
    emu, port = emu_and_port
    port.write(encode_enable())
    port.write(encode_motion(0.2, 0.3))
    assert wait_until(lambda: emu.commanded == VelocityCommand(0.2, 0.3), 0.2)
    sent = time.monotonic()
    time.sleep(0.35)
    assert emu.commanded == VelocityCommand(0.2, 0.3)  # still within the 0.5 s timeout
    assert wait_until(lambda: emu.commanded.is_zero, 0.4)
    stopped_after = time.monotonic() - sent
    assert 0.45 <= stopped_after <= 0.75
    assert wait_until(lambda: emu.actual.is_zero, 0.3)


def test_flipped_bits_and_dropped_bytes_reach_the_host_parser():
    with LimoEmulator(config=EmulatorConfig(seed=3, faults=EmulatorFaults(flip_bit_prob=1.0))) as emu:
        with serial.serial_for_url(emu.device_path, baudrate=460800, timeout=0.02) as port:
            parser = FrameParser()
            msgs = collect(port, 0.3, parser)
            sent = emu.stats.feedback_frames_sent
            # a flip in the count byte goes unnoticed (receivers ignore it): about 1 frame in 14
            assert parser.stats.bad_checksums + parser.stats.bytes_skipped > 0
            assert len(msgs) < sent / 3
            emu.set_faults(EmulatorFaults(drop_byte_prob=1.0))
            port.reset_input_buffer()
            parser2 = FrameParser()
            dropped = collect(port, 0.3, parser2)
            assert parser2.stats.bytes_skipped > 100
            assert len(dropped) < parser2.stats.bytes_skipped / 14
            emu.set_faults(EmulatorFaults())
            port.reset_input_buffer()
            clean = collect(port, 0.3, FrameParser())
            assert len(clean) >= 40


def test_frozen_link_sends_nothing_and_may_swallow_commands(emu_and_port):
    emu, port = emu_and_port
    port.write(encode_enable())
    port.write(encode_motion(0.3, 0.0))
    assert wait_until(lambda: emu.commanded.v_mps == 0.3, 0.2)
    emu.freeze(True, drop_commands=True)
    time.sleep(0.05)
    port.reset_input_buffer()
    assert collect(port, 0.25) == []
    before = emu.stats.motion_commands
    port.write(encode_motion(0.3, 0.0))
    time.sleep(0.05)
    assert emu.stats.motion_commands == before
    assert wait_until(lambda: emu.commanded.is_zero, 0.6)  # its own timeout stops the base
    emu.freeze(False)
    assert len(collect(port, 0.2)) > 10


def test_fault_specs_parse_and_bad_ones_are_named():
    assert parse_fault("flip-bits=0.05") == {"flip-bits": 0.05}
    assert parse_fault("freeze") == {"freeze-at": 0.0}
    assert parse_fault("freeze-at=2.5") == {"freeze-at": 2.5}
    with pytest.raises(EmulatorError, match="unknown fault 'melt'"):
        parse_fault("melt=1")
    with pytest.raises(EmulatorError, match="probability"):
        parse_fault("drop-bytes=2")
    with pytest.raises(EmulatorError, match="NUMBER"):
        parse_fault("flip-bits=lots")
    with pytest.raises(EmulatorError, match="probability"):
        EmulatorFaults(flip_bit_prob=-0.1)


@pytest.mark.slow     # a subprocess
def test_cli_prints_a_device_that_answers_and_exits():
    proc = subprocess.Popen([sys.executable, "-m", "limo.emulator", "--duration", "1.0",
                             "--battery-v", "11.1", "--error-bits", "0x0002"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        path = proc.stdout.readline().strip()
        assert path.startswith("/dev/")
        with serial.serial_for_url(path, baudrate=460800, timeout=0.02) as port:
            msgs = collect(port, 0.3)
        system = [m for m in msgs if isinstance(m, SystemState)]
        assert system and system[-1].battery_v == pytest.approx(11.1) and system[-1].error_bits == 0x0002
        assert proc.wait(timeout=5) == 0
    finally:
        proc.kill()
        proc.wait()


@pytest.mark.slow     # a subprocess
def test_cli_rejects_a_bad_fault_with_a_message():
    result = subprocess.run([sys.executable, "-m", "limo.emulator", "--fault", "melt"],
                            capture_output=True, text=True, timeout=30)
    assert result.returncode == 2
    assert "unknown fault 'melt'" in result.stderr and "Traceback" not in result.stderr


PYLIMO_CLIENT = """
import json, os, sys, time
from pylimo import limo
robot = limo.LIMO(name=sys.argv[1])       # AgileX's own client: it reads 28 bytes, parses the first frame
robot.EnableCommand()
deadline = time.monotonic() + 2.0
while time.monotonic() < deadline:
    robot.SetMotionCommand(linear_vel=0.2, angular_vel=0.0)
    time.sleep(0.02)
print(json.dumps({"linear": robot.GetLinearVelocity(), "battery": robot.GetBatteryVoltage(),
                  "left_odom": robot.GetLeftWheelOdeom(), "right_odom": robot.GetRightWheelOdom()}), flush=True)
os._exit(0)                               # its reader thread never ends by itself
"""


@pytest.mark.slow     # a subprocess, in real time
def test_agilex_pylimo_reads_the_emulators_motion_state_odometry_and_battery():
    with LimoEmulator(config=EmulatorConfig(battery_v=11.8)) as emu:
        proc = subprocess.run([sys.executable, "-c", PYLIMO_CLIENT, emu.device_path], capture_output=True,
                              text=True, timeout=60)
        assert proc.returncode == 0, proc.stderr
        seen = json.loads(proc.stdout.strip().splitlines()[-1])
        assert emu.stats.motion_commands > 20 and emu.commanded == VelocityCommand(0.2, 0.0)
    assert seen["linear"] == pytest.approx(0.2, abs=0.01)
    assert seen["battery"] == pytest.approx(11.8, abs=0.05)
    assert 200 < seen["left_odom"] < 500                   # mm after about 2 s at 0.2 m/s
    assert seen["left_odom"] == pytest.approx(seen["right_odom"], abs=5)

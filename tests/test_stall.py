"""Telling a stalled robot from its commanded turns and its gyro (controllers.stall)."""

import math

import pytest

from controllers.config import RecoveryConfig
from controllers.stall import StallMonitor

DT = 0.1


def _feed(monitor, commanded, measured, seconds, start=0.0):
    out = []
    for k in range(int(round(seconds / DT))):
        out.append(monitor.update(start + (k + 1) * DT, commanded, measured))
    return out


def test_turns_commanded_and_not_made_are_a_stall_after_the_window():
    monitor = StallMonitor(RecoveryConfig(window_s=2.0, min_turn_deg=30.0, turn_ratio=0.25))
    monitor.update(0.0, 0.0, 0.0)
    seen = _feed(monitor, -0.4, 0.01, 3.0)           # turning right, the gyro sees nothing
    assert not any(seen[:19]) and all(seen[20:])     # two seconds of it first


def test_a_free_robot_a_straight_drive_and_no_gyro_are_not():
    config = RecoveryConfig(window_s=2.0, min_turn_deg=30.0, turn_ratio=0.25)
    free = StallMonitor(config)
    free.update(0.0, 0.0, 0.0)
    assert not any(_feed(free, 0.5, 0.35, 4.0))       # a skid-steer turns a bit less than commanded
    straight = StallMonitor(config)
    straight.update(0.0, 0.0, 0.0)
    assert not any(_feed(straight, 0.0, 0.0, 4.0))    # nothing to compare: not told
    flip_flop = StallMonitor(config)                  # left and right alternating: no net turn commanded
    flip_flop.update(0.0, 0.0, 0.0)
    assert not any(flip_flop.update((k + 1) * DT, 0.5 if k % 2 else -0.5, 0.0) for k in range(40))
    blind = StallMonitor(config)
    assert not any(blind.update((k + 1) * DT, 0.5, None) for k in range(40))
    wrong_way = StallMonitor(config)                  # turning the other way than commanded: stalled too
    wrong_way.update(0.0, 0.0, 0.0)
    assert _feed(wrong_way, 0.5, -0.1, 3.0)[-1]


def test_reset_starts_the_window_again():
    monitor = StallMonitor(RecoveryConfig(window_s=1.0))
    monitor.update(0.0, 0.0, 0.0)
    assert _feed(monitor, 0.8, 0.0, 2.0)[-1]
    monitor.reset()
    monitor.update(10.0, 0.0, 0.0)
    assert not any(_feed(monitor, 0.8, 0.0, 0.9, start=10.0))
    assert math.isclose(monitor.config.window_s, 1.0)


@pytest.mark.parametrize("start_yaw_rad", [0.0, 0.3])
def test_a_simulated_limo_pressed_against_a_wall_is_told_and_a_free_one_is_not(start_yaw_rad):
    """Real PyBullet: driving forward-right into a wall, head-on or oblique, the body stops turning
    while its wheels turn on; in the open the same command turns it."""
    from core.hal import Pose2D, VelocityCommand
    from sim.config import SimConfig
    from sim.hal import SimLimo
    from tests.test_limo_kinematics import _add_wall

    def stalls(wall: bool) -> list[bool]:
        with SimLimo(SimConfig(camera_enabled=False), start=Pose2D(0.0, 0.0, start_yaw_rad)) as base:
            if wall:
                _add_wall(base.client_id, x_face_m=0.45)
            monitor, command, flags = StallMonitor(RecoveryConfig()), VelocityCommand(0.2, -0.3), []
            for k in range(60):
                frame = base.read()
                flags.append(monitor.update(frame.stamp_s, command.w_radps if k else 0.0, frame.imu_yaw_rate_radps))
                base.apply(command)
                base.tick()
            return flags

    against = stalls(True)
    assert not any(against[:15]) and True in against and all(against[-20:])
    assert not any(stalls(False))

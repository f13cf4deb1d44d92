"""The simulated Limo turns as commanded: achieved (v, w) from ground truth within 10%."""

import math

import pybullet as p
import pytest

from core.angles import wrap_angle
from core.hal import Pose2D, VelocityCommand
from limo.geometry import BODY_LENGTH_M
from sim.config import SimConfig
from sim.hal import SimLimo

SETTLE_S = 0.5          # the acceleration ramps need at most 0.32 s (1 rad/s at 3.2 rad/s^2)
MEASURE_S = 2.0
TOLERANCE = 0.10
GRID = [(v, w) for v in (0.0, 0.2, 0.5) for w in (-1.0, -0.5, 0.0, 0.5, 1.0) if (v, w) != (0.0, 0.0)]


def measure_twist(base: SimLimo, v_mps: float, w_radps: float) -> tuple[float, float]:
    """Achieved (v, w) over MEASURE_S after SETTLE_S: path length and unwrapped heading change, from ground truth."""
    truth = base.ground_truth
    truth.teleport(Pose2D(0.0, 0.0, 0.0))
    base.apply(VelocityCommand(v_mps, w_radps))
    for _ in range(round(SETTLE_S / base.control_period_s)):
        base.tick()
    prev = truth.true_pose()
    path_m = turn_rad = 0.0
    for _ in range(round(MEASURE_S / base.control_period_s)):
        base.tick()
        pose = truth.true_pose()
        path_m += pose.distance_to(prev)   # chords of 0.1 s arcs: under 0.01% short at 1 rad/s
        turn_rad += wrap_angle(pose.yaw_rad - prev.yaw_rad)
        prev = pose
    assert not truth.toppled()
    return path_m / MEASURE_S, turn_rad / MEASURE_S


@pytest.fixture(scope="module")
def base():
    with SimLimo(SimConfig(camera_enabled=False)) as b:
        yield b


@pytest.mark.parametrize("v_mps,w_radps", GRID)
def test_achieved_twist_within_tolerance(base, v_mps, w_radps):
    v, w = measure_twist(base, v_mps, w_radps)
    print(f"commanded ({v_mps:+.2f} m/s, {w_radps:+.2f} rad/s) -> achieved ({v:+.3f}, {w:+.3f})")
    assert abs(v - v_mps) <= TOLERANCE * max(abs(v_mps), 0.05), f"v: commanded {v_mps}, achieved {v:.4f}"
    assert abs(w - w_radps) <= TOLERANCE * max(abs(w_radps), 0.05), f"w: commanded {w_radps}, achieved {w:.4f}"


def test_acceleration_is_limited(base):
    truth = base.ground_truth
    truth.teleport(Pose2D(0.0, 0.0, 0.0))
    base.apply(VelocityCommand(0.5, 0.0))
    base.tick()                                   # 0.1 s at 2.5 m/s^2: at most 0.25 m/s, 0.0125 m
    x = truth.true_pose().x_m
    assert 0.005 < x < 0.0135


def test_wheel_odometry_follows_the_drive(base):
    """Odometry comes from the wheel joints; with its default noise it stays near the truth on a short arc."""
    start = base.read().odometry
    start_pose = base.ground_truth.true_pose()
    base.apply(VelocityCommand(0.3, 0.4))
    for _ in range(20):
        base.tick()
    odom, pose = base.read().odometry, base.ground_truth.true_pose()
    travelled = math.hypot(odom.x_m - start.x_m, odom.y_m - start.y_m)
    assert travelled == pytest.approx(pose.distance_to(start_pose), rel=0.05)
    assert wrap_angle(odom.yaw_rad - start.yaw_rad) == pytest.approx(wrap_angle(pose.yaw_rad - start_pose.yaw_rad), rel=0.05)
    assert odom.v_mps == pytest.approx(0.3, rel=0.05) and odom.w_radps == pytest.approx(0.4, rel=0.1)
    assert odom.right_m - start.right_m > odom.left_m - start.left_m > 0  # turning left: right side travels further


def _add_wall(client_id: int, x_face_m: float) -> int:
    """A static box wall 0.1 m thick whose near face is at x = x_face_m."""
    half = [0.05, 1.5, 0.5]
    col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=client_id)
    return p.createMultiBody(0, col, basePosition=[x_face_m + half[0], 0.0, half[2]], physicsClientId=client_id)


@pytest.mark.parametrize("start_yaw_rad", [0.0, 0.3])
def test_wall_stops_the_robot_and_counts_one_collision(start_yaw_rad):
    """Head-on and oblique: the robot stops at the wall, upright; a long push is one collision."""
    with SimLimo(SimConfig(camera_enabled=False), start=Pose2D(0.0, 0.0, start_yaw_rad)) as base:
        truth = base.ground_truth
        wall = _add_wall(base.client_id, x_face_m=1.0)
        base.apply(VelocityCommand(0.5, 0.0))
        for _ in range(10):                       # 1 s: not there yet
            base.tick()
        assert truth.collision_count() == 0       # the floor is not an obstacle
        for _ in range(40):                       # 4 s more: pushing against the wall most of the time
            base.tick()
            assert truth.true_pose().x_m < 1.0 - BODY_LENGTH_M / 2 + 0.01, "the robot passed into the wall"
        assert p.getContactPoints(base.robot_id, wall, physicsClientId=base.client_id)
        assert truth.collision_count() == 1       # one long push is one collision
        assert not truth.toppled()
        odom = base.read().odometry
        assert odom.x_m > truth.true_pose().x_m + 0.5    # the wheels kept turning against the wall

        truth.teleport(Pose2D(0.2, 0.0, 0.0))     # back off, then hit it again
        base.tick()
        assert not p.getContactPoints(base.robot_id, wall, physicsClientId=base.client_id)
        base.apply(VelocityCommand(0.5, 0.0))
        for _ in range(20):
            base.tick()
        assert truth.collision_count() == 2
        assert truth.true_pose().x_m < 1.0 - BODY_LENGTH_M / 2 + 0.01   # stops with its bumper at the wall
        assert not truth.toppled()


def test_teleport_puts_the_robot_at_rest():
    with SimLimo(SimConfig(camera_enabled=False)) as base:
        base.apply(VelocityCommand(0.5, 1.0))
        for _ in range(5):
            base.tick()
        base.ground_truth.teleport(Pose2D(2.0, -1.0, 1.2))
        for _ in range(5):
            base.tick()
        pose = base.ground_truth.true_pose()
        assert pose.distance_to(Pose2D(2.0, -1.0, 1.2)) < 1e-3 and abs(pose.yaw_rad - 1.2) < 1e-3

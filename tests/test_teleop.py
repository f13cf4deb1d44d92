"""The scripted teleoperator follows a closed route with a unicycle model (no simulator)."""

import math

import numpy as np
import pytest

from core.hal import Pose2D
from sim.teleop import TeleopConfig, WaypointTeleop

SQUARE = [(0, 0), (4, 0), (4, 3), (0, 3), (0, 0)]


def _distance_to_polyline(p, pts):
    pts = np.asarray(pts, float)
    best = math.inf
    for a, b in zip(pts[:-1], pts[1:]):
        t = np.clip(np.dot(p - a, b - a) / np.dot(b - a, b - a), 0, 1)
        best = min(best, float(np.hypot(*(a + t * (b - a) - p))))
    return best


def _drive(teleop, pose, dt=0.1, max_steps=2000):
    trace = [pose]
    for _ in range(max_steps):
        if teleop.done(pose):
            break
        cmd = teleop.command(pose)
        yaw = pose.yaw_rad + cmd.w_radps * dt
        pose = Pose2D(pose.x_m + cmd.v_mps * dt * math.cos(yaw), pose.y_m + cmd.v_mps * dt * math.sin(yaw), yaw)
        trace.append(pose)
    return trace


def test_follows_a_closed_square_and_stops_at_the_start():
    teleop = WaypointTeleop(SQUARE)
    trace = _drive(teleop, Pose2D(0, 0, 0))
    assert teleop.done(trace[-1]), "the drive did not finish"
    assert trace[-1].distance_to(Pose2D(0, 0, 0)) < TeleopConfig().goal_tolerance_m
    worst = max(_distance_to_polyline(np.array([p.x_m, p.y_m]), SQUARE) for p in trace)
    assert worst < 0.35, f"left the path by {worst:.2f} m"
    # it must have gone round, not declared the loop done at the start
    assert teleop.progress_m > 0.9 * teleop.length_m
    assert max(p.x_m for p in trace) > 3.5 and max(p.y_m for p in trace) > 2.5


def test_turns_in_place_when_facing_away():
    teleop = WaypointTeleop(SQUARE)
    cmd = teleop.command(Pose2D(0, 0, math.pi))
    assert cmd.v_mps == 0.0 and abs(cmd.w_radps) > 0


def test_rejects_malformed_waypoints():
    with pytest.raises(ValueError, match="at least two"):
        WaypointTeleop([(0, 0)])
    with pytest.raises(ValueError, match="cruise_v_mps"):
        TeleopConfig(cruise_v_mps=0)

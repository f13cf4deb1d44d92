"""The gyro's heading (core/yaw_rate.py) and the run loop's heading from it."""

import math
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from controllers.config import NavigationConfig
from core.hal import Odometry, SensorFrame
from core.yaw_rate import YawRateIntegrator
from maps.graph import MapError, TopoMap
from robot.episode.loop import _Heading, navigation_headings
from robot.episode.setup import configure_heading


def test_a_rate_is_integrated_by_the_trapezoid_rule():
    gyro = YawRateIntegrator()
    assert gyro.yaw_rad is None
    assert gyro.update(5.0, 0.3) == 0.0                           # the first sample starts at 0
    assert gyro.update(5.5, 0.5) == pytest.approx(0.2)            # (0.3 + 0.5) / 2 x 0.5 s
    assert gyro.update(5.5, -1.0) == pytest.approx(0.2)           # no time passed
    for bad in ((5.4, 0.0), (6.0, float("nan")), (float("inf"), 0.0)):
        with pytest.raises(ValueError):
            gyro.update(*bad)


def _frame(k: int, odom_yaw: float, rate: float) -> SensorFrame:
    return SensorFrame(stamp_s=0.1 * k, rgb=None, odometry=Odometry(0.0, 0.0, odom_yaw, 0.0, 0.0, 0.1 * k, 0.0),
                       imu_yaw_rate_radps=rate)


def test_the_navigators_heading_from_the_gyro_ignores_a_wheel_scrubbing_on_a_wall():
    """Standing still, the wheels' yaw jumps by 0.5 rad (scrubbing along a wall): the gyro's
    heading does not; turning at 0.5 rad/s for 1 s, both follow."""
    gyro, wheels = _Heading("gyro"), _Heading("odometry")
    yaws = [0.0] * 5 + [0.5] * 5 + [0.5 + 0.05 * k for k in range(1, 11)]
    rates = [0.0] * 10 + [0.5] * 10
    out = [(gyro.update(_frame(k, y, r)), wheels.update(_frame(k, y, r))) for k, (y, r) in enumerate(zip(yaws, rates))]
    assert out[9] == (pytest.approx(0.0), pytest.approx(0.5))
    assert out[-1][0] == pytest.approx(0.475) and out[-1][1] == pytest.approx(1.0)    # 0.5 rad/s from step 10
    assert _Heading("gyro").update(SensorFrame(stamp_s=0.0, rgb=None)) is None      # no gyro: no heading
    assert math.isclose(_Heading("odometry").update(SensorFrame(stamp_s=0.0, rgb=None, imu_yaw_rate_radps=1.0)), 0.0)


def test_navigation_takes_the_maps_headings_of_its_source_or_refuses():
    graph_map = TopoMap(4)
    for k in range(3):
        graph_map.add_node(np.eye(4)[k], k, 0.2 * k)
    assert navigation_headings(graph_map, "gyro") is None          # a video's map: no headings at all
    for k in range(3):
        graph_map.set_odom_yaw(k, 0.1 * k)
    assert navigation_headings(graph_map, "odometry") == {0: 0.0, 1: 0.1, 2: 0.2}
    with pytest.raises(MapError, match="heading_source 'gyro': the map has no gyro headings"):
        navigation_headings(graph_map, "gyro")
    for k in range(3):
        graph_map.set_gyro_yaw(k, -0.1 * k)
    assert navigation_headings(graph_map, "gyro") == {0: 0.0, 1: -0.1, 2: -0.2}


def test_a_map_without_gyro_headings_navigates_on_the_wheels_with_a_note():
    """``heading_source: gyro`` on a map recorded before gyro headings were kept: both the map's
    and the robot's heading come from the wheel odometry, and the note names the map."""
    graph_map = TopoMap(4)
    for k in range(3):
        graph_map.add_node(np.eye(4)[k], k, 0.2 * k)
    loaded = SimpleNamespace(path=Path("maps/old"), topomap=graph_map)
    gyro = NavigationConfig(heading_source="gyro")
    assert configure_heading(loaded, gyro) == (gyro, None)                  # a video's map: no headings at all
    for k in range(3):
        graph_map.set_odom_yaw(k, 0.1 * k)
    used, note = configure_heading(loaded, gyro)
    assert used.heading_source == "odometry" and used == replace(gyro, heading_source="odometry")
    assert "maps/old has no gyro headings" in note and "rebuild" in note
    for k in range(3):
        graph_map.set_gyro_yaw(k, -0.1 * k)
    assert configure_heading(loaded, gyro) == (gyro, None)
    wheels = NavigationConfig(heading_source="odometry")
    assert configure_heading(loaded, wheels) == (wheels, None)

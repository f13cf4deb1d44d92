"""Recordings are written atomically and read back exactly."""

import json

import numpy as np
import pytest

from core.hal import Odometry, Pose2D, SensorFrame
from robot.mapping.recording import RecordingError, RecordingWriter, read_recording


def _frame(i):
    rgb = np.full((24, 32, 3), 10 * i, np.uint8)
    rgb[:, : 4 * (i + 1)] = 200
    return SensorFrame(stamp_s=0.1 * i, rgb=rgb, odometry=Odometry(i * 0.1, 0, 0, 0.5, 0, 0, 0), imu_yaw_rate_radps=0.0)


def test_round_trip(tmp_path):
    out = tmp_path / "rec"
    w = RecordingWriter(out)
    for i in range(5):
        w.append(_frame(i), Pose2D(i * 0.1, 0.0, 0.0))
    summary = w.finish({"world": "test"})
    assert summary["frames"] == 5 and summary["metres_driven"] == pytest.approx(0.4)
    assert json.loads((out / "summary.json").read_text())["world"] == "test"
    frames = read_recording(out)
    assert [f.index for f in frames] == list(range(5))
    assert frames[3].true_pose == Pose2D(3 * 0.1, 0.0, 0.0)
    img = frames[2].load_rgb()
    assert img.shape == (24, 32, 3)
    assert abs(int(img[0, 20, 0]) - 20) < 6 and img[0, 0, 0] > 190


def test_interrupted_recording_leaves_previous_one(tmp_path):
    out = tmp_path / "rec"
    w = RecordingWriter(out)
    w.append(_frame(0))
    w.finish()
    w2 = RecordingWriter(out)
    w2.append(_frame(1))
    w2.abort()
    assert len(read_recording(out)) == 1
    assert not any(p.name.startswith(".rec") for p in tmp_path.iterdir())


def test_missing_and_broken_recordings_are_named(tmp_path):
    with pytest.raises(RecordingError, match="frames.csv"):
        read_recording(tmp_path)
    (tmp_path / "frames.csv").write_text("index,stamp_s,file\n0,0.0,frames/000000.jpg\n")
    with pytest.raises(RecordingError, match="000000.jpg"):
        read_recording(tmp_path)


def test_the_gyro_heading_is_integrated_over_every_frame_or_none(tmp_path):
    """The recorded yaw rate turns into a heading per frame (trapezoid rule: a rate rising
    linearly is integrated exactly); one frame without a rate leaves the whole drive without."""
    out = tmp_path / "rec"
    w = RecordingWriter(out)
    for i in range(6):
        frame = _frame(i)
        w.append(SensorFrame(stamp_s=frame.stamp_s, rgb=frame.rgb, odometry=frame.odometry,
                             imu_yaw_rate_radps=0.2 * frame.stamp_s))
    w.finish()
    frames = read_recording(out)
    assert [f.gyro_yaw_rad for f in frames] == pytest.approx([0.1 * (0.1 * i) ** 2 for i in range(6)])
    table = out / "frames.csv"
    rows = table.read_text().splitlines()
    cells = rows[3].split(",")
    cells[8] = ""                                         # imu_yaw_rate_radps of frame 2
    table.write_text("\n".join(rows[:3] + [",".join(cells)] + rows[4:]) + "\n")
    assert all(f.gyro_yaw_rad is None for f in read_recording(out))
    cells[0], cells[1], cells[8] = "2", "0.0", "0.1"     # a stamp that goes back
    table.write_text("\n".join(rows[:3] + [",".join(cells)] + rows[4:]) + "\n")
    with pytest.raises(RecordingError, match="line 4: gyro stamps must not go back"):
        read_recording(out)

"""CameraSource on a real video file written with cv2.VideoWriter (MJPG .avi)."""

import time

import cv2
import numpy as np
import pytest

from core.hal import HalError
from limo.camera import CameraError, CameraSource

# BGR colours as OpenCV writes them; the source must hand out RGB
BGR_FRAMES = [(0, 0, 255), (0, 255, 0), (255, 0, 0), (0, 255, 255)]  # red, green, blue, yellow
RGB_EXPECTED = [(255, 0, 0), (0, 255, 0), (0, 0, 255), (255, 255, 0)]


@pytest.fixture
def video(tmp_path):
    path = tmp_path / "route.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 20.0, (80, 60))
    assert writer.isOpened()
    for bgr in BGR_FRAMES:
        writer.write(np.full((60, 80, 3), bgr, np.uint8))
    writer.release()
    return path


def test_replay_gives_rgb_frames_in_order_with_monotonic_stamps(video):
    with CameraSource(video) as cam:
        assert cam.fps == pytest.approx(20.0)
        frames = []
        before = time.monotonic()
        while (frame := cam.read()) is not None:
            frames.append(frame)
        after = time.monotonic()
        assert cam.ended
    assert [f.index for f in frames] == [0, 1, 2, 3]
    for frame, rgb in zip(frames, RGB_EXPECTED):
        assert frame.rgb.shape == (60, 80, 3) and frame.rgb.dtype == np.uint8
        assert np.abs(frame.rgb.reshape(-1, 3).mean(axis=0) - rgb).max() < 12  # MJPG is lossy
    stamps = [f.stamp_s for f in frames]
    assert before <= stamps[0] and stamps == sorted(stamps) and stamps[-1] <= after


def test_loop_restarts_a_file_at_its_end(video):
    with CameraSource(video, loop=True) as cam:
        frames = [cam.read() for _ in range(6)]
    assert all(f is not None for f in frames)
    assert np.abs(frames[4].rgb.reshape(-1, 3).mean(axis=0) - RGB_EXPECTED[0]).max() < 12


def test_background_grabbing_keeps_the_newest_frame_and_stops_on_close(video):
    cam = CameraSource(video, realtime=False)
    cam.start()
    try:
        deadline = time.monotonic() + 1.0
        while not cam.ended and time.monotonic() < deadline:
            time.sleep(0.005)
        last = cam.latest()
        assert cam.ended and last.index == 3
        assert np.abs(last.rgb.reshape(-1, 3).mean(axis=0) - RGB_EXPECTED[3]).max() < 12
    finally:
        cam.close()
    assert not cam.is_open


def test_background_pacing_takes_the_file_duration(video):
    cam = CameraSource(video)
    start = time.monotonic()
    cam.start()
    try:
        while cam.latest() is None or cam.latest().index < 3:
            assert time.monotonic() - start < 1.0
            time.sleep(0.002)
        elapsed = cam.latest().stamp_s - start
    finally:
        cam.close()
    assert 0.12 <= elapsed <= 0.5  # frame 3 is due 3/20 s after frame 0


def test_missing_file_and_bad_device_are_clear_errors(tmp_path):
    with pytest.raises(CameraError, match="no such video file"):
        CameraSource(tmp_path / "missing.avi").open()
    garbage = tmp_path / "garbage.avi"
    garbage.write_bytes(b"not a video at all" * 10)
    with pytest.raises(CameraError, match="cannot open camera source .*garbage.avi"):
        CameraSource(garbage).open()
    with pytest.raises(CameraError, match="/dev/video57"):
        CameraSource("57").open()  # digit strings are device indices
    assert issubclass(CameraError, HalError)


def test_read_before_open_is_an_error(video):
    cam = CameraSource(video)
    with pytest.raises(CameraError, match="not open"):
        cam.read()
    cam.open()
    with pytest.raises(CameraError, match="already open"):
        cam.open()
    cam.close()
    cam.close()


def test_wait_for_frame_returns_the_first_frame_or_names_the_camera(video):
    cam = CameraSource(video, realtime=True)
    try:
        with pytest.raises(CameraError, match=r"route\.avi.*delivered no frame within 0\.05 s"):
            cam.wait_for_frame(0.05)          # not started: nothing grabs
        cam.start()
        first = cam.wait_for_frame(5.0)       # right after start, without polling
        assert first.index in (0, 1)
        assert np.abs(first.rgb.reshape(-1, 3).mean(axis=0) - RGB_EXPECTED[first.index]).max() < 12
    finally:
        cam.close()

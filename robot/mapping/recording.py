"""Recorded drives: camera frames with timestamps, odometry and (in simulation) true poses.

Layout of a recording folder::

    frames/000000.jpg ...   camera frames (RGB saved as JPEG)
    frames.csv              one row per frame: index, stamp_s, file, odometry, IMU, true pose
    summary.json            frames, metres driven, duration, and whatever the run adds

A recording is written into a sibling temporary folder and moved into place only when it is
complete, so an interrupted run never leaves a half-written recording where a finished one
(or nothing) was expected; an existing recording at the same path is replaced only then.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterator, Optional

import cv2
import numpy as np

from core.atomic import AtomicFolder
from core.hal import Pose2D, SensorFrame
from core.yaw_rate import YawRateIntegrator

COLUMNS = ["index", "stamp_s", "file", "odom_x_m", "odom_y_m", "odom_yaw_rad", "odom_v_mps",
           "odom_w_radps", "imu_yaw_rate_radps", "true_x_m", "true_y_m", "true_yaw_rad"]


class RecordingError(ValueError):
    """A recording folder is missing, incomplete or malformed; the message names the file."""


@dataclass(frozen=True)
class RecordedFrame:
    index: int
    stamp_s: float
    path: Path
    true_pose: Optional[Pose2D]
    odom_yaw_rad: Optional[float] = None   # the base's odometry heading (any fixed frame)
    gyro_yaw_rad: Optional[float] = None   # the gyro's rate integrated over the recording (any fixed frame)

    def load_rgb(self) -> np.ndarray:
        bgr = cv2.imread(str(self.path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise RecordingError(f"{self.path}: cannot read the image")
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def _num(value: Optional[float]) -> str:
    return "" if value is None else repr(float(value))


class RecordingWriter:
    """Writes a recording atomically: ``append`` frames, then ``finish(summary)``."""

    def __init__(self, out_dir: str | Path, jpeg_quality: int = 95):
        self.out_dir = Path(out_dir)
        self.jpeg_quality = int(jpeg_quality)
        self._folder = AtomicFolder(self.out_dir)
        self.tmp_dir = self._folder.path
        self._folder.mkdir("frames")
        self._csv_file = open(self.tmp_dir / "frames.csv", "w", newline="", encoding="utf-8")
        self._csv = csv.writer(self._csv_file)
        self._csv.writerow(COLUMNS)
        self.count = 0
        self.metres = 0.0
        self._last_xy: Optional[tuple[float, float]] = None
        self._first_stamp: Optional[float] = None
        self._last_stamp: Optional[float] = None

    @property
    def path(self) -> Path:
        """Where files go while recording (extra artefacts may be written here before finish)."""
        return self.tmp_dir

    def append(self, frame: SensorFrame, true_pose: Optional[Pose2D] = None) -> None:
        if frame.rgb is None:
            raise RecordingError("cannot record a frame without a camera image")
        name = f"frames/{self.count:06d}.jpg"
        ok = cv2.imwrite(str(self.tmp_dir / name), cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2BGR),
                         [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if not ok:
            raise RecordingError(f"{self.tmp_dir / name}: could not write the image")
        odo = frame.odometry
        self._csv.writerow([
            self.count, repr(frame.stamp_s), name,
            _num(odo and odo.x_m), _num(odo and odo.y_m), _num(odo and odo.yaw_rad),
            _num(odo and odo.v_mps), _num(odo and odo.w_radps), _num(frame.imu_yaw_rate_radps),
            _num(true_pose and true_pose.x_m), _num(true_pose and true_pose.y_m),
            _num(true_pose and true_pose.yaw_rad),
        ])
        if true_pose is not None:
            if self._last_xy is not None:
                self.metres += math.hypot(true_pose.x_m - self._last_xy[0], true_pose.y_m - self._last_xy[1])
            self._last_xy = (true_pose.x_m, true_pose.y_m)
        if self._first_stamp is None:
            self._first_stamp = frame.stamp_s
        self._last_stamp = frame.stamp_s
        self.count += 1

    def summary(self) -> dict:
        duration = 0.0 if self._first_stamp is None else self._last_stamp - self._first_stamp
        return {"frames": self.count, "metres_driven": round(self.metres, 3), "duration_s": round(duration, 3)}

    def finish(self, extra: Optional[dict] = None) -> dict:
        """Write summary.json and move the recording into place. Returns the summary."""
        self._csv_file.close()
        summary = {**self.summary(), **(extra or {})}
        self._folder.write("summary.json", (json.dumps(summary, indent=2) + "\n").encode("utf-8"))
        self._folder.commit()
        return summary

    def abort(self) -> None:
        """Drop the partial recording (an interrupted run leaves any earlier recording untouched)."""
        if not self._csv_file.closed:
            self._csv_file.close()
        self._folder.discard()


def _opt(row: dict, key: str, source: Path, line: int) -> Optional[float]:
    text = row.get(key, "")
    if text in ("", None):
        return None
    try:
        return float(text)
    except ValueError:
        raise RecordingError(f"{source}: line {line}: column {key!r} is not a number: {text!r}") from None


def read_recording(folder: str | Path) -> list[RecordedFrame]:
    """The frames of a recording, in order; errors name the missing or malformed file."""
    folder = Path(folder)
    table = folder / "frames.csv"
    if not table.is_file():
        raise RecordingError(f"{table}: not found; is {folder} a recording made by `robot.run --mode map`?")
    frames: list[RecordedFrame] = []
    gyro: Optional[YawRateIntegrator] = YawRateIntegrator()   # None once a frame has no rate
    with open(table, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        missing = [c for c in ("index", "stamp_s", "file") if c not in (reader.fieldnames or [])]
        if missing:
            raise RecordingError(f"{table}: missing column(s) {missing}")
        for line, row in enumerate(reader, start=2):
            stamp = _opt(row, "stamp_s", table, line)
            x, y, yaw = (_opt(row, k, table, line) for k in ("true_x_m", "true_y_m", "true_yaw_rad"))
            pose = Pose2D(x, y, yaw) if None not in (x, y, yaw) else None
            path = folder / row["file"]
            if not path.is_file():
                raise RecordingError(f"{path}: listed in {table} line {line} but missing")
            rate = _opt(row, "imu_yaw_rate_radps", table, line)
            if gyro is not None and rate is not None and stamp is not None:
                try:
                    gyro.update(stamp, rate)
                except ValueError as exc:
                    raise RecordingError(f"{table}: line {line}: {exc}") from None
            else:
                gyro = None
            frames.append(RecordedFrame(index=int(row["index"]), stamp_s=float(stamp or 0.0), path=path, true_pose=pose,
                                        odom_yaw_rad=_opt(row, "odom_yaw_rad", table, line),
                                        gyro_yaw_rad=None if gyro is None else gyro.yaw_rad))
    if not frames:
        raise RecordingError(f"{table}: the recording has no frames")
    if gyro is None:   # a heading from part of the drive would not match the rest
        frames = [replace(f, gyro_yaw_rad=None) for f in frames]
    return frames


def iter_rgb(frames: list[RecordedFrame]) -> Iterator[np.ndarray]:
    for frame in frames:
        yield frame.load_rgb()

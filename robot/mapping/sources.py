"""Where mapping frames come from: a recorded drive, a video file, or a folder of images.

Each source yields :class:`MapFrame` (index in the source, timestamp, RGB image, true pose when
the simulator knew it) and knows its length, so mapping can show a progress bar. Sampling by
``every_n`` frames or by ``every_s`` seconds applies to all of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Optional

import cv2
import numpy as np

from core.cli import quiet_video_decoder
from core.hal import Pose2D
from robot.mapping.recording import read_recording

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".ppm", ".tif", ".tiff", ".webp")


class FrameSourceError(ValueError):
    """A frame source cannot be read; the message names the file."""


@dataclass(frozen=True)
class MapFrame:
    index: int                  # position in the source (video frame number, file order, recording index)
    stamp_s: float              # seconds from the start of the source
    rgb: np.ndarray             # (H, W, 3) uint8
    true_pose: Optional[Pose2D] = None
    odom_yaw_rad: Optional[float] = None   # the base's odometry heading (recordings of a drive)
    gyro_yaw_rad: Optional[float] = None   # the gyro's integrated heading (recordings of a drive)


@dataclass(frozen=True)
class Sampling:
    """Keep every ``every_n``-th frame, or one frame per ``every_s`` seconds when that is set."""

    every_n: int = 1
    every_s: Optional[float] = None
    max_width_px: int = 640     # larger frames are shrunk on reading: descriptors never need more, memory does

    def __post_init__(self) -> None:
        if self.every_n < 1:
            raise FrameSourceError(f"--every must be >= 1, got {self.every_n}")
        if self.every_s is not None and not self.every_s > 0:
            raise FrameSourceError(f"--every-s must be > 0, got {self.every_s}")

    def keep(self, position: int, stamp_s: float, last_kept_s: Optional[float]) -> bool:
        if self.every_s is not None:
            return last_kept_s is None or stamp_s - last_kept_s >= self.every_s - 1e-9
        return position % self.every_n == 0


def _shrink(rgb: np.ndarray, max_width: int) -> np.ndarray:
    h, w = rgb.shape[:2]
    if w <= max_width:
        return rgb
    return cv2.resize(rgb, (max_width, int(round(h * max_width / w))), interpolation=cv2.INTER_AREA)


def _read_image(path: Path) -> np.ndarray:
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise FrameSourceError(f"{path}: cannot read the image (not an image, or damaged)")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


class RecordingSource:
    """Frames of a drive recorded by ``robot.run --mode map`` (with true poses in simulation)."""

    def __init__(self, folder: str | Path, sampling: Sampling = Sampling()):
        self.folder = Path(folder)
        self._frames = read_recording(self.folder)
        self.sampling = sampling
        self.description = f"recording {self.folder}"

    def __len__(self) -> int:
        return len(self._frames)

    def __iter__(self) -> Iterator[MapFrame]:
        last = None
        for pos, f in enumerate(self._frames):
            if self.sampling.keep(pos, f.stamp_s, last):
                last = f.stamp_s
                yield MapFrame(f.index, f.stamp_s, _shrink(f.load_rgb(), self.sampling.max_width_px), f.true_pose,
                               f.odom_yaw_rad, f.gyro_yaw_rad)


class ImageFolderSource:
    """Image files of a folder in name order; timestamps count one second per file."""

    def __init__(self, folder: str | Path, sampling: Sampling = Sampling(), seconds_per_image: float = 1.0):
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise FrameSourceError(f"{self.folder}: not a folder")
        self._files = sorted(p for p in self.folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not self._files:
            raise FrameSourceError(f"{self.folder}: no images ({', '.join(IMAGE_SUFFIXES)}) in this folder")
        self.sampling = sampling
        self.seconds_per_image = seconds_per_image
        self.description = f"images {self.folder}"

    def __len__(self) -> int:
        return len(self._files)

    def __iter__(self) -> Iterator[MapFrame]:
        last = None
        for pos, path in enumerate(self._files):
            stamp = pos * self.seconds_per_image
            if self.sampling.keep(pos, stamp, last):
                last = stamp
                yield MapFrame(pos, stamp, _shrink(_read_image(path), self.sampling.max_width_px))


class VideoSource:
    """Frames of a video file, e.g. a phone video walked along the route (as the paper did)."""

    def __init__(self, path: str | Path, sampling: Sampling = Sampling()):
        self.path = Path(path)
        if not self.path.is_file():
            raise FrameSourceError(f"{self.path}: no such video file")
        quiet_video_decoder()
        cap = cv2.VideoCapture(str(self.path))
        try:
            if not cap.isOpened():
                raise FrameSourceError(f"{self.path}: OpenCV cannot open this video (unknown container or codec)")
            fps = cap.get(cv2.CAP_PROP_FPS)
            self.fps = float(fps) if fps and math.isfinite(fps) and fps > 0 else 30.0
            self._count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        finally:
            cap.release()
        self.sampling = sampling
        self.description = f"video {self.path} ({self.fps:.1f} fps)"

    def __len__(self) -> int:
        return self._count

    def __iter__(self) -> Iterator[MapFrame]:
        quiet_video_decoder()
        cap = cv2.VideoCapture(str(self.path))
        last, pos, kept = None, 0, 0
        try:
            while True:
                ok, bgr = cap.read()
                if not ok:
                    break
                stamp = pos / self.fps
                if self.sampling.keep(pos, stamp, last):
                    last = stamp
                    kept += 1
                    yield MapFrame(pos, stamp, _shrink(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), self.sampling.max_width_px))
                pos += 1
        finally:
            cap.release()
        if pos == 0:
            raise FrameSourceError(f"{self.path}: the video has no readable frames")

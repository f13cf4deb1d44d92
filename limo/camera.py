"""Camera frames from OpenCV ``VideoCapture``: a device index, a stream URL, or a video file to replay.

Frames come out as (H, W, 3) uint8 **RGB** (OpenCV delivers BGR) with ``stamp_s`` taken on the
same monotonic clock as the serial backend's :class:`~core.hal.SensorFrame`, at the moment the
frame was grabbed.

Two ways to use it:

* ``read()`` blocks for the next frame (replaying a file frame by frame, offline tools);
* ``start()`` runs a grabber thread and ``latest()`` returns the newest frame without waiting,
  which is what a control loop wants: a live camera delivers at its own rate (30 fps on the
  Limo's Dabai) and stale buffered frames must not pile up. When replaying a file in the
  background, frames are paced at the file's frame rate (``realtime=True``) so replay looks
  like a live camera.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Union

import numpy as np

from core.cli import quiet_video_decoder
from core.hal import HalError


class CameraError(HalError):
    """The camera source cannot be opened or has failed; the message names the source."""


@dataclass(frozen=True)
class CameraFrame:
    """One RGB image and the monotonic time it was grabbed."""

    stamp_s: float
    rgb: np.ndarray
    index: int


def _import_cv2():
    try:
        import cv2  # noqa: PLC0415 - imported lazily so the HAL imports without OpenCV
    except ImportError as exc:  # pragma: no cover - opencv is a project dependency
        raise CameraError("OpenCV is needed for the camera: pip install opencv-python-headless") from exc
    return cv2


class CameraSource:
    """Frames from ``cv2.VideoCapture``.

    ``source``: an int (device index, ``0`` is ``/dev/video0``), a digit string (same), a URL
    (``rtsp://...``, ``http://...``), or a path to a video file. ``width``/``height`` request a
    capture size from a device (ignored by files). ``realtime`` paces background replay of a file
    at its frame rate; ``loop`` restarts a file at its end instead of ending.
    """

    def __init__(self, source: Union[int, str, Path], *, width: Optional[int] = None,
                 height: Optional[int] = None, realtime: bool = True, loop: bool = False,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if isinstance(source, str) and source.strip().isdigit():
            source = int(source)
        self.source = source
        self.width = width
        self.height = height
        self.realtime = realtime
        self.loop = loop
        self._clock = clock
        self._cap = None
        self._is_file = False
        self._fps = 0.0
        self._index = 0
        self._lock = threading.Lock()
        self._latest: Optional[CameraFrame] = None
        self._error: Optional[str] = None
        self._ended = False
        self._thread: Optional[threading.Thread] = None
        self._stop = threading.Event()
        self._grabbed = threading.Event()    # set on the first frame, an error or the end

    @property
    def is_open(self) -> bool:
        return self._cap is not None

    @property
    def ended(self) -> bool:
        """True once a replayed file has no more frames (never for a live source)."""
        return self._ended

    def open(self) -> None:
        """Open the capture; raises :class:`CameraError` naming the source and what to check."""
        if self._cap is not None:
            raise CameraError(f"camera {self.source!r} is already open")
        cv2 = _import_cv2()
        source = self.source
        if isinstance(source, Path):
            source = str(source)
        self._is_file = isinstance(source, str) and "://" not in source
        if self._is_file and not Path(source).is_file():
            raise CameraError(f"camera source {source!r}: no such video file")
        quiet_video_decoder()
        cap = cv2.VideoCapture(source)
        if not cap.isOpened():
            cap.release()
            if isinstance(source, int):
                hint = (f"is a camera plugged in as /dev/video{source}? Is it used by another program? "
                        "Is the user in the 'video' group? (the Limo's Dabai colour stream is often not "
                        "index 0: try `v4l2-ctl --list-devices`)")
            elif self._is_file:
                hint = "OpenCV cannot decode it (try an MJPG .avi or an H.264 .mp4)"
            else:
                hint = "check the URL and that the stream is running"
            raise CameraError(f"cannot open camera source {source!r}: {hint}")
        if self.width:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.width)
        if self.height:
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height)
        fps = cap.get(cv2.CAP_PROP_FPS)
        self._fps = float(fps) if fps and fps > 0 else 0.0
        self._cap = cap
        self._index = 0
        self._ended = False

    @property
    def fps(self) -> float:
        """The frame rate OpenCV reports (0.0 when unknown)."""
        return self._fps

    def read(self) -> Optional[CameraFrame]:
        """Block for the next frame; ``None`` at the end of a file. Raises if a live source fails."""
        if self._cap is None:
            raise CameraError(f"camera {self.source!r} is not open: call open() first")
        cv2 = _import_cv2()
        ok, bgr = self._cap.read()
        if not ok and self._is_file and self.loop and self._index > 0:
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
            ok, bgr = self._cap.read()
        stamp = self._clock()
        if not ok or bgr is None:
            if self._is_file:
                self._ended = True
                return None
            raise CameraError(f"camera {self.source!r} stopped delivering frames (unplugged?)")
        if bgr.ndim == 2:  # some devices deliver grey
            rgb = cv2.cvtColor(bgr, cv2.COLOR_GRAY2RGB)
        else:
            rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        frame = CameraFrame(stamp_s=stamp, rgb=rgb, index=self._index)
        self._index += 1
        return frame

    # -- background grabbing ---------------------------------------------------------------

    def start(self) -> None:
        """Grab frames in a background thread; read them with :meth:`latest`. Opens if needed."""
        if self._cap is None:
            self.open()
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._grab_loop, name="camera-grabber", daemon=True)
        self._thread.start()

    def _grab_loop(self) -> None:
        period = 1.0 / self._fps if (self._is_file and self.realtime and self._fps > 0) else 0.0
        next_due = time.monotonic()
        while not self._stop.is_set():
            try:
                frame = self.read()
            except CameraError as exc:
                with self._lock:
                    self._error = str(exc)
                self._grabbed.set()
                return
            if frame is None:
                self._grabbed.set()
                return
            with self._lock:
                self._latest = frame
            self._grabbed.set()
            if period:
                next_due += period
                self._stop.wait(max(0.0, next_due - time.monotonic()))

    def wait_for_frame(self, timeout_s: float) -> CameraFrame:
        """Block until the background grabber has a frame (after :meth:`start`); raises
        :class:`CameraError` naming the camera when none comes within ``timeout_s``."""
        self._grabbed.wait(timeout_s)
        frame = self.latest()
        if frame is None:
            raise CameraError(f"camera {self.source!r} delivered no frame within {timeout_s:g} s"
                              + (" (the video has no frames)" if self._grabbed.is_set() else ""))
        return frame

    def latest(self) -> Optional[CameraFrame]:
        """The newest frame grabbed in the background (None before the first).

        Raises :class:`CameraError` when the background grabber failed (a live camera vanished).
        """
        with self._lock:
            if self._error is not None:
                raise CameraError(self._error)
            return self._latest

    def close(self) -> None:
        """Stop the grabber and release the capture. Safe to call more than once."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    def __enter__(self) -> "CameraSource":
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

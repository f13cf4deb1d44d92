"""The real Limo base over its serial port: a :class:`~core.hal.RobotBase` backend on pyserial.

``LimoSerialBase(LimoSerialConfig(port=...))`` opens any pyserial URL (``/dev/ttyTHS1``, a pty path
from :mod:`limo.emulator`, ``loop://``), hands the base to serial control (0x421), then a
background *writer* thread sends the motion command (0x111) at ``command_rate_hz`` whether it
changed or not (the firmware's own command timeout is undocumented, so silence must never be what
keeps a robot moving), and a background *reader* thread parses feedback into odometry, gyro yaw
rate, battery voltage and error bits. A :class:`~limo.state_estimate.StateEstimator` fuses wheel
and gyro yaw rates into the heading the rotate-in-place behaviour needs.

Safety rules, all enforced here and not by the caller:

* no feedback for ``feedback_timeout_s`` (0.5 s): ``SensorFrame.fault`` says so and the writer
  sends zero velocity; when feedback returns the fault clears, but zero is held until the
  controller applies a new command (a stale command is never resumed on its own);
* ``close()`` (also from ``with``, on an exception or Ctrl-C, and at interpreter exit) stops
  the writer, sends ``stop_frames`` zero-velocity frames and flushes them before the port closes.
"""

from __future__ import annotations

import atexit
import errno
import math
import threading
import time
from dataclasses import dataclass
from typing import Callable, Optional

import serial

from core.hal import STOP, HalError, Odometry, RobotBase, SensorFrame, VelocityCommand
from limo.camera import CameraError, CameraSource
from limo.config import LimoSerialConfig
from limo.protocol import (
    ERROR_BITS_SEVERE,
    ControlModeCommand,
    FrameParser,
    ImuAccel,
    ImuEuler,
    ImuGyro,
    MotionCommand,
    MotionState,
    SystemState,
    WheelOdometry,
    describe_error_bits,
    encode_enable,
    encode_motion,
)
from limo.state_estimate import PlanarEstimate, StateEstimator

PORT_HINT = ("the Limo's Jetson uses /dev/ttyTHS1 (some Orin units /dev/ttyTHS0); a USB-serial "
             "adapter shows up as /dev/ttyUSB0; list ports with `python -m serial.tools.list_ports`")


@dataclass(frozen=True)
class LinkStats:
    """Counters of the serial link since connect."""

    frames_sent: int
    frames_received: int
    feedback_frames: int
    bytes_skipped: int
    bad_checksums: int
    write_errors: int
    #: seconds since the last feedback frame (None before the first)
    feedback_age_s: Optional[float]
    #: candidate frames with a good checksum rejected for an unknown id or an implausible value
    #: (limo.protocol.FrameParser), and why the last one was
    unknown_ids: int = 0
    implausible: int = 0
    last_rejected: str = ""

    @property
    def rejected(self) -> int:
        """Candidate frames thrown away: bad checksum, unknown id, implausible value."""
        return self.bad_checksums + self.unknown_ids + self.implausible


@dataclass(frozen=True)
class LimoFeedback:
    """The latest decoded message of each feedback kind (None until one arrived)."""

    system: Optional[SystemState] = None
    motion: Optional[MotionState] = None
    odometry: Optional[WheelOdometry] = None
    accel: Optional[ImuAccel] = None
    gyro: Optional[ImuGyro] = None
    euler: Optional[ImuEuler] = None


class PortError(HalError):
    """The serial port cannot be opened (missing, no permission, in use, not a serial device):
    an argument that cannot work, where a base that does not answer is a failed run."""


def describe_open_error(port: str, baud: int, exc: BaseException) -> str:
    """A message for a port that would not open, naming the port and what to check."""
    code = getattr(exc, "errno", None)
    if code == errno.ENOENT:
        return f"serial port {port!r} does not exist: check the cable and the port name ({PORT_HINT})"
    if code in (errno.EACCES, errno.EPERM):
        return (f"permission denied opening serial port {port!r}: add your user to the dialout group "
                f"(`sudo usermod -aG dialout $USER`, then log out and in) and make sure no serial "
                f"console (nvgetty on the Jetson) holds the port")
    if code in (errno.EBUSY, errno.EAGAIN, errno.EWOULDBLOCK):
        return (f"serial port {port!r} is in use by another program (a ROS limo_base node? another "
                f"controller?): stop it first")
    if isinstance(exc, ValueError):
        return f"cannot open serial port {port!r} at {baud} baud: {exc}"
    return f"cannot open serial port {port!r} at {baud} baud: {exc} (is it a serial device? {PORT_HINT})"


def open_port(port: str, baud: int, read_timeout_s: float = 0.02) -> serial.SerialBase:
    """Open ``port`` (a path or pyserial URL) 8N1 raw, exclusively; errors become :class:`PortError`."""
    try:
        return serial.serial_for_url(port, baudrate=baud, bytesize=serial.EIGHTBITS,
                                     parity=serial.PARITY_NONE, stopbits=serial.STOPBITS_ONE,
                                     timeout=read_timeout_s, write_timeout=0.2, exclusive=True)
    except (serial.SerialException, OSError, ValueError) as exc:
        raise PortError(describe_open_error(port, baud, exc)) from exc


class LimoSerialBase(RobotBase):
    """The Limo base over serial. See the module docstring for the threads and safety rules.

    ``camera``: an optional :class:`CameraSource` (overrides ``config.camera``); ``clock``: the
    monotonic clock used for stamps and the feedback watchdog.
    """

    def __init__(self, config: LimoSerialConfig = LimoSerialConfig(), camera: Optional[CameraSource] = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.config = config
        self.limits = config.limits
        self.control_period_s = config.control_period_s
        self._camera = camera
        if self._camera is None and config.camera is not None:
            self._camera = CameraSource(config.camera, width=config.camera_width, height=config.camera_height)
        self._clock = clock
        self._serial: Optional[serial.SerialBase] = None
        self._lock = threading.Lock()
        self._write_lock = threading.Lock()
        self._wake = threading.Event()
        self._threads_stop = threading.Event()
        self._reader: Optional[threading.Thread] = None
        self._writer: Optional[threading.Thread] = None
        self._reset_state()

    def _reset_state(self) -> None:
        self._parser = FrameParser()
        self._estimator = StateEstimator(self.config.estimate)
        self._command = STOP
        self._hold_zero = False
        self._link_fault: Optional[str] = None
        self._port_error: Optional[str] = None
        self._send_enable = False
        self._connected_s = 0.0
        self._last_feedback_s: Optional[float] = None
        self._feedback = LimoFeedback()
        self._wheel_raw: Optional[tuple] = None
        self._wheel_units = [0, 0]
        self._error_bits = 0
        self._counts = dict(sent=0, received=0, feedback=0, write_errors=0)
        self._next_tick_s = 0.0

    # -- life cycle ------------------------------------------------------------------------

    @property
    def connected(self) -> bool:
        return self._serial is not None

    def connect(self) -> None:
        """Open the port, enable serial control, start the threads (and the camera), wait for feedback."""
        if self._serial is not None:
            raise HalError(f"LimoSerialBase on {self.config.port!r} is already connected")
        port = open_port(self.config.port, self.config.baud)
        try:
            port.reset_input_buffer()  # stale bytes from before we opened would look like feedback
        except (serial.SerialException, OSError):
            pass
        self._reset_state()
        self._serial = port
        self._connected_s = self._clock()
        self._next_tick_s = self._connected_s
        self._threads_stop.clear()
        try:
            self._write(encode_enable())
            self._reader = threading.Thread(target=self._read_loop, name="limo-serial-reader", daemon=True)
            self._writer = threading.Thread(target=self._write_loop, name="limo-serial-writer", daemon=True)
            self._reader.start()
            self._writer.start()
            if self._camera is not None:
                self._camera.start()
                # navigation needs an image in the very first frame: a camera that is still
                # opening must not look like a camera that delivers nothing
                self._camera.wait_for_frame(self.config.camera_timeout_s)
            self._wait_for_feedback()
        except BaseException:
            self.close()
            raise
        atexit.register(self.close)

    def _wait_for_feedback(self) -> None:
        timeout = self.config.connect_timeout_s
        if timeout <= 0:
            return
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self._lock:
                # the first system state too (sent at a lower rate): battery and mode are known
                # when connect() returns
                if self._last_feedback_s is not None and self._feedback.system is not None:
                    return
                if self._port_error:
                    raise HalError(self._port_error)
            time.sleep(0.005)
        stats = self._parser.stats
        why = ("frames arrived but no system state (0x211): is this a Limo base?" if self._last_feedback_s is not None
               else "bytes arrived but none formed a valid frame: is the baud rate 460800?"
               if stats.bytes_skipped or stats.rejected else
               "nothing arrived: is the base switched on, and is this its port?")
        raise HalError(f"no feedback from the Limo base on {self.config.port!r} within {timeout} s: {why} "
                       f"({PORT_HINT})")

    def close(self) -> None:
        """Stop the writer, send zero velocity, release port and camera. Safe to call more than once."""
        atexit.unregister(self.close)
        port = self._serial
        if port is not None:
            with self._lock:
                self._command = STOP
                self._hold_zero = True
            self._threads_stop.set()
            self._wake.set()
            if self._writer is not None:
                self._writer.join(timeout=1.0)
            stop_frame = encode_motion(0.0, 0.0)
            for _ in range(self.config.stop_frames):
                self._write(stop_frame)
            try:
                port.flush()
            except Exception:  # noqa: BLE001 - termios.error when the device vanished; close anyway
                pass
            if self._reader is not None:
                self._reader.join(timeout=1.0)
            try:
                port.close()
            except Exception:  # noqa: BLE001 - releasing a vanished device must not fail close()
                pass
            self._serial = None
            self._reader = self._writer = None
        if self._camera is not None:
            self._camera.close()

    # -- control ---------------------------------------------------------------------------

    def apply(self, cmd: VelocityCommand) -> VelocityCommand:
        """Set the command the writer streams; returns what is sent (zero while the link is faulted)."""
        self._require_connected()
        clipped = self.limits.clip(cmd)
        with self._lock:
            if self._link_fault is not None or self._port_error is not None:
                return STOP
            self._command = clipped
            self._hold_zero = False
        self._wake.set()  # send it now rather than up to one period later
        return clipped

    @property
    def commanded(self) -> VelocityCommand:
        """The velocity the writer is sending now (after limits, faults and holds)."""
        with self._lock:
            return STOP if self._hold_zero else self._command

    def tick(self) -> None:
        """Sleep until the next control period on the monotonic clock (no catching up when late)."""
        self._require_connected()
        now = self._clock()
        self._next_tick_s += self.control_period_s
        if self._next_tick_s <= now:
            self._next_tick_s = now
            return
        time.sleep(self._next_tick_s - now)

    def read(self) -> SensorFrame:
        """The latest feedback as a :class:`SensorFrame` (non-blocking)."""
        self._require_connected()
        now = self._clock()
        rgb = None
        camera_fault = None
        if self._camera is not None:
            try:
                frame = self._camera.latest()
                rgb = frame.rgb if frame is not None else None
            except CameraError as exc:
                camera_fault = str(exc)
        with self._lock:
            fb = self._feedback
            odometry = self._odometry_locked()
            faults = [f for f in (self._port_error, self._link_fault, camera_fault) if f]
            error_bits = self._error_bits
            if error_bits & ERROR_BITS_SEVERE:
                faults.append("base reports errors: " + ", ".join(describe_error_bits(error_bits & ERROR_BITS_SEVERE)))
            return SensorFrame(
                stamp_s=now, rgb=rgb, odometry=odometry,
                imu_yaw_rate_radps=(self.config.gyro_yaw_sign * math.radians(fb.gyro.z_degps)) if fb.gyro else None,
                battery_v=fb.system.battery_v if fb.system else None,
                error_bits=error_bits, fault="; ".join(faults) if faults else None)

    def _odometry_locked(self) -> Optional[Odometry]:
        if self._feedback.odometry is None:
            return None
        est = self._estimator.estimate()
        unit = self.config.odometry_unit_m
        return Odometry(x_m=est.x_m, y_m=est.y_m, yaw_rad=est.yaw_rad, v_mps=est.v_mps, w_radps=est.w_radps,
                        left_m=self._wheel_units[0] * unit, right_m=self._wheel_units[1] * unit)

    def estimate(self) -> PlanarEstimate:
        """The fused planar estimate (odometry + gyro), in the frame where the base connected."""
        with self._lock:
            return self._estimator.estimate()

    def feedback(self) -> LimoFeedback:
        """The latest raw message of each feedback kind (for checklists and debugging)."""
        with self._lock:
            return self._feedback

    def link_stats(self) -> LinkStats:
        with self._lock:
            p, c = self._parser.stats, self._counts
            age = None if self._last_feedback_s is None else self._clock() - self._last_feedback_s
            return LinkStats(c["sent"], c["received"], c["feedback"], p.bytes_skipped, p.bad_checksums,
                             c["write_errors"], age, p.unknown_ids, p.implausible, p.last_rejected)

    def _require_connected(self) -> None:
        if self._serial is None:
            raise HalError(f"LimoSerialBase on {self.config.port!r} is not connected: call connect() "
                           f"or use it in a with block")

    # -- threads ---------------------------------------------------------------------------

    def _write(self, frame: bytes) -> None:
        port = self._serial
        if port is None:
            return
        try:
            with self._write_lock:
                port.write(frame)
            with self._lock:
                self._counts["sent"] += 1
        except (serial.SerialException, OSError) as exc:
            with self._lock:
                self._counts["write_errors"] += 1
                if self._port_error is None:
                    self._port_error = f"writing to serial port {self.config.port!r} failed: {exc}"

    def _write_loop(self) -> None:
        period = 1.0 / self.config.command_rate_hz
        next_due = time.monotonic()
        while not self._threads_stop.is_set():
            woken = self._wake.wait(max(0.0, next_due - time.monotonic()))
            self._wake.clear()
            if self._threads_stop.is_set():
                return
            now = self._clock()
            with self._lock:
                self._check_feedback_locked(now)
                send_enable, self._send_enable = self._send_enable, False
                cmd = STOP if (self._hold_zero or self._link_fault or self._port_error) else self._command
            if send_enable:
                self._write(encode_enable())
            self._write(encode_motion(cmd.v_mps, cmd.w_radps))
            sent_s = time.monotonic()
            # an early send (apply woke us) restarts the period; a late one does not burst to catch up
            next_due = sent_s + period if woken else max(next_due + period, sent_s)

    def _check_feedback_locked(self, now: float) -> None:
        since = self._last_feedback_s if self._last_feedback_s is not None else self._connected_s
        silent_s = now - since
        if self._link_fault is None and silent_s > self.config.feedback_timeout_s:
            self._link_fault = (f"no feedback from the Limo base on {self.config.port!r} for {silent_s:.2f} s "
                                f"(limit {self.config.feedback_timeout_s} s): commanding zero velocity until "
                                f"feedback returns and a new command is applied")
            self._hold_zero = True

    def _read_loop(self) -> None:
        port = self._serial
        while not self._threads_stop.is_set() and port is not None:
            try:
                data = port.read(max(1, port.in_waiting))
            except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
                # TypeError/AttributeError: pyserial internals after the fd vanished under us
                with self._lock:
                    if self._port_error is None:
                        self._port_error = f"reading serial port {self.config.port!r} failed: {exc}"
                        self._hold_zero = True
                return
            if not data:
                continue
            now = self._clock()
            with self._lock:
                for msg in self._parser.feed(data):
                    self._counts["received"] += 1
                    self._handle_locked(now, msg)

    def _handle_locked(self, now: float, msg: object) -> None:
        if isinstance(msg, (ControlModeCommand, MotionCommand)):
            return  # our own frames echoed back (loop://, a wired loopback): not feedback
        self._counts["feedback"] += 1
        self._last_feedback_s = now
        if self._link_fault is not None:
            self._link_fault = None
            self._send_enable = True  # the base may have rebooted meanwhile; _hold_zero stays set
        fb = self._feedback
        if isinstance(msg, WheelOdometry):
            self._feedback = LimoFeedback(fb.system, fb.motion, msg, fb.accel, fb.gyro, fb.euler)
            self._update_wheels_locked(now, msg)
        elif isinstance(msg, ImuGyro):
            self._feedback = LimoFeedback(fb.system, fb.motion, fb.odometry, fb.accel, msg, fb.euler)
            self._estimator.update_gyro(now, self.config.gyro_yaw_sign * math.radians(msg.z_degps))
        elif isinstance(msg, SystemState):
            # the checksum does not cover the id: one flipped id bit turns 0x311 into 0x211, so an
            # error bit counts only when two consecutive system frames agree on it
            self._error_bits = msg.error_bits if fb.system is None else msg.error_bits & fb.system.error_bits
            self._feedback = LimoFeedback(msg, fb.motion, fb.odometry, fb.accel, fb.gyro, fb.euler)
        elif isinstance(msg, MotionState):
            self._feedback = LimoFeedback(fb.system, msg, fb.odometry, fb.accel, fb.gyro, fb.euler)
        elif isinstance(msg, ImuAccel):
            self._feedback = LimoFeedback(fb.system, fb.motion, fb.odometry, msg, fb.gyro, fb.euler)
        elif isinstance(msg, ImuEuler):
            self._feedback = LimoFeedback(fb.system, fb.motion, fb.odometry, fb.accel, fb.gyro, msg)

    def _update_wheels_locked(self, now: float, msg: WheelOdometry) -> None:
        raw = (msg.left_mm, msg.right_mm)
        unit = self.config.odometry_unit_m
        if self._wheel_raw is not None:
            # int32 counters wrap; the difference modulo 2**32 is the true step
            steps = [((raw[i] - self._wheel_raw[i] + 2 ** 31) % 2 ** 32) - 2 ** 31 for i in range(2)]
            # a step no wheel can make in one frame is a counter reset or a corrupted id (0x211 read
            # as 0x311): re-reference instead of jumping, as the estimator does
            if max(abs(steps[0]), abs(steps[1])) * unit <= self.config.estimate.max_wheel_step_m:
                self._wheel_units[0] += steps[0]
                self._wheel_units[1] += steps[1]
        self._wheel_raw = raw
        self._estimator.update_wheels(now, self._wheel_units[0] * unit, self._wheel_units[1] * unit)

"""An emulated Limo base on a pseudo-terminal: a real serial device for pyserial, no hardware.

The emulator plays the base's firmware: it opens a pty pair, keeps the master side, and offers
the slave path (``/dev/pts/N``) to the host. After a control-mode frame (0x421) it applies motion
commands (0x111) to a :class:`BaseModel`; it sends feedback whether enabled or not, each message
in its own frame on its own schedule: motion state 0x221, odometry 0x311 (mm) and IMU
0x321/0x322/0x323 at ``feedback_rate_hz`` spread over the period, system state 0x211 at half of it,
and it stops by itself when no command arrived for ``command_timeout_s``, as the firmware's own
watchdog is assumed to do.

Faults for tests and demos (feedback direction, seeded): flipped bits and dropped bytes in a
fraction of outgoing frames, and a frozen link (no feedback; optionally commands ignored too).

Command line::

    python -m limo.emulator [--model kinematic] [--fault flip-bits=0.05] [--fault freeze-at=5]

prints the device path and runs until Ctrl-C (or ``--duration``). In process::

    with LimoEmulator() as emu:        # start() ... stop()
        port = emu.device_path         # give this to LimoSerialConfig(port=...)

The physics behind the wire is a small :class:`BaseModel` (``reset()``, ``step(dt_s, v_cmd_mps,
w_cmd_radps) -> BaseState``), so a PyBullet-backed Limo can replace the kinematic unicycle.
"""

from __future__ import annotations

import math
import os
import random
import select
import termios
import threading
import time
import tty
from dataclasses import dataclass, replace
from typing import List, Optional

from core.hal import Pose2D, VelocityCommand
from core.validate import check_positive, check_range
from limo.emulator.models import BaseModel, BaseState, KinematicUnicycle
from limo.protocol import (
    ControlModeCommand,
    FrameParser,
    ImuAccel,
    ImuEuler,
    ImuGyro,
    MotionCommand,
    MotionState,
    SystemState,
    WheelOdometry,
    encode,
)


class EmulatorError(RuntimeError):
    """The emulator cannot start or was given a bad option (the message names it)."""


@dataclass(frozen=True)
class EmulatorFaults:
    """Faults on the link, applied to the feedback the emulator sends (seeded).

    ``flip_bit_prob``: fraction of frames with one bit flipped; ``drop_byte_prob``: fraction of
    frames with one byte removed; ``frozen``: no feedback at all; ``frozen_drops_commands``: a
    frozen link also swallows the host's commands (the base then stops on its own timeout).
    """

    flip_bit_prob: float = 0.0
    drop_byte_prob: float = 0.0
    frozen: bool = False
    frozen_drops_commands: bool = False

    def __post_init__(self) -> None:
        for name in ("flip_bit_prob", "drop_byte_prob"):
            check_range(name, getattr(self, name), 0.0, 1.0, what="a probability", error=EmulatorError)


@dataclass(frozen=True)
class EmulatorConfig:
    """How the emulated firmware behaves."""

    feedback_rate_hz: float = 50.0
    #: without a motion command for this long the base stops (assumed firmware watchdog)
    command_timeout_s: float = 0.5
    battery_v: float = 12.2
    error_bits: int = 0
    seed: int = 0
    faults: EmulatorFaults = EmulatorFaults()
    #: the longest time one model step may cover: after a longer stall of the firmware thread the
    #: base does not jump ahead (a model that must follow wall time, like the PyBullet twin whose
    #: renders stall every thread, may allow more)
    max_step_s: float = 0.1

    def __post_init__(self) -> None:
        for name in ("max_step_s", "feedback_rate_hz", "command_timeout_s"):
            check_positive(name, getattr(self, name), error=EmulatorError)


@dataclass(frozen=True)
class EmulatorStats:
    """Counters of the emulated firmware."""

    frames_received: int
    motion_commands: int
    enable_commands: int
    feedback_frames_sent: int
    feedback_frames_lost: int
    parser_bytes_skipped: int
    parser_bad_checksums: int


class LimoEmulator:
    """The Limo firmware on a pseudo-terminal, run in a background thread.

    ``start()`` returns the slave device path; ``stop()`` ends the thread and closes the pty.
    Properties give the command the base is executing, its actual velocity and pose; fault
    methods change the link while it runs.
    """

    def __init__(self, model: Optional[BaseModel] = None, config: EmulatorConfig = EmulatorConfig()) -> None:
        self.config = config
        self._model: BaseModel = model if model is not None else KinematicUnicycle()
        self._faults = config.faults
        self._rng = random.Random(config.seed)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._master: Optional[int] = None
        self._slave: Optional[int] = None
        self._path: Optional[str] = None
        self._parser = FrameParser()
        self._state = self._model.reset()
        self._enabled = False
        self._command = VelocityCommand()
        self._last_command_s = -math.inf
        self._counts = dict(frames=0, motion=0, enable=0, sent=0, lost=0)
        self._out = bytearray()          # the rest of a frame waiting for room in the pty buffer
        self._pending: List[bytes] = []  # frames queued by _send, written one per write

    # -- life cycle -------------------------------------------------------------------------

    def start(self) -> str:
        """Open the pty pair, start the firmware thread, and return the device path."""
        if self._thread is not None:
            raise EmulatorError("emulator already started")
        try:
            master, slave = os.openpty()
        except OSError as exc:
            raise EmulatorError(f"cannot open a pseudo-terminal: {exc}") from None
        # raw mode on the slave: no echo, no line editing, no CR/LF translation of binary frames
        tty.setraw(slave, termios.TCSANOW)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self._path = os.ttyname(slave)
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="limo-emulator", daemon=True)
        self._thread.start()
        return self._path

    def stop(self) -> None:
        """Stop the thread and close the pty (the host then sees the device vanish)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        for fd in (self._master, self._slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = None

    def __enter__(self) -> "LimoEmulator":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- observation ----------------------------------------------------------------------

    @property
    def device_path(self) -> str:
        if self._path is None:
            raise EmulatorError("emulator not started: call start() first")
        return self._path

    @property
    def enabled(self) -> bool:
        """True once a control-mode frame handed the base to serial control."""
        with self._lock:
            return self._enabled

    @property
    def commanded(self) -> VelocityCommand:
        """The command the base is executing now (zero when disabled or timed out)."""
        with self._lock:
            return self._command

    @property
    def actual(self) -> VelocityCommand:
        """The base's actual body velocity."""
        with self._lock:
            return VelocityCommand(self._state.v_mps, self._state.w_radps)

    @property
    def pose(self) -> Pose2D:
        with self._lock:
            return Pose2D(self._state.x_m, self._state.y_m, self._state.yaw_rad)

    @property
    def state(self) -> BaseState:
        with self._lock:
            return self._state

    @property
    def stats(self) -> EmulatorStats:
        with self._lock:
            c, p = self._counts, self._parser.stats
            return EmulatorStats(c["frames"], c["motion"], c["enable"], c["sent"], c["lost"],
                                 p.bytes_skipped, p.bad_checksums)

    # -- faults ----------------------------------------------------------------------------

    @property
    def faults(self) -> EmulatorFaults:
        with self._lock:
            return self._faults

    def set_faults(self, faults: EmulatorFaults) -> None:
        """Replace the active faults (takes effect on the next frame)."""
        with self._lock:
            self._faults = faults

    def freeze(self, frozen: bool = True, drop_commands: bool = False) -> None:
        """Freeze (or thaw) the link: no feedback; with ``drop_commands`` the host's frames are lost too."""
        with self._lock:
            self._faults = replace(self._faults, frozen=frozen, frozen_drops_commands=drop_commands)

    # -- firmware loop ---------------------------------------------------------------------

    def _run(self) -> None:
        """Step the model at ``feedback_rate_hz``; send each feedback message on its own schedule
        (:meth:`_schedule`), one frame per write, as the firmware does: a host that reads a couple
        of frames at a time (AgileX's pylimo reads 28 bytes and parses the first frame) still sees
        every kind of message."""
        period = 1.0 / self.config.feedback_rate_hz
        last = time.monotonic()
        next_step = last + period
        schedule = self._schedule(last)
        while not self._stop.is_set():
            due = min(next_step, min(t for t, _, _ in schedule))
            try:
                readable, _, _ = select.select([self._master], [], [], max(0.0, due - time.monotonic()))
            except (OSError, ValueError):
                return
            if readable:
                self._receive()
            now = time.monotonic()
            if now >= next_step:
                self._advance(now, min(now - last, self.config.max_step_s))  # a stall must not teleport the base
                last = now
                next_step += period
                if next_step < now:  # fell behind (busy machine): do not burst to catch up
                    next_step = now + period
            for k, (t, every, kind) in enumerate(schedule):
                if now >= t:
                    self._send(kind)
                    schedule[k] = (max(t + every, now), every, kind)
            self._flush()

    def _schedule(self, start: float) -> List[tuple]:
        """(next due time, period, message kind) per feedback message: motion state, odometry and
        the three IMU messages at ``feedback_rate_hz``, spread evenly over each period with the
        motion state first; the system state at half the rate, between them. Eleven frames per
        two periods: a reader that keeps every other frame (pylimo) sees each kind in turn."""
        period = 1.0 / self.config.feedback_rate_hz
        fast = ("motion", "odometry", "accel", "gyro", "euler")
        out = [(start + period * k / len(fast), period, kind) for k, kind in enumerate(fast)]
        out.append((start + period / (2 * len(fast)), 2 * period, "system"))
        return out

    def _receive(self) -> None:
        try:
            data = os.read(self._master, 4096)
        except BlockingIOError:
            return
        except OSError:  # EIO: no process has the slave open (cannot happen while we hold it)
            return
        with self._lock:
            if self._faults.frozen and self._faults.frozen_drops_commands:
                return
            now = time.monotonic()
            for msg in self._parser.feed(data):
                self._counts["frames"] += 1
                if isinstance(msg, ControlModeCommand):
                    self._counts["enable"] += 1
                    self._enabled = msg.command_control
                    if not self._enabled:
                        self._command = VelocityCommand()
                elif isinstance(msg, MotionCommand):
                    self._counts["motion"] += 1
                    if self._enabled:
                        self._command = VelocityCommand(msg.linear_mps, msg.angular_radps)
                        self._last_command_s = now

    def _advance(self, now: float, dt_s: float) -> None:
        with self._lock:
            if now - self._last_command_s > self.config.command_timeout_s:
                self._command = VelocityCommand()
            cmd = self._command
        state = self._model.step(dt_s, cmd.v_mps, cmd.w_radps)
        with self._lock:
            self._state = state

    def _send(self, kind: str) -> None:
        """Queue one feedback frame of ``kind`` from the current state (faults applied)."""
        with self._lock:
            faults, s = self._faults, self._state
            if faults.frozen:
                return
            if kind == "system":
                msg = SystemState(vehicle_state=0, control_mode=1 if self._enabled else 0,
                                  battery_v=self.config.battery_v, error_bits=self.config.error_bits,
                                  motion_mode=0)
            elif kind == "motion":
                msg = MotionState(s.v_mps, s.w_radps, 0.0, 0.0)
            elif kind == "odometry":
                msg = WheelOdometry(int(round(s.left_m * 1000)), int(round(s.right_m * 1000)))
            elif kind == "accel":
                msg = ImuAccel(s.accel_mps2, s.v_mps * s.w_radps, 9.81)
            elif kind == "gyro":
                msg = ImuGyro(0.0, 0.0, math.degrees(s.w_radps))
            else:
                msg = ImuEuler(math.degrees(s.yaw_rad), 0.0, 0.0)
            frame = bytearray(encode(msg))
            if faults.flip_bit_prob and self._rng.random() < faults.flip_bit_prob:
                frame[self._rng.randrange(len(frame))] ^= 1 << self._rng.randrange(8)
            if faults.drop_byte_prob and self._rng.random() < faults.drop_byte_prob:
                del frame[self._rng.randrange(len(frame))]
            self._pending.append(bytes(frame))
            self._counts["sent"] += 1

    def _flush(self) -> None:
        """Write the queued frames, each with its own write (as a UART sends them one by one)."""
        while self._pending or self._out:
            if not self._out:
                self._out += self._pending.pop(0)
            try:
                written = os.write(self._master, bytes(self._out))
            except BlockingIOError:
                written = 0
            except OSError:
                return
            del self._out[:written]
            if self._out:                       # the pty buffer is full: the host is not reading
                break
        # a host that does not read would make this grow forever; a UART would overrun instead
        if len(self._pending) > 300:
            with self._lock:
                self._counts["lost"] += len(self._pending)
            self._pending.clear()
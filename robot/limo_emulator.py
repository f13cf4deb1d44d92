"""An emulated Limo base on a pseudo-terminal: a real serial device for pyserial, no hardware.

The emulator plays the base's firmware: it opens a pty pair, keeps the master side, and offers
the slave path (``/dev/pts/N``) to the host. After a control-mode frame (0x421) it applies motion
commands (0x111) to a :class:`BaseModel`; it sends feedback at ``feedback_rate_hz`` (system state
0x211, motion state 0x221, odometry 0x311 in mm, IMU 0x321/0x322/0x323) whether enabled or not,
and it stops by itself when no command arrived for ``command_timeout_s``, as the firmware's own
watchdog is assumed to do.

Faults for tests and demos (feedback direction, seeded): flipped bits and dropped bytes in a
fraction of outgoing frames, and a frozen link (no feedback; optionally commands ignored too).

Command line::

    python -m robot.limo_emulator [--model kinematic] [--fault flip-bits=0.05] [--fault freeze-at=5]

prints the device path and runs until Ctrl-C (or ``--duration``). In process::

    with LimoEmulator() as emu:        # start() ... stop()
        port = emu.device_path         # give this to LimoSerialConfig(port=...)

The physics behind the wire is a small :class:`BaseModel` (``reset()``, ``step(dt_s, v_cmd_mps,
w_cmd_radps) -> BaseState``), so a PyBullet-backed Limo can replace the kinematic unicycle.
"""

from __future__ import annotations

import argparse
import math
import os
import random
import select
import sys
import termios
import threading
import time
import tty
from dataclasses import dataclass, replace
from typing import Callable, Dict, List, Optional, Protocol

from robot.camera_source import CameraSource
from robot.hal import HalError, Pose2D, VelocityCommand
from robot.limo_protocol import (ControlModeCommand, FrameParser, ImuAccel, ImuEuler, ImuGyro,
                                 MotionCommand, MotionState, SystemState, WheelOdometry, encode)
from robot.limo_serial import LimoSerialBase, LimoSerialConfig


class EmulatorError(RuntimeError):
    """The emulator cannot start or was given a bad option (the message names it)."""


# ---------------------------------------------------------------------------------- models


@dataclass(frozen=True)
class BaseState:
    """What a model reports after a step: pose, body velocity, cumulative wheel travel, accel."""

    x_m: float = 0.0
    y_m: float = 0.0
    yaw_rad: float = 0.0
    v_mps: float = 0.0
    w_radps: float = 0.0
    left_m: float = 0.0
    right_m: float = 0.0
    accel_mps2: float = 0.0


class BaseModel(Protocol):
    """The physics behind the emulated firmware (kinematic here; PyBullet can implement it too)."""

    def reset(self) -> BaseState:
        """Back to the origin at rest; returns that state."""

    def step(self, dt_s: float, v_cmd_mps: float, w_cmd_radps: float) -> BaseState:
        """Advance ``dt_s`` seconds under the commanded body velocity; return the new state."""


@dataclass(frozen=True)
class KinematicModelConfig:
    """A unicycle with acceleration and speed limits (AgileX navigation values by default)."""

    max_accel_mps2: float = 2.5
    max_yaw_accel_radps2: float = 3.2
    max_v_mps: float = 1.0
    max_w_radps: float = 2.5
    #: wheel separation used to turn (v, w) into left/right wheel travel (driver value)
    track_m: float = 0.172


class KinematicUnicycle:
    """Unicycle kinematics: velocity slews toward the command at the accel limits, then integrates."""

    def __init__(self, config: KinematicModelConfig = KinematicModelConfig()) -> None:
        self.config = config
        self._state = BaseState()

    def reset(self) -> BaseState:
        self._state = BaseState()
        return self._state

    @staticmethod
    def _slew(current: float, target: float, max_rate: float, dt: float) -> float:
        step = max_rate * dt
        return current + min(max(target - current, -step), step)

    def step(self, dt_s: float, v_cmd_mps: float, w_cmd_radps: float) -> BaseState:
        c, s = self.config, self._state
        if dt_s <= 0:
            return s
        v_target = min(max(v_cmd_mps, -c.max_v_mps), c.max_v_mps)
        w_target = min(max(w_cmd_radps, -c.max_w_radps), c.max_w_radps)
        v = self._slew(s.v_mps, v_target, c.max_accel_mps2, dt_s)
        w = self._slew(s.w_radps, w_target, c.max_yaw_accel_radps2, dt_s)
        # integrate with the mean velocities over the step (exact for constant acceleration in v)
        v_mid, w_mid = 0.5 * (s.v_mps + v), 0.5 * (s.w_radps + w)
        yaw_mid = s.yaw_rad + 0.5 * w_mid * dt_s
        yaw = math.atan2(math.sin(s.yaw_rad + w_mid * dt_s), math.cos(s.yaw_rad + w_mid * dt_s))
        half_track = 0.5 * c.track_m
        self._state = BaseState(
            x_m=s.x_m + v_mid * math.cos(yaw_mid) * dt_s,
            y_m=s.y_m + v_mid * math.sin(yaw_mid) * dt_s,
            yaw_rad=yaw, v_mps=v, w_radps=w,
            left_m=s.left_m + (v_mid - w_mid * half_track) * dt_s,
            right_m=s.right_m + (v_mid + w_mid * half_track) * dt_s,
            accel_mps2=(v - s.v_mps) / dt_s)
        return self._state


MODELS: Dict[str, Callable[[], BaseModel]] = {"kinematic": KinematicUnicycle}


# ---------------------------------------------------------------------------------- faults


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
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise EmulatorError(f"{name} must be a probability in [0, 1], got {value!r}")


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
        if not (math.isfinite(self.max_step_s) and self.max_step_s > 0):
            raise EmulatorError(f"max_step_s must be a positive number of seconds, got {self.max_step_s!r}")
        if not self.feedback_rate_hz > 0:
            raise EmulatorError(f"feedback_rate_hz must be positive, got {self.feedback_rate_hz!r}")
        if not self.command_timeout_s > 0:
            raise EmulatorError(f"command_timeout_s must be positive, got {self.command_timeout_s!r}")


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


# ---------------------------------------------------------------------------------- emulator


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
        self._out = bytearray()  # feedback waiting for room in the pty buffer

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
        period = 1.0 / self.config.feedback_rate_hz
        last = time.monotonic()
        next_feedback = last + period
        while not self._stop.is_set():
            timeout = max(0.0, next_feedback - time.monotonic())
            try:
                readable, _, _ = select.select([self._master], [], [], timeout)
            except (OSError, ValueError):
                return
            if readable:
                self._receive()
            now = time.monotonic()
            if now >= next_feedback:
                self._advance(now, min(now - last, self.config.max_step_s))  # a stall must not teleport the base
                last = now
                next_feedback += period
                if next_feedback < now:  # fell behind (busy machine): do not burst to catch up
                    next_feedback = now + period
            self._flush()

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
            faults = self._faults
            if faults.frozen:
                return
            for msg in self._feedback(state):
                frame = bytearray(encode(msg))
                if faults.flip_bit_prob and self._rng.random() < faults.flip_bit_prob:
                    frame[self._rng.randrange(len(frame))] ^= 1 << self._rng.randrange(8)
                if faults.drop_byte_prob and self._rng.random() < faults.drop_byte_prob:
                    del frame[self._rng.randrange(len(frame))]
                self._out += frame
                self._counts["sent"] += 1

    def _feedback(self, s: BaseState) -> List[object]:
        return [
            SystemState(vehicle_state=0, control_mode=1 if self._enabled else 0,
                        battery_v=self.config.battery_v, error_bits=self.config.error_bits, motion_mode=0),
            MotionState(s.v_mps, s.w_radps, 0.0, 0.0),
            WheelOdometry(int(round(s.left_m * 1000)), int(round(s.right_m * 1000))),
            ImuAccel(s.accel_mps2, s.v_mps * s.w_radps, 9.81),
            ImuGyro(0.0, 0.0, math.degrees(s.w_radps)),
            ImuEuler(math.degrees(s.yaw_rad), 0.0, 0.0),
        ]

    def _flush(self) -> None:
        if not self._out:
            return
        try:
            written = os.write(self._master, bytes(self._out))
        except BlockingIOError:
            written = 0
        except OSError:
            return
        del self._out[:written]
        # a host that does not read would make this grow forever; a UART would overrun instead
        if len(self._out) > 4096:
            with self._lock:
                self._counts["lost"] += len(self._out) // 14
            self._out.clear()


# ---------------------------------------------------------------------------------- HAL wiring


class EmulatedSerialLimo(LimoSerialBase):
    """The serial backend wired to its own in-process emulator: every command crosses a real
    pseudo-terminal as bytes. ``connect()`` starts the emulator and points the backend at it;
    ``close()`` stops the base, closes the port, then stops the emulator. ``config.port`` is
    ignored. Useful for the HAL conformance test and for driving the stack without hardware.
    """

    def __init__(self, config: LimoSerialConfig = LimoSerialConfig(), camera: Optional[CameraSource] = None,
                 model: Optional[BaseModel] = None, emulator_config: EmulatorConfig = EmulatorConfig()) -> None:
        super().__init__(config, camera=camera)
        self._model_for_emulator = model
        self._emulator_config = emulator_config
        self.emulator: Optional[LimoEmulator] = None

    def connect(self) -> None:
        if self.emulator is not None:
            raise HalError("EmulatedSerialLimo is already connected")
        self.emulator = LimoEmulator(self._model_for_emulator, self._emulator_config)
        try:
            self.config = replace(self.config, port=self.emulator.start())
            super().connect()
        except BaseException:
            if self.emulator is not None:  # super().connect() may have closed it already
                self.emulator.stop()
                self.emulator = None
            raise

    def close(self) -> None:
        try:
            super().close()
        finally:
            if self.emulator is not None:
                self.emulator.stop()
                self.emulator = None


# ---------------------------------------------------------------------------------- CLI


def parse_fault(text: str) -> Dict[str, float]:
    """Parse one ``--fault`` value: ``flip-bits=P``, ``drop-bytes=P``, ``freeze-at=S``, ``freeze``."""
    name, _, value = text.partition("=")
    known = ("flip-bits", "drop-bytes", "freeze-at", "freeze")
    if name not in known:
        raise EmulatorError(f"--fault {text!r}: unknown fault {name!r} (known: {', '.join(known)})")
    if name == "freeze":
        if value:
            raise EmulatorError(f"--fault {text!r}: 'freeze' takes no value (use freeze-at=SECONDS)")
        return {"freeze-at": 0.0}
    try:
        number = float(value)
    except ValueError:
        raise EmulatorError(f"--fault {text!r}: expected {name}=NUMBER, got {value!r}") from None
    if name in ("flip-bits", "drop-bytes") and not 0.0 <= number <= 1.0:
        raise EmulatorError(f"--fault {text!r}: {name} is a probability per frame in [0, 1]")
    if name == "freeze-at" and not (math.isfinite(number) and number >= 0):
        raise EmulatorError(f"--fault {text!r}: freeze-at is seconds after start, >= 0")
    return {name: number}


def _error_bits(text: str) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer such as 0x0002, got {text!r}") from None
    if not 0 <= value <= 0xFFFF:
        raise argparse.ArgumentTypeError(f"error bits are 16 bits (0..0xFFFF), got {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m robot.limo_emulator",
        description="Emulate an AgileX Limo base on a pseudo-terminal. Prints the device path; "
                    "point the serial backend at it (LimoSerialConfig(port=PATH)). Ctrl-C stops.")
    parser.add_argument("--model", choices=sorted(MODELS), default="kinematic",
                        help="physics behind the firmware (default: kinematic unicycle with accel limits)")
    parser.add_argument("--fault", action="append", default=[], metavar="SPEC",
                        help="inject a fault, repeatable: flip-bits=P (fraction of feedback frames with "
                             "one flipped bit), drop-bytes=P (fraction with one byte removed), "
                             "freeze-at=S (freeze the link S seconds after start), freeze (from the start)")
    parser.add_argument("--battery-v", type=float, default=12.2, help="battery voltage to report (V)")
    parser.add_argument("--error-bits", type=_error_bits, default=0,
                        help="error bits to report in 0x211, e.g. 0x0002 (battery warning)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the fault injection")
    parser.add_argument("--duration", type=float, default=None,
                        help="stop after this many seconds (default: run until Ctrl-C)")
    parser.add_argument("--status-every", type=float, default=0.0,
                        help="print commanded/actual velocity and pose every N seconds (0: never)")
    return parser


def main(argv: Optional[List[str]] = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        specs: Dict[str, float] = {}
        for text in args.fault:
            specs.update(parse_fault(text))
        faults = EmulatorFaults(flip_bit_prob=specs.get("flip-bits", 0.0),
                                drop_byte_prob=specs.get("drop-bytes", 0.0),
                                frozen=specs.get("freeze-at") == 0.0)
        config = EmulatorConfig(battery_v=args.battery_v, error_bits=args.error_bits, seed=args.seed,
                                faults=faults)
        emulator = LimoEmulator(MODELS[args.model](), config)
        path = emulator.start()
    except EmulatorError as exc:
        print(f"limo_emulator: error: {exc}", file=sys.stderr)
        return 2
    print(path, flush=True)
    start = time.monotonic()
    freeze_at = specs.get("freeze-at")
    next_status = start + args.status_every if args.status_every > 0 else math.inf
    try:
        while args.duration is None or time.monotonic() - start < args.duration:
            time.sleep(0.05)
            now = time.monotonic()
            if freeze_at and not emulator.faults.frozen and now - start >= freeze_at:
                emulator.freeze(True)
                print("link frozen", file=sys.stderr, flush=True)
            if now >= next_status:
                next_status += args.status_every
                cmd, act, pose = emulator.commanded, emulator.actual, emulator.pose
                print(f"cmd v={cmd.v_mps:+.3f} w={cmd.w_radps:+.3f}  actual v={act.v_mps:+.3f} "
                      f"w={act.w_radps:+.3f}  pose x={pose.x_m:+.3f} y={pose.y_m:+.3f} "
                      f"yaw={pose.yaw_rad:+.3f}", file=sys.stderr, flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        emulator.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())

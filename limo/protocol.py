"""The AgileX Limo serial protocol: a codec for its 14-byte frames and a resynchronising parser.

Wire format (see ``shared/docs/limo.md``), every field big-endian::

    0x55 0x0E  id_hi id_lo  d0 d1 d2 d3 d4 d5 d6 d7  count  checksum

``checksum = (d0 + ... + d7) & 0xFF``; the count byte is sent as 0 and ignored on receipt.

Everything here is pure: messages are frozen dataclasses with units in their field names,
:func:`encode` turns any of them into bytes (host->base commands and, for the emulator,
base->host feedback), :func:`decode_frame` does the reverse, and :class:`FrameParser` turns an
arbitrary byte stream into messages. Values outside a field's range are clipped to the range,
never wrapped (a wrapped +33 m/s would become -32 m/s on the wire).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import List, Optional, Tuple, Union

FRAME_LEN = 14
HEADER = 0x55
LENGTH_BYTE = 0x0E
_SYNC = bytes((HEADER, LENGTH_BYTE))

ID_CONTROL_MODE = 0x421
ID_MOTION_COMMAND = 0x111
ID_SYSTEM_STATE = 0x211
ID_MOTION_STATE = 0x221
ID_ODOMETRY = 0x311
ID_IMU_ACCEL = 0x321
ID_IMU_GYRO = 0x322
ID_IMU_EULER = 0x323

#: Error bits of the system-state message (0x211, d4-5), as named by AgileX.
ERROR_BIT_NAMES = {
    0x0001: "battery low (error)",
    0x0002: "battery low (warning)",
    0x0004: "remote control link lost",
    0x0008: "motor driver 1",
    0x0010: "motor driver 2",
    0x0020: "motor driver 3",
    0x0040: "motor driver 4",
    0x0100: "drive status error",
}
#: Bits that mean the base cannot drive safely (the low-battery warning is not among them).
ERROR_BITS_SEVERE = 0x0001 | 0x0008 | 0x0010 | 0x0020 | 0x0040 | 0x0100

_INT16 = (-32768, 32767)
_INT32 = (-(2 ** 31), 2 ** 31 - 1)
_UINT8 = (0, 255)
_UINT16 = (0, 65535)


class ProtocolError(ValueError):
    """A frame or a value cannot be encoded or decoded; the message names the field or byte."""


# ---------------------------------------------------------------------------------- messages


@dataclass(frozen=True)
class ControlModeCommand:
    """Host->base 0x421: hand the base to serial command control (d0=1), optionally Mecanum (d2=1)."""

    command_control: bool = True
    mecanum: bool = False


@dataclass(frozen=True)
class MotionCommand:
    """Host->base 0x111. Wire order is always linear, angular, lateral, steering (each x1000 int16)."""

    linear_mps: float = 0.0
    angular_radps: float = 0.0
    lateral_mps: float = 0.0
    steering_rad: float = 0.0


@dataclass(frozen=True)
class SystemState:
    """Base->host 0x211: state, control mode, battery (0.1 V steps), error bits, motion mode."""

    vehicle_state: int = 0
    control_mode: int = 0
    battery_v: float = 0.0
    error_bits: int = 0
    #: 0 differential, 1 Ackermann, 2 Mecanum
    motion_mode: int = 0


@dataclass(frozen=True)
class MotionState:
    """Base->host 0x221: the velocity the base reports, same fields and scale as 0x111."""

    linear_mps: float = 0.0
    angular_radps: float = 0.0
    lateral_mps: float = 0.0
    steering_rad: float = 0.0


@dataclass(frozen=True)
class WheelOdometry:
    """Base->host 0x311: cumulative travel of the left and right wheels, int32.

    The unit is believed to be millimetres (AgileX's other bases use mm); the serial backend
    scales it with its ``odometry_unit_m`` setting, so a different firmware needs no code change.
    """

    left_mm: int = 0
    right_mm: int = 0


@dataclass(frozen=True)
class ImuAccel:
    """Base->host 0x321: linear acceleration, int16 / 100 m/s^2."""

    x_mps2: float = 0.0
    y_mps2: float = 0.0
    z_mps2: float = 0.0


@dataclass(frozen=True)
class ImuGyro:
    """Base->host 0x322: angular rate, int16 / 100 deg/s (z is yaw, counter-clockwise positive)."""

    x_degps: float = 0.0
    y_degps: float = 0.0
    z_degps: float = 0.0


@dataclass(frozen=True)
class ImuEuler:
    """Base->host 0x323: orientation, int16 / 100 deg, wire order yaw, pitch, roll."""

    yaw_deg: float = 0.0
    pitch_deg: float = 0.0
    roll_deg: float = 0.0


@dataclass(frozen=True)
class UnknownFrame:
    """A frame with a valid checksum but an id this codec does not decode (e.g. 0x251 actuators)."""

    msg_id: int
    payload: bytes


Message = Union[ControlModeCommand, MotionCommand, SystemState, MotionState, WheelOdometry,
                ImuAccel, ImuGyro, ImuEuler, UnknownFrame]


# ---------------------------------------------------------------------------------- encoding


def checksum(payload: bytes) -> int:
    """The frame checksum: the sum of the eight payload bytes, modulo 256."""
    return sum(payload) & 0xFF


def build_frame(msg_id: int, payload: bytes) -> bytes:
    """Wrap an 8-byte payload into a 14-byte frame (count byte 0)."""
    if len(payload) != 8:
        raise ProtocolError(f"payload must be 8 bytes, got {len(payload)}")
    if not 0 <= msg_id <= 0xFFFF:
        raise ProtocolError(f"message id must fit in 16 bits, got {msg_id:#x}")
    return bytes((HEADER, LENGTH_BYTE, msg_id >> 8, msg_id & 0xFF)) + bytes(payload) + bytes((0, checksum(payload)))


def _scaled(name: str, value: float, scale: float, bounds: Tuple[int, int]) -> int:
    """``round(value * scale)`` clipped to ``bounds``; NaN is refused (it has no clipped value)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ProtocolError(f"{name}: expected a number, got {value!r}")
    if math.isnan(value):
        raise ProtocolError(f"{name}: NaN cannot be sent")
    lo, hi = bounds
    scaled = value * scale
    if scaled <= lo:
        return lo
    if scaled >= hi:
        return hi
    return min(max(int(round(scaled)), lo), hi)


_S_4H = struct.Struct(">hhhh")
_S_3H = struct.Struct(">hhh2x")
_S_2I = struct.Struct(">ii")
_S_SYS = struct.Struct(">BBHHBx")
_S_HDR = struct.Struct(">BBH8sBB")


def _encode_four(msg: Union[MotionCommand, MotionState]) -> bytes:
    return _S_4H.pack(_scaled("linear_mps", msg.linear_mps, 1000, _INT16),
                      _scaled("angular_radps", msg.angular_radps, 1000, _INT16),
                      _scaled("lateral_mps", msg.lateral_mps, 1000, _INT16),
                      _scaled("steering_rad", msg.steering_rad, 1000, _INT16))


def _encode_three(names: Tuple[str, str, str], values: Tuple[float, float, float]) -> bytes:
    return _S_3H.pack(*(_scaled(n, v, 100, _INT16) for n, v in zip(names, values)))


def encode_payload(msg: Message) -> Tuple[int, bytes]:
    """The message id and 8-byte payload of ``msg``."""
    if isinstance(msg, ControlModeCommand):
        return ID_CONTROL_MODE, bytes((1 if msg.command_control else 0, 0, 1 if msg.mecanum else 0, 0, 0, 0, 0, 0))
    if isinstance(msg, MotionCommand):
        return ID_MOTION_COMMAND, _encode_four(msg)
    if isinstance(msg, MotionState):
        return ID_MOTION_STATE, _encode_four(msg)
    if isinstance(msg, SystemState):
        return ID_SYSTEM_STATE, _S_SYS.pack(_scaled("vehicle_state", msg.vehicle_state, 1, _UINT8),
                                            _scaled("control_mode", msg.control_mode, 1, _UINT8),
                                            _scaled("battery_v", msg.battery_v, 10, _UINT16),
                                            _scaled("error_bits", msg.error_bits, 1, _UINT16),
                                            _scaled("motion_mode", msg.motion_mode, 1, _UINT8))
    if isinstance(msg, WheelOdometry):
        return ID_ODOMETRY, _S_2I.pack(_scaled("left_mm", msg.left_mm, 1, _INT32),
                                       _scaled("right_mm", msg.right_mm, 1, _INT32))
    if isinstance(msg, ImuAccel):
        return ID_IMU_ACCEL, _encode_three(("x_mps2", "y_mps2", "z_mps2"), (msg.x_mps2, msg.y_mps2, msg.z_mps2))
    if isinstance(msg, ImuGyro):
        return ID_IMU_GYRO, _encode_three(("x_degps", "y_degps", "z_degps"), (msg.x_degps, msg.y_degps, msg.z_degps))
    if isinstance(msg, ImuEuler):
        return ID_IMU_EULER, _encode_three(("yaw_deg", "pitch_deg", "roll_deg"),
                                           (msg.yaw_deg, msg.pitch_deg, msg.roll_deg))
    if isinstance(msg, UnknownFrame):
        return msg.msg_id, bytes(msg.payload)
    raise ProtocolError(f"cannot encode {type(msg).__name__}: not a Limo protocol message")


def encode(msg: Message) -> bytes:
    """The 14-byte frame for any message of this module."""
    return build_frame(*encode_payload(msg))


def encode_enable(mecanum: bool = False) -> bytes:
    """The 0x421 frame that hands the base to serial command control."""
    return encode(ControlModeCommand(True, mecanum))


def encode_motion(linear_mps: float, angular_radps: float, lateral_mps: float = 0.0,
                  steering_rad: float = 0.0) -> bytes:
    """The 0x111 frame; values beyond +-32.767 are clipped."""
    return encode(MotionCommand(linear_mps, angular_radps, lateral_mps, steering_rad))


# ---------------------------------------------------------------------------------- decoding


def decode_payload(msg_id: int, payload: bytes) -> Message:
    """Decode an 8-byte payload by message id; unknown ids give :class:`UnknownFrame`."""
    if len(payload) != 8:
        raise ProtocolError(f"payload must be 8 bytes, got {len(payload)}")
    if msg_id == ID_CONTROL_MODE:
        return ControlModeCommand(payload[0] != 0, payload[2] == 1)
    if msg_id in (ID_MOTION_COMMAND, ID_MOTION_STATE):
        lin, ang, lat, steer = _S_4H.unpack(payload)
        cls = MotionCommand if msg_id == ID_MOTION_COMMAND else MotionState
        return cls(lin / 1000, ang / 1000, lat / 1000, steer / 1000)
    if msg_id == ID_SYSTEM_STATE:
        state, mode, battery, errors, motion_mode = _S_SYS.unpack(payload)
        return SystemState(state, mode, battery / 10, errors, motion_mode)
    if msg_id == ID_ODOMETRY:
        return WheelOdometry(*_S_2I.unpack(payload))
    if msg_id in (ID_IMU_ACCEL, ID_IMU_GYRO, ID_IMU_EULER):
        a, b, c = _S_3H.unpack(payload)  # signed: sign extension is the classic bug here
        cls3 = {ID_IMU_ACCEL: ImuAccel, ID_IMU_GYRO: ImuGyro, ID_IMU_EULER: ImuEuler}[msg_id]
        return cls3(a / 100, b / 100, c / 100)
    return UnknownFrame(msg_id, bytes(payload))


def decode_frame(frame: bytes) -> Message:
    """Decode one complete 14-byte frame; raises :class:`ProtocolError` naming what is wrong."""
    if len(frame) != FRAME_LEN:
        raise ProtocolError(f"a frame is {FRAME_LEN} bytes, got {len(frame)}")
    header, length, msg_id, payload, _count, check = _S_HDR.unpack(bytes(frame))
    if header != HEADER or length != LENGTH_BYTE:
        raise ProtocolError(f"bad frame start {header:#04x} {length:#04x}, expected 0x55 0x0e")
    if check != checksum(payload):
        raise ProtocolError(f"bad checksum {check:#04x} for id {msg_id:#05x}, expected {checksum(payload):#04x}")
    return decode_payload(msg_id, payload)


def describe_error_bits(bits: int) -> List[str]:
    """Names of the error bits set in ``bits`` (unknown bits as hex)."""
    names = [name for bit, name in ERROR_BIT_NAMES.items() if bits & bit]
    unknown = bits & ~sum(ERROR_BIT_NAMES)
    if unknown:
        names.append(f"unknown bits {unknown:#06x}")
    return names


# ---------------------------------------------------------------------------------- validity

#: every id the Limo protocol uses: host -> base commands, base -> host feedback, and the actuator
#: states AgileX's driver ignores. The checksum covers the payload only, so noise that happens to
#: hold ``55 0E`` and a matching sum is only caught by the id and by the values.
KNOWN_IDS = frozenset({ID_CONTROL_MODE, ID_MOTION_COMMAND, ID_SYSTEM_STATE, ID_MOTION_STATE, ID_ODOMETRY,
                       ID_IMU_ACCEL, ID_IMU_GYRO, ID_IMU_EULER, *range(0x251, 0x255), *range(0x261, 0x265)})

#: the largest magnitudes a Limo can report (well beyond what it does: 1 m/s, a few rad/s, 12 V)
MAX_SPEED_MPS = 5.0
MAX_YAW_RATE_RADPS = 20.0
MAX_STEERING_RAD = 1.6
MAX_BATTERY_V = 30.0


def implausible(msg: Message) -> Optional[str]:
    """Why a decoded message cannot come from a Limo (a value out of range), or None."""
    if isinstance(msg, (MotionCommand, MotionState)):
        for name, value, limit in (("linear_mps", msg.linear_mps, MAX_SPEED_MPS),
                                   ("angular_radps", msg.angular_radps, MAX_YAW_RATE_RADPS),
                                   ("lateral_mps", msg.lateral_mps, MAX_SPEED_MPS),
                                   ("steering_rad", msg.steering_rad, MAX_STEERING_RAD)):
            if abs(value) > limit:
                return f"{type(msg).__name__}.{name} {value:g} beyond {limit:g}"
    elif isinstance(msg, SystemState):
        if msg.battery_v > MAX_BATTERY_V:
            return f"SystemState.battery_v {msg.battery_v:g} beyond {MAX_BATTERY_V:g}"
        if msg.control_mode > 3 or msg.motion_mode > 3:
            return f"SystemState control_mode {msg.control_mode} / motion_mode {msg.motion_mode} not a mode (0..3)"
    elif isinstance(msg, ImuEuler):       # (accelerations and rates saturate at the wire's +-327.67)
        if abs(msg.yaw_deg) > 360.0 or abs(msg.pitch_deg) > 180.0 or abs(msg.roll_deg) > 180.0:
            return "ImuEuler angle beyond +-360 / +-180 deg"
    return None


# ---------------------------------------------------------------------------------- parser


@dataclass(frozen=True)
class ParserStats:
    """What a :class:`FrameParser` has seen: good frames, bytes skipped while hunting for a frame
    start, and candidate frames rejected for a bad checksum, an unknown id or an implausible value
    (their first byte is counted as skipped too, since the hunt resumes one byte later), with the
    last rejection's reason."""

    frames: int
    bytes_skipped: int
    bad_checksums: int
    unknown_ids: int = 0
    implausible: int = 0
    last_rejected: str = ""

    @property
    def rejected(self) -> int:
        return self.bad_checksums + self.unknown_ids + self.implausible


class FrameParser:
    """Turns an arbitrary byte stream into messages; never raises on any input.

    ``feed(data)`` appends bytes and returns every message completed by them. Frames may be split
    across calls. A candidate frame is rejected for a bad checksum, an id the protocol does not
    use (:data:`KNOWN_IDS`) or an implausible value (:func:`implausible`); after garbage or a
    rejected candidate the parser resynchronises on the next ``0x55 0x0E`` (a rejected candidate
    is skipped by one byte only, so a real frame that starts inside it is still found).
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._frames = 0
        self._skipped = 0
        self._bad = 0
        self._unknown = 0
        self._implausible = 0
        self._last = ""

    @property
    def stats(self) -> ParserStats:
        return ParserStats(self._frames, self._skipped, self._bad, self._unknown, self._implausible, self._last)

    def reset(self) -> None:
        """Drop buffered bytes (e.g. after reopening the port); counters are kept."""
        self._buf.clear()

    def feed(self, data: bytes) -> List[Message]:
        """Add bytes; return the messages they complete, in stream order."""
        buf = self._buf
        buf += data
        out: List[Message] = []
        pos = 0
        end = len(buf)
        while True:
            start = buf.find(_SYNC, pos)
            if start < 0:
                # keep a trailing 0x55: it may be the first half of the next sync pair
                keep = end - 1 if end > pos and buf[end - 1] == HEADER else end
                self._skipped += keep - pos
                pos = keep
                break
            self._skipped += start - pos
            pos = start
            if end - pos < FRAME_LEN:
                break
            payload = bytes(buf[pos + 4:pos + 12])
            msg_id = (buf[pos + 2] << 8) | buf[pos + 3]
            msg = why = None
            if sum(payload) & 0xFF != buf[pos + 13]:
                self._bad += 1
            elif msg_id not in KNOWN_IDS:
                self._unknown += 1
                why = f"unknown id {msg_id:#05x}"
            else:
                msg = decode_payload(msg_id, payload)
                why = implausible(msg)
                if why is not None:
                    self._implausible += 1
            if msg is None or why is not None:
                if why is not None:
                    self._last = why
                self._skipped += 1
                pos += 1
                continue
            out.append(msg)
            self._frames += 1
            pos += FRAME_LEN
        del buf[:pos]
        return out

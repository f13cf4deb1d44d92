"""The Limo serial codec and stream parser: golden bytes, round trips, clipping, resynchronisation."""

import random

import pytest

from limo.protocol import (
    FRAME_LEN,
    ControlModeCommand,
    FrameParser,
    ImuAccel,
    ImuEuler,
    ImuGyro,
    MotionCommand,
    MotionState,
    ProtocolError,
    SystemState,
    UnknownFrame,
    WheelOdometry,
    build_frame,
    decode_frame,
    describe_error_bits,
    encode,
    encode_enable,
    encode_motion,
)

# the three frames of shared/docs/limo.md, checksums verified there
GOLDEN_ENABLE = "55 0E 04 21 01 00 00 00 00 00 00 00 00 01"
GOLDEN_FORWARD = "55 0E 01 11 00 C8 00 00 00 00 00 00 00 C8"
GOLDEN_TURN = "55 0E 01 11 00 00 FE 0C 00 00 00 00 00 0A"


def test_golden_frames_are_reproduced_exactly():
    assert encode_enable() == bytes.fromhex(GOLDEN_ENABLE)
    assert encode_motion(0.2, 0.0) == bytes.fromhex(GOLDEN_FORWARD)
    assert encode_motion(0.0, -0.5) == bytes.fromhex(GOLDEN_TURN)


def test_golden_frames_decode():
    assert decode_frame(bytes.fromhex(GOLDEN_ENABLE)) == ControlModeCommand(True, False)
    assert decode_frame(bytes.fromhex(GOLDEN_FORWARD)) == MotionCommand(0.2, 0.0, 0.0, 0.0)
    assert decode_frame(bytes.fromhex(GOLDEN_TURN)) == MotionCommand(0.0, -0.5, 0.0, 0.0)


def test_wire_order_is_linear_angular_lateral_steering():
    frame = encode_motion(0.001, 0.002, 0.003, 0.004)
    assert frame[4:12] == bytes([0, 1, 0, 2, 0, 3, 0, 4])


ROUND_TRIP = [
    ControlModeCommand(True, False),
    ControlModeCommand(True, True),
    ControlModeCommand(False, False),
    MotionCommand(0.25, -1.5, -0.125, 0.4),
    MotionCommand(-0.8, 0.999, 0.0, -0.48),
    MotionState(-0.3, -0.75, 0.001, -0.001),
    SystemState(vehicle_state=2, control_mode=1, battery_v=11.7, error_bits=0x0104, motion_mode=2),
    SystemState(battery_v=0.0),
    WheelOdometry(left_mm=-123456, right_mm=2 ** 31 - 1),
    WheelOdometry(left_mm=-(2 ** 31), right_mm=-1),
    ImuAccel(-9.81, 0.12, -0.01),
    ImuGyro(-327.68, 327.67, -57.3),
    ImuEuler(-179.99, 45.5, -3.25),
    UnknownFrame(0x251, bytes([1, 2, 3, 4, 250, 251, 252, 253])),
]


@pytest.mark.parametrize("msg", ROUND_TRIP, ids=lambda m: type(m).__name__)
def test_every_message_round_trips(msg):
    frame = encode(msg)
    assert len(frame) == FRAME_LEN and frame[:2] == b"\x55\x0e" and frame[12] == 0
    assert frame[13] == sum(frame[4:12]) & 0xFF
    assert decode_frame(frame) == msg
    assert encode(decode_frame(frame)) == frame


def test_imu_values_are_sign_extended():
    # 0xFF38 is -200 as int16: -2.00, not 653.36 (the unsigned reading a buggy driver gives)
    frame = build_frame(0x323, bytes([0xFF, 0x38, 0x00, 0x64, 0x80, 0x00, 0, 0]))
    assert decode_frame(frame) == ImuEuler(yaw_deg=-2.0, pitch_deg=1.0, roll_deg=-327.68)


def test_out_of_range_values_are_clipped_not_wrapped():
    assert decode_frame(encode_motion(40.0, -1e9, float("inf"), float("-inf"))) == \
        MotionCommand(32.767, -32.768, 32.767, -32.768)
    assert decode_frame(encode(ImuGyro(1000.0, -1000.0, 0.0))) == ImuGyro(327.67, -327.68, 0.0)
    assert decode_frame(encode(WheelOdometry(2 ** 40, -(2 ** 40)))) == WheelOdometry(2 ** 31 - 1, -(2 ** 31))
    clipped = decode_frame(encode(SystemState(vehicle_state=300, control_mode=-4, battery_v=-1.0,
                                              error_bits=0x1FFFF, motion_mode=7)))
    assert clipped == SystemState(255, 0, 0.0, 0xFFFF, 7)
    assert decode_frame(encode(SystemState(battery_v=7000.0))).battery_v == 6553.5


def test_nan_and_non_numbers_are_refused_with_the_field_name():
    with pytest.raises(ProtocolError, match="angular_radps"):
        encode_motion(0.0, float("nan"))
    with pytest.raises(ProtocolError, match="linear_mps"):
        encode(MotionCommand("fast", 0.0))  # type: ignore[arg-type]
    with pytest.raises(ProtocolError, match="cannot encode"):
        encode(object())  # type: ignore[arg-type]


def test_decode_frame_names_what_is_wrong():
    good = bytearray(encode_motion(0.2, 0.0))
    with pytest.raises(ProtocolError, match="14 bytes"):
        decode_frame(bytes(good[:13]))
    bad = bytearray(good)
    bad[13] ^= 0x01
    with pytest.raises(ProtocolError, match="checksum"):
        decode_frame(bytes(bad))
    bad = bytearray(good)
    bad[0] = 0xAA
    with pytest.raises(ProtocolError, match="frame start"):
        decode_frame(bytes(bad))


def test_error_bits_are_named():
    assert describe_error_bits(0x0001 | 0x0010) == ["battery low (error)", "motor driver 2"]
    assert describe_error_bits(0x8000) == ["unknown bits 0x8000"]
    assert describe_error_bits(0) == []


def test_parser_handles_frames_split_at_every_byte():
    stream = b"".join(encode(m) for m in ROUND_TRIP)
    parser = FrameParser()
    out = []
    for i in range(len(stream)):
        out += parser.feed(stream[i:i + 1])
    assert out == ROUND_TRIP
    assert parser.stats.frames == len(ROUND_TRIP) and parser.stats.bytes_skipped == 0


def test_parser_resyncs_after_bad_checksum_and_counts_drops():
    good = encode(ImuGyro(1.0, 2.0, 3.0))
    corrupt = bytearray(encode(MotionState(0.5, 0.5)))
    corrupt[13] ^= 0xFF
    garbage = b"\x00\x55\x55\x13"
    parser = FrameParser()
    out = parser.feed(garbage + bytes(corrupt) + good)
    assert out == [ImuGyro(1.0, 2.0, 3.0)]
    stats = parser.stats
    assert stats.bad_checksums == 1
    assert stats.bytes_skipped == len(garbage) + len(corrupt)
    assert stats.frames == 1


def test_parser_finds_a_frame_that_starts_inside_a_rejected_candidate():
    good = encode(WheelOdometry(1000, -1000))
    # a fake header right before the real frame: its "payload" swallows the real frame's start
    stream = b"\x55\x0e\x03\x11" + good
    parser = FrameParser()
    assert parser.feed(stream) == [WheelOdometry(1000, -1000)]
    assert parser.stats.bad_checksums == 1


def test_parser_recovers_every_frame_from_100k_random_bytes():
    rng = random.Random(20250707)
    expected = []
    chunks = []
    for _ in range(2000):
        chunks.append(bytes(rng.getrandbits(8) for _ in range(rng.randrange(0, 100))))
        msg = MotionState(rng.randint(-5000, 5000) / 1000, rng.randint(-20000, 20000) / 1000,
                          0.0, 0.0) if rng.random() < 0.5 else WheelOdometry(rng.getrandbits(31), -rng.getrandbits(31))
        expected.append(msg)
        chunks.append(encode(msg))
    stream = b"".join(chunks)
    assert len(stream) > 100_000 + 2000 * FRAME_LEN - 2000 * 10
    parser = FrameParser()
    out = []
    pos = 0
    while pos < len(stream):  # feed in random-sized pieces, as a serial read would deliver them
        step = rng.randrange(1, 64)
        out += parser.feed(stream[pos:pos + step])
        pos += step
    # every valid frame appears, in order (random bytes may also form an occasional valid frame)
    it = iter(out)
    assert all(any(m == e for m in it) for e in expected)
    stats = parser.stats
    assert stats.frames == len(out) >= len(expected)
    assert stats.bytes_skipped > 90_000  # the garbage was counted, not silently swallowed


def test_parser_never_raises_on_any_input():
    rng = random.Random(7)
    parser = FrameParser()
    # bytes rich in header and length values stress the resync paths
    alphabet = [0x55, 0x0E, 0x00, 0xFF, 0x01, 0x11, 0x03, 0x23]
    for _ in range(300):
        data = bytes(rng.choice(alphabet) if rng.random() < 0.7 else rng.getrandbits(8)
                     for _ in range(rng.randrange(0, 200)))
        for msg in parser.feed(data):
            assert encode(msg)[:2] == b"\x55\x0e"
    assert parser.feed(b"") == []
    assert parser.stats.bytes_skipped > 0 and parser.stats.bad_checksums > 0


def _fake_frame(rng: random.Random) -> bytes:
    """``55 0E``, a random id and payload, and a checksum that matches: what the checksum cannot catch."""
    payload = bytes(rng.getrandbits(8) for _ in range(8))
    return bytes((0x55, 0x0E, rng.getrandbits(8), rng.getrandbits(8))) + payload + bytes((0, sum(payload) & 0xFF))


def test_frames_with_an_unknown_id_or_implausible_values_are_rejected_and_counted():
    """Noise with 1,000 fake frames whose checksums match, and 5,000 real frames: every real one
    comes out, no fake one does (the checksum alone let about 5 in 1,000 through)."""
    rng = random.Random(11)
    real = [MotionState(0.3, -0.2, 0.0, 0.0), SystemState(0, 1, 12.2, 0, 0), WheelOdometry(1234, -567),
            ImuGyro(0.0, 0.0, 28.6), ImuEuler(90.0, 1.0, -1.0), ImuAccel(0.1, 0.0, 9.81)]
    stream, expected = bytearray(), []
    for k in range(6000):
        if k % 6 == 5:
            stream += _fake_frame(rng)
        else:
            msg = real[k % len(real)]
            stream += encode(msg)
            expected.append(msg)
        stream += bytes(rng.getrandbits(8) for _ in range(rng.randrange(0, 6)))
    parser = FrameParser()
    out = []
    for start in range(0, len(stream), 61):
        out += parser.feed(bytes(stream[start:start + 61]))
    assert out == expected
    stats = parser.stats
    assert stats.unknown_ids > 900 and stats.frames == len(expected)
    assert stats.rejected == stats.bad_checksums + stats.unknown_ids + stats.implausible


@pytest.mark.parametrize("msg, why", [
    (MotionState(12.0, 0.0, 0.0, 0.0), "MotionState.linear_mps 12"),
    (SystemState(0, 1, 250.0, 0, 0), "battery_v 250"),
    (SystemState(0, 9, 12.0, 0, 0), "control_mode 9"),
    (ImuEuler(0.0, 200.0, 0.0), "ImuEuler"),
])
def test_an_implausible_frame_is_rejected_saying_why(msg, why):
    parser = FrameParser()
    assert parser.feed(encode(msg) + encode(WheelOdometry(1, 2))) == [WheelOdometry(1, 2)]
    assert parser.stats.implausible == 1 and why in parser.stats.last_rejected

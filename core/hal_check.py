"""Conformance checker for HAL backends, in the manner of gymnasium's ``env_checker``.

``check_base(make_base)`` runs a fixed script against fresh bases from ``make_base`` and raises
``AssertionError`` with a message saying which rule of :mod:`core.hal` was broken. Every backend
(the simulated Limo, the serial Limo on an emulated port) is checked by the same parametrised
test, so they stay interchangeable for the run loop.

The script drives gently (a quarter of the limits) for a few control periods; a real base on
the floor would move a few centimetres.
"""

from __future__ import annotations

import math
from typing import Callable, List

import numpy as np

from core.hal import STOP, HalError, Odometry, RobotBase, SensorFrame, VelocityCommand

# After stop(), measured body speeds (where a base has odometry) must fall below these within
# STOP_WITHIN_S: generous enough for the Limo's acceleration limits (0.2 s from full speed).
STOP_V_TOL_MPS = 0.02
STOP_W_TOL_RADPS = 0.05
STOP_WITHIN_S = 1.0


class _Probe(Exception):
    """Raised inside a ``with`` block to check that the base still stops and closes."""


def _record_applies(base: RobotBase) -> List[VelocityCommand]:
    """Wrap ``base.apply`` on the instance so every command that reaches it is recorded."""
    calls: List[VelocityCommand] = []
    original = base.apply

    def recording_apply(cmd: VelocityCommand) -> VelocityCommand:
        calls.append(cmd)
        return original(cmd)

    base.apply = recording_apply  # type: ignore[method-assign]
    return calls


def _name(base: RobotBase) -> str:
    return type(base).__name__


def _check_frame(base: RobotBase, frame: object) -> SensorFrame:
    name = _name(base)
    assert isinstance(frame, SensorFrame), f"{name}.read() must return a SensorFrame, got {type(frame).__name__}"
    assert isinstance(frame.stamp_s, (int, float)) and math.isfinite(frame.stamp_s), \
        f"{name}: SensorFrame.stamp_s must be a finite number of seconds, got {frame.stamp_s!r}"
    rgb = frame.rgb
    if rgb is not None:
        assert isinstance(rgb, np.ndarray), f"{name}: SensorFrame.rgb must be a numpy array or None, got {type(rgb).__name__}"
        assert rgb.ndim == 3 and rgb.shape[2] == 3 and rgb.shape[0] > 0 and rgb.shape[1] > 0, \
            f"{name}: SensorFrame.rgb must have shape (H, W, 3), got {rgb.shape}"
        assert rgb.dtype == np.uint8, f"{name}: SensorFrame.rgb must be uint8, got {rgb.dtype}"
    if frame.odometry is not None:
        odom = frame.odometry
        assert isinstance(odom, Odometry), f"{name}: SensorFrame.odometry must be an Odometry or None"
        for field in ("x_m", "y_m", "yaw_rad", "v_mps", "w_radps", "left_m", "right_m"):
            value = getattr(odom, field)
            assert isinstance(value, (int, float)) and math.isfinite(value), \
                f"{name}: Odometry.{field} must be a finite number, got {value!r}"
    if frame.imu_yaw_rate_radps is not None:
        assert math.isfinite(frame.imu_yaw_rate_radps), \
            f"{name}: SensorFrame.imu_yaw_rate_radps must be finite or None, got {frame.imu_yaw_rate_radps!r}"
    return frame


def _check_attributes(base: RobotBase) -> None:
    name = _name(base)
    assert base.limits.max_v_mps > 0 and base.limits.max_w_radps > 0, \
        f"{name}.limits must be positive, got {base.limits}"
    assert base.control_period_s > 0, f"{name}.control_period_s must be > 0, got {base.control_period_s}"
    assert not base.connected, f"{name}: a new base must not be connected before connect() (__init__ only stores config)"
    try:
        base.read()
    except HalError:
        pass
    else:
        raise AssertionError(f"{name}.read() before connect() must raise HalError")


def _check_apply_clips(base: RobotBase) -> None:
    name, lim = _name(base), base.limits
    cases = [
        (VelocityCommand(2.0 * lim.max_v_mps, 3.0 * lim.max_w_radps), VelocityCommand(lim.max_v_mps, lim.max_w_radps)),
        (VelocityCommand(-2.0 * lim.max_v_mps, -3.0 * lim.max_w_radps), VelocityCommand(-lim.max_v_mps, -lim.max_w_radps)),
        (VelocityCommand(0.25 * lim.max_v_mps, -0.25 * lim.max_w_radps),
         VelocityCommand(0.25 * lim.max_v_mps, -0.25 * lim.max_w_radps)),
    ]
    for cmd, expected in cases:
        got = base.apply(cmd)
        assert isinstance(got, VelocityCommand), f"{name}.apply() must return a VelocityCommand, got {type(got).__name__}"
        assert math.isclose(got.v_mps, expected.v_mps, abs_tol=1e-9) and \
            math.isclose(got.w_radps, expected.w_radps, abs_tol=1e-9), \
            f"{name}.apply({cmd}) must return the command clipped to {lim}, expected {expected}, got {got}"


def _check_ticks(base: RobotBase) -> None:
    name = _name(base)
    before = _check_frame(base, base.read()).stamp_s
    for _ in range(3):
        base.tick()
        after = _check_frame(base, base.read()).stamp_s
        assert after > before, f"{name}: SensorFrame.stamp_s must increase after tick(), got {before} then {after}"
        before = after


def _check_stop(base: RobotBase, applied: List[VelocityCommand]) -> None:
    name = _name(base)
    base.apply(VelocityCommand(0.25 * base.limits.max_v_mps, 0.25 * base.limits.max_w_radps))
    base.tick()
    applied.clear()
    base.stop()
    assert applied and applied[-1].is_zero, \
        f"{name}.stop() must apply a zero VelocityCommand, applied {applied or 'nothing'}"
    frame = base.read()
    for _ in range(max(1, math.ceil(STOP_WITHIN_S / base.control_period_s))):
        base.tick()
        frame = base.read()
    if frame.odometry is not None:
        assert abs(frame.odometry.v_mps) < STOP_V_TOL_MPS and abs(frame.odometry.w_radps) < STOP_W_TOL_RADPS, \
            f"{name}: {STOP_WITHIN_S} s after stop() odometry must show the base at rest, got {frame.odometry}"


def _check_context_manager(make_base: Callable[[], RobotBase]) -> None:
    base = make_base()
    name = _name(base)
    applied = _record_applies(base)
    try:
        with base as entered:
            assert entered is base, f"{name}.__enter__ must return the base itself"
            assert base.connected, f"{name}: a base must be connected inside its 'with' block"
            base.apply(VelocityCommand(0.25 * base.limits.max_v_mps, 0.0))
            applied.clear()
            raise _Probe()
    except _Probe:
        pass
    assert applied and applied[0].is_zero, \
        f"{name}: leaving a 'with' block on an exception must stop the base first, applied {applied or 'nothing'}"
    assert not base.connected, f"{name}: leaving a 'with' block on an exception must close the base"


def check_base(make_base: Callable[[], RobotBase]) -> None:
    """Check that bases from ``make_base`` follow the :mod:`core.hal` contract; AssertionError if not."""
    base = make_base()
    assert isinstance(base, RobotBase), f"make_base() must return a RobotBase, got {type(base).__name__}"
    name = _name(base)
    _check_attributes(base)
    applied = _record_applies(base)
    base.connect()
    try:
        assert base.connected, f"{name}.connected must be True after connect()"
        try:
            base.connect()
        except HalError:
            pass
        else:
            raise AssertionError(f"{name}.connect() twice must raise HalError")
        _check_frame(base, base.read())
        _check_apply_clips(base)
        _check_ticks(base)
        _check_stop(base, applied)
    finally:
        base.close()
    assert not base.connected, f"{name}.connected must be False after close()"
    base.close()  # a second close() must be harmless
    for what, call in (("read()", base.read), ("apply()", lambda: base.apply(STOP)), ("tick()", base.tick)):
        try:
            call()
        except HalError:
            continue
        raise AssertionError(f"{name}.{what} after close() must raise HalError")
    _check_context_manager(make_base)

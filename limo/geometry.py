"""The AgileX Limo's body: dimensions and skid-steer kinematics, written once for the simulator,
the emulated firmware and the state estimate (``shared/docs/limo.md``; AgileX's driver values)."""

from __future__ import annotations

WHEEL_RADIUS_M = 0.045
WHEEL_WIDTH_M = 0.045
WHEELBASE_M = 0.200
#: effective track of the base; the Limo driver uses 0.172 m (the manual says 0.175 m)
TRACK_M = 0.172
TOTAL_MASS_KG = 4.8
BODY_LENGTH_M = 0.322
BODY_WIDTH_M = 0.220
GROUND_CLEARANCE_M = 0.024

#: acceleration limits from AgileX's navigation configs
MAX_LINEAR_ACCEL_MPS2 = 2.5
MAX_ANGULAR_ACCEL_RADPS2 = 3.2


def wheel_speeds_radps(v_mps: float, w_radps: float) -> tuple[float, float]:
    """Skid-steer inverse kinematics: (left, right) wheel angular speeds in rad/s."""
    half = w_radps * TRACK_M / 2.0
    return (v_mps - half) / WHEEL_RADIUS_M, (v_mps + half) / WHEEL_RADIUS_M


def body_twist(left_mps: float, right_mps: float) -> tuple[float, float]:
    """Skid-steer forward kinematics: wheel rim speeds (m/s) -> body (v_mps, w_radps)."""
    return (left_mps + right_mps) / 2.0, (right_mps - left_mps) / TRACK_M

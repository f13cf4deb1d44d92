"""Angle helpers: the one place where angles are wrapped (a second copy is a bug waiting)."""

from __future__ import annotations

import math


def wrap_angle(angle_rad: float) -> float:
    """An angle in radians brought into [-pi, pi)."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


def angle_between(a_rad: float, b_rad: float) -> float:
    """The unsigned angle between two headings, in [0, pi] (radians)."""
    return abs(wrap_angle(a_rad - b_rad))

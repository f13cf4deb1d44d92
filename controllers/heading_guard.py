"""Keeping the robot facing along the route: the map's node headings against the odometry heading.

The mapping drive's odometry heading at every node (``TopoMap.odom_headings``) says which way the
route runs there. Odometry headings of two drives differ by a constant offset (the frames' zero)
plus slow drift, so the offset measured at the nodes the robot confirmed (odometry heading then
minus the map's heading there) turns a node's mapped heading into the heading the robot's own
odometry should read when it faces along the route at that node. A single confirmation is off by
however the robot was angled when it confirmed; the median over several is less so
(:meth:`HeadingGuard.offset`), and a full look round measures it better still
(:mod:`controllers.compass`): the navigator passes whichever it has.

:class:`HeadingGuard` compares the robot's heading with the target node's mapped heading and,
past ``max_error_deg``, asks to turn back (LEFT / RIGHT, which creep forward) until the error is
within ``release_deg`` (hysteresis: it does not chatter at the limit). See
:class:`controllers.config.HeadingGuardConfig` for why.
"""

from __future__ import annotations

import math
from typing import Hashable, Mapping, Optional, Sequence

import numpy as np

from controllers.actions import Action
from controllers.config import HeadingGuardConfig
from core.angles import wrap_angle

NodeId = Hashable


def median_offset(offsets: Sequence[float]) -> Optional[float]:
    """The circular median of heading offsets (radians), as differences from the newest so that
    offsets either side of +-pi average right; None for none."""
    if not offsets:
        return None
    newest = float(offsets[-1])
    spread = [wrap_angle(float(o) - newest) for o in offsets]
    return wrap_angle(newest + float(np.median(spread)))


def offset_votes(offsets: Sequence[float], count: int, look: Optional[float] = None) -> list[float]:
    """The last ``count`` offsets (newest last); with a look round's offset, that one and the
    last ``count - 1``: the look stays one vote for the whole episode."""
    offsets = [float(o) for o in offsets]
    if look is None:
        return offsets[-count:]
    return [float(look)] + (offsets[-(count - 1):] if count > 1 else [])


class HeadingGuard:
    """Turns the robot back towards the route when it faces too far from it (see the module
    docstring). ``headings``: node -> the mapping drive's odometry heading there (radians)."""

    def __init__(self, config: HeadingGuardConfig, headings: Mapping[NodeId, float]):
        self.config = config
        self._headings = dict(headings)
        self._active = False

    @property
    def active(self) -> bool:
        """Whether the guard is turning the robot back now."""
        return self._active

    def reset(self) -> None:
        """Forget a turn back in progress (a new state, a new plan)."""
        self._active = False

    def error_rad(self, target: NodeId, heading_rad: float, offset_rad: float) -> float:
        """How far the robot faces from the target's mapped heading (positive: to its left)."""
        return wrap_angle(float(heading_rad) - (self._headings[target] + float(offset_rad)))

    def offset(self, offsets: Sequence[float], look: Optional[float] = None) -> Optional[float]:
        """The map-to-odometry heading offset from those measured at confirmations (newest last):
        the median of the last ``confirmations``, None with fewer than ``min_confirmations``.
        With a look round's offset (``look``) that stays one of them and suffices alone: it is
        measured over a whole turn, and the confirmations after it follow the odometry's drift."""
        if look is not None:
            return median_offset(offset_votes(offsets, self.config.confirmations, look))
        offsets = list(offsets)[-self.config.confirmations:]
        return median_offset(offsets) if len(offsets) >= self.config.min_confirmations else None

    def hold(self, node: NodeId, heading_rad: Optional[float], offset: Optional[float]) -> Optional[tuple[Action, str]]:
        """``(action, reason)`` that drives on along ``node``'s mapped heading in the final
        approach (``final_approach``), or None where the guard cannot tell (off, no heading, no
        offset)."""
        if not self.config.final_approach:
            return None
        return self.along(node, heading_rad, offset, "final approach")

    def along(self, node: NodeId, heading_rad: Optional[float], offset: Optional[float],
              what: str) -> Optional[tuple[Action, str]]:
        """``(action, reason)`` that drives forward along ``node``'s mapped heading, correcting by
        FORWARD_LEFT / FORWARD_RIGHT beyond ``final_tolerance_deg``; ``what`` names the purpose in
        the reason. None where the guard cannot tell (off, no heading, no offset)."""
        cfg = self.config
        if not cfg.enabled or heading_rad is None or node not in self._headings or offset is None:
            return None
        error = self.error_rad(node, heading_rad, offset)
        if abs(error) <= math.radians(cfg.final_tolerance_deg):
            action = Action.FORWARD
        else:
            action = Action.FORWARD_RIGHT if error > 0 else Action.FORWARD_LEFT
        return action, (f"{what} along the map's heading at node {node!r}: facing "
                        f"{math.degrees(error):+.0f} deg from it, {action.value}")

    def check(self, target: Optional[NodeId], heading_rad: Optional[float],
              offset: Optional[float]) -> Optional[tuple[Action, str]]:
        """``(action, reason)`` while the robot must turn back towards the target's mapped heading,
        else None. ``offset``: the map-to-odometry heading offset (:meth:`offset`, or a look's),
        None while unknown."""
        cfg = self.config
        if (not cfg.enabled or target is None or heading_rad is None or target not in self._headings
                or offset is None):
            self._active = False
            return None
        error = self.error_rad(target, heading_rad, offset)
        limit = math.radians(cfg.release_deg if self._active else cfg.max_error_deg)
        self._active = abs(error) > limit
        if not self._active:
            return None
        action = Action.RIGHT if error > 0 else Action.LEFT
        return action, (f"facing {math.degrees(error):+.0f} deg from the map's heading at node {target!r} "
                        f"(limit {cfg.max_error_deg:g}): turning back ({action.value}) to within {cfg.release_deg:g}")

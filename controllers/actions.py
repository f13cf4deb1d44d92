"""The discrete actions of the navigator and their body velocities."""

from __future__ import annotations

import enum

from controllers.config import ActionSpeeds
from core.hal import STOP as ZERO_VELOCITY
from core.hal import VelocityCommand


class Action(enum.Enum):
    """What the robot does during one control tick.

    ``LEFT`` / ``FORWARD`` / ``RIGHT`` come from the Left / Middle / Right thirds agreeing over two
    cycles; ``FORWARD_LEFT`` / ``FORWARD_RIGHT`` from a conflict between Middle and a side;
    ``NONE`` means no action is taken this tick (a storing cycle without a held action, a
    conflict, no vote, a localisation being confirmed): the robot stands still.
    ``SEARCH_ROTATE`` turns counter-clockwise in place to look for a match. ``BACKWARD`` backs off
    a wall the robot is pinned against (``navigation.recovery``). ``RETRACE`` drives the way just
    driven backwards before a turn in place (``navigation.turn_room``): its velocity is a recent
    command negated, so it has no speed of its own. ``STOP`` is final: arrived or failed.
    """

    LEFT = "left"
    FORWARD = "forward"
    RIGHT = "right"
    FORWARD_LEFT = "forward_left"
    FORWARD_RIGHT = "forward_right"
    NONE = "none"
    SEARCH_ROTATE = "search_rotate"
    BACKWARD = "backward"
    RETRACE = "retrace"
    STOP = "stop"

    @property
    def moves(self) -> bool:
        """True when the action commands a non-zero velocity."""
        return self not in (Action.NONE, Action.STOP)


def action_velocity(action: Action, speeds: ActionSpeeds) -> VelocityCommand:
    """The body velocity (v_mps, w_radps) of ``action`` under the configured ``speeds``."""
    if not isinstance(action, Action):
        raise TypeError(f"expected an Action, got {action!r}")
    if not action.moves:
        return ZERO_VELOCITY
    if action is Action.RETRACE:
        raise ValueError("RETRACE has no speed of its own: it negates a command the robot just drove")
    return getattr(speeds, action.value)

"""Ending on a signal the way Ctrl-C ends: through every ``finally`` that stops the robot.

Python turns SIGINT (Ctrl-C) into :class:`KeyboardInterrupt`, so the run loop's and the serial
base's cleanup runs and the base is commanded to zero. SIGTERM (what systemd, docker and ``kill``
send) and SIGHUP (a closed terminal or SSH session) would end the process at once instead, leaving
the last motion command on the wire. :func:`stop_on_signals` makes them raise
:class:`Terminated`, a :class:`KeyboardInterrupt`, so the same cleanup runs; a repeated signal is
ignored while it does. :func:`exit_status` gives the conventional status, 128 + the signal number
(130 Ctrl-C, 143 SIGTERM, 129 SIGHUP).
"""

from __future__ import annotations

import signal
from typing import Sequence

SIGNALS = (signal.SIGTERM, signal.SIGHUP)


class Terminated(KeyboardInterrupt):
    """The process was asked to end by ``signum`` (SIGTERM, SIGHUP)."""

    def __init__(self, signum: int):
        super().__init__(f"ended by {signal.Signals(signum).name}")
        self.signum = signum


def _raise_terminated(signum, frame) -> None:
    for s in SIGNALS:                     # the cleanup this starts must not be cut short
        signal.signal(s, signal.SIG_IGN)
    raise Terminated(signum)


def stop_on_signals(signals: Sequence[int] = SIGNALS) -> None:
    """From now on, ``signals`` raise :class:`Terminated` in the main thread (call it there)."""
    for s in signals:
        signal.signal(s, _raise_terminated)


def exit_status(exc: KeyboardInterrupt) -> int:
    """130 for Ctrl-C, 128 + the signal number for :class:`Terminated`."""
    return 128 + (exc.signum if isinstance(exc, Terminated) else signal.SIGINT)


def interrupted_by(exc: KeyboardInterrupt) -> str:
    """How the process was stopped, for the one line it prints: "interrupted" or "terminated (SIGTERM)"."""
    return f"terminated ({signal.Signals(exc.signum).name})" if isinstance(exc, Terminated) else "interrupted"

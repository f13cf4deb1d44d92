"""Waiting in real-time tests: poll a condition instead of sleeping a fixed time."""

from __future__ import annotations

import time


def wait_until(predicate, timeout_s: float, step_s: float = 0.005) -> bool:
    """True as soon as ``predicate()`` is; its last value once ``timeout_s`` has passed."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(step_s)
    return predicate()

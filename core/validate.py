"""Field validators for the configuration dataclasses: one set for the whole stack.

Every config dataclass checks its fields in ``__post_init__`` with these; a bad value raises
``ValueError`` (or the component's own subclass of it, ``error=``) whose message starts with the
field name, and :mod:`core.configfile` turns it into an error naming the YAML file and the dotted
field. Booleans are never numbers here (``true`` where a count belongs is a mistake in the file,
not 1).
"""

from __future__ import annotations

import math
from typing import Any


def is_number(value: Any) -> bool:
    """A finite int or float, not a bool."""
    return not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)


def check_bool(name: str, value: Any, *, error: type[Exception] = ValueError) -> None:
    if not isinstance(value, bool):
        raise error(f"{name} must be true or false, got {value!r}")


def check_count(name: str, value: Any, least: int, *, error: type[Exception] = ValueError) -> None:
    """An integer of at least ``least``."""
    if isinstance(value, bool) or not isinstance(value, int) or value < least:
        raise error(f"{name} must be an integer >= {least}, got {value!r}")


def check_positive(name: str, value: Any, *, error: type[Exception] = ValueError) -> None:
    """A finite number above zero."""
    if not (is_number(value) and value > 0):
        raise error(f"{name} must be a positive finite number, got {value!r}")


def check_at_least(name: str, value: Any, least: float, *, error: type[Exception] = ValueError) -> None:
    """A finite number of at least ``least``."""
    if not (is_number(value) and value >= least):
        raise error(f"{name} must be at least {least:g}, got {value!r}")


def check_range(name: str, value: Any, low: float, high: float, *, low_open: bool = False,
                high_open: bool = False, what: str = "a number", error: type[Exception] = ValueError) -> None:
    """A finite number within ``[low, high]``; an open end excludes that bound. ``what`` says what
    the number is in the message (``"a number of degrees"``, ``"a probability"``)."""
    ok = is_number(value)
    if ok:
        ok = (value > low if low_open else value >= low) and (value < high if high_open else value <= high)
    if not ok:
        interval = f"{'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"
        raise error(f"{name} must be {what} in {interval}, got {value!r}")


def check_similarity(name: str, value: Any, *, error: type[Exception] = ValueError) -> None:
    """A cosine similarity of L2-normalised descriptors: a finite number in [-1, 1]."""
    if not (is_number(value) and -1.0 <= value <= 1.0):
        raise error(f"{name} must be a cosine similarity in [-1, 1], got {value!r}")


def check_choice(name: str, value: Any, choices, *, error: type[Exception] = ValueError) -> None:
    """One of ``choices``."""
    if value not in choices:
        raise error(f"{name} must be one of {', '.join(map(repr, choices))}, got {value!r}")

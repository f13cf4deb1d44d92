"""The map-to-odometry heading offset from a look round, not from one heading.

A node's view matches best when the camera faces the way the mapping drive's camera faced there.
During a full turn in place every heading is seen, so for each node near where the robot stands
the heading at which its similarity peaks, minus the map's heading at the node, measures the
offset between the robot's odometry frame and the map's. The heading the robot happens to face
when it is placed does not: a robot set down 15 deg off the route and trusted to face along it
carries that 15 deg into every heading check that follows.

:class:`LookCompass` keeps the look's ``(heading, similarity row)`` pairs; :meth:`LookCompass.offset`
smooths each node's similarity over the heading with a Gaussian kernel of ``bandwidth_rad`` (the
views come a few degrees apart and each is noisy), takes the heading of its maximum, and returns
the circular median over the nodes given.
"""

from __future__ import annotations

import math
from typing import Optional, Sequence

import numpy as np

from controllers.heading_guard import median_offset
from core.angles import wrap_angle

#: the headings the smoothed similarity is evaluated at (1 deg apart)
_GRID = np.linspace(-math.pi, math.pi, 360, endpoint=False)


class LookCompass:
    """Collects a turn in place's views and measures the heading offset from them."""

    def __init__(self, bandwidth_rad: float):
        if not (math.isfinite(bandwidth_rad) and bandwidth_rad > 0.0):
            raise ValueError(f"bandwidth_rad must be a positive number, got {bandwidth_rad!r}")
        self.bandwidth_rad = float(bandwidth_rad)
        self._headings: list[float] = []
        self._rows: list[np.ndarray] = []

    def __len__(self) -> int:
        return len(self._headings)

    def clear(self) -> None:
        """Forget the views (a new look)."""
        self._headings.clear()
        self._rows.clear()

    def add(self, heading_rad: Optional[float], row: np.ndarray) -> None:
        """One view: its heading (any frame, may wrap) and its similarity to every node."""
        if heading_rad is not None:
            self._headings.append(float(heading_rad))
            self._rows.append(np.asarray(row, dtype=np.float64))

    def peak_rad(self, column: int) -> Optional[float]:
        """The heading at which the views match node ``column`` best (wrapped), None without views."""
        if not self._headings:
            return None
        headings = np.asarray(self._headings)
        scores = np.array([row[column] for row in self._rows])
        diff = np.angle(np.exp(1j * (_GRID[:, None] - headings[None, :])))
        weights = np.exp(-0.5 * (diff / self.bandwidth_rad) ** 2)
        smoothed = (weights * scores[None, :]).sum(axis=1) / np.maximum(weights.sum(axis=1), 1e-12)
        return float(_GRID[int(np.argmax(smoothed))])

    def offset(self, columns: Sequence[int], mapped_headings: Sequence[float]) -> Optional[float]:
        """The odometry heading minus the map's: the circular median over ``columns`` of each
        node's peak heading minus its ``mapped_headings`` entry; None without views or columns."""
        offsets = []
        for column, mapped in zip(columns, mapped_headings):
            peak = self.peak_rad(column)
            if peak is not None:
                offsets.append(wrap_angle(peak - float(mapped)))
        return median_offset(offsets)

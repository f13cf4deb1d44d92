"""Kalman smoothing of the per-node similarity signals.

Each node's similarity to the current view is filtered by its own scalar Kalman filter with a
random-walk model (see :class:`controllers.config.SimilarityFilterConfig`). This is exactly
``filterpy.kalman.KalmanFilter(dim_x=1, dim_z=1)`` with ``F = H = 1``, ``Q = process_std**2``,
``R = measurement_std**2``, started at the first measurement with ``P = R`` (the tests check
the equivalence against filterpy), but vectorised over all nodes with numpy, because one
filterpy object per node would cost far more than the rest of a control tick.

Why: single noisy frames must not flip decisions. ViNT's deployment takes the arg-max node of
the raw scores every frame, and users report the closest node flickering while the robot stands
still, so the goal is never detected.
"""

from __future__ import annotations

import numpy as np

from controllers.config import SimilarityFilterConfig


class SimilarityFilter:
    """A bank of independent scalar Kalman filters, one per column of the similarity row."""

    def __init__(self, size: int, config: SimilarityFilterConfig = SimilarityFilterConfig()):
        if size < 1:
            raise ValueError(f"a similarity filter needs at least one node, got size {size}")
        self.size = int(size)
        self.q = config.process_std ** 2
        self.r = config.measurement_std ** 2
        self._x = np.zeros(self.size)
        self._p = np.zeros(self.size)
        self._started = False

    @property
    def started(self) -> bool:
        return self._started

    @property
    def estimate(self) -> np.ndarray:
        """The filtered similarities (a copy); zeros before the first update."""
        return self._x.copy()

    @property
    def variance(self) -> np.ndarray:
        """The posterior variance of each estimate (a copy)."""
        return self._p.copy()

    def reset(self) -> None:
        """Forget everything; the next update starts from its measurement."""
        self._started = False
        self._x[:] = 0.0
        self._p[:] = 0.0

    def update(self, similarities: np.ndarray) -> np.ndarray:
        """Predict one tick and correct with ``similarities`` (one per node); returns the estimate."""
        z = np.asarray(similarities, dtype=float)
        if z.shape != (self.size,):
            raise ValueError(f"expected {self.size} similarities, got shape {z.shape}")
        if not np.all(np.isfinite(z)):
            raise ValueError("similarities must be finite")
        if not self._started:
            self._x[:] = z
            self._p[:] = self.r
            self._started = True
            return self.estimate
        p_prior = self._p + self.q
        gain = p_prior / (p_prior + self.r)
        self._x += gain * (z - self._x)
        self._p = (1.0 - gain) * p_prior
        return self.estimate

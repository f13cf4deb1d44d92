"""A tiny, deterministic stand-in descriptor: no network, no vocabulary, microseconds per image.

Each image (or third) is shrunk to a small grey thumbnail, its mean removed, and its pixels plus
its horizontal and vertical gradients L2-normalised. It separates rendered places well enough
for fast tests of the mapping and navigation plumbing; it is no place recognition method for
real photographs (use ``effnet-vlad`` or ``anyloc-dinov2``).
"""

from __future__ import annotations

from typing import Mapping, Sequence

import cv2
import numpy as np

from descriptors.base import DescriptorError, DescriptorIdentity, check_state_matches
from descriptors.preprocess import third_bounds, to_rgb_batch
from descriptors.vlad import l2_normalise


class TinyDescriptor:
    backend = "tiny"
    needs_fit = False

    def __init__(self, width_px: int = 24, height_px: int = 18):
        if width_px < 6 or height_px < 2:
            raise DescriptorError(f"tiny descriptor thumbnails must be at least 6x2 px, got {width_px}x{height_px}")
        if width_px % 3:
            raise DescriptorError(f"tiny descriptor width_px must be a multiple of 3 (thirds), got {width_px}")
        self.size = (int(width_px), int(height_px))

    @property
    def settings(self) -> dict:
        return {"width_px": self.size[0], "height_px": self.size[1]}

    @property
    def identity(self) -> DescriptorIdentity:
        return DescriptorIdentity(self.backend, self.settings, "", self._dim(self.size[0]))

    def _dim(self, w: int) -> int:
        h = self.size[1]
        return w * h + (w - 1) * h + w * (h - 1)

    def fit(self, images: Sequence[np.ndarray]) -> None:
        """Nothing to learn."""

    def state_dict(self) -> dict:
        return {"backend": self.backend, "settings": self.settings}

    def load_state(self, state: Mapping[str, object]) -> None:
        check_state_matches(state, self.backend, self.settings)

    def _thumbs(self, images: Sequence[np.ndarray]) -> np.ndarray:
        out = []
        for img in to_rgb_batch(images):
            grey = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
            out.append(cv2.resize(grey, self.size, interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0)
        return np.stack(out)

    @staticmethod
    def _parts(thumbs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = thumbs - thumbs.mean(axis=(1, 2), keepdims=True)
        return t, np.diff(t, axis=2), np.diff(t, axis=1)

    @staticmethod
    def _join(t: np.ndarray, gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
        n = len(t)
        return l2_normalise(np.concatenate([t.reshape(n, -1), gx.reshape(n, -1), gy.reshape(n, -1)], axis=1))

    def describe(self, images: Sequence[np.ndarray]) -> np.ndarray:
        return self._join(*self._parts(self._thumbs(images)))

    def describe_thirds(self, images: Sequence[np.ndarray]) -> np.ndarray:
        """Each third keeps the full vector's layout with everything outside its columns zeroed,
        so a third compares directly with a full-image descriptor."""
        return self._thirds(*self._parts(self._thumbs(images)))

    def _thirds(self, t: np.ndarray, gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
        rows = [self._join(t, gx, gy)]
        for a, b in third_bounds(t.shape[2]):
            keep = np.zeros(t.shape[2], dtype=np.float32)
            keep[a:b] = 1.0
            rows.append(self._join(t * keep, gx * keep[:-1] * keep[1:], gy * keep))
        return np.stack(rows, axis=1)

    def describe_with_columns(self, images: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """``(describe_thirds(images), column profiles (N, W, 2H - 1))``: per thumbnail column its
        pixels and vertical gradients, unit length (:mod:`descriptors.columns`)."""
        t, gx, gy = self._parts(self._thumbs(images))
        columns = np.concatenate([t, gy], axis=1).transpose(0, 2, 1)
        return self._thirds(t, gx, gy), l2_normalise(columns)

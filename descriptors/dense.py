"""Descriptors made of a dense local-feature extractor and an aggregation.

:class:`DenseVlad` is AnyLoc's recipe for any extractor (EfficientNet-Lite0 blocks here, DINOv2
value facets in :mod:`descriptors.dinov2`): unit-length local features, a VLAD vocabulary
fitted on the map's own keyframes, hard assignment, intra-normalisation, final L2.
:class:`DenseMeanPool` is the trivial baseline (global average pooling of the same features) so
that benchmarks show what VLAD adds.

An *extractor* is any object with ``__call__(images) -> (N, H', W', C)`` unit-length features,
``feature_dim`` and ``settings`` (a JSON-able dict of everything that changes its features).
The thirds of an image are the Left / Middle / Right thirds of the feature map's columns, so one
forward pass gives the full view and its three thirds (:meth:`describe_thirds`), and with them the
view's column profile (:meth:`describe_with_columns`, :mod:`descriptors.columns`).
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from descriptors.base import DescriptorError, DescriptorIdentity, check_state_matches
from descriptors.columns import column_profiles
from descriptors.preprocess import third_bounds, to_rgb_batch
from descriptors.vlad import VladVocabulary, l2_normalise


class DenseVlad:
    """VLAD over dense local features (implements :class:`descriptors.base.Descriptor`)."""

    def __init__(self, backend: str, extractor, num_clusters: int = 32, seed: int = 0,
                 max_features: int = 100_000):
        self.backend = backend
        self.extractor = extractor
        self.vocabulary = VladVocabulary(num_clusters=num_clusters, seed=seed, max_features=max_features)

    # -- identity and state ---------------------------------------------------------------------
    @property
    def settings(self) -> dict:
        return {**self.extractor.settings, "clusters": self.vocabulary.num_clusters,
                "seed": self.vocabulary.seed, "max_features": self.vocabulary.max_features}

    @property
    def identity(self) -> DescriptorIdentity:
        return DescriptorIdentity(self.backend, self.settings, self.vocabulary.sha256(), self.vocabulary.dim)

    @property
    def needs_fit(self) -> bool:
        return not self.vocabulary.fitted

    def state_dict(self) -> dict:
        state = {"backend": self.backend, "settings": self.settings}
        if self.vocabulary.fitted:
            state["vlad_centres"] = self.vocabulary.centres.copy()
        return state

    def load_state(self, state: Mapping[str, object]) -> None:
        check_state_matches(state, self.backend, self.settings)
        centres = state.get("vlad_centres")
        if centres is None:
            raise DescriptorError("descriptor state holds no VLAD vocabulary (vlad_centres)")
        centres = np.asarray(centres)
        if centres.ndim != 2 or centres.shape[1] != self.extractor.feature_dim:
            raise DescriptorError(f"VLAD centres of shape {centres.shape} do not fit local features of "
                                  f"dimension {self.extractor.feature_dim}")
        self.vocabulary.load({"centres": centres})

    # -- work -------------------------------------------------------------------------------------
    def local_features(self, images: Sequence[np.ndarray]) -> np.ndarray:
        return self.extractor(to_rgb_batch(images))

    def fit(self, images: Sequence[np.ndarray]) -> None:
        self.vocabulary.fit(self.local_features(images))

    def fit_features(self, maps: np.ndarray) -> None:
        """Fit from local features already extracted (benchmarks reuse one extraction)."""
        self.vocabulary.fit(maps)

    def describe(self, images: Sequence[np.ndarray]) -> np.ndarray:
        return self.aggregate(self.local_features(images))

    def describe_thirds(self, images: Sequence[np.ndarray]) -> np.ndarray:
        return self.aggregate_thirds(self.local_features(images))

    def describe_with_columns(self, images: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """``(describe_thirds(images), column profiles (N, W, C))`` from one forward pass."""
        maps = self.local_features(images)
        return self.aggregate_thirds(maps), column_profiles(maps)

    def aggregate(self, maps: np.ndarray) -> np.ndarray:
        if not self.vocabulary.fitted:
            raise DescriptorError(f"{self.backend}: the VLAD vocabulary is not fitted; call fit() on the "
                                  "map's keyframes first, or load the map's descriptor state")
        return self.vocabulary.aggregate(maps)

    def aggregate_thirds(self, maps: np.ndarray) -> np.ndarray:
        if not self.vocabulary.fitted:
            raise DescriptorError(f"{self.backend}: the VLAD vocabulary is not fitted; call fit() first")
        w = maps.shape[2]
        if w < 3:
            raise DescriptorError(f"{self.backend}: a feature map {w} columns wide cannot be split in thirds")
        ranges = [(0, w)] + third_bounds(w)
        return self.vocabulary.aggregate(maps, ranges)


class DenseMeanPool:
    """Global average pooling of the same dense features: the trivial baseline. Needs no fit."""

    def __init__(self, backend: str, extractor):
        self.backend = backend
        self.extractor = extractor

    @property
    def settings(self) -> dict:
        return dict(self.extractor.settings)

    @property
    def identity(self) -> DescriptorIdentity:
        return DescriptorIdentity(self.backend, self.settings, "", self.extractor.feature_dim)

    needs_fit = False

    def fit(self, images: Sequence[np.ndarray]) -> None:
        """Nothing to learn."""

    def fit_features(self, maps: np.ndarray) -> None:
        """Nothing to learn."""

    def state_dict(self) -> dict:
        return {"backend": self.backend, "settings": self.settings}

    def load_state(self, state: Mapping[str, object]) -> None:
        check_state_matches(state, self.backend, self.settings)

    def local_features(self, images: Sequence[np.ndarray]) -> np.ndarray:
        return self.extractor(to_rgb_batch(images))

    def describe(self, images: Sequence[np.ndarray]) -> np.ndarray:
        return self.aggregate(self.local_features(images))

    def describe_thirds(self, images: Sequence[np.ndarray]) -> np.ndarray:
        return self.aggregate_thirds(self.local_features(images))

    def describe_with_columns(self, images: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """``(describe_thirds(images), column profiles (N, W, C))`` from one forward pass."""
        maps = self.local_features(images)
        return self.aggregate_thirds(maps), column_profiles(maps)

    @staticmethod
    def aggregate(maps: np.ndarray) -> np.ndarray:
        return l2_normalise(maps.mean(axis=(1, 2)))

    @staticmethod
    def aggregate_thirds(maps: np.ndarray) -> np.ndarray:
        w = maps.shape[2]
        ranges = [(0, w)] + third_bounds(w)
        return np.stack([l2_normalise(maps[:, :, a:b].mean(axis=(1, 2))) for a, b in ranges], axis=1)

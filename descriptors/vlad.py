"""VLAD aggregation as AnyLoc does it: a vocabulary of cluster centres from cosine k-means on
L2-normalised local features, hard assignment, residuals summed per cluster, each cluster block
L2-normalised (intra-normalisation), then the whole vector L2-normalised. No power norm.

Local features arrive as dense maps (N, H, W, C). Sums are kept per feature-map column so that
any range of columns (an image third) is aggregated from the same single pass: the residual sum
of cluster k over a column range is ``sum(features assigned to k) - count_k * centre_k``.
"""

from __future__ import annotations

import hashlib
from typing import Mapping, Sequence

import numpy as np

from descriptors.base import DescriptorError

_EPS = 1e-12


def l2_normalise(x: np.ndarray, axis: int = -1) -> np.ndarray:
    """Rows of unit length along ``axis``; all-zero rows stay zero."""
    norm = np.linalg.norm(x, axis=axis, keepdims=True)
    return (x / np.maximum(norm, _EPS)).astype(np.float32, copy=False)


def cosine_kmeans(features: np.ndarray, num_clusters: int, seed: int, iterations: int = 50) -> np.ndarray:
    """(K, C) unit-length centres of the unit-length rows of ``features`` (M, C).

    k-means++ seeding on the cosine distance with ``np.random.default_rng(seed)``, then Lloyd
    steps (assign by largest dot product, centre = normalised mean) until assignments settle or
    ``iterations`` run out. An emptied cluster is re-seeded with the worst-explained feature.
    """
    x = l2_normalise(np.asarray(features, dtype=np.float32))
    m = x.shape[0]
    if m < num_clusters:
        raise DescriptorError(f"VLAD needs at least {num_clusters} local features to fit {num_clusters} "
                              f"clusters, got {m}; fit on more or larger images")
    rng = np.random.default_rng(seed)
    centres = np.empty((num_clusters, x.shape[1]), dtype=np.float32)
    centres[0] = x[rng.integers(m)]
    best = 1.0 - x @ centres[0]
    for k in range(1, num_clusters):
        p = np.maximum(best, 0.0) ** 2
        total = p.sum()
        idx = rng.choice(m, p=p / total) if total > 0 else rng.integers(m)
        centres[k] = x[idx]
        best = np.minimum(best, 1.0 - x @ centres[k])
    labels = None
    for _ in range(iterations):
        sims = x @ centres.T
        new_labels = sims.argmax(axis=1)
        if labels is not None and np.array_equal(new_labels, labels):
            break
        labels = new_labels
        # per-cluster sums as one product (np.add.at took most of a small map's fit time)
        sums = (labels[:, None] == np.arange(num_clusters)).astype(np.float32).T @ x
        counts = np.bincount(labels, minlength=num_clusters)
        for k in np.flatnonzero(counts == 0):
            worst = int(sims[np.arange(m), labels].argmin())
            sums[k] = x[worst]
            labels[worst] = k
        centres = l2_normalise(sums)
    return centres


class VladVocabulary:
    """The cluster centres and the aggregation. ``fit`` first, then ``aggregate``.

    ``num_clusters``: K (AnyLoc uses 32); ``seed``: k-means seeding; ``max_features``: at most
    this many local features (chosen with the same seed) are clustered, to bound fit time.
    """

    def __init__(self, num_clusters: int = 32, seed: int = 0, max_features: int = 100_000):
        if num_clusters < 1:
            raise DescriptorError(f"VLAD num_clusters must be at least 1, got {num_clusters}")
        self.num_clusters = int(num_clusters)
        self.seed = int(seed)
        self.max_features = int(max_features)
        self.centres: np.ndarray | None = None

    @property
    def fitted(self) -> bool:
        return self.centres is not None

    @property
    def dim(self) -> int:
        """Descriptor length K * C (0 before fitting)."""
        return 0 if self.centres is None else int(self.centres.size)

    def fit(self, features: np.ndarray) -> None:
        """Learn the centres from local features (M, C) or maps (N, H, W, C)."""
        x = np.asarray(features, dtype=np.float32)
        x = x.reshape(-1, x.shape[-1])
        if x.shape[0] > self.max_features:
            keep = np.random.default_rng(self.seed).choice(x.shape[0], self.max_features, replace=False)
            x = x[np.sort(keep)]
        self.centres = cosine_kmeans(x, self.num_clusters, self.seed)

    def aggregate(self, maps: np.ndarray, column_ranges: Sequence[tuple[int, int]] | None = None) -> np.ndarray:
        """VLAD vectors of feature maps (N, H, W, C).

        Without ``column_ranges``: (N, K*C) for the whole maps. With ranges [(start, stop), ...]
        of map columns: (N, R, K*C), one vector per range, all from one assignment pass.
        """
        centres = self._require_centres()
        maps = np.asarray(maps, dtype=np.float32)
        if maps.ndim != 4 or maps.shape[-1] != centres.shape[1]:
            raise DescriptorError(f"VLAD expects feature maps (N, H, W, {centres.shape[1]}), got {maps.shape}")
        x = l2_normalise(maps)
        n, h, w, c = x.shape
        k = self.num_clusters
        labels = (x.reshape(-1, c) @ centres.T).argmax(axis=1).reshape(n, h, w)
        onehot = np.zeros((n, h, w, k), dtype=np.float32)
        np.put_along_axis(onehot, labels[..., None], 1.0, axis=3)
        if column_ranges is None:
            sums = np.einsum("nhwk,nhwc->nkc", onehot, x, optimize=True)
            return self._finish(sums, onehot.sum(axis=(1, 2)))
        col_sums = np.einsum("nhwk,nhwc->nwkc", onehot, x, optimize=True)
        col_counts = onehot.sum(axis=1)
        out = np.empty((n, len(column_ranges), k * c), dtype=np.float32)
        for r, (start, stop) in enumerate(column_ranges):
            if not 0 <= start < stop <= w:
                raise DescriptorError(f"column range {(start, stop)} is outside a map {w} columns wide")
            out[:, r] = self._finish(col_sums[:, start:stop].sum(axis=1), col_counts[:, start:stop].sum(axis=1))
        return out

    def _finish(self, sums: np.ndarray, counts: np.ndarray) -> np.ndarray:
        """Residual sums (N, K, C) -> intra-normalised, flattened, L2-normalised (N, K*C)."""
        residuals = sums - counts[..., None] * self.centres[None]
        # A cluster that no feature chose keeps an all-zero block (l2_normalise leaves it zero).
        vlad = l2_normalise(residuals, axis=2).reshape(sums.shape[0], -1)
        return l2_normalise(vlad)

    def _require_centres(self) -> np.ndarray:
        if self.centres is None:
            raise DescriptorError("the VLAD vocabulary is not fitted: call fit() on the map's keyframes first")
        return self.centres

    def sha256(self) -> str:
        """Hash of the centres (shape and little-endian float32 bytes); "" before fitting."""
        if self.centres is None:
            return ""
        c = np.ascontiguousarray(self.centres, dtype="<f4")
        return hashlib.sha256(f"{c.shape}".encode() + c.tobytes()).hexdigest()

    def state(self) -> dict:
        """Settings and centres (None before fitting) as plain Python and numpy values."""
        return {"num_clusters": self.num_clusters, "seed": self.seed, "max_features": self.max_features,
                "centres": None if self.centres is None else self.centres.copy()}

    def load(self, state: Mapping[str, object]) -> None:
        """Restore from :meth:`state`; the centre count and dimension are checked."""
        centres = state.get("centres")
        if centres is None:
            self.centres = None
            return
        c = np.asarray(centres, dtype=np.float32)
        if c.ndim != 2 or c.shape[0] != self.num_clusters:
            raise DescriptorError(f"VLAD state holds centres of shape {c.shape}, expected ({self.num_clusters}, C)")
        if not np.all(np.isfinite(c)):
            raise DescriptorError("VLAD state holds non-finite centres")
        self.centres = np.ascontiguousarray(c)

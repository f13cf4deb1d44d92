"""The one descriptor interface: RGB images in, L2-normalised float32 vectors out.

Similarity between two images is the dot product (cosine) of their descriptors. A backend
may need a vocabulary (VLAD): ``fit`` learns it from a set of images, ``state_dict`` /
``load_state`` carry it, and :class:`DescriptorIdentity` names the backend, its settings and a
hash of the vocabulary so that a map can refuse a descriptor that does not match it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Protocol, Sequence, runtime_checkable

import numpy as np


class DescriptorError(ValueError):
    """Bad input to a descriptor (empty batch, unreadable or too small image, missing weights)."""


@dataclass(frozen=True)
class DescriptorIdentity:
    """What a descriptor is: two descriptors are comparable only when identities are equal."""

    backend: str                      # e.g. "effnet-vlad", "anyloc-dinov2", "tiny" (see factory.py)
    settings: Mapping[str, object] = field(default_factory=dict)   # layer, resolution, clusters, ...
    vocabulary_sha256: str = ""       # hash of the fitted vocabulary ("" when there is none)
    dim: int = 0

    def to_dict(self) -> dict:
        return {"backend": self.backend, "settings": dict(self.settings),
                "vocabulary_sha256": self.vocabulary_sha256, "dim": self.dim}

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> "DescriptorIdentity":
        return cls(backend=str(data["backend"]), settings=dict(data.get("settings", {})),
                   vocabulary_sha256=str(data.get("vocabulary_sha256", "")), dim=int(data.get("dim", 0)))

    def mismatch(self, other: "DescriptorIdentity") -> str | None:
        """A human sentence saying how ``other`` differs from this identity, or ``None``."""
        if self.backend != other.backend:
            return f"descriptor backend {other.backend!r} does not match {self.backend!r}"
        if dict(self.settings) != dict(other.settings):
            return f"descriptor settings {dict(other.settings)} do not match {dict(self.settings)}"
        if self.vocabulary_sha256 != other.vocabulary_sha256:
            return (f"vocabulary hash {other.vocabulary_sha256[:12]} does not match "
                    f"{self.vocabulary_sha256[:12]}")
        if self.dim != other.dim:
            return f"descriptor dimension {other.dim} does not match {self.dim}"
        return None


def check_state_matches(state: Mapping[str, object], backend: str, settings: Mapping[str, object]) -> None:
    """Raise :class:`DescriptorError` unless a saved ``state`` is for ``backend`` with ``settings``."""
    saved = state.get("backend")
    if saved != backend:
        raise DescriptorError(f"descriptor state is for backend {saved!r}, this descriptor is {backend!r}")
    saved_settings = dict(state.get("settings") or {})
    if saved_settings != dict(settings):
        raise DescriptorError(f"descriptor state settings {saved_settings} do not match {dict(settings)}")


@runtime_checkable
class Descriptor(Protocol):
    """A place descriptor backend."""

    @property
    def identity(self) -> DescriptorIdentity: ...

    @property
    def needs_fit(self) -> bool:
        """True when :meth:`fit` must run before :meth:`describe` (VLAD without a vocabulary)."""
        ...

    def fit(self, images: Sequence[np.ndarray]) -> None:
        """Learn the vocabulary from RGB uint8 images (H, W, 3)."""
        ...

    def describe(self, images: Sequence[np.ndarray]) -> np.ndarray:
        """(N, D) float32, every row L2-normalised, for N RGB uint8 images of any size."""
        ...

    def describe_thirds(self, images: Sequence[np.ndarray]) -> np.ndarray:
        """(N, 4, D): the full image, then its Left, Middle and Right vertical thirds."""
        ...

    # Optional: ``describe_with_columns(images) -> (describe_thirds(images), (N, W, C) column
    # profiles)`` for steering by bearing (:mod:`descriptors.columns`; :func:`has_columns`).

    def state_dict(self) -> dict:
        """Everything needed to rebuild the fitted descriptor (settings and vocabulary)."""
        ...

    def load_state(self, state: Mapping[str, object]) -> None:
        """Restore from :meth:`state_dict`; raises :class:`DescriptorError` on a mismatch."""
        ...


def has_columns(descriptor: object) -> bool:
    """Whether ``descriptor`` gives column profiles with its thirds (``describe_with_columns``)."""
    return callable(getattr(descriptor, "describe_with_columns", None))

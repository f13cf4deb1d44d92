"""Dense local features from mid-level blocks of EfficientNet-Lite0 (ImageNet weights).

Every image is resized to one fixed ``input_width_px`` x ``input_height_px`` (aspect not kept,
so a batch is one tensor and references and queries see the same geometry), normalised as the
Lite weights expect, and run up to the deepest chosen block. When several blocks are chosen,
each block's map is L2-normalised per location, finer maps are average-pooled to the coarsest
grid, and the maps are concatenated along channels. The result is L2-normalised per location.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import torch
from torch.nn import functional as F

from descriptors.base import DescriptorError
from descriptors.efficientnet_lite import load_efficientnet_lite0
from descriptors.efficientnet_lite_spec import (
    INPUT_MEAN,
    INPUT_STD,
    block_channels,
    block_stride,
    packaged_weights_path,
)
from descriptors.preprocess import resize_rgb


class EffNetExtractor:
    """Callable: list of RGB uint8 images -> (N, H', W', C) float32 unit-length local features."""

    def __init__(self, blocks: Sequence[int] = (10,), input_width_px: int = 320, input_height_px: int = 240,
                 weights: str | Path | None = None, batch_size: int = 16):
        self.blocks = tuple(sorted(set(int(b) for b in blocks)))
        if not self.blocks or self.blocks[0] < 0 or self.blocks[-1] > 15:
            raise DescriptorError(f"EfficientNet-Lite0 blocks must be in 0..15, got {list(blocks)}")
        coarsest = max(block_stride(b) for b in self.blocks)
        if input_width_px < coarsest or input_height_px < coarsest:
            raise DescriptorError(f"input {input_width_px}x{input_height_px} px is smaller than the stride "
                                  f"{coarsest} of block {self.blocks[-1]}")
        self.input_size = (int(input_width_px), int(input_height_px))
        self.batch_size = int(batch_size)
        self.weights_path = Path(weights) if weights is not None else packaged_weights_path()
        self._net = None  # loaded on first use, so building a descriptor from a state is cheap

    @property
    def feature_dim(self) -> int:
        return sum(block_channels(b) for b in self.blocks)

    @property
    def settings(self) -> dict:
        """What changes the features: blocks, input size and the weights file name."""
        return {"blocks": list(self.blocks), "input_width_px": self.input_size[0],
                "input_height_px": self.input_size[1], "weights": self.weights_path.name}

    def grid_shape(self) -> tuple[int, int]:
        """(rows, columns) of the feature map for the configured input size."""
        stride = max(block_stride(b) for b in self.blocks)
        w, h = self.input_size
        return -(-h // stride), -(-w // stride)

    def network(self):
        if self._net is None:
            self._net = load_efficientnet_lite0(self.weights_path)
        return self._net

    def to_tensor(self, images: Sequence[np.ndarray]) -> torch.Tensor:
        """(N, 3, H, W) normalised float tensor of already-checked RGB uint8 images."""
        w, h = self.input_size
        batch = np.stack([resize_rgb(img, w, h) for img in images]).astype(np.float32) / 255.0
        batch = (batch - np.asarray(INPUT_MEAN, np.float32)) / np.asarray(INPUT_STD, np.float32)
        return torch.from_numpy(batch).permute(0, 3, 1, 2).contiguous()

    @torch.inference_mode()
    def __call__(self, images: Sequence[np.ndarray]) -> np.ndarray:
        net = self.network()
        out = []
        for start in range(0, len(images), self.batch_size):
            maps = net.block_outputs(self.to_tensor(images[start:start + self.batch_size]), self.blocks)
            out.append(self._combine([maps[b] for b in self.blocks]).numpy())
        return np.concatenate(out, axis=0)

    @staticmethod
    def _combine(maps: list[torch.Tensor]) -> torch.Tensor:
        rows = min(m.shape[2] for m in maps)
        cols = min(m.shape[3] for m in maps)
        parts = []
        for m in maps:
            if m.shape[2:] != (rows, cols):
                m = F.adaptive_avg_pool2d(m, (rows, cols))
            parts.append(F.normalize(m, dim=1))
        x = torch.cat(parts, dim=1) if len(parts) > 1 else parts[0]
        return F.normalize(x, dim=1).permute(0, 2, 3, 1).contiguous()

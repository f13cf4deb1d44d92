"""The torch side of the EfficientNet-Lite0 extractor: the chosen blocks' maps combined into unit
local features, as one module (run eagerly by the torch engine, exported to ONNX for the other)."""

from __future__ import annotations

from typing import Sequence

import torch
from torch import nn
from torch.nn import functional as F


class CombinedBlocks(nn.Module):
    """(N, 3, H, W) normalised images -> (N, H', W', C) unit-length local features: each chosen
    block's map L2-normalised per location, finer maps average-pooled to the coarsest grid,
    concatenated along channels and normalised again."""

    def __init__(self, net: nn.Module, blocks: Sequence[int]):
        super().__init__()
        self.net = net
        self.blocks = tuple(blocks)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        found = self.net.block_outputs(x, self.blocks)
        maps = [found[b] for b in self.blocks]
        rows = min(m.shape[2] for m in maps)
        cols = min(m.shape[3] for m in maps)
        parts = []
        for m in maps:
            if m.shape[2:] != (rows, cols):
                m = F.adaptive_avg_pool2d(m, (rows, cols))
            parts.append(F.normalize(m, dim=1))
        out = torch.cat(parts, dim=1) if len(parts) > 1 else parts[0]
        return F.normalize(out, dim=1).permute(0, 2, 3, 1).contiguous()

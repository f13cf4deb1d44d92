"""Dense local features from mid-level blocks of EfficientNet-Lite0 (ImageNet weights).

Every image is resized to one fixed ``input_width_px`` x ``input_height_px`` (aspect not kept,
so a batch is one tensor and references and queries see the same geometry), normalised as the
Lite weights expect, and run up to the deepest chosen block. When several blocks are chosen,
each block's map is L2-normalised per location, finer maps are average-pooled to the coarsest
grid, and the maps are concatenated along channels. The result is L2-normalised per location.

The network runs in ONNX Runtime (default) or torch (``engine``, :mod:`descriptors.inference`):
the same graph from the same weights, so the engine is no part of the descriptor's identity.
torch is imported only to export the graph once, or to run the torch engine.

``precision: int8`` (ONNX Runtime only) runs the graph quantised to int8, its activation ranges
calibrated on :data:`CALIBRATION_DIR`'s frames (a rendered hospital walkthrough, shipped with
the package, so every machine quantises alike). Its features differ from fp32 ones (a cosine of
about 0.98 per location), so the precision is part of the identity: a map records it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from core.validate import check_count
from descriptors.base import DescriptorError
from descriptors.efficientnet_lite_spec import (
    INPUT_MEAN,
    INPUT_STD,
    block_channels,
    block_stride,
    packaged_weights_path,
)
from descriptors.inference import GRAPH_VERSION, OnnxNet, check_engine, export_torch_module, file_sha256, quantize_int8
from descriptors.preprocess import resize_rgb

PRECISIONS = ("fp32", "int8")
#: the int8 graph's calibration frames (320x240 JPEGs of the hospital walkthrough, appearance 0)
CALIBRATION_DIR = Path(__file__).resolve().parent / "calibration"


class EffNetExtractor:
    """Callable: list of RGB uint8 images -> (N, H', W', C) float32 unit-length local features."""

    def __init__(self, blocks: Sequence[int] = (10,), input_width_px: int = 320, input_height_px: int = 240,
                 weights: str | Path | None = None, batch_size: int = 16, engine: Optional[str] = None,
                 threads: Optional[int] = None, providers: Optional[Sequence[str]] = None,
                 precision: str = "fp32"):
        for name, value, least in (("input_width_px", input_width_px, 8), ("input_height_px", input_height_px, 8),
                                   ("batch_size", batch_size, 1)):
            check_count(name, value, least, error=DescriptorError)
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
        self.engine = check_engine(engine)
        if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int) or threads < 1):
            raise DescriptorError(f"threads must be an integer >= 1, got {threads!r}")
        if providers is not None and (isinstance(providers, str) or not all(isinstance(p, str) for p in providers)):
            raise DescriptorError(f"providers must be a list of ONNX Runtime execution provider names, got "
                                  f"{providers!r}")
        if precision not in PRECISIONS:
            raise DescriptorError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
        if precision == "int8" and self.engine != "onnxruntime":
            raise DescriptorError("precision int8 runs in ONNX Runtime only: set engine: onnxruntime")
        self.precision = precision
        self.threads = threads
        self.providers = None if providers is None else tuple(providers)
        self._net = None   # loaded on first use, so building a descriptor from a state is cheap
        self._onnx: Optional[OnnxNet] = None

    @property
    def feature_dim(self) -> int:
        return sum(block_channels(b) for b in self.blocks)

    @property
    def settings(self) -> dict:
        """What changes the features: blocks, input size, the weights file name and (when not
        fp32, so that fp32 identities stay as they were) the precision."""
        out = {"blocks": list(self.blocks), "input_width_px": self.input_size[0],
               "input_height_px": self.input_size[1], "weights": self.weights_path.name}
        if self.precision != "fp32":
            out["precision"] = self.precision
        return out

    @property
    def runtime(self) -> dict:
        """How the features are computed (not what they are): engine, threads, providers."""
        return {"engine": self.engine, "threads": self.threads,
                "providers": None if self.providers is None else list(self.providers)}

    def grid_shape(self) -> tuple[int, int]:
        """(rows, columns) of the feature map for the configured input size."""
        stride = max(block_stride(b) for b in self.blocks)
        w, h = self.input_size
        return -(-h // stride), -(-w // stride)

    def network(self):
        """The torch network (loaded once; the torch engine, and the ONNX export)."""
        if self._net is None:
            from descriptors.efficientnet_lite import load_efficientnet_lite0

            self._net = load_efficientnet_lite0(self.weights_path)
        return self._net

    def normalised(self, images: Sequence[np.ndarray]) -> np.ndarray:
        """(N, 3, H, W) normalised float32 batch of already-checked RGB uint8 images."""
        w, h = self.input_size
        batch = np.stack([resize_rgb(img, w, h) for img in images]).astype(np.float32) / 255.0
        batch = (batch - np.asarray(INPUT_MEAN, np.float32)) / np.asarray(INPUT_STD, np.float32)
        return np.ascontiguousarray(batch.transpose(0, 3, 1, 2))

    def __call__(self, images: Sequence[np.ndarray]) -> np.ndarray:
        run = self._run_onnx if self.engine == "onnxruntime" else self._run_torch
        out = [run(self.normalised(images[start:start + self.batch_size]))
               for start in range(0, len(images), self.batch_size)]
        return np.concatenate(out, axis=0)

    def _run_torch(self, batch: np.ndarray) -> np.ndarray:
        import torch

        from descriptors.effnet_torch import CombinedBlocks

        with torch.inference_mode():
            return CombinedBlocks(self.network(), self.blocks)(torch.from_numpy(batch)).numpy()

    def onnx_net(self) -> OnnxNet:
        """The exported graph of these blocks, input size, weights and precision (made on first use)."""
        if self._onnx is None:
            self._onnx = OnnxNet(self._graph_name(self.precision), self._make_graph, threads_=self.threads,
                                 providers=self.providers)
        return self._onnx

    def _graph_name(self, precision: str) -> str:
        w, h = self.input_size
        return (f"effnet-lite0_b{'-'.join(map(str, self.blocks))}_{w}x{h}_{file_sha256(self.weights_path)[:16]}"
                f"_g{GRAPH_VERSION}{'' if precision == 'fp32' else '_' + precision}.onnx")

    def _make_graph(self, path: Path) -> None:
        if self.precision == "fp32":
            self._export_fp32(path)
            return
        fp32 = OnnxNet(self._graph_name("fp32"), self._export_fp32)
        if not fp32.path.is_file():
            self._export_fp32(fp32.path)
        quantize_int8(fp32.path, path, [self.normalised([frame]) for frame in calibration_frames()])

    def _export_fp32(self, path: Path) -> None:
        from descriptors.effnet_torch import CombinedBlocks

        w, h = self.input_size
        export_torch_module(CombinedBlocks(self.network(), self.blocks), np.zeros((1, 3, h, w), np.float32), path)

    def _run_onnx(self, batch: np.ndarray) -> np.ndarray:
        return self.onnx_net()(batch)


def calibration_frames() -> list[np.ndarray]:
    """The int8 calibration frames (RGB uint8), in name order."""
    import cv2

    files = sorted(CALIBRATION_DIR.glob("*.jpg"))
    if not files:
        raise DescriptorError(f"no calibration frames in {CALIBRATION_DIR} (a damaged installation?)")
    return [cv2.cvtColor(cv2.imread(str(f), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB) for f in files]

"""Where the dense CNN runs: torch eager, or the same network exported to ONNX and run by ONNX
Runtime (the default when ``onnxruntime`` is installed, which the package's dependencies make
true).

The engine changes speed, not features: both compute the same graph from the same weights
(outputs agree to about 1e-6), so it is no part of a descriptor's identity and a map built with
one engine navigates with the other.

The ONNX graph is exported from the weights on first use (offline; the exporter is
deterministic) into a cache folder, ``$LIMO_TOPONAV_CACHE/onnx`` (default
``$XDG_CACHE_HOME/limo-toponav`` or ``~/.cache/limo-toponav``), named by the weights' SHA-256,
the blocks and the input size, so a change of any of them exports a new graph, and reused
afterwards. Threads: :func:`set_threads` sets the process's budget for both engines (the paper
harness's workers use one thread each; unset, ONNX Runtime takes half the cores,
:func:`default_onnx_threads`); a descriptor's own ``threads`` setting overrides it.
Execution providers are a setting too: ``providers: [CUDAExecutionProvider,
CPUExecutionProvider]`` runs on a GPU where ONNX Runtime has one (a Jetson: the CUDA or TensorRT
provider of its ONNX Runtime build); providers the installed ONNX Runtime lacks are skipped.
"""

from __future__ import annotations

import hashlib
import io
import os
import sys
import warnings
from pathlib import Path
from typing import Callable, Optional, Sequence

import numpy as np

from core.atomic import write_bytes
from descriptors.base import DescriptorError

ENGINES = ("onnxruntime", "torch")
#: bump when the exported graph changes for the same weights, blocks and size (2: int8 weights
#: in 7 bits, see :func:`quantize_int8`)
GRAPH_VERSION = 2
OPSET = 17
DEFAULT_PROVIDERS = ("CPUExecutionProvider",)

_threads: Optional[int] = None


def set_threads(n: Optional[int]) -> None:
    """The number of threads inference may use in this process (None: each engine's default,
    all cores); applies to torch at once and to ONNX Runtime sessions made from now on."""
    global _threads
    if n is not None and (isinstance(n, bool) or not isinstance(n, int) or n < 1):
        raise DescriptorError(f"threads must be an integer >= 1 or None, got {n!r}")
    _threads = n
    if n is not None and "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(n)


def threads() -> Optional[int]:
    """The process's inference thread budget (None: the engines' defaults)."""
    return _threads


def default_onnx_threads() -> int:
    """ONNX Runtime's threads when nothing is set: half the cores, at least one. The rest of the
    control step (camera, rendering in simulation, physics, mapping's video decoding) runs beside
    the network; measured on 2 cores, one thread described a frame in the loop in 21-27 ms and
    two in 34 ms, and mapped a video at 31-37 frames/s against 25."""
    return max(1, (os.cpu_count() or 2) // 2)


def onnxruntime_available() -> bool:
    try:
        import onnxruntime  # noqa: F401
    except ImportError:
        return False
    return True


def default_engine() -> str:
    return "onnxruntime" if onnxruntime_available() else "torch"


def check_engine(engine: Optional[str]) -> str:
    """The engine to use for a setting (None: :func:`default_engine`)."""
    if engine is None:
        return default_engine()
    if engine not in ENGINES:
        raise DescriptorError(f"engine must be one of {', '.join(ENGINES)}, got {engine!r}")
    if engine == "onnxruntime" and not onnxruntime_available():
        raise DescriptorError("engine 'onnxruntime' needs the package onnxruntime (pip install onnxruntime), "
                              "or set the descriptor setting engine: torch")
    return engine


def cache_dir() -> Path:
    """Where exported graphs are kept (see the module docstring)."""
    root = os.environ.get("LIMO_TOPONAV_CACHE")
    if root:
        return Path(root)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "limo-toponav"


def file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


class OnnxNet:
    """An exported network run by ONNX Runtime: ``__call__(batch (N, 3, H, W) float32) -> array``.

    ``export(path)`` writes the ONNX graph (called once, when the cached file is missing);
    ``name`` is the cache file's name, which must change whenever the graph would.
    """

    def __init__(self, name: str, export: Callable[[Path], None], threads_: Optional[int] = None,
                 providers: Optional[Sequence[str]] = None):
        self.path = cache_dir() / "onnx" / name
        self._export = export
        self.threads = threads_
        self.providers = tuple(providers) if providers else DEFAULT_PROVIDERS
        self._session = None

    def session(self):
        if self._session is None:
            import onnxruntime as ort

            if not self.path.is_file():
                self._export(self.path)
            options = ort.SessionOptions()
            n = self.threads if self.threads is not None else threads()
            options.intra_op_num_threads = n if n is not None else default_onnx_threads()
            options.inter_op_num_threads = 1
            options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
            available = set(ort.get_available_providers())
            providers = [p for p in self.providers if p in available]
            if not providers:
                raise DescriptorError(f"none of the execution providers {list(self.providers)} is available in "
                                      f"this ONNX Runtime (available: {sorted(available)})")
            try:
                self._session = ort.InferenceSession(str(self.path), options, providers=providers)
            except Exception as exc:          # a damaged cache file: export again, once
                self.path.unlink(missing_ok=True)
                self._export(self.path)
                try:
                    self._session = ort.InferenceSession(str(self.path), options, providers=providers)
                except Exception:
                    raise DescriptorError(f"ONNX Runtime cannot load {self.path}: {exc}") from None
        return self._session

    def __call__(self, batch: np.ndarray) -> np.ndarray:
        session = self.session()
        return session.run(None, {session.get_inputs()[0].name: np.ascontiguousarray(batch, dtype=np.float32)})[0]


def quantize_int8(fp32: Path, path: Path, batches: Sequence[np.ndarray]) -> None:
    """The int8 graph of ``fp32`` at ``path``: ONNX Runtime's static quantisation (QDQ, int8
    weights per channel, uint8 activations) with activation ranges measured (MinMax) on
    ``batches``, the normalised network inputs of the calibration images. Weights use 7 bits
    (``reduce_range``): x86 CPUs without VNNI (AVX2, AVX-512 alone) saturate the uint8 x int8
    products otherwise, and the features drift far from fp32 (ONNX Runtime's quantisation notes)."""
    import tempfile

    from onnxruntime.quantization import (
        CalibrationDataReader,
        CalibrationMethod,
        QuantFormat,
        QuantType,
        quantize_static,
    )
    from onnxruntime.quantization.shape_inference import quant_pre_process

    class Batches(CalibrationDataReader):
        def __init__(self) -> None:
            self._left = iter({"image": np.ascontiguousarray(b, dtype=np.float32)} for b in batches)

        def get_next(self):
            return next(self._left, None)

    with tempfile.TemporaryDirectory(prefix="limo-toponav-int8-") as tmp:
        prepared, quantised = Path(tmp) / "prepared.onnx", Path(tmp) / "int8.onnx"
        quant_pre_process(str(fp32), str(prepared))
        quantize_static(str(prepared), str(quantised), Batches(), quant_format=QuantFormat.QDQ, per_channel=True,
                        activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8,
                        calibrate_method=CalibrationMethod.MinMax, reduce_range=True)
        write_bytes(path, quantised.read_bytes())


def export_torch_module(module, example: np.ndarray, path: Path) -> None:
    """Export a torch module (eval mode) to ONNX at ``path`` atomically, with a dynamic batch."""
    import torch

    buf = io.BytesIO()
    with warnings.catch_warnings(), torch.inference_mode(False), torch.no_grad():
        warnings.simplefilter("ignore")       # the exporter's notes about traced shapes
        torch.onnx.export(module.eval(), (torch.from_numpy(example),), buf, input_names=["image"],
                          output_names=["features"], dynamic_axes={"image": {0: "batch"}, "features": {0: "batch"}},
                          opset_version=OPSET, dynamo=False)
    write_bytes(path, buf.getvalue())

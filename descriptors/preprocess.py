"""Input checking and conversion for every descriptor: whatever arrives becomes RGB uint8.

Accepted per image: (H, W) grey, (H, W, 1) grey, (H, W, 3) RGB, (H, W, 4) RGBA (alpha dropped);
dtype uint8, bool, uint16 (scaled by 1/257) or float in [0, 1]. Images are RGB by convention
(cameras in this project and :func:`descriptors.imagefile.read_rgb` deliver RGB); an
OpenCV BGR array must be converted by the caller, or passed with ``channel_order="bgr"``.
Anything else raises :class:`DescriptorError` naming the image index and the problem.
"""

from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np

from descriptors.base import DescriptorError

MIN_SIDE_PX = 8  # below this an image holds no usable structure for any backend here


def to_rgb_uint8(image: object, index: int = 0, channel_order: str = "rgb") -> np.ndarray:
    """One image as a C-contiguous (H, W, 3) uint8 RGB array; raises DescriptorError if unusable."""
    where = f"image {index}"
    if not isinstance(image, np.ndarray):
        raise DescriptorError(f"{where}: expected a numpy array, got {type(image).__name__}")
    if image.ndim == 3 and image.shape[2] in (1, 3, 4):
        channels = image.shape[2]
    elif image.ndim == 2:
        channels = 0
    else:
        raise DescriptorError(f"{where}: expected shape (H, W), (H, W, 1), (H, W, 3) or (H, W, 4), "
                              f"got {image.shape}")
    h, w = image.shape[:2]
    if h < MIN_SIDE_PX or w < MIN_SIDE_PX:
        raise DescriptorError(f"{where}: {w}x{h} px is too small (at least {MIN_SIDE_PX}x{MIN_SIDE_PX} px)")
    pixels = _as_uint8(image, where)
    if channels in (0, 1):
        pixels = np.repeat(pixels.reshape(h, w, 1), 3, axis=2)
    elif channels == 4:
        pixels = pixels[:, :, :3]
    if channel_order == "bgr":
        pixels = pixels[:, :, ::-1]
    elif channel_order != "rgb":
        raise DescriptorError(f"channel_order must be 'rgb' or 'bgr', got {channel_order!r}")
    return np.ascontiguousarray(pixels)


def _as_uint8(image: np.ndarray, where: str) -> np.ndarray:
    if image.dtype == np.uint8:
        return image
    if image.dtype == np.bool_:
        return image.astype(np.uint8) * 255
    if image.dtype == np.uint16:
        return (image.astype(np.uint32) // 257).astype(np.uint8)
    if np.issubdtype(image.dtype, np.floating):
        if not np.all(np.isfinite(image)):
            raise DescriptorError(f"{where}: float image holds NaN or infinite values")
        lo, hi = float(image.min()), float(image.max())
        if lo < 0.0 or hi > 1.0:
            raise DescriptorError(f"{where}: float images must lie in [0, 1], got [{lo:.3g}, {hi:.3g}] "
                                  "(pass uint8 for 0..255 data)")
        return np.round(image * 255.0).astype(np.uint8)
    raise DescriptorError(f"{where}: unsupported dtype {image.dtype} (use uint8, uint16, bool or float in [0, 1])")


def to_rgb_batch(images: Sequence[np.ndarray] | np.ndarray, channel_order: str = "rgb") -> list[np.ndarray]:
    """A non-empty list of RGB uint8 images from a sequence or an (N, H, W[, C]) array."""
    if isinstance(images, np.ndarray):
        if images.ndim not in (3, 4):
            raise DescriptorError(f"a batch array must be (N, H, W) or (N, H, W, C), got shape {images.shape}")
        images = list(images)
    if isinstance(images, (str, bytes)) or not isinstance(images, Sequence):
        raise DescriptorError(f"expected a sequence of images, got {type(images).__name__}")
    if len(images) == 0:
        raise DescriptorError("empty batch: at least one image is needed")
    return [to_rgb_uint8(img, i, channel_order) for i, img in enumerate(images)]


def resize_rgb(image: np.ndarray, width_px: int, height_px: int) -> np.ndarray:
    """Resize to exactly width x height; area averaging when shrinking, bilinear when enlarging."""
    h, w = image.shape[:2]
    if (w, h) == (width_px, height_px):
        return image
    shrinking = width_px <= w and height_px <= h
    return cv2.resize(image, (width_px, height_px), interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)


def third_bounds(width: int) -> list[tuple[int, int]]:
    """Column ranges [start, stop) of the Left, Middle and Right thirds of ``width`` columns."""
    edges = [round(width * i / 3) for i in range(4)]
    return [(edges[i], edges[i + 1]) for i in range(3)]

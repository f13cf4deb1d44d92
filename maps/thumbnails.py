"""Node thumbnails: the small JPEG a map keeps of every node's keyframe (for pictures, goal
checks and the learned baseline), made the same way wherever a frame becomes a thumbnail."""

from __future__ import annotations

import cv2
import numpy as np

from maps.graph import MapError

#: thumbnail width, height in pixels (4:3, like the Limo camera), and JPEG quality
THUMB_SIZE = (160, 120)
THUMB_QUALITY = 80


def make_thumbnail(rgb: np.ndarray, size: tuple[int, int] = THUMB_SIZE) -> np.ndarray:
    """Centre-crop an RGB uint8 (H, W, 3) image to the aspect of ``size`` (width, height) and
    shrink it to ``size``. Keep these instead of full frames while mapping."""
    img = np.asarray(rgb)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8 or min(img.shape[:2]) < 2:
        raise MapError(f"thumbnail source must be an RGB uint8 (H, W, 3) image, got {img.dtype} {img.shape}")
    w, h = size
    ih, iw = img.shape[:2]
    if iw * h > ih * w:                      # too wide: crop the sides
        cw = max(1, int(round(ih * w / h)))
        x0 = (iw - cw) // 2
        img = img[:, x0:x0 + cw]
    else:
        ch = max(1, int(round(iw * h / w)))
        y0 = (ih - ch) // 2
        img = img[y0:y0 + ch]
    if img.shape[1] == w and img.shape[0] == h:
        return np.ascontiguousarray(img)
    return cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)


def encode_thumbnail(image: np.ndarray | bytes) -> bytes:
    """The JPEG bytes of a node thumbnail (THUMB_SIZE, THUMB_QUALITY) from an RGB uint8 image, or
    from JPEG bytes made earlier (kept as they are when already thumbnail-sized). About 5 KB a
    frame, so a mapping run can keep one for every frame until it knows the keyframes."""
    if isinstance(image, (bytes, bytearray)):
        bgr = cv2.imdecode(np.frombuffer(image, dtype=np.uint8), cv2.IMREAD_COLOR)
        if bgr is None:
            raise MapError("thumbnail bytes are not a readable JPEG")
        if bgr.shape[1::-1] == THUMB_SIZE:
            return bytes(image)
        image = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(make_thumbnail(image), cv2.COLOR_RGB2BGR),
                           [cv2.IMWRITE_JPEG_QUALITY, THUMB_QUALITY])
    if not ok:
        raise MapError("could not encode a thumbnail as JPEG")
    return buf.tobytes()

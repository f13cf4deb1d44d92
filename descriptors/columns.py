"""Column profiles: where a view's content lies from left to right, for steering by bearing.

A dense extractor's feature map ``(N, H, W, C)`` holds one feature per cell; a view's *column
profile* is, per column, the mean of its cells' unit features, itself made unit length:
``(N, W, C)``. Two views of one place taken at a slightly different heading, or a little
beside each other, have profiles that agree best at a horizontal shift; :func:`column_shift`
finds it to a fraction of a column. That shift is the bearing of the mapped view: steering to
null it turns the robot back onto the mapping drive's heading, and, since near things shift more
than far ones, back towards its line (bearing-only visual teach and repeat). Measured on the
simulator's office and hospital under other lighting: about 1.2 columns (of ten) per 10 deg
of heading and up to one column per half metre beside the line (docs/results.md).
"""

from __future__ import annotations

from typing import Tuple

import numpy as np

from descriptors.vlad import l2_normalise

#: the largest shift tried, as a fraction of the view's width (either way): beyond it too little
#: of the two views overlaps to compare
MAX_SHIFT_FRACTION = 0.4


def column_profiles(feature_maps: np.ndarray) -> np.ndarray:
    """``(N, W, C)`` unit column profiles of ``(N, H, W, C)`` feature maps (float32)."""
    maps = np.asarray(feature_maps, dtype=np.float32)
    if maps.ndim != 4:
        raise ValueError(f"feature maps must have shape (N, H, W, C), got {maps.shape}")
    return l2_normalise(l2_normalise(maps).mean(axis=1)).astype(np.float32)


def column_shift(query: np.ndarray, reference: np.ndarray,
                 max_fraction: float = MAX_SHIFT_FRACTION) -> Tuple[float, float]:
    """``(bearing, score)``: the shift that best aligns the ``(W, C)`` column profile ``query``
    with ``reference``, as a fraction of the view's width, positive when the query sees the
    reference's content further left than the reference did (the robot faces right of the way
    the reference was taken, or stands right of where: turn left); ``score`` is the mean cosine of the overlapping columns at the best whole shift. The
    shift is refined to a fraction of a column by a parabola through the neighbouring shifts."""
    q = np.asarray(query, dtype=np.float32)
    r = np.asarray(reference, dtype=np.float32)
    if q.ndim != 2 or q.shape != r.shape:
        raise ValueError(f"column profiles must be two (W, C) arrays of one shape, got {q.shape} and {r.shape}")
    width = q.shape[0]
    reach = min(width - 1, int(round(max_fraction * width)))
    scores = np.empty(2 * reach + 1)
    for k, shift in enumerate(range(-reach, reach + 1)):
        a = q[max(0, -shift):width - max(0, shift)]
        b = r[max(0, shift):width - max(0, -shift)]
        scores[k] = float(np.einsum("ij,ij->i", a, b).mean())
    best = int(np.argmax(scores))
    fraction = 0.0
    if 0 < best < len(scores) - 1:
        low, mid, high = scores[best - 1], scores[best], scores[best + 1]
        curvature = low - 2.0 * mid + high
        if curvature < 0:
            fraction = 0.5 * (low - high) / curvature
    # query column c sees what the reference saw at column c + shift
    return (best - reach + fraction) / width, float(scores[best])

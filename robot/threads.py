"""Thread pools for the 2-core control loop.

Describing one frame at batch 1 runs torch, then a numpy matrix product (VLAD assignment), then
OpenCV resizing. OpenBLAS's and OpenCV's own thread pools keep spinning after their calls and
fight torch's threads for the cores: measured here, describe_thirds of one 320x240 frame took
100 ms to 2 s instead of 28 ms. The entry points therefore give numpy (OpenBLAS) and OpenCV one
thread each and leave the cores to torch. Call :func:`limit_helper_threads` before numpy is
imported (environment variables are read when OpenBLAS loads); a user's own setting wins.
"""

from __future__ import annotations

import os

_BLAS_VARIABLES = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def limit_helper_threads() -> None:
    """One thread for OpenBLAS/MKL (unless set by the user) and for OpenCV."""
    for name in _BLAS_VARIABLES:
        os.environ.setdefault(name, "1")
    import cv2

    cv2.setNumThreads(1)

"""OpenCV's own thread pool during a run.

A run already spreads its frames over worker threads; OpenCV, by default, splits each
call again over all cores. On the small images of the per-patch work (64 x 64
phase correlations and cubic shifts, thousands a run) starting and joining its pool
costs several times the arithmetic: ``cv2.warpAffine`` of a 64 x 64 patch takes
~60 µs on one thread and ~340 µs on a busy 2-core machine with the pool (measured,
OpenCV 5.0). :func:`opencv_threads` sets the pool for the duration of a run and
restores it after, so a library caller's setting survives.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import cv2

__all__ = ["opencv_threads"]


@contextmanager
def opencv_threads(count: int) -> Iterator[None]:
    """Run the block with OpenCV's thread pool at ``count`` threads (1: none).

    ``count`` <= 0 leaves the pool as it is.
    """
    if count <= 0:
        yield
        return
    previous = cv2.getNumThreads()
    cv2.setNumThreads(count)
    try:
        yield
    finally:
        cv2.setNumThreads(previous)

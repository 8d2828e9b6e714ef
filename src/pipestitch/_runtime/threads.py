"""Worker threads of a pass: results in order, and OpenCV's own thread pool during a run.

A run already spreads its frames over worker threads; OpenCV, by default, splits each
call again over all cores. On the small images of the per-patch work (64 x 64
phase correlations and cubic shifts, thousands a run) starting and joining its pool
costs several times the arithmetic: ``cv2.warpAffine`` of a 64 x 64 patch takes
~60 µs on one thread and ~340 µs on a busy 2-core machine with the pool (measured,
OpenCV 5.0). :func:`opencv_threads` sets the pool for the duration of a run and
restores it after, so a library caller's setting survives.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import TypeVar

import cv2

from pipestitch._runtime import scratch
from pipestitch._runtime.memory import TRIM_EVERY, every_n, release_free_memory

__all__ = ["opencv_threads", "ordered_map"]

T = TypeVar("T")


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


def ordered_map(func: Callable[[int], T], indices: Iterable[int], workers: int) -> Iterator[T]:
    """``func`` over ``indices`` on ``workers`` threads, results in order (lazily).

    At most ``2 * workers`` results are computed ahead of the consumer, so memory does
    not grow with the run when the consumer is the slower side; every
    ``TRIM_EVERY`` results the heap's free pages are handed back
    (:func:`pipestitch._runtime.memory.release_free_memory`), as each frame's buffers,
    freed among the small results that outlive them, otherwise leave the heap's
    resident size growing through a pass.
    """
    yield from every_n(_in_order(func, indices, workers), TRIM_EVERY, release_free_memory)


def _in_order(func: Callable[[int], T], indices: Iterable[int], workers: int) -> Iterator[T]:
    """:func:`ordered_map`'s results, before the hand-backs."""
    if workers <= 1:
        try:
            yield from map(func, indices)
        finally:   # the frame buffers this (main) thread took (pipestitch._runtime.scratch)
            scratch.release()
        return
    with ThreadPoolExecutor(max_workers=workers) as pool:
        pending: deque = deque()
        for index in indices:
            pending.append(pool.submit(func, index))
            if len(pending) >= 2 * workers:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()

"""OpenCV's thread pool is set for a run and restored after it (pipeline/threads.py)."""

from __future__ import annotations

import cv2
import pytest

from pipestitch.pipeline.threads import opencv_threads


def test_opencv_threads_sets_the_pool_and_restores_it() -> None:
    before = cv2.getNumThreads()
    with opencv_threads(1):
        assert cv2.getNumThreads() == 1
    assert cv2.getNumThreads() == before


def test_opencv_threads_restores_the_pool_when_the_block_raises() -> None:
    before = cv2.getNumThreads()
    with pytest.raises(RuntimeError), opencv_threads(1):
        raise RuntimeError("a failing run")
    assert cv2.getNumThreads() == before


def test_opencv_threads_zero_leaves_the_pool_alone() -> None:
    before = cv2.getNumThreads()
    with opencv_threads(0):
        assert cv2.getNumThreads() == before

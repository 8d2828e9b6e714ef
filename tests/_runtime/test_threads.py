"""OpenCV's thread pool is set for a run and restored after it (_runtime/threads.py)."""

from __future__ import annotations

import cv2
import pytest

from pipestitch._runtime import threads
from pipestitch._runtime.memory import every_n
from pipestitch._runtime.threads import opencv_threads


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


def test_passes_hand_free_heap_back_every_n_frames(monkeypatch) -> None:
    """Within a pass, the ordered worker map hands the heap's free pages back every
    TRIM_EVERY results (and yields every result, in order, whatever the workers)."""
    calls: list[int] = []
    seen: list[int] = []
    assert list(every_n(iter(range(7)), 3, lambda: calls.append(len(seen)))) == list(range(7))
    assert len(calls) == 2
    calls.clear()
    monkeypatch.setattr(threads, "TRIM_EVERY", 10)
    monkeypatch.setattr(threads, "release_free_memory", lambda: calls.append(len(seen)))
    for workers in (1, 2):
        calls.clear()
        seen.clear()
        for value in threads.ordered_map(lambda i: i * i, range(35), workers):
            seen.append(value)
        assert seen == [i * i for i in range(35)]
        assert calls == [10, 20, 30]
    with pytest.raises(ValueError, match="n must be"):
        list(every_n([1], 0, lambda: None))

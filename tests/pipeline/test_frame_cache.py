"""The run's LED-frame cache: kept when the whole run fits its budget, else not at all."""

from __future__ import annotations

import threading
from collections import Counter

import numpy as np
import pytest

from pipestitch.pipeline.frame_cache import CachedLedFrames


class FakeDataset:
    """Counts reads; frames of 1000 bytes."""

    def __init__(self, n_pairs: int) -> None:
        self.n_pairs = n_pairs
        self.reads: Counter[int] = Counter()
        self.lock = threading.Lock()
        self.root = "fake"

    def read_led(self, index: int) -> np.ndarray:
        with self.lock:
            self.reads[index] += 1
        return np.full((10, 100), index, np.uint8)


def test_a_run_that_fits_is_decoded_once_per_frame() -> None:
    ds = FakeDataset(5)
    cache = CachedLedFrames(ds, budget_bytes=5000)
    for _ in range(3):
        for i in range(5):
            assert cache.read_led(i)[0, 0] == i
    assert all(ds.reads[i] == 1 for i in range(5))
    assert cache.root == "fake"                     # everything else is the dataset's
    with pytest.raises(ValueError):
        cache.read_led(0)[0, 0] = 7                 # shared frames are read-only


def test_a_run_larger_than_the_budget_is_not_cached_at_all() -> None:
    ds = FakeDataset(6)
    cache = CachedLedFrames(ds, budget_bytes=5000)  # 6 x 1000 bytes do not fit
    for _ in range(2):
        for i in range(6):
            cache.read_led(i)
    assert all(ds.reads[i] == 2 for i in range(6))
    assert cache._bytes == 0                        # memory does not grow with the run


def test_concurrent_reads_give_the_right_frames() -> None:
    ds = FakeDataset(20)
    cache = CachedLedFrames(ds, budget_bytes=10**6)
    errors = []

    def work(offset: int) -> None:
        for k in range(200):
            i = (k + offset) % 20
            if cache.read_led(i)[0, 0] != i:
                errors.append(i)

    threads = [threading.Thread(target=work, args=(t,)) for t in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    assert sum(ds.reads.values()) <= 20 * 4       # at most one decode per frame and thread

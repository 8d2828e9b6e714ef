"""The run's LED-frame cache: kept when the whole run fits its budget, else not at all."""

from __future__ import annotations

import threading
from collections import Counter
from pathlib import Path

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


class MixedDataset(FakeDataset):
    """Colour 8-bit frames and grey 16-bit ones, alternately; can be closed."""

    closed = False

    def frame(self, index: int) -> np.ndarray:
        rng = np.random.default_rng(index)
        if index % 2:
            return rng.integers(0, 65535, (12, 20), dtype=np.uint16)
        return rng.integers(0, 255, (12, 20, 3), dtype=np.uint8)

    def read_led(self, index: int) -> np.ndarray:
        super().read_led(index)
        return self.frame(index)

    def close(self) -> None:
        self.closed = True


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


def test_a_run_larger_than_the_budget_without_a_spill_folder_is_not_cached() -> None:
    ds = FakeDataset(6)
    cache = CachedLedFrames(ds, budget_bytes=5000)  # 6 x 1000 bytes do not fit
    for _ in range(2):
        for i in range(6):
            cache.read_led(i)
    assert all(ds.reads[i] == 2 for i in range(6))
    assert cache._bytes == 0                        # memory does not grow with the run


def test_a_run_larger_than_the_budget_is_decoded_once_into_the_spill_file(
        tmp_path: Path) -> None:
    """Each frame is decoded once and read back from an unlinked file in the spill
    folder (nothing is left there, nothing is kept in memory); colour and 16-bit
    frames come back exactly, read-only."""
    ds = MixedDataset(6)
    cache = CachedLedFrames(ds, budget_bytes=1000, spill_dir=tmp_path)   # 6 frames do not fit
    for _ in range(3):
        for i in range(6):
            got = cache.read_led(i)
            np.testing.assert_array_equal(got, ds.frame(i))
            assert got.dtype == ds.frame(i).dtype and not got.flags.writeable
    assert all(ds.reads[i] == 1 for i in range(6))
    assert cache._bytes == 0 and cache.spilled_bytes == sum(ds.frame(i).nbytes for i in range(6))
    assert list(tmp_path.iterdir()) == []           # the file has no name
    cache.close()
    assert ds.closed
    np.testing.assert_array_equal(cache.read_led(2), ds.frame(2))   # decoded again
    assert ds.reads[2] == 2


@pytest.mark.parametrize("where", ["memory", "spill file", "spill file, closed on a thread"])
def test_released_frames_are_decoded_again_and_the_dataset_stays_open(
        where: str, tmp_path: Path) -> None:
    # After the last pass that reads them the kept frames are let go (the spill file
    # closed, the memory freed); a later read still gets its frame, decoded again and
    # not kept, and the dataset stays open until close().
    ds = MixedDataset(4)
    budget = 10**6 if where == "memory" else 100
    cache = CachedLedFrames(ds, budget_bytes=budget, spill_dir=tmp_path)
    for i in range(4):
        cache.read_led(i)
    assert (cache._bytes > 0) == (where == "memory")
    assert (cache.spilled_bytes > 0) == (where != "memory")
    spill = cache._file
    cache.release(close_in_background=where.endswith("thread"))
    assert cache._bytes == 0 and cache._file is None and not ds.closed
    for thread in threading.enumerate():
        if thread.name == "close the spill file":
            thread.join()
    assert spill is None or spill.closed
    for _ in range(2):
        np.testing.assert_array_equal(cache.read_led(1), ds.frame(1))
    assert ds.reads[1] == 3 and cache._bytes == 0
    cache.close()
    assert ds.closed


def test_the_spill_file_stays_within_its_budget(tmp_path: Path) -> None:
    ds = FakeDataset(6)
    cache = CachedLedFrames(ds, budget_bytes=0, spill_dir=tmp_path, spill_budget_bytes=2500)
    for _ in range(2):
        for i in range(6):
            assert cache.read_led(i)[0, 0] == i
    assert cache.spilled_bytes == 2000              # the first two frames kept
    assert [ds.reads[i] for i in range(6)] == [1, 1, 2, 2, 2, 2]


def test_a_spill_folder_that_cannot_take_the_file_leaves_the_frames_decoded(
        tmp_path: Path) -> None:
    ds = FakeDataset(3)
    cache = CachedLedFrames(ds, budget_bytes=0, spill_dir=tmp_path / "missing")
    for _ in range(2):
        for i in range(3):
            assert cache.read_led(i)[0, 0] == i
    assert all(ds.reads[i] == 2 for i in range(3)) and cache.spilled_bytes == 0


@pytest.mark.parametrize("where", ["memory", "spill file"])
def test_concurrent_reads_give_the_right_frames(where: str, tmp_path: Path) -> None:
    ds = FakeDataset(20)
    cache = (CachedLedFrames(ds, budget_bytes=10**6) if where == "memory" else
             CachedLedFrames(ds, budget_bytes=0, spill_dir=tmp_path))
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


def test_a_full_disk_gives_the_spill_file_up_and_its_space_back(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A write that fails (ENOSPC) ends the spilling: the file is emptied so that the
    outputs still fit, every frame is still right, decoded at each read from then on."""
    import errno
    import os

    from pipestitch.pipeline import frame_cache

    ds = FakeDataset(4)
    cache = CachedLedFrames(ds, budget_bytes=0, spill_dir=tmp_path)
    cache.read_led(0)
    assert cache.spilled_bytes == 1000
    written = os.pwrite

    def full(fd: int, data: object, offset: int) -> int:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(frame_cache.os, "pwrite", full)
    assert cache.read_led(1)[0, 0] == 1
    monkeypatch.setattr(frame_cache.os, "pwrite", written)
    assert cache.spilled_bytes == 0 and os.fstat(cache._file.fileno()).st_size == 0
    for _ in range(2):
        for i in range(4):
            assert cache.read_led(i)[0, 0] == i
    assert [ds.reads[i] for i in range(4)] == [3, 3, 2, 2]
    cache.close()


@pytest.mark.parametrize("budget", [5000, 100])
def test_a_frame_is_judged_blank_once_per_decode(budget: int,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """blank_led gives blank_frame's verdict (frame 0 is all 0: black; the others flat
    grey), asking it once per decode: once per frame when the run is kept, at every
    read when the frames are decoded again (budget too small, no spill folder); a
    dataset without the cache is judged at every call."""
    import pipestitch.pipeline.frame_cache as frame_cache
    from pipestitch.camera.frames import blank_frame

    asked: Counter[int] = Counter()

    def counted(frame: np.ndarray) -> str:
        asked[int(frame[0, 0])] += 1
        return blank_frame(frame)

    monkeypatch.setattr(frame_cache, "blank_frame", counted)
    ds = FakeDataset(5)
    cache = CachedLedFrames(ds, budget_bytes=budget)
    for _ in range(3):
        for i in range(5):
            verdict = frame_cache.blank_led(cache, i, cache.read_led(i))
            assert verdict == blank_frame(np.full((10, 100), i, np.uint8))
    assert "black" in frame_cache.blank_led(cache, 0, cache.read_led(0))
    decodes = 1 if budget == 5000 else 3
    assert ds.reads == Counter({i: decodes + (i == 0 and budget == 100) for i in range(5)})
    assert asked == ds.reads
    frame_cache.blank_led(ds, 2, ds.read_led(2))   # not the cache: judged at each call
    assert asked == ds.reads

"""Frames decoded ahead are read exactly as the files themselves, and only while useful."""

from __future__ import annotations

import os
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from pipestitch.errors import DatasetError
from pipestitch.io import ahead
from pipestitch.io.ahead import DecodeAhead
from pipestitch.io.images import read_image
from pipestitch.pipeline import warm_start
from pipestitch.pipeline.warm_start import decode_ahead


def _frames(folder: Path, n: int, shape=(48, 64)) -> list[Path]:
    rng = np.random.default_rng(3)
    paths = []
    for i in range(n):
        path = folder / f"img_{i:02d}.png"
        cv2.imwrite(str(path), rng.integers(0, 255, shape, dtype=np.uint8))
        paths.append(path)
    return paths


def _wait_until(predicate, seconds: float = 10.0) -> None:
    end = time.monotonic() + seconds
    while not predicate():
        assert time.monotonic() < end, "decode-ahead thread did not get there"
        time.sleep(0.005)


def test_frames_decoded_ahead_are_the_files_pixels(tmp_path: Path) -> None:
    paths = _frames(tmp_path, 6)
    expected = [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in paths]
    with DecodeAhead(paths, budget_bytes=10**9) as frames:
        _wait_until(lambda: frames.decoded == 6)
        got = [read_image(p, size=(64, 48)) for p in paths]
        assert frames.decoded == 0   # each taken once
        assert ahead.take(paths[0]) is None   # a second read decodes the file itself
    for a, b in zip(got, expected, strict=True):
        np.testing.assert_array_equal(a, b)
    assert ahead.take(paths[1]) is None   # nothing is decoded ahead after the block


def test_a_file_changed_after_it_was_decoded_is_read_again(tmp_path: Path) -> None:
    paths = _frames(tmp_path, 2)
    with DecodeAhead(paths, budget_bytes=10**9) as frames:
        _wait_until(lambda: frames.decoded == 2)
        new = np.full((48, 64), 7, np.uint8)
        cv2.imwrite(str(paths[1]), new)
        st = os.stat(paths[1])
        os.utime(paths[1], ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
        np.testing.assert_array_equal(read_image(paths[1]), new)


def test_errors_are_those_of_the_file_itself(tmp_path: Path) -> None:
    paths = _frames(tmp_path, 2)
    paths[1].write_bytes(b"\x89PNG\r\n\x1a\n not really")
    with DecodeAhead(paths, budget_bytes=10**9) as frames:
        _wait_until(lambda: frames._reached == 2)
        assert frames.decoded == 1   # the corrupt file is left to the reader
        with pytest.raises(DatasetError) as wrong_size:
            read_image(paths[0], size=(32, 32))
        with pytest.raises(DatasetError) as corrupt:
            read_image(paths[1])
    with pytest.raises(DatasetError) as wrong_size_read:
        read_image(paths[0], size=(32, 32))
    assert str(wrong_size.value) == str(wrong_size_read.value)
    assert "from its header; not decoded" in str(wrong_size.value)
    assert "cannot decode image" in str(corrupt.value)


def test_the_thread_stops_at_its_budget(tmp_path: Path) -> None:
    paths = _frames(tmp_path, 8)
    with DecodeAhead(paths, budget_bytes=3 * 48 * 64) as frames:
        frames._thread.join(10)
        assert not frames._thread.is_alive()
        assert frames.decoded == 3


def test_a_reader_that_caught_up_stops_the_thread(tmp_path: Path) -> None:
    paths = _frames(tmp_path, 40)
    frames = DecodeAhead(paths, budget_bytes=10**9)   # not started: at its first file
    # a reader sampling the run far ahead does not stop the thread
    assert frames.take(paths[30]) is None
    assert not frames._stopped.is_set()
    assert frames.take(paths[0]) is None   # the reader at the thread's position: once
    assert not frames._stopped.is_set()
    assert frames.take(paths[1]) is None   # twice: caught up
    assert frames._stopped.is_set()
    with frames:
        frames._thread.join(10)
        assert frames.decoded == 0


def test_files_asked_for_ahead_of_the_thread_are_not_decoded_by_it(tmp_path: Path) -> None:
    paths = _frames(tmp_path, 6)
    frames = DecodeAhead(paths, budget_bytes=10**9)
    assert frames.take(paths[4]) is None
    with frames:
        frames._thread.join(10)
        assert [p for p in paths if p in frames._done] == paths[:4] + paths[5:]


def test_a_runs_frames_are_decoded_in_the_pose_pass_order(tmp_path: Path,
                                                          monkeypatch) -> None:
    made = []   # the run's allocator settings come before the thread allocates anything
    monkeypatch.setattr(warm_start, "keep_buffers_in_heap", lambda: made.append(True))
    (tmp_path / "frames").mkdir()
    for name in ("laser_00000.png", "led_00000.png", "laser_00001.png", "led_00001.png",
                 "laser_00002.png", "notes.txt"):
        (tmp_path / "frames" / name).write_bytes(b"")
    frames = decode_ahead(tmp_path)
    assert made and not frames._thread.is_alive()
    assert [p.name for p in frames._paths] == ["laser_00000.png", "led_00000.png",
                                               "laser_00001.png", "led_00001.png",
                                               "laser_00002.png"]
    assert not isinstance(decode_ahead(tmp_path, video=tmp_path / "run.mp4"), DecodeAhead)
    assert not isinstance(decode_ahead(tmp_path / "missing"), DecodeAhead)


def test_what_read_image_would_refuse_unread_is_not_decoded_ahead(tmp_path: Path) -> None:
    paths = _frames(tmp_path, 2)
    big = tmp_path / "img_02.png"   # small file, 16-bit 3000 x 3000: 54 MB decoded
    cv2.imwrite(str(big), np.zeros((3000, 3000, 3), np.uint16))
    other = tmp_path / "img_03.png"   # another size than the run's first frame
    cv2.imwrite(str(other), np.zeros((10, 10), np.uint8))
    fifo = tmp_path / "img_04.png"
    os.mkfifo(fifo)   # never opened: a reader would block on it
    with DecodeAhead([paths[0], other, fifo, *paths[1:], big],
                     budget_bytes=2**20) as frames:
        frames._thread.join(10)
        assert not frames.running
        assert sorted(frames._done) == sorted(paths)   # the big one would pass the budget


def test_a_block_that_raises_ends_the_thread_and_releases_the_frames(tmp_path: Path) -> None:
    paths = _frames(tmp_path, 30)
    with pytest.raises(RuntimeError), DecodeAhead(paths, budget_bytes=10**9) as frames:
        raise RuntimeError("the run failed")
    assert not frames.running and frames.decoded == 0
    assert ahead.take(paths[0]) is None


def test_frames_passed_over_are_dropped_once_the_thread_has_ended(tmp_path: Path) -> None:
    paths = _frames(tmp_path, 40)
    with DecodeAhead(paths, budget_bytes=10**9) as frames:
        frames._thread.join(10)
        assert frames.decoded == 40   # all decoded: the thread ended by itself
        frames.take(paths[0])
        assert frames.decoded == 39   # nothing behind the furthest file taken
        frames.take(paths[30])
        assert frames.decoded == 38 - (30 - ahead.KEPT_BEHIND - 1)
        assert frames.take(paths[30 - ahead.KEPT_BEHIND - 1]) is None   # dropped
        np.testing.assert_array_equal(frames.take(paths[31])[1],
                                      cv2.imread(str(paths[31]), cv2.IMREAD_UNCHANGED))

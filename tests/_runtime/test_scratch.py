"""Per-thread scratch buffers: reused within a thread, never shared between threads."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from pipestitch._runtime import scratch
from pipestitch.camera.frames import to_grey


def test_a_key_gives_the_same_array_until_its_shape_or_dtype_changes() -> None:
    a = scratch.buffer("t", (4, 5), np.float32)
    assert scratch.buffer("t", (4, 5), np.float32) is a
    assert scratch.buffer("other", (4, 5), np.float32) is not a
    b = scratch.buffer("t", (4, 6), np.float32)
    assert b is not a and b.shape == (4, 6)
    c = scratch.buffer("t", (4, 6), np.float64)
    assert c.dtype == np.float64
    scratch.release()
    assert scratch.buffer("t", (4, 6), np.float64) is not c
    scratch.release()


def test_threads_get_their_own_buffers() -> None:
    def take(_: int) -> int:
        arr = scratch.buffer("t", (8,), np.float32)
        arr[:] = 1
        return id(arr)

    mine = scratch.buffer("t", (8,), np.float32)
    mine[:] = 0
    with ThreadPoolExecutor(max_workers=1) as pool:
        other = pool.submit(take, 0).result()
    assert other != id(mine) and not mine.any()
    scratch.release()


def test_to_grey_into_a_buffer_is_the_same_as_a_new_array() -> None:
    frame = np.random.default_rng(0).integers(0, 65535, (30, 40), dtype=np.uint16)
    out = scratch.buffer("grey", frame.shape, np.float32)
    got = to_grey(frame, out=out)
    assert got is out
    np.testing.assert_array_equal(got, to_grey(frame))
    scratch.release()

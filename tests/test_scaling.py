"""imaging.scaled_float32: numpy's scaled float32 cast, to the bit, compiled or not."""

from __future__ import annotations

import numpy as np
import pytest

from pipestitch.imaging import scaled_float32

RNG = np.random.default_rng(11)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("read_only", [False, True])
def test_a_grey_integer_frame_is_numpys_product(dtype: type, read_only: bool) -> None:
    top = np.iinfo(dtype).max
    frame = RNG.integers(0, top, (37, 53), dtype=dtype, endpoint=True)
    frame[0, :2] = [0, top]
    frame.flags.writeable = not read_only
    scale = 1.0 / top
    want = np.multiply(frame, np.float32(scale), dtype=np.float32)
    np.testing.assert_array_equal(scaled_float32(frame, scale), want)
    out = np.full(frame.shape, np.nan, np.float32)
    assert scaled_float32(frame, scale, out=out) is out
    np.testing.assert_array_equal(out, want)


def test_other_frames_are_left_to_numpy() -> None:
    """A colour channel (strided), signed and float frames, 3-D frames: numpy's result;
    an ``out`` of the wrong shape: numpy's error."""
    colour = RNG.integers(0, 255, (20, 30, 3), dtype=np.uint8)
    for values in (colour[..., 1], colour, RNG.integers(-9, 9, (5, 7), dtype=np.int16),
                   RNG.random((6, 4)).astype(np.float32)):
        np.testing.assert_array_equal(scaled_float32(values, 0.5),
                                      np.multiply(values, np.float32(0.5), dtype=np.float32))
    with pytest.raises(ValueError):
        scaled_float32(colour[..., 0].copy(), 0.5, out=np.empty((3, 3), np.float32))

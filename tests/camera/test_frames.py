"""Camera frames as grey values, and frames that show no picture at all."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipestitch.camera import blank_frame, mean_level
from pipestitch.camera.frames import to_grey


@pytest.mark.parametrize("frame,word", [
    (np.zeros((480, 640), np.uint8), "black"),
    (np.full((480, 640, 3), 65535, np.uint16), "saturated"),
    (np.full((480, 640), 0.5, np.float32), "flat"),
    (np.full((480, 640), np.nan, np.float32), "no finite"),
])
def test_a_frame_without_a_picture_is_named_blank(frame: np.ndarray, word: str) -> None:
    assert word in blank_frame(frame)


def test_hot_pixels_and_one_count_of_noise_do_not_make_a_picture() -> None:
    rng = np.random.default_rng(0)
    frame = rng.integers(0, 2, (480, 640)).astype(np.uint8)   # dark-frame noise, 0-1 DN
    frame[::4, ::4][:4, :4] = 255                             # 16 of 19200 samples hot
    assert "black" in blank_frame(frame)


@pytest.mark.parametrize("dtype,full", [(np.uint8, 255), (np.uint16, 65535), (np.float32, 1.0)])
def test_a_dim_textured_frame_is_a_picture(dtype: type, full: float) -> None:
    # a wall 5 % of full scale bright (13-19 DN of 8 bits) with 50 % contrast
    rng = np.random.default_rng(1)
    wall = 0.05 * full * (1 + 0.5 * rng.random((480, 640)))
    assert blank_frame(wall.astype(dtype)) == ""


def test_mean_level_is_a_fraction_of_full_scale_whatever_the_type() -> None:
    half = np.full((64, 80), 0.5)
    for frame in ((half * 255).round().astype(np.uint8), (half * 65535).round().astype(np.uint16),
                  np.dstack([half] * 3).astype(np.float32)):
        assert abs(mean_level(frame) - 0.5) < 0.003, frame.dtype
    with_nan = half.copy()
    with_nan[::8, ::16] = np.nan    # every other sampled pixel
    assert mean_level(with_nan) == 0.5
    assert np.isnan(mean_level(np.full((8, 8), np.nan)))


def _grey_whole_frame(img: np.ndarray) -> np.ndarray:
    """A colour frame as one OpenCV conversion of its whole float32 copy, then scaled."""
    scale = 1.0 / np.iinfo(img.dtype).max if img.dtype.kind in "ui" else 1.0
    grey = cv2.cvtColor(img[..., :3].astype(np.float32), cv2.COLOR_BGR2GRAY)
    return np.nan_to_num(grey * np.float32(scale), nan=0.0, posinf=0.0, neginf=0.0)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32, np.float64])
@pytest.mark.parametrize("shape", [(1024, 1224, 3), (65, 37, 4), (33, 1223, 3), (1, 5, 3),
                                   (31, 7, 3)])
def test_colour_to_grey_by_blocks_of_rows_is_the_whole_frame_s_conversion(
        dtype: type, shape: tuple[int, int, int]) -> None:
    """Blocks of rows cast and converted in turn, into a new array and into a buffer:
    the same float32 values as the whole frame converted at once, whatever the row
    length (so wherever OpenCV's vector loop ends) and with NaN in a float frame."""
    rng = np.random.default_rng(shape[1])
    if np.dtype(dtype).kind == "u":
        img = rng.integers(0, np.iinfo(dtype).max, shape, endpoint=True).astype(dtype)
    else:
        img = rng.random(shape).astype(dtype)
        img[0, 0, 1] = np.nan
    given = img.copy()
    want = _grey_whole_frame(img)
    np.testing.assert_array_equal(to_grey(img), want)
    out = np.full(shape[:2], -1.0, np.float32)
    assert to_grey(img, out=out) is out
    np.testing.assert_array_equal(out, want)
    strided = np.full((shape[1], shape[0]), -1.0, np.float32).T   # not C-ordered: not used
    np.testing.assert_array_equal(to_grey(img, out=strided), want)
    np.testing.assert_array_equal(img, given)   # the frame itself is left as it was

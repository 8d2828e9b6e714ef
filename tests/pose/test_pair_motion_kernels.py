"""The compiled correlations of the LED frame's shift against the OpenCV blurs they
replace (bitwise) and against their definition."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipestitch.pose._pair_motion_kernels import ROWS, _box_means, box_mean_reflect

RNG = np.random.default_rng(11)


@pytest.mark.parametrize("length", [1, 3, 5, 7, 15])
@pytest.mark.parametrize("size", [1, 2, 3, 4, 6, 7, 8, 15, 16, 29, 707])
def test_a_box_mean_is_opencvs_blur_to_the_bit(length: int, size: int) -> None:
    """Rows shorter than the box (reflected more than once), as long as it, and a
    ring's length; the values of a log reflectance high-passed (both signs)."""
    row = RNG.normal(0.0, 0.3, size).astype(np.float32)
    want = cv2.blur(row[None, :], (length, 1), borderType=cv2.BORDER_REFLECT)[0]
    got = np.full(size, np.nan, np.float32)
    box_mean_reflect(row, length, got)
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("length", [3, 5, 7, 15])
@pytest.mark.parametrize("size", [1, 5, 15, 16, 300])
def test_rows_side_by_side_are_each_opencvs_blur_to_the_bit(length: int, size: int) -> None:
    rows = RNG.normal(0.0, 0.3, (ROWS, size)).astype(np.float32)
    want = cv2.blur(rows, (length, 1), borderType=cv2.BORDER_REFLECT)
    got = np.full(rows.shape, np.nan, np.float32)
    _box_means(rows, length, got)
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("length", [2, 4, 16])
def test_a_box_of_even_length_is_refused(length: int) -> None:
    # cv2.blur puts an even box off centre; the kernels take centred ones only
    row = np.ones(9, np.float32)
    with pytest.raises(ValueError, match="odd"):
        box_mean_reflect(row, length, np.empty_like(row))
    with pytest.raises(ValueError, match="odd"):
        _box_means(np.ones((ROWS, 9), np.float32), length, np.empty((ROWS, 9), np.float32))

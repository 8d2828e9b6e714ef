"""The compiled correlations of the LED frame's shift against the OpenCV blurs they
replace (bitwise) and against their definition."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipestitch.pose._pair_motion_kernels import ROWS, row_means

RNG = np.random.default_rng(11)


@pytest.mark.parametrize("length", [1, 3, 5, 7, 15])
@pytest.mark.parametrize("size", [1, 2, 3, 4, 5, 6, 7, 8, 15, 16, 29, 300, 707])
def test_box_means_are_opencvs_blur_to_the_bit(length: int, size: int) -> None:
    """Rows shorter than the box (reflected more than once), as long as it, and a
    ring's length; the values of a log reflectance high-passed (both signs)."""
    rows = RNG.normal(0.0, 0.3, (ROWS, size)).astype(np.float32)
    want = cv2.blur(rows, (length, 1), borderType=cv2.BORDER_REFLECT)
    got = np.full(rows.shape, np.nan, np.float32)
    row_means(rows, length, got)
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("length", [2, 4, 16])
def test_a_box_of_even_length_is_refused(length: int) -> None:
    # cv2.blur puts an even box off centre; the kernels take centred ones only
    rows = np.ones((ROWS, 9), np.float32)
    with pytest.raises(ValueError, match="odd"):
        row_means(rows, length, np.empty_like(rows))

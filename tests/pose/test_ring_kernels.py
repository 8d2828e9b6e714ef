"""The compiled laser-ring kernels against the numpy expressions they replace."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipestitch.pose._ring_kernels import flatten_by_reflectance, ridge_peaks

RNG = np.random.default_rng(7)


def test_ridge_peaks_are_the_strongest_local_maxima() -> None:
    ridge = RNG.random((50, 80)).astype(np.float32)
    index, value = ridge_peaks(ridge, 0.3, 3)
    for row, idx, val in zip(ridge, index, value, strict=True):
        j = np.arange(2, row.size - 2)
        peak = j[(row[j] > 0.3) & (row[j] > row[j - 1]) & (row[j] >= row[j + 1])]
        best = peak[np.argsort(-row[peak], kind="stable")][:3]
        assert list(idx[:best.size]) == list(best)
        np.testing.assert_array_equal(val[:best.size], row[best])
        assert np.all(np.isneginf(val[best.size:]))


@pytest.mark.parametrize("shape", [(30, 40), (9, 200), (1, 7), (13, 1)])
@pytest.mark.parametrize("box", [3, 41, 81])
def test_reflectance_division_is_opencvs_blurs_and_the_numpy_expression(
        shape: tuple[int, int], box: int) -> None:
    """Row counts that are not a multiple of the kernel's block, boxes longer than a
    row, a dark patch and zeros: the same float32 values, to the bit (the float64
    sums of float32 samples are exact here whatever their order)."""
    polar, local = (RNG.random(shape).astype(np.float32) for _ in range(2))
    local[: shape[0] // 2, : shape[1] // 3] *= 0.05
    local[-1, :2] = 0
    kernel = (box, 1)
    broad = cv2.blur(cv2.blur(local, kernel, borderType=cv2.BORDER_REPLICATE), kernel,
                     borderType=cv2.BORDER_REPLICATE)
    valid = (local > 0.15 * broad) & (broad > 0)
    relative = np.where(valid, local / np.where(broad > 0, broad, 1.0), 1.0)
    want = np.where(valid, polar / np.maximum(relative, 0.15), 0.0).astype(np.float32)
    got = flatten_by_reflectance(polar, local, box, 0.15, 0.15)
    np.testing.assert_array_equal(got, want)
    assert np.any(got == 0) and np.any(got != 0)

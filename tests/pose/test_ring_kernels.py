"""The compiled laser-ring kernels against the numpy expressions they replace."""

from __future__ import annotations

import numpy as np

from pipestitch.pose._ring_kernels import divide_by_reflectance, ridge_peaks

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


def test_reflectance_division_is_the_numpy_expression() -> None:
    polar, local, broad = (RNG.random((30, 40)).astype(np.float32) for _ in range(3))
    broad[0, :5] = 0
    valid = (local > 0.15 * broad) & (broad > 0)
    relative = np.where(valid, local / np.where(broad > 0, broad, 1.0), 1.0)
    want = np.where(valid, polar / np.maximum(relative, 0.15), 0.0).astype(np.float32)
    np.testing.assert_array_equal(divide_by_reflectance(polar, local, broad, 0.15, 0.15), want)

"""The invert detection's median: numpy's, from one sort."""

from __future__ import annotations

import numpy as np


def test_the_sorted_median_is_numpys_nanmedian() -> None:
    """Along either axis, with NaN (a whole line of them too), ties, infinities, odd
    and even counts, float32 and float64: the same values and dtype as ``np.nanmedian``."""
    import warnings

    from pipestitch.standards.invert import _nanmedian

    rng = np.random.default_rng(0)
    for dtype in (np.float32, np.float64):
        for shape in ((50, 7), (7, 50), (300, 40), (3, 1), (1, 4), (0, 3)):
            a = rng.random(shape).astype(dtype)
            a[rng.random(shape) < 0.3] = np.nan
            if a.size:
                a[0] = np.nan
                a[:, 0] = np.round(a[:, 0] * 4) / 4
                a[-1, -1] = np.inf
            for axis in (0, 1):
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)
                    want = np.nanmedian(a, axis=axis)
                got = _nanmedian(a, axis)
                assert got.dtype == want.dtype
                np.testing.assert_array_equal(got, want)

"""The kernels' small sorts give numpy's order exactly."""

from __future__ import annotations

import numba
import numpy as np

from pipestitch.pose._fit_kernels import argsort_small

RNG = np.random.default_rng(11)


@numba.njit
def _numba_argsort(d: np.ndarray) -> np.ndarray:
    return np.argsort(d)


def test_argsort_small_is_numbas_argsort() -> None:
    """The order numba's ``np.argsort`` gave (the one it replaces), ties and NaN included."""
    for n in range(1, 16):
        for _ in range(50):
            d = np.round(RNG.normal(size=n), 1)          # ties
            d[RNG.random(n) < 0.1] = np.nan
            got = argsort_small(d)
            np.testing.assert_array_equal(got, _numba_argsort(d))
            np.testing.assert_array_equal(got, np.argsort(d, kind="stable"))

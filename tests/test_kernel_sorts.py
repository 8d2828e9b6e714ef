"""The kernels' small selections give numpy's order statistics and order exactly."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from pipestitch.mosaic._unwrap_kernels import select
from pipestitch.pose._fit_kernels import argsort_small

RNG = np.random.default_rng(11)


@pytest.mark.parametrize("kind", ["random", "ties", "sorted", "reversed", "constant"])
def test_select_gives_the_order_statistics_of_np_partition(kind: str) -> None:
    for n in (1, 2, 3, 5, 8, 33, 200):
        values = RNG.normal(size=n).astype(np.float32)
        if kind == "ties":
            values = np.round(values).astype(np.float32)
        elif kind == "sorted":
            values = np.sort(values)
        elif kind == "reversed":
            values = np.sort(values)[::-1].copy()
        elif kind == "constant":
            values[:] = 1.5
        for k in {0, n // 2, n - 1}:
            a = np.concatenate([values, np.full(3, np.nan, np.float32)])   # tail untouched
            select(a, n, k)
            want = np.partition(values, k)
            assert a[k] == want[k]
            assert np.all(a[:k] <= a[k]) and np.all(a[k + 1:n] >= a[k])
            assert np.array_equal(np.sort(a[:n]), np.sort(values))
            assert np.isnan(a[n:]).all()


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

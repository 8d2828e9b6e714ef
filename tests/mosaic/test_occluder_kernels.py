"""The compiled frame-stack quantile and variance against numpy's."""

from __future__ import annotations

import numpy as np
import pytest

from pipestitch.mosaic._occluder_kernels import quantile_over_frames, variance_over_frames

RNG = np.random.default_rng(7)


@pytest.mark.parametrize("n", [1, 2, 3, 6, 11, 12, 21, 321])


@pytest.mark.parametrize("q", [0.85, 0.5, 0.1])
def test_frame_quantiles_are_numpy_quantiles(n: int, q: float) -> None:
    stack = RNG.random((n, 9, 13)).astype(np.float32)
    stack[:, 0, 0] = 0.5                       # ties
    quant, med = quantile_over_frames(stack, (n - 1) * q, True)   # numpy's linear index
    np.testing.assert_array_equal(quant, np.quantile(stack, q, axis=0))
    np.testing.assert_array_equal(med, np.median(stack, axis=0))


@pytest.mark.parametrize("n", [2, 3, 5, 11, 12])
@pytest.mark.parametrize("ddof", [0, 1])
def test_frame_variances_are_numpy_variances_to_the_bit(n: int, ddof: int) -> None:
    """Values of very different scales (a dark sensor's thousandths, 8-bit counts) and a
    constant pixel: every rounding of numpy's float32 sums and float64 divisions."""
    scale = RNG.choice(np.array([1e-3, 1.0, 255.0], np.float32), size=(n, 17, 23))
    stack = (RNG.random((n, 17, 23)).astype(np.float32) * scale).astype(np.float32)
    stack[:, 3, 4] = 0.25
    np.testing.assert_array_equal(variance_over_frames(stack, ddof),
                                  np.var(stack, axis=0, ddof=ddof))

"""The compiled frame-stack quantile against numpy's quantile."""

from __future__ import annotations

import numpy as np
import pytest

from pipestitch.mosaic._occluder_kernels import quantile_over_frames

RNG = np.random.default_rng(7)


@pytest.mark.parametrize("n", [1, 2, 3, 6, 11, 12])


@pytest.mark.parametrize("q", [0.85, 0.5, 0.1])
def test_frame_quantiles_are_numpy_quantiles(n: int, q: float) -> None:
    stack = RNG.random((n, 9, 13)).astype(np.float32)
    stack[:, 0, 0] = 0.5                       # ties
    quant, med = quantile_over_frames(stack, n * q + (1 - q) - 1, True)
    np.testing.assert_array_equal(quant, np.quantile(stack, q, axis=0))
    np.testing.assert_array_equal(med, np.median(stack, axis=0))

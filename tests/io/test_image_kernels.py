"""The compiled 8-bit mosaic conversion against the numpy expression it replaces."""

from __future__ import annotations

import numpy as np

from pipestitch.io._image_kernels import scaled_uint8

RNG = np.random.default_rng(7)


def test_scaled_uint8_is_the_numpy_conversion() -> None:
    image = (3 * RNG.random((40, 50))).astype(np.float32)
    image[3, :9] = np.nan
    image[4, :3] = np.inf
    image[5, :4] = 0   # data, mapped to 1
    finite = np.isfinite(image)
    want = np.zeros(image.shape, np.uint8)
    want[finite] = np.clip(np.rint(image[finite] / 1.7 * 250), 1, 255).astype(np.uint8)
    np.testing.assert_array_equal(scaled_uint8(image, 1.7), want)
